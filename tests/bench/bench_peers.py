"""Peers benchmark (issues 15, 42): evtools beside dv-processing, aedat, faery and evlib, measured in one run.

The files: the real DVXplorer recording (111,954 events) repeated in time to ``--events`` events (10 M and 50 M),
written by dv-processing's ``MonoCameraWriter`` as DV stores recordings (files evtools wrote flattered it: its LZ4
frames have independent blocks and a stored size, DV's are linked blocks without): AEDAT 4.0, LZ4 and
uncompressed, in packets of the recording's own size (1,898 events, about 10 ms) and of 620 events (what DV writes
for a DAVIS346 at moderate rates: a reader's cost per packet counts), in ``/dev/shm`` when it has room.

Every row runs its tools in paired rounds (``--repeat``, 5): each round runs every tool once, in turns, the order
reversed every other round, and the ratio peer time / evtools time is taken within each round; a row reports the
median time, the peak RSS (from ``wait4``), and the min and median of the per-round ratios (> 1: evtools faster),
with the machine's load over its rounds. evtools runs as users run it: the installed ``evtools`` command (the
header says whether the install is editable or a wheel), or ``python -c`` with only the tool imported for the
reads (:data:`READ_SCRIPTS`: the same for every tool), which also report the read's own time (in-process).

- read into numpy: ``evtools.read``; ``aedat.Decoder`` (packets concatenated); dv-processing's
  ``MonoCameraRecording`` (batches' ``numpy()`` concatenated); faery's ``events_stream_from_file(...).to_array()``;
  evlib's ``load_events(...).collect()``;
- ``bafilter --preset dv`` file to file against dv-processing's read + ``BackgroundActivityNoiseFilter`` + write
  (:data:`DV_FILTER`), both writing the input's compression;
- ``estimate --method offe`` and ``correct`` against issue 42's targets (``correct`` >= 20 Mev/s whole process at
  320 x 240, < 150 MiB at 1280 x 720: the Gen4.1 recording tiled, 25 Mev/s), ``correct`` with a map valid on every
  pixel (:func:`full_map`: every event re-sampled; offE's maps of these tiled clips are valid on 0.4-4.6 % of the
  pixels, and their pixels without an estimate pass through untouched: 81-96 % of the events went by the
  correction);
- start-up: ``evtools info`` and ``evtools bafilter`` on 1,000 events against the peers' read and filter scripts;
- Prophesee RAW and Metavision HDF5 read into numpy: the real Gen4.1 recording (EVT 3.0, 219,596 events in 8.8 ms)
  repeated to the same sizes, written by faery as EVT 3.0 (as Metavision writes Gen4 recordings), by evtools as
  EVT 2.0, by this module's encoders as EVT 2.1 and Metavision HDF5, against faery and evlib.

Peers missing from the environment are installed into it with pip first (``aedat``, ``evlib``; dv-processing and
faery come with the test extra).

Run: ``python -m tests.bench.bench_peers [--events 10000000,50000000] [--repeat 5] [--rows read,bafilter,...]
[--packets recorded,620]``; at load 2: start two busy loops first (``sh -c 'while :; do :; done' &``, twice).
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from tests.bench.common import install_kind, measure_command, median, paired, ratios, scratch_dir

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


READ_SCRIPTS = {
    "evtools": "import evtools\nn = len(evtools.read(path)[0])",
    "aedat": "import aedat, numpy as np\n"
             "n = len(np.concatenate([p['events'] for p in aedat.Decoder(path) if 'events' in p]))",
    "dv_processing": "import dv_processing as dv, numpy as np\nrecording = dv.io.MonoCameraRecording(path)\n"
                     "parts = []\nwhile recording.isRunning():\n    batch = recording.getNextEventBatch()\n"
                     "    if batch is not None:\n        parts.append(batch.numpy())\nn = len(np.concatenate(parts))",
    "faery": "import faery\nn = len(faery.events_stream_from_file(path).to_array())",
    "evlib": "import evlib\nframe = evlib.load_events(path).collect()\n"
             "n = len([frame[column].to_numpy() for column in frame.columns][0])",
}
"""Each tool's whole read of ``path`` into numpy, as its documentation shows it, run as ``python -c`` with nothing
else imported (a start-up row measures the tool, not the benchmark): prints the events read and the seconds from
the tool's import to the end (``in_process_seconds``: the read alone, imports excluded)."""


def read_child(tool: str, path) -> dict:
    """Read ``path`` with ``tool`` in a fresh interpreter: its wall time (start-up included), peak RSS, and the
    in-process time of the read alone."""
    imports, read = READ_SCRIPTS[tool].split("\n", 1)
    script = (f"import sys, time\npath = sys.argv[1]\n{imports}\nt = time.perf_counter()\n{read}\n"
              "print(n, time.perf_counter() - t)")
    run = measure_command([sys.executable, "-c", script, path], stdout=subprocess.PIPE)
    events, seconds = run["output"].split()
    return {"events": int(events), "in_process_seconds": float(seconds), "peak_mb": run["peak_mb"],
            "wall_seconds": run["seconds"]}


