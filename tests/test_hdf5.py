"""HDF5 reader and writer: the reference files, v2e's layout, round trips, ms_to_idx, bad inputs."""

from __future__ import annotations

import io
import sys
import types
from unittest import mock

import h5py
import hdf5plugin  # noqa: F401
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import evtools.formats.hdf5
from evtools.events import StreamInfo, make_events
from evtools.formats import FormatError, ReadOptions, WriteOptions, create_events, open_events
from evtools.formats.hdf5 import Hdf5Writer
from evtools.formats.io import Source
from tests.conftest import data_file
from tests.helpers import assert_clean_error, random_events, read_all, run, write_bytes

COMPRESSIONS = ["none", "gzip", "lzf", "zstd"]


@st.composite
def event_arrays(draw, max_events: int = 200):
    n = draw(st.integers(0, max_events))
    width = draw(st.integers(1, 700))
    height = draw(st.integers(1, 500))
    t0_us = draw(st.integers(0, 2**42))
    gaps_us = draw(st.lists(st.sampled_from([0, 1, 7, 400, 999, 1000, 1001, 2500, 10**6]), min_size=n, max_size=n))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    t = t0_us + np.cumsum(np.asarray(gaps_us, dtype=np.int64))
    events = make_events(t, rng.integers(0, width, n), rng.integers(0, height, n), rng.integers(0, 2, n))
    cuts = draw(st.lists(st.integers(0, n), max_size=6))
    return events, StreamInfo(width, height), cuts


# -- the reference files ------------------------------------------------------------------------------------
def test_dsec_sample_gives_the_aedat4_events(dvxplorer_events):
    info, events = read_all(data_file("derived/dvxplorer_sample.dsec.h5"), sensor_size=(320, 240), chunk_events=5000)
    assert np.array_equal(events, dvxplorer_events)  # t_offset added: absolute microseconds
    assert info.size == (320, 240)
    assert info.metadata["layout"] == "dsec"


def test_dsec_sample_reads_in_slices_and_infers_the_size(dvxplorer_events):
    with open_events(data_file("derived/dvxplorer_sample.dsec.h5"), chunk_events=5000) as stream:
        lengths = [len(chunk) for chunk in stream]
        assert stream.info.size == (320, 240)  # not stored: inferred from max x, y
    assert max(lengths) == 5000 and sum(lengths) == len(dvxplorer_events)


def test_eventutils_sample_gives_the_aedat4_events(dvxplorer_events):
    info, events = read_all(data_file("derived/dvxplorer_sample.eventutils.h5"))
    assert np.array_equal(events, dvxplorer_events)  # ts float64 seconds, absolute
    assert info.size == (320, 240)  # from sensor_resolution = (H, W)
    assert info.metadata["layout"] == "event_utils"


def test_writer_ms_to_idx_equals_the_published_dsec_file(dvxplorer_events, tmp_path):
    path = tmp_path / "out.h5"
    with create_events(path, StreamInfo(320, 240)) as writer:
        writer.write(dvxplorer_events)
    with h5py.File(data_file("derived/dvxplorer_sample.dsec.h5"), "r") as ref, h5py.File(path, "r") as ours:
        assert np.array_equal(ours["ms_to_idx"][:], ref["ms_to_idx"][:])
        assert ours["t_offset"][()] == ref["t_offset"][()]
        assert np.array_equal(ours["events/t"][:], ref["events/t"][:])


# -- v2e ----------------------------------------------------------------------------------------------------
def test_v2e_n_by_4_layout(tmp_path):
    rng = np.random.default_rng(3)
    n = 2500
    t_us = np.sort(rng.integers(0, 10**7, n))
    rows = np.stack([t_us, rng.integers(0, 346, n), rng.integers(0, 260, n), rng.integers(0, 2, n)], axis=1)
    path = tmp_path / "v2e.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("events", data=rows.astype(np.uint32), maxshape=(None, 4), compression="gzip")
    info, events = read_all(path, sensor_size=(346, 260), chunk_events=1000)
    assert np.array_equal(events, make_events(t_us, rows[:, 1], rows[:, 2], rows[:, 3]))
    assert info.metadata["layout"] == "v2e" and info.size == (346, 260)


