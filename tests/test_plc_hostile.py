"""The PLC link on a hostile or faulty network (issue 15): crafted, forged, replayed and fuzzed datagrams.

Two levels. The simulator's datagram handler driven directly (no sockets,
a fake clock) with a job fed by an in-test PC, so 100 000 CRC-correct
fuzzed datagrams run in seconds; and scenarios on real loopback sockets with
the real sender. Every test checks what the PLC *executed* against the file:
each command once, in order, ending where the plan says.
"""

import hmac
import math
import struct
import zlib
from hashlib import sha256

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from doodlecam.link.plc import protocol as P
from doodlecam.link.plc.packetfile import RECORD_DTYPE, read_plc_array
from doodlecam.link.plc.protocol import Fault, Msg, Nak, State
from doodlecam.link.plc.simulator import PlcConfig, PlcSimulator
from doodlecam.link.plc.sender import UdpSender
from doodlecam.link.session import LinkError
from test_udp import assert_drawn_as_planned, bounded, synth_job, wait_for

LEGIT = ("127.0.0.1", 40000)
KEY = b"shared secret of the shop"


class Bench:
    """A simulator driven by hand: ``feed`` datagrams to its handler, ``pump`` answers its requests as a PC would."""

    def __init__(self, data: bytes, key: bytes | None = None, **cfg):
        self.sim = PlcSimulator(PlcConfig(key=key, **cfg))
        self.key = key
        self.now = 0.0
        self.sim._enter(State.A_INIT, 0.0)
        self.sim._tick(0.0)
        assert self.sim.state == State.B_READY
        self.data = data
        self.header, self.arr = read_plc_array(data)
        self.crc = P.job_crc(data)
        self.nonce, self.token, self.job_id, self.seq = 0x5EED_0001_CAFE_F00D, 0x70C3_0000_0000_0001, 77, 0
        self.done = False
        self.sent: list[bytes] = []  # every legit datagram, for replays

    def legit(self, datagram: bytes) -> None:
        self.sent.append(datagram)
        self.sim._handle(datagram, LEGIT, self.now)

    def next_seq(self) -> int:
        self.seq += 1
        return self.seq

    def start(self, start_at: int = 1) -> None:
        resume = P.resume_state(self.arr, self.header.delta_time, start_at)
        h = P.JobHeader.from_plc(self.header, self.crc, start_at, resume, token=self.token)
        self.legit(P.header(self.nonce, self.next_seq(), self.job_id, h, self.key))

    def pump(self, steps: int = 1) -> None:
        """Advance the clock; answer every REQUEST addressed to the PC with DATA."""
        for _ in range(steps):
            self.now += 0.01
            self.sim._tick(self.now)
            for raw, addr in list(self.sim._outbound.due(math.inf)):
                if tuple(addr) != LEGIT:
                    continue
                m = P.decode(raw, self.key)
                if m.type == Msg.DONE and m.job_id == self.job_id:
                    self.done = True
                if m.type == Msg.REQUEST and m.job_id == self.job_id:
                    for first, count in m.ranges:
                        lo, hi = max(first, 1), min(first + count - 1, len(self.arr))
                        for a in range(lo, hi + 1, P.MAX_PER_DATA):
                            b = min(a + P.MAX_PER_DATA - 1, hi)
                            self.legit(P.data(self.nonce, self.next_seq(), self.job_id, self.arr[a - 1:b], self.key))

    def finish(self, max_steps: int = 3000) -> None:
        for _ in range(max_steps):
            if self.done:
                return
            self.pump()
        raise AssertionError(f"job not done: executed {self.sim.job.executed if self.sim.job else '?'}")

    def close(self):
        self.sim.sock.close()
        self.sim.nv.close()


@pytest.fixture
def small_job():
    return synth_job(n_strokes=2, samples=40, seed=7)


def reframe(buf: bytearray, key: bytes | None) -> bytes:
    """Make a (mutated) datagram CRC-correct again; with ``key``, tag it too (a forger's own key)."""
    end = len(buf) - P.CRC.size
    if key and len(buf) >= P.COMMON.size + P.TAG_SIZE + P.CRC.size and buf[20] & P.AUTH:
        buf[end - P.TAG_SIZE:end] = hmac.new(key, bytes(buf[:end - P.TAG_SIZE]), sha256).digest()
    buf[end:] = zlib.crc32(bytes(buf[:end])).to_bytes(4, "little")
    return bytes(buf)


# ---------------------------------------------------------------- the crashes of the issue, one by one

