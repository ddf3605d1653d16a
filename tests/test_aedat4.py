"""AEDAT 4.0: evtools' reader against `aedat` and dv-processing, its writer read back by both, chunk invariance."""

import io
import json
import re
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import evtools
from evtools.events import StreamInfo, join, make_events
from evtools.formats import FormatError, create_events, open_events
from evtools.formats.aedat4 import Aedat4Writer, _parse_ioheader
from evtools.formats.registry import WriteOptions
from tests.conftest import data_file
from tests.helpers import aedat4_packets, assert_same_events, cut, random_events, read_all

COMPRESSIONS = ["none", "lz4", "zstd"]


def test_reads_the_real_dvxplorer_recording_as_aedat_does(dvxplorer_events):
    info, events = read_all(data_file("dvxplorer_sample.aedat4"))
    assert (info.width, info.height, info.format) == (320, 240, "aedat4")
    assert info.metadata["source"] == "DVXplorer_DXB00010"
    assert sorted(info.metadata["skipped_streams"]) == ["imu", "triggers"]
    assert_same_events(events, dvxplorer_events)


def test_reads_the_real_recording_through_a_pipe(dvxplorer_events, monkeypatch):
    """stdin is sniffed for its format and then read from its first byte."""
    import sys

    raw = data_file("dvxplorer_sample.aedat4").read_bytes()
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(io.BytesIO(raw))))
    info, events = read_all("-")
    assert (info.width, info.height) == (320, 240)
    assert_same_events(events, dvxplorer_events)


def _write(path, events, size=(346, 260), compression="none"):
    with create_events(path, StreamInfo(*size, metadata={"source": "test"}), compression=compression) as writer:
        writer.write(events)


@pytest.mark.parametrize("compression", COMPRESSIONS)
def test_written_file_is_read_identically_by_aedat_and_dv_processing(tmp_path, compression):
    import aedat
    import dv_processing as dv

    events = random_events(100_000, seed=1, t0_us=1_600_000_000_000_000)
    path = tmp_path / f"out_{compression}.aedat4"
    _write(path, events, compression=compression)

    decoder = aedat.Decoder(str(path))
    assert decoder.id_to_stream()[0] == {"type": "events", "width": 346, "height": 260}
    by_aedat = np.concatenate([packet["events"] for packet in decoder if "events" in packet])
    np.testing.assert_array_equal(by_aedat["t"].astype(np.int64), events["t"])
    np.testing.assert_array_equal(by_aedat["x"], events["x"])
    np.testing.assert_array_equal(by_aedat["y"], events["y"])
    np.testing.assert_array_equal(by_aedat["on"], events["p"])

    recording = dv.io.MonoCameraRecording(str(path))
    assert recording.getEventResolution() == (346, 260)
    batches = []
    while recording.isRunning():
        batch = recording.getNextEventBatch()
        if batch is not None:
            batches.append(batch.numpy())
    by_dv = np.concatenate(batches)
    np.testing.assert_array_equal(by_dv["timestamp"], events["t"])
    np.testing.assert_array_equal(by_dv["x"], events["x"])
    np.testing.assert_array_equal(by_dv["y"], events["y"])
    np.testing.assert_array_equal(by_dv["polarity"].astype(bool), events["p"])
    _, ours = read_all(path)
    assert_same_events(ours, events)


@pytest.mark.parametrize("compression", ["none", "lz4", "zstd"])
def test_reads_a_file_written_by_dv_processing(tmp_path, compression):
    import dv_processing as dv

    events = random_events(50_000, width=640, height=480, seed=2, t0_us=1_000_000)
    path = tmp_path / "dv.aedat4"
    config = dv.io.MonoCameraWriter.Config("DVXplorer_test")
    config.addEventStream((640, 480))
    config.compression = {
        "none": dv.CompressionType.NONE, "lz4": dv.CompressionType.LZ4, "zstd": dv.CompressionType.ZSTD,
    }[compression]
    writer = dv.io.MonoCameraWriter(str(path), config)
    for part in np.array_split(events, 7):
        store = dv.EventStore()
        for t, x, y, p in zip(part["t"], part["x"], part["y"], part["p"]):
            store.push_back(int(t), int(x), int(y), bool(p))
        writer.writeEvents(store)
    del writer  # closes the file and writes dv's index table
    info, ours = read_all(path)
    assert (info.width, info.height) == (640, 480)
    assert info.metadata["source"] == "DVXplorer_test"
    assert_same_events(ours, events)


@settings(max_examples=25, deadline=None)
@given(cuts=st.lists(st.integers(0, 200_000), max_size=6), compression=st.sampled_from(COMPRESSIONS))
def test_bytes_written_do_not_depend_on_chunking(cuts, compression):
    events = random_events(70_000, seed=4)
    info = StreamInfo(346, 260)
    one, many = io.BytesIO(), io.BytesIO()
    writer = Aedat4Writer(one, info, WriteOptions(compression))
    writer.write(events)
    writer.close()
    writer = Aedat4Writer(many, info, WriteOptions(compression))
    for part in cut(events, cuts):
        writer.write(part)
    writer.close()
    assert one.getvalue() == many.getvalue()


