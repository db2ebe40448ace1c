"""A minimal PLC written only from docs/protocol.md section 1 (version 3), with no doodlecam imports.

It is the check that the document is enough to build a PLC: the real sender
must complete jobs against it. It executes a command the moment it is next
in order (no motion), and keeps what a PLC must: the window and slots, the
session (address + nonce + challenge), the current challenge, the owner
(IP + token), the ended jobs and the contents that ran to their end, the
replay window and the HMAC key.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import select
import socket
import struct
import threading
import time
import zlib

COMMON = struct.Struct("<2sBBIQIB3xQ")  # 1.2
STATUS = struct.Struct("<BBBBIIIIiiII")  # 1.3, status block
HEADER = struct.Struct("<IIIIdddiiiiddiiQ")  # 1.3, 88 bytes
RECORD = struct.Struct("<IHHii")
HELLO, HDR, DATA, STOP, CANCEL = 1, 2, 3, 4, 5
READY, REQUEST, STAT, DONE, FAULT, NAK = 0x10, 0x11, 0x12, 0x13, 0x14, 0x15
BUSY, FINISHED, START_MISMATCH, BAD_HEADER, ALREADY_DONE, AUTH_REQUIRED, STALE_CHALLENGE = 1, 2, 3, 4, 6, 7, 8
B_READY, D_OPERATING = 2, 4


class DocPlc:
    def __init__(self, buffer_size: int = 64, key: bytes | None = None):
        self.B, self.key = buffer_size, key
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.address = self.sock.getsockname()
        self.boot, self.seq = 0x1234_5678_9ABC_DEF1, 0
        self.job = None  # dict: id, n, crc, token, executed, slots
        self.session = None  # ((ip, port), nonce, challenge)
        self.challenge = secrets.randbits(64) or 1  # 1.9: the next HEADER or CANCEL must carry it
        self.owner = None  # (ip, token)
        self.top, self.seen = 0, set()  # replay window of the session (1.9)
        self.ended: dict[int, int] = {}  # job id -> fault
        self.done_crcs: dict[int, tuple[int, int]] = {}  # crc -> (job id, when)
        self.last_done = 0
        self.executed: list[tuple[int, int, int, int, int]] = []  # (job, command_no, type, x, y)
        self.refused = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    # --- framing (1.2)
    def _frame(self, kind, job_id, body, key, challenge):
        msg = COMMON.pack(b"DP", 3, kind, job_id, self.boot, self.seq, 1 if key else 0, challenge) + body
        if key:
            msg += hmac.new(key, msg, hashlib.sha256).digest()
        return msg + struct.pack("<I", zlib.crc32(msg))

    def _parse(self, d: bytes):
        if len(d) < 36 or struct.unpack_from("<I", d, len(d) - 4)[0] != zlib.crc32(d[:-4]):
            return None
        magic, version, kind, job_id, origin, seq, flags, challenge = COMMON.unpack_from(d)
        if magic != b"DP" or version != 3 or flags & ~1:
            return None
        end = len(d) - 4
        if flags & 1:
            end -= 32
            if not self.key or end < 32 or not hmac.compare_digest(
                    hmac.new(self.key, d[:end], hashlib.sha256).digest(), d[end:end + 32]):
                return "auth"
        elif self.key:
            return "auth"
        return kind, job_id, origin, seq, challenge, d[32:end]

    def _send(self, kind, addr, job_id=None, extra=b"", key_ok=True):
        j = self.job
        self.seq += 1
        st = STATUS.pack(D_OPERATING if j else B_READY,  # it runs a command the moment it is next
                         0, 0, 0, self.B, j["executed"] if j else 0, j["buffered"] if j else 0, 0, 0, 0,
                         self.last_done, j["crc"] if j else 0) if key_ok else bytes(STATUS.size)
        jid = job_id if job_id is not None else (j["id"] if j else 0)
        self.sock.sendto(self._frame(kind, jid, st + extra, self.key if key_ok else None, self.challenge), addr)

    def _nak(self, addr, job_id, reason, detail=0, owner=("0.0.0.0", 0), when=0):
        ip = struct.unpack(">I", socket.inet_aton(owner[0]))[0]
        self._send(NAK, addr, job_id, struct.pack("<HHIII", reason, owner[1], detail, ip, when))

    # --- the PLC (1.5)
    def _handle(self, d, addr):
        p = self._parse(d)
        if p == "auth":
            if d[3] == HELLO:
                self.seq += 1
                self.sock.sendto(self._frame(NAK, 0, bytes(STATUS.size) + struct.pack("<HHIII", AUTH_REQUIRED, 0, 0, 0, 0),
                                             None, 0), addr)
            return
        if p is None:
            return
        kind, job_id, origin, seq, challenge, body = p
        mine = self.session == (addr, origin, challenge)
        fresh = challenge == self.challenge
        if mine:  # replay window, 64 wide
            if seq <= self.top - 64 or seq in self.seen:
                return
            self.seen.add(seq)
            self.top = max(self.top, seq)
            self.seen = {s for s in self.seen if s > self.top - 64}
        j = self.job
        if kind == HELLO and len(body) == 0:
            if j is None or mine:
                self._send(STAT if j else READY, addr)
            else:
                self.refused += 1
                self._nak(addr, job_id, BUSY, j["id"], self.session[0])
        elif kind == HDR and len(body) == HEADER.size:
            crc, n, start, flags, dt, sx, sy, ax, ay, vx, vy, rx, ry, rvx, rvy, token = HEADER.unpack(body)
            if j is not None:
                if job_id == j["id"] and (addr[0], token) == self.owner:
                    if mine or fresh:  # a duplicate, or the owner's restarted sender with the current challenge
                        if not mine:
                            self._bind(addr, origin, seq, challenge)
                        self._send(STAT, addr)
                    else:
                        self._nak(addr, job_id, STALE_CHALLENGE)
                else:
                    self.refused += 1
                    self._nak(addr, job_id, BUSY, j["id"], self.session[0])
            elif job_id in self.ended:
                self._nak(addr, job_id, FINISHED, self.ended[job_id])
            elif job_id == 0 or not 1 <= start <= n or not 0 < dt <= 1 or min(sx, sy, ax, ay, vx, vy) <= 0 or flags & ~1:
                self._nak(addr, job_id, BAD_HEADER)
            elif not fresh:
                self._nak(addr, job_id, STALE_CHALLENGE)
            elif crc in self.done_crcs and not flags & 1:
                self._nak(addr, job_id, ALREADY_DONE, *self.done_crcs[crc][:1], when=self.done_crcs[crc][1])
            elif start != 1:
                self._nak(addr, job_id, START_MISMATCH, 1)  # this PLC never holds jobs
            else:
                self.job = {"id": job_id, "n": n, "crc": crc, "executed": 0, "buffered": 0,
                            "slots": [None] * self.B}
                self.owner = (addr[0], token)
                self._bind(addr, origin, seq, challenge)
                self._request(addr)
        elif kind == DATA and mine and j and job_id == j["id"] and len(body) >= 8:
            first, count = struct.unpack_from("<IH", body)
            if not 1 <= count <= 64 or len(body) != 8 + 16 * count or first < 1 or first + count - 1 > 2**32 - 1:
                return
            recs = [RECORD.unpack_from(body, 8 + 16 * i) for i in range(count)]
            if any(r[0] != first + i or r[1] > 1 for i, r in enumerate(recs)):
                return
            for r in recs:
                c = r[0]
                if j["executed"] < c <= min(j["executed"] + self.B, j["n"]):
                    j["slots"][(c - 1) % self.B] = r
            self._execute(addr)
        elif kind == STOP and mine and len(body) == 4 and body[0] <= 1:
            self._send(STAT, addr)
        elif kind == CANCEL and len(body) == 8 and j and job_id == j["id"] \
                and (addr[0], struct.unpack("<Q", body)[0]) == self.owner:
            if not fresh:
                self._nak(addr, job_id, STALE_CHALLENGE)
                return
            self.challenge = secrets.randbits(64) or 1  # used up
            self.ended[j["id"]] = 5
            self.job = None
            self._send(READY, addr, job_id)

    def _bind(self, addr, origin, seq, challenge):
        self.session, self.top, self.seen = (addr, origin, challenge), seq, {seq}
        self.challenge = secrets.randbits(64) or 1  # used up: a captured HEADER never binds again

    def _execute(self, addr):
        j = self.job
        while j["executed"] < j["n"]:
            c = j["executed"] + 1
            r = j["slots"][(c - 1) % self.B]
            if r is None or r[0] != c:
                break
            self.executed.append((j["id"], c, r[1], r[3], r[4]))
            j["executed"] = c
        j["buffered"] = j["executed"]
        if j["executed"] == j["n"]:
            self.ended[j["id"]] = 0
            self.done_crcs[j["crc"]] = (j["id"], int(time.time()))
            self.last_done = j["id"]
            self._send(DONE, addr)
            self.job = None
            self._send(READY, addr, j["id"])
        else:
            self._request(addr)

    def _request(self, addr):
        j = self.job
        hi = min(j["executed"] + self.B, j["n"])
        missing = [c for c in range(j["executed"] + 1, hi + 1) if j["slots"][(c - 1) % self.B] is None
                   or j["slots"][(c - 1) % self.B][0] != c]
        ranges = []
        for c in missing:
            if ranges and ranges[-1][0] + ranges[-1][1] == c:
                ranges[-1][1] += 1
            else:
                ranges.append([c, 1])
        ranges = ranges[:16]
        if ranges:
            self._send(REQUEST, addr, None, struct.pack("<Hxx", len(ranges))
                       + b"".join(struct.pack("<II", f, n) for f, n in ranges))

    def _run(self):
        last = time.monotonic()
        while not self._stop.is_set():
            r, _, _ = select.select([self.sock], [], [], 0.05)
            if r:
                d, addr = self.sock.recvfrom(2048)
                self._handle(d, addr)
            if self.job and self.session and time.monotonic() - last > 0.05:  # re-request what is missing
                last = time.monotonic()
                self._request(self.session[0])

    def start(self):
        self._thread.start()
        return self

    def stop(self):
        self._stop.set()
        self._thread.join(5)
        self.sock.close()
