"""The PLC link on a hostile or faulty network (issue 15): crafted, forged, replayed and fuzzed datagrams.

Two levels. The simulator's datagram handler driven directly (no sockets,
a fake clock) with a job fed by an in-test PC, so 100 000 CRC-correct
fuzzed datagrams run in seconds; and scenarios on real loopback sockets with
the real sender. Every test checks what the PLC *executed* against the file:
each command once, in order, ending where the plan says.
"""

import dataclasses
import types
import hmac
import time
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
from test_udp import assert_drawn_as_planned, bounded, sim_factory as sims, synth_job, wait_for  # noqa: F401

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
        self.bound = 0  # the challenge of the session's HEADER: its DATA carry it
        self.sent: list[bytes] = []  # every legit datagram, for replays

    def legit(self, datagram: bytes) -> None:
        self.sent.append(datagram)
        self.sim._handle(datagram, LEGIT, self.now)

    def next_seq(self) -> int:
        self.seq += 1
        return self.seq

    def challenges(self) -> tuple[int, int]:
        """The PLC's current challenge and the session's: both on the wire for whoever listens."""
        return self.sim.challenge, self.bound

    def start(self, start_at: int = 1) -> None:
        resume = P.resume_state(self.arr, self.header.delta_time, start_at)
        h = P.JobHeader.from_plc(self.header, self.crc, start_at, resume, token=self.token)
        self.bound = self.sim.challenge  # as announced in the PLC's READY
        self.legit(P.header(self.nonce, self.next_seq(), self.job_id, h, self.key, self.bound))

    def pump(self, steps: int = 1) -> None:
        """Advance the clock; answer every REQUEST addressed to the PC with DATA."""
        for _ in range(steps):
            self.now += 0.01
            self.sim._tick(self.now)
            for raw, addr in list(self.sim._outbound.due(math.inf)):
                if tuple(addr) != LEGIT:
                    continue
                try:
                    m = P.decode(raw, self.key)
                except P.AuthError:  # an untagged NAK AUTH_REQUIRED answering a forger's HELLO from our address
                    continue
                if m.type == Msg.DONE and m.job_id == self.job_id:
                    self.done = True
                if m.type == Msg.REQUEST and m.job_id == self.job_id:
                    for first, count in m.ranges:
                        lo, hi = max(first, 1), min(first + count - 1, len(self.arr))
                        for a in range(lo, hi + 1, P.MAX_PER_DATA):
                            b = min(a + P.MAX_PER_DATA - 1, hi)
                            self.legit(P.data(self.nonce, self.next_seq(), self.job_id, self.arr[a - 1:b], self.key,
                                              self.bound))

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
    b.bound = b.sim.challenge
    b.legit(P.header(b.nonce, b.next_seq(), b.job_id, h, challenge=b.bound))
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
    b.legit(P.stop(b.nonce, b.next_seq(), b.job_id, now=True, challenge=b.bound))
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


def test_a_captured_header_replayed_from_another_port_never_moves_the_session():
    """With a key: the job's HEADER, captured and sent again from another port of the same computer (a
    sender restarting would draw a fresh session nonce; a capture cannot), leaves the session where it is, so
    the legitimate sender keeps driving the job to its end with no underrun."""
    job = synth_job(n_strokes=3, samples=200, seed=8)
    b = Bench(job, key=b"k" * 32, buffer_size=16)
    b.start()
    b.pump(3)
    header = b.sent[0]
    session = b.sim.session
    for port in (LEGIT[1] + 1, LEGIT[1] + 2, 1):
        b.sim._handle(header, (LEGIT[0], port), b.now)
        assert b.sim.session == session
    assert b.sim.stats["stale_challenges"] == 3
    b.finish()
    assert b.sim.stats["underruns"] == 0
    assert_drawn_as_planned(b.sim, job, b.job_id)
    b.close()