@pytest.mark.parametrize("compression", ["lz4", "zstd"])
def test_packets_compressed_on_several_threads_are_the_bytes_of_one(compression):
    """Packets are compressed on ENCODE_THREADS threads and written in order: the file is the one a single
    thread writes, and flush() (a live output) writes every packet given so far."""
    from evtools.formats import aedat4

    events = random_events(9 * aedat4.PACKET_EVENTS + 123, seed=10)
    files = {}
    for threads in (1, 3):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(aedat4, "ENCODE_THREADS", threads)
            stream = io.BytesIO()
            writer = Aedat4Writer(stream, StreamInfo(346, 260), WriteOptions(compression))
            writer.write(events)
            writer.flush()
            flushed = stream.getvalue()
            writer.close()
            files[threads] = stream.getvalue()
    assert files[1] == files[3]
    assert files[3].startswith(flushed) and len(files[3]) - len(flushed) < 200  # only the end mark came after
    path_events = read_all_bytes(files[3])
    assert_same_events(path_events, events)


def read_all_bytes(data: bytes):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "x.aedat4"
        path.write_bytes(data)
        return read_all(path)[1]


@pytest.mark.parametrize("chunk_events", [1, 1000, 1 << 20])
def test_reading_any_chunk_size_gives_the_same_events(tmp_path, chunk_events):
    events = random_events(40_000, seed=5)
    _write(tmp_path / "a.aedat4", events)
    _, back = read_all(tmp_path / "a.aedat4", chunk_events=chunk_events)
    assert_same_events(back, events)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(packet_events=st.integers(1, 3000), chunk_events=st.integers(1, 50_000), n=st.integers(0, 30_000),
       compression=st.sampled_from(COMPRESSIONS))
def test_small_packets_read_the_same_in_any_chunks(tmp_path, packet_events, chunk_events, n, compression):
    """DV records packets of a few thousand events; compressed ones are decoded in groups of about a chunk: the
    events and the chunks' sizes (at most chunk_events, or a packet) do not depend on how packets fall in groups."""
    events = random_events(n, seed=n)
    path = tmp_path / f"small_{compression}.aedat4"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("evtools.formats.aedat4.PACKET_EVENTS", packet_events)
        with create_events(path, StreamInfo(346, 260), compression=compression) as writer:
            writer.write(events)
    with open_events(path, chunk_events=chunk_events) as stream:
        chunks = list(stream)
    assert all(0 < len(chunk) <= max(chunk_events, packet_events) for chunk in chunks)  # (packets are not cut)
    assert_same_events(join(chunks) if chunks else random_events(0), events)
    with open_events(path, chunk_events=chunk_events) as stream:  # the whole-file read (evtools.read)
        assert_same_events(stream.read_all(), events)


@pytest.mark.parametrize("guess", [1.0, 2.0, 64.0])
@pytest.mark.parametrize("compression", ["lz4", "zstd"])
def test_a_group_sized_by_a_wrong_guess_decodes_the_same(tmp_path, guess, compression):
    """A group's array is sized by the compression ratio seen so far and grown when that is short: a first guess
    far too small (grown, packet after packet) or far too large gives the same events."""
    from evtools.formats import aedat4

    events = random_events(30_000, seed=4)
    events["t"] = 20 * np.arange(len(events))  # regular times, few pixels: compresses well
    events["x"] %= 4
    events["y"] %= 2
    path = tmp_path / "packets.aedat4"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(aedat4, "PACKET_EVENTS", 700)
        _write(path, events, compression=compression)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(aedat4, "GUESSED_RATIO", guess)
        _, back = read_all(path, chunk_events=8192)
    assert_same_events(back, events)
    # the data compress 1.8x or more: a guess of 1 (1.125 with the margin) sizes the first group's array short
    assert 16 * len(events) / path.stat().st_size > 1.5


def test_groups_stay_about_a_chunk_after_empty_packets(tmp_path):
    """A run of empty event packets decodes to nothing: the next groups are still sized by the bytes of about a
    chunk, not grown to the rest of the file."""
    import struct

    from evtools.formats import aedat4

    events = random_events(40_000, seed=9)
    stream = io.BytesIO()
    writer = Aedat4Writer(stream, StreamInfo(346, 260), WriteOptions("lz4"))
    empty = writer.compress(aedat4._packet_prefix(0))
    for _ in range(300):
        stream.write(struct.pack("<iI", 0, len(empty)) + empty)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(aedat4, "PACKET_EVENTS", 500)
        writer.write(events)
        writer.close()
    path = tmp_path / "empty_packets.aedat4"
    path.write_bytes(stream.getvalue())
    sizes = []
    decode_group = aedat4.Aedat4Reader._decode_group
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(aedat4.Aedat4Reader, "_decode_group",
                      lambda self, group: sizes.append(sum(len(body) for body, _ in group))
                      or decode_group(self, group))
        _, back = read_all(path, chunk_events=4096)
    assert_same_events(back, events)
    assert len(sizes) > 5 and max(sizes) <= 16 * 4096 + max(len(empty), 16 * 500)


