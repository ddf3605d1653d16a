"""Peers benchmark (issue 15): evtools beside dv-processing, aedat and faery, measured in one run.

The files: the real DVXplorer recording (111,954 events) repeated in time to ``--events`` events (10 M and 50 M),
written by dv-processing's ``MonoCameraWriter`` as DV stores recordings (issue 42: files evtools wrote flattered
it): AEDAT 4.0, LZ4 (DV's linked blocks) and uncompressed, in packets of the recording's own size (1,898 events,
about 10 ms: a reader's cost per packet counts), in ``/dev/shm`` when it has room. Every row is a
whole process (interpreter start-up and imports included), the fastest of ``--repeat`` runs (the tools compared
in a row measured in turns), with its peak RSS from ``wait4``:

- read into numpy: ``evtools.read``; ``aedat.Decoder`` (packets concatenated); dv-processing's
  ``MonoCameraRecording`` (batches' ``numpy()`` concatenated); faery's ``events_stream_from_file(...).to_array()``;
- ``bafilter --preset dv`` file to file against dv-processing's read + ``BackgroundActivityNoiseFilter`` + write,
  both writing the input's compression (``--compression lz4``: the LZ4 file filtered is stored as DV stores it);
- ``estimate --method offe`` and ``correct`` (with offe's map) file to file, against issue 15's targets (30 Mev/s
  whole process, peak RSS under 100 MiB); ``correct`` also on the recording made 50 times denser (9.5 Mev/s: its
  reorder buffer holds 0.9 s of output);
- start-up: 1,000 events read;
- Prophesee RAW read into numpy: the real Gen4.1 recording (EVT 3.0, 219,596 events in 8.8 ms) repeated in time to
  the same sizes, written by faery as EVT 3.0 (vectorised, as Metavision writes Gen4 recordings) and by evtools as
  EVT 2.0 (Gen3's format), against faery and evlib (``load_events(...).collect()``, its columns as numpy).

Ratios are peer time / evtools time (> 1: evtools is faster). Peers missing from the environment are installed
into it with pip first (``aedat``, ``evlib``; dv-processing and faery come with the test extra).

Run: ``python -m tests.bench.bench_peers [--events 10000000,50000000] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from tests.bench.common import fastest, fastest_each, measure_child, measure_command, scratch_dir

EVTOOLS = str(Path(sys.executable).with_name("evtools"))
RECORDING = Path(__file__).resolve().parents[3] / "shared" / "data" / "dvxplorer_sample.aedat4"
GEN4_RECORDING = RECORDING.with_name("gen41_sample.evt3.raw")
PEERS = {"aedat": "aedat", "faery": "faery", "dv_processing": "dv-processing", "evlib": "evlib"}


def ensure_peers() -> list[str]:
    """Install the missing peers into this environment; the names that are available."""
    missing = [package for module, package in PEERS.items() if importlib.util.find_spec(module) is None]
    if missing:
        subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", *missing], check=False)
        importlib.invalidate_caches()
    return [module for module in PEERS if importlib.util.find_spec(module) is not None]


def recorded_packet_events(path: Path) -> int:
    """The mean number of events in the event packets of the AEDAT 4.0 file ``path`` (DV's packets: 1,897 in the
    DVXplorer recording, about 10 ms each)."""
    import struct

    from evtools.formats import open_events

    with open_events(path) as stream:
        reader, events = stream.reader, len(stream.read_all())
    packets, end = 0, reader.data_position if reader.data_position > 0 else float("inf")  # (DV's index table)
    with open(path, "rb") as file:
        file.seek(14)  # the magic
        (length,) = struct.unpack("<I", file.read(4))
        file.seek(length, 1)
        while file.tell() < end and len(head := file.read(8)) == 8:
            stream_id, size = struct.unpack("<iI", head)
            packets += stream_id == reader.stream_id
            file.seek(size, 1)
    return max(1, round(events / max(packets, 1)))


def make_file(path: Path, events: int, compression: str, denser: int = 1, packet_events: int | None = None) -> None:
    """``events`` events of the recording repeated in time, written by dv-processing's ``MonoCameraWriter`` as DV
    writes a recording (its LZ4: linked blocks, no stored size), in packets of the recording's own size (the
    reader's cost per packet counts) or of ``packet_events``; ``denser``: times divided by it (a busier scene: 50
    gives 9.5 Mev/s)."""
    import dv_processing as dv

    import evtools

    recording, info = evtools.read(RECORDING)
    recording["t"] -= recording["t"][0]
    recording["t"] //= denser
    span_us = int(recording["t"][-1]) + 1
    packet_events = packet_events or recorded_packet_events(RECORDING)
    config = dv.io.MonoCameraWriter.Config("bench")
    config.addEventStream((info.width, info.height))
    config.compression = dv.CompressionType.LZ4 if compression == "lz4" else dv.CompressionType.NONE
    writer = dv.io.MonoCameraWriter(str(path), config)
    with tempfile.TemporaryDirectory(dir=path.parent) as folder:  # the tiled events, read back by dv in batches
        tiled = Path(folder) / "tiled.aedat4"
        _write_tiled(tiled, recording, info, span_us, events)
        source = dv.io.MonoCameraRecording(str(tiled))
        while (batch := source.getNextEventBatch()) is not None:  # (a batch: one of evtools' large packets)
            for start in range(0, batch.size(), packet_events):
                writer.writeEventPacket(batch.slice(start, min(packet_events, batch.size() - start)).toPacket())
    del writer  # (closes the file: dv-processing writes its index on destruction)


def _write_tiled(path: Path, recording, info, span_us: int, events: int) -> None:
    import evtools

    with evtools.writer(path, info) as sink:
        done, k = 0, 0
        while done < events:
            part = recording[: events - done].copy()
            part["t"] += k * span_us
            sink.write(part)
            done += len(part)
            k += 1


def child_read(tool: str, path: str) -> dict:
    """Read the whole file into one numpy array with ``tool``."""
    if tool == "evtools":
        import evtools

        n = len(evtools.read(path)[0])
    elif tool == "aedat":
        import aedat

        parts = [packet["events"] for packet in aedat.Decoder(path) if "events" in packet]
        n = len(np.concatenate(parts))
    elif tool == "dv_processing":
        import dv_processing as dv

        recording = dv.io.MonoCameraRecording(path)
        parts = []
        while recording.isRunning():
            batch = recording.getNextEventBatch()
            if batch is not None:
                parts.append(batch.numpy())
        n = len(np.concatenate(parts))
    elif tool == "faery":
        import faery

        n = len(faery.events_stream_from_file(path).to_array())
    elif tool == "evlib":
        import evlib

        frame = evlib.load_events(path).collect()
        n = len([frame[column].to_numpy() for column in frame.columns][0])
    else:
        raise SystemExit(f"unknown tool {tool}")
    return {"events": n}


def make_prophesee(path: Path, events: int, version: str) -> None:
    """``events`` events of the Gen4.1 recording repeated in time, as a Prophesee RAW file: EVT 3.0 written by
    faery (vectorised, as Metavision writes), EVT 2.0 by evtools, EVT 2.1 by :func:`write_evt21`; or a Metavision
    HDF5 event file (``hdf5-ecf``) by :func:`write_metavision_hdf5`."""
    import evtools

    recording, info = evtools.read(GEN4_RECORDING)
    span_us = int(recording["t"][-1] - recording["t"][0]) + 1
    copies = -(-events // len(recording))
    tiled = np.tile(recording, copies)[:events]
    tiled["t"] += (np.arange(len(tiled)) // len(recording)) * span_us
    if version == "evt2":
        evtools.write(path, tiled, info)
        return
    if version == "evt21":
        write_evt21(path, tiled, info.width, info.height)
        return
    if version == "hdf5-ecf":
        write_metavision_hdf5(path, tiled, info.width, info.height)
        return
    import faery

    array = np.empty(len(tiled), faery.EVENTS_DTYPE)
    array["t"], array["x"], array["y"], array["on"] = tiled["t"], tiled["x"], tiled["y"], tiled["p"]
    faery.events_stream_from_array(array, (info.width, info.height)).to_file(str(path), version="evt3")


def write_evt21(path: Path, events: np.ndarray, width: int, height: int) -> None:
    """``events`` (times from 0, below 2^34 us) as a GenX320-style EVT 2.1 RAW file, as a sensor groups them: the
    consecutive events of one time, row and polarity in one 32-column group, columns rising, share a word (its
    mask); a time-high word before each word whose ``t >> 6`` differs from the word before's. (evtools reads EVT 2.1
    but does not write it: a numpy encoder for the benchmark alone; ``tests/naive`` holds the tests' encoder.)"""
    t, x, y, p = (events[k].astype(np.int64) for k in ("t", "x", "y", "p"))
    starts = np.flatnonzero(np.concatenate([[True], (t[1:] != t[:-1]) | (y[1:] != y[:-1]) | (p[1:] != p[:-1])
                                            | (x[1:] >> 5 != x[:-1] >> 5) | (x[1:] <= x[:-1])])) if len(t) else []
    masks = np.bitwise_or.reduceat(np.left_shift(1, x & 31), starts) if len(t) else np.zeros(0, np.int64)
    t, x, y, p = t[starts], x[starts] & ~31, y[starts], p[starts]
    typed = (p << 28) | ((t & 63) << 22) | (x << 11) | y
    high = t >> 6
    new_high = np.concatenate([[True], high[1:] != high[:-1]]) if len(t) else np.zeros(0, bool)
    position = np.arange(len(t)) + np.cumsum(new_high)
    words = np.zeros(len(t) + int(new_high.sum()), np.uint64)
    words[position] = (typed.astype(np.uint64) << np.uint64(32)) | masks.astype(np.uint64)
    words[position[new_high] - 1] = ((8 << 28) | (high[new_high] & ((1 << 28) - 1))).astype(np.uint64) << np.uint64(32)
    with open(path, "wb") as file:
        file.write(f"% evt 2.1\n% format EVT21;width={width};height={height}\n% end\n".encode())
        file.write(words.astype("<u8").tobytes())


