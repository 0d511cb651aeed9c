"""The package's layout: the safety core imports nothing of the runtime, the QP backends'
registry closes no import circle, and the modules' old paths still import, as the same
modules, with a warning."""

from __future__ import annotations

import ast
import importlib
import sys
import warnings
from pathlib import Path

import pytest

from swarm._moved import MOVED

pytestmark = pytest.mark.unit

SWARM = Path(__file__).resolve().parents[2] / "swarm"


def _imports(path: Path) -> set[str]:
    """Every ``swarm...`` module that ``path`` imports, at any depth of the file."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("swarm"):
            out |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("swarm")}
    return out


def test_the_safety_core_imports_only_itself_and_the_model():
    allowed = ("swarm.safety", "swarm.errors", "swarm.rotation", "swarm.model")
    for path in (SWARM / "safety").rglob("*.py"):
        bad = {m for m in _imports(path) if not m.startswith(allowed)}
        assert not bad, f"{path.relative_to(SWARM)} imports {sorted(bad)}"


def test_no_qp_backend_import_leads_back_to_the_registry():
    qp = SWARM / "safety" / "qp"
    assert not {m for m in _imports(qp / "problem.py") if "backend" in m or "registry" in m}
    for backend in qp.glob("*_backend.py"):
        assert not {m for m in _imports(backend) if m.endswith("registry")}, backend.name


@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_import_path_gives_the_moved_module_with_a_warning(old):
    new = importlib.import_module(MOVED[old])
    sys.modules.pop(old, None)  # (another test may have imported it already)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert importlib.import_module(old) is new
    assert any(issubclass(w.category, DeprecationWarning) and MOVED[old] in str(w.message) for w in caught)
    assert new.__spec__ is not None and new.__spec__.name == MOVED[old]  # the module keeps its own spec


def test_a_class_imported_by_its_old_path_is_the_same_class():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from swarm.filter import SafetyFilter as OldFilter
        from swarm.qp.problem import QPStatus as OldStatus
    from swarm.safety.filter import SafetyFilter
    from swarm.safety.qp.problem import QPStatus

    assert OldFilter is SafetyFilter and OldStatus is QPStatus


def _room(module: str) -> str | None:
    """The room of ``swarm...`` module ``module``: its top-level folder or module of the package."""
    parts = module.split(".")
    if parts[0] != "swarm" or len(parts) < 2:
        return None
    top = SWARM / parts[1]
    return parts[1] if top.is_dir() or top.with_suffix(".py").exists() else None


def test_the_package_s_folders_and_modules_import_one_way():
    """No top-level folder or module of the package imports one that imports it back, at any
    depth (function-level imports count): the layers point one way."""
    import graphlib

    graph: dict[str, set[str]] = {}
    for path in SWARM.rglob("*.py"):
        rel = path.relative_to(SWARM)
        src = rel.parts[0].removesuffix(".py")
        rooms = {_room(m) for m in _imports(path)} - {None, src}
        graph.setdefault(src, set()).update(r for r in rooms if r is not None)
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as e:
        pytest.fail(f"a loop of imports between the package's folders and modules: {e.args[1]}")