def test_a_pipe_groups_the_packets_that_have_arrived(tmp_path):
    """A live input (here a FIFO fed from a file, as `cat file | evtools ...`) is decoded in groups of the packets
    already there, not packet by packet (a 10M-event DV file through a pipe: 1.12 -> 0.6 s), with the same events."""
    import os
    import threading

    from evtools.formats import aedat4

    events = random_events(40_000, seed=13)
    path = tmp_path / "small.aedat4"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(aedat4, "PACKET_EVENTS", 400)
        with create_events(path, StreamInfo(346, 260), compression="lz4") as writer:
            writer.write(events)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    feeder = threading.Thread(target=lambda: fifo.write_bytes(path.read_bytes()))
    feeder.start()
    groups = []
    decode_group = aedat4.Aedat4Reader._decode_group
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(aedat4.Aedat4Reader, "_decode_group",
                      lambda self, group: groups.append(len(group)) or decode_group(self, group))
        with open_events(str(fifo)) as stream:
            back = join(list(stream))
    feeder.join()
    assert_same_events(back, events)
    assert sum(groups) == 101 and len(groups) < 60  # 100 packets and the end mark, not one group each


def test_recycled_chunk_memory_is_reused_only_when_nothing_refers_to_it():
    from evtools.formats.io import Recycled

    pool = Recycled(keep=3)
    first = pool.take(100)
    part = first[10:20]  # a view of a view: it keeps the memory too
    del first
    second = pool.take(100)
    assert not np.shares_memory(second, part)
    del part
    third = pool.take(90)
    assert not np.shares_memory(third, second) and third.base is not None and len(third) == 90
    kept = id(third.base)
    del third
    assert id(pool.take(100).base) == kept  # free again: reused, not allocated


