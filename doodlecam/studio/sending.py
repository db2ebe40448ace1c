"""Sending the studio's job to a PLC over UDP, to GRBL or to an EiBotBoard over serial, as ``doodlecam send`` does.

PLC: the same ``UdpSender``; GRBL: the same serial transport (``send_gcode``:
character counting, resume record, pause/hold/stop controls), against a real
port or the built-in GRBL emulator on a pseudo-terminal (``studio.grbl``);
EiBotBoard (AxiDraw): the ``ebb`` transport (one command in flight, pause/stop
at a stroke's end with the pen up), against a real port or the built-in EBB
emulator (``studio.ebb``).

The send runs in its own thread, owned by the server, not by a page: closing
the tab does not touch it, so the job runs to its end (the PLC never sees a
half-sent job). Stop asks the sender as Ctrl-C does: the PLC stops at the end
of the current stroke with the pen up and holds the job; sending the same job
again resumes it after the last executed command (the PLC's count is the
truth, as for ``doodlecam send``). The built-in simulator lives as long as the
server, so a job it holds can be resumed too.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import re
import tempfile
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from doodlecam.errors import DoodleError, InputError
from doodlecam.link.grbl.timing import time_left
from doodlecam.studio.ebb import EbbTargets, is_ebb, work_positions
from doodlecam.studio.grbl import GrblTargets, work_position


# States in which a send is under way (the event stream follows them); "waiting" is for a job that
# waits for the operator (a pen change), left by ``continue``.
ACTIVE = ("sending", "pausing", "paused", "held", "stopping", "waiting")
# What each state lets the page do (GRBL; the PLC has only stop): the buttons it shows. A job waiting
# for the operator (a pen change, G-code M0) gets "continue" here once the streamer takes it.
GRBL_CONTROLS = {"sending": ("pause", "hold", "stop", "feed+", "feed-", "feed="), "pausing": ("stop",),
                 "paused": ("resume", "stop"), "held": ("resume", "stop"), "stopping": (), "waiting": ("continue", "stop")}
PLC_CONTROLS = {"sending": ("stop",), "waiting": ("continue", "stop")}
# the EiBotBoard stops only at a stroke's end with the pen up: pause and stop both wait for it
EBB_CONTROLS = {"sending": ("pause", "stop"), "pausing": ("stop",), "paused": ("resume", "stop"), "stopping": (),
                "waiting": ("continue", "stop")}
CONTROLS = {"grbl": GRBL_CONTROLS, "ebb": EBB_CONTROLS, "plc": PLC_CONTROLS}


@dataclass
class SendState:
    state: str = "idle"  # idle | done | stopped | failed, or one of ACTIVE
    transport: str = ""  # plc | grbl | ebb
    target: str = ""
    executed: int = 0  # PLC: commands executed; GRBL: lines answered; EBB: commands answered
    total: int = 0
    line: int | None = None  # GRBL: the G-code file's line number being sent next
    time_left_s: float = 0.0
    time_total_s: float = 0.0  # the link's model of the whole job's time (time_left_s at its first command)
    position_mm: tuple[float, float] | None = None
    machine_state: str = ""  # GRBL's own state from its status reports (Run, Hold:0, Idle ...)
    layers: list[str] | None = None  # the layers sent (None: every layer), for the page's live view
    message: str = ""
    version: int = 0  # bumped on every change, for the event stream
    started: float = field(default_factory=time.monotonic)

    def public(self) -> dict[str, Any]:
        pct = 100.0 * self.executed / self.total if self.total else 0.0
        controls = CONTROLS.get(self.transport, PLC_CONTROLS).get(self.state, ())
        return {"state": self.state, "transport": self.transport, "target": self.target, "executed": self.executed,
                "total": self.total, "line": self.line, "percent": round(pct, 2),
                "time_left_s": round(self.time_left_s, 2), "time_total_s": round(self.time_total_s, 2),
                "position_mm": self.position_mm,
                "machine_state": self.machine_state, "message": self.message, "controls": list(controls),
                "layers": self.layers,
                "elapsed_s": round(time.monotonic() - self.started, 2),
                "version": self.version}  # grows with every change: the page keeps the newest it has seen


class Sender:
    """At most one send at a time; ``start`` returns at once, ``state`` reports progress."""

    def __init__(self):
        self.lock = threading.Lock()
        self.changed = threading.Condition(self.lock)
        self.s = SendState()
        self._sender = None
        self._sim = None
        self._thread: threading.Thread | None = None
        self._grbl = GrblTargets()
        self._ebb = EbbTargets()
        self._controls: deque[str] = deque()  # GRBL: the page's controls, taken by the streamer at safe points
        self._operator = threading.Event()  # set by Continue (or Stop) while the job waits for a pen change
        self._stop_waiting = False
        # The sender's record (job id, owner token, progress): with it a stopped job resumes on the
        # PLC that holds it, which takes it only from the computer that started it (docs/protocol.md).
        self._records = tempfile.TemporaryDirectory(prefix="doodlecam-studio-")
        # held from the check that no send runs to the end of the send: two requests (a double-click on
        # Send, two tabs) can never both start one
        self._one = threading.Lock()

    def _claim(self, speed) -> None:
        if speed is not None and not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed > 0):
            raise InputError(f"speed must be a positive number, got {speed!r}")
        if not self._one.acquire(blocking=False):
            raise InputError("a send is running; stop it or wait for it to finish")

    def _exclusive(self, speed, start, *args) -> dict:
        """``start(*args)`` holding the one-send lock; released here if it fails, else when the send ends."""
        self._claim(speed)
        try:
            return start(*args)
        except BaseException:
            self._one.release()
            raise

    def record_dir(self, target: str) -> Path:
        """Where a target's resume record lives: a job stopped on one machine resumes on that machine only;
        sent to another one it starts at the beginning (the record is also tied to the job's CRC)."""
        d = Path(self._records.name) / hashlib.sha256(target.encode()).hexdigest()[:16]
        d.mkdir(exist_ok=True)
        return d

    def _update(self, **kw) -> None:
        if isinstance(kw.get("message"), str):
            kw["message"] = for_page(kw["message"])
        with self.changed:
            for k, v in kw.items():
                setattr(self.s, k, v)
            self.s.version += 1
            self.changed.notify_all()

    def note(self, **kw) -> dict:
        """Add what the page needs to the state of the send just started (the layers sent); its snapshot."""
        self._update(**kw)
        return self.snapshot()[1]

    def snapshot(self) -> tuple[int, dict]:
        with self.lock:
            return self.s.version, self.s.public()

    def wait(self, version: int, timeout: float) -> tuple[int, dict]:
        """The state once its version differs from ``version`` (or after ``timeout`` s)."""
        with self.changed:
            self.changed.wait_for(lambda: self.s.version != version, timeout)
            return self.s.version, self.s.public()

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def grbl_port(self, target: str) -> str:
        """The port of a GRBL target for the machine panel; refused while a send uses GRBL."""
        if self.busy and self.s.transport == "grbl":
            raise InputError("a send to GRBL is running; the panel can talk to GRBL when it has ended")
        return self._grbl.port(target, keep_speed=True)[0]

    def ebb_port(self, target: str) -> tuple[str | None, str]:
        """(port, label) of an EiBotBoard target for the machine panel; refused while a send uses the board."""
        if self.busy and self.s.transport == "ebb":
            raise InputError("a send to the EiBotBoard is running; the panel can talk to it when it has ended")
        return self._ebb.port(target)

    def _pen_change(self, machine):
        """The links' ``pen_change``: the send waits in state 'waiting' (the pen up, the machine holding
        the job) until the page's Continue; Stop ends the send there, resumable (it asks again)."""
        from doodlecam.link.session import Paused

        def ask(pen, what: str) -> None:
            what = machine.describe_pen(pen, what)
            self._operator.clear()
            self._stop_waiting = False
            self._update(state="waiting", message=f"change to {what}, then press Continue")
            self._operator.wait()
            if self._stop_waiting:
                raise Paused(f"stopped at the pen change, pen up: change to {what}, then send again to resume")
            self._update(state="sending", message="")

        return ask

    def _answer(self, action: str) -> dict:
        """Continue or Stop while the job waits for the operator."""
        self._stop_waiting = action == "stop"
        self._update(state="stopping" if self._stop_waiting else "sending",
                     message="stopping at the pen change" if self._stop_waiting else "")
        self._operator.set()
        return self.snapshot()[1]

    def start(self, plc_bytes: bytes, machine, target: str, speed: float | None = None, again: bool = False,
              restart: bool = False) -> dict:
        return self._exclusive(speed, self._start_plc, plc_bytes, machine, target, speed, again, restart)

    def _start_plc(self, plc_bytes: bytes, machine, target: str, speed, again: bool, restart: bool) -> dict:
        """Send to ``target``: 'simulator' (a built-in PLC simulator, ``speed`` x real time;
        None = as fast as it can) or 'HOST:PORT' of a PLC. ``again``: run a job the PLC has
        already finished once more (``doodlecam send --again``); ``restart``: start over instead of resuming."""
        from doodlecam.link.plc.sender import UdpSender, parse_target, planned_time_left
        from doodlecam.link.plc.simulator import PlcConfig, PlcSimulator

        sim = None
        if target == "simulator":
            want = speed or math.inf
            if self._sim is None or self._sim.cfg.speed != want:  # one simulator per speed: it keeps held jobs
                self._close_plc_sim()
                self._sim = PlcSimulator(PlcConfig.from_machine(machine, speed=want)).start()
            sim = self._sim
            host, port = sim.address
        else:
            host, port = parse_target(target, 5005)
        header = None

        def progress(executed: int, total: int, status) -> None:
            pos = None
            if status is not None and header is not None:
                pos = (round(status.x / header.steps_per_mm_x, 2), round(status.y / header.steps_per_mm_y, 2))
            self._update(executed=executed, total=total, position_mm=pos,
                         time_left_s=float(left[min(executed, len(left) - 1)]))

        key = None
        if sim is None:  # a real PLC: the machine's key, as 'doodlecam send --udp' uses (docs/protocol.md 1.9)
            from doodlecam.link.plc.keys import profile_key

            key = profile_key(machine)[0]
        sender = UdpSender(host, port, plc_bytes, "studio.plc", progress=progress, again=again, restart=restart, key=key,
                           state_file=self.record_dir(target) / "send-record.json",
                           pen_change=self._pen_change(machine))
        header = sender.plc_header
        left = planned_time_left(sender.records, header)
        self._sender = sender
        with self.changed:
            self.s = SendState(state="sending", transport="plc",
                               target=target if sim is None else f"PLC simulator {host}:{port}",
                               total=sender.n, time_left_s=float(left[0]), time_total_s=float(left[0]),
                               version=self.s.version + 1)
            self.changed.notify_all()
        self._thread = threading.Thread(target=self._run, name="studio-send", daemon=True)
        self._thread.start()
        return self.snapshot()[1]

    def _run(self) -> None:
        from doodlecam.link.session import Paused

        try:
            r = self._sender.run()
            end = dict(state="done", executed=r.commands, time_left_s=0.0,
                       message=f"{r.commands} commands in {r.elapsed:.2f} s"
                       + (f", resumed at command {r.start_at}" if r.resumed else ""))
        except Paused as e:  # the PLC's count, confirmed by its stop (progress reports lag behind it)
            end = dict(state="stopped", message=str(e), executed=self._sender.executed)
        except DoodleError as e:
            end = dict(state="failed", message=str(e))
        except Exception as e:  # never let a send kill the server quietly
            end = dict(state="failed", message=f"send failed: {type(e).__name__}: {e}")
        self._thread = None  # the next send may start as soon as the state says this one ended
        self._update(**end)
        self._one.release()

    def stop(self) -> dict:
        """PLC: stop at the end of the current stroke, pen up (the sender's Ctrl-C). GRBL: ``control('stop')``."""
        if not self.busy:
            raise InputError("no send is running")
        if self.s.transport in ("grbl", "ebb"):
            return self.control("stop")
        if self.s.state == "waiting":
            return self._answer("stop")
        self._sender.interrupts.count += 1  # the sender raises at its next safe point, then stops the PLC
        self._update(message="stopping at the end of the current stroke")
        return self.snapshot()[1]

    # ------------------------------------------------------------ GRBL

    def start_grbl(self, gcode: bytes, machine, target: str, speed: float | None = None, restart: bool = False,
                   plugin_dirs: tuple = ()) -> dict:
        return self._exclusive(speed, self._start_grbl, gcode, machine, target, speed, restart, plugin_dirs)

    def _start_grbl(self, gcode: bytes, machine, target: str, speed, restart: bool, plugin_dirs: tuple) -> dict:
        """Stream G-code to GRBL: ``target`` 'grbl-simulator' (the built-in emulator, ``speed`` x real time)
        or 'serial:PORT'. As ``doodlecam send --serial``: a stopped job resumes after its last executed
        line when sent again, unless ``restart``."""
        from doodlecam import registry
        from doodlecam.link.grbl.protocol import prepare
        from doodlecam.link.grbl.streamer import end_positions
        from doodlecam.link.session import state_file_for

        try:
            text = gcode.decode("ascii")
        except UnicodeDecodeError:
            raise InputError("the job's G-code is not ASCII, which GRBL reads only; check the gcode post's "
                             "pen_up / pen_down options") from None
        lines = prepare(text, "job.gcode")
        if not lines:
            raise InputError("the job's G-code has no lines to send")
        left = time_left(text, lines, machine)
        port, label = self._grbl.port(target, speed)
        cls = registry.get("transport", "serial", plugin_dirs)
        options = cls.resolve_options(machine.plugin_options.get("transport.serial", {}), {})
        path = self.record_dir(target) / "studio.gcode"  # the resume record goes next to it (same CRC: resume)
        path.write_bytes(gcode)
        if restart:
            state_file_for(path).unlink(missing_ok=True)
        self._controls.clear()
        last = [0.0]
        acked = [0]  # lines answered so far, every one (the page's updates are thinned out)

        def progress(done: int, total: int, st) -> None:
            acked[0] = done
            now = time.monotonic()
            if now - last[0] < 0.05 and done < total:  # the page needs no more than 20 updates a second
                return
            last[0] = now
            self._update(executed=done, total=total, line=lines[min(done, len(lines) - 1)].lineno,
                         time_left_s=float(left[min(done, len(left) - 1)]), position_mm=work_position(st) or
                         self.s.position_mm, machine_state=_grbl_state(st) or self.s.machine_state)

        ends = end_positions(lines)

        def log(msg: str) -> None:
            msg = msg.replace(str(path), "job.gcode")  # the private copy's path means nothing to the user
            # the streamer reports its pause by log lines: they move the state on
            if "with the pen up" in msg and msg.startswith("paused"):
                # paused: every line sent has run, so the pen stands at the end of the last one
                k = acked[0]
                x, y = ends[max(k - 1, 0)]
                self._update(state="paused", message=msg, machine_state="Idle", executed=k,
                             line=lines[min(k, len(lines) - 1)].lineno, time_left_s=float(left[k]),
                             position_mm=(x, y) if x is not None and y is not None else self.s.position_mm)
            elif msg == "resumed":
                self._update(state="sending", message="")
            else:
                self._update(message=msg)

        def controls() -> str | None:
            return self._controls.popleft() if self._controls else None

        import inspect

        extra = {"pen_change": self._pen_change(machine)} if "pen_change" in inspect.signature(cls.send).parameters else {}

        def run():
            return cls().send(path, port, options, progress=progress, log=log, controls=controls, **extra)

        with self.changed:
            self.s = SendState(state="sending", transport="grbl", target=label, total=len(lines),
                               line=lines[0].lineno, time_left_s=float(left[0]), time_total_s=float(left[0]),
                               version=self.s.version + 1)
            self.changed.notify_all()
        def done(r) -> str:
            return f"{r['lines']} lines in {r['elapsed_s']:.2f} s" + (f", resumed at line {r['start_line']}"
                                                                      if r["resumed"] else "")

        self._thread = threading.Thread(target=self._run_serial, args=(run, path, acked, done),
                                        name="studio-send-grbl", daemon=True)
        self._thread.start()
        return self.snapshot()[1]

    def _run_serial(self, run, path: Path, acked: list[int], done) -> None:
        """A GRBL or EBB send's thread: ``run()`` to its end; ``done(result)`` says how it went."""
        from doodlecam.link.session import Paused

        alias = "job" + path.suffix  # the private copy's path means nothing to the user
        try:
            r = run()
            end = dict(state="done", executed=self.s.total, time_left_s=0.0, message=done(r))
        except Paused as e:
            end = dict(state="stopped", message=str(e).replace(str(path), alias), executed=acked[0])
        except DoodleError as e:
            end = dict(state="failed", message=str(e).replace(str(path), alias))
        except Exception as e:  # never let a send kill the server quietly
            end = dict(state="failed", message=f"send failed: {type(e).__name__}: {e}")
        self._thread = None
        self._update(**end)
        self._one.release()

    # ------------------------------------------------------------ EiBotBoard

    def start_ebb(self, ebb: bytes, machine, target: str, speed: float | None = None, restart: bool = False,
                  plugin_dirs: tuple = ()) -> dict:
        return self._exclusive(speed, self._start_ebb, ebb, machine, target, speed, restart, plugin_dirs)

    def _start_ebb(self, ebb: bytes, machine, target: str, speed, restart: bool, plugin_dirs: tuple) -> dict:
        """Stream the ``.ebb`` job to an EiBotBoard: ``target`` 'ebb-simulator' (the built-in emulator, ``speed``
        x real time) or 'ebb:PORT' ('ebb:auto' finds the board on USB). As ``doodlecam send job.ebb --serial``:
        a stopped job resumes after the stroke it stopped at when sent again, unless ``restart``."""
        from doodlecam import registry
        from doodlecam.link.ebb.jobfile import read_ebb
        from doodlecam.link.ebb.sender import line_effects
        from doodlecam.link.session import state_file_for

        job = read_ebb(ebb, "job.ebb")
        if not job.lines:
            raise InputError("the job's EBB stream has no commands to send")
        steps, dur = line_effects(job.lines)
        where = work_positions(steps, float(job.header.get("steps_per_mm", 80)), machine.height)
        left = list(itertools.accumulate(reversed(dur), initial=0.0))[::-1]  # time left after k commands
        port, label = self._ebb.port(target, speed)
        cls = registry.get("transport", "ebb", plugin_dirs)
        options = cls.resolve_options(machine.plugin_options.get("transport.ebb", {}), {})
        path = self.record_dir(target) / "studio.ebb"  # the resume record goes next to it (same CRC: resume)
        path.write_bytes(ebb)
        if restart:
            state_file_for(path).unlink(missing_ok=True)
        self._controls.clear()
        last = [0.0]
        acked = [0]

        def progress(done: int, total: int, _status) -> None:
            acked[0] = done
            now = time.monotonic()
            if now - last[0] < 0.05 and done < total:  # the page needs no more than 20 updates a second
                return
            last[0] = now
            self._update(executed=done, time_left_s=left[done], position_mm=where[done - 1])

        def log(msg: str) -> None:
            if msg.startswith("paused, pen up"):  # the board has run every command sent: it stands at the last
                k = acked[0]
                self._update(state="paused", message=msg, executed=k, time_left_s=left[k],
                             position_mm=where[k - 1] if k else self.s.position_mm)
            elif msg == "resumed":
                self._update(state="sending", message="")
            else:
                self._update(message=msg)

        def controls() -> str | None:
            return self._controls.popleft() if self._controls else None

        def run():
            return cls().send(path, port, options, restart=restart, progress=progress, log=log, controls=controls,
                              pen_change=self._pen_change(machine))

        with self.changed:
            self.s = SendState(state="sending", transport="ebb", target=label, total=len(job.lines),
                               time_left_s=left[0], time_total_s=left[0], version=self.s.version + 1)
            self.changed.notify_all()

        def done(r) -> str:
            return (f"{r['commands']} commands in {r['elapsed_s']:.2f} s (firmware {r['firmware']})"
                    + (f", resumed at command {r['start_at']}" if r["resumed"] else ""))

        self._thread = threading.Thread(target=self._run_serial, args=(run, path, acked, done),
                                        name="studio-send-ebb", daemon=True)
        self._thread.start()
        return self.snapshot()[1]

    def control(self, action: str) -> dict:
        """A control of the running GRBL send (``streamer.Streamer``'s): pause (GRBL finishes the lines it
        has, then the pen is lifted), hold (feed hold '!': stops at once, the pen stays as it is),
        resume, stop (ends with the pen up), feed+ / feed- / feed= (feed override). An EiBotBoard send
        has pause, resume and stop, both taking effect at the end of the stroke, pen up."""
        if not self.busy:
            raise InputError("no send is running")
        if self.s.state == "waiting" and action in ("continue", "stop"):
            return self._answer(action)  # a pen change: the operator has fitted the pen, or stops there
        if self.s.transport == "plc":
            if action == "stop":
                return self.stop()
            raise InputError(f"'{action}' is for GRBL and the EiBotBoard; the PLC stops at the end of a stroke "
                             "with Stop, and Resume sends the job again")
        allowed = CONTROLS[self.s.transport].get(self.s.state, ())
        if action not in allowed:
            raise InputError(f"cannot {action} while {self.s.state}"
                             + (f"; possible now: {', '.join(allowed)}" if allowed else ""))
        if action == "stop" and self.s.state == "held":
            # a stop in a feed hold would reset GRBL with the pen where it is: resume first, so GRBL
            # finishes the lines it has and the pen is lifted (the clean stop)
            self._controls.append("resume")
        self._controls.append(action)
        new = {"pause": "pausing", "hold": "held", "resume": "sending", "stop": "stopping"}.get(action, self.s.state)
        if self.s.transport == "ebb":
            msg = {"pause": "pausing at the end of the stroke, pen up",
                   "stop": "stopping at the end of the stroke, pen up"}.get(action, "")
            self._update(state=new, message=msg)
            return self.snapshot()[1]
        msg = {"pause": "pausing: GRBL finishes the lines it has, then the pen is lifted",
               "hold": "feed hold: stopped on the path, the pen as it was",
               "stop": "stopping: GRBL finishes the lines it has, then the pen is lifted"}.get(action, self.s.message)
        self._update(state=new, message=msg)
        return self.snapshot()[1]

    def abandon(self, target: str, job: bytes, machine) -> dict:
        """Forget a stopped job on ``target``: its resume record here, and for a PLC the job it holds
        (only the computer that started it can cancel it). The next Send starts at the beginning."""
        from doodlecam.link.plc.sender import UdpSender, parse_target
        from doodlecam.link.session import state_file_for

        self._claim(None)
        try:
            if target == "grbl-simulator" or target.startswith("serial:"):
                state_file_for(self.record_dir(target) / "studio.gcode").unlink(missing_ok=True)
                msg = "abandoned: the next send starts at the first line"
            elif is_ebb(target):
                state_file_for(self.record_dir(target) / "studio.ebb").unlink(missing_ok=True)
                msg = "abandoned: the next send starts at the first command"
            else:
                if target == "simulator":
                    if self._sim is None:
                        raise InputError("the PLC simulator holds no job; press Send")
                    host, port = self._sim.address
                    key = None
                else:
                    from doodlecam.link.plc.keys import profile_key

                    host, port = parse_target(target, 5005)
                    key = profile_key(machine)[0]
                victim = UdpSender(host, port, job, "studio.plc", key=key,
                                   state_file=self.record_dir(target) / "send-record.json").cancel()
                msg = f"abandoned job {victim}: the next send starts at the first command" if victim else \
                    "the PLC holds no job; the next send starts at the first command"
            self._update(state="idle", message=msg, executed=0, line=0)
            return self.snapshot()[1]
        finally:
            self._one.release()

    def _close_plc_sim(self) -> None:
        if self._sim is not None:
            self._sim.stop()
            self._sim = None

    def close(self, timeout: float = 30.0) -> None:
        """At server shutdown (Ctrl-C): a GRBL send stops as Stop does (GRBL finishes the lines it has,
        the pen is lifted, the resume record kept) before the process ends; then the built-in
        simulators stop."""
        thread = self._thread
        if thread is not None and self.busy and self.s.state == "waiting":
            self._answer("stop")  # nobody will answer the pen change now: stop there, pen up
            thread.join(timeout)
        elif thread is not None and self.busy and self.s.transport in ("grbl", "ebb"):
            try:
                self.control("stop")
            except InputError:  # already stopping
                pass
            thread.join(timeout)
        self._close_plc_sim()
        self._grbl.close()
        self._ebb.close()


# the links speak to a terminal; the page has buttons for the same choices
_FOR_PAGE = ((re.compile(r"(?:send (?:it )?(?:again )?with|add) --restart to start over(?: \(that abandons it\))?"),
              "press Start over to draw it from the beginning"),
             (re.compile(r"(?:add --cancel to abandon it|cancel the job with --cancel)"), "press Abandon to cancel it"),
             (re.compile(r"add --again"), "press Send again"))


def for_page(message: str) -> str:
    """A link's message with its command-line advice turned into the page's buttons."""
    for pattern, words in _FOR_PAGE:
        message = pattern.sub(words, message)
    return message


def _grbl_state(st) -> str:
    if st is None:
        return ""
    return st.state + (f":{st.substate}" if st.substate is not None else "")
