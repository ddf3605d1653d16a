"""Slow reference of the threshold-correction kernel (evtools/_kernels/correct.py), one event at a time.

Follows the founding report's section 4.2 literally, with this project's additions spelled out: per pixel, the
reconstruction is a polyline through points (time, level); each original event adds a point one of the pixel's
own thresholds up (ON) or down (OFF). With ``turns`` the polyline also starts at (stream start, 0), and the
segment that ends at a pixel's first event or at a polarity reversal is drawn only when the pixel's next event is
known: if it comes within the window (``max_gap_us``, or ``hold_us`` when smaller and the mode is not foh), it
gives the slope after the turn; otherwise (or when the stream ends first) that slope is unknown. Waiting pixels
are also settled, slope unknown, whenever the stream has moved a window on since the last such check (they
would get the same from their own next event, so this only fixes the order in which events are created):

- at a reversal, the polyline goes through the extremum: after a straight run (its last two intervals within
  1 % of each other) where the line of the run before (through its last two events) meets the line of the run
  after (through its first two events), if that point lies less than one of the run's thresholds beyond its last
  level; otherwise half a threshold beyond it, at the time where the run's slope (rising to it) and the new run's
  slope (falling from it to the event's level) meet when scaled to fill the gap. A reversal over a rest (all but
  foh, unless the run ended in a re-sampled tail or, with ``curves``, slowed down: its approach's model says how
  far it went) goes half a threshold beyond at the run's slope from its last
  event (no earlier than three windows before the event), stays, and comes back at the event's time;
- at a first event, the first run's line is followed back to the start level; the polyline is flat before. A
  first run whose line back meets the anchor (within 1 %), or of one event (its line is the anchored one), counts
  as straight so far.

With ``curves``, a segment between two events of a run (same polarity, within the window) whose interval is more
than 1 % longer than the run's previous interval is not a line but the exponential approach ``A (1 - exp(-s /
tau))`` through the run's last three events (levels one threshold apart), tau solved by bisection and kept to the
whole us. Beyond the event, that approach goes on towards its asymptote: if within min(window, 3 tau) it rises by
less than a threshold (the pixel will not fire again) but far enough to cross a target level, the pixel waits a
window: an event of its own within the window drops that tail, otherwise (or at the stream's end) the tail's
crossings are made and the level returns to the pixel's own reference level.

With ``turns``, at the stream's end every pixel's run goes on by half its threshold at its slope (unless the run
ended in a re-sampled tail or, with ``curves``, slowed down).

Every segment of the polyline is re-sampled: an event wherever it crosses the corrected reference plus or minus
the target threshold, at the crossing time on the segment. The output is then sorted by time, ties between pixels
of even and of odd sensor rows with the even rows' first (the kernel's two lanes), other ties in creation order;
when every pixel's thresholds equal the target, the output is the input itself.
"""

from __future__ import annotations

import math

import numpy as np

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


def _curve_crossings(level, change, t_from, span, tau, t_event, target_on, target_off):
    """As :func:`_crossings` for the exponential approach ``level + change (1 - exp(-s / tau)) / (1 - exp(-span /
    tau))`` for s from 0 (time ``t_event + t_from``) to ``span``."""
    events = []
    reference = 0.0
    k = 0
    full = 1.0 - math.exp(-span / tau)
    while change > 0 and level + change >= (k + 1) * target_on:
        k += 1
        s = _curve_time(1.0 - (k * target_on - level) / change * full, tau, span)
        events.append((t_event + math.floor(t_from + s + 0.5), True))
        reference = k * target_on
    while change < 0 and level + change <= -(k + 1) * target_off:
        k += 1
        s = _curve_time(1.0 - (-k * target_off - level) / change * full, tau, span)
        events.append((t_event + math.floor(t_from + s + 0.5), False))
        reference = -k * target_off
    return events, level + change - reference


def _curve_time(remaining, tau, span):
    """When ``1 - exp(-s / tau)`` reaches ``1 - remaining``; never after the segment's end (a crossing at the end
    itself may compute slightly past it, or at ``log(0)`` when ``exp(-span / tau)`` underflows)."""
    return span if remaining <= 0 else min(-tau * math.log(remaining), span)


