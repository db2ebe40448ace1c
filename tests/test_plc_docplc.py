"""The real sender against a PLC written only from docs/protocol.md (tests/docplc.py), over loopback."""

import numpy as np
import pytest

from docplc import DocPlc
from doodlecam.link.plc.packetfile import read_plc_array
from doodlecam.link.plc.sender import UdpSender
from doodlecam.link.session import LinkError
from test_udp import bounded, synth_job


@pytest.fixture
def docplc():
    made = []

    def make(**kw):
        plc = DocPlc(**kw).start()
        made.append(plc)
        return plc

    yield make
    for p in made:
        p.stop()


def executed_records(plc: DocPlc, job_id: int) -> np.ndarray:
    return np.array([(c, t, x, y) for j, c, t, x, y in plc.executed if j == job_id], dtype=np.int64)


@pytest.mark.parametrize("key", [None, b"a key both sides share"])
def test_sender_completes_a_job_on_the_document_plc_exactly_once(docplc, tmp_path, key):
    data = synth_job(n_strokes=12, samples=98, seed=21)
    _, arr = read_plc_array(data)
    plc = docplc(buffer_size=64, key=key)
    r = bounded(lambda: UdpSender(*plc.address, data, state_file=tmp_path / "j.json", timeout=5.0, rto=0.05,
                                  key=key).run())
    got = executed_records(plc, r.job_id)
    want = np.column_stack([arr["command_no"], arr["type"], arr["x"], arr["y"]]).astype(np.int64)
    np.testing.assert_array_equal(got, want)  # every command once, in order, as in the file
    # The same file again: the document PLC remembers the content and says so.
    with pytest.raises(LinkError, match="already finished .*--again"):
        bounded(lambda: UdpSender(*plc.address, data, state_file=tmp_path / "k.json", timeout=3.0, key=key).run())
    r2 = bounded(lambda: UdpSender(*plc.address, data, state_file=tmp_path / "k.json", timeout=5.0, key=key,
                                   again=True).run())
    np.testing.assert_array_equal(executed_records(plc, r2.job_id), want)


def test_document_plc_refuses_a_second_sender_and_a_keyless_one(docplc, tmp_path):
    import socket
    import time

    from doodlecam.link.plc import protocol as P

    data = synth_job(n_strokes=2, samples=98, seed=22)
    header, _ = read_plc_array(data)
    plc = docplc()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as first:  # a PC that started a job and sends no data
        first.bind(("127.0.0.1", 0))
        h = P.JobHeader.from_plc(header, 0xABCD, token=99)
        first.settimeout(2.0)
        first.sendto(P.hello(5, 1), plc.address)
        ready = P.decode(first.recv(2048))  # its challenge: what a HEADER must carry
        first.sendto(P.header(5, 2, 4242, h, challenge=ready.challenge), plc.address)
        time.sleep(0.2)
        with pytest.raises(LinkError, match=rf"busy: job 4242 from 127\.0\.0\.1:{first.getsockname()[1]} is running"):
            bounded(lambda: UdpSender(*plc.address, data, timeout=3.0).run())
    assert plc.refused >= 1 and plc.executed == []
    plc = docplc(key=b"k" * 16)
    with pytest.raises(LinkError, match="requires a key"):
        bounded(lambda: UdpSender(*plc.address, data, timeout=1.0).run())
    assert plc.executed == []
