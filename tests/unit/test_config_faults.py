"""Configs that cannot fly are refused before anything starts: ``swarm run`` exits 2 with
one line naming the file, the field and the reason, in under 2 s, and leaves no run folder."""

from __future__ import annotations

import copy
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swarm.config import AGENTS_PER_CPU, ConfigError, load, machine_cpus, resolve
from tools.bad_configs import CASES, patched, write_bad_files

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("case", sorted(CASES))
def test_impossible_config_is_a_config_error_naming_the_field(case: str) -> None:
    change, field = CASES[case]
    with pytest.raises(ConfigError) as err:
        resolve(patched(change), "bad.yaml")
    assert str(err.value).startswith("bad.yaml: ") and field in str(err.value), str(err.value)


def test_swarm_run_refuses_each_bad_file_with_exit_2_fast_and_starts_nothing(tmp_path: Path) -> None:
    slowest = 0.0
    t0 = time.monotonic()  # the pace of this run: the command line's own start-up, refusing nothing
    subprocess.run([sys.executable, "-m", "swarm.cli", "--help"], capture_output=True, timeout=60, cwd=ROOT, check=True)
    start_up = time.monotonic() - t0
    for case, (path, needle) in write_bad_files(tmp_path).items():
        out = tmp_path / f"run-{case}"
        t0 = time.monotonic()
        p = subprocess.run(
            [sys.executable, "-m", "swarm.cli", "run", str(path), "--out", str(out)],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=ROOT,
        )
        took = time.monotonic() - t0
        slowest = max(slowest, took)
        assert p.returncode == 2, (case, p.returncode, p.stderr[-2000:])
        lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
        assert lines == [lines[0]] and re.match(rf"config error: {re.escape(str(path))}(:\d+)?: ", lines[0]), (
            case,
            p.stderr,
        )  # the file, and the line where the key is written
        assert needle in lines[0], (case, lines[0])
        assert "Traceback" not in p.stderr
        assert not out.exists(), f"{case}: a run folder was made"
    # a refusal costs about the command line's start-up (no world, no simulator, no session), at any pace
    assert slowest < 3.0 * start_up + 0.5, (slowest, start_up)


def test_the_agent_limit_can_be_raised_knowingly() -> None:
    n = AGENTS_PER_CPU * machine_cpus() + 1
    agents = [{"id": f"a{i}", "start": [0.5 * i, 0.0, 1.0], "goal": [0.5 * i, 5.0, 1.0]} for i in range(n)]
    raw = {"version": 1, "name": "many", "duration_s": 1.0, "agents": agents}
    with pytest.raises(ConfigError, match=f"limits.max_agents: {n}"):
        resolve(copy.deepcopy(raw), "many.yaml")
    assert len(resolve({**raw, "limits": {"max_agents": n}}, "many.yaml").agents) == n


def test_shipped_configs_still_load() -> None:
    for p in sorted((ROOT / "configs").rglob("*.yaml")):
        load(p)