def approach_tau(interval_a, interval_b):
    """Time constant of ``A (1 - exp(-t / tau))`` through (0, 0), (interval_a, theta), (interval_a + interval_b,
    2 theta), by bisection on log(tau) (the ratio of the two rises grows with tau, from 1 to (a + b) / a > 2)."""
    def ratio(tau):
        return (1.0 - math.exp(-(interval_a + interval_b) / tau)) / (1.0 - math.exp(-interval_a / tau))
    low, high = math.log(interval_a * 1e-3), math.log(interval_a * 1e9)
    for _ in range(200):
        middle = 0.5 * (low + high)
        if ratio(math.exp(middle)) < 2.0:
            low = middle
        else:
            high = middle
    return math.exp(0.5 * (low + high))


def _clamp(value, low, high):
    return min(max(value, low), high)


def extremum(gap, theta_before, interval_before, theta_after, interval_after, straight=True):
    """Where a run turns between its last event and, ``gap`` us later, the first event of the other polarity
    (``theta_after`` beyond): (us after the last event, level beyond it). A ramp's slope is one threshold per
    interval between its events (``interval_*``, 0 unknown).

    ``straight``: the two lines meet where ``beyond = theta_before / interval_before * u`` and ``beyond +
    theta_after = theta_after / interval_after * (gap - u)``, kept when ``beyond < theta_before``. Otherwise
    ``beyond`` is half of ``theta_before``, reached after ``u`` in the ratio of the time to rise to it and the time
    to fall from it by ``beyond + theta_after``. A slope not known takes the other's; neither known: both are the
    slope of a symmetric turn half a threshold beyond the run's last level."""
    if interval_before <= 0 and interval_after <= 0:
        # slope (theta_before + theta_after) / gap on both sides
        interval_before = theta_before * gap / (theta_before + theta_after)
        interval_after = theta_after * gap / (theta_before + theta_after)
    elif interval_before <= 0:
        interval_before = theta_before * interval_after / theta_after
    elif interval_after <= 0:
        interval_after = theta_after * interval_before / theta_before
    if straight:
        if gap <= interval_after:  # the new ramp's line reaches its first event's level only from the last event on
            return 0.0, 0.0
        # solve both line equations for u (multiplying out the slopes' divisions)
        scale = theta_after * (gap - interval_after) / (theta_before * interval_after + theta_after * interval_before)
        if scale < 1:
            return scale * interval_before, scale * theta_before
        if scale <= 1.01:  # a turn at the next level, within the precision of whole-us event times
            return interval_before, theta_before
    beyond = 0.5 * theta_before
    rise = beyond * interval_before / theta_before  # at the run's slope
    fall = (beyond + theta_after) * interval_after / theta_after  # at the new run's slope
    return (gap * rise / (rise + fall) if rise + fall > 0 else 0.0), beyond


