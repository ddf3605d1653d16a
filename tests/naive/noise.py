"""Background activity drawn by plain numpy, for tests of what measures or filters it: shares nothing with
``evtools.noise``. Shot noise: a Poisson process per pixel, each event ON or OFF at random; leak: ON events at a
fixed period per pixel, with a random phase."""

from __future__ import annotations

import numpy as np

EVENT_FIELDS = [("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "?")]


def background_activity(width, height, start_us, end_us, *, shot_hz, leak_hz, seed):
    """Noise events on [start_us, end_us) of a width x height sensor, in time order, as a record array."""
    rng = np.random.default_rng(seed)
    seconds = (end_us - start_us) * 1e-6
    count = rng.poisson(shot_hz * width * height * seconds)
    t = rng.uniform(start_us, end_us, count)
    x, y = rng.integers(0, width, count), rng.integers(0, height, count)
    p = rng.random(count) < 0.5
    if leak_hz > 0:
        period_us = 1e6 / leak_hz
        phase = rng.uniform(0, period_us, (height, width))
        for row in range(height):
            for column in range(width):
                times = np.arange(start_us + phase[row, column], end_us, period_us)
                t = np.concatenate([t, times])
                x = np.concatenate([x, np.full(len(times), column)])
                y = np.concatenate([y, np.full(len(times), row)])
                p = np.concatenate([p, np.ones(len(times), bool)])
    order = np.argsort(t, kind="stable")
    out = np.zeros(len(t), EVENT_FIELDS)
    out["t"], out["x"], out["y"], out["p"] = t[order].astype(np.int64), x[order], y[order], p[order]
    return out


def merge(signal, noise):
    """The two streams merged by time (signal first at equal times) and a label per event: 0 signal, 1 noise."""
    events = np.concatenate([np.asarray(signal, EVENT_FIELDS), np.asarray(noise, EVENT_FIELDS)])
    labels = np.concatenate([np.zeros(len(signal), np.uint8), np.ones(len(noise), np.uint8)])
    order = np.argsort(events["t"], kind="stable")
    return events[order], labels[order]
