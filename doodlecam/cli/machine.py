"""``doodlecam machine --serial PORT home|unlock|reset|jog X Y|zero|status|settings|console``: control a GRBL machine.

Registered lazily in cli.LAZY_COMMANDS. The commands are GRBL 1.1's own
(``doodlecam.link.grbl.control``); every refusal prints GRBL's code and meaning.
"""

from __future__ import annotations

import contextlib
import sys

import click


@click.group()
@click.option("--serial", "port", required=True, metavar="PORT", help="GRBL's serial port (e.g. /dev/ttyUSB0).")
@click.option("--baud", type=int, default=115200, show_default=True, help="Serial baud rate.")
@click.option("--timeout", type=float, default=5.0, show_default=True, help="Seconds without an answer before giving up.")
@click.pass_context
def machine(ctx, port, baud, timeout):
    """Control a GRBL machine: home, unlock, jog, set work zero, status, settings, an interactive console."""
    ctx.obj = {"port": port, "baud": baud, "timeout": timeout}


@contextlib.contextmanager
def _controller(ctx, reset_if_silent: bool = False):
    from doodlecam.link.grbl.control import Controller
    from doodlecam.link.grbl.port import GrblLink

    o = ctx.obj
    with GrblLink(o["port"], o["baud"], timeout=o["timeout"], log=lambda m: click.echo(m, err=True)) as link:
        ctl = Controller(link)
        ctl.attach(reset_if_silent)
        with link.interrupts:
            yield ctl


def _show(ctl, st) -> None:
    from doodlecam.link.grbl.control import status_line

    click.echo(status_line(st, ctl.wco))


def _simple(name: str, doc: str, action: str) -> None:
    """A command that runs one Controller method and prints the status it returns."""

    @machine.command(name, help=doc)
    @click.pass_context
    def cmd(ctx):
        with _controller(ctx) as ctl:
            _show(ctl, getattr(ctl, action)())


_simple("home", "Run the homing cycle ($H; needs $22=1). Machine travel is then negative: -$130..0, -$131..0.", "home")
_simple("unlock", "Leave the alarm state without homing ($X); the position may be off.", "unlock")
_simple("status", "Print GRBL's state, machine and work position, feed and feed override.", "status")


@machine.command()
@click.pass_context
def reset(ctx):
    """Soft-reset GRBL (Ctrl-X): frees a controller that answers nothing after a limit alarm."""
    with _controller(ctx, reset_if_silent=True) as ctl:
        _show(ctl, ctl.reset())


@machine.command()
@click.argument("x", type=float)
@click.argument("y", type=float)
@click.option("--feed", type=float, default=3000.0, show_default=True, help="Jog feed (mm/min).")
@click.option("--to", "absolute", is_flag=True, help="Jog to work coordinates X Y instead of by X Y mm.")
@click.pass_context
def jog(ctx, x, y, feed, absolute):
    """Jog by X Y mm ($J=G91 ...), or to work X Y with --to; GRBL refuses targets beyond soft limits (error:15)."""
    with _controller(ctx) as ctl:
        _show(ctl, ctl.jog(x, y, feed, absolute=absolute))


@machine.command()
@click.option("--x", "x", type=float, default=0.0, show_default=True, help="Work X the current position gets.")
@click.option("--y", "y", type=float, default=0.0, show_default=True, help="Work Y the current position gets.")
@click.pass_context
def zero(ctx, x, y):
    """Make the current position work zero (G10 L20 P1 X0 Y0; GRBL stores it in G54)."""
    with _controller(ctx) as ctl:
        _show(ctl, ctl.zero(x, y))


@machine.command()
@click.pass_context
def settings(ctx):
    """Print GRBL's $ settings with their names and units ($$)."""
    with _controller(ctx) as ctl:
        for line in ctl.settings():
            click.echo(line)


@machine.command()
@click.option("--step", type=float, default=1.0, show_default=True, help="Arrow-key jog step (mm); [ and ] change it.")
@click.option("--feed", type=float, default=3000.0, show_default=True, help="Arrow-key jog feed (mm/min).")
@click.pass_context
def console(ctx, step, feed):
    """Interactive console: status line, arrow-key jog, $ commands with decoded replies, feed override keys."""
    from doodlecam.errors import InputError
    from doodlecam.link.grbl.control import run_console

    if not sys.stdin.isatty():
        raise InputError("the console needs a terminal; use 'doodlecam machine --serial PORT status|jog|home' in scripts")
    # keys first: what is typed while the port opens waits, unechoed, for the console
    with raw_keys() as getch, _controller(ctx, reset_if_silent=True) as ctl:
        run_console(ctl, getch, lambda s: click.echo("\r" + s + "\x1b[K"), step=step, feed=feed)


@contextlib.contextmanager
def raw_keys():
    """Single keys from the terminal without echo (cbreak mode), restored on exit; yields getch() -> str | None."""
    import os
    import select
    import termios
    import tty

    fd = sys.stdin.fileno()
    old = termios.tcgetattr(fd)

    def getch() -> str | None:
        if select.select([fd], [], [], 0)[0]:
            return os.read(fd, 1).decode("latin-1")
        return None

    try:
        tty.setcbreak(fd)
        yield getch
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)


# ---------------------------------------------------------------- machine --serial PORT ebb ...

@machine.group("ebb")
@click.pass_context
def machine_ebb(ctx):
    """Manual controls of an EiBotBoard (AxiDraw): pen up/down, motors off, jog, home, status."""


def _run(ctx, action: str, **kw) -> None:
    from doodlecam.link.ebb import manual

    o = ctx.obj or {}
    port = o.get("port")
    r = manual.run(None if port in (None, "auto") else port, manual.commands(action, **kw),
                   timeout=o.get("timeout", 5.0))
    click.echo(f"EiBotBoard firmware {r['firmware']} on {r['port']}: motors at {r['steps'][0]},{r['steps'][1]} steps")


@machine_ebb.command("pen")
@click.argument("state", type=click.Choice(["up", "down"]))
@click.pass_context
def ebb_pen(ctx, state):
    """Raise or lower the pen (SP)."""
    _run(ctx, f"pen_{state}")


@machine_ebb.command("motors-off")
@click.pass_context
def ebb_off(ctx):
    """Switch the motors off so the carriage moves by hand (EM,0,0); the position is forgotten."""
    _run(ctx, "motors_off")


@machine_ebb.command("jog")
@click.argument("x", type=float)
@click.argument("y", type=float)
@click.option("--speed", type=float, default=50.0, show_default=True, help="mm/s of the pen.")
@click.pass_context
def ebb_jog(ctx, x, y, speed):
    """Move the pen up by X Y mm on the page (y away from home), with XM (motor 1 = x + y, motor 2 = x - y)."""
    _run(ctx, "jog", dx=x, dy=y, speed=speed)


@machine_ebb.command("home")
@click.pass_context
def ebb_home(ctx):
    """Pen up, then back to where the motors were switched on (the start corner: HM)."""
    _run(ctx, "home")


@machine_ebb.command("status")
@click.pass_context
def ebb_status(ctx):
    """Firmware version and step position (V, QS)."""
    _run(ctx, "status")
