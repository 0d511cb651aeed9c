"""The examples run as a user would run them (``examples/``)."""

import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_the_filter_example_filters_a_command_towards_a_sphere():
    p = subprocess.run([sys.executable, str(EXAMPLES / "filter_call.py")], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("status ok, u = [") and "intervention" in p.stdout, p.stdout
