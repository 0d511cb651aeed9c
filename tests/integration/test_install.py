"""The package as a user installs it: a wheel built from the checkout holds every module of
the source tree, and installed (not editable) in a fresh virtual environment it flies a swarm
from a folder outside the checkout, compiling its kernels into an empty cache."""

from __future__ import annotations

import json
import shutil
import site
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    src, out = tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("wheel")
    for name in ("pyproject.toml", "README.md"):  # a copy: the build writes build/ and egg-info beside it
        shutil.copy(ROOT / name, src / name)
    shutil.copytree(ROOT / "swarm", src / "swarm", ignore=shutil.ignore_patterns("__pycache__"))
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out), str(src)],
        check=True,
        timeout=300,
    )
    (whl,) = out.glob("c3swarm-*.whl")
    return whl


def test_the_wheel_holds_every_module_of_the_source_tree(wheel: Path):
    tree = {p.relative_to(ROOT).as_posix() for p in (ROOT / "swarm").rglob("*.py")}
    with zipfile.ZipFile(wheel) as z:
        held = {n for n in z.namelist() if n.endswith(".py")}
    assert tree - held == set(), f"modules missing from {wheel.name}"
    assert {"swarm/safety/filter.py", "swarm/agents/agent.py", "swarm/world/main.py"} <= held
    assert not {n for n in held if n.startswith(("tests/", "tools/"))}


def _site_packages() -> list[str]:
    """This environment's site folders, which the fresh one borrows its dependencies from
    (as folders on its path: their ``.pth`` files, this checkout's editable install among them,
    are not run)."""
    dirs = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"], *site.getsitepackages()}
    return sorted(d for d in dirs if Path(d).is_dir())


def test_a_non_editable_install_in_a_fresh_venv_starts_eight_agents_on_its_empty_compile_cache(
    wheel: Path, tmp_path: Path
):
    """After an install (or a code change) numba's on-disk cache is empty: the kernels are compiled
    once (9 to 32 s of CPU, by machine and hour; the fork server's warm-up) and every process loads
    them. Eight agents that each compiled at once would need four times that on two cores, past
    the run's start timeout."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    purelib = subprocess.run(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    (Path(purelib) / "borrowed_deps.pth").write_text("\n".join(_site_packages()) + "\n")
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "--quiet", str(wheel)],
        check=True,
        timeout=300,
    )
    where = subprocess.run(
        [str(py), "-c", "import swarm.safety.filter as f, swarm.agents.agent as a; print(f.__file__, a.__file__)"],
        check=True,
        capture_output=True,
        text=True,
        cwd=tmp_path,
    ).stdout
    assert str(ROOT) not in where and "site-packages" in where, where
    cfg = yaml.safe_load((ROOT / "configs" / "circle_8.yaml").read_text())
    cfg["duration_s"] = 0.5
    cfg.setdefault("time", {})["start_timeout_s"] = 75.0
    (tmp_path / "circle_8.yaml").write_text(yaml.safe_dump(cfg))
    out = tmp_path / "run"
    proc = subprocess.run(
        [str(venv / "bin" / "swarm"), "run", str(tmp_path / "circle_8.yaml"), "--out", str(out)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["complete"] and metrics["collisions"] == 0 and set(metrics["exit_codes"].values()) == {0}, metrics
    assert len(metrics["agents"]) == 8
    assert any((Path(purelib) / "swarm").rglob("*.nbi"))  # its kernels compiled beside the installed package
