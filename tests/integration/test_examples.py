"""The swap example (``examples/swap_run.py``) as a user would run it."""

import json
import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_the_swap_example_flies_a_swap_and_prints_its_metrics(tmp_path):
    out = tmp_path / "swap"
    p = subprocess.run(
        [sys.executable, str(EXAMPLES / "swap_run.py"), "--out", str(out)], capture_output=True, text=True, timeout=300
    )
    assert p.returncode == 0, p.stderr[-3000:]
    assert p.stdout.startswith("completed: collisions 0"), p.stdout
    m = json.loads((out / "metrics.json").read_text())
    assert m["all_reached_goal"] is True and m["collisions"] == 0


def test_the_scripted_experiment_joins_a_running_swarm_and_flies_it(tmp_path):
    # as the example's docstring says: `swarm run` in one shell, the script in another (lockstep: the
    # swarm keeps its pace on a machine of any load)
    out = tmp_path / "s1"
    run = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "swarm.cli",
            "run",
            str(EXAMPLES.parent / "configs" / "script_lab.yaml"),
            "--out",
            str(out),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        p = subprocess.run(
            [sys.executable, str(EXAMPLES / "scripted_experiment.py"), str(out)],
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert p.returncode == 0, p.stderr[-3000:]
        assert run.wait(timeout=120) == 0, run.stderr.read()[-3000:] if run.stderr else ""
    finally:
        if run.poll() is None:
            run.terminate()
            run.wait(timeout=60)
    lines = p.stdout.splitlines()
    assert lines[0].startswith("joined run script_lab-") and lines[-1].endswith("landed"), p.stdout
    m = json.loads((out / "metrics.json").read_text())
    assert m["stop_reason"] == "completed" and m["collisions"] == 0
    assert len(m["orders"]) == 3 + 4 + 2 + 3 and all(o["arrived_s"] is not None for o in m["orders"])


def test_the_ros2_services_example_flies_the_same_experiment(tmp_path):
    import pytest

    pytest.importorskip("zenoh_ros2_sdk")
    out = tmp_path / "r1"
    p = subprocess.run(
        [sys.executable, str(EXAMPLES / "ros2_services.py"), "--out", str(out), "--mode", "lockstep"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert p.returncode == 0, p.stderr[-3000:]
    lines = p.stdout.splitlines()
    assert lines[0] == "all at 1 m" and "cf1 and cf2 swapped" in lines and lines[-1] == "landed", p.stdout
    m = json.loads((out / "metrics.json").read_text())
    assert m["collisions"] == 0
    log = (out / "logs" / "ros2.log").read_text()
    assert log.count("/cf1/go_to goal") == 5 and "/all/land land" in log, log[-2000:]
