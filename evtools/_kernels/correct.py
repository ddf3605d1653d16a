"""Threshold-correction kernels: re-sample every pixel's events at one target threshold, and release them in order.

Each pixel's events are read as samples of its log intensity: event j moves the reconstruction by the pixel's own
``+on`` or ``-off`` threshold. The pixel keeps ``level``, the reconstruction minus the corrected (re-sampled)
reference. Between two points of the reconstruction the signal is a straight line (first-order hold); every time
``level`` reaches ``+target_on`` (``-target_off``) an ON (OFF) event is emitted at the exact crossing time on that
line and the reference moves by the target threshold; what is left over is carried on (the report's eq. 15).

Where the line of event j starts (``mode``):

- ``MODE_FOH`` (0): at the pixel's previous event, never before ``t_j - max_gap_us`` (the bound that keeps the
  reordering window finite); a pixel's first event has no predecessor: its crossings are at its own time;
- ``MODE_STEP`` (1): as FOH when the gap is at most ``hold_us``; over a longer gap (a rest) the signal is held
  constant until ``t_j``, so every crossing of event j is at ``t_j`` (the report's step-aware variant);
- ``MODE_HIGHPASS`` (2): as STEP, and over a rest the carried ``level`` decays by ``exp(-(gap - hold_us) /
  tau_us)``, so the level error that inexact thresholds add with every event is forgotten at every rest.

With ``turns`` (on in the ``turns`` and ``highpass`` modes of the corrector) the reconstruction is also

- anchored: every pixel's reconstruction starts at level 0 (its reference) at the stream's start (the caller sets
  ``last_us`` of every pixel to that time), so the crossings of its first event are interpolated too (unless the
  first event comes after a rest);
- turned: when the polarity reverses without a rest, the signal went on beyond the last event of the run (by
  less than that run's threshold, else the pixel would have fired again) before it turned. A virtual extremum P is
  inserted between the run's last event ``(t_a, R)`` and the reversing event ``t_b``: assuming the run's slope
  ``s = theta_run / (t_a - t_prev)`` on both sides of the turn, ``P - R = (s (t_b - t_a) - theta_new) / 2`` at
  ``t_a + (P - R) / s``, clamped to ``[0, theta_run]``; ``theta_run / 2`` at the midpoint when the run has one
  event. The line then goes ``(t_a, R) -> P -> (t_b, R -/+ theta_new)``, both segments re-sampled. On a
  log-linear triangle with exact thresholds this is the signal itself, so the re-sampling is exact.

Every re-sampled event of input event j lies in ``[start, t_j]`` with ``start`` the pixel's previous event (or
``max(origin, t_j - max_gap_us)``), the ordering argument of :class:`evtools.correct.ThresholdCorrector`.
Pixels whose ``use`` flag is False pass through unchanged. ``tests/naive/correct.py`` holds the pure-Python
reference.

References
----------
The founding report, section 4.2 (FOH re-sampling) and 5.2 (step-aware variant).
C. Scheerlinck, N. Barnes, R. Mahony, "Continuous-time Intensity Estimation Using Event Cameras", ACCV 2018
(the high-pass filter whose exponential decay ``MODE_HIGHPASS`` applies to the carried level).
"""

from __future__ import annotations

import math

import numpy as np

from evtools._kernels.jit import kernel
from evtools._kernels.prefetch import prefetch

MODE_FOH = 0
MODE_STEP = 1
MODE_HIGHPASS = 2

NO_EVENT_US = (1 << 63) - 1
"""``last_us`` of a pixel that has not fired yet (the largest int64, so a minimum over pixels ignores it)."""


ON_BIT = 1 << 32
"""The polarity bit of an event's second 8-byte word (x int16 at byte 8, y int16 at byte 10, p bool at byte 12)."""