def _ecf_block(t: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray) -> bytes:
    """One ECF block in the codec's "y, x and p packed" mode (what Metavision's encoder picks for busy sensors),
    numpy-vectorised: the times as runs of equal times, a step of 15 us or more spelled in 4-bit pieces first."""
    n = len(t)
    starts = np.flatnonzero(np.concatenate([[True], t[1:] != t[:-1]]))
    runs = np.diff(np.append(starts, n))
    steps = np.diff(t[starts], prepend=t[0])
    long_step = steps >= 15
    pieces = np.where(long_step, (np.floor(np.log2(np.maximum(steps, 1))).astype(np.int64) >> 2) + 1, 0)
    long_run = runs >= 15
    sizes = pieces + 1 + 2 * long_run
    ends = np.cumsum(sizes)
    times = np.zeros(int(ends[-1]), np.uint8)
    first = ends - sizes
    piece_run = np.repeat(np.arange(len(runs)), pieces)
    piece_index = np.arange(len(piece_run)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    times[first[piece_run] + piece_index] = 0xF0 | ((steps[piece_run] >> (4 * piece_index)) & 15)
    head = first + pieces
    times[head] = (np.where(long_step, 0, steps) << 4) | np.where(long_run, 15, runs)
    times[head[long_run] + 1] = runs[long_run] & 0xFF
    times[head[long_run] + 2] = runs[long_run] >> 8
    values = np.zeros(-(-n // 4) * 4, np.int64)
    values[:n] = (y << 12) | (x << 1) | p
    v0, v1, v2, v3 = (values[j::4] for j in range(4))
    words = np.stack([(v0 << 8) | (v1 & 0xFF), ((v1 >> 8) << 16) | (v2 & 0xFFFF), ((v2 >> 16) << 24) | v3], axis=1)
    header = np.array([(n << 2) | 2], "<u4").tobytes() + np.array([t[0]], "<i8").tobytes()
    return header + times.tobytes() + words.astype("<u4").tobytes()


def write_metavision_hdf5(path: Path, events: np.ndarray, width: int, height: int, chunk: int = 16384) -> None:
    """``events`` as a Metavision HDF5 event file (``CD/events`` in ECF chunks of 16,384 events, the sensor size in
    the root's ``format`` attribute), for the benchmark (``tests/naive`` holds the tests' encoder)."""
    import h5py

    record = np.dtype({"names": ["x", "y", "p", "t"], "formats": ["<u2", "<u2", "<i2", "<i8"],
                       "offsets": [0, 2, 4, 8], "itemsize": 16})
    t, x, y, p = (events[k].astype(np.int64) for k in ("t", "x", "y", "p"))
    with h5py.File(path, "w") as f:
        f.attrs["version"] = "1.0"
        f.attrs["format"] = f"EVT3;height={height};width={width}"
        group = f.create_group("CD")
        dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
        dcpl.set_chunk((chunk,))
        dcpl.set_filter(0x8ECF, h5py.h5z.FLAG_OPTIONAL, ())
        space = h5py.h5s.create_simple((len(t),), (h5py.h5s.UNLIMITED,))
        dataset = h5py.h5d.create(group.id, b"events", h5py.h5t.py_create(record), space, dcpl=dcpl)
        for start in range(0, len(t), chunk):
            part = slice(start, start + chunk)
            dataset.write_direct_chunk((start,), _ecf_block(t[part], x[part], y[part], p[part]), 0)


def child_dv_filter(path: str, out: str, compression: str) -> dict:
    """dv-processing: read, BackgroundActivityNoiseFilter (its defaults), write with ``compression``."""
    import dv_processing as dv

    recording = dv.io.MonoCameraRecording(path)
    config = dv.io.MonoCameraWriter.Config("bench")
    config.addEventStream(recording.getEventResolution())
    config.compression = dv.CompressionType.LZ4 if compression == "lz4" else dv.CompressionType.NONE
    writer = dv.io.MonoCameraWriter(out, config)
    noise_filter = dv.noise.BackgroundActivityNoiseFilter(recording.getEventResolution())
    n = 0
    while recording.isRunning():
        batch = recording.getNextEventBatch()
        if batch is not None:
            n += batch.size()
            noise_filter.accept(batch)
            writer.writeEvents(noise_filter.generateEvents())
    del writer
    return {"events": n}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--events", default="10000000,50000000")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--child", nargs="+")
    args = parser.parse_args()
    if args.child:
        kind, *rest = args.child
        result = child_read(*rest) if kind == "read" else child_dv_filter(*rest)
        print(json.dumps(result))
        return
    if not RECORDING.exists():
        raise SystemExit(f"{RECORDING} is missing (the tests' real recordings)")
    peers = ensure_peers()
    sizes = [int(n) for n in args.events.split(",")]
    folder = Path(tempfile.mkdtemp(prefix="bench_peers_", dir=scratch_dir(max(sizes) * 40)))
    print(f"DVXplorer recording repeated; AEDAT 4.0 as DV writes it; whole processes, fastest of {args.repeat}; "
          f"peers available: {', '.join(peers)}; ratio = peer time / evtools time")
    print(f"{'task':42} {'tool':14} {'seconds':>8} {'Mev/s':>7} {'peak MiB':>9} {'ratio':>6}")
    try:
        tiny = folder / "tiny.aedat4"
        make_file(tiny, 1000, "lz4")
        for events in sizes:
            for compression in ("lz4", "none"):
                path = folder / f"in_{events}_{compression}.aedat4"
                make_file(path, events, compression)
                task = f"read into numpy, {events // 1_000_000}M {compression}"
                tools = ["evtools", *(p for p in ("dv_processing", "aedat", "faery", "evlib") if p in peers)]
                results = fastest_each(args.repeat, [(measure_child, "bench_peers", "read", tool, path)
                                                     for tool in tools], key="wall_seconds")
                for tool, result in zip(tools, results):
                    _row(task, tool, result, events, results[0] if tool != "evtools" else None)
                task = f"bafilter --preset dv file to file, {events // 1_000_000}M {compression}"
                out = folder / "out.aedat4"
                contenders = [(_timed_command, [EVTOOLS, "-q", "bafilter", path, "--method", "baf", "--preset", "dv",
                                                 "-o", out, "--compression", compression])]
                if "dv_processing" in peers:  # both write the input's compression (DV records LZ4)
                    contenders.append((measure_child, "bench_peers", "filter", path, folder / "dv.aedat4",
                                       compression))
                results = fastest_each(args.repeat, contenders, key="wall_seconds")
                _row(task, "evtools", results[0], events, None)
                if len(results) > 1:
                    _row(task, "dv_processing", results[1], events, results[0])
                for name, argv in (("estimate --method offe", ["estimate", path, "--method", "offe", "-o",
                                                              folder / "th.h5"]),
                                   ("correct (offe's thresholds)", ["correct", path, "--thresholds", folder / "th.h5",
                                                                    "-o", out])):
                    task = f"{name}, {events // 1_000_000}M {compression}"
                    ours = fastest(args.repeat, measure_command, [EVTOOLS, "-q", *argv])
                    ours["wall_seconds"] = ours["seconds"]
                    _row(task, "evtools", ours, events, None)
                    print(f"{'':42} {'target':14} {events / 30e6:8.2f} {30.0:7.1f} {100:9.0f}   (issue 15: "
                          f"{'met' if events / ours['seconds'] >= 30e6 else 'not met'} / "
                          f"{'met' if ours['peak_mb'] < 100 else 'not met'})", flush=True)
                path.unlink()
                if events == sizes[0] and compression == "lz4":  # correct on a dense stream: it holds 0.9 s of it
                    make_file(path, events, compression, denser=50)
                    task = f"correct, {events // 1_000_000}M lz4 at 9.5 Mev/s"
                    ours = fastest(args.repeat, measure_command, [EVTOOLS, "-q", "correct", path, "--thresholds",
                                                                  folder / "th.h5", "-o", out])
                    ours["wall_seconds"] = ours["seconds"]
                    _row(task, "evtools", ours, events, None)
                    path.unlink()
        for events in sizes:
            for version in ("evt3", "evt2", "evt21", "hdf5-ecf") if "faery" in peers else ("evt2", "evt21", "hdf5-ecf"):
                path = folder / f"in_{events}_{version}.{'hdf5' if version == 'hdf5-ecf' else 'raw'}"
                make_prophesee(path, events, version)
                task = f"read into numpy, {events // 1_000_000}M {version.upper()} (Gen4)"
                # (faery reads neither EVT 2.1 nor Metavision's HDF5; evlib reads HDF5 ECF only with Prophesee's
                # plugin installed, which the bench does not)
                readers = {"evt21": ("evlib",), "hdf5-ecf": ()}.get(version, ("faery", "evlib"))
                tools = ["evtools", *(p for p in readers if p in peers)]
                results = fastest_each(args.repeat, [(measure_child, "bench_peers", "read", tool, path)
                                                     for tool in tools], key="wall_seconds")
                for tool, result in zip(tools, results):
                    _row(task, tool, result, events, results[0] if tool != "evtools" else None)
                path.unlink()
        task = "start-up: read 1,000 events"
        tools = ["evtools", *(p for p in ("dv_processing", "aedat", "faery") if p in peers)]
        results = fastest_each(args.repeat, [(measure_child, "bench_peers", "read", tool, tiny) for tool in tools],
                               key="wall_seconds")
        for tool, result in zip(tools, results):
            _row(task, tool, result, 1000, results[0] if tool != "evtools" else None)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _timed_command(argv) -> dict:
    """:func:`measure_command` with its wall time under the key the children's rows use."""
    result = measure_command(argv)
    return {**result, "wall_seconds": result["seconds"]}


def _row(task: str, tool: str, result: dict, events: int, ours: dict | None) -> None:
    seconds = result["wall_seconds"]
    ratio = f"{seconds / ours['wall_seconds']:6.2f}" if ours else "     -"
    print(f"{task:42} {tool:14} {seconds:8.2f} {events / seconds / 1e6:7.1f} {result['peak_mb']:9.0f} "
          f"{ratio}", flush=True)


if __name__ == "__main__":
    main()
