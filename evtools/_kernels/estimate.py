"""Threshold-estimation kernels: per-pixel sums accumulated event by event, in O(pixels) memory.

Two accumulators, one per method of :mod:`evtools.estimate` (``tests/naive/estimate.py`` holds the pure-Python
references):

- :func:`offe_accumulate` (Wang et al. 2019, offE): each pixel's cumulative event count E and polarity sum P since
  the start, sampled at every segment boundary; instead of storing the samples, the sums the least-squares fit
  ``P = m E + d`` needs (K, sum E, sum P, sum E^2, sum EP, sum P^2) are accumulated in exact integers.
- :func:`stimulus_accumulate`: the known stimulus ``L(t)`` at each event (from a one-period table for a flicker:
  no logarithm per event); a pixel's consecutive events differ by exactly one threshold in L, summed per polarity.

Every kernel visits the events in stream order and updates only the state of the event's pixel (offE also every
pixel at a segment boundary); L is a function of (t, x) alone, so chunking cannot change the sums. Each event
touches one row of per-pixel state (16 or 64 bytes), not one entry in each of several arrays: with random pixel
order the cache misses, not the arithmetic, set the speed.
"""

from __future__ import annotations

import math

import numpy as np

from evtools._kernels.jit import kernel
from evtools._kernels.pixel import LIN_LOG_KNEE, LIN_LOG_SLOPE

# offE scalar state (int64 array): the segment clock
OFFE_ORIGIN = 0  # time of the first event (segments start there)
OFFE_NEXT = 1  # time of the next segment boundary
OFFE_SAMPLES = 2  # K: number of (E, P) samples taken so far
OFFE_STARTED = 3  # 1 once the first event is seen
OFFE_PENDING = 4  # 1 when events arrived after the last sample
OFFE_STATE_SIZE = 5

# offE per-pixel sums (int64, shape (5, pixels))
SUM_E, SUM_P, SUM_EE, SUM_EP, SUM_PP = range(5)

PROFILE_INTENSITY = 0
PROFILE_LOG = 1


@kernel
def _offe_sample(cumulative, sums, times):  # pragma: no cover - compiled
    """Add ``times`` identical samples of every pixel's cumulative (E, P) to the fit sums."""
    for i in range(cumulative.shape[0]):
        e = cumulative[i, 0]
        p = cumulative[i, 1]
        sums[SUM_E, i] += times * e
        sums[SUM_P, i] += times * p
        sums[SUM_EE, i] += times * e * e
        sums[SUM_EP, i] += times * e * p
        sums[SUM_PP, i] += times * p * p


@kernel
def offe_accumulate(t, x, y, p, width, segment_us, cumulative, sums, state):  # pragma: no cover - compiled
    """Feed events to the offE sums.

    Segments are ``[origin + k * segment_us, origin + (k + 1) * segment_us)`` from the first event's time. When
    an event reaches a boundary, every pixel's cumulative count and polarity sum up to that boundary
    (``cumulative[i] = (E, P)``, side by side so that an event touches one cache line) are sampled once per
    boundary passed (a gap of several segments samples the same values several times, as the reference's
    per-frame snapshots do), then the event is counted.
    """
    for k in range(t.shape[0]):
        tk = t[k]
        if state[OFFE_STARTED] == 0:
            state[OFFE_STARTED] = 1
            state[OFFE_ORIGIN] = tk
            state[OFFE_NEXT] = tk + segment_us
        if tk >= state[OFFE_NEXT]:
            passed = (tk - state[OFFE_NEXT]) // segment_us + 1
            _offe_sample(cumulative, sums, passed)
            state[OFFE_SAMPLES] += passed
            state[OFFE_NEXT] += passed * segment_us
        i = np.int64(y[k]) * width + x[k]
        cumulative[i, 0] += 1
        cumulative[i, 1] += 1 if p[k] else -1
        state[OFFE_PENDING] = 1


