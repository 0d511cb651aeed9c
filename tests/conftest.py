"""Markers by folder: everything under ``tests/unit`` is ``unit`` (pure code, no processes),
everything under ``tests/integration`` is ``integration`` (real processes, Zenoh, PyBullet):
``python -m pytest -m unit`` runs the fast half.

The suite runs on pytest-xdist's workers (``pyproject.toml``: up to four, a file per worker at a
time, unit tests first). Integration tests time real processes on every core, so under xdist
they take turns (:class:`Turns`): no unit test runs while an integration test does, and one
integration file at a time. ``-n 0`` runs everything in one process, in the same order."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
TURNS = pytest.StashKey["Turns"]()
KIND = pytest.StashKey[str]()  # an item's folder: "unit" or "integration"


def _folder(item: pytest.Item) -> str:
    parts = Path(str(item.fspath)).resolve().relative_to(HERE).parts
    return parts[0] if parts[0] in ("unit", "integration") else "unit"


class Turns:
    """One xdist worker's side of a lock file shared by the run's workers: a shared ``flock``
    while it runs unit tests, an exclusive one while it runs an integration file. A worker
    waiting for its turn holds neither, so two workers cannot wait on each other."""

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        self.held: str | None = None

    def take(self, kind: str) -> None:
        if self.held == kind:
            return
        self.release()
        fcntl.flock(self.fd, fcntl.LOCK_EX if kind == "integration" else fcntl.LOCK_SH)
        self.held = kind

    def release(self) -> None:
        if self.held is not None:
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            self.held = None


def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config, "workerinput"):  # an xdist worker: xdist puts its basetemp in the run's, where the lock is
        run_temp = Path(config.option.basetemp).parent
        run_temp.mkdir(parents=True, exist_ok=True)
        config.stash[TURNS] = Turns(run_temp / "turns.lock")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        item.stash[KIND] = _folder(item)
        item.add_marker(getattr(pytest.mark, item.stash[KIND]))
    items.sort(key=lambda item: item.stash[KIND] == "integration")  # (stable: unit tests first, each half in order)


@pytest.hookimpl(hookwrapper=True, tryfirst=True)  # outside pytest-timeout's: waiting for a turn is not the test's time
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):  # type: ignore[no-untyped-def]
    turns = item.config.stash.get(TURNS, None)
    kind = item.stash[KIND]
    if turns is not None:
        turns.take(kind)
    yield
    if turns is not None and (
        nextitem is None or nextitem.stash[KIND] != kind or (kind == "integration" and nextitem.path != item.path)
    ):
        turns.release()  # (after the file's module fixtures are torn down, in this item's teardown)


def pytest_unconfigure(config: pytest.Config) -> None:
    turns = config.stash.get(TURNS, None)
    if turns is not None:
        turns.release()
        os.close(turns.fd)
