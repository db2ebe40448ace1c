"""The PLC link over real UDP sockets on 127.0.0.1: wire format, simulator, sender, CLI.

Every test is bounded in time (socket timeouts, subprocess timeouts, polling
deadlines), so a broken link fails instead of hanging.
"""

import math
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from doodlecam.link.plc import protocol as P
from doodlecam.link.plc.packetfile import DRAW, MOVE, RECORD_DTYPE, PlcHeader, read_plc_array, write_plc
from doodlecam.link.plc.protocol import Fault, Msg, State
from doodlecam.link.plc.simulator import REENTRY_ROW, STOP_ROW, PlcConfig, PlcSimulator
from doodlecam.link.plc.network import Impairments
from doodlecam.link.session import LinkError, load_state
from doodlecam.link.plc.sender import UdpSender

ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONWARNINGS="ignore")


def synth_job(n_strokes=100, samples=98, seed=0, width=32000, height=24000, dt=0.04, outside=None) -> bytes:
    """A .plc job: strokes of smooth velocity samples from rest to rest, inside the area; then home.

    ``outside = (i, (x, y))`` replaces command i (0-based) by a MOVE to (x, y) steps.
    """
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(n_strokes):
        start = rng.uniform([6000, 6000], [width - 6000, height - 6000])
        rows.append((MOVE, *np.round(start)))
        k = np.arange(1, samples + 1)
        env = np.sin(np.pi * k / samples)
        v = env[:, None] * np.sin(2 * np.pi * rng.uniform(1, 4, 2) * k[:, None] / samples + rng.uniform(0, 6.3, 2))
        reach = np.abs(np.cumsum(v, axis=0) * dt).max()
        v = np.round(v * min(8000.0, 5000.0 / max(reach, 1e-9)))
        v[-1] = 0
        rows += [(DRAW, vx, vy) for vx, vy in v]
    rows.append((MOVE, 0, 0))
    if outside is not None:
        rows[outside[0]] = (MOVE, *outside[1])
    arr = np.zeros(len(rows), RECORD_DTYPE)
    arr["command_no"] = np.arange(1, len(rows) + 1)
    t = np.array(rows)
    arr["type"], arr["x"], arr["y"] = t[:, 0], t[:, 1], t[:, 2]
    return write_plc(PlcHeader(dt, len(rows), 160000, 160000, 12000, 12000, 80.0, 80.0), arr)


def assert_drawn_as_planned(sim: PlcSimulator, data: bytes, job_id: int) -> None:
    """Every command executed once, in order, and each ended where the plan says (steps)."""
    header, arr = read_plc_array(data)
    np.testing.assert_array_equal(sim.executed(job_id), np.arange(1, len(arr) + 1))
    tr = sim.trajectory()
    tr = tr[tr["type"] >= 0]
    pos, vel = P.planned_states(arr, header.delta_time)
    np.testing.assert_allclose(np.column_stack([tr["x"], tr["y"]]), pos, atol=1e-6)
    np.testing.assert_allclose(np.column_stack([tr["vx"], tr["vy"]]), vel, atol=1e-9)
    assert np.all(tr["pen"] == (arr["type"] == DRAW))  # pen down exactly for DRAW


def wait_for(pred, timeout, what):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


def bounded(fn, timeout=60.0):
    """Run fn() in a thread; fail (instead of hanging the suite) if it takes longer than timeout."""
    import threading

    box = {}

    def target():
        try:
            box["value"] = fn()
        except BaseException as e:  # re-raised in the test's thread
            box["error"] = e

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(timeout)
    if t.is_alive():
        raise AssertionError(f"did not finish within {timeout} s")
    if "error" in box:
        raise box["error"]
    return box["value"]


@pytest.fixture
def sim_factory():
    sims = []

    def make(cls=PlcSimulator, **kw):
        sim = cls(PlcConfig(**kw)).start()
        sims.append(sim)
        return sim

    yield make
    for s in sims:
        s.stop()


# ---------------------------------------------------------------- wire format

status_st = st.builds(P.Status, state=st.integers(0, 4), fault=st.integers(0, 7), pen=st.integers(0, 1),
                      flags=st.integers(0, 1), buffer_size=st.integers(1, 2**32 - 1),
                      executed=st.integers(0, 2**32 - 1), buffered=st.integers(0, 2**32 - 1),
                      fault_command=st.integers(0, 2**32 - 1), x=st.integers(-2**31, 2**31 - 1),
                      y=st.integers(-2**31, 2**31 - 1), last_done_job=st.integers(0, 2**32 - 1),
                      job_crc=st.integers(0, 2**32 - 1))