@kernel
def offe_finish(cumulative, sums, state):  # pragma: no cover - compiled
    """Take the last (partial) segment's sample if events arrived after the last boundary."""
    if state[OFFE_PENDING] != 0:
        _offe_sample(cumulative, sums, 1)
        state[OFFE_SAMPLES] += 1
        state[OFFE_PENDING] = 0


@kernel(inline=True)
def _triangle_level(phase, a, b, profile):  # pragma: no cover - compiled
    """L at ``phase`` (any real; period 1) of a triangle 0 at phase 0, 1 at phase 1/2, from ``a`` to ``b``."""
    phase -= math.floor(phase)
    tri = 1.0 - abs(2.0 * phase - 1.0)
    if profile == PROFILE_LOG:
        return a + (b - a) * tri
    intensity = a + (b - a) * tri
    if intensity <= LIN_LOG_KNEE:
        return intensity * LIN_LOG_SLOPE
    return math.log(intensity)


@kernel
def stimulus_level(t_us, x, a, b, period_us, wavelength_px, profile):  # pragma: no cover - compiled
    """L(t) of column ``x`` under a triangle stimulus from ``a`` to ``b``.

    ``profile`` intensity: ``a``, ``b`` are intensities (0-255), the triangle is linear in intensity and
    ``L = lin_log(I)``; log: ``a``, ``b`` are log intensities and the triangle is linear in L. The phase is
    ``t / period - (x + 0.5) / wavelength`` (``wavelength_px`` 0: every pixel alike, the flicker scene); for a
    whole number of microseconds per period, ``t`` is first reduced modulo the period in integers (exact, and
    the same value :func:`stimulus_table` stores).
    """
    period_int = np.int64(period_us)
    if period_int == period_us:
        phase = (t_us % period_int) / period_us
    else:
        phase = t_us / period_us
    if wavelength_px > 0.0:
        phase -= (x + 0.5) / wavelength_px
    return _triangle_level(phase, a, b, profile)


@kernel
def stimulus_table(a, b, period_us, profile, table):  # pragma: no cover - compiled
    """``table[j]`` = L at ``t = j`` microseconds, for a flicker whose period is ``table.shape[0]`` microseconds:
    bit for bit what :func:`stimulus_level` gives for any ``t = j + k * period``."""
    for j in range(table.shape[0]):
        table[j] = _triangle_level(j / period_us, a, b, profile)


SEED_PAIRS = 5
"""stimulus: a pixel's first 5 changes of each polarity; their median is the reference the later ones are held to
(an odd number: the median is one of them)."""
ACCEPT_LOW = 0.8
ACCEPT_HIGH = 1.25
"""stimulus: a change outside [0.8, 1.25] x the pixel's reference is not one threshold (a lost event makes it 2x,
a noise event ends it early) and is left out."""

# stimulus per-pixel state: one row of 16 float64 (two cache lines, the first holding what every event reads)
ST_LAST = 0  # L at the pixel's last event
ST_EVENTS = 1  # the pixel's events so far (exact in float64 up to 2^53)
ST_REF = 2  # 2 (ON), 3 (OFF): the reference change once seeded (> 0); before that -(seeds taken so far)
ST_SUM = 4  # 4, 5: sum of accepted ON, OFF changes
ST_PAIRS = 6  # 6, 7: accepted ON, OFF changes
ST_SQUARES = 8  # 8, 9: sum of the squares of accepted ON, OFF changes (their scatter: the fit)
ST_ALL = 10  # 10, 11: every change that ended in an ON, OFF event (accepted, outside the window, or the wrong sign)
ST_SIZE = 16


