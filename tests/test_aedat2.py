"""AEDAT 2.0 (jAER): real recordings, hand-decoded records, round trips, timestamp wrap, bad input."""

import io
import logging
import re
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import evtools
from evtools.events import StreamInfo, make_events
from evtools.formats import FormatError, create_events
from evtools.formats.aedat2 import LAYOUT_SIZES, Aedat2Writer
from evtools.formats.registry import WriteOptions
from tests.conftest import data_file
from tests.helpers import assert_same_events, cut, read_all

HEADER_NO_CHIP = b"#!AER-DAT2.0\r\n# Timestamps tick is 1 us\r\n"


def _body_offset(raw: bytes) -> int:
    """Where the body starts: the first line that does not start with '#'."""
    offset = 0
    while raw[offset : offset + 1] == b"#":
        offset = raw.index(b"\n", offset) + 1
    return offset


def _written(events, size, layout=None, chunks=None) -> bytes:
    out = io.BytesIO()
    writer = Aedat2Writer(out, StreamInfo(*size), WriteOptions(aedat2_layout=layout))
    for chunk in chunks if chunks is not None else [events]:
        writer.write(chunk)
    writer.close()
    return out.getvalue()


def test_reads_the_derived_davis346_file_as_the_aedat4_events(dvxplorer_events):
    info, events = read_all(data_file("derived/dvxplorer_sample.davis346.aedat"))
    assert (info.width, info.height, info.format) == (346, 260, "aedat2")
    assert info.metadata["aechip"] == "eu.seebetter.ini.chips.davis.Davis346B"
    assert info.metadata["aedat2_layout"] == "davis346"
    expected = dvxplorer_events.copy()
    expected["t"] -= expected["t"][0]  # the file stores timestamps relative to the first event
    assert_same_events(events, expected)


def test_reads_the_jaer_dvs128_recording_with_jaer_conventions():
    path = data_file("dvs128_walk.aedat")
    info, events = read_all(path, chunk_events=100_000)  # several blocks: wrap state carried across them
    assert (info.width, info.height) == (128, 128)
    assert info.metadata["aedat2_layout"] == "dvs128"
    assert info.metadata["skipped_words"]["special"] == 0
    assert len(events) == 290_292
    assert (events["t"][-1] - events["t"][0]) / 1e6 == pytest.approx(25.1, abs=0.05)
    assert events["p"].any() and not events["p"].all()

    # a few records decoded by hand with DVS128.java's formulas (FORMATS.md), then flipped to image rows
    raw = path.read_bytes()
    body = _body_offset(raw)
    for i in (0, 1, 2, 1234, 150_000, 290_291):
        a, t = struct.unpack_from(">ii", raw, body + 8 * i)
        x = 127 - ((a & 0xFE) >> 1)
        y_jaer = (a & 0x7F00) >> 8  # origin bottom-left
        polarity = 1 - (a & 1)  # raw bit 0 clear = ON
        assert (events["x"][i], events["y"][i], int(events["p"][i]), events["t"][i]) == (x, 127 - y_jaer, polarity, t)


def test_reads_the_real_jaer_davis346_header_with_no_events():
    info, events = read_all(data_file("jaer_davis346_header_only.aedat"))
    assert (info.width, info.height) == (346, 260)
    assert info.metadata["aechip"] == "eu.seebetter.ini.chips.davis.Davis346red"
    assert len(events) == 0


def test_davis_words_for_aps_imu_and_external_input_are_skipped(tmp_path):
    path = tmp_path / "mixed.aedat"
    dvs = (259 - 10) << 22 | (345 - 20) << 12 | 1 << 11
    words = [(dvs, 5), (1 << 31 | 77, 6), (1 << 10, 7), (dvs, 8)]
    body = b"".join(struct.pack(">II", a, t) for a, t in words)
    path.write_bytes(b"#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.Davis346B\r\n" + body)
    info, events = read_all(path)
    assert_same_events(events, make_events([5, 8], [20, 20], [10, 10], [1, 1]))
    assert info.metadata["skipped_words"] == {"special": 0, "aps_imu": 1, "external_input": 1}