@kernel(inline=True)
def _segment(level, delta, off0, off1, t_b, xy, target_on, target_off, out_t, out_w, n):
    """Re-sample the line from ``(t_b + off0, level)`` to ``(t_b + off1, level + delta)``; returns (level, n).

    ``xy`` is the pixel's x and y as the low 32 bits of an event's second word; created events are written as
    (time, word) pairs."""
    span = off1 - off0
    if delta > 0.0:
        k = 1.0
        while level + delta >= k * target_on:
            out_t[n] = t_b + np.int64(math.floor(off0 + (k * target_on - level) / delta * span + 0.5))
            out_w[n] = xy | ON_BIT
            n += 1
            k += 1.0
        return level + delta - (k - 1.0) * target_on, n
    if delta < 0.0:
        k = 1.0
        while level + delta <= -k * target_off:
            out_t[n] = t_b + np.int64(math.floor(off0 + (-k * target_off - level) / delta * span + 0.5))
            out_w[n] = xy
            n += 1
            k += 1.0
        return level + delta + (k - 1.0) * target_off, n
    return level, n


AHEAD = 16
"""How many events ahead the kernel prefetches a pixel's state (events hit random pixels: 20 % faster on the
bench stream than a plain load ahead, which was itself 20 % faster than none)."""

PIXEL_DTYPE = np.dtype([("level", np.float64), ("last_us", np.int64), ("previous_us", np.int64),
                        ("on", np.float32), ("off", np.float32)])
"""Per-pixel state, 32 bytes (one cache line holds two pixels, so an event touches one): the carried level, the
previous event's time (NO_EVENT_US before the first), the one before it when of the same polarity and not across
a rest (else NO_EVENT_US), and the pixel's thresholds (float32, the maps' precision)."""


@kernel
def correct_events(words, start, width, state, polarity, use, target_on, target_off, mode, turns, hold_us,
                   max_gap_us, tau_us, out_t, out_w, n):  # pragma: no cover - compiled
    """Process the events ``words[start:]`` ((n, 2) int64: time, then x, y, p as EVENT_DTYPE lays them out) while
    their worst case fits in the output arrays.

    Returns (next input, count).

    ``state`` (:data:`PIXEL_DTYPE`) and ``polarity`` (int8: +1, -1, 0 before the first event) are per pixel (index
    ``y * width + x``) and updated in place; ``use`` says which pixels are re-sampled. Events are written from
    index ``n`` on, in creation order, as times ``out_t`` and second words ``out_w`` (padding zero).
    """
    capacity = out_t.shape[0]
    min_target = min(target_on, target_off)
    end = words.shape[0]
    i = start
    while i < end:
        if i + AHEAD < end:  # the state of a pixel a few events ahead: its cache miss overlaps this work
            ahead = words[i + AHEAD, 1]
            prefetch(state, ((ahead >> 16) & 0xFFFF) * width + (ahead & 0xFFFF))
        t_b = words[i, 0]
        word = words[i, 1]
        xy = word & 0xFFFFFFFF
        on = ((word >> 32) & 0xFF) != 0
        pixel = ((word >> 16) & 0xFFFF) * width + (word & 0xFFFF)
        if not use[pixel]:
            if n >= capacity:
                return i, n
            out_t[n] = t_b
            out_w[n] = xy | ON_BIT if on else xy
            n += 1
            i += 1
            continue
        row = state[pixel]
        a = row.level
        theta_on = float(row.on)
        theta_off = float(row.off)
        last_polarity = polarity[pixel]
        t_a = row.last_us
        t_prev = row.previous_us
        sign = 1 if on else -1
        d = theta_on if on else -theta_off
        # worst case: |a| < max target, an extremum < one threshold, the event's own threshold
        if n + (abs(a) + theta_on + theta_off) / min_target + 3.0 > capacity:
            return i, n
        off_start = 0.0
        turn = False
        rest = False
        if t_a != NO_EVENT_US:
            gap = t_b - t_a
            rest = mode != MODE_FOH and gap > hold_us
            if rest:
                if mode == MODE_HIGHPASS:
                    a = a * math.exp(-(gap - hold_us) / tau_us)
            else:
                off_start = -float(min(gap, max_gap_us))
                turn = turns and last_polarity == -sign and gap <= max_gap_us
        if turn:
            run = -float(sign)  # the run's direction: the opposite of this event's
            theta_run = theta_on if run > 0.0 else theta_off
            gap_f = float(t_b - t_a)
            if t_prev != NO_EVENT_US and t_a > t_prev:
                slope = theta_run / float(t_a - t_prev)
                excess = 0.5 * (slope * gap_f - abs(d))
                excess = min(max(excess, 0.0), theta_run)
                off_peak = -gap_f + excess / slope
            else:
                excess = 0.5 * theta_run
                off_peak = -0.5 * gap_f
            a, n = _segment(a, run * excess, -gap_f, off_peak, t_b, xy, target_on, target_off, out_t, out_w, n)
            a, n = _segment(a, d - run * excess, off_peak, 0.0, t_b, xy, target_on, target_off, out_t, out_w, n)
        else:
            a, n = _segment(a, d, off_start, 0.0, t_b, xy, target_on, target_off, out_t, out_w, n)
        row.level = a
        polarity[pixel] = sign
        # the run's previous event, for its slope (not across a rest: that is no ramp)
        row.previous_us = t_a if (last_polarity == sign and not rest) else NO_EVENT_US
        row.last_us = t_b
        i += 1
    return i, n


