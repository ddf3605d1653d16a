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
from numba import njit

MODE_FOH = 0
MODE_STEP = 1
MODE_HIGHPASS = 2

NO_EVENT_US = (1 << 63) - 1
"""``last_us`` of a pixel that has not fired yet (the largest int64, so a minimum over pixels ignores it)."""


@njit(cache=True, nogil=True, inline="always")
def _segment(level, delta, off0, off1, t_b, x, y, target_on, target_off, out_t, out_x, out_y, out_p, n):
    """Re-sample the line from ``(t_b + off0, level)`` to ``(t_b + off1, level + delta)``; returns (level, n)."""
    span = off1 - off0
    if delta > 0.0:
        k = 1.0
        while level + delta >= k * target_on:
            out_t[n] = t_b + np.int64(math.floor(off0 + (k * target_on - level) / delta * span + 0.5))
            out_x[n] = x
            out_y[n] = y
            out_p[n] = True
            n += 1
            k += 1.0
        return level + delta - (k - 1.0) * target_on, n
    if delta < 0.0:
        k = 1.0
        while level + delta <= -k * target_off:
            out_t[n] = t_b + np.int64(math.floor(off0 + (-k * target_off - level) / delta * span + 0.5))
            out_x[n] = x
            out_y[n] = y
            out_p[n] = False
            n += 1
            k += 1.0
        return level + delta + (k - 1.0) * target_off, n
    return level, n


AHEAD = 16
"""How many events ahead the kernel touches a pixel's state (a software prefetch: events hit random pixels)."""

PIXEL_DTYPE = np.dtype([("level", np.float64), ("last_us", np.int64), ("previous_us", np.int64),
                        ("on", np.float32), ("off", np.float32)])
"""Per-pixel state, 32 bytes (one cache line holds two pixels, so an event touches one): the carried level, the
previous event's time (NO_EVENT_US before the first), the one before it when of the same polarity and not across
a rest (else NO_EVENT_US), and the pixel's thresholds (float32, the maps' precision)."""


@njit(cache=True, nogil=True)
def correct_events(t, x, y, p, start, width, state, polarity, use, target_on, target_off, mode, turns, hold_us,
                   max_gap_us, tau_us, out_t, out_x, out_y, out_p, n):  # pragma: no cover - compiled
    """Process events ``start..`` while their worst case fits in the output arrays.

    Returns (next input, count, a sum of the touched levels that only keeps the look-ahead loads alive).

    ``state`` (:data:`PIXEL_DTYPE`) and ``polarity`` (int8: +1, -1, 0 before the first event) are per pixel (index
    ``y * width + x``) and updated in place; ``use`` says which pixels are re-sampled. Events are written from
    index ``n`` on, in creation order.
    """
    capacity = out_t.shape[0]
    min_target = min(target_on, target_off)
    end = t.shape[0]
    touched = 0.0
    i = start
    while i < end:
        if i + AHEAD < end:  # touch the state of a pixel a few events ahead: its cache miss overlaps this work
            touched += state[y[i + AHEAD] * width + x[i + AHEAD]].level
        t_b = t[i]
        xi = x[i]
        yi = y[i]
        pixel = yi * width + xi
        if not use[pixel]:
            if n >= capacity:
                return i, n, touched
            out_t[n] = t_b
            out_x[n] = xi
            out_y[n] = yi
            out_p[n] = p[i]
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
        sign = 1 if p[i] else -1
        d = theta_on if p[i] else -theta_off
        # worst case: |a| < max target, an extremum < one threshold, the event's own threshold
        if n + (abs(a) + theta_on + theta_off) / min_target + 3.0 > capacity:
            return i, n, touched
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
            a, n = _segment(a, run * excess, -gap_f, off_peak, t_b, xi, yi, target_on, target_off,
                            out_t, out_x, out_y, out_p, n)
            a, n = _segment(a, d - run * excess, off_peak, 0.0, t_b, xi, yi, target_on, target_off,
                            out_t, out_x, out_y, out_p, n)
        else:
            a, n = _segment(a, d, off_start, 0.0, t_b, xi, yi, target_on, target_off, out_t, out_x, out_y, out_p, n)
        row.level = a
        polarity[pixel] = sign
        # the run's previous event, for its slope (not across a rest: that is no ramp)
        row.previous_us = t_a if (last_polarity == sign and not rest) else NO_EVENT_US
        row.last_us = t_b
        i += 1
    return i, n, touched


@njit(cache=True, nogil=True)
def release_sorted(held_t, held_x, held_y, held_p, h, new_t, new_x, new_y, new_p, n, bound, order, counts,
                   sorted_t, sorted_x, sorted_y, sorted_p, out_t, out_x, out_y, out_p, keep_t, keep_x, keep_y,
                   keep_p):  # pragma: no cover - compiled
    """Merge the held events (sorted) with the new ones (creation order); split at ``bound``.

    The new events are sorted by time into ``sorted_*``, ties in creation order (a counting sort that scatters
    them straight to their places when ``counts`` covers their time span, else a stable merge sort and a
    gather), then merged with the held ones (held first on ties: they were created earlier), both read in order.
    Events at or before ``bound`` go to ``out_*`` in order, the rest to ``keep_*``. Returns (released, kept).
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
                place = counts[new_t[k] - low]
                counts[new_t[k] - low] = place + 1
                sorted_t[place] = new_t[k]
                sorted_x[place] = new_x[k]
                sorted_y[place] = new_y[k]
                sorted_p[place] = new_p[k]
        else:
            order[:n] = np.argsort(new_t[:n], kind="mergesort")
            for j in range(n):
                k = order[j]
                sorted_t[j] = new_t[k]
                sorted_x[j] = new_x[k]
                sorted_y[j] = new_y[k]
                sorted_p[j] = new_p[k]
    i = 0
    j = 0
    released = 0
    kept = 0
    while i < h or j < n:
        if j >= n or (i < h and held_t[i] <= sorted_t[j]):
            tt, xx, yy, pp = held_t[i], held_x[i], held_y[i], held_p[i]
            i += 1
        else:
            tt, xx, yy, pp = sorted_t[j], sorted_x[j], sorted_y[j], sorted_p[j]
            j += 1
        if tt <= bound:
            out_t[released] = tt
            out_x[released] = xx
            out_y[released] = yy
            out_p[released] = pp
            released += 1
        else:
            keep_t[kept] = tt
            keep_x[kept] = xx
            keep_y[kept] = yy
            keep_p[kept] = pp
            kept += 1
    return released, kept