@settings(max_examples=60, deadline=None)
@given(status=status_st, ranges=st.lists(st.integers(1, 2**32 - 1).flatmap(
           lambda f: st.tuples(st.just(f), st.integers(1, 2**32 - f))), max_size=16),
       origin=st.integers(0, 2**64 - 1), seq=st.integers(0, 2**32 - 1), job=st.integers(0, 2**32 - 1),
       flip=st.integers(0, 10**6))
def test_plc_messages_round_trip_and_any_bit_flip_is_rejected(status, ranges, origin, seq, job, flip):
    d = P.plc_message(Msg.REQUEST, origin, seq, job, status, ranges=ranges)
    m = P.decode(d)
    assert (m.type, m.origin, m.seq, m.job_id, m.status, list(m.ranges)) == (Msg.REQUEST, origin, seq, job, status, ranges)
    bad = bytearray(d)
    bad[flip % len(d)] ^= 1 << (flip % 8)
    with pytest.raises(P.ProtocolError):
        P.decode(bytes(bad))
    with pytest.raises(P.ProtocolError):
        P.decode(d[:-1])  # truncated


@settings(max_examples=40, deadline=None)
@given(first=st.integers(1, 10**6), count=st.integers(1, P.MAX_PER_DATA), seed=st.integers(0, 2**32 - 1))
def test_data_round_trip_keeps_numbering(first, count, seed):
    rng = np.random.default_rng(seed)
    recs = np.zeros(count, RECORD_DTYPE)
    recs["command_no"] = np.arange(first, first + count)
    recs["type"] = rng.integers(0, 2, count)
    recs["x"], recs["y"] = rng.integers(-2**31, 2**31 - 1, (2, count))
    d = P.data(5, 6, 7, recs)
    assert len(d) <= P.MAX_DATAGRAM
    m = P.decode(d)
    assert m.first == first and np.array_equal(m.records, recs)
    # Records whose numbers do not follow 'first' are refused (even with a valid CRC).
    if count > 1:
        recs2 = recs.copy()
        recs2["command_no"][[0, 1]] = recs2["command_no"][[1, 0]]
        body = bytearray(P.data(5, 6, 7, recs2))
        import zlib

        body[P.COMMON.size:P.COMMON.size + 4] = int(first).to_bytes(4, "little")
        body[-4:] = zlib.crc32(bytes(body[:-4])).to_bytes(4, "little")
        with pytest.raises(P.ProtocolError):
            P.decode(bytes(body))


def test_header_round_trip():
    h = P.JobHeader(0xDEADBEEF, 12345, 77, 0.04, 80.0, 81.5, 160000, 150000, 12000, 11000, 123.25, -4.5, 1600, -800)
    m = P.decode(P.header(2**63 + 5, 9, 42, h))
    assert m.type == Msg.HEADER and m.header == h and m.job_id == 42


def test_planned_states_follow_the_ramp_model():
    """planned_states against a plain loop over the documented semantics (docs/formats.md)."""
    data = synth_job(n_strokes=3, samples=20, seed=3)
    header, arr = read_plc_array(data)
    pos, vel = P.planned_states(arr, header.delta_time)
    p, v = np.zeros(2), np.zeros(2)
    for i, r in enumerate(arr):
        if r["type"] == MOVE:
            p, v = np.array([r["x"], r["y"]], float), np.zeros(2)
        else:
            nv = np.array([r["x"], r["y"]], float)
            p, v = p + 0.5 * header.delta_time * (v + nv), nv
        np.testing.assert_allclose(pos[i], p, atol=1e-9)
        np.testing.assert_allclose(vel[i], v)
        if i + 2 <= len(arr):
            (rx, ry), (rvx, rvy) = P.resume_state(arr, header.delta_time, i + 2)
            np.testing.assert_allclose([rx, ry, rvx, rvy], [*p, *v], atol=1e-9)


# ---------------------------------------------------------------- the link