# -- round trips --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("compression", COMPRESSIONS)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=event_arrays())
def test_round_trip_and_bytes_independent_of_chunking(compression, case, tmp_path_factory):
    events, info, cuts = case
    with mock.patch.object(evtools.formats.hdf5, "WRITE_BLOCK_EVENTS", 16), mock.patch.object(evtools.formats.hdf5, "MS_BLOCK", 64):
        whole = write_bytes(Hdf5Writer, events, [], info, compression)
        chunked = write_bytes(Hdf5Writer, events, cuts, info, compression)
    if compression != "lzf":  # (liblzf's encoder leaves its hash table unset: its bytes vary from run to run, the
        assert whole == chunked  # same cuts too; what they decode to is compared below)
    path = tmp_path_factory.mktemp("rt") / "events.h5"
    path.write_bytes(chunked)
    got_info, got = read_all(path, chunk_events=7)
    assert np.array_equal(got, events)
    assert got_info.size == info.size and got_info.metadata["layout"] == "evtools"
    with h5py.File(path, "r") as f:
        check_ms_to_idx(f["events/t"][:].astype(np.int64), f["ms_to_idx"][:])
        assert f["t_offset"][()] == (events["t"][0] if len(events) else 0)


def check_ms_to_idx(t_us: np.ndarray, ms_to_idx: np.ndarray) -> None:
    """t[ms_to_idx[ms]] >= 1000*ms > t[ms_to_idx[ms]-1], one entry per millisecond up to the last event."""
    assert len(ms_to_idx) == (int(t_us[-1]) // 1000 + 1 if len(t_us) else 0)
    index, ms = ms_to_idx.astype(np.int64), np.arange(len(ms_to_idx), dtype=np.int64)
    assert (index < len(t_us)).all() and (t_us[index] >= 1000 * ms).all()
    after_one = index > 0
    assert (1000 * ms[after_one] > t_us[index[after_one] - 1]).all()


@pytest.mark.parametrize("compression", COMPRESSIONS)
def test_end_to_end_write_then_read(compression, tmp_path, dvxplorer_events):
    path = tmp_path / "out.h5"
    with create_events(path, StreamInfo(320, 240), compression=compression) as writer:
        for part in np.array_split(dvxplorer_events, 9):
            writer.write(part)
    info, events = read_all(path)
    assert np.array_equal(events, dvxplorer_events)
    assert info.size == (320, 240) and info.format == "hdf5"
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == "evtools"
        assert f["events/t"].dtype == np.uint64 and f["events/x"].dtype == np.uint16
        assert f["events/p"].dtype == np.uint8 and f["t_offset"].dtype == np.int64
        check_ms_to_idx(f["events/t"][:].astype(np.int64), f["ms_to_idx"][:])


def test_empty_stream_round_trip(tmp_path):
    path = tmp_path / "empty.h5"
    with create_events(path, StreamInfo(64, 48)) as writer:
        writer.write(make_events([], [], [], []))
    info, events = read_all(path)
    assert len(events) == 0 and info.size == (64, 48)


def test_reads_from_stdin(monkeypatch, tmp_path, dvxplorer_events):
    data = write_bytes(Hdf5Writer, dvxplorer_events, [1000], StreamInfo(320, 240))
    monkeypatch.setattr(sys, "stdin", types.SimpleNamespace(buffer=io.BufferedReader(io.BytesIO(data))))
    info, events = read_all("-")
    assert np.array_equal(events, dvxplorer_events) and info.size == (320, 240)


# -- bad inputs ---------------------------------------------------------------------------------------------
def test_file_without_events_names_the_file_and_what_it_holds(tmp_path):
    path = tmp_path / "frames.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("frames", data=np.zeros((2, 4, 4), np.uint8))
    with pytest.raises(FormatError, match=r"frames\.h5.*no events dataset.*frames \(2, 4, 4\)"):
        open_events(path)


def test_prophesee_layouts_evtools_cannot_decode_are_refused_saying_why(tmp_path):
    """(Metavision's own files are read: tests/test_ecf.py.) CD/events of other records, and ECF data elsewhere."""
    path = tmp_path / "prophesee.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("CD/events", data=np.zeros(3, np.int64))
    with pytest.raises(FormatError, match=r"prophesee\.h5: CD/events has shape \(3,\) and fields \(\); expected the "
                                          r"1-D records x, y, p, t"):
        open_events(path)
    path = tmp_path / "elsewhere.h5"
    with h5py.File(path, "w") as f:
        dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
        dcpl.set_chunk((4,))
        dcpl.set_filter(0x8ECF, h5py.h5z.FLAG_OPTIONAL, ())
        h5py.h5d.create(f.id, b"tracks", h5py.h5t.NATIVE_INT64, h5py.h5s.create_simple((4,)), dcpl=dcpl)
    with pytest.raises(FormatError, match=r"elsewhere\.h5: dataset tracks is compressed by Prophesee's ECF codec"):
        open_events(path)


def test_not_hdf5_is_a_format_error(tmp_path):
    path = tmp_path / "fake.h5"
    path.write_bytes(b"not an hdf5 file at all\n" * 10)
    with pytest.raises(FormatError, match=r"fake\.h5"):
        open_events(path, format="hdf5")


def test_unknown_compression(tmp_path):
    with pytest.raises(FormatError, match="compression"):
        Hdf5Writer(io.BytesIO(), StreamInfo(8, 8), WriteOptions(compression="brotli"))


def test_sensor_size_option_when_missing(tmp_path):
    path = tmp_path / "dsec.h5"
    with h5py.File(path, "w") as f:
        for key, dtype in (("x", "u2"), ("y", "u2"), ("t", "u4"), ("p", "u1")):
            f.create_dataset(f"events/{key}", data=(np.arange(5) % (2 if key == "p" else 5)).astype(dtype))
        f.create_dataset("t_offset", data=np.int64(100))
    info, events = read_all(path, sensor_size=(640, 480))
    assert info.size == (640, 480) and list(events["t"]) == [100, 101, 102, 103, 104]
    source = Source(path)
    reader = evtools.formats.hdf5.Hdf5Reader(source, ReadOptions(sensor_size=(10, 10), chunk_events=2))
    assert [len(chunk) for chunk in reader] == [2, 2, 1]
    reader.close()
    source.close()


def test_a_stream_spanning_more_than_the_ms_index_can_hold_is_refused(tmp_path):
    """Issue 37 item 4: two events 10^12 us apart (a 45-byte CSV) asked 13.7 GB for ms_to_idx; now refused before
    any allocation, naming the span and the limit, with nothing left under the output's name."""
    source = tmp_path / "two.csv"
    source.write_text("0,1,1,1\n1000000000000,2,2,0\n")
    done = run("convert", source, "--sensor-size", "4x4", "-o", tmp_path / "two.h5", check=False)
    assert_clean_error(done, "two.h5")
    assert "1,000,000,001 ms" in done.stderr.decode() and "268,435,456" in done.stderr.decode()
    assert not (tmp_path / "two.h5").exists()


def test_polarities_other_than_on_and_off_are_refused(tmp_path):
    """Issue 37 item 9: a polarity of 2 (HDF5 and an AEDAT 4.0 byte) and of 0.5 were read as ON (or ON in one
    layout, OFF in another) and copied into outputs; every reader now refuses them, naming the file."""
    import h5py

    from evtools.events import make_events
    from evtools.formats import create_events
    from evtools.events import StreamInfo

    events = make_events([1, 2, 3, 4], [0, 1, 2, 3], [0, 0, 1, 1], [1, 0, 1, 0])
    damaged = events.copy()
    damaged["p"].view(np.uint8)[2] = 2
    with create_events(str(tmp_path / "a.aedat4"), StreamInfo(4, 4)) as writer:
        writer.write(damaged)
    assert_clean_error(run("info", tmp_path / "a.aedat4", check=False), "a.aedat4", "polarity byte of 2")
    with create_events(str(tmp_path / "d.h5"), StreamInfo(4, 4)) as writer:
        writer.write(events)
    with h5py.File(tmp_path / "d.h5", "r+") as file:
        file["events/p"][1] = 2
    assert_clean_error(run("info", tmp_path / "d.h5", check=False), "d.h5", "polarities other than")
    with h5py.File(tmp_path / "d.h5", "r+") as file:
        del file["events/p"]
        file["events/p"] = np.array([1.0, 0.5, 1.0, 0.0])
    assert_clean_error(run("info", tmp_path / "d.h5", check=False), "d.h5", "polarities other than")


def test_fractional_times_in_microsecond_layouts_are_refused(tmp_path):
    """Found by a QA sweep: float times (seconds, or fractional us) in the DSEC and v2e layouts were rounded as
    microseconds: a 1.25 s stream read as 1 us long, exit 0. Whole-number floats are taken; event_utils' float ts
    are seconds (rounded to the microsecond), as that layout says."""
    import h5py

    seconds = np.array([0.001, 0.5, 1.25])
    with h5py.File(tmp_path / "v2e.h5", "w") as f:
        f["events"] = np.stack([seconds, [1, 3, 2], [2, 0, 2], [1, 0, 1]], axis=1)
    with h5py.File(tmp_path / "dsec.h5", "w") as f:
        f["events/t"] = seconds * 1e6 + 0.5
        f["events/x"], f["events/y"] = np.array([1, 3, 2], "u2"), np.array([2, 0, 2], "u2")
        f["events/p"] = np.array([1, 0, 1], "u1")
    for name, value in (("v2e.h5", "0.001 (event 0)"), ("dsec.h5", "1000.5 (event 0)")):
        assert_clean_error(run("info", tmp_path / name, "--sensor-size", "4x4", check=False),
                           f"{name}: event time {value} is not a whole number of microseconds")
    with h5py.File(tmp_path / "whole.h5", "w") as f:
        f["events"] = np.stack([seconds * 1e6, [1, 3, 2], [2, 0, 2], [1, 0, 1]], axis=1)
    assert read_all(tmp_path / "whole.h5", sensor_size=(4, 4))[1]["t"].tolist() == [1000, 500000, 1250000]


@pytest.mark.parametrize("layout", ["dsec", "event_utils", "v2e"])
def test_fractional_coordinates_are_refused_not_cut(tmp_path, layout):
    """Found by a QA sweep: a float x of 2.7 (DSEC) or 1.5 (event_utils, v2e) was read as 2 or 1, exit 0; a pixel's
    coordinate is whole, so it is refused naming the event (as a fractional time is); whole floats are taken."""
    import h5py

    for name, x in (("bad.h5", [1.0, 2.7, 3.0]), ("whole.h5", [1.0, 2.0, 3.0])):
        with h5py.File(tmp_path / name, "w") as f:
            t, y, p = np.array([0, 5, 10]), np.array([1, 2, 3]), np.array([1, 0, 1], "u1")
            if layout == "v2e":
                f["events"] = np.stack([t, x, y, p], axis=1).astype("f8")
            elif layout == "dsec":
                f["events/x"], f["events/y"], f["events/t"], f["events/p"] = np.array(x), y.astype("u2"), t, p
            else:
                f["events/xs"], f["events/ys"], f["events/ts"], f["events/ps"] = np.array(x, "f4"), y, t * 1e-6, p
    assert_clean_error(run("info", tmp_path / "bad.h5", "--sensor-size", "4x4", check=False),
                       "bad.h5: event x coordinate 2.7", "(event 1) is not a whole pixel")
    assert read_all(tmp_path / "whole.h5", sensor_size=(4, 4))[1]["x"].tolist() == [1, 2, 3]


def test_a_damaged_time_chunk_disagrees_with_ms_to_idx_and_is_refused(tmp_path):
    """Issue 37 item 5: a damaged chunk of t decoded as zeros was read as 30,000 events at one time, exit 0. The
    DSEC layout's ms_to_idx says where each millisecond starts: times that disagree are refused naming the file;
    undamaged files (written by evtools, read in any chunk size) pass the check."""
    from evtools.events import StreamInfo, make_events
    from evtools.formats import create_events

    rng = np.random.default_rng(0)
    n = 50_000
    events = make_events(np.sort(rng.integers(0, 2_000_000, n)), rng.integers(0, 64, n), rng.integers(0, 48, n),
                         rng.integers(0, 2, n))
    path = tmp_path / "d.h5"
    with create_events(str(path), StreamInfo(64, 48)) as writer:
        writer.write(events)
    for chunk_events in (1000, 7777, 1 << 20):
        _, back = read_all(path, chunk_events=chunk_events)
        assert np.array_equal(back["t"], events["t"])
    with h5py.File(path, "r+") as file:
        t = file["events/t"]
        t[20_000:30_000] = np.full(10_000, t[20_000])  # a run of one time where the events spread over ~400 ms
    with pytest.raises(FormatError, match=r"d\.h5.*ms_to_idx"):
        read_all(path)


def test_the_default_output_opens_in_plain_h5py(tmp_path):
    """Issue 39: the default HDF5 output needs no plugin (h5py alone, hdf5plugin never imported, reads it back)."""
    import subprocess

    events = random_events(1_000, 32, 24, seed=3)
    path = tmp_path / "plain.h5"
    with create_events(path, StreamInfo(32, 24)) as writer:
        writer.write(events)
    code = ("import sys, h5py, numpy; f = h5py.File(sys.argv[1]); x = f['events/x'][()]; "
            "assert 'hdf5plugin' not in sys.modules; print(len(x), int(x.sum()))")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(len(events)), str(int(events["x"].sum()))]