def full_map(path: Path, width: int, height: int) -> None:
    """A thresholds map valid on every pixel (0.2 +/- 0.03 ON and OFF, drawn with a fixed seed): ``correct``
    re-samples every event with it."""
    from evtools.formats.thresholds import ThresholdMap, write_thresholds

    rng = np.random.default_rng(0)
    on, off = (np.clip(rng.normal(0.2, 0.03, (height, width)), 0.05, None).astype(np.float32) for _ in range(2))
    write_thresholds(str(path), ThresholdMap(on, off, np.ones((height, width), bool), {"method": "bench"}))


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
    if version == "aedat4":  # as DV would record a 1280 x 720 camera: LZ4 (evtools' writer: DV's packets)
        evtools.write(path, tiled, info, compression="lz4")
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


DV_FILTER_FUNCTION = """import sys
import dv_processing as dv


def filter_file(path, out, compression):
    recording = dv.io.MonoCameraRecording(path)
    config = dv.io.MonoCameraWriter.Config("bench")
    config.addEventStream(recording.getEventResolution())
    config.compression = dv.CompressionType.LZ4 if compression == "lz4" else dv.CompressionType.NONE
    writer = dv.io.MonoCameraWriter(out, config)
    noise_filter = dv.noise.BackgroundActivityNoiseFilter(recording.getEventResolution())
    while recording.isRunning():
        batch = recording.getNextEventBatch()
        if batch is not None:
            noise_filter.accept(batch)
            writer.writeEvents(noise_filter.generateEvents())
    del writer  # (dv-processing writes the file's index when the writer is destroyed)
"""
"""dv-processing's read, ``BackgroundActivityNoiseFilter`` (its defaults) and write with the given compression."""
DV_FILTER = DV_FILTER_FUNCTION + "\nfilter_file(*sys.argv[1:])\n"
"""``python -c DV_FILTER IN OUT COMPRESSION``: one file filtered."""


def command(argv) -> dict:
    """A whole process: wall time (``wall_seconds``) and peak RSS."""
    result = measure_command(argv, stdout=subprocess.DEVNULL)
    return {**result, "wall_seconds": result["seconds"]}


def compare(task: str, rounds: int, contenders: dict[str, tuple], events: int) -> None:
    """Run ``contenders`` (name: ``(measure, *args)``, evtools first) in paired rounds and print a row each: median
    wall time, Mev/s, peak RSS, in-process median where measured, and the peer/evtools ratios taken round by round
    (min and median; > 1: evtools faster), with the load range over the rounds."""
    results, loads = paired(rounds, list(contenders.values()))
    ours = results[0]
    load = f"{min(loads):.1f}-{max(loads):.1f}"
    for name, runs in zip(contenders, results):
        seconds = median(runs, "wall_seconds")
        inner = median(runs, "in_process_seconds") if "in_process_seconds" in runs[0] else None
        whole = ratios(runs, ours, "wall_seconds") if runs is not ours else None
        within = (ratios(runs, ours, "in_process_seconds")
                  if runs is not ours and inner is not None and "in_process_seconds" in ours[0] else None)
        print(f"{task:44} {name:14} {seconds:8.3f} {events / seconds / 1e6:7.1f} "
              f"{max(r['peak_mb'] for r in runs):7.0f} {'' if inner is None else f'{inner:8.3f}':>8} "
              f"{'' if whole is None else f'{whole[0]:5.2f}/{whole[1]:5.2f}':>11} "
              f"{'' if within is None else f'{within[0]:5.2f}/{within[1]:5.2f}':>11} {load:>9}", flush=True)


def target(task: str, rounds: int, argv: list, events: int, mev_s: float, peak_mib: float) -> None:
    """An evtools command alone against a target speed and peak RSS (no peer does it)."""
    results, loads = paired(rounds, [(command, argv)])
    seconds = median(results[0], "wall_seconds")
    peak = max(r["peak_mb"] for r in results[0])
    print(f"{task:44} {'evtools':14} {seconds:8.3f} {events / seconds / 1e6:7.1f} {peak:7.0f} {'':8} "
          f"target >= {mev_s:g} Mev/s, < {peak_mib:g} MiB: {'met' if events / seconds / 1e6 >= mev_s else 'not met'}"
          f" / {'met' if peak < peak_mib else 'not met'}  {min(loads):.1f}-{max(loads):.1f}", flush=True)


