"""The one family of exceptions a user can cause.

The CLI prints ``str(error)`` on one line, without a traceback, and exits
non-zero. Messages say what is wrong *and* what to do about it.
"""


def did_you_mean(name: str, known, quotes: str = "''") -> str:
    """`` (did you mean 'x'?)`` for the closest known name, or ``""``; ``quotes``: the
    opening and closing characters around it (``"[]"`` for a TOML table)."""
    import difflib

    by_fold: dict[str, str] = {}  # compared without case: 'GCOD' -> 'gcode'
    for k in known:
        by_fold.setdefault(str(k).casefold(), str(k))
    hint = difflib.get_close_matches(str(name).casefold(), list(by_fold), n=1, cutoff=0.6)
    return f" (did you mean {quotes[0]}{by_fold[hint[0]]}{quotes[1]}?)" if hint else ""


def interrupted(exc: BaseException | None) -> bool:
    """Whether ``exc`` is a KeyboardInterrupt or was raised because of one. Ctrl-C inside a
    compiled kernel can surface as ``SystemError: CPUDispatcher(...) returned a result with an
    exception set`` (numba), with the KeyboardInterrupt as its cause; code that wraps errors
    (a plugin's failure, cleanup that fails) keeps it in the chain too."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


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
