"""Format benchmark (issue 2): read and write throughput and peak memory of every format, beside `aedat` and
dv-processing, measured in one run; then `evtools convert` of a 50-million-event AEDAT 4.0 file to HDF5.

Run: ``make bench`` (or ``.venv/bin/python -m tests.bench.bench_formats [--events N] [--big-events N]``).
"checked" reads verify every event (on the sensor, time never going backwards), as every evtools command does;
"decode only" is the like-for-like comparison with ``aedat``, which checks nothing. Every measurement runs in a fresh process, so its peak RSS (from ``wait4``) is its own; throughput is
events / wall-clock seconds of the timed part. Timing covers reading or writing only, not making the events.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tests.bench.common import measure_child, measure_command

WIDTH, HEIGHT = 346, 260
CHUNK = 1 << 20
TARGETS = {  # what issue 2 asks for, in events/s
    ("write", "aedat4"): 50e6, ("read", "hdf5"): 20e6, ("write", "hdf5"): 20e6, ("read", "csv"): 2e6,
}


def synthetic_chunks(n_events: int, seed: int = 0):
    """Chunks of random events on a 346 x 260 sensor at about 10 Mev/s, sorted by time."""
    from evtools.events import make_events

    rng = np.random.default_rng(seed)
    t0 = 0
    for start in range(0, n_events, CHUNK):
        n = min(CHUNK, n_events - start)
        t = t0 + np.sort(rng.integers(0, n // 10 + 1, n))
        t0 = int(t[-1])
        yield make_events(t, rng.integers(0, WIDTH, n), rng.integers(0, HEIGHT, n), rng.integers(0, 2, n))


# ---- children: each prints one JSON line {"events": n, "seconds": s} ----

def child_write(path: str, fmt: str, compression: str | None, n_events: int) -> dict:
    from evtools.events import StreamInfo
    from evtools.formats import create_events

    spent = 0.0
    with create_events(path, StreamInfo(WIDTH, HEIGHT), format=fmt, compression=compression) as writer:
        for chunk in synthetic_chunks(n_events):
            start = time.perf_counter()
            writer.write(chunk)
            spent += time.perf_counter() - start
        start = time.perf_counter()
    spent += time.perf_counter() - start  # closing: last packet, index, rename
    return {"events": n_events, "seconds": spent}


def child_read(path: str, sensor_size: str | None, check: str = "check") -> dict:
    from evtools.formats import open_events

    size = tuple(int(v) for v in sensor_size.split("x")) if sensor_size else None
    start = time.perf_counter()
    n = 0
    with open_events(path, sensor_size=size, check=check == "check") as stream:
        for chunk in stream:
            n += len(chunk)
    return {"events": n, "seconds": time.perf_counter() - start}


def child_aedat_read(path: str) -> dict:
    import aedat

    start = time.perf_counter()
    n = sum(len(packet["events"]) for packet in aedat.Decoder(path) if "events" in packet)
    return {"events": n, "seconds": time.perf_counter() - start}


def _dv_batches(path: str):
    import dv_processing as dv

    recording = dv.io.MonoCameraRecording(path)
    while recording.isRunning():
        batch = recording.getNextEventBatch()
        if batch is not None:
            yield batch


def child_dv_read(path: str) -> dict:
    start = time.perf_counter()
    n = sum(batch.size() for batch in _dv_batches(path))
    return {"events": n, "seconds": time.perf_counter() - start}


def child_dv_write(path: str, out: str) -> dict:
    import dv_processing as dv

    batches = list(_dv_batches(path))  # not timed: dv's reader fills its own EventStores
    config = dv.io.MonoCameraWriter.Config("bench")
    config.addEventStream((WIDTH, HEIGHT))
    config.compression = dv.CompressionType.NONE
    start = time.perf_counter()
    writer = dv.io.MonoCameraWriter(out, config)
    for batch in batches:
        writer.writeEvents(batch)
    del writer
    return {"events": sum(b.size() for b in batches), "seconds": time.perf_counter() - start}


CHILDREN = {"write": child_write, "read": child_read, "aedat_read": child_aedat_read,
            "dv_read": child_dv_read, "dv_write": child_dv_write}


def measure(*args) -> dict:
    """Run one child in a fresh interpreter; its JSON result plus its peak RSS in MB."""
    result = measure_child("bench_formats", *args)
    result["rate"] = result["events"] / result["seconds"]
    return result


def row(what: str, result: dict, peer: dict | None = None, target: float | None = None) -> None:
    ratio = f"{result['rate'] / peer['rate']:.2f}x" if peer else ""
    goal = ("ok" if result["rate"] >= target else "BELOW") + f" {target / 1e6:g}" if target else ""
    print(f"{what:34} {result['rate'] / 1e6:9.1f} {result['peak_mb']:9.0f} {ratio:>10} {goal:>10}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--events", type=int, default=10_000_000)
    parser.add_argument("--big-events", type=int, default=50_000_000)
    parser.add_argument("--dir", default=None, help="scratch folder (default: a temporary one)")
    parser.add_argument("--child", nargs="+")
    args = parser.parse_args()
    if args.child:
        name, *rest = args.child
        rest = [None if value == "None" else value for value in rest]
        if name == "write":
            rest[-1] = int(rest[-1])
        print(json.dumps(CHILDREN[name](*rest)))
        return

    with tempfile.TemporaryDirectory(dir=args.dir) as scratch:
        scratch = Path(scratch)
        n = args.events
        print(f"{n:,} synthetic events at {WIDTH} x {HEIGHT}; Mev/s and peak RSS (MB) per process, one run\n")
        print(f"{'operation':34} {'Mev/s':>9} {'peak MB':>9} {'vs peer':>10} {'target':>10}")
        base = scratch / "base.aedat4"
        written = {}
        for fmt, compression, ext in [("aedat4", None, "aedat4"), ("aedat4", "lz4", "lz4.aedat4"),
                                      ("aedat4", "zstd", "zstd.aedat4"), ("aedat2", None, "aedat"),
                                      ("hdf5", "none", "h5"), ("hdf5", "zstd", "zstd.h5"), ("prophesee", None, "raw"),
                                      ("csv", None, "csv")]:
            path = base if ext == "aedat4" else scratch / f"events.{ext}"
            written[ext] = path
            result = measure("write", path, fmt, compression, n)
            label = f"evtools write {fmt}" + (f" ({compression})" if compression else "")
            if ext == "aedat4":
                dv_write = measure("dv_write", base, scratch / "dv.aedat4")
                row(label, result, dv_write, TARGETS.get(("write", fmt)))
                row("  dv-processing write aedat4", dv_write)
            else:
                row(label, result, None, None if compression else TARGETS.get(("write", fmt)))

        aedat_read = measure("aedat_read", base)
        dv_read = measure("dv_read", base)
        for ext, path in written.items():
            fmt = ext.split(".")[-1]
            result = measure("read", path, f"{WIDTH}x{HEIGHT}" if fmt == "csv" else None)
            label = f"evtools read {ext}"
            if ext == "aedat4":
                row(label + " (checked)", result, aedat_read)
                row("  evtools read aedat4 (decode only)", measure("read", path, None, "nocheck"), aedat_read)
                row("  aedat read aedat4 (no checks)", aedat_read)
                row("  dv-processing read aedat4", dv_read)
                print(f"{'  evtools / dv-processing read':34} {result['rate'] / dv_read['rate']:9.2f}x")
            else:
                row(label, result, None, TARGETS.get(("read", {"h5": "hdf5"}.get(fmt, fmt))))
        for path in written.values():
            path.unlink()

        big, out = scratch / "big.aedat4", scratch / "big.h5"
        measure("write", big, "aedat4", None, args.big_events)
        evtools = str(Path(sys.executable).with_name("evtools"))
        result = measure_command([evtools, "convert", str(big), "-o", str(out)])
        verdict = "ok" if result["peak_mb"] < 500 else "OVER 500 MB"
        print(f"\nevtools convert {args.big_events:,} events aedat4 -> hdf5: {result['seconds']:.1f} s "
              f"({args.big_events / result['seconds'] / 1e6:.1f} Mev/s), peak RSS {result['peak_mb']:.0f} MB ({verdict})")


if __name__ == "__main__":
    main()
