"""APS frames benchmark (issue 38): ``estimate --method frames`` and reading AEDAT 4.0 with frames, beside
dv-processing's reader, on a DAVIS346 recording as DV stores it.

The input: the DAVIS346 recording of the tests (``davis346_lab_frames.aedat4``: 117,667 events in 0.13 s, three
346 x 260 frames 40 ms apart) tiled in time to ``--events`` events (its events repeated, shifted by its span each
time) with a frame every 40 ms (its three frames in turn), written as DV records a DAVIS: LZ4, packets of 620
events (DV's own for this camera at moderate rates), a frame packet after the events of its exposure.

Rows (each the fastest of ``--repeat`` runs in a fresh process, peak RSS from ``wait4``):

- ``evtools estimate --method frames``: whole process (start-up, reading, counting, the fits, writing the maps);
- ``evtools info``: reading every event and frame (count, rate, exposure);
- dv-processing's ``MonoCameraRecording``: every event batch and every frame read in a loop (its decoder in C++).

Goal (issue 38): estimate >= 20 Mev/s and < 300 MiB at 50 M events.

Run: ``python -m tests.bench.bench_frames [--events 50000000] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from tests.bench.common import ROOT, fastest_each, measure_command, scratch_dir

RECORDING = ROOT.parent / "shared" / "data" / "davis346_lab_frames.aedat4"
FRAME_PERIOD_US = 40_000
DV_PACKET_EVENTS = 620


def make_input(path: str, events_wanted: int) -> tuple[int, int]:
    """The tiled recording (see the module docstring): (events, frames) written."""
    import evtools
    import evtools.formats.aedat4 as aedat4

    events, info, frames = evtools.read(RECORDING, frames=True)
    span_us = int(events["t"][-1] - events["t"][0]) + 1
    start_us = int(events["t"][0])
    aedat4.PACKET_EVENTS = DV_PACKET_EVENTS  # DV's packets, not evtools' 32,768
    copies = -(-events_wanted // len(events))
    written = frame_count = 0
    next_frame_us = start_us
    exposure_us = frames[0].exposure_us
    with evtools.writer(path, info, compression="lz4") as sink:
        for copy in range(copies):
            part = events.copy()
            part["t"] += copy * span_us
            part = part[: events_wanted - written]
            while next_frame_us + exposure_us <= int(part["t"][-1]):
                upto = int(np.searchsorted(part["t"], next_frame_us + exposure_us, "right"))
                sink.write(part[:upto])
                part = part[upto:]
                written += upto
                image = frames[frame_count % len(frames)].image
                sink.write_frame(evtools.Frame(image, next_frame_us + exposure_us // 2, next_frame_us,
                                               next_frame_us + exposure_us))
                frame_count += 1
                next_frame_us += FRAME_PERIOD_US
            sink.write(part)
            written += len(part)
            if written >= events_wanted:
                break
    return written, frame_count


DV_READ = """
import sys, dv_processing as dv
reader = dv.io.MonoCameraRecording(sys.argv[1])
events = frames = 0
while reader.isRunning():
    batch = reader.getNextEventBatch()
    events += len(batch) if batch is not None else 0
while (frame := reader.getNextFrame()) is not None:
    frames += 1
print(events, frames)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--events", type=int, default=50_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    options = parser.parse_args()
    if not RECORDING.exists():
        print(f"bench_frames: skipped, {RECORDING} is missing (the project's test data, ../shared/data)")
        return
    evtools_bin = str(Path(sys.executable).with_name("evtools"))
    with tempfile.TemporaryDirectory(dir=scratch_dir(options.events * 6)) as folder:
        path = os.path.join(folder, "davis.aedat4")
        count, frame_count = make_input(path, options.events)
        size_mb = os.path.getsize(path) / 2**20
        print(f"input: {count:,} events, {frame_count:,} frames (346 x 260, 25 fps), LZ4 in {DV_PACKET_EVENTS}-event "
              f"packets, {size_mb:.0f} MiB")
        estimate = [evtools_bin, "-q", "estimate", path, "--method", "frames", "-o", os.path.join(folder, "t.h5")]
        rows = fastest_each(options.repeat, [
            (measure_command, estimate),
            (measure_command, [evtools_bin, "-q", "info", path, "--json"]),
            (measure_command, [sys.executable, "-c", DV_READ, path]),
        ])
    names = ["evtools estimate --method frames", "evtools info (read events and frames)",
             "dv-processing MonoCameraRecording (read events and frames)"]
    print(f"{'row':62} {'seconds':>8} {'Mev/s':>7} {'peak MiB':>9}")
    for name, row in zip(names, rows):
        print(f"{name:62} {row['seconds']:8.2f} {count / row['seconds'] / 1e6:7.1f} {row['peak_mb']:9.0f}")
    print(f"read: evtools info / dv-processing = {rows[2]['seconds'] / rows[1]['seconds']:.2f}x as fast; "
          f"estimate goal >= 20 Mev/s and < 300 MiB: {count / rows[0]['seconds'] / 1e6:.1f} Mev/s, "
          f"{rows[0]['peak_mb']:.0f} MiB")


if __name__ == "__main__":
    main()