def test_data_whose_numbers_overflow_32_bits_is_invalid_not_a_crash(small_job):
    b = Bench(small_job, buffer_size=32)
    b.start()
    recs = np.zeros(3, RECORD_DTYPE)
    recs["command_no"] = [2**32 - 2, 2**32 - 1, 0]  # first + count overflows
    body = struct.pack("<IHxx", 2**32 - 2, 3) + recs.tobytes()
    b.legit(P.frame(Msg.DATA, b.job_id, b.nonce, b.next_seq(), body))
    assert b.sim.stats["dropped_invalid"] == 1 and b.sim.stats["handler_errors"] == 0
    with pytest.raises(P.ProtocolError, match="outside"):
        P.decode(P.frame(Msg.DATA, 1, 1, 1, body))
    b.finish()
    assert_drawn_as_planned(b.sim, small_job, b.job_id)
    b.close()


@pytest.mark.parametrize("resume", [(math.nan, 0.0), (1e10, 1e10), (-1e300, 5.0), (math.inf, 0.0)])
def test_resume_header_with_non_finite_or_huge_position_is_refused_or_faults(small_job, resume):
    b = Bench(small_job, buffer_size=32)
    _, arr = b.header, b.arr
    start = 5  # a DRAW in the first stroke: the resume needs a re-entry move
    assert arr["type"][start - 1] == P.DRAW
    h = P.JobHeader.from_plc(b.header, b.crc, start, (resume, (100, 100)), token=b.token)
    b.legit(P.header(b.nonce, b.next_seq(), b.job_id, h))
    for _ in range(300):
        b.pump()
    sim = b.sim
    assert sim.stats["handler_errors"] == 0
    if all(map(math.isfinite, resume)):  # accepted, but the re-entry move would leave the area: a fault, no motion
        assert sim.finished[b.job_id][0] == Fault.BOUNDARY and sim.fault_cmd == start
        assert len(sim.executed()) == 0 and np.all(np.isfinite(sim.pos)) and sim._inside(sim.pos, sim.pos)
    else:
        assert sim.stats["bad_headers"] >= 1 and sim.job is None and b.job_id not in sim.finished
    assert sim.state == State.B_READY
    b.close()


def test_stop_with_an_undefined_mode_is_invalid_and_a_later_stop_still_works(small_job):
    b = Bench(small_job, buffer_size=16)
    b.start()
    b.pump(3)
    assert b.sim.job is not None
    b.legit(P.frame(Msg.STOP, b.job_id, b.nonce, b.next_seq(), struct.pack("<B3x", 7)))
    assert b.sim.stats["dropped_invalid"] == 1 and b.sim.job.stop_mode is None
    b.legit(P.stop(b.nonce, b.next_seq(), b.job_id, now=True))
    assert b.sim.job is None and b.sim.held is not None and b.sim.held.reason == Fault.STOPPED
    b.close()


def test_a_hello_with_the_largest_session_id_locks_nobody_out(small_job):
    b = Bench(small_job, buffer_size=32)
    b.sim._handle(P.hello(2**64 - 1, 2**32 - 1), ("127.0.0.9", 999), b.now)
    b.start()  # the next sender still gets the PLC
    b.finish()
    assert_drawn_as_planned(b.sim, small_job, b.job_id)
    b.close()


def test_replayed_datagrams_of_the_bound_session_are_dropped():
    job = synth_job(n_strokes=3, samples=200, seed=8)
    b = Bench(job, buffer_size=16)
    b.start()
    b.pump(3)
    assert b.sim.job is not None
    for d in list(b.sent):
        b.sim._handle(d, LEGIT, b.now)  # the same address, nonce and seq: a replay
    assert b.sim.stats["dropped_replayed"] == len(b.sent)
    b.finish()
    executed = len(b.sim.executed_log)
    for d in list(b.sent):  # the whole session again, after the job ended: nothing runs
        b.sim._handle(d, LEGIT, b.now)
    b.pump(50)
    assert len(b.sim.executed_log) == executed and b.sim.job is None
    assert_drawn_as_planned(b.sim, job, b.job_id)
    b.close()


# ---------------------------------------------------------------- fuzzing

INTERESTING_U32 = [0, 1, 2, 63, 64, 65, 2**16 - 1, 2**31 - 1, 2**31, 2**32 - 64, 2**32 - 2, 2**32 - 1]
INTERESTING_F64 = [math.nan, math.inf, -math.inf, 1e10, -1e10, 1e300, -0.0, 5e-324, 0.04, 1e-9]
ATTACKERS = [("127.0.0.2", 40000), ("127.0.0.1", 40001), ("10.0.0.66", 5005), ("127.0.0.1", 1)]
BATCH = 300
EXAMPLES = 334  # 334 x 300 = 100 200 datagrams per run