def test_lossy_network_executes_every_command_exactly_once_in_order(sim_factory, tmp_path):
    """20 % loss, duplication, reordering, corruption and delay in both directions: 10 000 commands arrive intact."""
    data = synth_job(n_strokes=101, samples=98, seed=1)  # 101 strokes * 99 commands + home
    n = read_plc_array(data)[0].no_commands
    assert n == 10000
    imp = Impairments(loss=0.2, dup=0.1, reorder=0.1, corrupt=0.01, delay=0.001, jitter=0.002, seed=7)
    sim = sim_factory(rto=0.02, ready_interval=0.05, status_interval=0.1, impair=imp)
    state = tmp_path / "job.plc.send.json"
    r = bounded(UdpSender(*sim.address, data, state_file=state, timeout=5.0, rto=0.03).run)
    assert r.executed == n and not r.resumed
    assert_drawn_as_planned(sim, data, r.job_id)
    net = sim._inbound.stats + sim._outbound.stats
    assert net["lost"] > 50 and net["duplicated"] > 10 and net["reordered"] > 10 and net["corrupted"] > 0
    assert sim.stats["dropped_invalid"] + r.stats["invalid_received"] > 0  # corrupt datagrams were seen and dropped
    # duplicates reached the PLC and were ignored: by the session's sequence window, or as commands it has
    assert sim.stats["dup_or_late_commands"] + sim.stats["dropped_replayed"] > 0
    assert sim.stats["rerequested_commands"] > 0  # losses were repaired by re-requests
    assert not state.exists()  # a finished job leaves no resume record


def test_killed_sender_resumes_without_repeating_a_command(sim_factory, tmp_path):
    """SIGKILL the sending process mid-job; the PLC stops when its buffer runs dry; a new sender resumes."""
    data = synth_job(n_strokes=10, samples=300, seed=2)
    job = tmp_path / "kill.plc"
    job.write_bytes(data)
    sim = sim_factory(speed=50.0, starve_timeout=0.3, buffer_size=128)
    cmd = [sys.executable, "-m", "doodlecam", "send", str(job), "--udp", f"127.0.0.1:{sim.address[1]}", "--no-progress",
           "--no-auth"]  # an in-process PLC without a key
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV, cwd=ROOT)
    try:
        wait_for(lambda: len(sim.executed_log) >= 700, 30, "the job to get going")
    finally:
        p.kill()
        p.communicate(timeout=10)
    saved = load_state(tmp_path / "kill.plc.send.json", P.job_crc(data))
    assert saved is not None and saved["executed"] >= 1  # the record was written while running
    wait_for(lambda: sim.held is not None, 10, "the PLC to hold the job")
    held = sim.held
    assert held.reason == Fault.UNDERRUN and held.next > 700
    assert len(sim.executed_log) == held.next - 1
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60)
    assert r.returncode == 0, r.stderr
    assert f"resumed at command {held.next}" in r.stdout
    job_id = sim.executed_log[0][0]
    assert_drawn_as_planned(sim, data, job_id)
    kinds = sim.trajectory()["type"]
    if np.any(kinds == STOP_ROW):  # it ran dry mid-stroke: stopped, then re-entered the stroke
        assert np.any(kinds == REENTRY_ROW)
    assert not (tmp_path / "kill.plc.send.json").exists()


def test_ctrl_c_pauses_at_the_end_of_a_stroke_and_resumes(sim_factory, tmp_path):
    data = synth_job(n_strokes=12, samples=60, seed=4)
    job = tmp_path / "pause.plc"
    job.write_bytes(data)
    header, arr = read_plc_array(data)
    sim = sim_factory(speed=20.0)
    cmd = [sys.executable, "-m", "doodlecam", "send", str(job), "--udp", f"127.0.0.1:{sim.address[1]}", "--no-progress",
           "--no-auth"]  # an in-process PLC without a key
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
    try:
        wait_for(lambda: len(sim.executed_log) >= 100, 30, "the job to get going")
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
    finally:
        p.kill()
    assert p.returncode == 130, err
    assert "paused before command" in err and "Traceback" not in err
    held = sim.held
    assert held is not None and held.reason == Fault.STOPPED
    assert arr["type"][held.next - 1] == MOVE  # stopped where a stroke ended, pen up
    assert not sim.pen and not np.any(sim.vel)
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60)
    assert r.returncode == 0, r.stderr
    assert_drawn_as_planned(sim, data, sim.executed_log[0][0])
    assert not np.any(sim.trajectory()["type"] == STOP_ROW)  # a clean stop needs no emergency deceleration