@kernel(inline=True)
def _merge(a_t, a_w, i, a_end, b_t, b_w, j, b_end, dst_t, dst_w, d):
    """Merge ``a[i:a_end]`` and ``b[j:b_end]`` (each sorted by time) into ``dst`` from ``d``, ``a`` first on ties;
    branch-free in the common part (which run is next is a coin toss)."""
    while i < a_end and j < b_end:
        ta = a_t[i]
        tb = b_t[j]
        take_a = ta <= tb
        dst_t[d] = ta if take_a else tb
        dst_w[d] = a_w[i] if take_a else b_w[j]
        i += take_a
        j += 1 - take_a
        d += 1
    while i < a_end:
        dst_t[d] = a_t[i]
        dst_w[d] = a_w[i]
        i += 1
        d += 1
    while j < b_end:
        dst_t[d] = b_t[j]
        dst_w[d] = b_w[j]
        j += 1
        d += 1
    return d


@kernel
def release_sorted(held_t, held_w, h, new_t, new_w, n, bound, order, counts, sorted_t, sorted_w, out_t, out_w,
                   keep_t, keep_w):  # pragma: no cover - compiled
    """Merge the held events (sorted) with the new ones (creation order); split at ``bound``.

    The new events are sorted by time into ``sorted_*``, ties in creation order (a counting sort that scatters
    them straight to their places when ``counts`` covers their time span, else a stable merge sort and a
    gather). The merged stream is sorted, so the events at or before ``bound`` are its first ones: the runs' parts
    up to ``bound`` are merged into ``out_*``, the rest into ``keep_*`` (held first on ties: they were created
    earlier). Returns (released, kept).
    """
    if n > 0:
        low = new_t[0]
        high = new_t[0]
        for k in range(n):
            low = min(low, new_t[k])
            high = max(high, new_t[k])
        span = high - low + 1
        if span <= counts.shape[0]:
            counts[:span] = 0
            for k in range(n):
                counts[new_t[k] - low] += 1
            total = 0
            for b in range(span):
                c = counts[b]
                counts[b] = total
                total += c
            for k in range(n):  # reads in order, writes scattered: stores do not stall like loads
                bucket = new_t[k] - low
                place = counts[bucket]
                counts[bucket] = place + 1
                sorted_w[place] = new_w[k]
            place = 0  # counts[b] is now where bucket b ends: the times follow in order, no scatter needed
            for b in range(span):
                while place < counts[b]:
                    sorted_t[place] = low + b
                    place += 1
        else:
            order[:n] = np.argsort(new_t[:n], kind="mergesort")
            for j in range(n):
                k = order[j]
                sorted_t[j] = new_t[k]
                sorted_w[j] = new_w[k]
    held_end = np.searchsorted(held_t[:h], bound, side="right")
    new_end = np.searchsorted(sorted_t[:n], bound, side="right")
    released = _merge(held_t, held_w, 0, held_end, sorted_t, sorted_w, 0, new_end, out_t, out_w, 0)
    kept = _merge(held_t, held_w, held_end, h, sorted_t, sorted_w, new_end, n, keep_t, keep_w, 0)
    return released, kept
