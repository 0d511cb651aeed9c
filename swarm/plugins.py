"""Plugins by entry point: the safety filters, reference controllers and planners a run can fly
(docs/plugins.md).

A safety filter is found by its name in the entry-point group :data:`FILTERS`
(``c3swarm.filters``), a reference controller in :data:`CONTROLLERS` (``c3swarm.controllers``), a
planner in :data:`PLANNERS` (``c3swarm.planners``),
among the installed distributions' entries (``importlib.metadata.entry_points``), the built-ins
as any other: c3swarm's own ``pyproject.toml`` registers ``c3bf``, ``hocbf``, ``path_tracker``,
``grid`` and ``none``, and :data:`BUILTIN` holds the same entries for an install whose metadata
predates them (an editable install of an older checkout). A config names one with ``filter.kind``
(``controller.kind``) and gives its options with ``filter.options`` (``controller.options``);
:func:`plugin_class` and :func:`plugin_options` check both when the config is loaded, so an
unknown name, a plugin that cannot be imported or options its own schema refuses stop the run
before anything flies (``ConfigError`` naming the field: the CLI exits 2).

The protocols, and their containment in flight, are in :mod:`swarm.safety.external` (filters),
:mod:`swarm.reference` (controllers) and :mod:`swarm.planner` (planners).
"""

from __future__ import annotations

import sys
from functools import lru_cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from pydantic import BaseModel, ValidationError

FILTERS = "c3swarm.filters"
"""The entry-point group of safety filters: ``name = "module:Class"``."""

CONTROLLERS = "c3swarm.controllers"
"""The entry-point group of reference controllers: ``name = "module:Class"``."""

PLANNERS = "c3swarm.planners"
"""The entry-point group of planners: ``name = "module:Class"``."""

BUILTIN: dict[str, dict[str, str]] = {
    FILTERS: {"c3bf": "swarm.safety.external:C3BF", "hocbf": "swarm.safety.external:HOCBF"},
    CONTROLLERS: {"path_tracker": "swarm.reference:PathTracking"},
    PLANNERS: {"grid": "swarm.planner:GridPlanner", "none": "swarm.planner:Straight"},
}

_WHAT = {FILTERS: ("filter", "filter"), CONTROLLERS: ("controller", "reference"), PLANNERS: ("planner", "plan")}
"""Per group: what its plugins are called, and the method each must have."""
"""c3swarm's own entries (the same as its ``pyproject.toml``'s), per group."""

UNFILTERED = "none"
"""The name ``swarm compare`` and ``swarm sweep`` give flying the reference unfiltered
(``filter.enabled: false``); not a filter, so no plugin may take it."""


class PluginError(ValueError):
    """A plugin that cannot be used; the config's validation names the field it came from."""


def registered(group: str = FILTERS) -> dict[str, EntryPoint]:
    """Every entry of ``group`` by name: the installed distributions' and c3swarm's own.
    Raises :class:`PluginError` when two distributions register one name for different objects.
    Read once per import path (``sys.path``): a package installed into a folder already on it
    is found by a new process."""
    return dict(_registered(group, tuple(sys.path)))


@lru_cache(maxsize=8)
def _registered(group: str, path: tuple[str, ...]) -> dict[str, EntryPoint]:
    found: dict[str, EntryPoint] = {}
    eps = list(entry_points(group=group)) + [EntryPoint(n, v, group) for n, v in BUILTIN.get(group, {}).items()]
    for ep in eps:
        other = found.get(ep.name)
        if other is not None and other.value != ep.value:
            raise PluginError(f"{ep.name!r} is registered twice in {group}: {other.value} and {ep.value}")
        found[ep.name] = ep
    return found


def names(group: str = FILTERS) -> list[str]:
    """The registered names of ``group``, sorted."""
    return sorted(registered(group))


def plugin_class(group: str, name: str) -> type:
    """The class registered in ``group`` as ``name``. Raises :class:`PluginError` (unknown name,
    an import that fails, an object that is not a class with the group's method)."""
    what, method = _WHAT[group]
    if group == FILTERS and name == UNFILTERED:
        raise PluginError(f"{name!r} is not a filter: fly unfiltered with filter.enabled: false")
    eps = registered(group)
    ep = eps.get(name)
    if ep is None:
        raise PluginError(
            f"unknown {what} {name!r}; registered in {group}: {', '.join(sorted(eps))} "
            "(a plugin's package must be installed in this environment: docs/plugins.md)"
        )
    try:
        obj = ep.load()
    except Exception as exc:  # an import error of any kind: the plugin is not usable
        raise PluginError(f"{what} {name!r} ({ep.value}) cannot be imported: {type(exc).__name__}: {exc}") from None
    if not isinstance(obj, type) or not callable(getattr(obj, method, None)):
        raise PluginError(f"{what} {name!r} ({ep.value}) is not a class with a {method}(inp) method")
    return obj


def filter_class(name: str) -> type:
    """The safety filter class registered as ``name`` (:func:`plugin_class` of :data:`FILTERS`)."""
    return plugin_class(FILTERS, name)


def filter_options(cls: type, options: dict[str, Any]) -> BaseModel | None:
    """``options`` validated by a plugin class's ``Options`` model (None: it takes none).
    Raises :class:`PluginError` whose message starts with the option's path (``options.x: ...``)."""
    from swarm.safety.external import options_of

    model = options_of(cls)
    if model is None:
        if options:
            raise PluginError(f"options: {cls.__name__} takes no options, got {sorted(options)}")
        return None
    try:
        return model.model_validate(options)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
        raise PluginError(f"options{'.' + where if where else ''}: {first['msg']}{more}") from None


plugin_options = filter_options
