"""Batch benchmark (issues 14, 42): a folder of recordings through ``evtools bafilter IN... -o FOLDER``, beside
dv-processing filtering the same files in a loop in one Python process.

The files: the real DVXplorer recording (tests' data, 111,954 events) repeated in time to ``--events`` events
(1 M), written once by dv-processing's ``MonoCameraWriter`` as DV stores recordings (AEDAT 4.0, LZ4 linked blocks,
the recording's packets) and copied ``--files`` times (100), in ``/dev/shm`` when it has room. Rows, in paired
rounds (``--repeat``; tools in turns, see :func:`tests.bench.common.paired`): one ``evtools bafilter --preset dv``
process on one file (start-up included); the batch with ``--jobs 1`` and ``--jobs 2`` (workers reused: start-up paid
once per worker, not per file); dv-processing's read, ``BackgroundActivityNoiseFilter`` and LZ4 write of every file
in one loop in one process (its start-up paid once). Ratios: dv-processing's loop time / the batch's, per round.

Run: ``python -m tests.bench.bench_batch [--files 100] [--events 1000000] [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from tests.bench.bench_peers import DV_FILTER_FUNCTION, make_file
from tests.bench.common import install_kind, measure_command, median, paired, ratios, scratch_dir

EVTOOLS = str(Path(sys.executable).with_name("evtools"))
RECORDING = Path(__file__).resolve().parents[3] / "shared" / "data" / "dvxplorer_sample.aedat4"
DV_LOOP = DV_FILTER_FUNCTION + """
for path in sys.argv[2:]:
    filter_file(path, sys.argv[1] + "/dv_" + path.rsplit("/", 1)[-1], "lz4")
"""
"""``python -c DV_LOOP FOLDER IN...``: dv-processing's filter of every file, in one process."""


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--files", type=int, default=100)
    parser.add_argument("--events", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    if not RECORDING.exists():
        raise SystemExit(f"{RECORDING} is missing (the tests' real recordings)")
    folder = Path(tempfile.mkdtemp(prefix="bench_batch_", dir=scratch_dir(args.files * args.events * 8)))
    try:
        inputs = folder / "in"
        inputs.mkdir()
        make_file(inputs / "rec000.aedat4", args.events, "lz4")
        paths = [inputs / "rec000.aedat4"]
        for i in range(1, args.files):
            paths.append(inputs / f"rec{i:03d}.aedat4")
            shutil.copyfile(paths[0], paths[-1])
        size_mb = sum(p.stat().st_size for p in paths) / 1e6
        print(f"{args.files} files of {args.events:,} events (DVXplorer recording repeated, written by "
              f"dv-processing: AEDAT 4.0 LZ4, {size_mb:.0f} MB); bafilter --preset dv; evtools {install_kind()} "
              f"install; {args.repeat} paired rounds")
        outputs = {jobs: folder / f"out{jobs}" for jobs in (1, 2)}
        for out in [*outputs.values(), folder / "dv"]:
            out.mkdir()

        def batch(jobs):
            return measure_command([EVTOOLS, "-q", "bafilter", *paths, "--preset", "dv", "-o", outputs[jobs],
                                    "--compression", "lz4", "--jobs", str(jobs)])

        rounds, loads = paired(args.repeat, [
            (measure_command, [EVTOOLS, "-q", "bafilter", paths[0], "--preset", "dv", "-o", folder / "one.aedat4",
                               "--compression", "lz4"]),
            (batch, 1), (batch, 2),
            (measure_command, [sys.executable, "-c", DV_LOOP, folder / "dv", *paths]),
        ])
        names = ["evtools, one file, one process", "evtools batch --jobs 1", "evtools batch --jobs 2",
                 "dv-processing loop, one process"]
        print(f"{'run':34} {'median s':>8} {'per file s':>10} {'Mev/s':>7} {'peak MiB':>8} {'dv loop / this':>15}")
        for name, runs in zip(names, rounds):
            files = 1 if name.endswith("one process") and "one file" in name else args.files
            seconds = median(runs, "seconds")
            ratio = ratios(rounds[3], runs, "seconds") if "batch" in name else None
            print(f"{name:34} {seconds:8.2f} {seconds / files:10.3f} {files * args.events / seconds / 1e6:7.1f} "
                  f"{max(r['peak_mb'] for r in runs):8.0f} "
                  f"{'' if ratio is None else f'{ratio[0]:.2f}/{ratio[1]:.2f} (min/med)':>15}")
        print(f"load {min(loads):.1f}-{max(loads):.1f}; peak RSS: the largest one process of a run (wait4)")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
