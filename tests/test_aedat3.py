"""AEDAT 3.1 (cAER / libcaer): the derived recording, hand-built packets, bad input."""

import io
import re
import struct

import numpy as np
import pytest

from evtools.events import make_events
from evtools.formats import FormatError
from tests.conftest import data_file
from tests.helpers import assert_clean_error, assert_same_events, read_all, run

HEADER = b"#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 1: DAVIS346B\r\n#!END-HEADER\r\n"


def _packet(kind, events, overflow=0, capacity=None, size=8, ts_offset=4, payload=None):
    """One packet: 28-byte header, then ``capacity`` slots of ``size`` bytes (polarity: (data, ts) pairs)."""
    capacity = len(events) if capacity is None else capacity
    if payload is None:
        payload = b"".join(struct.pack("<Ii", data, ts) for data, ts in events)
        payload += bytes(size * capacity - len(payload))
    valid = sum(data & 1 for data, _ in events)
    head = struct.pack("<hhiiiiii", kind, 1, size, ts_offset, overflow, capacity, len(events), valid)
    return head + payload


def _polarity(x, y, on, valid=True):
    return x << 17 | y << 2 | int(on) << 1 | int(valid)


def test_reads_the_derived_file_as_the_aedat4_events(dvxplorer_events):
    info, events = read_all(data_file("derived/dvxplorer_sample.aedat3"))
    assert info.format == "aedat3"
    assert info.metadata["sources"] == {1: "DVXplorer"}
    assert (info.width, info.height) == (320, 240)  # not in the header: inferred by a scan of the events
    expected = dvxplorer_events.copy()
    expected["t"] -= expected["t"][0]  # the file stores timestamps relative to the first event
    assert_same_events(events, expected)
    _, small_chunks = read_all(data_file("derived/dvxplorer_sample.aedat3"), chunk_events=1000)
    assert_same_events(small_chunks, expected)


def test_given_sensor_size_wins_and_pipes_need_it(monkeypatch):
    import sys

    raw = data_file("derived/dvxplorer_sample.aedat3").read_bytes()
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(io.BytesIO(raw))))
    with pytest.raises(FormatError, match="--sensor-size"):
        read_all("-")
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(io.BytesIO(raw))))
    info, events = read_all("-", sensor_size=(640, 480))
    assert (info.width, info.height, len(events)) == (640, 480, 111_954)


def test_packets_overflow_invalid_events_and_other_types(tmp_path):
    path = tmp_path / "built.aedat3"
    first = [(_polarity(3, 4, True), 10), (_polarity(5, 6, False, valid=False), 11), (_polarity(7, 8, False), 12)]
    frame = _packet(3, [], capacity=3, size=20, payload=bytes(60))  # an IMU packet: skipped by its size
    second = [(_polarity(345, 259, True), 5)]
    body = _packet(1, first, capacity=5) + frame + _packet(1, second, overflow=3)
    path.write_bytes(HEADER + body)
    info, events = read_all(path)
    assert (info.width, info.height) == (346, 260)  # from '#Source 1: DAVIS346B'
    expected = make_events([10, 12, (3 << 31) | 5], [3, 7, 345], [4, 8, 259], [1, 0, 1])
    assert_same_events(events, expected)
    assert info.metadata["skipped_packets"] == {3: 1}  # (frame packets, type 2, are read: test_frames.py)
    assert info.metadata["invalid_events"] == 1


def test_truncated_packet_names_the_file_and_the_packets_before_it_are_read(tmp_path, caplog):
    path = tmp_path / "cut.aedat3"
    packet = _packet(1, [(_polarity(1, 2, True), 1), (_polarity(1, 2, True), 2)])
    path.write_bytes(HEADER + packet[:-3])
    assert len(read_all(path, sensor_size=(346, 260))[1]) == 0
    assert re.search(rf"cut\.aedat3.*truncated AEDAT 3\.1 packet at byte offset {len(HEADER)}.*file was cut", caplog.text)
    caplog.clear()
    path.write_bytes(HEADER + packet + packet[:10])
    assert len(read_all(path, sensor_size=(346, 260))[1]) == 2
    assert re.search(r"cut\.aedat3.*truncated AEDAT 3\.1 packet header.*file was cut", caplog.text)
    caplog.clear()
    assert len(read_all(path)[1]) == 2  # its size scanned first: the cut said once
    assert caplog.text.count("file was cut") == 1
    piped = run("info", "-", "--sensor-size", "346x260", input=path.read_bytes(), check=False)  # its writer stopped
    assert_clean_error(piped, "<stdin>", "truncated AEDAT 3.1 packet header")


@pytest.mark.parametrize("capacity", [2**27 + 1, 2**30])
def test_a_size_no_packet_can_have_is_damage_not_a_cut(tmp_path, capacity):
    """A QA sweep: a packet header saying 1-8 GiB of body was taken for a file cut inside it (a warning, the output
    marked cut, exit 0); as for AEDAT 4.0, over 1 GiB is a damaged size field: one line, exit 1."""
    path = tmp_path / "big.aedat3"
    good = _packet(1, [(_polarity(1, 2, True), 1)])
    path.write_bytes(HEADER + good + struct.pack("<hhiiiiii", 1, 1, 8, 4, 0, capacity, 1, 1) + bytes(64))
    done = run("convert", path, "-o", tmp_path / "out.h5", check=False)
    assert_clean_error(done, "big.aedat3", f"corrupt AEDAT 3.1 packet header at byte offset {len(HEADER + good)}",
                       "more than a packet holds")
    assert not (tmp_path / "out.h5").exists()


def test_wrong_magic_and_missing_end_of_header_name_the_file(tmp_path):
    path = tmp_path / "wrong.aedat3"
    path.write_bytes(b"#!AER-DAT2.0\r\n" + bytes(8))
    with pytest.raises(FormatError, match=r"wrong\.aedat3.*not an AEDAT 3\.1"):
        read_all(path, format="aedat3")
    path.write_bytes(b"#!AER-DAT3.1\r\n#Format: RAW\r\n" + np.zeros(4, "<u4").tobytes())
    with pytest.raises(FormatError, match=r"wrong\.aedat3.*END-HEADER"):
        read_all(path)


def test_a_file_cut_inside_its_end_of_header_line_is_refused(tmp_path):
    """Issue 37 item 11: cut inside (or right after the text of) its end-of-header line, an AEDAT 3.1 file read as
    0 events on a 1 x 1 sensor, exit 0."""
    path = tmp_path / "cut.aedat"
    for cut in (b"#!END-HEADER", b"#!END-HEADER\r"):
        path.write_bytes(b"#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 1: DAVIS346B\r\n" + cut)
        with pytest.raises(FormatError, match=r"cut\.aedat.*ends inside its AEDAT 3\.1 header"):
            read_all(path)
