"""Slow reference of the threshold-correction kernel (evtools/_kernels/correct.py), one event at a time.

Follows the founding report's section 4.2 literally: per pixel, the reconstruction moves by the pixel's own
threshold at each event; between the pixel's previous event and this one it is a straight line; an event is
emitted wherever the line crosses the corrected reference plus or minus the target threshold, at the crossing
time on that line. The whole output is then sorted by time, ties in creation order.
"""

from __future__ import annotations

import math

FOH, STEP, HIGHPASS = "foh", "step", "highpass"


def correct_naive(events, on, off, target_on, target_off, mode=FOH, hold_us=100_000, max_gap_us=1_000_000,
                  tau_us=100_000.0, passthrough=None):
    """``(t, x, y, p)`` tuples of the corrected stream.

    ``on[y][x]``, ``off[y][x]`` are the pixel thresholds (floats); ``passthrough(x, y)`` says which pixels are left
    alone (default: those whose thresholds equal the target).
    """
    if passthrough is None:
        def passthrough(x, y):
            return on[y][x] == target_on and off[y][x] == target_off

    last = {}  # pixel -> time of its previous original event
    level = {}  # pixel -> reconstruction minus corrected reference
    created = []
    for t, x, y, p in events:
        t, x, y, p = int(t), int(x), int(y), bool(p)
        if passthrough(x, y):
            created.append((t, x, y, p))
            continue
        a = level.get((x, y), 0.0)
        t_start = t
        if (x, y) in last:
            gap = t - last[(x, y)]
            if mode == HIGHPASS and gap > hold_us:
                a = a * math.exp(-(gap - hold_us) / tau_us)
            if mode == FOH or gap <= hold_us:
                t_start = last[(x, y)] if gap <= max_gap_us else t - max_gap_us
        step = float(on[y][x]) if p else -float(off[y][x])
        k = 1
        if p:
            while a + step >= k * target_on:  # the line reaches the k-th ON level above the reference
                fraction = (k * target_on - a) / step
                created.append((t_start + math.floor(fraction * (t - t_start) + 0.5), x, y, True))
                k += 1
            level[(x, y)] = a + step - (k - 1) * target_on
        else:
            while a + step <= -k * target_off:
                fraction = (-k * target_off - a) / step
                created.append((t_start + math.floor(fraction * (t - t_start) + 0.5), x, y, False))
                k += 1
            level[(x, y)] = a + step + (k - 1) * target_off
        last[(x, y)] = t
    order = sorted(range(len(created)), key=lambda i: (created[i][0], i))
    return [created[i] for i in order]
