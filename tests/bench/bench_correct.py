"""Correction benchmark (issue 6): throughput and peak memory of ThresholdCorrector at 346 x 260.

Events are generated chunk by chunk (1M each, random pixels and polarities, about 20 Mev/s of stream time) and
never held together; each row runs in a fresh process, so its peak RSS (from ``wait4``) is its own. Only
``process`` is timed (the re-sampling kernel plus the sort-and-merge release). Random pixels are the worst case
for the per-pixel state (a cache miss per event); random polarities the worst case for ``turns``/``highpass``
(a reversal at almost every event). Target: >= 20 Mev/s.

Run: ``python -m tests.bench.bench_correct [--events N]``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from tests.bench.common import measure_child

WIDTH, HEIGHT = 346, 260
CHUNK = 1 << 20
TARGET_MEV_S = 20.0


def child(total: int, mode: str) -> dict:
    from evtools.correct import ThresholdCorrector
    from evtools.events import make_events

    rng = np.random.default_rng(0)
    on = rng.normal(0.2, 0.03, (HEIGHT, WIDTH)).clip(0.05)
    off = rng.normal(0.2, 0.03, (HEIGHT, WIDTH)).clip(0.05)
    warm = make_events([0, 1], [0, 1], [0, 0], [1, 0])  # the first call (loading the stored kernel) is not throughput
    ThresholdCorrector(WIDTH, HEIGHT, on, off, target=0.2, mode=mode).process(warm)
    corrector = ThresholdCorrector(WIDTH, HEIGHT, on, off, target=0.2, mode=mode)
    spent, produced, t0 = 0.0, 0, 0
    for start in range(0, total, CHUNK):
        n = min(CHUNK, total - start)
        t = t0 + np.sort(rng.integers(0, n // 20 + 1, n))  # ~20 events per us
        chunk = make_events(t, rng.integers(0, WIDTH, n), rng.integers(0, HEIGHT, n), rng.integers(0, 2, n))
        t0 = int(t[-1])
        begin = time.perf_counter()
        produced += len(corrector.process(chunk))
        spent += time.perf_counter() - begin
    produced += len(corrector.flush())
    return {"events": total, "produced": produced, "seconds": spent}


def measure(total: int, mode: str) -> dict:
    return measure_child("bench_correct", total, mode)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--events", type=int, default=100_000_000)
    parser.add_argument("--child", nargs=2, metavar=("N", "MODE"))
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(int(args.child[0]), args.child[1])))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"correct, {WIDTH} x {HEIGHT}, {args.events:,} events")
    for column in ("operation", "Mev/s", "peak RSS MB", "target"):
        table.add_column(column, justify="right")
    for mode in ("highpass", "turns", "step", "foh"):
        row = measure(args.events, mode)
        rate = row["events"] / row["seconds"] / 1e6
        table.add_row(f"ThresholdCorrector {mode}", f"{rate:.1f}", f"{row['peak_mb']:.0f}",
                      f">= {TARGET_MEV_S:.0f} Mev/s {'ok' if rate >= TARGET_MEV_S else 'MISSED'}")
    Console().print(table)


if __name__ == "__main__":
    main()
