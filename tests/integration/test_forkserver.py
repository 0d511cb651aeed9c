"""The fork server (swarm.runs.forkserver) starts a run's processes as ``subprocess.Popen``
would have, only without each importing numpy, numba and Zenoh again: held against Popen
itself (the same module from scratch) for what a process sees of itself and how it ends."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from swarm.runs import forkserver
from swarm.runs.launch import RunHandle
from swarm.runs.reaper import GROUPS_FILE, process_groups

from .conftest import scenario

ROOT = Path(__file__).resolve().parents[2]
CHILD = ["-m", "tests.integration.forkchild"]


@pytest.fixture(autouse=True)
def _ctrl_c_as_a_terminal_gives_it():
    """SIGINT at its default, as in a terminal: a shell's background job (a CI script's) starts
    with it ignored, and every process started from it, forked or not, would ignore it too."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)


@pytest.fixture
def server(_ctrl_c_as_a_terminal_gives_it):
    s = forkserver.ForkServer.start()  # (its own: the tests below kill it)
    yield s
    assert s.proc.stdin is not None
    s.proc.stdin.close()
    s.proc.wait(10)


def _facts(log: Path) -> dict:
    line = next(ln for ln in log.read_text().splitlines() if ln.startswith("FACTS "))
    return json.loads(line.removeprefix("FACTS "))


def _popen(args: list[str], log: Path, env: dict[str, str]) -> subprocess.Popen[bytes]:
    """What the launcher did before the fork server (and does with ``SWARM_FORKSERVER=0``)."""
    with open(log, "wb") as f:
        return subprocess.Popen(
            [sys.executable, *args], stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            start_new_session=True, env=env, cwd=ROOT,
        )  # fmt: skip


@pytest.fixture
def ready():
    """An abstract Unix socket each child tells its pid once it runs (``FORKCHILD_READY``), and
    the wait for those pids."""
    name = f"c3swarm-forkchild-{os.getpid()}-{time.monotonic_ns()}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind("\0" + name)
        sock.settimeout(30.0)

        def wait(*pids: int) -> None:
            heard: set[int] = set()
            while not set(pids) <= heard:
                heard.add(int(sock.recv(64)))  # (socket.timeout after 30 s: the child never ran)

        yield name, wait


@pytest.mark.parametrize(
    ("what", "sig"),
    [(["exit", "0"], None), (["exit", "3"], None), (["raise"], None), (["wait"], signal.SIGTERM),
     (["wait"], signal.SIGINT), (["wait"], signal.SIGKILL)],
)  # fmt: skip
def test_a_forked_process_sees_and_ends_as_one_started_from_scratch(server, ready, tmp_path, what, sig):
    name, wait_ready = ready
    env = {**{k: v for k, v in os.environ.items() if k != "HOME"}, "ONLY_THIS": "1", "PYTHONUNBUFFERED": "1"}
    env["FORKCHILD_READY"] = name
    forked = server.spawn([*CHILD, *what], tmp_path / "forked.log", env, tmp_path / GROUPS_FILE)
    scratch = _popen([*CHILD, *what], tmp_path / "scratch.log", env)
    if sig is not None:
        wait_ready(forked.pid, scratch.pid)
        for pid in (forked.pid, scratch.pid):
            os.killpg(pid, sig)  # (its own group, as the launcher signals it)
    assert forked.wait(30) == scratch.wait(30)
    f, s = _facts(tmp_path / "forked.log"), _facts(tmp_path / "scratch.log")
    assert f["pid"] == f["pgid"] == f["sid"] == forked.pid  # a session and process group of its own
    assert process_groups(tmp_path) == [forked.pid]  # listed for the reaper before it ran
    for key in ("argv", "name", "env", "stdin", "threads"):
        assert f[key] == s[key], key
    assert f["env"]["ONLY_THIS"] == "1" and "HOME" not in f["env"]  # its own environment, not the server's
    forked_log, scratch_log = ((tmp_path / n).read_text() for n in ("forked.log", "scratch.log"))
    assert forked_log.count("to stderr") == scratch_log.count("to stderr") == 1
    if what == ["raise"]:
        assert "RuntimeError: raised on purpose" in forked_log


