"""A two-drone swap run from Python: the same processes as ``swarm run`` (world, router,
recorder, one agent each), started, waited for, and their metrics read.

    python examples/swap_run.py [--out runs/example_swap]
"""

import argparse
import json
from pathlib import Path

from swarm.config import load
from swarm.runs.launch import RunHandle

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def main(out: Path) -> dict:
    cfg = load(CONFIGS / "swap_2.yaml", {"name": "example_swap"})  # a shipped config, one field replaced
    run = RunHandle.start(cfg, out)
    reason = run.wait()  # "completed", or why it stopped
    metrics = json.loads((out / "metrics.json").read_text())
    print(
        f"{reason}: collisions {metrics['collisions']}, closest {metrics['min_separation_m']:.3f} m, "
        f"all at their goals {metrics['all_reached_goal']}"
    )
    return metrics


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("runs/example_swap"))
    main(ap.parse_args().out)
