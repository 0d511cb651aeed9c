"""Every error c3swarm raises on purpose, under one base class, :class:`SwarmError`.

Each also derives from the built-in it refines (``ValueError``, ``RuntimeError``), so a
caller may catch either. The message names what was wrong and why, so it can be shown as is.
"""


class SwarmError(Exception):
    """Base of every c3swarm error."""


class InputError(SwarmError, ValueError):
    """An argument is not acceptable: wrong shape, not finite, out of range."""


class ConfigError(SwarmError, ValueError):
    """A config that cannot run: ``file: field.path: reason``."""


class DecodeError(SwarmError, ValueError):
    """A message that is malformed, of another version or run, or of an unexpected kind."""


class SecretsError(SwarmError, RuntimeError):
    """The run's credentials are missing, unreadable or open to other users."""


class ScriptError(SwarmError, RuntimeError):
    """A script's client cannot do what it was asked: the run not reached, the credentials
    refused, the run over (``swarm.script``)."""


class RefusedError(ScriptError, ValueError):
    """An order refused before anything flew: an unknown drone, one the script may not
    steer, a goal that is not finite, out of ``script.bounds_m`` or below the floor."""


class ArrivalTimeoutError(ScriptError, TimeoutError):
    """A drone did not arrive within the time given (run time)."""