class _StallingSender(UdpSender):
    """Answers requests only up to ``limit`` until the PLC runs dry; then behaves."""

    limit = 10**9

    def _send_range(self, first, count):
        hi = min(first + count - 1, self.limit)
        if hi >= first:
            super()._send_range(first, hi - first + 1)

    def _start(self, start_at):
        if start_at > 1:
            self.limit = 10**9
        super()._start(start_at)


class _GaveUp(Exception):
    pass


class _GiveUpSender(_StallingSender):
    """Walks away instead of resuming once the PLC holds the job."""

    def _start(self, start_at):
        if start_at > 1:
            raise _GaveUp
        UdpSender._start(self, start_at)


def test_underrun_mid_stroke_stops_and_reenters_on_the_plan(sim_factory):
    data = synth_job(n_strokes=3, samples=200, seed=5)
    header, arr = read_plc_array(data)
    sim = sim_factory(starve_timeout=0.2)
    s = _StallingSender(*sim.address, data, timeout=5.0, rto=0.05)
    s.limit = 250  # in the middle of the second stroke, moving
    r = bounded(s.run)
    assert r.underruns == 1
    kinds = sim.trajectory()["type"]
    assert np.sum(kinds == STOP_ROW) == 1 and np.sum(kinds == REENTRY_ROW) == 1
    assert_drawn_as_planned(sim, data, r.job_id)  # every command ends exactly on the plan, after the re-entry too


def test_boundary_fault_stops_before_the_command(sim_factory, tmp_path):
    data = synth_job(n_strokes=3, samples=40, seed=6, outside=(41, (40000, 100)))  # a MOVE past x = 32000
    sim = sim_factory()
    with pytest.raises(LinkError, match=r"PLC fault at command 42 of .*boundary"):
        bounded(UdpSender(*sim.address, data, state_file=tmp_path / "s.json", timeout=3.0).run)
    assert sim.executed().max() == 41 and sim.state == State.B_READY and sim.fault == Fault.BOUNDARY
    assert sim.pos[0] <= sim.cfg.width  # it never left the work area


def test_limit_switch_trips_without_soft_limits_and_forces_reinit(sim_factory):
    data = synth_job(n_strokes=3, samples=40, seed=6, outside=(41, (40000, 100)))
    sim = sim_factory(soft_limits=False, init_time=0.3)
    with pytest.raises(LinkError, match="limit switch"):
        bounded(UdpSender(*sim.address, data, timeout=3.0).run)
    tr = sim.trajectory()
    stop = tr[tr["type"] == STOP_ROW]
    assert len(stop) == 1 and stop["command_no"][0] == 42
    assert stop["x"][0] == pytest.approx(sim.cfg.width + sim.cfg.switch_margin)  # stopped at the switch
    assert any("POWER_ON" in e for _, e in sim.events) and any("A_INIT" in e for _, e in sim.events[-3:])


