"""The serial link to a GRBL controller: open the port, wake GRBL, character-counted writes,
real-time bytes, answers and status reports.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from dataclasses import dataclass
from typing import Callable

from doodlecam.link.grbl.protocol import (
    STATUS_PERIOD,
    GrblError,
    GrblStatus,
    alarm_advice,
    alarm_text,
    parse_status,
)
from doodlecam.link.session import Interrupts, LinkError

# ---------------------------------------------------------------- the link

@dataclass
class StreamResult:
    lines: int
    start: int  # index of the first line of the job this run sent
    errors: list  # check mode: (GcodeLine, code)
    elapsed: float
    max_outstanding: int


class GrblLink:
    """A GRBL controller on a serial port (or a pyserial URL such as ``loop://``)."""

    def __init__(self, port: str, baud: int = 115200, *, timeout: float = 5.0, connect_timeout: float = 3.0,
                 log: Callable[[str], None] | None = None):
        self.port, self.baud = port, baud
        self.timeout, self.connect_timeout = timeout, connect_timeout
        self.log = log or (lambda msg: None)
        self.q: queue.Queue = queue.Queue()
        self.status: GrblStatus | None = None
        self.messages: list[str] = []
        self.ser = None
        self._reader: threading.Thread | None = None
        self._closing = threading.Event()
        self._last_query = 0.0
        self._last_rx = time.monotonic()
        self.polling = True
        self.max_outstanding = 0
        self.alarm_banner = False
        self.interrupts = Interrupts()  # Ctrl-C surfaces in next_event, never halfway through a write

    # ------------------------------------------------------------ port

    def open(self) -> "GrblLink":
        import serial

        try:
            self.ser = serial.serial_for_url(self.port, baudrate=self.baud, timeout=0.05, write_timeout=self.timeout)
        except (serial.SerialException, OSError, ValueError) as e:
            if "://" not in self.port and not os.path.exists(self.port):
                why = "no such device"
            else:
                why = str(getattr(e, "strerror", None) or e).split(":")[-1].strip() or type(e).__name__
            raise LinkError(f"serial port {self.port}: {why}; check the cable and the port name "
                            "(ls /dev/ttyUSB* /dev/ttyACM*), or try 'doodlecam sim grbl'") from None
        self._last_rx = time.monotonic()
        self._reader = threading.Thread(target=self._read_loop, name="grbl-reader", daemon=True)
        self._reader.start()
        return self

    def close(self) -> None:
        self._closing.set()
        if self._reader is not None:
            self._reader.join(1.0)
        if self.ser is not None:
            try:
                self.ser.close()
            except Exception:
                pass

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def _gone(self, why: str) -> LinkError:
        return LinkError(f"serial port {self.port} disappeared ({why}); reconnect it, then send the job again to resume")

    def _read_loop(self) -> None:
        buf = b""
        while not self._closing.is_set():
            try:
                chunk = self.ser.read(self.ser.in_waiting or 1)
            except Exception as e:  # pyserial raises SerialException, OSError or TypeError on a vanished port
                if not self._closing.is_set():
                    self.q.put(("gone", str(e) or type(e).__name__))
                return
            if not chunk:
                continue
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for raw in lines:
                line = raw.strip(b"\r").decode("ascii", "replace").strip()
                if line:
                    self._dispatch(line)

    def _dispatch(self, line: str) -> None:
        now = time.monotonic()
        if line == "ok":
            self.q.put(("ok",))
        elif line.startswith("error:"):
            self.q.put(("error", _code(line)))
        elif line.startswith("ALARM:"):
            self.q.put(("alarm", _code(line)))
        elif line.startswith("<"):
            st = parse_status(line, now)
            if st is not None:
                self.status = st
                self.q.put(("status", st))
        elif line.startswith("Grbl "):
            self.q.put(("banner", line))
        elif line.startswith("[MSG:"):
            self.q.put(("msg", line[5:-1] if line.endswith("]") else line[5:]))
        else:
            self.q.put(("info", line))

    def write(self, data: bytes) -> None:
        import serial

        try:
            self.ser.write(data)
        except (serial.SerialException, OSError) as e:
            raise self._gone(str(e) or type(e).__name__) from None

    def realtime(self, char: bytes) -> None:
        self.write(char)

    # ------------------------------------------------------------ events

    def _poll(self) -> None:
        now = time.monotonic()
        if self.polling and now - self._last_query >= STATUS_PERIOD:
            self._last_query = now
            self.realtime(b"?")

    def next_event(self, wait: float) -> tuple | None:
        """The next event from GRBL within ``wait`` s (status polled meanwhile), else None."""
        end = time.monotonic() + wait
        while True:
            self.interrupts.check()
            self._poll()
            now = time.monotonic()
            left = end - now
            if left <= 0:
                self._check_alive()
                return None
            step = min(left, max(self._last_query + STATUS_PERIOD - now, 0.001)) if self.polling else left
            try:
                ev = self.q.get(timeout=step)
            except queue.Empty:
                self._check_alive()
                continue
            self._last_rx = time.monotonic()
            if ev[0] == "gone":
                raise self._gone(ev[1])
            if ev[0] == "msg":
                self.messages.append(ev[1])
                if "to unlock" in ev[1]:
                    self.alarm_banner = True
            return ev

    def _check_alive(self) -> None:
        if self.polling and time.monotonic() - self._last_rx > self.timeout:
            raise LinkError(f"GRBL on {self.port} stopped answering for {self.timeout:g} s; check the cable and its power")

    def fresh_status(self, wait: float | None = None) -> GrblStatus:
        """A status report requested after this call."""
        t0 = time.monotonic()
        end = t0 + (wait if wait is not None else self.timeout)
        while time.monotonic() < end:
            ev = self.next_event(end - time.monotonic())
            if ev is None:
                break
            if ev[0] == "status" and ev[1].at > t0:
                return ev[1]
            self._unexpected(ev, during="waiting for a status report")
        raise LinkError(f"GRBL on {self.port} sends no status reports; check the port and baud rate")

    def _unexpected(self, ev: tuple, during: str) -> None:
        if ev[0] == "alarm":
            raise self.alarm_error(ev[1], during)
        if ev[0] == "banner":
            raise GrblError(f"GRBL on {self.port} reset itself while {during}; check its power and wiring, then send again")

    def alarm_error(self, code: int, where: str) -> GrblError:
        done = ""
        if code in CRITICAL_ALARMS:  # GRBL takes nothing until a soft reset
            try:
                done = ("GRBL was reset and stays locked: " if self.reset_after_alarm()
                        else "GRBL did not restart after a reset; power-cycle it, then: ")
            except LinkError:
                done = "the port closed; reconnect, run 'doodlecam machine --serial PORT reset', then: "
        return GrblError(f"GRBL ALARM:{code} {where}: {alarm_text(code)}; {done}{alarm_advice(code)}")

    def reset_after_alarm(self) -> bool:
        """After a critical alarm GRBL waits 500 ms (report_alarm_message's delay), prints "[MSG:Reset to
        continue]", discards any reset that came meanwhile and answers nothing (not even status) until a new
        one. So: wait for that message (or the 500 ms), then reset; True once GRBL has restarted."""
        polling, self.polling = self.polling, False  # a silent GRBL is no dead cable here
        try:
            end = time.monotonic() + CRITICAL_DELAY_S + 1.0
            while time.monotonic() < end:
                ev = self.next_event(end - time.monotonic())
                if ev is not None and ev[0] == "msg" and "Reset to continue" in ev[1]:
                    break
            return self.try_reset()  # (without the message the 500 ms are long over)
        finally:
            self.polling = polling

    def try_reset(self) -> bool:
        """A soft reset; True when GRBL prints its banner again."""
        self.alarm_banner = False
        self.realtime(b"\x18")
        return self.wait_banner(self.connect_timeout)

    def wait_idle(self) -> GrblStatus:
        """Wait until GRBL reports Idle (motion done), failing on alarms or silence."""
        while True:
            st = self.fresh_status()
            if st.state in ("Idle", "Check"):
                return st
            if st.state == "Alarm":
                raise GrblError(f"GRBL on {self.port} is in alarm state; {alarm_advice(0)}")
            if st.state in ("Door", "Sleep"):
                raise GrblError(f"GRBL on {self.port} is in {st.state} state; close the door / reset it, then send again")

    def send_wait(self, text: str) -> tuple[str, int]:
        """Send one line and wait for its answer: ('ok', 0) or ('error', code)."""
        self.write((text + "\n").encode("ascii"))
        while True:
            ev = self.next_event(self.timeout)
            if ev is None:
                continue
            if ev[0] == "ok":
                return "ok", 0
            if ev[0] == "error":
                return "error", ev[1]
            self._unexpected(ev, during=f"waiting for the answer to '{text}'")

    def wait_banner(self, wait: float) -> bool:
        end = time.monotonic() + wait
        while time.monotonic() < end:
            ev = self.next_event(end - time.monotonic())
            if ev is not None and ev[0] == "banner":
                return True
        return False

    def soft_reset(self) -> None:
        if not self.try_reset():
            raise LinkError(f"GRBL on {self.port} did not restart after a soft reset; power-cycle it")

    # ------------------------------------------------------------ session

    def first_status(self) -> GrblStatus:
        """GRBL's first status report after opening the port, in whatever state it is."""
        end = time.monotonic() + self.connect_timeout
        while time.monotonic() < end:
            try:
                ev = self.next_event(end - time.monotonic())
            except LinkError as e:
                if "stopped answering" in str(e):
                    break
                raise
            if ev and ev[0] == "status":
                return ev[1]
        raise LinkError(f"no answer from GRBL on {self.port} within {self.connect_timeout:g} s; check the port, the "
                        "baud rate (--baud) and that the controller runs GRBL")

    def connect(self) -> GrblStatus:
        """Make sure GRBL answers, wait for a previous job to finish, start from a clean reset."""
        st = self.first_status()
        if st.state in ("Run", "Jog", "Home"):
            self.log("GRBL is still moving (a previous job?); waiting for it to finish")
            st = self.wait_idle()
        if st.state == "Hold":
            raise GrblError(f"GRBL on {self.port} is in feed hold; resume (~) or reset it, then send again")
        if st.state == "Check":
            self.send_wait("$C")
            self.wait_banner(self.connect_timeout)
            st = self.fresh_status()
        if st.state == "Alarm":
            raise GrblError(f"GRBL on {self.port} is in alarm state; home it ($H: 'doodlecam machine --serial "
                            f"{self.port} home') or unlock it ($X: '... unlock'), then send again")
        if st.state != "Idle":
            raise GrblError(f"GRBL on {self.port} is in {st.state} state; make it idle, then send again")
        # A soft reset while idle keeps the position and clears any half-received line.
        self.soft_reset()
        st = self.fresh_status()
        if st.state == "Alarm" or self.alarm_banner:
            raise GrblError(f"GRBL on {self.port} starts in alarm state (homing enabled?); home it ($H: 'doodlecam "
                            f"machine --serial {self.port} home') or unlock it ($X: '... unlock'), then send again")
        return st


# ALARM:1 (hard limit) and ALARM:2 (soft limit) block GRBL until a reset (protocol.c); 10 is grblHAL's e-stop
CRITICAL_ALARMS = (1, 2, 10)
CRITICAL_DELAY_S = 0.5  # GRBL's delay_ms(500) after printing a critical alarm


def _code(line: str) -> int:
    try:
        return int(line.split(":", 1)[1])
    except ValueError:
        return -1