def correct_naive(events, on, off, target_on, target_off, mode=FOH, hold_us=100_000, max_gap_us=1_000_000,
                  tau_us=100_000.0, turns=False, curves=False, start_us=None, passthrough=None):
    """``(t, x, y, p)`` tuples of the corrected stream.

    ``on[y][x]``, ``off[y][x]`` are the pixel thresholds (floats); ``passthrough(x, y)`` says which pixels are left
    alone (default: those whose thresholds equal the target).
    """
    events = [(int(t), int(x), int(y), bool(p)) for t, x, y, p in events]
    if passthrough is None:
        def passthrough(x, y):
            return on[y][x] == target_on and off[y][x] == target_off
    if all(passthrough(x, y) for y in range(len(on)) for x in range(len(on[0]))):
        return events

    window = max_gap_us if mode == FOH else min(max_gap_us, hold_us)
    due = None  # when the waiting pixels are next checked
    origin = None
    last = {}  # pixel -> time of its latest original event (or the stream start, with turns)
    polarity = {}  # pixel -> polarity of its latest event
    interval = {}  # pixel -> time between the last two events of its current run (us; 0 unknown or > window)
    previous = {}  # pixel -> the run's interval before that (us, whole; 0 unknown)
    level = {}  # pixel -> reconstruction minus corrected reference, at the start of what is not drawn yet
    waiting = {}  # pixel -> (kind "first", "turn" or "tail", segment length us or tail's tau) not drawn yet
    created = []

    def draw(pixel, points, t):
        """Re-sample the polyline ``points`` [(time offset to t, level change since the previous point)]."""
        x, y = pixel
        a = level.get(pixel, 0.0)
        for (t_from, _), (t_to, change) in zip(points, points[1:]):
            made, a = _crossings(a, change, t_from, t_to, t, target_on, target_off)
            created.extend((when, x, y, p) for when, p in made)
        level[pixel] = a

    def tail_of(theta, interval_us, tau):
        """How far the approach goes on after its event, within the span it is followed."""
        span = min(float(window), 3.0 * tau)
        decay = math.exp(-interval_us / tau)  # the rest to the asymptote is theta * decay / (1 - decay)
        return theta * decay / (1.0 - decay) * (1.0 - math.exp(-span / tau)), span

    def run_excess(pixel):
        """How far the pixel's run went on after its latest event (signed): none after a re-sampled tail; with
        curves, a run that slowed down goes on by its approach's rest when below a threshold; else half a
        threshold."""
        x, y = pixel
        up = polarity[pixel]
        theta = float(on[y][x]) if up else float(off[y][x])
        gone, before = interval.get(pixel, 0), previous.get(pixel, 0)
        excess = 0.5 * theta
        if gone < 0:
            excess = 0.0
        elif curves and before > 0 and gone > 1.01 * before:
            tau = min(math.floor(approach_tau(float(before), float(gone)) + 0.5), 2**31 - 1)
            decay = math.exp(-gone / tau)
            if theta * decay / (1.0 - decay) < theta:  # followed as a tail is: for at most 3 tau
                excess = theta * decay / (1.0 - decay) * (1.0 - math.exp(-3.0))
        return excess if up else -excess

    def settle(pixel, interval_after):
        kind, gap = waiting.pop(pixel)
        x, y = pixel
        up = polarity[pixel]
        theta = float(on[y][x]) if up else float(off[y][x])
        step = theta if up else -theta
        t = last[pixel]
        if kind == "tail":
            rise, span = tail_of(theta, float(interval[pixel]), float(gap))
            rise = rise if up else -rise
            made, a = _curve_crossings(level[pixel], rise, 0.0, span, float(gap), t, target_on, target_off)
            created.extend((when, x, y, p) for when, p in made)
            level[pixel] = a - rise
            interval[pixel] = -1  # a tail re-sampled: a reversal over a rest adds no excess
            previous[pixel] = 0
            return
        if kind == "first":
            back = min(gap, interval_after) if interval_after > 0 else gap  # the first ramp's line back to 0
            draw(pixel, [(-float(back), 0.0), (0.0, step)], t)
            # the anchored line is the first ramp (unknown slope, or its line back meets the anchor)
            meets = interval_after == 0 or max(gap, interval_after) <= 1.01 * min(gap, interval_after)
            interval[pixel] = previous[pixel] = gap if meets else 0
            return
        theta_before = float(off[y][x]) if up else float(on[y][x])
        u, beyond = extremum(float(gap), theta_before, float(interval[pixel]), theta, float(interval_after),
                             kind == "lines")
        signed = -beyond if up else beyond
        draw(pixel, [(-float(gap), 0.0), (u - gap, signed), (0.0, step - signed)], t)
        interval[pixel] = previous[pixel] = 0

    for t, x, y, p in events:
        t, x, y, p = int(t), int(x), int(y), bool(p)
        if origin is None:
            origin = t if start_us is None else min(start_us, t)
        if due is None or t >= due:
            for pixel in sorted(waiting, key=lambda q: last[q]):  # stable: pixels started waiting in that order
                if t - last[pixel] > window:
                    settle(pixel, 0.0)
            due = t + window
        if passthrough(x, y):
            created.append((t, x, y, p))
            continue
        pixel = (x, y)
        theta = float(on[y][x]) if p else float(off[y][x])
        step = theta if p else -theta
        if turns and pixel not in last:
            last[pixel] = origin
        if pixel in waiting:
            gap = t - last[pixel]
            if waiting[pixel][0] == "tail" and gap <= window:
                del waiting[pixel]  # the pixel fired again: no tail
                previous[pixel] = 0
            else:
                settle(pixel, gap if polarity[pixel] == p and 0 < gap <= window else 0)
        if pixel not in last:
            draw(pixel, [(0.0, 0.0), (0.0, step)], t)
            interval[pixel] = previous[pixel] = 0
        else:
            gap = t - last[pixel]
            before = polarity.get(pixel)
            if mode != FOH and gap > hold_us:  # a rest: held, everything at t
                forget = math.exp(-(gap - hold_us) / tau_us) if mode == HIGHPASS else 1.0
                if turns and before is not None and before != p:
                    # the run's excess, reached at its slope after its last event (but not earlier than three
                    # windows before t), held (highpass: the level then forgotten over the rest), and back at t
                    beyond = run_excess(pixel)
                    begin = max(-float(gap), -3.0 * window)
                    reached = -min(gap - 0.5 * max(interval.get(pixel, 0), 0), 3.0 * window)
                    draw(pixel, [(begin, 0.0), (reached, beyond)], t)
                    level[pixel] *= forget
                    draw(pixel, [(0.0, 0.0), (0.0, step - beyond * forget)], t)
                else:
                    level[pixel] = level.get(pixel, 0.0) * forget
                    draw(pixel, [(0.0, 0.0), (0.0, step)], t)
                interval[pixel] = 0
                previous[pixel] = 0
            elif turns and before != p and gap <= max_gap_us:
                a, b = float(interval.get(pixel, 0)), float(previous.get(pixel, 0))
                straight = a > 0 and b > 0 and max(a, b) <= 1.01 * min(a, b)
                waiting[pixel] = ("first" if before is None else "lines" if straight else "turn", gap)
            elif curves and before == p and 0 < interval[pixel] and gap <= window and gap > 1.01 * interval[pixel]:
                tau = min(math.floor(approach_tau(float(interval[pixel]), float(gap)) + 0.5), 2**31 - 1)
                made, a = _curve_crossings(level.get(pixel, 0.0), step, -float(gap), float(gap), float(tau), t,
                                           target_on, target_off)
                created.extend((when, x, y, q) for when, q in made)
                level[pixel] = a
                previous[pixel] = math.floor(interval[pixel] + 0.5)
                interval[pixel] = gap
                rise, _ = tail_of(theta, float(gap), float(tau))
                reaches = (a + rise >= target_on) if p else (a - rise <= -target_off)
                if rise < theta and reaches:
                    waiting[pixel] = ("tail", tau)
            else:
                draw(pixel, [(-float(min(gap, max_gap_us)), 0.0), (0.0, step)], t)
                ramp = before == p and 0 < gap <= window
                previous[pixel] = math.floor(max(interval.get(pixel, 0), 0) + 0.5) if ramp else 0
                interval[pixel] = gap if ramp else 0
        polarity[pixel] = p
        last[pixel] = t
    for pixel in sorted(waiting, key=lambda q: last[q]):
        settle(pixel, 0.0)
    if turns and events:  # the stream ended: each pixel's run went on by half its threshold, at its slope, but
        # not before three windows before the stream's last event (what the kernel has released by then)
        not_before = events[-1][0] - 3 * window
        for pixel in sorted(polarity, key=lambda q: (q[1], q[0])):
            if passthrough(*pixel):
                continue
            excess = run_excess(pixel)
            gone = interval.get(pixel, 0)
            begin = float(max(not_before - last[pixel], 0))
            draw(pixel, [(begin, 0.0), (max(0.5 * gone, begin), excess)], last[pixel])
    order = sorted(range(len(created)), key=lambda i: (created[i][0], created[i][2] % 2, i))
    return [created[i] for i in order]