def test_finished_job_is_never_run_again_by_a_late_header(sim_factory):
    data = synth_job(n_strokes=2, samples=20, seed=8)
    sim = sim_factory()
    r = bounded(UdpSender(*sim.address, data, timeout=3.0).run)
    n_before = len(sim.executed_log)
    # Replay the job's header as a late duplicate would arrive: the PLC refuses it.
    header, arr = read_plc_array(data)
    late = P.header(1, 1, r.job_id, P.JobHeader.from_plc(header, P.job_crc(data)))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(2.0)
        s.sendto(P.hello(time.time_ns() // 1000 + 10**9, 1), sim.address)
        s.sendto(late, sim.address)  # an older session: ignored outright
        s.sendto(P.header(time.time_ns() // 1000 + 2 * 10**9, 2, r.job_id,
                          P.JobHeader.from_plc(header, P.job_crc(data))), sim.address)
        kinds = []
        end = time.monotonic() + 2
        while time.monotonic() < end and Msg.NAK not in kinds:
            m = P.decode(s.recv(65536))
            kinds.append(m.type)
        assert Msg.NAK in kinds and m.reason == P.Nak.FINISHED
    time.sleep(0.1)
    assert len(sim.executed_log) == n_before and sim.state == State.B_READY


def test_cancel_forgets_a_held_job(sim_factory, tmp_path):
    data = synth_job(n_strokes=3, samples=200, seed=5)
    sim = sim_factory(starve_timeout=0.2)
    s = _GiveUpSender(*sim.address, data, state_file=tmp_path / "c.json", timeout=5.0)
    s.limit = 250
    with pytest.raises(_GaveUp):
        bounded(s.run)  # leaves once the PLC holds the job
    wait_for(lambda: sim.held is not None, 5, "a held job")
    held_id = sim.held.id
    # Without the record of starting it (its owner token), nobody else can cancel it.
    with pytest.raises(LinkError, match="only the computer that started a job can cancel it"):
        bounded(UdpSender(*sim.address, data, state_file=tmp_path / "other.json", timeout=3.0).cancel)
    assert sim.held is not None
    assert bounded(UdpSender(*sim.address, data, state_file=tmp_path / "c.json", timeout=3.0).cancel) == held_id
    assert sim.held is None and sim.finished[held_id][0] == Fault.CANCELLED


def test_a_send_cancelled_from_elsewhere_says_how_far_it_got(sim_factory, tmp_path):
    """'doodlecam send --cancel' from a second terminal while the first sends: the first says the job was cancelled
    after the command the PLC had run, not 'command 0'."""
    import threading

    data = synth_job(n_strokes=6, samples=200, seed=13)
    sim = sim_factory(speed=20.0)
    state = tmp_path / "c.json"
    box = {}

    def run():
        try:
            UdpSender(*sim.address, data, state_file=state, timeout=5.0).run()
        except LinkError as e:
            box["error"] = str(e)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    wait_for(lambda: len(sim.executed_log) >= 300, 30, "the job to get going")
    bounded(UdpSender(*sim.address, data, state_file=state, timeout=3.0).cancel)
    t.join(30)
    ran = len(sim.executed_log)
    m = re.search(r"cancelled on the PLC after command (\d+) of", box.get("error", ""))
    assert m and 300 <= int(m.group(1)) <= ran, box


# ---------------------------------------------------------------- errors a user sees

def test_nothing_listening_gives_a_one_line_error_quickly(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # free once closed: nothing listens there
    job = tmp_path / "j.plc"
    job.write_bytes(synth_job(n_strokes=1, samples=10))
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(job), "--udp", f"127.0.0.1:{port}",
                        "--timeout", "2"], capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=30)
    assert r.returncode != 0 and time.monotonic() - t0 < 15
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("doodlecam: error:") and f"127.0.0.1:{port}" in lines[0]


def test_silent_plc_times_out_with_a_one_line_error(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:  # bound, never answers
        silent.bind(("127.0.0.1", 0))
        job = tmp_path / "j.plc"
        job.write_bytes(synth_job(n_strokes=1, samples=10))
        t0 = time.monotonic()
        r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(job), "--udp",
                            f"127.0.0.1:{silent.getsockname()[1]}", "--timeout", "0.7"],
                           capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=30)
        elapsed = time.monotonic() - t0
    assert r.returncode != 0
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "no answer from the PLC" in lines[0] and "0.7 s" in lines[0]
    assert elapsed < 15


