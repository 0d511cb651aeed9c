"""``swarm sweep --engine ray`` on a local Ray cluster that the tests start (``ray start
--head`` in a temporary folder): the same results as the local pool, a run whose Ray
worker is killed leaves no process behind and is flown again, a failed run is a row, and
``--resume`` flies only the points without a row."""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import secrets
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarm.config import load
from swarm.runs.reaper import process_groups
from swarm.runs.sweep import parse_axes, sweep

pytestmark = pytest.mark.integration

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
TIMING = {"solve_us_mean", "attempts", "error"}  # columns that differ between two flights of a point


def _ray_or_skip() -> None:
    """Skip where Ray is not installed (CI fails instead), without importing it."""
    if importlib.util.find_spec("ray") is None:
        if os.environ.get("C3SWARM_CI"):
            raise AssertionError("ray is not installed: .ci/run installs it with the dev extra")
        pytest.skip("ray is not installed (pip install -e '.[cluster]')")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def ray_cluster(plugins: Path) -> Iterator[str]:
    """A one-node Ray cluster (4 logical CPUs) in a temporary folder, with a token of its own
    (whatever ``~/.ray`` holds), its workers finding the installed plugins (``plugins``); its address."""
    _ray_or_skip()
    auth = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32), "RAY_USAGE_STATS_ENABLED": "0"}
    env = dict(os.environ, **auth)
    saved = {k: os.environ.get(k) for k in auth}
    os.environ.update(auth)  # this process connects with the same token (read when ray is imported)
    ray_bin = str(Path(sys.executable).with_name("ray"))
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # (Ray's socket paths must stay short)
    port = _free_port()
    subprocess.run(
        [ray_bin, "start", "--head", "--num-cpus", "4", "--port", str(port), "--temp-dir", temp,
         "--include-dashboard", "false", "--disable-usage-stats"],
        check=True, capture_output=True, env=env, timeout=180,
    )  # fmt: skip
    try:
        yield f"127.0.0.1:{port}"
    finally:
        import ray

        ray.shutdown()
        subprocess.run([ray_bin, "stop", "--force"], capture_output=True, env=env, timeout=120)
        shutil.rmtree(temp, ignore_errors=True)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _base(duration_s: float = 3.0) -> dict:
    raw = load(CONFIGS / "sweeps" / "head_on.yaml").model_dump(mode="json")
    raw["duration_s"] = duration_s
    return raw


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


def test_a_ray_sweep_gives_the_local_pool_s_table(ray_cluster, tmp_path):
    axes = parse_axes(["filter=c3bf,hocbf", "obstacle_speed=1"])
    sweep(_base(), axes, tmp_path / "local", jobs=2)
    events: list[tuple[str, str]] = []  # progress: each point heard to start, then to end
    rows = sweep(
        _base(),
        axes,
        tmp_path / "ray",
        engine="ray",
        address=ray_cluster,
        on_start=lambda h: events.append(("start", h["run"])),
        on_done=lambda r: events.append(("done", r["run"])),
    )
    assert [r["attempts"] for r in rows] == [1, 1] and not any(r["error"] for r in rows)
    for r in rows:
        assert events.count(("start", r["run"])) == 1
        assert events.index(("start", r["run"])) < events.index(("done", r["run"]))
    ray, local = _rows(tmp_path / "ray" / "results.csv"), _rows(tmp_path / "local" / "results.csv")
    differ = [{k: (a[k], b.get(k)) for k in a if a[k] != b.get(k)} for a, b in zip(ray, local, strict=True)]
    assert not any(differ), differ  # (ray's, the pool's) of each column that differs, by row


def test_a_ray_sweep_flies_a_plugin_beside_c3bf(ray_cluster, tmp_path):
    rows = sweep(
        _base(), parse_axes(["filter=c3bf,c3swarm_vo.vo"]), tmp_path / "ray", engine="ray", address=ray_cluster
    )
    assert [r["filter"] for r in rows] == ["c3bf", "c3swarm_vo.vo"] and not any(r["error"] for r in rows), rows
    assert all(r["collisions"] == 0 and r["plugin_fallbacks"] == 0 for r in rows), rows


def _alive(group: int) -> bool:
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return False
    return True


def _wait_ended(leaders: list[int], timeout_s: float) -> None:
    """Block until every group leader has exited (a pidfd each, readable at its exit), then
    check that nothing is left in their groups."""
    deadline = time.monotonic() + timeout_s
    for pid in leaders:
        try:
            fd = os.pidfd_open(pid)
        except ProcessLookupError:
            continue
        try:
            ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
            assert ready, f"process {pid} of the killed run still runs after {timeout_s} s"
        finally:
            os.close(fd)
    assert not any(_alive(g) for g in leaders)


