"""render benchmark (issue 18): 10M events drawn to one PNG and to a 30 fps MP4, whole processes.

The file: the real DVXplorer recording (320 x 240) repeated in time to ``--events`` events, AEDAT 4.0 with LZ4 as DV
records it (the peers benchmark's file). Rows: ``render -o x.png`` with one window spanning the whole stream (every
event counted into one frame); ``render -o x.mp4 --fps 30 --window-us 33333`` (real time: one frame per 33 ms of
stream, 2x upscaled to 640 x 480); the same video in ``--mode decay`` and ``--mode time-surface``. Each row is the
fastest of ``--repeat`` runs with its peak RSS; frames per second of wall time for the videos.

Run: ``python -m tests.bench.bench_render [--events 10000000] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from tests.bench.bench_peers import RECORDING, make_file
from tests.bench.common import fastest, measure_command, scratch_dir

EVTOOLS = str(Path(sys.executable).with_name("evtools"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=10_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    if not RECORDING.exists():
        raise SystemExit(f"{RECORDING} is missing (the tests' real recordings)")
    import evtools

    folder = Path(tempfile.mkdtemp(prefix="bench_render_", dir=scratch_dir(args.events * 20)))
    try:
        path = folder / "in.aedat4"
        make_file(path, args.events, "lz4")
        with evtools.open(path) as stream:
            first_us = last_us = None
            for chunk in stream:
                first_us = int(chunk["t"][0]) if first_us is None else first_us
                last_us = int(chunk["t"][-1])
        span_us = last_us - first_us + 1
        frames = -(-span_us // 33_333)
        print(f"render: DVXplorer recording repeated to {args.events:,} events ({span_us / 1e6:.1f} s), AEDAT 4.0 "
              f"LZ4; whole processes, fastest of {args.repeat}")
        print(f"{'output':44} {'seconds':>8} {'Mev/s':>7} {'frames/s':>9} {'peak MiB':>9}")
        rows = [("PNG, one window of the whole stream", ["-o", folder / "all.png", "--window-us", span_us], 1)]
        for mode in ("accumulate", "decay", "time-surface"):
            rows.append((f"MP4 30 fps, {frames:,} frames, {mode}",
                         ["-o", folder / "v.mp4", "--fps", "30", "--window-us", "33333", "--mode", mode], frames))
        for name, argv, count in rows:
            result = fastest(args.repeat, measure_command, [EVTOOLS, "-q", "render", path, *map(str, argv)])
            seconds = result["seconds"]
            print(f"{name:44} {seconds:8.2f} {args.events / seconds / 1e6:7.1f} {count / seconds:9.0f} "
                  f"{result['peak_mb']:9.0f}", flush=True)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
