"""Threshold-estimation kernels: per-pixel sums accumulated event by event, in O(pixels) memory.

Three accumulators, one per method of :mod:`evtools.estimate` (``tests/naive/estimate.py`` holds the pure-Python
references):

- :func:`offe_accumulate` (Wang et al. 2019, offE): each pixel's cumulative event count E and polarity sum P since
  the start, sampled at every segment boundary; instead of storing the samples, the sums the least-squares fit
  ``P = m E + d`` needs (K, sum E, sum P, sum E^2, sum EP, sum P^2) are accumulated in exact integers.
- :func:`stimulus_accumulate`: the known stimulus ``L(t)`` evaluated at each event; a pixel's consecutive events
  differ by exactly one threshold in L, summed per polarity.
- :func:`ramps_accumulate`: per pixel, the events of each complete run of one polarity (a ramp between two
  polarity reversals), counted per polarity with the number of complete runs.

Every kernel visits the events in stream order and updates only the state of the event's pixel (offE also every
pixel at a segment boundary), so chunking cannot change the sums.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

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


@njit(cache=True, nogil=True)
def _offe_sample(cum_e, cum_p, sums, times):  # pragma: no cover - compiled
    """Add ``times`` identical samples of every pixel's cumulative (E, P) to the fit sums."""
    for i in range(cum_e.shape[0]):
        e = cum_e[i]
        p = cum_p[i]
        sums[SUM_E, i] += times * e
        sums[SUM_P, i] += times * p
        sums[SUM_EE, i] += times * e * e
        sums[SUM_EP, i] += times * e * p
        sums[SUM_PP, i] += times * p * p


@njit(cache=True, nogil=True)
def offe_accumulate(t, x, y, p, width, segment_us, cum_e, cum_p, sums, state):  # pragma: no cover - compiled
    """Feed events to the offE sums.

    Segments are ``[origin + k * segment_us, origin + (k + 1) * segment_us)`` from the first event's time. When
    an event reaches a boundary, every pixel's cumulative count and polarity sum up to that boundary are sampled
    once per boundary passed (a gap of several segments samples the same values several times, as the
    reference's per-frame snapshots do), then the event is counted.
    """
    for k in range(t.shape[0]):
        tk = t[k]
        if state[OFFE_STARTED] == 0:
            state[OFFE_STARTED] = 1
            state[OFFE_ORIGIN] = tk
            state[OFFE_NEXT] = tk + segment_us
        if tk >= state[OFFE_NEXT]:
            passed = (tk - state[OFFE_NEXT]) // segment_us + 1
            _offe_sample(cum_e, cum_p, sums, passed)
            state[OFFE_SAMPLES] += passed
            state[OFFE_NEXT] += passed * segment_us
        i = np.int64(y[k]) * width + x[k]
        cum_e[i] += 1
        cum_p[i] += 1 if p[k] else -1
        state[OFFE_PENDING] = 1


@njit(cache=True, nogil=True)
def offe_finish(cum_e, cum_p, sums, state):  # pragma: no cover - compiled
    """Take the last (partial) segment's sample if events arrived after the last boundary."""
    if state[OFFE_PENDING] != 0:
        _offe_sample(cum_e, cum_p, sums, 1)
        state[OFFE_SAMPLES] += 1
        state[OFFE_PENDING] = 0


@njit(cache=True, nogil=True, inline="always")
def stimulus_level(t_us, x, low, high, period_us, wavelength_px, profile):  # pragma: no cover - compiled
    """L(t) of column ``x`` under a triangle stimulus from ``low`` to ``high`` (intensities 0-255).

    The triangle is 0 at phase 0 and 1 at phase 1/2; the phase is ``t / period - (x + 0.5) / wavelength``
    (``wavelength_px`` 0: every pixel alike, the flicker scene). ``profile`` intensity: linear in intensity,
    ``L = lin_log(I)``; log: linear in ``L`` between ``lin_log(low)`` and ``lin_log(high)``.
    """
    phase = t_us / period_us
    if wavelength_px > 0.0:
        phase -= (x + 0.5) / wavelength_px
    phase -= math.floor(phase)
    tri = 1.0 - abs(2.0 * phase - 1.0)
    if profile == PROFILE_LOG:
        a = low * LIN_LOG_SLOPE if low <= LIN_LOG_KNEE else math.log(low)
        b = high * LIN_LOG_SLOPE if high <= LIN_LOG_KNEE else math.log(high)
        return a + (b - a) * tri
    intensity = low + (high - low) * tri
    if intensity <= LIN_LOG_KNEE:
        return intensity * LIN_LOG_SLOPE
    return math.log(intensity)


