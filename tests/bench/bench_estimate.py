"""Estimation benchmark (issue 5): throughput (events/s) and peak memory of :class:`ThresholdEstimator`.

A 346 x 260 stream of random events (uniform over the sensor, time increasing at 10 Mev/s, so 10 ms offE
segments hold 100,000 events) is generated chunk by chunk (1M events each) in the measuring process, never held
whole; only ``process`` is timed. Each method runs on 10M and 100M events, each in a fresh process whose peak
RSS comes from ``wait4``: equal peaks show that memory does not grow with the stream. Target >= 50 Mev/s.

Methods: ``offe``, ``stimulus`` (the flicker, every pixel's phase given: L from a one-period table), ``fitted``
(the flicker, every pixel's phase fitted to its first events: a search per pixel, then L from the ramp table),
``gradient`` (stimulus on a moving gradient, phases given: L computed per event, one logarithm each). Random events
are the worst case for ``stimulus``: every pixel's first changes (its seeding) and its accept test are
unpredictable branches, and every pixel shows turns at once (the phase search runs on all of them).

Run: ``python -m tests.bench.bench_estimate [--events 10000000,100000000] [--methods offe,stimulus,fitted,gradient]``.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from tests.bench.common import measure_child

WIDTH, HEIGHT = 346, 260
CHUNK = 1 << 20
RATE_EV_PER_US = 10
TARGET_EV_S = 50e6


def child(method: str, events: int) -> dict:
    from evtools.estimate import Stimulus, ThresholdEstimator
    from evtools.events import make_events

    stimulus = Stimulus.moving(50, 200, 50, 64) if method == "gradient" else Stimulus()
    phase = "fit" if method == "fitted" else "given"
    method = "offe" if method == "offe" else "stimulus"
    estimator = ThresholdEstimator(WIDTH, HEIGHT, method, stimulus=stimulus, segment_us=10_000, phase=phase,
                                   max_fit=float("inf"))
    rng = np.random.default_rng(0)
    spent = 0.0
    done = 0
    t0 = 0
    while done < events:
        n = min(CHUNK, events - done)
        t = t0 + np.sort(rng.integers(0, n // RATE_EV_PER_US + 1, n))
        t0 = int(t[-1])
        chunk = make_events(t, rng.integers(0, WIDTH, n), rng.integers(0, HEIGHT, n), rng.integers(0, 2, n))
        if done == 0:  # compile outside the clock
            estimator_warm = ThresholdEstimator(WIDTH, HEIGHT, method, stimulus=stimulus, segment_us=10_000,
                                                phase=phase)
            estimator_warm.process(chunk[:1000])
        start = time.perf_counter()
        estimator.process(chunk)
        spent += time.perf_counter() - start
        done += n
    start = time.perf_counter()
    result = estimator.result()
    final = time.perf_counter() - start
    return {"events": done, "seconds": spent, "result_s": final,
            "valid": int(result.valid.sum())}


def measure(method: str, events: int) -> dict:
    return measure_child("bench_estimate", method, events)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--child", nargs=2)
    parser.add_argument("--events", default="10000000,100000000")
    parser.add_argument("--methods", default="offe,stimulus,fitted,gradient")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], int(args.child[1]))))
        return
    print(f"ThresholdEstimator.process on random events at {WIDTH}x{HEIGHT} (generation not timed); "
          f"target >= {TARGET_EV_S / 1e6:.0f} Mev/s, peak RSS independent of length")
    print(f"{'method':9} {'events':>12} {'seconds':>8} {'Mev/s':>7} {'result s':>8} {'peak RSS MB':>11} {'vs target':>9}")
    for method in args.methods.split(","):
        for events in (int(n) for n in args.events.split(",")):
            r = measure(method, events)
            rate = r["events"] / r["seconds"]
            print(f"{method:9} {r['events']:>12,} {r['seconds']:8.2f} {rate / 1e6:7.1f} {r['result_s']:8.2f} "
                  f"{r['peak_mb']:11.0f} {rate / TARGET_EV_S:8.2f}x", flush=True)


if __name__ == "__main__":
    main()
