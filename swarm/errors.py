"""Exceptions raised at the library boundary."""


class InputError(ValueError):
    """An argument is not acceptable: wrong shape, not finite, out of range.

    The message names the argument and the reason, so a caller can show it as is.
    """
