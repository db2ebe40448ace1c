"""Shell completion of the names options take: machine profiles, tracers, posts, solvers.

click asks these (``shell_complete=``) when the shell's completion script runs
``_DOODLECAM_COMPLETE=bash_complete doodlecam ...`` (README: enabling it). A
completer never fails: a broken plugin folder just completes nothing.
"""

from __future__ import annotations

from click.shell_completion import CompletionItem


def _starting(names, incomplete: str) -> list[CompletionItem]:
    fold = incomplete.casefold()  # names are matched without case (--post GCODE)
    return [CompletionItem(n) for n in sorted(set(names)) if n.casefold().startswith(fold)]


def machines(ctx, param, incomplete: str) -> list[CompletionItem]:
    """Profile names on the search path; the shell's own file completion for what looks like a path."""
    if incomplete.startswith((".", "/", "~")) or "/" in incomplete:
        return [CompletionItem(incomplete, type="file")]
    from doodlecam.machine import find_machines

    try:
        return _starting(find_machines(), incomplete)
    except OSError:
        return []


def _plugins(kind: str | None, ctx, incomplete: str) -> list[CompletionItem]:
    from doodlecam.registry import discover

    dirs: tuple = ()
    while ctx is not None:  # --plugin-dir given before, on this command or its group (plugins show)
        dirs += tuple(ctx.params.get("plugin_dirs") or ())
        ctx = ctx.parent
    try:
        infos = discover(dirs)
    except Exception:  # a missing --plugin-dir, a broken entry point: the command itself will say
        return []
    return _starting((i.name for i in infos if i.kind != "?" and kind in (None, i.kind)), incomplete)


def tracers(ctx, param, incomplete: str) -> list[CompletionItem]:
    return _plugins("tracer", ctx, incomplete)


def posts(ctx, param, incomplete: str) -> list[CompletionItem]:
    return _plugins("postprocessor", ctx, incomplete)


def plugins(ctx, param, incomplete: str) -> list[CompletionItem]:
    """Any plugin's name (``doodlecam plugins show NAME``), of the --kind given if any."""
    return _plugins(ctx.params.get("kind"), ctx, incomplete)


def solvers(ctx, param, incomplete: str) -> list[CompletionItem]:
    from doodlecam.options import SOLVERS

    return _starting(SOLVERS, incomplete)
