"""Batch benchmark (issue 14): a folder of recordings through ``evtools bafilter IN... -o FOLDER``.

The files: the real DVXplorer recording (tests' data, 111,954 events) repeated in time to ``--events`` events each
(1 M), stored as DV stores recordings, AEDAT 4.0 with LZ4, ``--files`` of them (100), in ``/dev/shm`` when it has
room. Rows (whole processes, wall time, the fastest of ``--repeat`` runs): one ``evtools bafilter`` run on one
file (start-up included), and the batch with ``--jobs 1`` and ``--jobs 2``: the speed-up of two jobs, and the
per-file cost in a batch against the single run (a batch pays the interpreter's start-up once per worker, not per
file).

Run: ``python -m tests.bench.bench_batch [--files 100] [--events 1000000] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from tests.bench.common import fastest, measure_command, scratch_dir

EVTOOLS = str(Path(sys.executable).with_name("evtools"))
RECORDING = Path(__file__).resolve().parents[3] / "shared" / "data" / "dvxplorer_sample.aedat4"


def make_files(folder: Path, files: int, events: int) -> list[Path]:
    import evtools

    recording, info = evtools.read(RECORDING)
    recording["t"] -= recording["t"][0]
    span_us = int(recording["t"][-1]) + 1
    repeats = -(-events // len(recording))
    tiled = np.concatenate([recording] * repeats)[:events]
    tiled["t"] += np.repeat(np.arange(repeats, dtype=np.int64) * span_us, len(recording))[:events]
    paths = []
    for i in range(files):
        path = folder / f"rec{i:03d}.aedat4"
        evtools.write(path, tiled, info, compression="lz4")
        paths.append(path)
    return paths


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--files", type=int, default=100)
    parser.add_argument("--events", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    if not RECORDING.exists():
        raise SystemExit(f"{RECORDING} is missing (the tests' real recordings)")
    folder = Path(tempfile.mkdtemp(prefix="bench_batch_", dir=scratch_dir(args.files * args.events * 8)))
    try:
        inputs = folder / "in"
        inputs.mkdir()
        paths = make_files(inputs, args.files, args.events)
        size_mb = sum(p.stat().st_size for p in paths) / 1e6
        print(f"{args.files} files of {args.events:,} events (DVXplorer recording repeated, AEDAT 4.0 LZ4, "
              f"{size_mb:.0f} MB) in {folder}; bafilter --method baf; fastest of {args.repeat} runs")
        single = fastest(args.repeat, measure_command, [EVTOOLS, "-q", "bafilter", paths[0], "-o", folder / "one.aedat4"])
        rows = {}
        for jobs in (1, 2):
            out = folder / f"out{jobs}"

            def batch(out=out, jobs=jobs):
                shutil.rmtree(out, ignore_errors=True)
                return measure_command([EVTOOLS, "-q", "bafilter", *paths, "-o", out, "--jobs", str(jobs)])

            rows[jobs] = fastest(args.repeat, batch)
        print(f"{'run':28} {'wall s':>8} {'per file s':>10} {'Mev/s':>7} {'peak RSS MB':>11}")
        print(f"{'one file, one process':28} {single['seconds']:8.2f} {single['seconds']:10.3f} "
              f"{args.events / single['seconds'] / 1e6:7.1f} {single['peak_mb']:11.0f}")
        for jobs, r in rows.items():
            per_file = r["seconds"] / args.files
            print(f"{f'batch --jobs {jobs}':28} {r['seconds']:8.2f} {per_file:10.3f} "
                  f"{args.files * args.events / r['seconds'] / 1e6:7.1f} {r['peak_mb']:11.0f}")
        print(f"speed-up of --jobs 2 over --jobs 1: {rows[1]['seconds'] / rows[2]['seconds']:.2f}x; a file in a "
              f"batch (--jobs 1) costs {rows[1]['seconds'] / args.files / single['seconds']:.2f}x a single run "
              "(peak RSS: the largest one process of the run, from wait4)")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
