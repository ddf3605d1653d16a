"""Slow reference of the threshold-correction kernel (evtools/_kernels/correct.py), one event at a time.

Follows the founding report's section 4.2 literally, with this project's additions spelled out: per pixel, the
reconstruction is a polyline through points (time, level); each original event adds a point one of the pixel's
own thresholds up (ON) or down (OFF); with ``turns`` the polyline also starts at (stream start, 0) and gets an
extra point (the extremum) between the last event of a run and an event of the other polarity. Every segment of
the polyline is re-sampled: an event wherever it crosses the corrected reference plus or minus the target
threshold, at the crossing time on the segment. The whole output is then sorted by time, ties in creation order.
"""

from __future__ import annotations

import math

FOH, STEP, HIGHPASS = "foh", "step", "highpass"


def _crossings(level, change, t_from, t_to, t_event, target_on, target_off):
    """Events where the segment from ``level`` (time ``t_event + t_from``) to ``level + change`` (time ``t_event
    + t_to``) crosses +target_on / -target_off around a reference that moves with each event; (events, level)."""
    events = []
    reference = 0.0  # counted in target thresholds, relative to the start of the segment
    k = 0
    while change > 0 and level + change >= (k + 1) * target_on:
        k += 1
        where = (k * target_on - level) / change  # fraction of the segment
        events.append((t_event + math.floor(t_from + where * (t_to - t_from) + 0.5), True))
        reference = k * target_on
    while change < 0 and level + change <= -(k + 1) * target_off:
        k += 1
        where = (-k * target_off - level) / change
        events.append((t_event + math.floor(t_from + where * (t_to - t_from) + 0.5), False))
        reference = -k * target_off
    return events, level + change - reference


def correct_naive(events, on, off, target_on, target_off, mode=FOH, hold_us=100_000, max_gap_us=1_000_000,
                  tau_us=100_000.0, turns=False, start_us=None, passthrough=None):
    """``(t, x, y, p)`` tuples of the corrected stream.

    ``on[y][x]``, ``off[y][x]`` are the pixel thresholds (floats); ``passthrough(x, y)`` says which pixels are left
    alone (default: those whose thresholds equal the target).
    """
    if passthrough is None:
        def passthrough(x, y):
            return on[y][x] == target_on and off[y][x] == target_off

    origin = None
    history = {}  # pixel -> list of (time, polarity) of its original events since the last rest
    last = {}  # pixel -> time of its previous original event (or the stream start, with turns)
    level = {}  # pixel -> reconstruction minus corrected reference
    created = []
    for t, x, y, p in events:
        t, x, y, p = int(t), int(x), int(y), bool(p)
        if origin is None:
            origin = t if start_us is None else min(start_us, t)
        if passthrough(x, y):
            created.append((t, x, y, p))
            continue
        pixel = (x, y)
        if turns and pixel not in last:
            last[pixel] = origin
        a = level.get(pixel, 0.0)
        step = float(on[y][x]) if p else -float(off[y][x])
        run = history.setdefault(pixel, [])
        points = None  # the polyline of this event: [(time offset to t, level change since the previous point)]
        if pixel in last:
            gap = t - last[pixel]
            if mode != FOH and gap > hold_us:  # a rest: held, everything at t
                if mode == HIGHPASS:
                    a *= math.exp(-(gap - hold_us) / tau_us)
                run.clear()
                points = [(0.0, 0.0), (0.0, step)]
            elif turns and run and run[-1][1] != p and gap <= max_gap_us:
                # the run went on beyond its last event before turning: an extremum between the two
                up = run[-1][1]
                theta_run = float(on[y][x]) if up else float(off[y][x])
                if len(run) >= 2 and run[-1][1] == run[-2][1] and run[-1][0] > run[-2][0]:
                    slope = theta_run / (run[-1][0] - run[-2][0])
                    beyond = min(max((slope * gap - abs(step)) / 2, 0.0), theta_run)
                    when = -gap + beyond / slope
                else:
                    beyond, when = theta_run / 2, -gap / 2
                signed = beyond if up else -beyond
                points = [(-float(gap), 0.0), (when, signed), (0.0, step - signed)]
            else:
                points = [(-float(min(gap, max_gap_us)), 0.0), (0.0, step)]
        else:
            points = [(0.0, 0.0), (0.0, step)]
        for (t_from, _), (t_to, change) in zip(points, points[1:]):
            made, a = _crossings(a, change, t_from, t_to, t, target_on, target_off)
            created.extend((when, x, y, polarity) for when, polarity in made)
        level[pixel] = a
        if run and run[-1][1] != p:
            run.clear()
        run.append((t, p))
        last[pixel] = t
    order = sorted(range(len(created)), key=lambda i: (created[i][0], i))
    return [created[i] for i in order]