SEED_PAIRS = 5
"""stimulus: a pixel's first 5 changes of each polarity; their median is the reference the later ones are held to."""
ACCEPT_LOW = 0.8
ACCEPT_HIGH = 1.25
"""stimulus: a change outside [0.8, 1.25] x the pixel's reference is not one threshold (a lost event makes it 2x,
a noise event ends it early) and is left out."""


@njit(cache=True, nogil=True, inline="always")
def _accept(change, reference, slot, i, level_sums, pair_counts):  # pragma: no cover - compiled
    if ACCEPT_LOW * reference <= change <= ACCEPT_HIGH * reference:
        level_sums[slot, i] += change
        pair_counts[slot, i] += 1


@njit(cache=True, nogil=True)
def _median_small(values):  # pragma: no cover - compiled
    ordered = np.sort(values)
    n = ordered.shape[0]
    return ordered[n // 2] if n % 2 else 0.5 * (ordered[n // 2 - 1] + ordered[n // 2])


@njit(cache=True, nogil=True)
def stimulus_accumulate(
    t, x, y, p, width, low, high, period_us, wavelength_px, profile, last_level, seen, seeds, seed_counts,
    references, level_sums, pair_counts,
):  # pragma: no cover - compiled
    """Feed events to the known-stimulus sums.

    An ideal pixel's reference equals L at its last event, so the next event lies one threshold away:
    ``L(t_k) - L(t_{k-1}) = theta_on`` for an ON event, ``-theta_off`` for an OFF one, across a turn-around of
    the stimulus too. A pixel's first event (reference unknown) and changes of the wrong sign for the polarity
    (impossible for a signal event: noise) are skipped. Per polarity (slot 0 ON, 1 OFF) the first
    :data:`SEED_PAIRS` changes are kept in ``seeds``; their median becomes ``references[slot, i]``, and from
    then on (those first ones included) only changes within [0.8, 1.25] x the reference are summed into
    ``level_sums`` and counted in ``pair_counts``: robust to events lost by a denoiser and to noise events.
    """
    for k in range(t.shape[0]):
        i = np.int64(y[k]) * width + x[k]
        level = stimulus_level(t[k], x[k], low, high, period_us, wavelength_px, profile)
        if seen[i]:
            change = level - last_level[i]
            slot = -1
            if p[k]:
                if change > 0.0:
                    slot = 0
            elif change < 0.0:
                slot = 1
                change = -change
            if slot >= 0:
                n = seed_counts[slot, i]
                if n < SEED_PAIRS:
                    seeds[slot, i, n] = change
                    seed_counts[slot, i] = n + 1
                    if n + 1 == SEED_PAIRS:
                        reference = _median_small(seeds[slot, i])
                        references[slot, i] = reference
                        for j in range(SEED_PAIRS):
                            _accept(seeds[slot, i, j], reference, slot, i, level_sums, pair_counts)
                else:
                    _accept(change, references[slot, i], slot, i, level_sums, pair_counts)
        seen[i] = True
        last_level[i] = level


@njit(cache=True, nogil=True)
def ramps_accumulate(p, x, y, width, run_polarity, run_length, run_events, run_counts):  # pragma: no cover
    """Feed events to the complete-ramp counts.

    ``run_polarity[i]``: -1 before the pixel's first event, then 0 (OFF) or 1 (ON) for its current run;
    ``run_length[i]``: events in that run; a run is complete when a reversal ends it and one began it, so
    a pixel's first run is dropped (``run_length`` is set to -1 for it) and its last one never counts.
    ``run_events[0/1, i]`` sums ON/OFF events of complete runs, ``run_counts[0/1, i]`` counts those runs.
    """
    for k in range(p.shape[0]):
        i = np.int64(y[k]) * width + x[k]
        polarity = 1 if p[k] else 0
        if run_polarity[i] == polarity:
            if run_length[i] >= 0:
                run_length[i] += 1
            continue
        if run_polarity[i] >= 0 and run_length[i] >= 0:
            slot = 1 - run_polarity[i]  # 0: an ON run ended, 1: an OFF run
            run_events[slot, i] += run_length[i]
            run_counts[slot, i] += 1
        # the pixel's first run has an unknown start: mark it with -1 so that it never counts
        run_length[i] = -1 if run_polarity[i] < 0 else 1
        run_polarity[i] = polarity


@njit(cache=True, nogil=True)
def count_events(x, y, p, width, counts):  # pragma: no cover - compiled
    """``counts[0, i]`` += ON events of pixel i, ``counts[1, i]`` += OFF events."""
    for k in range(x.shape[0]):
        counts[0 if p[k] else 1, np.int64(y[k]) * width + x[k]] += 1