def test_chunks_held_by_the_consumer_are_never_overwritten(tmp_path):
    """The reader recycles its chunks' memory: every chunk kept (or a slice of it) still holds its events."""
    events = random_events(60_000, seed=8)
    path = tmp_path / "held.aedat4"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("evtools.formats.aedat4.PACKET_EVENTS", 700)
        with create_events(path, StreamInfo(346, 260), compression="lz4") as writer:
            writer.write(events)
    with open_events(path, chunk_events=2000) as stream:
        slices = [chunk[: len(chunk) // 2 + 1].copy() for chunk in stream]  # copies: the truth
    with open_events(path, chunk_events=2000) as stream:
        held = [chunk[: len(chunk) // 2 + 1] for chunk in stream]  # views only
    assert len(held) > 20 and all(np.array_equal(a, b) for a, b in zip(held, slices))


def test_empty_stream_round_trips(tmp_path):
    _write(tmp_path / "empty.aedat4", random_events(0))
    info, events = read_all(tmp_path / "empty.aedat4")
    assert (info.width, info.height, len(events)) == (346, 260, 0)


def test_truncated_packet_is_reported_with_its_offset(tmp_path, caplog):
    """(Its events are lost, the packets before it read: tests/test_faults.py.)"""
    _write(tmp_path / "a.aedat4", random_events(1000))
    data = (tmp_path / "a.aedat4").read_bytes()
    (tmp_path / "cut.aedat4").write_bytes(data[:-100])
    assert len(read_all(tmp_path / "cut.aedat4")[1]) == 0  # (one packet)
    assert re.search(r"cut.aedat4: truncated AEDAT 4.0 packet at byte \d+.*the file was cut", caplog.text)


def test_wrong_compression_name_is_an_error(tmp_path):
    with pytest.raises(FormatError, match="unknown AEDAT 4.0 compression 'brotli'"):
        _write(tmp_path / "a.aedat4", random_events(10), compression="brotli")
    assert not (tmp_path / "a.aedat4").exists()


@pytest.mark.parametrize("compression", ["none", "lz4"])
def test_padding_bytes_from_a_file_are_zeroed(tmp_path, monkeypatch, compression):
    """Records are copied as raw bytes (not field by field); the 3 padding bytes of each event, whatever another
    writer left in them, are zero in the chunks (uncompressed: read in place; LZ4: copied from the packet)."""
    import evtools.formats.aedat4 as aedat4

    events = make_events([1, 2, 3], [4, 5, 6], [7, 8, 9], [True, False, True])
    events.view(np.uint64).reshape(-1, 2)[:, 1] |= np.uint64(0xABCDEF << 40)  # another writer's padding
    path = tmp_path / "padded.aedat4"
    with monkeypatch.context() as patch:  # a writer that keeps the padding
        patch.setattr(aedat4, "PAYLOAD_MASK", np.uint64(2**64 - 1))
        with create_events(str(path), StreamInfo(16, 16), compression=compression) as writer:
            writer.write(events)
    assert b"\xef\xcd\xab" in path.read_bytes() or compression == "lz4"
    _, back = read_all(path)
    words = back.view(np.uint64).reshape(-1, 2)
    assert np.all(words[:, 1] >> np.uint64(40) == 0)
    assert np.array_equal(back["x"], events["x"]) and np.array_equal(back["p"], events["p"])


@pytest.mark.parametrize("compression", ["lz4", "zstd"])
def test_many_compressed_packets_in_order_and_a_corrupt_one_named(tmp_path, compression):
    """Packets are decompressed ahead on a thread and placed in file order; a packet that does not decompress is
    reported with its byte offset."""
    events = random_events(200_000, 64, 48, seed=5)  # 7 packets of 32,768 events
    path = tmp_path / "many.aedat4"
    with create_events(str(path), StreamInfo(64, 48), compression=compression) as writer:
        writer.write(events)
    _, back = read_all(path)
    assert_same_events(back, events)
    data = bytearray(path.read_bytes())
    data[len(data) // 2: len(data) // 2 + 64] = bytes(64)  # spoil a packet in the middle
    path.write_bytes(bytes(data))
    # LZ4 frames carry checksums (the packet is refused); a zstd frame without one may decode into garbage, which
    # the stream check refuses (times going backwards): never a silent result
    from evtools.errors import EvtoolsError

    with pytest.raises(EvtoolsError, match="many.aedat4: (cannot decompress packet at byte|truncated|time goes)"):
        read_all(path)


@pytest.mark.parametrize("compression", ["none", "lz4"])
def test_a_stream_cut_at_a_packet_boundary_is_not_passed_as_whole(tmp_path, compression):
    """evtools ends every AEDAT 4.0 stream with an end mark (an empty event packet, announced in the header):
    dv-processing reads such a file as before; without the mark, a pipe is an error (exit 1, one line, no output)
    and a file a warning (its events are read); a stream of another writer is not checked."""
    import subprocess

    from tests.helpers import EVTOOLS

    events = random_events(5000, 64, 48, seed=3)
    whole = tmp_path / "whole.aedat4"
    with create_events(whole, StreamInfo(64, 48), compression=compression) as writer:
        writer.write(events[:2500])
        writer.write(events[2500:])
    data = whole.read_bytes()
    assert b'key="evtoolsEndMark"' in data[:2000]
    packets = aedat4_packets(data)
    assert len(packets) >= 2
    cut = tmp_path / "cut.aedat4"
    cut.write_bytes(data[:packets[-1]])  # the end mark removed: a cut at a packet boundary
    assert len(_read_by_dv(whole)) == 5000
    piped = subprocess.run([EVTOOLS, "convert", "-", "-o", tmp_path / "out.aedat4"], input=cut.read_bytes(),
                           capture_output=True)
    assert piped.returncode == 1 and piped.stderr.count(b"\n") == 1 and b"without the end mark" in piped.stderr
    assert not (tmp_path / "out.aedat4").exists()
    from_file = subprocess.run([EVTOOLS, "info", cut], capture_output=True)
    assert from_file.returncode == 0 and b"warning" in from_file.stderr and b"without the end mark" in from_file.stderr
    assert_same_events(read_all(cut)[1], events)
    intact = subprocess.run([EVTOOLS, "info", whole], capture_output=True)
    assert intact.returncode == 0 and intact.stderr == b""


@pytest.mark.parametrize("output", ["h5", "csv", "txt", "aedat4", "aedat", "raw"])
def test_a_cut_file_converted_to_any_format_is_marked_cut_or_refused(tmp_path, output):
    """A cut AEDAT 4.0 file (its end mark missing) converted to HDF5, CSV or text came out looking whole (a QA
    sweep): each output now says it (HDF5's attribute ``cut``, a last comment line, AEDAT 4.0's missing end mark),
    evtools warns reading it and carries the cut on through the next command; AEDAT 2.0 and RAW, with nowhere to
    say it, are refused (exit 1, one line, no file)."""
    import subprocess

    from tests.helpers import EVTOOLS

    events = random_events(3000, 64, 48, seed=5)
    whole = tmp_path / "whole.aedat4"
    with create_events(whole, StreamInfo(64, 48)) as writer:
        writer.write(events)
    data = whole.read_bytes()
    packets = aedat4_packets(data)
    cut = tmp_path / "cut.aedat4"
    cut.write_bytes(data[:packets[-1]])
    out = tmp_path / f"out.{output}"
    converted = subprocess.run([EVTOOLS, "convert", cut, "-o", out, "-q"], capture_output=True)
    if output in ("aedat", "raw"):
        assert converted.returncode == 1 and converted.stderr.count(b"\n") == 1, converted.stderr
        assert b"nowhere to say so" in converted.stderr and not out.exists()
        return
    assert converted.returncode == 0 and out.exists(), converted.stderr
    assert_same_events(read_all(out)[1], events)
    read = subprocess.run([EVTOOLS, "info", out, "--json"], capture_output=True)
    assert read.returncode == 0 and b"warning" in read.stderr and b"cut" in read.stderr
    assert json.loads(read.stdout)["cut"] is True
    again = tmp_path / "again.h5"  # the cut is carried on
    subprocess.run([EVTOOLS, "convert", out, "-o", again, "-q"], check=True, capture_output=True)
    assert b"written from a cut input" in subprocess.run([EVTOOLS, "info", again], capture_output=True).stderr
    if output == "csv":  # noise added to a cut recording (simulate EVENTS) says so too
        noisy = tmp_path / "noisy.csv"
        subprocess.run([EVTOOLS, "simulate", cut, "--shot-noise-rate-hz", "1", "--seed", "1", "-o", noisy, "-q"],
                       check=True, capture_output=True)
        assert b"cut input" in subprocess.run([EVTOOLS, "info", noisy], capture_output=True).stderr
    # a whole stream's outputs say nothing
    intact = tmp_path / f"intact.{output}"
    subprocess.run([EVTOOLS, "convert", whole, "-o", intact, "-q"], check=True, capture_output=True)
    intact_info = subprocess.run([EVTOOLS, "info", intact, "--json"], capture_output=True)
    assert intact_info.stderr == b"" and json.loads(intact_info.stdout)["cut"] is False


def test_the_header_uses_only_attribute_types_every_reader_knows(tmp_path):
    """faery 0.7's decoder refuses an info node attribute of type "bool" (evtools' end mark once was one, and
    faery could not open evtools' files): every attribute is an "int" or a "string"; faery reads the file (the test
    extra brings faery)."""
    import re

    events = random_events(3000, 64, 48, seed=5)
    path = tmp_path / "x.aedat4"
    with create_events(path, StreamInfo(64, 48), compression="lz4") as writer:
        writer.write(events)
    header = path.read_bytes()[:3000].split(b"</dv>")[0].decode("latin-1")
    types = set(re.findall(r'<attr key="[^"]+" type="([a-z]+)"', header))
    assert types and types <= {"int", "string"}
    import faery  # the test extra brings it

    assert len(faery.events_stream_from_file(path).to_array()) == 3000


def _read_by_dv(path):
    dv = pytest.importorskip("dv_processing", reason="dv-processing (the test extra) reads the file back")
    recording, batches = dv.io.MonoCameraRecording(str(path)), []
    while recording.isRunning():
        batch = recording.getNextEventBatch()
        if batch is not None:
            batches.append(batch.numpy())
    return np.concatenate(batches)


def test_a_given_sensor_size_that_differs_from_the_files_is_warned(tmp_path):
    """--sensor-size over the size an AEDAT 4.0 file states: used, with a warning (it was silent)."""
    from tests.helpers import run

    path = tmp_path / "a.aedat4"
    with create_events(path, StreamInfo(32, 24)) as writer:
        writer.write(random_events(100, 32, 24, seed=1))
    result = run("info", path, "--sensor-size", "64x64")
    assert b"file says 32x24, using --sensor-size 64x64" in result.stderr


@settings(max_examples=60, deadline=None)
@given(st.text(max_size=30))
@example("cam\x01x")  # (the interop session's: evtools, aedat and faery refused the file evtools wrote)
@example("\ud800<&>\ufffe\r\n\t")
def test_any_source_name_gives_a_file_every_reader_parses(tmp_path_factory, source):
    """A source name of any characters (a file name with a control character, say) is written so that the stream
    description stays XML: characters XML forbids become U+FFFD, the rest come back (line ends as XML reads them)."""
    import faery

    path = tmp_path_factory.mktemp("source") / "events.aedat4"
    events = make_events([1, 2], [0, 1], [0, 1], [1, 0])
    evtools.write(path, events, StreamInfo(4, 4, metadata={"source": source}))
    read, info = evtools.read(path)
    assert_same_events(read, events)
    kept = "".join("\ufffd" if (ord(c) < 32 and c not in "\t\n\r") or 0xD800 <= ord(c) <= 0xDFFF
                   or c in "\ufffe\uffff" else c for c in (source or "evtools"))
    assert info.metadata["source"] == kept.replace("\r\n", "\n").replace("\r", "\n")
    assert len(faery.events_stream_from_file(path).to_array()) == 2


@given(st.data())
@settings(max_examples=60, deadline=None)
def test_damage_to_a_compressed_packet_evtools_wrote_is_an_error_not_other_events(data):
    """Issue 37 item 5: payload damage in AEDAT 4.0 read as other events in 5-8 % of mutants. evtools' LZ4 and
    zstd packets carry their codec's content checksum (which DV's and dv-processing's decoders check too): one
    flipped bit anywhere in a packet's body is an error naming the file, or changes nothing the packet decodes to
    (a compressed match copying zeros from another offset of zeros), never other events."""
    import tempfile
    from pathlib import Path

    import evtools
    from evtools.errors import EvtoolsError

    n = data.draw(st.integers(1, 40_000))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31 - 1)))
    events = evtools.from_columns(np.sort(rng.integers(0, 10_000_000, n)), rng.integers(0, 346, n),
                                  rng.integers(0, 260, n), rng.integers(0, 2, n))
    compression = data.draw(st.sampled_from(["lz4", "lz4-high", "zstd", "zstd-high"]))
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "e.aedat4"
        evtools.write(path, events, evtools.StreamInfo(346, 260), compression=compression)
        raw = bytearray(path.read_bytes())
        position = len(b"#!AER-DAT4.0\r\n")
        header_size = struct.unpack_from("<I", raw, position)[0]
        _, table_at, _ = _parse_ioheader(bytes(raw[position + 4:position + 4 + header_size]), "e")
        position += 4 + header_size
        bodies = []  # the packets up to the file's data table (an index that readers may ignore)
        while position + 8 <= (table_at if table_at > 0 else len(raw)):
            size = struct.unpack_from("<I", raw, position + 4)[0]
            bodies.append((position + 8, size))
            position += 8 + size
        start, size = data.draw(st.sampled_from([body for body in bodies if body[1] > 0]))
        raw[start + data.draw(st.integers(0, size - 1))] ^= 1 << data.draw(st.integers(0, 7))
        path.write_bytes(bytes(raw))
        try:
            assert_same_events(evtools.read(path)[0], events)
        except EvtoolsError as error:
            assert "e.aedat4" in str(error)


def _read_both_ways(path, monkeypatch, block_bytes: int):
    """(events, frames, metadata) or the error message, read by the block scan and by the per-packet path."""
    import evtools.formats.aedat4 as aedat4
    from evtools.errors import EvtoolsError

    results = []
    for scan in (True, False):
        monkeypatch.setattr(aedat4, "SCAN_PACKETS", scan)
        monkeypatch.setattr(aedat4, "SCAN_BLOCK_BYTES", block_bytes)
        try:
            events, info, frames = evtools.read(path, frames=True)
            results.append((events, [(f.t_us, f.image.tobytes()) for f in frames], info.metadata))
        except EvtoolsError as error:
            results.append(str(error))
    return results


@given(st.data())
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_the_block_scan_reads_what_the_per_packet_path_reads(tmp_path, monkeypatch, data):
    """Uncompressed files are read a block of whole packets at a time by a kernel (issue 42: 17 us a packet in
    Python); on random streams in random packet sizes, with APS frames among them, blocks from 64 bytes (every
    packet straddles them) to a megabyte, whole or cut anywhere, the events, frames, metadata and errors are
    those of the per-packet path."""
    import evtools.formats.aedat4 as aedat4
    from evtools.frames import Frame

    rng = np.random.default_rng(data.draw(st.integers(0, 2**31 - 1)))
    n = data.draw(st.integers(0, 3000))
    events = make_events(np.sort(rng.integers(0, 2_000_000, n)), rng.integers(0, 64, n), rng.integers(0, 48, n),
                         rng.integers(0, 2, n))
    frames = [Frame(rng.integers(0, 256, (48, 64), dtype=np.uint8), int(t), int(t) - 500, int(t) + 500)
              for t in np.sort(rng.integers(1000, 2_000_000, data.draw(st.integers(0, 5))))]
    monkeypatch.setattr(aedat4, "PACKET_EVENTS", data.draw(st.integers(1, 700)))
    path = tmp_path / "s.aedat4"
    evtools.write(path, events, StreamInfo(64, 48), frames=frames)
    raw = bytearray(path.read_bytes())
    at = 0
    for record in events.view(np.uint8).reshape(-1, 16):  # each event's padding made garbage, as files may hold
        at = raw.index(record[:13].tobytes(), at)
        raw[at + 13:at + 16] = rng.integers(0, 256, 3, dtype=np.uint8).tobytes()
        at += 16
    if data.draw(st.booleans()):  # cut anywhere after the header
        raw = raw[:data.draw(st.integers(200, len(raw)))]
    path.write_bytes(raw)
    block = data.draw(st.sampled_from([64, 100, 1000, 4096, 1 << 20]))
    scanned, per_packet = _read_both_ways(path, monkeypatch, block)
    if isinstance(per_packet, str):
        assert scanned == per_packet
    else:
        assert_same_events(scanned[0], per_packet[0])
        assert scanned[1] == per_packet[1] and scanned[2] == per_packet[2]
        assert not scanned[0].view(np.uint8).reshape(-1, 16)[:, 13:].any()  # the padding zeroed


def test_the_block_scan_reads_dvs_own_small_packets_as_the_per_packet_path(tmp_path, monkeypatch):
    """A file dv-processing wrote (its flatbuffer layout, packets of a few hundred events as DV writes a DAVIS346,
    LZ4 off) reads the same both ways and as dv-processing reads it."""
    dv = pytest.importorskip("dv_processing")
    rng = np.random.default_rng(5)
    n = 20_000
    path = tmp_path / "dv.aedat4"
    config = dv.io.MonoCameraWriter.Config("test")
    config.addEventStream((346, 260))
    config.compression = dv.CompressionType.NONE
    writer = dv.io.MonoCameraWriter(str(path), config)
    t = np.sort(rng.integers(0, 5_000_000, n))
    x, y, p = rng.integers(0, 346, n), rng.integers(0, 260, n), rng.integers(0, 2, n)
    start = 0
    while start < n:
        size = int(rng.integers(1, 900))
        store = dv.EventStore()
        for i in range(start, min(n, start + size)):
            store.push_back(int(t[i]), int(x[i]), int(y[i]), bool(p[i]))
        writer.writeEvents(store)
        start += size
    del writer
    for block in (64, 4096, 1 << 20):
        scanned, per_packet = _read_both_ways(path, monkeypatch, block)
        assert_same_events(scanned[0], per_packet[0])
        assert_same_events(scanned[0], make_events(t, x, y, p))


@given(st.data())
@settings(max_examples=60, deadline=None)
def test_a_group_of_compressed_packets_decodes_as_each_packet_alone(data):
    """Issue 42: a decoding thread lays a group's decompressed packets end to end and one kernel copies their events
    (``copy_decoded_packets``). On random groups - packet sizes, garbage in every event's padding, packets without
    events, a damaged or foreign flatbuffer among them - the events (padding zeroed) and the events of the group's
    last packet are those of each packet decompressed and parsed alone by the Python parser, and a packet that parser
    refuses is refused with its message."""
    import threading

    import lz4.frame

    import evtools.formats.aedat4 as aedat4
    from evtools.formats.io import Recycled

    rng = np.random.default_rng(data.draw(st.integers(0, 2**31 - 1)))
    bodies = []
    for _ in range(data.draw(st.integers(1, 12))):
        kind = data.draw(st.sampled_from(["events"] * 6 + ["empty", "trailing", "foreign"]))
        count = int(rng.integers(0, 700))
        records = rng.integers(0, 256, 16 * count, dtype=np.uint8).tobytes()  # times, x, y, p, padding: any bytes
        if kind == "events":
            bodies.append(aedat4._packet_prefix(count) + records)
        elif kind == "empty":
            bodies.append(aedat4._packet_prefix(0))
        elif kind == "trailing":  # bytes after the events: the Python parser reads it, the kernel leaves it
            bodies.append(aedat4._packet_prefix(count) + records + bytes(8))
        else:
            bodies.append(b"\x20\x00\x00\x00\x10\x00\x00\x00FRME" + bytes(24))
    group = [(lz4.frame.compress(body), 100 * k) for k, body in enumerate(bodies)]
    reader = aedat4.Aedat4Reader.__new__(aedat4.Aedat4Reader)
    reader.name, reader.decompress = "g.aedat4", aedat4._decompressor(1, "g.aedat4")
    reader._recycled, reader._staging = Recycled(), threading.local()
    try:
        expected = [aedat4._packet_events(body, "g.aedat4", 100 * k) for k, body in enumerate(bodies)]
    except FormatError as error:
        with pytest.raises(FormatError) as raised:
            reader._decode_group(group)
        assert str(raised.value) == str(error)
        return
    want = np.zeros(sum(len(e) for e in expected), evtools.EVENT_DTYPE)  # (concatenate would drop the padding)
    want.view(np.uint8)[:] = np.frombuffer(b"".join(e.tobytes() for e in expected), np.uint8)
    want.view(np.uint8).reshape(-1, 16)[:, 13:] = 0
    for _ in range(2):  # the thread's staging buffer is reused from group to group
        events, last, ratio = reader._decode_group(group)
        assert events.tobytes() == want.tobytes()
        assert last == len(expected[-1]) and ratio >= 1.0


# --- side streams (IMU samples, triggers): carried from an AEDAT 4.0 input to an AEDAT 4.0 output ---


def _dv_side_streams(path) -> tuple[list, list]:
    """(IMU samples, triggers) of an AEDAT 4.0 file as dv-processing reads them (each a tuple of its values)."""
    dv = pytest.importorskip("dv_processing", reason="dv-processing (the test extra) writes and reads side streams")
    imu, triggers = [], []
    recording = dv.io.MonoCameraRecording(str(path))
    if recording.isImuStreamAvailable():
        while (batch := recording.getNextImuBatch()) is not None:
            imu += [(s.timestamp, s.temperature, s.accelerometerX, s.accelerometerY, s.accelerometerZ, s.gyroscopeX,
                     s.gyroscopeY, s.gyroscopeZ) for s in batch]
    recording = dv.io.MonoCameraRecording(str(path))
    if recording.isTriggerStreamAvailable():
        while (batch := recording.getNextTriggerBatch()) is not None:
            triggers += [(trigger.timestamp, int(trigger.type)) for trigger in batch]
    return imu, triggers


def _write_with_side_streams(path, events, side, compression: str) -> None:
    """An AEDAT 4.0 file as DV records a camera with an IMU and a trigger input, by dv-processing's writer: the
    events, and ``side``'s packets (``(kind, sample times, lag_us)``: an IMU or trigger packet stored after the
    events up to its last sample's time + its lag, as a writer that fills a packet before storing it)."""
    dv = pytest.importorskip("dv_processing", reason="dv-processing (the test extra) writes side streams")
    config = dv.io.MonoCameraWriter.Config("test")
    config.addEventStream((64, 48))
    config.addImuStream()
    config.addTriggerStream()
    config.compression = {"lz4": dv.CompressionType.LZ4, "none": dv.CompressionType.NONE,
                          "zstd": dv.CompressionType.ZSTD}[compression]
    writer = dv.io.MonoCameraWriter(str(path), config)
    written = 0
    for kind, times, lag_us in sorted(side, key=lambda packet: packet[1][-1] + packet[2]) + [(None, [np.inf], 0)]:
        upto = int(np.searchsorted(events["t"], times[-1] + lag_us, side="left"))
        if upto > written:
            store = dv.EventStore()
            for event in events[written:upto]:
                store.push_back(int(event["t"]), int(event["x"]), int(event["y"]), bool(event["p"]))
            writer.writeEvents(store)
            written = upto
        if kind == "imu":
            packet = dv.IMUPacket()
            for k, t_us in enumerate(times):
                packet.elements.append(dv.IMU(int(t_us), 30.0 + k, 0.1 * k, -0.2, 1.0, 0.5 * k, 0.0, -0.5, 0, 0, 0))
            writer.writeImuPacket(packet)
        elif kind == "trigger":
            packet = dv.TriggerPacket()
            for t_us in times:
                packet.elements.append(dv.Trigger(int(t_us), dv.TriggerType.EXTERNAL_SIGNAL_RISING_EDGE))
            writer.writeTriggerPacket(packet)
    del writer  # (dv-processing completes the file on destruction)


@st.composite
def _side_packets(draw, span_us: int) -> list:
    """IMU and trigger packets of 1-3 samples each, in time order per stream, each stored up to 5 ms late."""
    packets = []
    for kind in ("imu", "trigger"):
        times, stored_us = sorted(draw(st.lists(st.integers(0, span_us), max_size=12))), 0
        while times:
            size = draw(st.integers(1, min(3, len(times))))
            stored_us = max(stored_us, times[size - 1] + draw(st.integers(0, 5000)))  # (a stream's packets in order)
            packets.append((kind, times[:size], stored_us - times[size - 1]))
            times = times[size:]
    return packets


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 3000), seed=st.integers(0, 2**31), data=st.data(),
       compressions=st.tuples(st.sampled_from(["lz4", "none", "zstd"]), st.sampled_from(["lz4", "none", "zstd"])),
       chunk_events=st.sampled_from([1, 7, 300, 1 << 20]), end=st.none() | st.floats(0, 1.2))
