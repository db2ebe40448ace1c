"""Streaming an ``.ebb`` job to an EiBotBoard over USB serial (pyserial; plotink finds the board).

Flow control: one command in flight. The board answers ``OK`` when a command has been
parsed and, for a motion command, has entered its motion FIFO; while the FIFO is full it
reads nothing, so the answer comes once there is room. With one command executing, one
in the FIFO and the next one sent as soon as the previous is answered, the board always
has the next period's LM before the current one ends (each lasts 40 ms) and never more
than it can hold.

Stops happen at a stroke's end with the pen up: Ctrl-C (or ``stop`` / ``pause`` from
``controls``) lets the job run on to its next ``SP,1`` (pen up), waits until the board has
executed it (``QM``), and saves the resume point (the command after it) next to the job.
Sending the job again resumes there: the servo set-up and a pen up are sent again, the
board is moved pen-up (``HM``) to where the job expects it, and the stream goes on. A
board lost mid-stroke (unplugged) resumes at the start of that stroke. ``@PAUSE,<pen>``
lines wait until the board has stopped, then ask the operator for the pen.
"""

from __future__ import annotations

import re
import time
import zlib
from pathlib import Path
from typing import Callable

from doodlecam.errors import InputError
from doodlecam.link.ebb.board import TICK_HZ, axis_move
from doodlecam.link.ebb.jobfile import EbbJob, read_ebb
from doodlecam.link.session import Interrupts, LinkError, Paused, clear_state, load_state, save_state

MIN_FIRMWARE = (2, 7, 0)  # LM (and LM's Clear, HM to a position)
_NEEDS = re.compile(r"^(\d+)\.(\d+)\.(\d+)")  # the header's "firmware: 3.0.0 or newer (...)"
_VERSION = re.compile(r"EBB.*Firmware Version (\d+)\.(\d+)\.(\d+)", re.I)
HOME_RATE = 4000  # steps/s of the HM move that puts the board back in place to resume


def line_effects(lines) -> tuple[list[tuple[int, int]], list[float]]:
    """Motor position (steps, from where EM zeroed the counters) after every line, and its duration (s)."""
    pos, out, dur = [0, 0], [], []
    for s in lines:
        p = s.split(",")
        name, a = p[0], [int(v) for v in p[1:]] if not s.startswith("@") else []
        d = 0.0
        if name == "LM":
            t1, d1, _ = axis_move(a[0], a[1], a[2])
            t2, d2, _ = axis_move(a[3], a[4], a[5])
            pos = [pos[0] + d1, pos[1] + d2]
            d = max(t1, t2) / TICK_HZ
        elif name in ("SM", "XM"):
            s1, s2 = (a[1], a[2] if len(a) > 2 else 0) if name == "SM" else (a[1] + a[2], a[1] - a[2])
            pos = [pos[0] + s1, pos[1] + s2]
            d = a[0] / 1000
        elif name == "SP" and len(a) > 1:
            d = a[1] / 1000
        elif name == "EM":
            pos = [0, 0]
        out.append((pos[0], pos[1]))
        dur.append(d)
    return out, dur


def find_port() -> str:
    """The first EiBotBoard on USB (vendor 04D8, product FD92), by plotink."""
    from plotink import ebb_serial

    port = ebb_serial.findPort()
    if not port:
        raise LinkError("no EiBotBoard found on USB (vendor id 04D8, product FD92); plug it in and switch it on, "
                        "or give the port with --serial PORT")
    return port


