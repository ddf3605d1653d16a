"""Estimation benchmark (issues 5, 13): throughput (events/s) and peak memory of :class:`ThresholdEstimator`.

A 346 x 260 stream of random events (uniform over the sensor, time increasing at 10 Mev/s, so 10 ms offE
segments hold 100,000 events) is generated chunk by chunk (1M events each) in the measuring process, never held
whole; only ``process`` is timed. Each method runs on 10M and 100M events, each in a fresh process whose peak
RSS comes from ``wait4``: equal peaks show that memory does not grow with the stream. Targets (issue 13):
>= 50 Mev/s, >= 20 for the phase-free stimulus method.

Methods: ``offe``, ``natural`` (counts and reversals per pixel; the neighbours' means at the end), ``stimulus`` (the flicker, every pixel's phase given: L from a one-period table), ``fitted``
(the flicker, every pixel's phase fitted to its first events: a search per pixel, then L from the ramp table),
``natural-online``, ``stimulus-online`` (a map every second of the stream: 10 maps on 100M events at 10 Mev/s,
each a few MB held for the output series), ``fitted-gradient`` (the same on a real calibration stream: two periods of the simulator's moving gradient,
2.15 M events, repeated; 34 MB of it held), ``gradient`` (stimulus on a moving gradient, phases given: L computed
per event, one logarithm each). Random events are the worst case for ``stimulus``: every pixel's first changes (its
seeding) and its accept test are unpredictable branches, and every pixel shows ~16 polarity reversals in its
first 32 events (16 candidate phases to screen).

``natural-texture``: natural on the tests' natural moving texture (``bench_correct``'s ``texture`` stream).
``--baseline DIR`` adds a row per method for the evtools in DIR (a worktree of an older commit), in the same run.

Run: ``python -m tests.bench.bench_estimate [--events 10000000,100000000] [--methods offe,stimulus,fitted,...]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time

import numpy as np

from tests.bench.common import measure_child

WIDTH, HEIGHT = 346, 260
CHUNK = 1 << 20
RATE_EV_PER_US = 10
TARGET_EV_S = {"fitted": 20e6, "fitted-gradient": 20e6}
"""The issue's targets: >= 20 Mev/s for the phase-free stimulus method, >= 50 Mev/s for the others."""
DEFAULT_TARGET_EV_S = 50e6


GRADIENT_S = 2.56
"""The ``fitted-gradient`` stream: two periods of the simulator's moving gradient (1.28 s each), repeated."""


def gradient_events(path: str) -> np.ndarray:
    """Two periods of ``evtools simulate scene:gradient`` at 346 x 260 (made once, outside every clock)."""
    import subprocess
    import sys
    from pathlib import Path

    from tests.helpers import read_all

    if not os.path.exists(path):
        subprocess.run([str(Path(sys.executable).with_name("evtools")), "simulate", "scene:gradient", "--duration",
                        f"{GRADIENT_S}s", "-o", path], check=True)
    return read_all(path)[1]


