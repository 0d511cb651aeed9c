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