def test_imu_samples_and_triggers_are_carried_to_an_aedat4_output(tmp_path, n, seed, data, compressions,
                                                                  chunk_events, end):
    """A DV recording's IMU samples and triggers were dropped by every command that wrote AEDAT 4.0 (the input lost,
    said in a warning). They now go on as they were, read back by dv-processing sample for sample, whatever the
    compressions, the chunks, and a time slice (``--end``: the packets that begin before it, even those stored
    after later events), and the events are unchanged."""
    from evtools.cli.convert import convert_one
    from evtools.formats.registry import ReadOptions
    from evtools.transform import Time

    events = random_events(n, 64, 48, seed=seed, t0_us=1_000)
    side = data.draw(_side_packets(int(events["t"][-1]) + 100))
    source = tmp_path / f"in_{seed}_{n}.aedat4"
    _write_with_side_streams(source, events, side, compressions[0])
    imu_in, triggers_in = _dv_side_streams(source)
    assert len(imu_in) + len(triggers_in) == sum(len(times) for _, times, _ in side)
    out = tmp_path / f"out_{seed}_{n}.aedat4"
    end_us = None if end is None else int(end * (events["t"][-1] - events["t"][0]))
    convert_one(source, out, reading=ReadOptions(chunk_events=chunk_events), output_format=None,
                compression=compressions[1], slicing=None if end_us is None else {"end": Time(end_us)})
    limit = np.inf if end_us is None else int(events["t"][0]) + end_us
    kept = {kind: sorted(t for packet_kind, times, _ in side if packet_kind == kind and times[0] < limit
                         for t in times) for kind in ("imu", "trigger")}
    imu_out, triggers_out = _dv_side_streams(out)
    assert [sample[0] for sample in imu_out] == kept["imu"]
    assert [trigger[0] for trigger in triggers_out] == kept["trigger"]
    assert all(sample in imu_in for sample in imu_out) and all(trigger in triggers_in for trigger in triggers_out)
    assert_same_events(read_all(out)[1], events[events["t"] < limit])


