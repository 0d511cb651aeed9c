"""The package as a user installs it: a wheel built from the checkout holds every module of
the source tree, and installed (not editable) in a fresh virtual environment it flies the
README's swarm from a folder outside the checkout."""

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


def test_a_non_editable_install_in_a_fresh_venv_flies_the_readme_swarm(wheel: Path, tmp_path: Path):
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
    out = tmp_path / "run"
    proc = subprocess.run(
        [str(venv / "bin" / "swarm"), "run", str(ROOT / "configs" / "swap_2.yaml"), "--out", str(out)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["complete"] and metrics["all_reached_goal"] and metrics["collisions"] == 0