def _wait_for(check, folder: Path, timeout_s: float, what: str) -> None:
    """Block until ``check()`` holds, looking again each time a file in ``folder`` (made if
    missing) is written or created (Linux inotify), with a deadline."""
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    folder.mkdir(parents=True, exist_ok=True)
    fd = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
    assert fd >= 0, "inotify_init1 failed"
    try:
        in_modify, in_close_write, in_create, in_moved_to = 0x2, 0x8, 0x100, 0x80
        mask = in_modify | in_close_write | in_create | in_moved_to
        assert libc.inotify_add_watch(fd, str(folder).encode(), mask) >= 0, "inotify_add_watch failed"
        deadline = time.monotonic() + timeout_s
        while not check():
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"timed out waiting for {what}")
            if select.select([fd], [], [], left)[0]:
                os.read(fd, 65536)  # the events themselves are not needed: look again
    finally:
        os.close(fd)


def test_a_killed_worker_leaves_no_process_and_its_point_is_flown_again(ray_cluster, tmp_path):
    out = tmp_path / "sweep"
    axes = parse_axes(["obstacle_speed=0.5,1"])
    first = out / "p000_obstacle_speed-0.5"
    killed: dict[str, object] = {}

    def kill_first_worker() -> None:
        # once the first point's world and agent are up, kill its Ray worker outright
        _wait_for(lambda: len(process_groups(first)) >= 3 and (first / "worker.pid").exists(), first, 120, "the run")
        killed["groups"] = process_groups(first)
        os.kill(int((first / "worker.pid").read_text()), signal.SIGKILL)

    t = threading.Thread(target=kill_first_worker, daemon=True)
    t.start()
    rows = sweep(_base(6.0), axes, out, engine="ray", address=ray_cluster)
    t.join(5)
    groups = killed["groups"]
    assert isinstance(groups, list) and groups
    assert (out / "p000_obstacle_speed-0.5.attempt1").is_dir()  # what the first attempt left is kept
    # every process the killed attempt started, those it listed after the kill too, has ended
    every = process_groups(out / "p000_obstacle_speed-0.5.attempt1")
    assert set(groups) <= set(every)
    _wait_ended(every, 15)
    assert rows[0]["attempts"] == 2 and rows[0]["error"] == ""  # flown again, in full
    assert [r["attempts"] for r in rows[1:]] == [1] and all(r["collisions"] == 0 for r in rows)


def test_resume_flies_only_the_points_without_a_row(tmp_path):
    out = tmp_path / "sweep"
    axes = parse_axes(["obstacle_speed=0.5,1"])
    sweep(_base(), axes, out)
    (out / "p001_obstacle_speed-1" / "row.json").unlink()  # as if the sweep had stopped before it ended
    flown: list[str] = []
    started: list[str] = []
    rows = sweep(
        _base(),
        axes,
        out,
        resume=True,
        on_start=lambda h: started.append(h["run"]),
        on_done=lambda r: flown.append(r["run"]),
    )
    assert flown == started == ["p001_obstacle_speed-1"]
    assert [r["run"] for r in rows] == ["p000_obstacle_speed-0.5", "p001_obstacle_speed-1"]
    assert len(_rows(out / "results.csv")) == 2


def test_a_run_that_fails_is_a_row_with_its_reason(tmp_path):
    raw = _base()
    raw["obstacles"] = [{"id": "ball", "shape": "sphere", "center": [4.0, 0.0, 1.0], "radius_m": 0.3}]
    raw["agents"][0]["goal"] = [8.0, 0.0, 2.0]  # a 3-D scene with an obstacle: ORCA cannot fly it
    rows = sweep(raw, parse_axes(["filter=orca,c3bf"]), tmp_path / "sweep")
    assert rows[0]["success"] == 0 and "ConfigError" in rows[0]["error"]
    assert rows[1]["error"] == "" and rows[1]["collisions"] == 0  # the other point still flew


def test_the_liveness_benchmark_on_ray_prints_the_local_pool_s_lines(ray_cluster, capsys):
    from tools import bench_liveness

    def lines(**kw) -> list[dict]:
        bench_liveness.main(quick=True, family="formation", jobs=1, orca=False, **kw)
        return [json.loads(s) for s in capsys.readouterr().out.splitlines() if s.startswith("{")]

    local = lines()
    on_ray = lines(engine="ray", address=ray_cluster)
    assert len(local) == 2 and on_ray == local  # rho 1 and 0.5, every figure to the bit