def test_a_cancel_needs_the_current_challenge_and_uses_it_up():
    job = synth_job(n_strokes=3, samples=200, seed=9)
    b = Bench(job, key=KEY, buffer_size=16)
    b.start()
    b.pump(3)
    jid = b.sim.job.id
    b.legit(P.cancel(b.nonce, b.next_seq(), jid, b.token, KEY, b.bound))  # the session's, used up by its HEADER
    assert b.sim.job is not None and b.sim.stats["stale_challenges"] == 1
    current = b.sim.challenge
    cancel = P.cancel(b.nonce, b.next_seq(), jid, b.token, KEY, current)
    b.legit(cancel)
    assert b.sim.job is None and b.sim.finished[jid][0] == Fault.CANCELLED and b.sim.challenge != current
    b.close()


# ---------------------------------------------------------------- fuzzing

INTERESTING_U32 = [0, 1, 2, 63, 64, 65, 2**16 - 1, 2**31 - 1, 2**31, 2**32 - 64, 2**32 - 2, 2**32 - 1]
INTERESTING_F64 = [math.nan, math.inf, -math.inf, 1e10, -1e10, 1e300, -0.0, 5e-324, 0.04, 1e-9]
ATTACKERS = [("127.0.0.2", 40000), ("127.0.0.1", 40001), ("10.0.0.66", 5005), ("127.0.0.1", 1)]
BATCH = 300
EXAMPLES = 334  # 334 x 300 = 100 200 datagrams per run


def _templates(b: Bench, rng, key, sniffed_token: bool) -> list[bytes]:
    """Well-formed datagrams of every kind, as a forger who sniffed the job id, nonce and challenges (and token)
    would make."""
    nonce = int(rng.choice([b.nonce, rng.integers(1, 2**63)]))
    challenge = int(rng.choice([*b.challenges(), rng.integers(0, 2**63)]))
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
        P.hello(nonce, seq, jid, key, challenge), P.header(nonce, seq, jid, h, key, challenge),
        P.data(nonce, seq, jid, recs, key, challenge), P.stop(nonce, seq, jid, bool(rng.integers(0, 2)), key, challenge),
        P.cancel(nonce, seq, jid, h.token, key, challenge),
        P.plc_message(Msg(int(rng.choice([0x10, 0x11, 0x12, 0x13, 0x14, 0x15]))), nonce, seq, jid, status,
                      ranges=[(first, count)], reason=1, key=key, challenge=challenge),
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


# ---------------------------------------------------------------- scenarios on loopback sockets

