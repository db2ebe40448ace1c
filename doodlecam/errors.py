"""The one family of exceptions a user can cause.

The CLI prints ``str(error)`` on one line, without a traceback, and exits
non-zero. Messages say what is wrong *and* what to do about it.
"""


class DoodleError(Exception):
    """Base class: a problem the user can fix (bad input, bad profile, ...)."""

    exit_code = 2


class InputError(DoodleError):
    """An input file is missing, unreadable, or holds nothing to draw."""


class MachineError(DoodleError):
    """A machine profile is missing, malformed, or physically impossible."""


class PluginError(DoodleError):
    """A plugin is unknown, failed to import, or misbehaved."""


class PlanError(DoodleError):
    """A path cannot be planned within the machine's limits."""


class OutputError(DoodleError):
    """An output cannot be written."""
