"""The EiBotBoard (AxiDraw) parts of the CLI: ``send job.ebb --serial PORT``, ``sim ebb``,
``machine --serial PORT ebb ...`` and ``inspect job.ebb``. Hooked into send/machine/inspect
by a line each, so those modules stay about their own links.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

EBB_KEYS = {"p": "pause", " ": "pause", "r": "resume", "s": "stop"}


def send_ebb(job: Path, port: str, restart: bool, machine: str | None, timeout: float | None, transport_opt,
             no_progress: bool, bar_cls, pen_changes) -> None:
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
        with _keys(bar.log) as keys:
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

    def __init__(self, log):
        self.log = log
        self.cm = None

    def __enter__(self) -> dict:
        if not sys.stdin.isatty():
            return {}
        from doodlecam.cli.machine import raw_keys

        self.log("keys: p pause (at the stroke's end, pen up) | r resume | s stop (resumable)")
        self.cm = raw_keys()
        getch = self.cm.__enter__()
        return {"controls": lambda: EBB_KEYS.get(getch() or ""), "getch": getch}

    def __exit__(self, *exc):
        if self.cm is not None:
            self.cm.__exit__(*exc)
        return False


@click.command("ebb")
@click.option("--speed", type=float, default=1.0, show_default=True, help="Motion runs this many times faster than real time.")
@click.option("--fifo", type=int, default=1, show_default=True, help="Motion commands queued behind the executing one.")
@click.option("--firmware", default="3.0.2", show_default=True, help="Version the board reports to V.")
@click.option("--vanish-at", type=int, metavar="N", help="Close the port after the N-th received command.")
@click.option("--link", "link_path", type=click.Path(path_type=Path), help="Also make a symlink with this name to the port.")
def sim_ebb(speed, fifo, firmware, vanish_at, link_path):
    """Emulate an EiBotBoard (AxiDraw) on a pseudo-terminal; prints the port to use."""
    from doodlecam.cli.send import serve_emulator
    from doodlecam.link.ebb.emulator import EbbConfig, EbbEmulator

    emu = EbbEmulator(EbbConfig(version=firmware, speed=speed, fifo=fifo, vanish_at=vanish_at),
                      log=lambda m: click.echo(f"[ebb] {m}", err=True))
    serve_emulator(emu, link_path, "EiBotBoard emulator", "", lambda: (
        f"EiBotBoard emulator stopped: {len(emu.received)} commands received, {len(emu.executed)} executed, "
        f"{len(emu.errors)} refused, motors at {tuple(emu.pos)} steps"))


# ---------------------------------------------------------------- machine --serial PORT ebb ...

@click.group("ebb")
@click.pass_context
def machine_ebb(ctx):
    """Manual controls of an EiBotBoard (AxiDraw): pen up/down, motors off, jog, home, status."""


def _board(ctx):
    from doodlecam.link.ebb.jobfile import EbbJob
    from doodlecam.link.ebb.sender import EbbSender, find_port

    o = ctx.obj or {}
    port = o.get("port")
    s = EbbSender(find_port() if port in (None, "auto") else port, EbbJob({}, ()), "manual",
                  timeout=o.get("timeout", 5.0))
    s._open()
    s.handshake()
    return s


def _run(ctx, commands: list[str], wait: bool = True) -> None:
    s = _board(ctx)
    try:
        for c in commands:
            s._ask(c, s.timeout)
        if wait:
            s.wait_idle(600)
        pos = s._ask("QS", s.timeout).split("\n")[0]
        click.echo(f"EiBotBoard firmware {s.version} on {s.port_name}: motors at {pos} steps")
    finally:
        s.ser.close()


@machine_ebb.command("pen")
@click.argument("state", type=click.Choice(["up", "down"]))
@click.pass_context
def ebb_pen(ctx, state):
    """Raise or lower the pen (SP)."""
    _run(ctx, [f"SP,{1 if state == 'up' else 0},200"])


@machine_ebb.command("motors-off")
@click.pass_context
def ebb_off(ctx):
    """Switch the motors off so the carriage moves by hand (EM,0,0); the position is forgotten."""
    _run(ctx, ["EM,0,0"])


@machine_ebb.command("jog")
@click.argument("x", type=float)
@click.argument("y", type=float)
@click.option("--speed", type=float, default=50.0, show_default=True, help="mm/s.")
@click.pass_context
def ebb_jog(ctx, x, y, speed):
    """Move the pen up by X Y mm on the page (y away from home), with XM (motor 1 = x + y, motor 2 = x - y)."""
    k = 80.0
    a, b = round(x * k), round(y * k)
    ms = max(1, round(1000 * max(abs(x), abs(y), 1e-9) / speed))
    _run(ctx, ["SP,1,200", f"XM,{ms},{a},{b}"])


@machine_ebb.command("home")
@click.pass_context
def ebb_home(ctx):
    """Pen up, then back to where the motors were switched on (the start corner: HM)."""
    _run(ctx, ["SP,1,200", "HM,4000"])


@machine_ebb.command("status")
@click.pass_context
def ebb_status(ctx):
    """Firmware version and step position (V, QS)."""
    _run(ctx, [], wait=False)


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
