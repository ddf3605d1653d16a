"""Slow reference of the threshold-correction kernel (evtools/_kernels/correct.py), one event at a time.

Follows the founding report's section 4.2 literally, with this project's additions spelled out: per pixel, the
reconstruction is a polyline through points (time, level); each original event adds a point one of the pixel's
own thresholds up (ON) or down (OFF). With ``turns`` the polyline also starts at (stream start, 0), and the
segment that ends at a pixel's first event or at a polarity reversal is drawn only when the pixel's next event is
known (or the stream ends, or more than the window has passed):

- at a reversal, the polyline goes through the extremum where the line of the run before (through its last two
  events) meets the line of the run after (through its first two events);
- at a first event, the first run's line is followed back to the start level; the polyline is flat before.

Every segment of the polyline is re-sampled: an event wherever it crosses the corrected reference plus or minus
the target threshold, at the crossing time on the segment. The whole output is then sorted by time, ties in
creation order.
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


def _clamp(value, low, high):
    return min(max(value, low), high)


def extremum(gap, theta_before, slope_before, theta_after, slope_after):
    """Where a run (slope ``slope_before``, 0 unknown) turns between its last event and, ``gap`` us later, the
    first event of the other polarity (``theta_after`` beyond): (us after the last event, level beyond it)."""
    if slope_before > 0 and slope_after > 0:
        # beyond = slope_before * u  and  beyond + theta_after = slope_after * (gap - u)
        u = _clamp((slope_after * gap - theta_after) / (slope_before + slope_after), 0.0, gap)
        return u, min(slope_before * u, theta_before)
    if slope_before > 0 or slope_after > 0:  # the known slope on both sides
        slope = slope_before if slope_before > 0 else slope_after
        beyond = _clamp((slope * gap - theta_after) / 2, 0.0, theta_before)
        if slope_before > 0:
            return beyond / slope_before, beyond
        return max(gap - (beyond + theta_after) / slope_after, 0.0), beyond
    return gap / 2, theta_before / 2


def correct_naive(events, on, off, target_on, target_off, mode=FOH, hold_us=100_000, max_gap_us=1_000_000,
                  tau_us=100_000.0, turns=False, start_us=None, passthrough=None):
    """``(t, x, y, p)`` tuples of the corrected stream.

    ``on[y][x]``, ``off[y][x]`` are the pixel thresholds (floats); ``passthrough(x, y)`` says which pixels are left
    alone (default: those whose thresholds equal the target).
    """
    if passthrough is None:
        def passthrough(x, y):
            return on[y][x] == target_on and off[y][x] == target_off

    window = max_gap_us if mode == FOH else min(max_gap_us, hold_us)
    origin = None
    last = {}  # pixel -> time of its latest original event (or the stream start, with turns)
    polarity = {}  # pixel -> polarity of its latest event
    slope = {}  # pixel -> slope of its current run (log units per us) from its last two events; 0 unknown
    level = {}  # pixel -> reconstruction minus corrected reference, at the start of what is not drawn yet
    waiting = {}  # pixel -> (kind "first" or "turn", segment length us) of a segment not drawn yet
    created = []

    def draw(pixel, points, t):
        """Re-sample the polyline ``points`` [(time offset to t, level change since the previous point)]."""
        x, y = pixel
        a = level.get(pixel, 0.0)
        for (t_from, _), (t_to, change) in zip(points, points[1:]):
            made, a = _crossings(a, change, t_from, t_to, t, target_on, target_off)
            created.extend((when, x, y, p) for when, p in made)
        level[pixel] = a

    def settle(pixel, slope_after):
        kind, gap = waiting.pop(pixel)
        x, y = pixel
        up = polarity[pixel]
        theta = float(on[y][x]) if up else float(off[y][x])
        step = theta if up else -theta
        t = last[pixel]
        if kind == "first":
            back = min(gap, theta / slope_after) if slope_after > 0 else gap
            draw(pixel, [(-float(back), 0.0), (0.0, step)], t)
            slope[pixel] = theta / gap if slope_after == 0 and gap > 0 else 0.0
            return
        theta_before = float(off[y][x]) if up else float(on[y][x])
        u, beyond = extremum(float(gap), theta_before, slope[pixel], theta, slope_after)
        signed = -beyond if up else beyond
        draw(pixel, [(-float(gap), 0.0), (u - gap, signed), (0.0, step - signed)], t)
        slope[pixel] = 0.0

    for t, x, y, p in events:
        t, x, y, p = int(t), int(x), int(y), bool(p)
        if origin is None:
            origin = t if start_us is None else min(start_us, t)
        for pixel in sorted(waiting, key=lambda q: last[q]):  # stable: pixels started waiting in that order
            if t - last[pixel] > window:
                settle(pixel, 0.0)
        if passthrough(x, y):
            created.append((t, x, y, p))
            continue
        pixel = (x, y)
        theta = float(on[y][x]) if p else float(off[y][x])
        step = theta if p else -theta
        if turns and pixel not in last:
            last[pixel] = origin
        if pixel in waiting:  # (waited at most the window)
            gap = t - last[pixel]
            settle(pixel, theta / gap if polarity[pixel] == p and gap > 0 else 0.0)
        if pixel not in last:
            draw(pixel, [(0.0, 0.0), (0.0, step)], t)
            slope[pixel] = 0.0
        else:
            gap = t - last[pixel]
            before = polarity.get(pixel)
            if mode != FOH and gap > hold_us:  # a rest: held, everything at t
                if mode == HIGHPASS:
                    level[pixel] = level.get(pixel, 0.0) * math.exp(-(gap - hold_us) / tau_us)
                draw(pixel, [(0.0, 0.0), (0.0, step)], t)
                slope[pixel] = 0.0
            elif turns and before != p and gap <= max_gap_us:
                waiting[pixel] = ("first" if before is None else "turn", gap)
            else:
                draw(pixel, [(-float(min(gap, max_gap_us)), 0.0), (0.0, step)], t)
                slope[pixel] = theta / gap if before == p and gap > 0 else 0.0
        polarity[pixel] = p
        last[pixel] = t
    for pixel in sorted(waiting, key=lambda q: last[q]):
        settle(pixel, 0.0)
    order = sorted(range(len(created)), key=lambda i: (created[i][0], i))
    return [created[i] for i in order]