@given(st.data())
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_damage_to_a_chunk_evtools_wrote_is_an_error_not_other_events(tmp_path, data):
    """Issue 37 item 5: a damaged chunk read as other events (one damaged `t` chunk decoded as zeros: 30,000 events
    at one time, exit 0). evtools' HDF5 outputs carry HDF5's Fletcher-32 checksum on every chunk, which any HDF5
    reader checks: one flipped bit anywhere in any chunk's stored bytes is an error naming the file."""
    import h5py

    import evtools
    from evtools.errors import EvtoolsError

    n = 20_000
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31 - 1)))
    events = evtools.from_columns(np.sort(rng.integers(0, 10_000_000, n)), rng.integers(0, 346, n),
                                  rng.integers(0, 260, n), rng.integers(0, 2, n))
    compression = data.draw(st.sampled_from(["none", "zstd", "gzip", "lzf"]))
    path = tmp_path / f"e-{compression}.h5"
    evtools.write(path, events, evtools.StreamInfo(346, 260), compression=compression)
    with h5py.File(path) as h5:
        name = data.draw(st.sampled_from(["events/t", "events/x", "events/y", "events/p", "ms_to_idx"]))
        dataset = h5[name]
        assert dataset.fletcher32
        chunk = dataset.id.get_chunk_info(data.draw(st.integers(0, dataset.id.get_num_chunks() - 1)))
    damaged = bytearray(path.read_bytes())
    position = chunk.byte_offset + data.draw(st.integers(0, chunk.size - 1))
    damaged[position] ^= 1 << data.draw(st.integers(0, 7))
    path.write_bytes(bytes(damaged))
    with pytest.raises(EvtoolsError, match=path.name):
        evtools.read(path)