def _random_events(rng, n, width, height, t0_us):
    t = t0_us + np.sort(rng.integers(0, 50 * n + 1, n))
    return make_events(t, rng.integers(0, width, n), rng.integers(0, height, n), rng.integers(0, 2, n))


def _without_leading_hash(events, layout):
    """Expected read-back: DAVIS leading events with raw y 140..143 (first byte '#') are dropped."""
    if layout == "dvs128":
        return events
    height = LAYOUT_SIZES[layout][1]
    hashes = ((height - 1 - events["y"].astype(int)) >> 2) == 0x23
    first = len(events) if hashes.all() else int(np.argmin(hashes))
    return events[first:]


@settings(max_examples=40, deadline=None)
@given(
    layout=st.sampled_from(sorted(LAYOUT_SIZES)),
    n=st.integers(0, 300),
    seed=st.integers(0, 2**32 - 1),
    t0_us=st.sampled_from([0, 123, 2**31 - 7, 2**32 - 1000]),
    cuts=st.lists(st.integers(0, 10_000), max_size=6),
)
def test_round_trip_for_every_layout_whatever_the_chunking(tmp_path_factory, layout, n, seed, t0_us, cuts):
    size = LAYOUT_SIZES[layout]
    events = _random_events(np.random.default_rng(seed), n, *size, t0_us)
    one_shot = _written(events, size)
    assert _written(events, size, chunks=cut(events, cuts)) == one_shot
    assert _written(events, size, layout=layout) == one_shot

    path = tmp_path_factory.mktemp("rt") / "events.aedat"
    path.write_bytes(one_shot)
    info, back = read_all(path, chunk_events=1 + seed % 97)
    assert (info.width, info.height) == size
    assert info.metadata["aedat2_layout"] == layout
    assert_same_events(back, _without_leading_hash(events, layout))


def test_round_trip_through_create_events_keeps_a_smaller_sensor_size(tmp_path):
    path = tmp_path / "small.aedat"
    events = _random_events(np.random.default_rng(1), 500, 64, 48, 0)
    with create_events(path, StreamInfo(64, 48)) as writer:
        writer.write(events)
    info, back = read_all(path)
    assert (info.width, info.height, info.metadata["aedat2_layout"]) == (64, 48, "davis240")
    assert_same_events(back, events)


def test_the_32_bit_timestamp_wrap_is_unwrapped(tmp_path):
    # consecutive events less than 2^31 us apart (a wider gap cannot be told from a wrap), 3.2 wraps in all
    t = np.array([0, 1_000, 2**31, 2**32 - 5, 2**32 + 10, 2**32 + 2**30, 2**32 + 2**31 + 2**30, 2**33 + 7,
                  2**33 + 2**31, 3 * 2**32 - 1, 3 * 2**32 + 2])
    events = make_events(t, np.arange(len(t)), np.zeros(len(t)), np.ones(len(t)))
    path = tmp_path / "long.aedat"
    with create_events(path, StreamInfo(128, 128)) as writer:
        for chunk in cut(events, [3, 5, 8]):
            writer.write(chunk)
    raw = path.read_bytes()
    stored = np.frombuffer(raw[_body_offset(raw) :], dtype=">u4")[1::2]
    assert stored.tolist() == (t % 2**32).tolist()
    for chunk_events in (1, 3, 1000):
        _, back = read_all(path, chunk_events=chunk_events)
        assert_same_events(back, events)


def test_leading_events_that_would_start_with_a_hash_are_dropped_with_a_warning(caplog):
    # DAVIS346: raw y = 259 - y in 140..143 gives a first byte 0x23 ('#')
    events = make_events([1, 2, 3, 4], [0, 1, 2, 3], [259 - 140, 259 - 143, 0, 259 - 141], [1, 0, 1, 1])
    with caplog.at_level(logging.WARNING, logger="evtools"):
        body = _written(events, (346, 260))
    assert "dropped 2 leading event" in caplog.text
    raw = body[_body_offset(body) :]
    assert len(raw) == 2 * 8 and raw[0] != 0x23