def _templates(b: Bench, rng, key, sniffed_token: bool) -> list[bytes]:
    """Well-formed datagrams of every kind, as a forger who sniffed the job id and nonce (and token) would make."""
    nonce = int(rng.choice([b.nonce, rng.integers(1, 2**63)]))
    jid = int(rng.choice([b.job_id, rng.integers(0, 2**32)]))
    seq = int(rng.integers(0, 2**32))
    first = int(rng.integers(1, len(b.arr) + 1))
    count = int(rng.integers(1, P.MAX_PER_DATA + 1))
    recs = np.zeros(count, RECORD_DTYPE)
    recs["command_no"] = np.arange(first, first + count)
    recs["type"] = rng.integers(0, 2, count)
    recs["x"], recs["y"] = rng.integers(-2**31, 2**31, (2, count))
    start = int(rng.integers(1, len(b.arr) + 1))
    h = P.JobHeader.from_plc(b.header, int(rng.choice([b.crc, rng.integers(0, 2**32)])), start,
                             ((float(rng.normal(0, 1e5)), float(rng.normal(0, 1e5))), (0, 0)),
                             token=int(rng.choice([b.token if sniffed_token else 1, rng.integers(0, 2**63)])),
                             flags=int(rng.integers(0, 2)))
    status = P.Status(int(rng.integers(0, 5)), int(rng.integers(0, 8)), 0, 0, 32, 0, 0, 0, 0, 0, 0, 0)
    return [
        P.hello(nonce, seq, jid, key), P.header(nonce, seq, jid, h, key), P.data(nonce, seq, jid, recs, key),
        P.stop(nonce, seq, jid, bool(rng.integers(0, 2)), key), P.cancel(nonce, seq, jid, h.token, key),
        P.plc_message(Msg(int(rng.choice([0x10, 0x11, 0x12, 0x13, 0x14, 0x15]))), nonce, seq, jid, status,
                      ranges=[(first, count)], reason=1, key=key),
    ]


def _mutate(d: bytes, rng, key) -> bytes:
    buf = bytearray(d)
    how = rng.integers(0, 6)
    if how == 0:  # flip bytes of the body / header fields
        for _ in range(int(rng.integers(1, 4))):
            buf[int(rng.integers(0, len(buf) - 4))] ^= int(rng.integers(1, 256))
    elif how == 1 and len(buf) > 32:  # an interesting integer at an aligned offset
        off = 4 * int(rng.integers(1, (len(buf) - 8) // 4))
        buf[off:off + 4] = struct.pack("<I", int(rng.choice(INTERESTING_U32)))
    elif how == 2 and len(buf) > 40:  # an interesting double
        off = 4 * int(rng.integers(1, (len(buf) - 12) // 4))
        buf[off:off + 8] = struct.pack("<d", float(rng.choice(INTERESTING_F64)))
    elif how == 3:  # truncated or extended
        buf = buf[:int(rng.integers(1, len(buf)))] + bytes(4) if rng.integers(0, 2) else buf[:-4] + bytes(8) + buf[-4:]
    elif how == 4:  # another version or type
        buf[2 if rng.integers(0, 2) else 3] = int(rng.integers(0, 256))
    else:  # random bytes behind a valid magic
        buf = bytearray(b"DP" + bytes([P.VERSION]) + rng.integers(0, 256, int(rng.integers(1, 120)), dtype=np.uint8).tobytes()
                        + bytes(4))
    if len(buf) < 4:
        buf += bytes(4)
    return reframe(buf, key)


@settings(max_examples=EXAMPLES, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), keyed=st.booleans())
def test_fuzzed_crc_correct_datagrams_never_crash_or_execute_anything_foreign(seed, keyed):
    """Random and mutated CRC-correct datagrams of every kind, interleaved with a real job.

    Without a key the forger knows the job id and the session nonce but sends
    from another address (same host included) and cannot read the job's owner
    token (who can read the traffic can impersonate the PC: that is what the key
    is for); with a key it also knows the token and may use the PC's own
    address, but has only its own key. The PLC must stay up (no handler error)
    and execute exactly the job's commands, once, on plan.
    """
    rng = np.random.default_rng(seed)
    key = KEY if keyed else None
    b = Bench(synth_job(n_strokes=1, samples=60, seed=seed % 5), key=key, buffer_size=16, starve_timeout=100.0)
    forger_key = b"not the key" if keyed else None
    attackers = ATTACKERS + ([LEGIT] if keyed else [])
    b.start()
    for i in range(BATCH):
        if i % 10 == 0:
            b.pump()
        tpl = _templates(b, rng, forger_key, sniffed_token=keyed)
        d = tpl[int(rng.integers(0, len(tpl)))]
        if rng.random() < 0.8:
            d = _mutate(d, rng, forger_key)
        b.sim._handle(d, attackers[int(rng.integers(0, len(attackers)))], b.now)
    b.finish()
    assert b.sim.stats["handler_errors"] == 0
    assert_drawn_as_planned(b.sim, b.data, b.job_id)
    assert {j for j, _ in b.sim.executed_log} == {b.job_id}
    b.close()