def test_a_recordings_imu_and_triggers_go_through_bafilter_and_are_said_where_they_cannot(tmp_path):
    """The real DAVIS346 recording (IMU, triggers, frames) through ``bafilter``: dv-processing reads the same IMU
    samples and triggers from the output as from the recording; to HDF5, which has no place for them, a warning
    says they are not in the output."""
    from tests.helpers import run

    recording = data_file("davis346_lab_frames.aedat4")
    imu, triggers = _dv_side_streams(recording)
    assert len(imu) == 130 and len(triggers) == 15
    filtered = tmp_path / "filtered.aedat4"
    result = run("bafilter", recording, "--method", "baf", "-o", filtered)
    assert b"not in the output" not in result.stderr
    assert _dv_side_streams(filtered) == (imu, triggers)
    to_hdf5 = run("convert", recording, "-o", tmp_path / "out.h5")
    assert b"24 packets of its imu, triggers streams are not in the output" in to_hdf5.stderr
    events, info = evtools.read(recording)  # from Python: the events alone, no stream declared empty
    evtools.write(tmp_path / "api.aedat4", events, info)
    dv = pytest.importorskip("dv_processing")
    assert not dv.io.MonoCameraRecording(str(tmp_path / "api.aedat4")).isImuStreamAvailable()


def test_a_side_packets_time_is_its_first_elements():
    """A second event stream carried as a side stream is placed by its first event's time (its elements are structs,
    not tables: read as a table's offset its time was garbage); an unknown packet type has none (it then takes the
    time of the side packet before it)."""
    from evtools.formats.aedat4 import _first_element_us, _packet_prefix

    events = make_events([123, 456], [1, 2], [3, 4], [True, False])
    body = _packet_prefix(2) + events.tobytes()
    assert _first_element_us(body) == 123
    assert _first_element_us(_packet_prefix(0)) is None
    assert _first_element_us(body[:8] + b"XXXX" + body[12:]) is None
