"""Latency benchmark (issue 16): a paced live source through one, two and three stages of
`convert | bafilter | correct`, at 100 k and 1 M events/s.

The source is the real DVXplorer recording (320 x 240, 111,954 events in 0.59 s), its times scaled to the rate
and repeated to ``--seconds`` of stream, sent as AEDAT 4.0 packets of 1 ms each when their time has come (the
harness of ``tests/latency.py``: the caller is the camera, the last stage writes CSV into a FIFO). The latency of
an output event is when it came out of the last stage minus when the first input packet reaching its time went
in. ``correct`` holds an event back by design up to three windows of ``--max-gap-us`` (here 5 ms: 15 ms) to
release its output sorted; the per-stage column is the increase over the stages before.

Regular files are not live: their chunks and throughput are those of the other benchmarks.

Run: ``python -m tests.bench.bench_latency [--seconds 3] [--rates 100000,1000000]``.
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from tests.latency import EVTOOLS, paced_packets, pipeline_latency_ms

RECORDING = Path(__file__).resolve().parents[3] / "shared" / "data" / "dvxplorer_sample.aedat4"
MAX_GAP_US = 5_000


def paced_source(rate_hz: int, seconds: float):
    """The recording at ``rate_hz`` events/s (its times scaled), repeated to ``seconds``, as 1 ms packets."""
    import evtools

    recording, info = evtools.read(RECORDING)
    offsets_us = recording["t"] - recording["t"][0]
    period_us = len(recording) * 1e6 / rate_hz  # one pass of the recording at the new rate
    scaled_us = offsets_us * (period_us / (int(offsets_us[-1]) + 1))
    repeats = int(np.ceil(seconds * rate_hz / len(recording)))
    events = np.tile(recording, repeats)
    events["t"] = np.round((scaled_us[None, :] + period_us * np.arange(repeats)[:, None]).reshape(-1)).astype(np.int64)
    events = events[: int(seconds * rate_hz)]
    return paced_packets(events, info, packet_us=1000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--rates", default="100000,1000000")
    arguments = parser.parse_args()
    if not RECORDING.exists():
        raise SystemExit(f"{RECORDING}: missing (the shared recordings)")
    folder = Path(tempfile.mkdtemp(prefix="evtools-latency-"))
    thresholds = folder / "thresholds.h5"
    subprocess.run([EVTOOLS, "-q", "estimate", str(RECORDING), "-o", str(thresholds)], check=True)
    stages = [["convert"], ["bafilter", "--preset", "dv"],
              ["correct", "--thresholds", str(thresholds), "--max-gap-us", str(MAX_GAP_US)]]
    print(f"{'rate ev/s':>10} {'stages':<26} {'events out':>10} {'median ms':>9} {'p99 ms':>7} {'max ms':>7} "
          f"{'p99 this stage':>14}")
    for rate_hz in map(int, arguments.rates.split(",")):
        header, packets, last_t_us, end_mark = paced_source(rate_hz, arguments.seconds)
        warm = folder / f"warm-{rate_hz}"
        warm.mkdir()
        pipeline_latency_ms(stages, header, packets[:100], last_t_us[:100], end_mark, warm)  # kernels compiled
        previous_p99 = 0.0
        for count in range(1, len(stages) + 1):
            run = folder / f"{rate_hz}-{count}"
            run.mkdir()
            latency_ms = pipeline_latency_ms(stages[:count], header, packets, last_t_us, end_mark, run)
            p99 = float(np.percentile(latency_ms, 99))
            names = " | ".join(stage[0] for stage in stages[:count])
            print(f"{rate_hz:>10,} {names:<26} {len(latency_ms):>10,} {np.median(latency_ms):>9.1f} {p99:>7.1f} "
                  f"{latency_ms.max():>7.1f} {p99 - previous_p99:>14.1f}", flush=True)
            previous_p99 = p99


if __name__ == "__main__":
    main()