@kernel
def _median_odd(seeds, i, slot):  # pragma: no cover - compiled
    """Median of ``seeds[i, slot]`` (an odd number of values) without allocating or making a view: the value
    with at most n // 2 others below it and at least n // 2 + 1 at or below it."""
    n = seeds.shape[2]
    for j in range(n):
        value = seeds[i, slot, j]
        below = 0
        at_or_below = 0
        for m in range(n):
            below += seeds[i, slot, m] < value
            at_or_below += seeds[i, slot, m] <= value
        if below <= n // 2 < at_or_below:
            return value
    return seeds[i, slot, n // 2]  # not reached for real numbers


@kernel(inline=True)
def _accept(change, reference, slot, i, state):  # pragma: no cover - compiled
    # branch-free: adding 0.0 leaves the sums bit for bit unchanged, and a random accept costs no misprediction
    inside = 1.0 if (ACCEPT_LOW * reference <= change) & (change <= ACCEPT_HIGH * reference) else 0.0
    state[i, ST_SUM + slot] += inside * change
    state[i, ST_SQUARES + slot] += inside * change * change
    state[i, ST_PAIRS + slot] += inside


@kernel
def _seed(change, slot, i, state, seeds):  # pragma: no cover - compiled
    """Keep one of a polarity's first changes; at the last one, set the reference and accept those kept."""
    n = np.int64(-state[i, ST_REF + slot])
    seeds[i, slot, n] = change
    if n + 1 < SEED_PAIRS:
        state[i, ST_REF + slot] = -(n + 1.0)
        return
    reference = _median_odd(seeds, i, slot)
    state[i, ST_REF + slot] = reference
    for j in range(SEED_PAIRS):
        _accept(seeds[i, slot, j], reference, slot, i, state)


@kernel
def stimulus_accumulate(
    t, x, y, p, width, a, b, period_us, wavelength_px, profile, table, state, seeds,
):  # pragma: no cover - compiled
    """Feed events to the known-stimulus sums.

    An ideal pixel's reference equals L at its last event, so the next event lies one threshold away:
    ``L(t_k) - L(t_{k-1}) = theta_on`` for an ON event, ``-theta_off`` for an OFF one, across a turn-around of
    the stimulus too. A pixel's first event (reference unknown) and changes of the wrong sign for the polarity
    (impossible for a signal event: noise) are skipped. Per polarity (slot 0 ON, 1 OFF) the first
    :data:`SEED_PAIRS` changes are kept in ``seeds[i, slot]``; their median becomes the pixel's reference, and
    from then on (those first ones included) only changes within [0.8, 1.25] x the reference are summed (with
    their squares) and counted: robust to events lost by a denoiser and to noise events. Every change is counted
    per polarity in ``ST_ALL``, so the share that did not fit (outside the window, or the wrong sign) is known.

    L comes from ``table`` (one flicker period at 1 us, :func:`stimulus_table`) when it is not empty, else from
    :func:`stimulus_level`; ``state`` is (pixels, :data:`ST_SIZE`), see the ``ST_*`` columns.
    """
    period = table.shape[0]
    base = (t[0] // period) * period if period > 0 and t.shape[0] > 0 else 0
    for k in range(t.shape[0]):
        if period > 0:  # t - base = t mod period, without a division per event (t is sorted)
            while t[k] - base >= period:
                base += period
            while t[k] < base:
                base -= period
            level = table[t[k] - base]
        else:
            level = stimulus_level(t[k], x[k], a, b, period_us, wavelength_px, profile)
        i = np.int64(y[k]) * width + x[k]
        if state[i, ST_EVENTS] > 0.0:
            change = level - state[i, ST_LAST]
            state[i, ST_ALL + (0 if p[k] else 1)] += 1.0
            slot = -1
            if p[k]:
                if change > 0.0:
                    slot = 0
            elif change < 0.0:
                slot = 1
                change = -change
            if slot >= 0:
                reference = state[i, ST_REF + slot]
                if reference > 0.0:
                    _accept(change, reference, slot, i, state)
                else:
                    _seed(change, slot, i, state, seeds)
        state[i, ST_EVENTS] += 1.0
        state[i, ST_LAST] = level
