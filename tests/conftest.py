"""Markers by folder: everything under ``tests/unit`` is ``unit`` (pure code, no processes),
everything under ``tests/integration`` is ``integration`` (real processes, Zenoh, PyBullet):
``python -m pytest -m unit`` runs the fast half."""

from __future__ import annotations

from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        folder = Path(str(item.fspath)).resolve().relative_to(HERE).parts[0]
        if folder in ("unit", "integration"):
            item.add_marker(getattr(pytest.mark, folder))