class EbbSender:
    def __init__(self, port: str, job: EbbJob, name: str, state_file: Path | None = None, timeout: float = 5.0,
                 restart: bool = False, progress: Callable | None = None, log: Callable[[str], None] | None = None,
                 controls: Callable[[], str | None] | None = None,
                 pen_change: Callable[[int, str], None] | None = None):
        self.port_name, self.job, self.name = port, job, name
        self.lines = list(job.lines)
        self.state_file, self.timeout, self.restart = state_file, timeout, restart
        self.progress, self.log = progress, log or (lambda m: None)
        self.controls, self.pen_change = controls, pen_change
        self.crc = zlib.crc32("\n".join(self.lines).encode())
        self.positions, self.durations = line_effects(self.lines)
        self.ser = None
        self.sent = 0  # commands answered OK this run
        self.pen_changes = 0
        self.version = ""
        # where each stroke block begins: after a pen up (SP,1) or a pen change
        self.block = []
        start = 0
        for i, s in enumerate(self.lines):
            self.block.append(start)
            if s.startswith("SP,1") or s.startswith("@PAUSE"):
                start = i + 1

    # ------------------------------------------------------------ serial

    def _open(self) -> None:
        import serial

        try:
            self.ser = serial.Serial(self.port_name, 115200, timeout=0.05, write_timeout=2.0)
        except (serial.SerialException, OSError) as e:
            raise LinkError(f"cannot open {self.port_name} ({e}); check the port (doodlecam send --serial PORT) "
                            "and that no other program uses it") from None
        self.ser.reset_input_buffer()

    def _write(self, text: str) -> None:
        import serial

        try:
            self.ser.write((text + "\r").encode("ascii"))
        except (serial.SerialException, OSError):
            raise self._lost() from None

    def _readline(self, deadline: float) -> str:
        import serial

        buf = b""
        while time.monotonic() < deadline:
            try:
                chunk = self.ser.read_until(b"\n", 256)
            except (serial.SerialException, OSError, TypeError):
                raise self._lost() from None
            buf += chunk
            if buf.endswith(b"\n"):
                text = buf.decode("ascii", "replace").strip("\r\n ")
                if text:
                    return text
                buf = b""
        return buf.decode("ascii", "replace").strip() or ""

    def _lost(self) -> LinkError:
        return LinkError(f"lost the board on {self.port_name}; plug it back in and send the job again to resume "
                         "(a stroke it was drawing is drawn again from its start)")

    def _ask(self, cmd: str, wait: float) -> str:
        """Send one command; its answer up to OK. Raises LinkError on an error answer or silence."""
        self._write(cmd)
        deadline = time.monotonic() + wait
        got = []
        while True:
            line = self._readline(deadline)
            if not line:
                what = f"'{got[-1]}'" if got else "nothing"
                raise LinkError(f"{self.port_name}: the board answered {what} to {cmd!r} within {wait:.1f} s; "
                                "check the cable and that it is an EiBotBoard")
            if "Err:" in line:
                if not line.endswith("OK"):
                    self._readline(time.monotonic() + 0.5)  # the OK that ends an error in legacy syntax
                raise _Refused(line.replace("OK", "").strip())
            got.append(line)
            if line.endswith("OK") or line.startswith("QM,") or cmd in ("V",) or cmd.startswith("QG"):
                return "\n".join(got)

    def handshake(self) -> str:
        """Check the board answers V as an EiBotBoard with firmware >= 2.7.0 and the job's; before anything moves."""
        self._write("V")
        line = self._readline(time.monotonic() + 2.0)
        m = _VERSION.search(line)
        if not m:
            said = f"answered {line[:60]!r}" if line else "did not answer"
            raise LinkError(f"{self.port_name} {said} to the version query V; it is not an EiBotBoard "
                            "(an AxiDraw's board says 'EBBv13... Firmware Version 2.x/3.x'); give its port")
        version = tuple(int(v) for v in m.groups())
        self.version = ".".join(m.groups())
        if version < MIN_FIRMWARE:
            raise LinkError(f"{self.port_name}: EiBotBoard firmware {self.version} is too old for LM moves (needs "
                            "2.7.0 or newer); update it (AxiDraw: the EBB firmware updater on the Evil Mad Scientist wiki)")
        need = _NEEDS.match(self.job.header.get("firmware", ""))
        if need and version < tuple(int(v) for v in need.groups()):
            raise LinkError(f"{self.port_name}: EiBotBoard firmware {self.version} cannot run {self.name}, which needs "
                            f"{'.'.join(need.groups())} or newer (its LMs turn a motor back mid-move); update the board "
                            "(the EBB firmware updater on the Evil Mad Scientist wiki) or convert again with "
                            "--post-opt ebb.firmware=2.7 (or firmware = \"2.7\" in the profile's [post.ebb])")
        return self.version

    def wait_idle(self, limit: float) -> None:
        """Poll QM until the board has executed everything it holds."""
        deadline = time.monotonic() + limit
        while time.monotonic() < deadline:
            status = self._ask("QM", self.timeout)
            f = status.split(",")
            if len(f) >= 5 and f[1].strip() == "0" and f[4].strip()[:1] == "0":
                return
            time.sleep(0.02)
        raise LinkError(f"{self.port_name}: the board is still moving after {limit:.0f} s; check it")

    # ------------------------------------------------------------ the job

    def _save(self, next_line: int) -> None:
        save_state(self.state_file, {"job_id": 1, "job_crc": self.crc, "next": int(next_line), "name": self.name})

    def run(self) -> dict:
        st = None if self.restart else load_state(self.state_file, self.crc)
        start = int(st["next"]) if st else 0
        if start >= len(self.lines):
            start = 0
        self._open()
        try:
            self.handshake()
            if start:
                self._resume_preamble(start)
            return self._stream(start)
        finally:
            try:
                self.ser.close()
            except Exception:
                pass

    def _resume_preamble(self, start: int) -> None:
        """Servo set-up and pen up again, then a pen-up move to where the job expects the board."""
        for s in self.lines[:start]:
            if s.startswith("SC,"):
                self._ask(s, self.timeout)
        self._ask("SP,1,200", self.timeout)
        want = self.positions[start - 1]
        got = self._ask("QS", self.timeout).split("\n")[0].split(",")
        here = (int(got[0]), int(got[1]))
        if here != want:
            self.log(f"resuming at command {start + 1}: moving pen-up from {here} to {want} steps")
            self._ask(f"HM,{HOME_RATE},{want[0]},{want[1]}", self.timeout)
        self.log(f"resuming at command {start + 1} of {len(self.lines)}")

    def _stream(self, start: int) -> dict:
        total = len(self.lines)
        left = sum(self.durations[start:])
        stop_after = None  # stop once this line (a pen up) has been sent
        stop_kind = ""
        ints = Interrupts()
        t0 = time.monotonic()
        i = start
        with ints:
            while i < total:
                s = self.lines[i]
                want = self.controls() if self.controls else None
                if ints.count and stop_after is None:
                    want = "stop"
                if want in ("stop", "pause") and stop_after is None:
                    stop_kind = want
                    stop_after = next((k for k in range(i, total) if self.lines[k].startswith("SP,1")), total - 1)
                    if i > 0 and self.lines[i - 1].startswith(("SP,1", "@PAUSE")):
                        stop_after = i - 1
                    self.log(f"{want}: stopping at the end of the stroke (command {stop_after + 1}), pen up")
                elif want == "stop":
                    stop_kind = "stop"  # a pause under way becomes a stop at the same stroke end
                if stop_after is not None and i > stop_after:
                    self.wait_idle(sum(self.durations[max(0, i - 3):i]) + self.timeout)
                    self._save(i)
                    if stop_kind == "pause" and self.controls:
                        self.log("paused, pen up: resume to go on")
                        while (want := self.controls() or "") != "resume":
                            if ints.count or want == "stop":
                                raise Paused(f"stopped at command {i} of {total}, pen up; send the job again to resume")
                            time.sleep(0.05)
                        self.log("resumed")
                        stop_after, stop_kind = None, ""
                        continue
                    raise Paused(f"stopped at command {i} of {total}, pen up; send the job again to resume")
                if s.startswith("@PAUSE"):
                    pen = int(s.split(",")[1])
                    self.wait_idle(sum(self.durations[max(0, i - 3):i]) + self.timeout)
                    if self.pen_change is None:
                        self._save(i + 1)  # the operator fits the pen, then sends again: on after the change
                        raise Paused(f"pen change to pen {pen} at command {i + 1}; fit it and send the job again")
                    self._save(i)  # an operator who stops here is asked again on resume
                    self.pen_changes += 1
                    self.pen_change(pen, f"pen {pen}")
                    self._save(i + 1)
                    i += 1
                    continue
                # the answer to a motion command waits for FIFO room: the one running and the one queued
                wait = self.timeout + sum(self.durations[max(0, i - 2):i])
                try:
                    self._ask(s, wait)
                except _Refused as e:
                    self._save(self.block[i])
                    raise LinkError(f"the board refused command {i + 1} {s[:48]!r}: {e}; the job stopped there "
                                    "(re-export the job; sending it again resumes at that stroke)") from None
                except LinkError:
                    self._save(self.block[i])
                    raise
                self.sent += 1
                if s.startswith("SP,1"):
                    self._save(i + 1)
                left -= self.durations[i]
                if self.progress:
                    self.progress(i + 1, total, {"left_s": max(left, 0.0)})
                i += 1
            self.wait_idle(sum(self.durations[-3:]) + self.timeout)
        clear_state(self.state_file)
        return {"port": self.port_name, "firmware": self.version, "commands": total, "start_at": start + 1,
                "resumed": start > 0, "sent": self.sent, "pen_changes": self.pen_changes,
                "elapsed_s": time.monotonic() - t0}


class _Refused(Exception):
    pass


def send_ebb(port: str | None, path: Path, **kw) -> dict:
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror}); check the path") from None
    job = read_ebb(data, str(path))  # a damaged file is refused before the port is opened
    return EbbSender(port or find_port(), job, str(path), **kw).run()