def test_cli_sim_plc_with_impairments_and_recorded_trajectory(tmp_path):
    data = synth_job(n_strokes=5, samples=50, seed=9)
    job = tmp_path / "cli.plc"
    job.write_bytes(data)
    rec = tmp_path / "trace.csv"
    sim = subprocess.Popen([sys.executable, "-m", "doodlecam", "sim", "plc", "--port", "0", "--loss", "0.1", "--dup",
                            "0.1", "--reorder", "0.1", "--corrupt", "0.02", "--seed", "3", "--rto", "0.02",
                            "--record", str(rec), "--state-file", str(tmp_path / "plc.nv"), "--key", "s3cret-of-the-shop"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
    try:
        first = sim.stdout.readline()
        port = int(first.split(" on ")[1].split()[0].rsplit(":", 1)[1])

        def send(*extra):
            return subprocess.run([sys.executable, "-m", "doodlecam", "send", str(job), "--udp", f"127.0.0.1:{port}",
                                   "--no-progress", "--transport-opt", "key=s3cret-of-the-shop", *extra],
                                  capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60)

        r = send()
        assert r.returncode == 0, r.stderr
        assert f"{read_plc_array(data)[0].no_commands} commands executed" in r.stdout
        again = send()  # the PLC remembers the content: a one-line refusal that says what to do
        assert again.returncode != 0 and "already finished" in again.stderr and "--again" in again.stderr
        assert "Traceback" not in again.stderr and len(again.stderr.strip().splitlines()) == 1
    finally:
        sim.send_signal(signal.SIGINT)
        sim.communicate(timeout=10)
    rows = np.loadtxt(rec, delimiter=",", skiprows=1)
    header, arr = read_plc_array(data)
    cmd_rows = rows[rows[:, 1] >= 0]
    np.testing.assert_array_equal(cmd_rows[:, 0], np.arange(1, len(arr) + 1))
    pos, _ = P.planned_states(arr, header.delta_time)
    np.testing.assert_allclose(cmd_rows[:, 3:5], pos, atol=1e-3)


def test_a_restarted_simulator_never_runs_a_finished_job_again(tmp_path):
    """Its non-volatile memory is kept by default (one per port in the user's state folder): a finished job sent
    again after a restart is refused, as a real PLC's retentive ended-job table does."""
    data = synth_job(n_strokes=2, samples=30, seed=11)
    job = tmp_path / "again.plc"
    job.write_bytes(data)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(ENV, XDG_STATE_HOME=str(tmp_path / "state"))

    def start():
        sim = subprocess.Popen([sys.executable, "-m", "doodlecam", "sim", "plc", "--port", str(port)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
        assert f":{port}" in sim.stdout.readline()
        return sim

    def send():
        return subprocess.run([sys.executable, "-m", "doodlecam", "send", str(job), "--udp", f"127.0.0.1:{port}",
                               "--no-progress"], capture_output=True, text=True, env=env, cwd=ROOT, timeout=60)

    for round_ in range(2):
        sim = start()
        try:
            r = send()
            if round_ == 0:
                assert r.returncode == 0, r.stderr
            else:  # restarted: it remembers
                assert r.returncode != 0 and "already finished" in r.stderr, r.stderr
        finally:
            sim.send_signal(signal.SIGTERM)
            sim.communicate(timeout=10)
    assert list((tmp_path / "state" / "doodlecam" / "plc-simulator").glob(f"*-{port}.json"))


def test_wrong_job_type_and_bad_target_are_one_line_errors(tmp_path):
    g = tmp_path / "a.gcode"
    g.write_text("G0 X1\n")
    r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(g), "--udp", "127.0.0.1:5005"],
                       capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=30)
    assert r.returncode != 0 and "not a .plc job" in r.stderr and "Traceback" not in r.stderr
    p = tmp_path / "a.plc"
    p.write_bytes(synth_job(n_strokes=1, samples=5))
    r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(p), "--udp", "localhost"],
                       capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=30)
    assert r.returncode != 0 and r.stderr.strip().count("\n") == 0 and "HOST:PORT" in r.stderr


def test_transports_are_plugins_listed_by_the_cli():
    from doodlecam import registry

    assert registry.get("transport", "udp").extension == ".plc"
    assert registry.get("transport", "serial").extension == ".gcode"
    r = subprocess.run([sys.executable, "-m", "doodlecam", "plugins"], capture_output=True, text=True, env=ENV,
                       cwd=ROOT, timeout=60)
    block = r.stdout.split("Transports:")[1]
    assert "udp " in block and "serial " in block


def edge_job(direction, brake: float, width=32000, height=24000, dt=0.04) -> bytes:
    """One straight stroke towards an edge at 12000 steps/s, ending at rest 100 steps from it; its last
    ramp brakes at ``brake`` steps/s^2 (the header's max_accel is 160000)."""
    v, acc = 12000.0, 100000.0
    up = [v * min(1.0, (k + 1) * acc * dt / v) for k in range(int(np.ceil(v / (acc * dt))))]
    down = [max(0.0, v - (k + 1) * brake * dt) for k in range(int(np.ceil(v / (brake * dt))))]
    speeds = up + [v] * 20 + down
    travel = 0.5 * dt * np.sum(np.add([0.0] + speeds[:-1], speeds))  # linear ramps between the samples
    d = np.array(direction, float)
    size = np.array([width, height], float)
    end = np.where(d > 0, size - 100, np.where(d < 0, 100, size / 2))
    start = np.round(end - d * travel)
    rows = [(MOVE, *start)] + [(DRAW, *(d * s)) for s in speeds] + [(MOVE, 0, 0)]
    arr = np.zeros(len(rows), RECORD_DTYPE)
    arr["command_no"] = np.arange(1, len(rows) + 1)
    t = np.array(rows)
    arr["type"], arr["x"], arr["y"] = t[:, 0], t[:, 1], t[:, 2]
    return write_plc(PlcHeader(dt, len(rows), 160000, 160000, 12000, 12000, 80.0, 80.0), arr)