def test_children_asked_for_from_many_threads_at_once_are_each_their_own(server, tmp_path):
    """A sweep's runs start their processes from threads of one launcher: each thread's child is
    the process it asked for (its pid, and so the group it signals), not another thread's."""
    env = dict(os.environ)

    def spawn(i: int) -> tuple[int, forkserver.Child]:
        return i, server.spawn([*CHILD, "exit", "0"], tmp_path / f"c{i}.log", env, tmp_path / GROUPS_FILE)

    with ThreadPoolExecutor(max_workers=8) as pool:
        children = list(pool.map(spawn, range(48)))
    for i, child in children:
        assert child.wait(30) == 0
        assert _facts(tmp_path / f"c{i}.log")["pid"] == child.pid, i


def test_with_its_server_gone_a_childs_end_is_still_seen(server, ready, tmp_path):
    name, wait_ready = ready
    env = dict(os.environ, FORKCHILD_READY=name)
    child = server.spawn([*CHILD, "wait"], tmp_path / "c.log", env, tmp_path / GROUPS_FILE)
    wait_ready(child.pid)
    server.proc.kill()
    server.proc.wait(10)
    assert child.poll() is None  # it runs on
    os.killpg(child.pid, signal.SIGKILL)
    assert child.wait(10) == 1  # (its code went with the server: unknown)


def test_a_changed_environment_gets_a_new_server_and_the_old_one_ends_its_children(ready, tmp_path, monkeypatch):
    name, wait_ready = ready
    old = forkserver.shared()
    assert old is not None and forkserver.shared() is old
    env = dict(os.environ, FORKCHILD_READY=name)
    child = old.spawn([*CHILD, "wait"], tmp_path / "c.log", env, tmp_path / GROUPS_FILE)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))  # what a server's imports read
    new = forkserver.shared()
    assert new is not None and new is not old and old.alive()
    wait_ready(child.pid)
    os.killpg(child.pid, signal.SIGTERM)
    assert child.wait(10) == -signal.SIGTERM  # still reported by the server that forked it
    monkeypatch.setenv(forkserver.DISABLE_ENV, "0")
    assert forkserver.shared() is None


def _parent(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


@pytest.mark.parametrize("forked", [True, False])
def test_a_run_forks_its_processes_from_the_server_unless_told_not_to(tmp_path, monkeypatch, forked):
    if not forked:
        monkeypatch.setenv(forkserver.DISABLE_ENV, "0")
    h = RunHandle.start(scenario("swap_2.yaml", duration_s=0.3), tmp_path / "run")
    try:
        parents = {name: _parent(p.pid) for name, p in h.procs.items()}
        server = forkserver.shared()
        expected = server.proc.pid if forked and server is not None else os.getpid()
        assert set(parents.values()) == {expected}, parents
        assert h.wait() == "completed"
    finally:
        if h.reason is None:
            h.finish("test teardown")
    m = json.loads((h.out / "metrics.json").read_text())
    assert set(m["exit_codes"].values()) == {0}, m["exit_codes"]


def test_a_run_s_process_that_outlives_sigterm_leaves_every_thread_s_stack_in_its_log(
    ready, start_run, monkeypatch, capsys
):
    """The launcher stops a run with SIGTERM and kills what is left after 5 s; what is left first
    writes its threads' stacks to its log (SIGUSR1, faulthandler: swarm.cli), so a process that
    hangs at its end says where."""
    name, wait_ready = ready
    h = start_run(scenario("swap_2.yaml", duration_s=1.0), "stubborn")
    monkeypatch.setenv("FORKCHILD_READY", name)
    h._spawn("stubborn", [*CHILD, "stubborn"])
    wait_ready(h.procs["stubborn"].pid)
    h.finish("test")
    assert h.procs["stubborn"].returncode == -signal.SIGKILL
    log = (h.out / "logs" / "stubborn.log").read_text()
    assert "most recent call first" in log and "forkchild.py" in log, log
    assert "stubborn did not end on SIGTERM in 5 s" in capsys.readouterr().err  # it alone
