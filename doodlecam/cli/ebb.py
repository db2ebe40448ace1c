"""The EiBotBoard (AxiDraw) parts of ``send job.ebb --serial PORT`` and ``inspect job.ebb``, hooked
into send/inspect by a line each (``sim ebb`` lives with the other simulators in cli/send.py, the
``machine --serial PORT ebb ...`` controls in cli/machine.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

EBB_KEYS = {"p": "pause", " ": "pause", "r": "resume", "s": "stop"}


def send_ebb(job: Path, port: str, restart: bool, machine: str | None, timeout: float | None, transport_opt,
             no_progress: bool, bar_cls, pen_changes, raw_keys) -> None:
    """``doodlecam send JOB.ebb --serial PORT`` (PORT 'auto' finds the board by its USB id)."""
    from doodlecam import registry
    from doodlecam.cli.options import _pairs
    from doodlecam.errors import InputError
    from doodlecam.link.ebb.jobfile import read_ebb
    from doodlecam.link.ebb.sender import line_effects
    from doodlecam.link.session import Paused

    try:
        ebb = read_ebb(job.read_bytes(), str(job))  # a damaged file stops here, before the port is opened
    except OSError as e:
        raise InputError(f"{job}: cannot read ({e.strerror}); check the path") from None
    cls = registry.get("transport", "ebb")
    cli_opts = _pairs(transport_opt, "--transport-opt")
    if timeout is not None:
        cli_opts["timeout"] = timeout
    profile, profile_opts = None, {}
    if machine:
        from doodlecam.machine import load_machine

        profile = load_machine(machine)
        profile_opts = profile.plugin_options.get("transport.ebb", {})
    options = cls.resolve_options(profile_opts, cli_opts)
    _, dur = line_effects(ebb.lines)
    left = [sum(dur[k:]) for k in range(len(dur) + 1)]
    bar = bar_cls(len(ebb.lines), "EBB", "cmd", lambda k: left[min(max(k, 0), len(left) - 1)], not no_progress)
    transport = cls()
    try:
        with _keys(bar.log, raw_keys) as keys:
            extra = pen_changes(transport, profile, bar, keys.pop("getch", None))
            r = transport.send(job, port, options, restart=restart, progress=bar, log=bar.log, **keys, **extra)
    except Paused as e:
        bar.close()
        click.echo(f"doodlecam: {e}", err=True)
        sys.exit(130)
    finally:
        bar.close()
    how = f"resumed at command {r['start_at']}" if r["resumed"] else "from the start"
    click.echo(f"sent {job} to the EiBotBoard on {r['port']} (firmware {r['firmware']}): {r['commands']} commands, "
               f"{how}, {r['pen_changes']} pen changes, {r['elapsed_s']:.1f} s")


class _keys:
    """p/space pause (at the stroke's end, pen up), r resume, s stop: from a terminal only."""

    def __init__(self, log, raw_keys):
        self.log, self.raw_keys = log, raw_keys
        self.cm = None

    def __enter__(self) -> dict:
        if not sys.stdin.isatty():
            return {}
        self.log("keys: p pause (at the stroke's end, pen up) | r resume | s stop (resumable)")
        self.cm = self.raw_keys()
        getch = self.cm.__enter__()
        return {"controls": lambda: EBB_KEYS.get(getch() or ""), "getch": getch}

    def __exit__(self, *exc):
        if self.cm is not None:
            self.cm.__exit__(*exc)
        return False


# ---------------------------------------------------------------- inspect

def inspect_ebb(file: Path, limit: int) -> None:
    from doodlecam.errors import InputError
    from doodlecam.link.ebb.jobfile import read_ebb

    try:
        job = read_ebb(file.read_bytes(), str(file))
    except OSError as e:
        raise InputError(f"{file}: cannot read ({e.strerror}); check the path") from None
    for key, val in job.header.items():
        click.echo(f"{key:<20} {val}")
    pauses = job.pauses()
    if pauses:
        click.echo(f"{'pen changes':<20} {len(pauses)} (" + ", ".join(f"pen {p} before command {i + 1}" for i, p in pauses) + ")")
    shown = job.lines if limit == 0 else job.lines[:limit]
    for i, s in enumerate(shown, 1):
        click.echo(f"{i:>8}  {s}")
    if len(shown) < len(job.lines):
        click.echo(f"... {len(job.lines) - len(shown)} more (--limit 0 shows all)")