@pytest.mark.parametrize("direction", [(1, 0), (-1, 0), (0, 1), (0, -1)])
def test_a_starving_job_stops_inside_the_work_area_at_every_edge(sim_factory, direction):
    """The sender withholds DATA while the pen heads for an edge: the PLC's own stop stays in the work area.
    A ramp whose stop (braking at max_accel) would not fit is never run: a job that brakes harder than the
    header says is refused before the edge, and one within its limits draws to the end."""
    for brake, starve_at in ((150000.0, 12), (150000.0, None), (480000.0, None), (480000.0, 12)):
        data = edge_job(direction, brake)
        sim = sim_factory(starve_timeout=0.2, speed=math.inf)
        s = _StallingSender(*sim.address, data, timeout=5.0, rto=0.05)
        if starve_at is not None:
            s.limit = starve_at  # moving at full speed towards the edge
        try:
            r = bounded(s.run)
            assert brake < 160000.0 and r.commands == read_plc_array(data)[0].no_commands
        except LinkError as e:
            assert brake > 160000.0 and "boundary" in str(e), e
        tr = sim.trajectory()
        assert tr["x"].min() >= 0 and tr["x"].max() <= sim.cfg.width, (brake, starve_at)
        assert tr["y"].min() >= 0 and tr["y"].max() <= sim.cfg.height, (brake, starve_at)


def test_the_plc_link_is_authenticated_by_default(tmp_path):
    """`sim plc` and `send --udp` share the machine's key (created on first use in the config folder): a
    stranger without it moves nothing; a key too short to be a secret is refused; --no-auth is said loudly."""
    data = synth_job(n_strokes=2, samples=30, seed=12)
    job = tmp_path / "auth.plc"
    job.write_bytes(data)
    env = dict(ENV, XDG_CONFIG_HOME=str(tmp_path / "config"), XDG_STATE_HOME=str(tmp_path / "state"))

    def start(*extra):
        sim = subprocess.Popen([sys.executable, "-m", "doodlecam", "sim", "plc", "--port", "0", *extra],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
        first = sim.stdout.readline()
        return sim, int(first.split(" on ")[1].split()[0].rsplit(":", 1)[1])

    def stop(sim):
        sim.send_signal(signal.SIGTERM)
        return sim.communicate(timeout=10)[1]

    sim, port = start()
    try:
        key_file = tmp_path / "config" / "doodlecam" / "keys" / "doodlebot.key"
        assert key_file.is_file() and (key_file.stat().st_mode & 0o077) == 0 and len(key_file.read_text().strip()) >= 32
        # a stranger on the network without the key: nothing runs
        with pytest.raises(LinkError):
            bounded(lambda: UdpSender("127.0.0.1", port, data, timeout=1.0).run())
        r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(job), "--udp", f"127.0.0.1:{port}",
                            "--no-progress"], capture_output=True, text=True, env=env, cwd=ROOT, timeout=60)
        assert r.returncode == 0, r.stderr  # the same computer's send has the machine's key
    finally:
        err = stop(sim)
    assert f"HMAC key created in {key_file}" in err
    for bad in (["--key", "short"], ["--key-file", str(tmp_path / "nope.key")], ["--key", "x" * 20, "--no-auth"]):
        r = subprocess.run([sys.executable, "-m", "doodlecam", "sim", "plc", "--port", "0", *bad],
                           capture_output=True, text=True, env=env, cwd=ROOT, timeout=30)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, (bad, r.stderr)
    sim, port = start("--no-auth")
    try:
        r = UdpSender("127.0.0.1", port, data, timeout=5.0)
        assert bounded(r.run).commands == len(read_plc_array(data)[1])
    finally:
        err = stop(sim)
    assert "WARNING: no authentication" in err
