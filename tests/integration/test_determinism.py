"""How far "the same config gives the same trajectories" holds (issue 21).

* On one machine, bit for bit, whatever the processes' CPU placement and thread counts:
  a lockstep run pinned one process per CPU, the same unpinned with every numerical
  library on one thread, and the same with the whole run confined to one CPU.
* Against a stored reference trajectory (``tests/data/reference_swap3.json``, written by
  this module with ``--write`` from the code of the commit it names), to 1 mm: a change
  of results from another machine's libraries or CPU, or from a code change, is caught
  here. A deliberate change of behaviour rewrites the reference in the same commit.

    python -m tests.integration.test_determinism --write
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from swarm.config import ScenarioConfig, load
from swarm.net.messages import measurement_agent
from swarm.runs.launch import RunHandle
from swarm.runs.runfiles import read_records

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "tests" / "data" / "reference_swap3.json"
SAMPLE_EVERY = 24  # ticks (0.2 s at 120 Hz) in the stored reference
REFERENCE_TOL_M = 1e-3
THREADS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


def config() -> ScenarioConfig:
    agents = [
        {"id": "cf1", "start": [0.0, 0.0, 1.0], "goal": [4.0, 0.0, 1.0]},
        {"id": "cf2", "start": [4.0, 0.05, 1.0], "goal": [0.0, 0.05, 1.0]},
        {"id": "cf3", "start": [2.0, 1.5, 1.0], "goal": [2.0, -1.5, 1.0], "speed_mps": 0.5},
    ]
    return load(ROOT / "configs" / "swap_2.yaml", {"name": "determinism", "duration_s": 8.0, "agents": agents})


def positions(run_dir: Path) -> dict[str, dict[int, list[float]]]:
    """Every recorded measurement's position [m, world] by agent and tick."""
    out: dict[str, dict[int, list[float]]] = {}
    for r in read_records(run_dir / "run.mcap"):
        if r["kind"] == "measurement":
            out.setdefault(measurement_agent(r), {})[r["k"]] = [*r["x"], *r["q"], *r["v"]]
    return out


def _run(cfg: ScenarioConfig, out: Path) -> dict[str, dict[int, list[float]]]:
    h = RunHandle.start(cfg, out)
    assert h.wait() == "completed"
    return positions(h.out)


def test_the_same_run_bit_for_bit_whatever_cpus_and_threads(tmp_path, monkeypatch):
    cfg = config()
    pinned = _run(cfg, tmp_path / "pinned")
    unpinned = cfg.model_copy(update={"time": cfg.time.model_copy(update={"pin_cpus": False})})
    for var in THREADS:
        monkeypatch.setenv(var, "1")
    one_thread = _run(unpinned, tmp_path / "one_thread")
    cpus = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(cpus)})  # the children inherit it: the whole run on one CPU
    try:
        one_cpu = _run(cfg, tmp_path / "one_cpu")
    finally:
        os.sched_setaffinity(0, cpus)
    for other in (one_thread, one_cpu):
        assert other.keys() == pinned.keys() == {"cf1", "cf2", "cf3"}
        for a in pinned:
            assert other[a] == pinned[a], a  # every tick's position, attitude and velocity, bit for bit

    ref = json.loads(REFERENCE.read_text())
    for a, samples in ref["positions"].items():
        for k, x in samples.items():
            err = float(np.linalg.norm(np.subtract(pinned[a][int(k)][:3], x)))
            assert err <= REFERENCE_TOL_M, (a, k, err, ref["commit"])


def write_reference() -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        pos = _run(config(), Path(tmp) / "ref")
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    sampled = {a: {str(k): x[:3] for k, x in sorted(by_k.items()) if k % SAMPLE_EVERY == 0} for a, by_k in pos.items()}
    REFERENCE.parent.mkdir(exist_ok=True)
    REFERENCE.write_text(json.dumps({"commit": commit, "tolerance_m": REFERENCE_TOL_M, "positions": sampled}, indent=1))
    print(f"wrote {REFERENCE}")


if __name__ == "__main__":
    if sys.argv[1:] == ["--write"]:
        write_reference()
    else:
        print(__doc__)
