"""Exceptions that the command line maps to exit statuses.

``InputError`` (and its subclasses) mean bad input or configuration: the command line prints its
message on one line and exits with status 2. Anything else is an internal error (status 1).
"""


class InputError(ValueError):
    """Bad input: a malformed record, an unknown plugin name, an invalid option."""


class RecordError(InputError):
    """A record file or array that cannot be used (missing column, NaN, non-uniform time ...)."""


class PluginNotFoundError(InputError, KeyError):
    """A plugin name that no registered plugin provides."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class UnstableError(InputError):
    """An unstable plant, controller or closed loop; the message says which."""
