"""Where a long command is: one status line on a terminal, stage timings with ``-v``.

``doodlecam convert`` on a big picture works for half a minute; on a terminal a line
on stderr, rewritten in place, says which stage runs and how many strokes it has done
("planning 1200/5400 strokes"), and is erased when the command ends (so the summary,
an error or "interrupted" stand alone). ``doodlecam -v`` prints each stage's time as
it finishes, on any stream.
"""

from __future__ import annotations

import os
import shutil
import sys
import time

import click

from doodlecam.memory import memory_mb

PERIOD = 0.1  # s between redraws of the status line: updates per stroke would cost more than the work

WORDS = {"tracing": "tracing {name}", "ordering": "ordering {total} strokes", "fitting": "fitting B-splines",
         "planning": "planning and sampling time-optimal motion", "writing": "writing"}


def verbosity() -> int:
    """The count of the global -v/--verbose (0 outside a command)."""
    ctx = click.get_current_context(silent=True)
    return ctx.meta.get("doodlecam.verbose", 0) if ctx is not None else 0


def status_line_wanted(stream=None) -> bool:
    """A status line only where someone watches it: a terminal that can erase a line."""
    stream = stream or sys.stderr
    return stream.isatty() and os.environ.get("TERM", "") != "dumb"


class Stages:
    """A pipeline ``progress`` callback (stage, done, total) that draws the status line and,
    verbosely, a line with the time of each stage when the next begins. Use as a context
    manager: leaving it erases the status line and reports the last stage."""

    def __init__(self, name: str, verbose: int = 0, line: bool | None = None, stream=None):
        self.name, self.verbose = name, verbose
        self.stream = stream or sys.stderr
        self.line = status_line_wanted(self.stream) if line is None else line
        self.stage: str | None = None
        self.t_stage = self.t_start = time.perf_counter()
        self.drawn = 0.0  # when the status line was last drawn
        self.shown = False

    def __call__(self, stage: str, done: int = 0, total: int = 0) -> None:
        now = time.perf_counter()
        if stage != self.stage:
            self._finish(now)
            self.stage, self.t_stage, self.drawn = stage, now, 0.0
        if self.line and now - self.drawn >= PERIOD:
            text = WORDS.get(stage, stage).format(name=self.name, total=total)
            if total and stage in ("fitting", "planning", "writing"):
                text += f"  {done}/{total}" + (" strokes" if stage != "writing" else " files")
            width = shutil.get_terminal_size((80, 24)).columns - 1
            self.drawn, self.shown = now, True  # before writing: Ctrl-C may land right after it
            self.stream.write("\r" + f"doodlecam: {text} ..."[:width] + "\x1b[K")
            self.stream.flush()

    def _erase(self) -> None:
        if self.shown:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self.shown = False

    def _finish(self, now: float) -> None:
        if self.stage is not None and self.verbose:
            self._erase()
            self.stream.write(f"doodlecam: {self.stage:<9} {now - self.t_stage:7.2f} s\n")
            self.stream.flush()

    def __enter__(self) -> "Stages":
        return self

    def __exit__(self, kind, value, tb) -> None:
        now = time.perf_counter()
        if kind is None:  # a stage cut short by an error or Ctrl-C has no time worth printing
            self._finish(now)
            if self.verbose:
                peak = memory_mb()[1]
                self.stream.write(f"doodlecam: {'total':<9} {now - self.t_start:7.2f} s"
                                  + (f", peak memory {peak:.0f} MB" if peak else "") + "\n")
        self._erase()
        self.stream.flush()
