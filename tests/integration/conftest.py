"""Integration tests start real processes (world, agents, recorder) talking over Zenoh on
loopback with multicast scouting off and a free explicit port. They wait on messages
and exit codes with deadlines, never on fixed sleeps, and always stop the process
groups they started."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from swarm.config import ScenarioConfig, load
from swarm.runs.launch import RunHandle

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
PLUGIN_SOURCES = (
    Path(__file__).resolve().parents[2] / "examples" / "vo_filter",  # c3swarm_vo.vo
    Path(__file__).resolve().parents[1] / "data" / "plugins" / "c3swarm_faulty",  # faulty.*
)


def scenario(file: str, **over: object) -> ScenarioConfig:
    """A shipped config with top-level fields replaced (dicts merge)."""
    return load(CONFIGS / file, dict(over))


@pytest.fixture
def start_run(tmp_path: Path) -> Iterator:
    handles: list[RunHandle] = []

    def start(cfg: ScenarioConfig, name: str = "run", **kw: Any) -> RunHandle:
        h = RunHandle.start(cfg, tmp_path / name, **kw)
        handles.append(h)
        return h

    yield start
    for h in handles:
        if h.reason is None:
            h.finish("test teardown")


def wait_linked(h: RunHandle, session: Any, heard: Any, probe_key: str, what: str = "the run") -> None:
    """Until a put of ``session`` on ``probe_key`` (its own keys) reaches the channel ``heard``
    of another session of the run: the first is linked. Raises after 100 tries, each one world
    status message apart."""
    from swarm.net import transport as tp

    for _ in range(100):
        session.put(probe_key, b"hello")
        h.wait_sim_time(h.progress.t_s + 0.02)
        if any(tp.payload(x) == b"hello" for x in tp.drain(heard)):
            return
    raise AssertionError(f"the session never linked to {what}")


SITL_DIR = Path(__file__).resolve().parents[3] / "shared" / "crazyflie-sitl"
"""CrazySim's firmware source and build script, beside the checkout (CI has ``../shared/``)."""


def _build_cf2(cache: Path) -> Path:
    """``SITL_DIR/build.sh`` into ``cache`` (once per version of its tarball: a file lock
    keeps concurrent sessions from building it twice)."""
    import fcntl
    import hashlib
    import subprocess

    tag = hashlib.sha1((SITL_DIR / "crazyflie-firmware-sitl.tar.xz").read_bytes()).hexdigest()[:12]
    out = cache / f"crazyflie-sitl-{tag}"
    out.mkdir(parents=True, exist_ok=True)
    with open(out / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (out / "cf2").is_file():
            res = subprocess.run(["bash", str(SITL_DIR / "build.sh"), str(out)], capture_output=True, text=True)
            if res.returncode != 0:
                raise RuntimeError(f"building the firmware failed:\n{res.stdout}\n{res.stderr}")
    return out / "cf2"


@pytest.fixture(scope="session")
def cf2() -> Path:
    """CrazySim's firmware binary: ``$C3SWARM_CF2`` (``.ci/run`` builds it and sets it), else
    built once from ``../shared/crazyflie-sitl/`` into ``$XDG_CACHE_HOME/c3swarm``. Where
    neither can be had the test skips saying why; with ``C3SWARM_CI`` set it fails."""
    import os
    import shutil

    from swarm.world.fw_process import CF2_ENV, find_cf2

    why = ""
    if os.environ.get(CF2_ENV):
        try:
            return find_cf2(None)
        except FileNotFoundError as exc:
            why = str(exc)
    elif not (SITL_DIR / "build.sh").is_file():
        why = f"no Crazyflie firmware: set {CF2_ENV} to a CrazySim cf2 build, or put crazyflie-sitl at {SITL_DIR}"
    elif not all(shutil.which(t) for t in ("cmake", "make", "cc")):
        why = (
            "building the Crazyflie firmware needs cmake, make and a C compiler (apt-get install cmake build-essential)"
        )
    else:
        cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "c3swarm"
        return _build_cf2(cache)
    if os.environ.get("C3SWARM_CI"):
        pytest.fail(f"{why} (.ci/run should have built it)")
    pytest.skip(why)


def install_plugins(target: Path) -> None:
    """Install the example plugin and the faulty ones into ``target`` as a user installs a
    package (pip, no dependencies), from copies (the build leaves nothing in the checkout). With
    setuptools and ``wheel`` in the environment (the dev extra) the build is offline, with them;
    without, pip builds in isolation from the configured index."""
    import importlib.util
    import shutil
    import subprocess
    import sys

    srcs = []
    for src in PLUGIN_SOURCES:
        copy = target.parent / f"src-{src.name}"
        shutil.copytree(src, copy, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
        srcs.append(str(copy))
    have = all(importlib.util.find_spec(m) is not None for m in ("setuptools", "wheel"))
    offline = ["--no-build-isolation"] if have else []
    cmd = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", *offline, "--target", str(target), *srcs]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, f"installing the plugins failed:\n{res.stdout}\n{res.stderr}"


@pytest.fixture(scope="session")
def plugins(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The example plugin (``c3swarm_vo.vo``) and the faulty ones (``faulty.*``) installed into a
    folder on this process's path and on every process it starts (``PYTHONPATH``); the folder."""
    import os
    import sys

    target = tmp_path_factory.mktemp("plugins") / "site"
    install_plugins(target)
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join([*([old] if old else []), str(target)])
    sys.path.append(str(target))
    try:
        yield target
    finally:
        sys.path.remove(str(target))
        if old is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = old