class RecordingSim(PlcSimulator):
    """Keeps every datagram it receives, with its source: a captured session to replay."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.captured: list[tuple[bytes, tuple]] = []

    def _handle(self, data, addr, now):
        self.captured.append((data, addr))
        super()._handle(data, addr, now)


def _forger(sim: PlcSimulator, data: bytes, stop, seed: int) -> int:
    """A second UDP socket on 127.0.0.1 forging DATA / STOP / CANCEL / HEADER for the running job id,
    plus mutated CRC-correct datagrams of every kind."""
    import socket as so
    import types

    rng = np.random.default_rng(seed)
    header, arr = read_plc_array(data)
    sent = 0
    with so.socket(so.AF_INET, so.SOCK_DGRAM) as s:
        while not stop.is_set():
            job = sim.job
            if job is None:
                stop.wait(0.002)
                continue
            recs = np.zeros(64, RECORD_DTYPE)
            first = job.executed + 1
            recs["command_no"] = np.arange(first, first + 64)
            recs["type"] = rng.integers(0, 2, 64)
            recs["x"], recs["y"] = rng.integers(0, 20000, (2, 64))
            nonce = sim.session[1] if sim.session else 1  # even the sniffed nonce and challenges, from another address
            bound = sim.session[2] if sim.session else 1
            forged = dataclasses.replace(job.h, token=int(rng.integers(1, 2**63)))  # the token is not sniffed
            seen = types.SimpleNamespace(nonce=nonce, job_id=job.id, token=0, arr=arr, header=header,
                                         crc=job.h.job_crc, challenges=lambda: (sim.challenge, bound))
            fuzzed = [_mutate(d, rng, None) for d in _templates(seen, rng, None, sniffed_token=False)]
            for d in (P.data(nonce, sent + 1, job.id, recs, challenge=bound),
                      P.stop(nonce, sent + 2, job.id, True, challenge=bound),
                      P.cancel(nonce, sent + 3, job.id, 12345, challenge=sim.challenge),
                      P.header(nonce, sent + 4, job.id, forged, challenge=sim.challenge), *fuzzed):
                s.sendto(d, sim.address)
                sent += 1
            stop.wait(0.002)
    return sent


def test_forged_stream_from_another_socket_executes_nothing(sims):
    import threading

    data = synth_job(n_strokes=25, samples=98, seed=11)
    sim = sims(speed=40.0)  # ~2.5 s of wall time under fire
    stop = threading.Event()
    box = {}
    t = threading.Thread(target=lambda: box.update(sent=_forger(sim, data, stop, 1)), daemon=True)
    t.start()
    try:
        r = bounded(lambda: UdpSender(*sim.address, data, timeout=5.0, rto=0.05).run(), 120)
    finally:
        stop.set()
        t.join(5)
    assert box["sent"] > 100 and sim.stats["dropped_foreign"] > 0
    assert sim.stats["handler_errors"] == 0
    assert_drawn_as_planned(sim, data, r.job_id)


def test_second_sender_is_told_busy_and_the_first_is_undisturbed(sims, tmp_path):
    import threading

    data = synth_job(n_strokes=40, samples=98, seed=12)
    sim = sims(speed=40.0)  # ~4 s of wall time: long enough for a second sender to try
    first = UdpSender(*sim.address, data, state_file=tmp_path / "a.json", timeout=5.0, rto=0.05)
    box = {}
    t = threading.Thread(target=lambda: box.update(r=first.run()), daemon=True)
    t.start()
    wait_for(lambda: sim.state == State.D_OPERATING, 10, "the first job running")
    port = first.sock.getsockname()[1]
    for other in (synth_job(n_strokes=2, seed=99), data):  # another job, and the same file without its record
        with pytest.raises(LinkError, match=rf"busy: job {sim.job.id} from 127\.0\.0\.1:{port} is running"):
            bounded(lambda: UdpSender(*sim.address, other, state_file=tmp_path / "b.json", timeout=3.0).run(), 20)
    with pytest.raises(LinkError, match="only the computer that started a job can stop or cancel it"):
        bounded(lambda: UdpSender(*sim.address, data, state_file=tmp_path / "b.json", timeout=3.0).cancel(), 20)
    t.join(120)
    assert "r" in box, "the first sender did not finish"
    assert sim.peer[1] == port and sim.stats["refused_busy"] >= 2
    assert_drawn_as_planned(sim, data, box["r"].job_id)


def test_replayed_session_and_a_finished_job_never_run_again_even_after_a_restart(sims, tmp_path):
    import socket as so

    data = synth_job(n_strokes=5, samples=98, seed=13)
    nv = tmp_path / "plc.nv"
    sim = sims(RecordingSim, state_file=nv)
    r = bounded(lambda: UdpSender(*sim.address, data, state_file=tmp_path / "j.json", timeout=5.0).run())
    assert_drawn_as_planned(sim, data, r.job_id)
    n = len(sim.executed_log)

    def replay(target):
        with so.socket(so.AF_INET, so.SOCK_DGRAM) as s:
            for d, _ in list(sim.captured):
                s.sendto(d, target.address)
        time.sleep(0.5)

    replay(sim)
    assert len(sim.executed_log) == n
    # The same file again (its record was deleted on success): refused, saying when it finished.
    with pytest.raises(LinkError, match=r"already finished .* on \d{4}-\d\d-\d\d .*add --again"):
        bounded(lambda: UdpSender(*sim.address, data, state_file=tmp_path / "k.json", timeout=3.0).run())
    sim.stop()  # a power cycle: a new PLC on the same non-volatile memory
    sim2 = sims(state_file=nv)
    sim.address = sim2.address
    replay(sim2)
    assert len(sim2.executed_log) == 0 and sim2.stats["sent_NAK"] >= 1
    with pytest.raises(LinkError, match="already finished"):
        bounded(lambda: UdpSender(*sim2.address, data, state_file=tmp_path / "k.json", timeout=3.0).run())
    r2 = bounded(lambda: UdpSender(*sim2.address, data, state_file=tmp_path / "k.json", timeout=5.0,
                                   again=True).run())
    assert r2.job_id != r.job_id
    assert_drawn_as_planned(sim2, data, r2.job_id)


def _replay(capture: list[tuple[bytes, tuple]], sim: PlcSimulator) -> None:
    """Send a captured session to ``sim`` again, from the address it came from when that port is free
    (else from another port of the same host), and wait until the PLC has read every datagram."""
    import socket as so

    seen = len(sim.captured)
    with so.socket(so.AF_INET, so.SOCK_DGRAM) as s:
        try:
            s.bind(capture[0][1])
        except OSError:
            s.bind(("127.0.0.1", 0))
        for d, _ in capture:
            s.sendto(d, sim.address)
            time.sleep(0.0002)  # as fast as a sender; the PLC's socket buffer keeps every one
    wait_for(lambda: len(sim.captured) >= seen + len(capture), 10, "the replay read by the PLC")
    time.sleep(0.5)  # time to act on it: run, request, execute


def test_a_captured_keyed_session_never_runs_again_after_70_jobs_or_a_restart(sims, tmp_path):
    """The issue's case: with a key and a state file, after 64 other jobs the PLC has forgotten a finished
    job, and a replay of its captured session ran all its commands again. Each session is now bound to a
    challenge the PLC drew for it: the captured HEADER carries a challenge that is not the PLC's current
    one, so nothing starts, and the captured DATA belong to no session."""
    data = synth_job(n_strokes=6, samples=98, seed=19)  # 595 commands
    nv = tmp_path / "plc.nv"
    sim = sims(RecordingSim, key=KEY, state_file=nv)
    r = bounded(lambda: UdpSender(*sim.address, data, state_file=tmp_path / "j.json", key=KEY).run())
    assert_drawn_as_planned(sim, data, r.job_id)
    capture = list(sim.captured)
    assert sum(d[3] == Msg.DATA for d, _ in capture) >= 10
    for i in range(70):
        other = synth_job(n_strokes=1, samples=8, seed=1000 + i)
        bounded(lambda: UdpSender(*sim.address, other, state_file=tmp_path / "o.json", key=KEY).run())
    assert r.job_id not in sim.finished and len(sim.finished) == 64  # forgotten: only the challenge is left
    before = len(sim.executed_log)
    _replay(capture, sim)
    assert len(sim.executed_log) == before and sim.job is None and sim.held is None
    assert sim.stats["stale_challenges"] >= 1 and sim.stats["handler_errors"] == 0
    sim.stop()  # a power cycle: the same non-volatile memory, a new challenge
    sim2 = sims(RecordingSim, key=KEY, state_file=nv)
    _replay(capture, sim2)
    assert len(sim2.executed_log) == 0 and sim2.job is None and sim2.held is None
    assert sim2.stats["stale_challenges"] >= 1
    # The legitimate sender is unaffected: the same file again (with --again) draws it once more.
    r2 = bounded(lambda: UdpSender(*sim2.address, data, state_file=tmp_path / "k.json", key=KEY, again=True).run())
    assert_drawn_as_planned(sim2, data, r2.job_id)


def test_a_captured_session_never_runs_on_a_plc_that_forgot_everything(sims, tmp_path):
    """Without a key and without non-volatile memory (the issue: 257 commands ran again after a restart):
    the restarted PLC draws a new challenge, so the capture still runs nothing."""
    data = synth_job(n_strokes=3, samples=98, seed=20)
    sim = sims(RecordingSim)
    r = bounded(lambda: UdpSender(*sim.address, data, timeout=5.0).run())
    assert_drawn_as_planned(sim, data, r.job_id)
    capture = list(sim.captured)
    sim.stop()
    sim2 = sims(RecordingSim)
    assert sim2.finished == {}
    _replay(capture, sim2)
    assert len(sim2.executed_log) == 0 and sim2.job is None


def test_a_restarted_sender_re_attaches_and_a_replayed_header_does_not(sims, tmp_path):
    """With a key, while the PLC runs a job: a second run of the same sender (same record: job id and token)
    takes the session over with the PLC's current challenge; the first run's captured HEADER, played back
    from another port of the same computer afterwards, leaves the session with the second run."""
    import threading

    data = synth_job(n_strokes=20, samples=98, seed=23)
    sim = sims(RecordingSim, key=KEY, speed=20.0)
    rec = tmp_path / "job.json"
    first = UdpSender(*sim.address, data, state_file=rec, key=KEY, timeout=2.0, rto=0.05)
    box = {}

    def run_first():
        try:
            first.run()
        except LinkError as e:  # the PLC talks to the second run now: this one hears nothing more
            box["first"] = str(e)

    t = threading.Thread(target=run_first, daemon=True)
    t.start()
    wait_for(lambda: len(sim.executed_log) > 200, 30, "the job under way")
    capture = [(d, a) for d, a in sim.captured if d[3] == Msg.HEADER]
    second = UdpSender(*sim.address, data, state_file=rec, key=KEY, timeout=5.0, rto=0.05)
    t2 = threading.Thread(target=lambda: box.update(r=second.run()), daemon=True)
    t2.start()
    wait_for(lambda: sim.session and sim.session[1] == second.session, 10, "the second run bound")
    bound = sim.session
    _replay(capture, sim)
    assert sim.session == bound and sim.stats["stale_challenges"] >= 1
    t2.join(60)
    t.join(10)
    assert "r" in box, "the second run did not finish"
    assert_drawn_as_planned(sim, data, box["r"].job_id)


def test_power_cycle_mid_job_is_reported_and_the_resume_repeats_nothing(sims, tmp_path):
    import threading

    data = synth_job(n_strokes=30, samples=98, seed=14)
    nv, rec = tmp_path / "plc.nv", tmp_path / "job.json"
    sim = sims(state_file=nv, speed=25.0)
    box = {}

    def run():
        try:
            UdpSender(*sim.address, data, state_file=rec, timeout=5.0, rto=0.05).run()
        except LinkError as e:
            box["error"] = str(e)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    wait_for(lambda: len(sim.executed_log) > 500, 30, "half the job")
    port = sim.address[1]
    sim.stop()
    sim2 = sims(state_file=nv, port=port, speed=25.0)
    t.join(30)
    assert "the PLC at" in box["error"] and "restarted during the job" in box["error"]
    assert sim2.held is not None and sim2.held.reason == Fault.POWER_LOST
    r = bounded(lambda: UdpSender(*sim2.address, data, state_file=rec, timeout=5.0, rto=0.05).run(), 120)
    header, arr = read_plc_array(data)
    executed = np.concatenate([sim.executed(r.job_id), sim2.executed(r.job_id)])
    np.testing.assert_array_equal(executed, np.arange(1, len(arr) + 1))  # every command exactly once
    assert r.start_at == len(sim.executed(r.job_id)) + 1
    # From the resume on, every command ends on the plan (the re-entry is a checked MOVE).
    tr = sim2.trajectory()
    tr = tr[tr["type"] >= 0]
    pos, _ = P.planned_states(arr, header.delta_time)
    np.testing.assert_allclose(np.column_stack([tr["x"], tr["y"]]), pos[r.start_at - 1:], atol=1e-6)


def test_hmac_session_and_key_mismatches(sims, tmp_path):
    data = synth_job(n_strokes=3, samples=98, seed=15)
    sim = sims(key=KEY)
    with pytest.raises(LinkError, match="requires a key"):
        bounded(lambda: UdpSender(*sim.address, data, timeout=1.0).run())
    with pytest.raises(LinkError, match="answers, but not with this key"):
        bounded(lambda: UdpSender(*sim.address, data, timeout=1.0, key=b"wrong").run())
    assert sim.stats["dropped_unauthenticated"] > 0 and len(sim.executed_log) == 0
    r = bounded(lambda: UdpSender(*sim.address, data, timeout=5.0, key=KEY).run())
    assert_drawn_as_planned(sim, data, r.job_id)


def test_old_protocol_version_is_declined_clearly(sims):
    import socket as so

    sim = sims()
    v1 = bytearray(P.hello(1, 1))
    v1[2] = 1
    with so.socket(so.AF_INET, so.SOCK_DGRAM) as s:
        s.sendto(reframe(v1, None), sim.address)
    wait_for(lambda: sim.stats["dropped_old_version"] == 1, 5, "the v1 datagram counted")
    with pytest.raises(P.OldVersion, match="protocol version 1"):
        P.decode(reframe(v1, None))


class _Deaf(UdpSender):
    """Hears nothing from the PLC for ``deaf`` s once the job runs (a network blackout one way)."""

    deaf, deaf_from, after = 0.0, None, 300

    def _recv(self, wait):
        m = super()._recv(wait)
        now = time.monotonic()
        if self.deaf_from is None and self.executed > self.after:
            self.deaf_from = now
        if self.deaf_from is not None and now - self.deaf_from < self.deaf:
            self.last_heard = min(self.last_heard, self.deaf_from)
            return None
        return m


def test_time_out_follows_the_buffer_not_just_the_timeout(sims):
    data = synth_job(n_strokes=8, samples=98, seed=16)
    sim = sims(speed=8.0, buffer_size=256)  # 256 commands x 40 ms = 10 s simulated = 1.3 s of wall time
    s = _Deaf(*sim.address, data, timeout=0.3, rto=0.05)
    s.deaf = 0.9  # three times --timeout, shorter than the PLC's buffer
    r = bounded(s.run, 120)
    assert s.deaf_from is not None
    assert_drawn_as_planned(sim, data, r.job_id)
    # The patience is --timeout plus the planned time of the buffered commands.
    st = P.Status(State.D_OPERATING, 0, 1, 0, 256, 100, 356, 0, 0, 0, 0, 0)
    s.last_status = st
    d = P.command_durations(s.records, s.plc_header)
    assert s._patience() == pytest.approx(0.3 + d[100:356].sum())


def test_sender_declines_a_version_1_plc_with_one_clear_line():
    import socket as so
    import threading

    data = synth_job(n_strokes=1, samples=20, seed=17)
    with so.socket(so.AF_INET, so.SOCK_DGRAM) as plc:
        plc.bind(("127.0.0.1", 0))
        plc.settimeout(5)

        def answer_like_v1():
            _, addr = plc.recvfrom(2048)
            v1 = bytearray(P.plc_message(Msg.READY, 7, 1, 0, P.Status(state=State.B_READY)))
            v1[2] = 1
            plc.sendto(reframe(v1, None), addr)

        t = threading.Thread(target=answer_like_v1, daemon=True)
        t.start()
        with pytest.raises(LinkError, match=f"speaks protocol version 1, this doodlecam speaks {P.VERSION}; update the PLC"):
            bounded(lambda: UdpSender(*plc.getsockname(), data, timeout=3.0).run())
        t.join(5)


def test_sender_survives_fuzzed_plc_datagrams_with_one_line_errors_only():
    """The PC side of the same fuzzing: 5 000 CRC-correct random and mutated PLC messages of every kind
    through the sender's receive path (real sockets): only LinkError (a one-line error) may come out."""
    import socket as so

    data = synth_job(n_strokes=2, samples=40, seed=18)
    rng = np.random.default_rng(18)
    with so.socket(so.AF_INET, so.SOCK_DGRAM) as plc:
        plc.bind(("127.0.0.1", 0))
        plc.setblocking(False)
        s = UdpSender(*plc.getsockname(), data, timeout=1.0)
        s._open()
        s.job_id, s.token = 77, 5
        b = types.SimpleNamespace(nonce=1, job_id=77, token=5, arr=read_plc_array(data)[1],
                                  header=read_plc_array(data)[0], crc=s.crc, challenges=lambda: (1, 2))
        errors = handled = 0
        try:
            for i in range(5000):
                tpl = _templates(b, rng, None, sniffed_token=True)
                d = tpl[-1] if rng.random() < 0.7 else tpl[int(rng.integers(0, len(tpl)))]
                if rng.random() < 0.7:
                    d = _mutate(d, rng, None)
                plc.sendto(d, s.sock.getsockname())
                s.last_seq = 0  # fuzzed seq numbers are random: let each one through to the logic
                try:
                    m = s._recv(0.05)
                    if m is not None:
                        handled += 1
                        s._on_message(m)
                except LinkError:
                    errors += 1
                    s.boot = None  # carry on as a fresh run would
                try:
                    while True:
                        plc.recv(2048)  # drop the sender's DATA answers
                except BlockingIOError:
                    pass
        finally:
            s.sock.close()
    print(f"{handled} handled, {errors} one-line errors")
    assert handled >= 1000 and errors >= 1  # the logic was reached, faults and restarts were among them