ROWS = ("read", "bafilter", "estimate", "correct", "prophesee", "startup")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--events", default="10000000,50000000")
    parser.add_argument("--repeat", type=int, default=5, help="paired rounds per row")
    parser.add_argument("--rows", default=",".join(ROWS), help=f"which rows: {', '.join(ROWS)}")
    parser.add_argument("--packets", default="recorded,620",
                        help="events per packet of the DV-written files: 'recorded' (the recording's own, 1,898) "
                             "and/or numbers (620: DV's packets for a DAVIS346 at moderate rates)")
    args = parser.parse_args()
    rows = set(args.rows.split(","))
    if not RECORDING.exists():
        raise SystemExit(f"{RECORDING} is missing (the tests' real recordings)")
    peers = ensure_peers()
    sizes = [int(n) for n in args.events.split(",")]
    folder = Path(tempfile.mkdtemp(prefix="bench_peers_", dir=scratch_dir(max(sizes) * 40)))
    print(f"evtools {install_kind()} install, `{EVTOOLS}`; inputs written by dv-processing's MonoCameraWriter as DV "
          f"records (AEDAT 4.0, LZ4 linked blocks or none); {args.repeat} paired rounds a row, tools in turns; "
          f"peers: {', '.join(peers)}")
    print(f"{'task':44} {'tool':14} {'median s':>8} {'Mev/s':>7} {'peak MiB':>7} {'in-proc':>8} "
          f"{'ratio min/med':>11} {'in-proc':>11} {'load':>9}")
    try:
        if "startup" in rows:
            tiny = folder / "tiny.aedat4"
            make_file(tiny, 1000, "lz4")
            compare("start-up: info, 1,000 events", args.repeat,
                    {"evtools": (command, [EVTOOLS, "info", tiny]),
                     **{tool: (read_child, tool, tiny) for tool in ("dv_processing", "aedat") if tool in peers}},
                    1000)
            contenders = {"evtools": (command, [EVTOOLS, "-q", "bafilter", tiny, "--preset", "dv", "-o",
                                                folder / "tiny_out.aedat4"])}
            if "dv_processing" in peers:
                contenders["dv_processing"] = (command, [sys.executable, "-c", DV_FILTER, tiny,
                                                         folder / "tiny_dv.aedat4", "lz4"])
            compare("start-up: bafilter, 1,000 events", args.repeat, contenders, 1000)
        for events in sizes:
            for packets in args.packets.split(","):
                for compression in ("lz4", "none"):
                    path = folder / f"in_{events}_{compression}.aedat4"
                    make_file(path, events, compression, packet_events=None if packets == "recorded" else int(packets))
                    label = f"{events // 1_000_000}M {compression}, {packets} packets"
                    if "read" in rows:
                        compare(f"read into numpy, {label}", args.repeat,
                                {tool: (read_child, tool, path) for tool in
                                 ("evtools", "dv_processing", "aedat", "faery", "evlib") if tool in peers + ["evtools"]},
                                events)
                    if "bafilter" in rows:
                        contenders = {"evtools": (command, [EVTOOLS, "-q", "bafilter", path, "--preset", "dv", "-o",
                                                            folder / "out.aedat4", "--compression", compression])}
                        if "dv_processing" in peers:  # both write the input's compression (DV records LZ4)
                            contenders["dv_processing"] = (command, [sys.executable, "-c", DV_FILTER, path,
                                                                     folder / "dv.aedat4", compression])
                        compare(f"bafilter --preset dv, {label}", args.repeat, contenders, events)
                    if packets == "recorded" and ({"estimate", "correct"} & rows):
                        thresholds = folder / "th.h5"
                        estimate = [EVTOOLS, "-q", "estimate", path, "--method", "offe", "-o", thresholds]
                        if "estimate" in rows:
                            target(f"estimate --method offe, {label}", args.repeat, estimate, events, 30, 100)
                        else:
                            command(estimate)
                        if "correct" in rows:
                            full_map(thresholds, 320, 240)
                            target(f"correct (every pixel), {label}", args.repeat,
                                   [EVTOOLS, "-q", "correct", path, "--thresholds", thresholds, "-o",
                                    folder / "out.aedat4"], events, 20, 150)
                    path.unlink()
            if "correct" in rows and events == sizes[0]:  # 1280 x 720: the Gen4.1 recording (25 Mev/s) tiled
                path = folder / "gen4.aedat4"
                make_prophesee(path, events, "aedat4")
                full_map(folder / "th4.h5", 1280, 720)
                target(f"correct (every pixel), {events // 1_000_000}M 1280x720 (Gen4.1 tiled, LZ4)", args.repeat,
                       [EVTOOLS, "-q", "correct", path, "--thresholds", folder / "th4.h5", "-o", folder / "out.aedat4"],
                       events, 20, 150)
                path.unlink()
        if "prophesee" in rows:
            for events in sizes:
                for version in ("evt3", "evt2", "evt21", "hdf5-ecf"):
                    if version == "evt3" and "faery" not in peers:
                        continue
                    path = folder / f"in_{events}_{version}.{'hdf5' if version == 'hdf5-ecf' else 'raw'}"
                    make_prophesee(path, events, version)
                    # (faery reads neither EVT 2.1 nor Metavision's HDF5; evlib reads HDF5 ECF only with
                    # Prophesee's plugin installed, which the bench does not)
                    readers = {"evt21": ("evlib",), "hdf5-ecf": ()}.get(version, ("faery", "evlib"))
                    compare(f"read into numpy, {events // 1_000_000}M {version.upper()} (Gen4)", args.repeat,
                            {tool: (read_child, tool, path) for tool in ("evtools", *readers)
                             if tool == "evtools" or tool in peers}, events)
                    path.unlink()
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
