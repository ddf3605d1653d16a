"""Threshold-correction kernel: re-samples every pixel's events at one target threshold, event by event.

Each pixel's events are read as samples of its log intensity: event j moves the reconstruction by the pixel's own
``+on`` or ``-off`` threshold. The pixel keeps ``level``, the reconstruction minus the corrected (re-sampled)
reference. Between the pixel's previous original event (or a later interpolation start, see below) and event j
the reconstruction is a straight line (first-order hold); every time ``level`` reaches ``+target_on`` (or
``-target_off``) an ON (OFF) event is emitted at the exact crossing time on that line and the reference moves by
the target threshold; what is left over is carried to the next event (the report's eq. 15).

Where the line starts (``mode``):

- ``MODE_FOH`` (0): at the pixel's previous event, but never before ``t_j - max_gap_us`` (the bound that keeps the
  reordering window finite);
- ``MODE_STEP`` (1): as FOH when the gap is at most ``hold_us``; over a longer gap the signal is held constant
  until ``t_j``, so every crossing of event j is emitted at ``t_j`` (the report's step-aware variant);
- ``MODE_HIGHPASS`` (2): as STEP, and before each event the carried ``level`` decays by ``exp(-gap / tau_us)``:
  the corrected reference relaxes to the pixel's own reference (a true sample of the signal), so the level error
  that inexact thresholds add with every event is forgotten instead of accumulated.

A pixel's first event has no previous one: its crossings are emitted at its own time. Pixels whose ``use`` flag is
False pass through unchanged. Events are emitted in creation order; :class:`evtools.correct.ThresholdCorrector`
sorts them. ``tests/naive/correct.py`` holds the pure-Python reference.

References
----------
The founding report, section 4.2 (FOH re-sampling) and 5.2 (step-aware variant).
C. Scheerlinck, N. Barnes, R. Mahony, "Continuous-time Intensity Estimation Using Event Cameras", ACCV 2018
(the high-pass filter whose exponential decay ``MODE_HIGHPASS`` applies to the carried level).
"""

from __future__ import annotations

import math

from numba import njit

MODE_FOH = 0
MODE_STEP = 1
MODE_HIGHPASS = 2

NO_EVENT_US = (1 << 63) - 1
"""``last_us`` of a pixel that has not fired yet (the largest int64, so a minimum over pixels ignores it)."""


@njit(cache=True, nogil=True)
def correct_events(t, x, y, p, start, width, on, off, use, target_on, target_off, last_us, level, mode, hold_us,
                   max_gap_us, tau_us, out_t, out_x, out_y, out_p):  # pragma: no cover - compiled
    """Process events ``start..`` until the output arrays might overflow; returns (next input index, outputs).

    ``on``, ``off``, ``use``, ``last_us`` and ``level`` are per pixel (index ``y * width + x``); ``last_us`` and
    ``level`` are updated in place. An event is processed only when its worst case fits in the output arrays.
    """
    capacity = out_t.shape[0]
    n = 0
    i = start
    while i < t.shape[0]:
        t_j = t[i]
        pixel = y[i] * width + x[i]
        if not use[pixel]:
            if n >= capacity:
                return i, n
            out_t[n] = t_j
            out_x[n] = x[i]
            out_y[n] = y[i]
            out_p[n] = p[i]
            n += 1
            i += 1
            continue
        a0 = level[pixel]
        previous = last_us[pixel]
        t_start = t_j
        if previous != NO_EVENT_US:
            gap = t_j - previous
            if mode == MODE_HIGHPASS and gap > hold_us:
                a0 = a0 * math.exp(-(gap - hold_us) / tau_us)
            if mode == MODE_FOH or gap <= hold_us:
                t_start = previous if gap <= max_gap_us else t_j - max_gap_us
        span = t_j - t_start
        if p[i]:
            d = on[pixel]
            k_max = math.floor((a0 + d) / target_on) + 1.0
        else:
            d = -off[pixel]
            k_max = math.floor((d - a0) / -target_off) + 1.0
        if n + k_max > capacity:
            return i, n
        if d > 0.0:
            k = 1.0
            while a0 + d >= k * target_on:
                s = (k * target_on - a0) / d
                out_t[n] = t_start + math.floor(s * span + 0.5)
                out_x[n] = x[i]
                out_y[n] = y[i]
                out_p[n] = True
                n += 1
                k += 1.0
            level[pixel] = a0 + d - (k - 1.0) * target_on
        else:
            k = 1.0
            while a0 + d <= -k * target_off:
                s = (-k * target_off - a0) / d
                out_t[n] = t_start + math.floor(s * span + 0.5)
                out_x[n] = x[i]
                out_y[n] = y[i]
                out_p[n] = False
                n += 1
                k += 1.0
            level[pixel] = a0 + d + (k - 1.0) * target_off
        last_us[pixel] = t_j
        i += 1
    return i, n