def test_writer_refuses_a_sensor_that_aedat2_cannot_hold():
    with pytest.raises(FormatError, match="cannot hold a 640x480 sensor"):
        Aedat2Writer(io.BytesIO(), StreamInfo(640, 480), WriteOptions())
    with pytest.raises(FormatError, match="cannot hold"):
        Aedat2Writer(io.BytesIO(), StreamInfo(300, 200), WriteOptions(aedat2_layout="davis240"))


def test_no_chip_line_needs_a_layout_or_a_sensor_size(tmp_path):
    path = tmp_path / "nochip.aedat"
    path.write_bytes(HEADER_NO_CHIP + struct.pack(">II", (127 - 5) << 8 | (127 - 9) << 1 | 1, 42))
    with pytest.raises(FormatError, match=r"nochip\.aedat.*--aedat2-layout"):
        read_all(path)
    info, events = read_all(path, aedat2_layout="dvs128")
    assert (info.width, info.height) == (128, 128)
    assert_same_events(events, make_events([42], [9], [5], [0]))
    _, events = read_all(path, sensor_size=(128, 128))
    assert_same_events(events, make_events([42], [9], [5], [0]))


def test_a_record_cut_short_is_named_with_its_offset_and_the_records_before_it_read(tmp_path, caplog):
    path = tmp_path / "cut.aedat"
    good = _written(make_events([1, 2], [3, 4], [5, 6], [1, 0]), (128, 128))
    path.write_bytes(good + b"\x00\x01\x02")
    _, events = read_all(path)
    assert_same_events(events, make_events([1, 2], [3, 4], [5, 6], [1, 0]))
    assert re.search(rf"cut\.aedat.*truncated.*byte offset {len(good):,}.*cut", caplog.text)


def test_wrong_magic_names_the_file(tmp_path):
    path = tmp_path / "wrong.aedat"
    path.write_bytes(b"#!AER-DAT3.1\r\n#!END-HEADER\r\n" + bytes(16))
    with pytest.raises(FormatError, match=r"wrong\.aedat.*not an AEDAT 2\.0"):
        read_all(path, format="aedat2")
    path.write_bytes(bytes(16))
    with pytest.raises(FormatError, match=r"wrong\.aedat.*not an AEDAT 2\.0"):
        read_all(path, format="aedat2")


def test_reads_from_a_pipe(monkeypatch):
    import sys

    raw = data_file("derived/dvxplorer_sample.davis346.aedat").read_bytes()
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(io.BytesIO(raw))))
    info, events = read_all("-")
    assert (info.width, info.height, len(events)) == (346, 260, 111_954)


@settings(max_examples=60, deadline=None)
@given(start=st.sampled_from([0, 5, 2**32 - 3, 1_605_537_493_718_345, 1_700_000_000_000_000]),
       gaps=st.lists(st.sampled_from([0, 1, 1000, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**33 + 5]), min_size=1,
                     max_size=12),
       cuts=st.lists(st.integers(0, 12), max_size=4))
def test_times_come_back_exact_or_the_write_is_refused(tmp_path_factory, start, gaps, cuts):
    """Absolute times (DV's Unix microseconds) come back through the header's t0 line; a gap the 32-bit counter
    cannot carry is refused naming the gap, never written to read back wrong (before: t0 dropped silently, a
    2^32 us gap read as none, a 2^32 - 1 us gap as time going backwards); the outcome does not depend on the
    chunks."""
    t = start + np.cumsum([0] + gaps)
    events = make_events(t, np.zeros(len(t)), np.zeros(len(t)), np.ones(len(t)))
    stored = t % 2**32
    fits = all((b - a if b - a >= -2**31 else b - a + 2**32) == g for a, b, g in zip(stored[:-1], stored[1:], gaps))
    folder = tmp_path_factory.mktemp("gaps")
    path = folder / "events.aedat"
    if not fits:
        with pytest.raises(FormatError, match=r"events\.aedat: AEDAT 2\.0 cannot store two consecutive events "
                                              r"[\d,]+ us apart here"):
            evtools.write(path, events, StreamInfo(128, 128))
        assert not path.exists()
        return
    with create_events(path, StreamInfo(128, 128)) as writer:
        for chunk in cut(events, cuts):
            writer.write(chunk)
    info, back = read_all(path)
    assert_same_events(back, events)
    assert info.metadata["t0_us"] == start >> 32 << 32