def chunks(method: str, events: int, scratch: str):
    """The measured stream, chunk by chunk: random events (uniform over the sensor, 10 Mev/s), or for
    ``fitted-gradient`` the simulated gradient repeated every two periods (its times shifted, so still sorted)."""
    from evtools.events import make_events

    if method == "natural-texture":  # the tests' natural moving texture (bench_correct's), repeated in time
        from tests.bench.bench_correct import texture_chunks

        yield from texture_chunks(events)
        return
    rng = np.random.default_rng(0)
    done = 0
    t0 = 0
    base = gradient_events(scratch) if method == "fitted-gradient" else None
    while done < events:
        n = min(CHUNK, events - done)
        if base is not None:
            start = done % len(base)
            n = min(n, len(base) - start)
            chunk = base[start:start + n].copy()
            chunk["t"] += (done // len(base)) * int(GRADIENT_S * 1e6)
        else:
            t = t0 + np.sort(rng.integers(0, n // RATE_EV_PER_US + 1, n))
            t0 = int(t[-1])
            chunk = make_events(t, rng.integers(0, WIDTH, n), rng.integers(0, HEIGHT, n), rng.integers(0, 2, n))
        done += n
        yield chunk


def child(method: str, events: int, scratch: str) -> dict:
    repo = os.environ.get("EVTOOLS_BENCH_REPO")
    if repo:  # another checkout's evtools (the baseline row)
        import sys

        sys.path.insert(0, repo)
        for name in [m for m in sys.modules if m == "evtools" or m.startswith("evtools.")]:
            del sys.modules[name]
    from evtools.estimation import Stimulus, ThresholdEstimator

    stimulus = Stimulus.moving(50, 200, 50, 64) if method == "gradient" else Stimulus()
    if method == "fitted-gradient":
        stimulus = Stimulus(50, 200, GRADIENT_S * 1e6 / 2)  # the gradient described by its period alone
    phase = "fit" if method.startswith("fitted") else "given"
    online = method.endswith("-online")  # a map every second of the stream (10 maps on 100M events)
    method = method.removesuffix("-online")
    kind = "natural" if method == "natural-texture" else method if method in ("offe", "natural") else "stimulus"
    estimator = ThresholdEstimator(WIDTH, HEIGHT, kind, stimulus=stimulus, segment_us=10_000, phase=phase,
                                   max_fit=float("inf"), interval_us=1_000_000 if online else None)
    spent = 0.0
    done = 0
    for chunk in chunks(method, events, scratch):
        if done == 0:  # compile outside the clock
            warm = ThresholdEstimator(WIDTH, HEIGHT, kind, stimulus=stimulus, segment_us=10_000, phase=phase)
            warm.process(chunk[:1000])
            try:
                warm.result()
            except Exception:  # noqa: BLE001 - 1000 events estimate nothing; only the compilation matters
                pass
        start = time.perf_counter()
        estimator.process(chunk)
        spent += time.perf_counter() - start
        done += len(chunk)
    start = time.perf_counter()
    result = estimator.result()
    final = time.perf_counter() - start
    return {"events": done, "seconds": spent, "result_s": final, "valid": int(result.valid.sum())}


def measure(method: str, events: int, scratch: str) -> dict:
    return measure_child("bench_estimate", method, events, scratch)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--child", nargs=3)
    parser.add_argument("--events", default="10000000,100000000")
    parser.add_argument("--baseline", metavar="DIR", help="also measure each method with the evtools in DIR")
    parser.add_argument("--methods", default="offe,natural,natural-online,stimulus,stimulus-online,fitted,"
                                                "fitted-gradient,gradient")
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child[0], int(args.child[1]), args.child[2])))
        return
    print(f"ThresholdEstimator.process on random events at {WIDTH}x{HEIGHT} (generation not timed); "
          "target >= 50 Mev/s (fitted phases: 20), peak RSS independent of length")
    print("fitted-gradient: the simulator's moving gradient (2.56 s, 2.15 M events) repeated, phases fitted")
    print(f"{'method':15} {'events':>12} {'seconds':>8} {'Mev/s':>7} {'result s':>8} {'peak RSS MB':>11} {'vs target':>9}")
    scratch = tempfile.mkdtemp(prefix="bench_estimate_")
    gradient = os.path.join(scratch, "gradient.aedat4")
    for method in args.methods.split(","):
        for events in (int(n) for n in args.events.split(",")):
            for repo in [None] + ([args.baseline] if args.baseline else []):
                if repo:
                    os.environ["EVTOOLS_BENCH_REPO"] = os.path.abspath(repo)
                r = measure(method, events, gradient)
                os.environ.pop("EVTOOLS_BENCH_REPO", None)
                rate = r["events"] / r["seconds"]
                label = f"{method} ({os.path.basename(os.path.abspath(repo))})" if repo else method
                print(f"{label:15} {r['events']:>12,} {r['seconds']:8.2f} {rate / 1e6:7.1f} {r['result_s']:8.2f} "
                      f"{r['peak_mb']:11.0f} {rate / TARGET_EV_S.get(method, DEFAULT_TARGET_EV_S):8.2f}x",
                      flush=True)


    shutil.rmtree(scratch)


if __name__ == "__main__":
    main()
