"""Slow reference of the high-pass reconstruction (evtools/metrics/reconstruction.py), one event at a time.

Per pixel a value s, 0 at the start: an event first lets s decay by exp(-2 pi cutoff dt) over the time since the
pixel's previous event, then adds its contrast (ON) or subtracts it (OFF). The snapshot at time T of a pixel is the
baseline plus s decayed from the pixel's last event at or before T to T.
"""

from __future__ import annotations

import math


def reconstruct_naive(events, baseline, frame_times, contrast_on, contrast_off, cutoff_hz):
    """``events``: (t, x, y, p) tuples in time order; ``baseline``, ``contrast_*``: nested lists [y][x]; returns
    the snapshots as nested lists [frame][y][x]."""
    alpha_per_us = 2.0 * math.pi * cutoff_hz / 1e6
    state = {}  # (x, y) -> (s, time of its last event)
    snapshots = []
    pending = list(events)
    for frame_t in frame_times:
        while pending and pending[0][0] <= frame_t:
            t, x, y, p = pending.pop(0)
            s, last = state.get((x, y), (0.0, t))
            s = s * math.exp(-alpha_per_us * (t - last))
            s += contrast_on[y][x] if p else -contrast_off[y][x]
            state[(x, y)] = (s, t)
        frame = []
        for y, row in enumerate(baseline):
            line = []
            for x, value in enumerate(row):
                s, last = state.get((x, y), (0.0, frame_t))
                line.append(value + s * math.exp(-alpha_per_us * (frame_t - last)))
            frame.append(line)
        snapshots.append(frame)
    return snapshots
