"""How often each `correct` mode makes a stream worse than doing nothing where the thresholds are nearly right.

Steps of log intensity (each at once, 400 ms apart: rests longer than the hold) at random levels, seen by ideal
pixels (tests/naive/ideal_pixel.py: exact crossings, none of the simulator's code) whose thresholds are within
0.5 % of the target, below it or above it; 300 draws of 6 pixels with 2-6 steps each, corrected with the exact
thresholds. The input's per-pixel counts then equal the ideal sensor's, so any change is the correction's error.
Prints, per mode, the share of draws whose per-pixel count error against the ideal grew, and the total error.
Run: python samples/near_target_steps.py (about a minute).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from evtools.correction import correct_thresholds  # noqa: E402
from evtools.events import make_events  # noqa: E402
from tests.naive.ideal_pixel import ideal_columns  # noqa: E402

TARGET = float(np.float32(0.2))
WIDTH, HEIGHT = 3, 2


def stream(waves, thresholds):
    return make_events(*ideal_columns(waves, [(theta, theta) for theta in thresholds], WIDTH))


def count_error(events, ideal):
    def counts(stream_):
        return np.array([[np.sum((stream_["x"] == i % WIDTH) & (stream_["y"] == i // WIDTH) & (stream_["p"] == p))
                          for p in (True, False)] for i in range(WIDTH * HEIGHT)])
    return int(np.abs(counts(events) - counts(ideal)).sum())


def main() -> None:
    rng = np.random.default_rng(0)
    print("| thresholds | mode | draws worse than uncorrected | count error in / out |")
    print("|---|---|---|---|")
    for sign, side in ((-1, "below the target"), (1, "above the target")):
        draws = []
        for _ in range(300):
            waves, thresholds = [], []
            for _ in range(WIDTH * HEIGHT):
                corners, level = [(0.0, 0.0)], 0.0
                steps = int(rng.integers(2, 7))
                for k in range(steps):
                    t, new = 400_000.0 * (k + 1), TARGET * (rng.integers(-7, 8) + rng.uniform(0.1, 0.9))
                    corners += [(t, level), (t, new)]
                    level = new
                corners.append((400_000.0 * (steps + 1), level))
                waves.append(corners)
                thresholds.append(float(np.float32(TARGET * (1 + sign * rng.uniform(0, 0.005)))))
            draws.append((stream(waves, thresholds), stream(waves, [TARGET] * len(waves)),
                          np.array(thresholds, np.float32).reshape(HEIGHT, WIDTH)))
        for mode in ("exponential", "turns", "highpass"):
            worse = error_in = error_out = 0
            for events, ideal, on in draws:
                out = correct_thresholds(events, WIDTH, HEIGHT, on, on, target=TARGET, mode=mode, start_us=0)
                before, after = count_error(events, ideal), count_error(out, ideal)
                worse += after > before
                error_in, error_out = error_in + before, error_out + after
            print(f"| {side} | {mode} | {100 * worse / len(draws):.0f} % | {error_in} / {error_out} |")


if __name__ == "__main__":
    main()
