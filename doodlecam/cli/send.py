"""``doodlecam send`` (to a PLC over UDP or GRBL over serial) and ``doodlecam sim`` (their simulators).

Registered lazily in cli.LAZY_COMMANDS, so ``doodlecam --help`` does not
import any of this.
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path

import click

from doodlecam.cli import complete

from doodlecam.errors import DoodleError

GCODE_EXTENSIONS = (".gcode", ".nc", ".gc", ".ngc", ".g")


def _stop_on_sigterm() -> None:
    """`kill PID` ends a simulator like Ctrl-C (background jobs of a script ignore SIGINT)."""
    import signal

    def handler(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)


def _fmt_s(s: float) -> str:
    s = max(0.0, s)
    return f"{int(s // 60)}:{int(s % 60):02d}" if s >= 60 else f"{s:.1f} s"


class _Progress:
    """A tqdm bar (stderr) of commands executed with the planned time left; log lines above it."""

    def __init__(self, total: int, desc: str, unit: str, left, enabled: bool):
        from tqdm import tqdm

        self.left = left
        self.bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True,
                        disable=None if enabled else True, bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} {unit}{postfix}")
        self.last = 0.0

    def __call__(self, done: int, total: int, status=None) -> None:
        now = time.monotonic()
        if now - self.last < 0.1 and done < total:
            return
        self.last = now
        extra = ""
        state = getattr(status, "state", None)
        if isinstance(state, str):  # GRBL status: state and position
            pos = status.mpos or status.wpos
            extra = f", {state}" + (f" X{pos[0]:.1f} Y{pos[1]:.1f}" if pos else "")
        self.bar.n = min(done, total)
        self.bar.set_postfix_str(f"left {_fmt_s(self.left(done))}{extra}", refresh=False)
        self.bar.refresh()

    def log(self, msg: str) -> None:
        from tqdm import tqdm

        if self.bar.disable:
            click.echo(f"doodlecam: {msg}", err=True)
        else:
            tqdm.write(f"doodlecam: {msg}", file=sys.stderr)

    def close(self) -> None:
        self.bar.close()


@click.command()
@click.argument("job", type=click.Path(path_type=Path))
@click.option("--udp", "udp", metavar="HOST:PORT", help="Send a .plc job to the DoodleBot PLC at this address.")
@click.option("--serial", "serial_port", metavar="PORT", help="Stream a .gcode job to GRBL on this serial port.")
@click.option("--baud", type=int, help="Serial baud rate (default 115200).")
@click.option("--check", is_flag=True, help="GRBL: dry run in check mode ($C): parse every line, move nothing.")
@click.option("--restart", is_flag=True, help="Start from the first command even if an earlier run was interrupted.")
@click.option("--cancel", is_flag=True, help="PLC: cancel the job it is running or holding, and forget the resume point.")
@click.option("--again", is_flag=True, help="PLC: draw a job the PLC has already finished once more.")
@click.option("-m", "--machine", shell_complete=complete.machines, help="Machine profile whose [transport.udp] / [transport.serial] table sets options "
              "(e.g. the PLC's pre-shared key).")
@click.option("--from-line", type=int, metavar="N", help="GRBL: start at line N of the file (after a stop you checked).")
@click.option("--timeout", type=float, help="Seconds without an answer before giving up (default 5).")
@click.option("--transport-opt", multiple=True, metavar="KEY=VALUE", help="Transport plugin option (repeatable).")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@click.option("--key-file", type=click.Path(path_type=Path), help="PLC: read the pre-shared key from this file "
              "(default: the machine's key file, created on first use; see 'doodlecam sim plc').")
@click.option("--no-auth", is_flag=True, help="PLC: send without authentication (only to a PLC started with --no-auth "
              "on a trusted bench).")
def send(job, udp, serial_port, baud, check, restart, cancel, again, machine, from_line, timeout, transport_opt,
         no_progress, key_file, no_auth):
    """Send JOB to a machine: a .plc file to the PLC (--udp), G-code to GRBL (--serial).

    \b
    Ctrl-C stops cleanly (at the end of the stroke / after GRBL's queued
    lines, pen up); running the same command again resumes after the last
    executed command. Try it without hardware:
      doodlecam sim plc --port 5005 &   doodlecam send out/camera.plc --udp 127.0.0.1:5005
      doodlecam sim grbl                doodlecam send out/camera.gcode --serial /dev/pts/N
      doodlecam sim ebb                 doodlecam send out/camera.ebb --serial /dev/pts/N   (AxiDraw; PORT auto finds it)
    """
    from doodlecam import registry
    from doodlecam.cli.options import _pairs

    if bool(udp) == bool(serial_port):
        raise click.UsageError("give exactly one of --udp HOST:PORT or --serial PORT")
    if serial_port and job.suffix.lower() == ".ebb":  # an EiBotBoard (AxiDraw) job: its own link
        if check or from_line or baud or cancel or again:
            raise click.UsageError("--check, --from-line, --baud, --cancel and --again are not for .ebb jobs")
        from doodlecam.cli.ebb import send_ebb

        from doodlecam.cli.machine import raw_keys

        return send_ebb(job, serial_port, restart, machine, timeout, transport_opt, no_progress, _Progress,
                        _pen_changes, raw_keys)
    kind = "udp" if udp else "serial"
    if kind == "udp" and (check or from_line or baud):
        raise click.UsageError("--check, --from-line and --baud are for --serial (GRBL)")
    if kind == "serial" and (cancel or again):
        raise click.UsageError("--cancel and --again are for --udp (a GRBL job stops with Ctrl-C)")
    if not job.is_file():
        raise click.BadParameter(f"{job} does not exist", param_hint="JOB")
    ext = job.suffix.lower()
    if kind == "udp" and ext != ".plc":
        raise click.BadParameter(f"{job.name} is not a .plc job; the PLC takes the packet file from "
                                 "'doodlecam convert --post plc'", param_hint="JOB")
    if kind == "serial" and ext not in GCODE_EXTENSIONS:
        raise click.BadParameter(f"{job.name} is not a G-code file ({', '.join(GCODE_EXTENSIONS)}); "
                                 "write one with 'doodlecam convert --post gcode'", param_hint="JOB")
    cls = registry.get("transport", kind)
    cli_opts = _pairs(transport_opt, "--transport-opt")
    if timeout is not None:
        cli_opts["timeout"] = timeout
    if baud is not None:
        cli_opts["baud"] = baud
    profile_opts = {}
    profile = None
    if machine:
        from doodlecam.machine import load_machine

        profile = load_machine(machine)
        profile_opts = profile.plugin_options.get(f"transport.{kind}", {})
    options = cls.resolve_options(profile_opts, cli_opts)
    transport = cls()
    if kind == "udp":  # authenticated by default: the machine's key (docs/protocol.md 1.9)
        secret, said = plc_key(profile.name if profile is not None else "doodlebot", None, options.get("key") or None,
                               key_file, no_auth)
        options = {**options, "key": secret.decode() if secret else ""}
        if no_auth:
            click.echo(said, err=True)

    if kind == "udp":
        total, left = _plc_plan(job)
        bar = _Progress(total, "PLC", "cmd", left, not (no_progress or cancel))
    else:
        total, left = _gcode_plan(job)
        bar = _Progress(total, "GRBL check" if check else "GRBL", "line", left, not no_progress)
    from doodlecam.link.session import Paused

    try:
        if kind == "udp":
            extra = _pen_changes(transport, profile, bar, None)
            result = transport.send(job, udp, options, restart=restart, cancel=cancel, again=again, progress=bar,
                                    log=bar.log, **extra)
        else:
            with _grbl_keys(transport, check, bar.log) as keys:
                extra = _pen_changes(transport, profile, bar, keys.pop("getch", None))
                result = transport.send(job, serial_port, options, restart=restart, check=check, from_line=from_line,
                                        progress=bar, log=bar.log, **keys, **extra)
    except Paused as e:
        bar.close()
        click.echo(f"doodlecam: {e}", err=True)
        sys.exit(130)  # cli.main returns 0 for click's Exit in non-standalone mode; SystemExit keeps 130
    finally:
        bar.close()
    _report(job, kind, result, check, cancel)


GRBL_KEYS = {"p": "pause", " ": "pause", "r": "resume", "~": "resume", "!": "hold", "+": "feed+", "-": "feed-",
             "=": "feed=", "s": "stop"}


@contextlib.contextmanager
def _grbl_keys(transport, check: bool, log):
    """Keys that control a GRBL send from a terminal (pause/resume, hold, feed override, stop); {} otherwise."""
    import inspect

    if check or not sys.stdin.isatty() or "controls" not in inspect.signature(transport.send).parameters:
        yield {}
        return
    from doodlecam.cli.machine import raw_keys

    log("keys: p pause (pen up) | r resume | ! hold | ~ cycle start | + - = feed override | s stop")
    with raw_keys() as getch:
        yield {"controls": lambda: GRBL_KEYS.get(getch() or ""), "getch": getch}


def _pen_changes(transport, profile, bar, getch) -> dict:
    """``pen_change=`` for a transport that pauses for pen changes: tell the operator which pen
    (named from the machine profile's [[pen]] when -m is given) and wait for Enter."""
    import inspect

    if "pen_change" not in inspect.signature(transport.send).parameters:
        return {}

    def ask(pen, what: str) -> None:
        from doodlecam.link.session import Paused

        if profile is not None:
            what = profile.describe_pen(pen, what)
        bar.log(f"change to {what}, then press Enter (Ctrl-C stops here, pen up)")
        if getch is not None:  # the terminal is in raw mode for the control keys
            while (getch() or "") not in ("\r", "\n"):
                time.sleep(0.02)
            return
        if not sys.stdin.readline():
            raise Paused(f"nobody answered the pen change (standard input is closed): change to {what}")

    return {"pen_change": ask}


def _plc_plan(job: Path):
    from doodlecam.errors import InputError
    from doodlecam.link.plc.packetfile import read_plc_array
    from doodlecam.link.plc.sender import planned_time_left

    try:
        header, arr = read_plc_array(job.read_bytes(), str(job))
    except OSError as e:
        raise InputError(f"{job}: cannot read ({e.strerror}); check the path") from None
    left = planned_time_left(arr, header)
    return len(arr), lambda k: float(left[min(max(k, 0), len(left) - 1)])


def _gcode_plan(job: Path):
    import numpy as np

    from doodlecam.errors import InputError
    from doodlecam.link.grbl.protocol import prepare
    from doodlecam.link.grbl.timing import time_left

    try:
        text = job.read_text("ascii")
        lines = prepare(text, str(job))
    except UnicodeDecodeError:
        raise InputError(f"{job}: not an ASCII G-code file; GRBL reads ASCII only") from None
    except OSError as e:
        raise InputError(f"{job}: cannot read ({e.strerror}); check the path") from None
    # GRBL's own time (the header's planner-model estimate), not length / feed
    left = time_left(text, lines) if lines else np.zeros(1)
    return len(lines), lambda k: float(left[min(max(k, 0), len(left) - 1)])


def _report(job: Path, kind: str, r: dict, check: bool, cancel: bool) -> None:
    if kind == "udp" and cancel:
        jid = r["cancelled_job"]
        click.echo(f"cancelled job {jid} on the PLC at {r['plc']}" if jid else f"the PLC at {r['plc']} had no job to cancel")
        return
    if kind == "udp":
        if r["already_done"]:
            click.echo(f"{job}: the PLC at {r['plc']} had already finished this job ({r['commands']} commands)")
            return
        how = f"resumed at command {r['start_at']}" if r["resumed"] else "all"
        click.echo(f"{job} -> PLC {r['plc']}: {r['commands']} commands executed ({how}), job {r['job_id']}, "
                   f"{r['elapsed_s']:.1f} s" + (f", {r['underruns']} underrun(s) recovered" if r["underruns"] else "")
                   + _pens_said(r))
        return
    if check:
        if r["errors"]:
            for lineno, src, code, text in r["errors"]:
                click.echo(f"{job}:{lineno}: error:{code} {text}: {src}", err=True)
            raise CheckFailed(f"GRBL check mode found {len(r['errors'])} error(s) in {job}; fix them before a real run")
        click.echo(f"{job}: GRBL check mode passed, {r['lines']} lines, no errors")
        return
    how = f"resumed at line {r['start_line']}" if r["resumed"] else "all"
    click.echo(f"{job} -> GRBL: {r['lines']} lines done ({how}), {r['elapsed_s']:.1f} s, "
               f"at most {r['max_outstanding_bytes']} bytes outstanding" + _pens_said(r))


def _pens_said(r: dict) -> str:
    n = r.get("pen_changes", 0)
    return f", {n} pen change{'s' if n != 1 else ''}" if n else ""


class CheckFailed(DoodleError):
    """GRBL check mode reported errors."""


# ---------------------------------------------------------------- simulators

@click.group()
def sim():
    """Machine simulators, to try 'send' without hardware."""


def plc_key(machine: str, profile, key: str | None, key_file: Path | None, no_auth: bool) -> tuple[bytes | None, str]:
    """The PLC link's key for ``sim plc`` and ``send --udp`` (docs/protocol.md 1.9), and a line saying where it is
    from: --key, --key-file, the profile's [transport.udp] key, else the machine's key file (created on first use)."""
    from doodlecam.errors import InputError
    from doodlecam.link.plc.keys import checked, machine_key, profile_key, read_key

    given = [n for n, v in (("--key", key), ("--key-file", key_file)) if v]
    if no_auth and given:
        raise InputError(f"give {given[0]} or --no-auth, not both")
    if len(given) > 1:
        raise InputError("give --key or --key-file, not both")
    if no_auth:
        return None, ("WARNING: no authentication (--no-auth): anyone who can reach this port can send the machine "
                      "commands; use it on a trusted bench only")
    if key_file is not None:
        return read_key(key_file), f"HMAC key from {key_file}"
    if key:
        return checked(key, "--key"), "HMAC key from --key (it shows in the process list: prefer --key-file)"
    if profile is not None:
        return profile_key(profile)
    secret, path, new = machine_key(machine)
    return secret, f"HMAC key {'created in' if new else 'from'} {path} (pair a real PLC by giving it this file's text)"


@sim.command("plc")
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on.")
@click.option("--port", type=int, default=5005, show_default=True, help="UDP port to listen on (0 = any).")
@click.option("-m", "--machine", default="doodlebot", show_default=True, shell_complete=complete.machines, help="Profile for boundaries and pen delays.")
@click.option("--buffer-size", type=int, default=256, show_default=True, help="BUFFER_SIZE: commands the PLC buffers.")
@click.option("--realtime", is_flag=True, help="Execute in real time (default: simulated time, as fast as possible).")
@click.option("--speed", type=float, help="Execute this many times faster than real time.")
@click.option("--loss", type=float, default=0.0, help="Probability a datagram is lost (each direction).")
@click.option("--dup", type=float, default=0.0, help="Probability a datagram is duplicated.")
@click.option("--reorder", type=float, default=0.0, help="Probability a datagram is held back so later ones overtake it.")
@click.option("--corrupt", type=float, default=0.0, help="Probability a datagram has bytes flipped.")
@click.option("--delay", type=float, default=0.0, help="Seconds of latency added to every datagram.")
@click.option("--jitter", type=float, default=0.0, help="Seconds of random extra latency.")
@click.option("--seed", type=int, help="Random seed for the impairments.")
@click.option("--rto", type=float, default=0.05, show_default=True, help="Seconds before missing commands are re-requested.")
@click.option("--no-boundaries", is_flag=True, help="Do not check commands against the work area (limit switches still trip).")
@click.option("--record", type=click.Path(path_type=Path), help="Write the executed trajectory to this CSV at exit.")
@click.option("--state-file", type=click.Path(path_type=Path),
              help="The PLC's non-volatile memory (ended jobs, current job); kept across restarts. Default: one per "
                   "port in the user's state folder, so a restarted simulator never runs a finished job again.")
@click.option("--no-state", is_flag=True, help="Forget everything at exit (a fresh PLC each start; finished jobs can "
              "run again after a restart).")
@click.option("--key", help="Pre-shared key (16+ characters): accept only HMAC-authenticated datagrams. Default: "
              "the profile's [transport.udp] key, else the machine's key file (created on first use).")
@click.option("--key-file", type=click.Path(path_type=Path), help="Read the pre-shared key from this file.")
@click.option("--no-auth", is_flag=True, help="Accept datagrams without authentication (a trusted bench only: anyone "
              "who can reach the port can then move the machine).")
@click.option("--quiet", is_flag=True, help="Do not log state changes.")
def sim_plc(host, port, machine, buffer_size, realtime, speed, loss, dup, reorder, corrupt, delay, jitter, seed, rto,
            no_boundaries, record, state_file, no_state, key, key_file, no_auth, quiet):
    """Simulate the DoodleBot PLC on UDP (Governor, command buffer, limit switches)."""
    import math

    from doodlecam.link.plc.network import Impairments
    from doodlecam.link.plc.simulator import PlcConfig, PlcSimulator
    from doodlecam.machine import load_machine

    if realtime and speed:
        raise click.UsageError("give --realtime or --speed, not both")
    imp = Impairments(loss=loss, dup=dup, reorder=reorder, corrupt=corrupt, delay=delay, jitter=jitter, seed=seed)
    try:
        imp.check()
    except ValueError as e:
        raise click.BadParameter(str(e)) from None
    profile = load_machine(machine)
    if state_file is not None and no_state:
        raise click.UsageError("give --state-file or --no-state, not both")
    if state_file is None and not no_state and port != 0:
        # a real PLC's command counter and ended-job table are retentive: so is the simulator's, by default
        from platformdirs import user_state_dir

        state_file = Path(user_state_dir("doodlecam", appauthor=False)) / "plc-simulator" / f"{host}-{port}.json"
        state_file.parent.mkdir(parents=True, exist_ok=True)
    secret, said = plc_key(profile.name, profile, key, key_file, no_auth)
    cfg = PlcConfig.from_machine(profile, host=host, port=port, buffer_size=buffer_size, rto=rto,
                                 speed=1.0 if realtime else (speed or math.inf), soft_limits=not no_boundaries,
                                 impair=imp, key=secret, state_file=state_file)
    t0 = time.monotonic()

    def log(msg: str) -> None:
        if not quiet:
            click.echo(f"[plc {time.monotonic() - t0:7.2f}] {msg}", err=True)

    try:
        plc = PlcSimulator(cfg, log=log)
    except OSError as e:
        raise DoodleError(f"cannot listen on {host}:{port} ({e.strerror}); pick another --port") from None
    mode = "real time" if realtime else (f"{speed:g}x real time" if speed else "simulated time")
    click.echo(f"PLC simulator on {plc.address[0]}:{plc.address[1]} ({mode}, buffer {buffer_size}, machine "
               f"{machine}{', HMAC key' if cfg.key else ''}); Ctrl-C stops", err=False)
    click.echo(f"  {said}", err=True)
    click.echo(f"  non-volatile memory: {state_file}" if state_file else
               "  no non-volatile memory (--no-state or --port 0): a restart forgets finished jobs", err=True)
    sys.stdout.flush()
    _stop_on_sigterm()
    try:
        plc.run()
    except KeyboardInterrupt:
        pass
    finally:
        plc.sock.close()
        plc.nv.close()
        if record:
            plc.write_trace_csv(record)
        net = plc._inbound.stats + plc._outbound.stats
        refused = {k: plc.stats[k] for k in ("dropped_foreign", "dropped_replayed", "dropped_unauthenticated",
                                             "dropped_old_version", "stale_challenges", "refused_busy",
                                             "handler_errors") if plc.stats[k]}
        click.echo(f"PLC simulator stopped: {len(plc.executed_log)} commands executed, "
                   f"{plc.stats['dropped_invalid']} corrupt datagrams dropped, impairments {dict(net) or 'none'}"
                   + (f", refused {refused}" if refused else ""), err=True)


@sim.command("grbl")
@click.option("--speed", type=float, default=1.0, show_default=True, help="Motion runs this many times faster than real time.")
@click.option("--error-at", multiple=True, metavar="N:CODE", help="Answer the N-th received line with error:CODE.")
@click.option("--alarm-at", multiple=True, metavar="N:CODE", help="Raise ALARM:CODE at the N-th received line.")
@click.option("--vanish-at", type=int, metavar="N", help="Close the port after the N-th received line.")
@click.option("--soft-limits", is_flag=True, help="Alarm on targets outside the travel ($20=1, with homing $22=1 as GRBL "
              "requires: travel is -W..0, -H..0 in machine coordinates).")
@click.option("--travel", default="400x300", show_default=True, metavar="WxH", help="Machine travel in mm ($130, $131).")
@click.option("--link", "link_path", type=click.Path(path_type=Path), help="Also make a symlink with this name to the port.")
def sim_grbl(speed, error_at, alarm_at, vanish_at, soft_limits, travel, link_path):
    """Emulate a GRBL 1.1 controller on a pseudo-terminal; prints the port to use."""
    from doodlecam.link.grbl.emulator import GrblConfig, GrblEmulator

    def pairs(values, what):
        out = {}
        for v in values:
            n, sep, code = v.partition(":")
            if not (sep and n.isdigit() and code.isdigit()):
                raise click.BadParameter(f"'{v}' is not N:CODE", param_hint=what)
            out[int(n)] = int(code)
        return out

    try:
        w, h = (float(v) for v in travel.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"'{travel}' is not WxH in mm, e.g. 400x300", param_hint="--travel") from None
    cfg = GrblConfig(speed=speed, error_at=pairs(error_at, "--error-at"), alarm_at=pairs(alarm_at, "--alarm-at"),
                     vanish_at=vanish_at, travel=(w, h), soft_limits=soft_limits)
    emu = GrblEmulator(cfg, log=lambda m: click.echo(f"[grbl] {m}", err=True))
    extra = ""
    if soft_limits:  # as GRBL 1.1: homing on, locked until $H, travel in negative machine space
        extra = (f"soft limits: machine travel X -{w:g}..0, Y -{h:g}..0; it starts in alarm: 'doodlecam machine "
                 f"--serial {link_path or emu.port} home', then jog to the drawing's corner and 'zero'")
    serve_emulator(emu, link_path, "GRBL emulator", extra, lambda: (
        f"GRBL emulator stopped: {len(emu.received)} lines received, {emu.overruns} bytes dropped "
        f"(receive buffer overruns), most bytes buffered {emu.max_rx}"))


def serve_emulator(emu, link_path, name: str, extra: str, summary) -> None:
    """Run an emulator on its pseudo-terminal (and a symlink ``link_path`` to it) until Ctrl-C,
    `kill` or the emulator vanishing; then print ``summary()``."""
    import os

    if link_path:
        tmp = link_path.with_name(link_path.name + ".tmp")
        if tmp.is_symlink():
            tmp.unlink()
        os.symlink(emu.port, tmp)
        os.replace(tmp, link_path)
    emu.start()
    click.echo(f"{name} on {emu.port}" + (f" (also {link_path})" if link_path else "") + "; Ctrl-C stops")
    if extra:
        click.echo(extra)
    sys.stdout.flush()
    _stop_on_sigterm()
    try:
        while not emu.vanished:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
        if link_path and link_path.is_symlink():
            link_path.unlink()
        click.echo(summary(), err=True)


@sim.command("ebb")
@click.option("--speed", type=float, default=1.0, show_default=True, help="Motion runs this many times faster than real time.")
@click.option("--fifo", type=int, default=1, show_default=True, help="Motion commands queued behind the executing one.")
@click.option("--firmware", default="3.0.2", show_default=True, help="Version the board reports to V.")
@click.option("--vanish-at", type=int, metavar="N", help="Close the port after the N-th received command.")
@click.option("--link", "link_path", type=click.Path(path_type=Path), help="Also make a symlink with this name to the port.")
def sim_ebb(speed, fifo, firmware, vanish_at, link_path):
    """Emulate an EiBotBoard (AxiDraw) on a pseudo-terminal; prints the port to use."""
    from doodlecam.link.ebb.emulator import EbbConfig, EbbEmulator

    emu = EbbEmulator(EbbConfig(version=firmware, speed=speed, fifo=fifo, vanish_at=vanish_at),
                      log=lambda m: click.echo(f"[ebb] {m}", err=True))
    serve_emulator(emu, link_path, "EiBotBoard emulator", "", lambda: (
        f"EiBotBoard emulator stopped: {len(emu.received)} commands received, {len(emu.executed)} executed, "
        f"{len(emu.errors)} refused, motors at {tuple(emu.pos)} steps"))
