"""Scripting a running swarm: :class:`Swarm` (the client), the orders it sends and the
agent's side of them (``script.enabled``; docs/scripting.md)."""

from swarm.errors import ArrivalTimeoutError, RefusedError, ScriptError
from swarm.script.client import DroneState, Orders, Report, Snapshot, Swarm

__all__ = ["ArrivalTimeoutError", "DroneState", "Orders", "RefusedError", "Report", "ScriptError", "Snapshot", "Swarm"]