def carried_naive(values, usable, stale, never=None):
    """A series of maps (maps, height, width) of one polarity with every unusable entry filled, pixel by pixel:
    before its first usable value a pixel takes that value (never usable: ``never``, or without it the median of
    the usable values of the last map that has any); then it keeps its latest usable value, except where a later map marks it stale: there
    it takes the median of the usable values of the latest map up to that one that has any (none yet: the median
    of map 0 as filled). A pixel never usable has no estimate to drop: stale leaves it as it is."""
    maps, height, width = values.shape
    with_usable = [k for k in range(maps) if usable[k].any()]
    last_median = np.median(values[with_usable[-1]][usable[with_usable[-1]]]) if never is None else np.float32(never)
    filled = np.empty(values.shape, np.float32)
    for y in range(height):
        for x in range(width):
            usable_at = [k for k in range(maps) if usable[k, y, x]]
            filled[0, y, x] = values[0, y, x] if usable[0, y, x] else (
                values[usable_at[0], y, x] if usable_at else last_median)
    for k in range(1, maps):
        earlier = [j for j in with_usable if j <= k]
        median = np.float32(np.median(values[earlier[-1]][usable[earlier[-1]]]) if earlier
                            else np.median(filled[0]))
        for y in range(height):
            for x in range(width):
                if usable[k, y, x]:
                    filled[k, y, x] = values[k, y, x]
                elif stale[k, y, x] and usable[:, y, x].any():
                    filled[k, y, x] = median
                else:
                    filled[k, y, x] = filled[k - 1, y, x]
    return filled
