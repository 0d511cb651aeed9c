"""The import paths of modules that moved (into ``swarm.safety``, ``swarm.net``,
``swarm.offline`` and ``swarm.runs``, or were renamed there): importing an old path gives the module at its new one
(the same module object) with a :class:`DeprecationWarning`. Kept for one release
(CHANGELOG)."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from types import ModuleType

MOVED = {
    "swarm.barriers": "swarm.safety.barriers",
    "swarm.rows": "swarm.safety.constraints",
    "swarm.filter": "swarm.safety.filter",
    "swarm.obstacles": "swarm.safety.obstacles",
    "swarm.qp": "swarm.safety.qp",
    "swarm.qp.problem": "swarm.safety.qp.problem",
    "swarm.qp.daqp_backend": "swarm.safety.qp.daqp_backend",
    "swarm.qp.osqp_backend": "swarm.safety.qp.osqp_backend",
    "swarm.transport": "swarm.net.transport",
    "swarm.messages": "swarm.net.messages",
    "swarm.access": "swarm.net.access",
    "swarm.cells": "swarm.net.cells",
    "swarm.neighbours": "swarm.net.neighbours",
    "swarm.bundle": "swarm.net.bundle",
    "swarm.statewire": "swarm.net.statewire",
    "swarm.orca": "swarm.offline.orca",
    "swarm.closed_loop": "swarm.offline.closed_loop",
    "swarm.metrics": "swarm.offline.metrics",
    "swarm.scenario": "swarm.offline.scenario",
    "swarm.scene": "swarm.runs.foxglove_scene",
    "swarm.layout": "swarm.runs.foxglove_layout",
    "swarm.runs.scene": "swarm.runs.foxglove_scene",
    "swarm.runs.layout": "swarm.runs.foxglove_layout",
}
"""Old module path -> new module path."""


class _Alias(importlib.abc.Loader):
    """Loads an old path as the module at its new one."""

    def __init__(self, target: str) -> None:
        self.target = target
        self.spec: importlib.machinery.ModuleSpec | None = None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        warnings.warn(f"{spec.name} moved to {self.target}", DeprecationWarning, stacklevel=2)
        module = importlib.import_module(self.target)
        self.spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run (the module ran at its new path); its own spec back (the import
        system set the old path's)."""
        module.__spec__ = self.spec


class MovedFinder(importlib.abc.MetaPathFinder):
    """Finds the old paths of :data:`MOVED`."""

    def find_spec(
        self, fullname: str, path: object = None, target: object = None
    ) -> importlib.machinery.ModuleSpec | None:
        new = MOVED.get(fullname)
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _Alias(new), is_package=new == "swarm.safety.qp")


def install() -> None:
    """Put :class:`MovedFinder` first on ``sys.meta_path`` (once): before the path finder,
    which would otherwise load ``swarm.qp.problem`` from the moved package's folder as a
    second copy."""
    if not any(isinstance(f, MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, MovedFinder())
