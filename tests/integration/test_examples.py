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
