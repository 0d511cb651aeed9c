"""A scripted experiment through the Python client (docs/scripting.md): three drones take off,
cf1 flies a square, cf1 and cf2 swap places, everyone lands, and the script ends the run.

    swarm run configs/script_lab.yaml --out runs/s1        # one shell: the swarm, waiting
    python examples/scripted_experiment.py runs/s1         # another: this script joins it

    python examples/scripted_experiment.py                 # or: start the run itself (runs/scripted)
"""

import argparse
import json
from pathlib import Path

from swarm.config import load
from swarm.script import Swarm

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "script_lab.yaml"
SQUARE = [[-0.5, -0.5, 1.0], [0.5, -0.5, 1.0], [0.5, 0.5, 1.0], [-0.5, 0.5, 1.0]]  # m, world


def experiment(swarm: Swarm) -> None:
    print(f"joined run {swarm.run}: drones {', '.join(swarm.drones)} at t = {swarm.now_s:.2f} s")
    swarm.takeoff(1.0, duration_s=2.5).wait(timeout_s=20.0)  # every drone, straight up to 1 m
    print(f"t = {swarm.now_s:5.2f} s  all at 1 m")
    for corner in SQUARE:
        swarm.go_to("cf1", corner, duration_s=1.5).wait(timeout_s=20.0)
        print(f"t = {swarm.now_s:5.2f} s  cf1 at {corner}")
    a, b = swarm.state("cf1").pos_w, swarm.state("cf2").pos_w
    swarm.go_to_many({"cf1": b, "cf2": a}).wait(timeout_s=40.0)  # head on: their filters keep them apart
    print(f"t = {swarm.now_s:5.2f} s  cf1 and cf2 swapped")
    swarm.sleep(1.0)  # a second of the run's time
    swarm.land().wait(timeout_s=20.0)
    print(f"t = {swarm.now_s:5.2f} s  landed")
    swarm.end("the experiment is done")


def main(run_dir: Path | None, out: Path, mode: str | None = None) -> dict:
    if run_dir is not None:
        with Swarm.connect(run_dir) as swarm:
            experiment(swarm)
        return {}
    with Swarm.launch(
        load(CONFIG, {"time": {"mode": mode}} if mode else None), out
    ) as swarm:  # leaving the block ends the run and writes its metrics
        experiment(swarm)
    metrics = json.loads((out / "metrics.json").read_text())
    print(f"{metrics['stop_reason']}: contacts {metrics['collisions']}, closest {metrics['min_separation_m']:.3f} m")
    for o in metrics["orders"]:
        print(f"  {o['drone']} {o['action']:8s} taken {o['taken_s']:6.2f} s  arrived {o['arrived_s']:6.2f} s")
    return metrics


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", nargs="?", type=Path, help="the folder of a running swarm (swarm run ... --out DIR)")
    ap.add_argument(
        "--mode", choices=["realtime", "lockstep"], help="the run's time.mode (no run_dir; default: the config's)"
    )
    ap.add_argument("--out", type=Path, default=Path("runs/scripted"), help="where to start the run (no run_dir)")
    args = ap.parse_args()
    main(args.run_dir, args.out, args.mode)
