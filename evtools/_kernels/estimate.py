"""Threshold-estimation kernels: per-pixel sums accumulated event by event, in O(pixels) memory.

The accumulators, one per method of :mod:`evtools.estimation` (``tests/naive/estimate.py`` holds the pure-Python
references):

- :func:`offe_accumulate` (Wang et al. 2019, offE): each pixel's cumulative event count E and polarity sum P since
  the start, sampled at every segment boundary; instead of storing the samples, the sums the least-squares fit
  ``P = m E + d`` needs (K, sum E, sum P, sum E^2, sum EP, sum P^2) are accumulated in exact integers, lazily
  (at the pixel's next event).
- :func:`stimulus_accumulate`: the known stimulus ``L(t)`` at each event (from a one-period table for a flicker:
  no logarithm per event); a pixel's consecutive events differ by exactly one threshold in L, summed per polarity.
- :func:`stimulus_fitted_accumulate`: the same with each pixel's phase fitted to its own first events
  (:func:`_fit_phase`), then only the changes within a ramp summed.
- :func:`count_accumulate` (natural scenes): each pixel's ON and OFF event counts, in two interleaved halves.

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
from evtools._kernels.prefetch import prefetch

AHEAD = 16
"""offE prefetches the state rows of the pixel of the event this many events ahead: on a large sensor (Gen4's
921,600 pixels: 88 MB of rows) nearly every event's rows are cache misses (measured in docs/performance.md)."""

# offE scalar state (int64 array): the segment clock
OFFE_ORIGIN = 0  # time of the first event (segments start there)
OFFE_NEXT = 1  # time of the next segment boundary
OFFE_SAMPLES = 2  # K: number of (E, P) samples taken so far
OFFE_STARTED = 3  # 1 once the first event is seen
OFFE_PENDING = 4  # 1 when events arrived after the last sample
OFFE_STATE_SIZE = 5

# offE per-pixel row (int64, shape (pixels, 8), one 64-byte cache line): the cumulative count E and polarity sum
# P, the number of samples the row's sums include, then the five fit sums
OFFE_E, OFFE_P, OFFE_SEEN = 0, 1, 2
OFFE_SUMS_AT = 3
OFFE_ROW = 8
SUM_E, SUM_P, SUM_EE, SUM_EP, SUM_PP = range(5)  # the sums, from OFFE_SUMS_AT on (and rows of offe_fit's input)

PROFILE_INTENSITY = 0
PROFILE_LOG = 1


@kernel(inline=True)
def _count(t_us, i, on, block_us, counts):  # pragma: no cover - compiled
    """One event of pixel i into its counts (see :func:`count_accumulate`)."""
    half = 3 * ((t_us // block_us) % 2)
    polarity = 1 if on else 2
    counts[i, half + polarity - 1] += 1
    last = counts[i, COUNT_LAST]
    counts[i, half + 2] += 1 if last != 0 and last != polarity else 0
    counts[i, COUNT_LAST] = polarity


@kernel(inline=True)
def _offe_catch_up(pixels, i, samples):  # pragma: no cover - compiled
    """Add to pixel i's sums the samples taken since its last event: its (E, P) did not change through them."""
    times = samples - pixels[i, OFFE_SEEN]
    if times != 0:
        e = pixels[i, OFFE_E]
        p = pixels[i, OFFE_P]
        pixels[i, OFFE_SUMS_AT + SUM_E] += times * e
        pixels[i, OFFE_SUMS_AT + SUM_P] += times * p
        pixels[i, OFFE_SUMS_AT + SUM_EE] += times * e * e
        pixels[i, OFFE_SUMS_AT + SUM_EP] += times * e * p
        pixels[i, OFFE_SUMS_AT + SUM_PP] += times * p * p
        pixels[i, OFFE_SEEN] = samples


@kernel
def offe_accumulate(t, x, y, p, width, segment_us, pixels, state, block_us, counts):  # pragma: no cover - compiled
    """Feed events to the offE sums.

    Segments are ``[origin + k * segment_us, origin + (k + 1) * segment_us)`` from the first event's time. At every
    boundary the reference samples every pixel's cumulative count and polarity sum (E, P) (a gap of several
    segments samples the same values several times, as its per-frame snapshots do). A pixel's (E, P) changes only
    at its own events, so the samples are added lazily, exactly: at an event, the samples taken since the pixel's
    previous one are added (times its unchanged E, P, ...), then the event is counted; :func:`offe_finish` adds the
    rest. O(events + pixels) instead of O(boundaries x pixels): 26,000 boundaries of a 76,800-pixel sensor were 2
    billion updates per 50M events. Each event also goes to the natural method's ``counts`` (:func:`_count`, blocks of
    ``block_us``: offE's fit compares with that estimate), in the same pass.
    """
    flat_pixels, flat_counts = pixels.reshape(pixels.size), counts.reshape(counts.size)
    n = t.shape[0]
    for k in range(n):
        if k + AHEAD < n:
            ahead = np.int64(y[k + AHEAD]) * width + x[k + AHEAD]
            prefetch(flat_pixels, ahead * OFFE_ROW)
            prefetch(flat_counts, ahead * COUNT_SIZE)
        tk = t[k]
        if state[OFFE_STARTED] == 0:
            state[OFFE_STARTED] = 1
            state[OFFE_ORIGIN] = tk
            state[OFFE_NEXT] = tk + segment_us
        if tk >= state[OFFE_NEXT]:
            passed = (tk - state[OFFE_NEXT]) // segment_us + 1
            state[OFFE_SAMPLES] += passed
            state[OFFE_NEXT] += passed * segment_us
        i = np.int64(y[k]) * width + x[k]
        _offe_catch_up(pixels, i, state[OFFE_SAMPLES])
        pixels[i, OFFE_E] += 1
        pixels[i, OFFE_P] += 1 if p[k] else -1
        state[OFFE_PENDING] = 1
        _count(tk, i, p[k], block_us, counts)


@kernel
def offe_finish(pixels, state):  # pragma: no cover - compiled
    """Take the last (partial) segment's sample if events arrived after the last boundary, and bring every pixel's
    sums up to the last sample."""
    if state[OFFE_PENDING] != 0:
        state[OFFE_SAMPLES] += 1
        state[OFFE_PENDING] = 0
    for i in range(pixels.shape[0]):
        _offe_catch_up(pixels, i, state[OFFE_SAMPLES])


@kernel(inline=True)
def _triangle_level(phase, a, b, rise, profile):  # pragma: no cover - compiled
    """L at ``phase`` (any real; period 1) of a triangle at its low end ``a`` at phase 0, rising linearly to its
    high end ``b`` at phase ``rise`` (0 < rise < 1) and falling back by phase 1."""
    phase -= math.floor(phase)
    tri = phase / rise if phase < rise else (1.0 - phase) / (1.0 - rise)
    if profile == PROFILE_LOG:
        return a + (b - a) * tri
    intensity = a + (b - a) * tri
    if intensity <= LIN_LOG_KNEE:
        return intensity * LIN_LOG_SLOPE
    return math.log(intensity)


@kernel
def stimulus_level(t_us, x, a, b, period_us, rise, wavelength_px, profile):  # pragma: no cover - compiled
    """L(t) of column ``x`` under a triangle stimulus from ``a`` to ``b`` (rising for the fraction ``rise`` of
    each period).

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
    return _triangle_level(phase, a, b, rise, profile)


@kernel
def stimulus_table(a, b, period_us, rise, profile, table):  # pragma: no cover - compiled
    """``table[j]`` = L at ``t = j`` microseconds, for a flicker whose period is ``table.shape[0]`` microseconds:
    bit for bit what :func:`stimulus_level` gives for any ``t = j + k * period``."""
    for j in range(table.shape[0]):
        table[j] = _triangle_level(j / period_us, a, b, rise, profile)


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


@kernel(inline=True)
def _observe(level, on, i, state, seeds):  # pragma: no cover - compiled
    """One event of pixel ``i`` at stimulus level ``level``: its change from the pixel's last event, if any, goes
    to the polarity's sums (see :func:`stimulus_accumulate`)."""
    if state[i, ST_EVENTS] > 0.0:
        change = level - state[i, ST_LAST]
        state[i, ST_ALL + (0 if on else 1)] += 1.0
        slot = -1
        if on:
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


@kernel
def stimulus_accumulate(
    t, x, y, p, width, a, b, period_us, rise, wavelength_px, profile, table, state, seeds,
):  # pragma: no cover - compiled
    """Feed events to the known-stimulus sums, every pixel's phase given (the stimulus at its low end at t = 0,
    delayed by the column for a moving gradient).

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
            level = stimulus_level(t[k], x[k], a, b, period_us, rise, wavelength_px, profile)
        # _observe's body, written out: calling the inlined helper here measured half the speed (100 M random
        # events at 346 x 260: 20-25 Mev/s against 53-63 written out, numba 0.68)
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


# -- the phase found from each pixel's own events ------------------------------------------------------------------

RING = 32
"""Phase fitting: a pixel's events are kept (the latest 32) until they show a turn of each kind (a peak: ON then
OFF; a valley: OFF then ON) and fill the ring; then its phase is fitted to them, they are replayed into the sums,
and every later event goes straight to the sums. 32 events hold a period of up to ~30 events (a log amplitude
of 3 at thresholds of 0.2) with both turns; a pixel with fewer events is fitted at the end of the stream."""
PHASE_GRID = 256
"""Phase fitting, for a pixel whose events show no polarity reversal: the cost is evaluated at 256 phases across
the period, then refined within a grid step."""
BRACKET_GRID = 16
"""Phase fitting: the best bracket is searched on a grid of 16 steps before the golden section (the cost is not
unimodal within a bracket; 8 steps missed the best phase at rise fractions near 0.1)."""
SCREEN_SLACK = 2
"""Phase fitting: only brackets whose centre puts at most 2 more events on the wrong ramp than the best bracket's
have their cost evaluated (a bracket's centre is off the true turn by up to half its width, which can misplace an
event next to the other turn; noise events are misplaced at every phase alike). On random events (16 brackets per
ring) this cut the search from 19 to 12 us per pixel."""
GOLDEN_STEPS = 20
"""Golden-section steps (each narrows the interval by 0.618: 20 steps take two grid steps of a bracket of a tenth
of a period to 8e-7 periods, 0.4 us of a 0.5 s period)."""
ST_PHASE = 12  # phase fitting: the pixel's valley time modulo the period (us), once fitted
ST_FITTED = 13  # phase fitting: 1 once the pixel's phase is fitted
ST_SEEN = 14  # phase fitting: every event of the pixel (those dropped from the ring too)
ST_LAST_ON = 15  # 1 when the pixel's last event was ON


WAVE_CELLS = 8192
"""Phase fitting: each ramp of the stimulus is tabulated in 8192 cells, L interpolated linearly between them
(exact for a triangle in log intensity; for one in intensity, L = log I bends by at most 1e-6 of a threshold
within a cell)."""


WAVE_SCALE = WAVE_CELLS + 1
"""Phase fitting: the table's last column holds each ramp's cells per period (a product per event, no division)."""


@kernel
def wave_table(a, b, rise, profile, wave):  # pragma: no cover - compiled
    """``wave[0, k]``: L at phase ``rise * k / WAVE_CELLS`` (the rise), ``wave[1, k]`` at ``rise + (1 - rise) * k /
    WAVE_CELLS`` (the fall), k = 0..WAVE_CELLS: the turns fall on the table's ends. ``wave`` is (2, WAVE_CELLS + 2):
    column :data:`WAVE_SCALE` holds ``WAVE_CELLS / rise`` and ``WAVE_CELLS / (1 - rise)``."""
    for k in range(WAVE_CELLS + 1):
        wave[0, k] = _triangle_level(rise * k / WAVE_CELLS, a, b, rise, profile)
        wave[1, k] = _triangle_level(rise + (1.0 - rise) * k / WAVE_CELLS, a, b, rise, profile)
    wave[1, WAVE_CELLS] = wave[0, 0]
    wave[0, WAVE_SCALE] = WAVE_CELLS / rise
    wave[1, WAVE_SCALE] = WAVE_CELLS / (1.0 - rise)


@kernel(inline=True)
def _wave_level(phase, rise, wave):  # pragma: no cover - compiled
    """L at ``phase`` (any real; period 1), interpolated in :func:`wave_table`'s table."""
    phase -= math.floor(phase)
    if phase < rise:
        ramp = 0
    else:
        ramp = 1
        phase -= rise
    cell = phase * wave[ramp, WAVE_SCALE]
    k = min(np.int64(cell), WAVE_CELLS - 1)
    return wave[ramp, k] + (cell - k) * (wave[ramp, k + 1] - wave[ramp, k])


@kernel(inline=True)
def _observe_within_ramp(level, on, i, state, seeds):  # pragma: no cover - compiled
    """:func:`_observe`, the change counted only when the pixel's last event had the same polarity (a change
    within one ramp of the stimulus)."""
    same = (state[i, ST_LAST_ON] > 0.0) == on
    state[i, ST_LAST_ON] = 1.0 if on else 0.0
    if same:
        _observe(level, on, i, state, seeds)
    else:
        state[i, ST_EVENTS] += 1.0
        state[i, ST_LAST] = level


@kernel(inline=True)
def _ring_event(ring, i, filled, j):  # pragma: no cover - compiled
    """The j-th oldest event still in pixel i's ring: (t_us, on)."""
    n = filled[i]
    first = n - RING if n > RING else 0
    packed = ring[i, (first + j) % RING]
    return packed >> 1, (packed & 1) == 1


@kernel
def _phase_cost(valley_us, times, ons, n, period_us, rise, wave, changes):  # pragma: no cover - compiled
    """How badly events (``times`` relative to the first, ``ons``) fit the stimulus with its valley at
    ``valley_us``: over the level changes between consecutive events, the sum of their squared relative deviation
    from their polarity's threshold, a change outside the acceptance window [0.8, 1.25] (or of the wrong sign)
    counting 1, as in the fit. A polarity's threshold is the mean of its changes within a ramp (between two events
    of that polarity) that lie within the window around their plain mean, so a noise event costs a fixed amount
    and cannot pull the phase (``changes``: scratch). Changes across a turn count in the cost: they place the
    turns."""
    per_period = 1.0 / period_us
    last = _wave_level((times[0] - valley_us) * per_period, rise, wave)
    sum_on = count_on = sum_off = count_off = 0.0
    for j in range(1, n):
        level = _wave_level((times[j] - valley_us) * per_period, rise, wave)
        change = level - last if ons[j] else last - level
        last = level
        changes[j] = change
        if change > 0.0 and ons[j] == ons[j - 1]:
            if ons[j]:
                sum_on += change
                count_on += 1.0
            else:
                sum_off += change
                count_off += 1.0
    mean_on = sum_on / count_on if count_on > 0.0 else 1.0
    mean_off = sum_off / count_off if count_off > 0.0 else 1.0
    sum_on = count_on = sum_off = count_off = 0.0
    for j in range(1, n):
        mean = mean_on if ons[j] else mean_off
        if ons[j] == ons[j - 1] and ACCEPT_LOW * mean <= changes[j] <= ACCEPT_HIGH * mean:
            if ons[j]:
                sum_on += changes[j]
                count_on += 1.0
            else:
                sum_off += changes[j]
                count_off += 1.0
    mean_on = sum_on / count_on if count_on > 0.0 else mean_on
    mean_off = sum_off / count_off if count_off > 0.0 else mean_off
    cost = 0.0
    for j in range(1, n):
        deviation = changes[j] / (mean_on if ons[j] else mean_off) - 1.0
        inside = ACCEPT_LOW - 1.0 <= deviation <= ACCEPT_HIGH - 1.0
        cost += deviation * deviation if inside else 1.0
    return cost


@kernel
def _golden(low, high, times, ons, n, period_us, rise, wave, changes):  # pragma: no cover - compiled
    """(valley, cost): the golden-section search's best valley time in [low, high]."""
    ratio = 0.5 * (math.sqrt(5.0) - 1.0)
    inner_left = high - ratio * (high - low)
    inner_right = low + ratio * (high - low)
    cost_left = _phase_cost(inner_left, times, ons, n, period_us, rise, wave, changes)
    cost_right = _phase_cost(inner_right, times, ons, n, period_us, rise, wave, changes)
    for _ in range(GOLDEN_STEPS):
        if cost_left <= cost_right:
            high, inner_right, cost_right = inner_right, inner_left, cost_left
            inner_left = high - ratio * (high - low)
            cost_left = _phase_cost(inner_left, times, ons, n, period_us, rise, wave, changes)
        else:
            low, inner_left, cost_left = inner_left, inner_right, cost_right
            inner_right = low + ratio * (high - low)
            cost_right = _phase_cost(inner_right, times, ons, n, period_us, rise, wave, changes)
    if cost_left <= cost_right:
        return inner_left, cost_left
    return inner_right, cost_right


@kernel
def _misplaced(valley_us, times, ons, n, period_us, rise):  # pragma: no cover - compiled
    """How many of the events lie on the wrong ramp for their polarity (an ON event on the fall, an OFF event on
    the rise) if the stimulus has its valley at ``valley_us``: an ideal pixel fires ON only while L rises."""
    per_period = 1.0 / period_us
    count = 0
    for j in range(n):
        phase = (times[j] - valley_us) * per_period
        phase -= math.floor(phase)
        count += (phase < rise) != ons[j]
    return count


@kernel
def _fit_phase(times, ons, n, period_us, rise, wave):  # pragma: no cover - compiled
    """The valley time (relative to ``times[0]``) that best fits ``n`` events of one pixel.

    Every polarity reversal brackets a turn: between an OFF event and the next ON event lies a valley, between an
    ON event and the next OFF a peak, ``rise`` periods after a valley. Each bracket's centre is a candidate; the
    cost (:func:`_phase_cost`) picks the best, a grid across its bracket and a golden-section search refine it. A false
    bracket (a noise event) only adds a candidate that loses. (Intersecting the brackets instead was tried: a noise
    event or one removed by a denoiser next to a turn excluded the true phase, leaving 15 of 768 pixels of a
    denoised simulated flicker 13-20 % off.) Events with no reversal: a grid of :data:`PHASE_GRID` phases over the
    period, refined within a grid step.
    """
    changes = np.empty(n)
    misplaced = np.empty(n)
    fewest = n
    for j in range(1, n):
        if ons[j] != ons[j - 1]:
            shift = 0.0 if ons[j] else rise * period_us  # OFF -> ON: a valley; ON -> OFF: a peak
            misplaced[j] = _misplaced(times[j - 1] + 0.5 * (times[j] - times[j - 1]) - shift, times, ons, n,
                                      period_us, rise)
            fewest = min(fewest, misplaced[j])
    best_cost = math.inf
    best_low = best_high = 0.0
    for j in range(1, n):
        if ons[j] != ons[j - 1] and misplaced[j] <= fewest + SCREEN_SLACK:
            shift = 0.0 if ons[j] else rise * period_us
            low = times[j - 1] - shift
            high = times[j] - shift
            cost = _phase_cost(0.5 * (low + high), times, ons, n, period_us, rise, wave, changes)
            if cost < best_cost:
                best_cost, best_low, best_high = cost, low, high
    if best_cost == math.inf:
        step = period_us / PHASE_GRID
        for g in range(PHASE_GRID):
            cost = _phase_cost((g + 0.5) * step, times, ons, n, period_us, rise, wave, changes)
            if cost < best_cost:
                best_cost, best_low, best_high = cost, g * step, (g + 1) * step
    # the cost is not unimodal within a bracket (every change entering or leaving the window is a step): a grid
    # across it first, then the golden section within a grid step of the best
    step = (best_high - best_low) / BRACKET_GRID
    best = 0.5 * (best_low + best_high)
    for g in range(BRACKET_GRID + 1):
        cost = _phase_cost(best_low + g * step, times, ons, n, period_us, rise, wave, changes)
        if cost < best_cost:
            best_cost, best = cost, best_low + g * step
    valley, cost = _golden(best - step, best + step, times, ons, n, period_us, rise, wave, changes)
    return valley if cost <= best_cost else best


@kernel
def _settle(i, ring, filled, period_us, rise, wave, state, seeds, times, ons):  # pragma: no cover
    """Fit pixel i's phase to the events in its ring, then replay them into its sums."""
    n = min(filled[i], RING)
    t0, _ = _ring_event(ring, i, filled, 0)
    for j in range(n):
        t_us, on = _ring_event(ring, i, filled, j)
        times[j] = t_us - t0
        ons[j] = on
    valley = _fit_phase(times, ons, n, period_us, rise, wave)
    state[i, ST_PHASE] = (t0 % period_us + valley) % period_us
    state[i, ST_FITTED] = 1.0
    per_period = 1.0 / period_us
    for j in range(n):
        t_us, on = _ring_event(ring, i, filled, j)
        level = _wave_level((t_us - state[i, ST_PHASE]) * per_period, rise, wave)
        _observe_within_ramp(level, on, i, state, seeds)


@kernel
def stimulus_fitted_accumulate(
    t, x, y, p, width, period_us, rise, wave, state, seeds, ring, filled,
):  # pragma: no cover - compiled
    """Feed events to the stimulus sums, each pixel's phase fitted to its own events (:data:`RING`).

    Until its phase is fitted, a pixel's events (``t * 2 + on``) go into its ring ``ring[i]`` (``filled[i]``
    events so far; the latest :data:`RING` are kept); once the ring is full and shows a valley and a peak, the
    phase is fitted (:func:`_fit_phase`) and the ring replayed into the sums; later events go straight to the
    sums with ``L = stimulus(t - phase)``. Chunking cannot change the result: every step depends only on the
    pixel's own events, in order.
    """
    times = np.empty(RING)
    ons = np.empty(RING, dtype=np.bool_)
    per_period = 1.0 / period_us
    for k in range(t.shape[0]):
        i = np.int64(y[k]) * width + x[k]
        state[i, ST_SEEN] += 1.0
        if state[i, ST_FITTED] > 0.0:
            # _wave_level and _observe_within_ramp written out: the inlined helpers measured 14 Mev/s on random
            # events at 346 x 260, written out 38-40 (numba 0.68)
            phase = (t[k] - state[i, ST_PHASE]) * per_period
            phase -= math.floor(phase)
            if phase < rise:
                ramp = 0
            else:
                ramp = 1
                phase -= rise
            cell = phase * wave[ramp, WAVE_SCALE]
            c = min(np.int64(cell), WAVE_CELLS - 1)
            level = wave[ramp, c] + (cell - c) * (wave[ramp, c + 1] - wave[ramp, c])
            on = p[k] != 0
            same = (state[i, ST_LAST_ON] > 0.0) == on
            state[i, ST_LAST_ON] = 1.0 if on else 0.0
            if same and state[i, ST_EVENTS] > 0.0:
                change = level - state[i, ST_LAST]
                state[i, ST_ALL + (0 if on else 1)] += 1.0
                slot = -1
                if on:
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
            continue
        ring[i, filled[i] % RING] = t[k] * 2 + (1 if p[k] else 0)
        filled[i] += 1
        if filled[i] >= RING and _shows_both_turns(ring, i, filled):
            _settle(i, ring, filled, period_us, rise, wave, state, seeds, times, ons)


@kernel
def _shows_both_turns(ring, i, filled):  # pragma: no cover - compiled
    """Whether pixel i's ring holds an OFF event followed by an ON one (a valley) and an ON followed by an OFF."""
    valley = False
    peak = False
    _, previous = _ring_event(ring, i, filled, 0)
    for j in range(1, min(filled[i], RING)):
        _, on = _ring_event(ring, i, filled, j)
        valley = valley or (on and not previous)
        peak = peak or (previous and not on)
        previous = on
    return valley and peak


@kernel
def stimulus_fitted_finish(period_us, rise, wave, state, seeds, ring, filled):  # pragma: no cover
    """At the end of the stream: fit the phase of every pixel still waiting, from the events it has (two or more)."""
    times = np.empty(RING)
    ons = np.empty(RING, dtype=np.bool_)
    for i in range(filled.shape[0]):
        if state[i, ST_FITTED] == 0.0 and filled[i] >= 2:
            _settle(i, ring, filled, period_us, rise, wave, state, seeds, times, ons)


# -- natural scenes: event counts per polarity, in two interleaved halves --------------------------------------------

COUNT_SIZE = 8
"""natural: per pixel (ON events, OFF events, polarity reversals) in the even time blocks, the same in the odd ones,
then the last event's polarity (0 none yet, 1 ON, 2 OFF), and a spare column: float32 (whole counts exact up to
16.7 million a pixel; online, the decayed sums), 32 bytes, two pixels to a cache line."""
COUNT_LAST = 6


@kernel
def count_accumulate(t, x, y, p, width, block_us, counts):  # pragma: no cover - compiled
    """Count each pixel's ON and OFF events and its polarity reversals (an event whose polarity differs from the
    pixel's previous event's: a turn of its signal), separately in even and odd blocks of ``block_us`` (absolute
    time: ``t // block_us`` even or odd), into ``counts`` (pixels, :data:`COUNT_SIZE`)."""
    for k in range(t.shape[0]):
        _count(t[k], np.int64(y[k]) * width + x[k], p[k], block_us, counts)


# frames method (APS frames with events, Wang et al. 2019's offEI): per pixel its cumulative ON and OFF counts
# (16 bytes: the counts of a DAVIS346 fit in a core's L2 cache)
FRAMES_ON, FRAMES_OFF = 0, 1
FRAMES_ROW = 2


@kernel
def polarity_counts(x, y, p, width, counts):  # pragma: no cover - compiled
    """Events into ``counts`` (int64, (pixels, FRAMES_ROW)): each pixel's ON and OFF counts."""
    for k in range(len(x)):
        i = y[k] * width + x[k]
        if p[k]:
            counts[i, FRAMES_ON] += 1
        else:
            counts[i, FRAMES_OFF] += 1


@kernel
def exposure_counts(x, y, p, width, counts, marks, exposure, count):  # pragma: no cover - compiled
    """Events of exposure number ``exposure``: each pixel's latest exposure with events (``marks[i, 0]``) and its
    events in it (``marks[i, 1]``, int32 side by side: one cache line); with ``count``, into ``counts`` too, as
    :func:`polarity_counts` does (the exposure's first half; its second half is marked, then counted later)."""
    for k in range(len(x)):
        i = y[k] * width + x[k]
        if marks[i, 0] != exposure:
            marks[i, 0] = exposure
            marks[i, 1] = 0
        marks[i, 1] += 1
        if count:
            if p[k]:
                counts[i, FRAMES_ON] += 1
            else:
                counts[i, FRAMES_OFF] += 1


@kernel
def count_times(t, x, y, p, width, origin_us, times):  # pragma: no cover - compiled
    """Events into ``times`` (float64, (pixels, FRAMES_ROW)): each pixel's sums of its ON and of its OFF events'
    times (seconds after ``origin_us``), the counts' first moments in time (onEI's lag, see :func:`frame_sums`)."""
    for k in range(len(x)):
        i = y[k] * width + x[k]
        seconds = (t[k] - origin_us) * 1e-6
        if p[k]:
            times[i, FRAMES_ON] += seconds
        else:
            times[i, FRAMES_OFF] += seconds


TIME_SUMS = 6
"""onEI's lag: rows of a memory's event-time sums (:func:`frame_sums` with ``time_sums``): z_on, x1 z_on, x2 z_on,
z_off, x1 z_off, x2 z_off."""


@kernel
def log_levels(table, black, min_signal, saturated_dn):  # pragma: no cover - compiled
    """``table[dn] = log(dn - black)`` for every DN a frame can hold that is neither dark (less than ``min_signal``
    above ``black``) nor saturated (``saturated_dn`` and up); NaN for those (one logarithm per DN, not per pixel)."""
    for value in range(len(table)):
        if value >= saturated_dn or value - black < min_signal:
            table[value] = np.nan
        else:
            table[value] = math.log(value - black)


@kernel(inline=True)
def _fold_run(sums, runs, run_counts, i, time_sums, run_times):  # pragma: no cover - compiled
    """Pixel i's open run (its frames since its counts last changed: their number, sum of y and of y^2, all at the
    same x1 = A, x2 = -B and event-time sums z_on, z_off) into its least-squares sums (and its event-time sums,
    unless ``time_sums`` is empty); the run is emptied, its counts and times kept."""
    n = runs[0, i]
    if n == 0.0:
        return
    x1 = float(run_counts[0, i])
    x2 = -float(run_counts[1, i])
    sum_y = runs[1, i]
    sums[0, i] += n
    sums[1, i] += n * x1
    sums[2, i] += n * x2
    sums[3, i] += sum_y
    sums[4, i] += n * x1 * x1
    sums[5, i] += n * x2 * x2
    sums[6, i] += n * x1 * x2
    sums[7, i] += x1 * sum_y
    sums[8, i] += x2 * sum_y
    sums[9, i] += runs[2, i]
    if time_sums.shape[0] > 0:
        z_on = n * run_times[FRAMES_ON, i]
        z_off = n * run_times[FRAMES_OFF, i]
        time_sums[0, i] += z_on
        time_sums[1, i] += x1 * z_on
        time_sums[2, i] += x2 * z_on
        time_sums[3, i] += z_off
        time_sums[4, i] += x1 * z_off
        time_sums[5, i] += x2 * z_off
    runs[0, i] = 0.0
    runs[1, i] = 0.0
    runs[2, i] = 0.0


@kernel
def fold_runs(sums, runs, run_counts, time_sums, run_times):  # pragma: no cover - compiled
    """Every pixel's open run into its sums (before a fit): see :func:`frame_sums`."""
    for i in range(sums.shape[1]):
        _fold_run(sums, runs, run_counts, i, time_sums, run_times)


@kernel
def frame_sums(image, x0, y0, width, counts, marks, exposure, log_dn, black, log_exposure, max_events,
               saturated_dn, sums, runs, run_counts, half, sample_step, inverse_sums, new_counts,
               saturated, weight, times, time_sums, run_times, sampled_only):  # pragma: no cover - compiled
    """One APS frame (``image``, its corner at ``x0, y0`` on a sensor ``width`` wide) into the frames method's
    per-pixel least-squares sums (see :class:`evtools.estimation_frames.FrameThresholdEstimator`), for one black
    level: a pixel that fired at most ``max_events`` times during the exposure (``marks``: see
    :func:`exposure_counts`) and whose DN has a log in ``log_dn`` (:func:`log_levels`: neither dark nor saturated) adds
    ``y = log(dn - black) - log_exposure`` against ``x1 = A``, ``x2 = -B`` (its ``counts`` at the exposure's
    middle) to its sums (rows n, x1, x2, y, x1x1, x2x2, x1x2, x1y, x2y, yy).

    A pixel's frames between two changes of its counts share x1 and x2: they are summed in its open run (``runs``:
    number, sum y, sum y^2; ``run_counts``: its A and B, -1 before any) and folded into ``sums`` when the counts
    change (``new_counts`` counts those frames) or by :func:`fold_runs`: three sums a frame instead of ten. With
    ``sample_step`` (0: none), every ``sample_step``-th pixel also adds the frame to ``half[0 or 1]``, by whether its
    count level is above its mean so far, and with ``sampled_only`` the other pixels are skipped (a black level only
    checked: its test needs the sampled pixels alone). ``saturated`` (unless empty) counts the frames in which a
    pixel is. The
    frame weighs ``weight`` in ``sums``, ``runs``, ``inverse_sums`` and ``new_counts`` (onEI's forgetting: see
    ``FrameThresholdEstimator._forget``), 1 in ``half``.

    onEI's lag: unless ``time_sums`` is empty, the pixel's event-time sums ``z_on``, ``z_off`` (``times``:
    :func:`count_times`, which change only with its counts: a run's are kept in ``run_times``) go against the same
    x1, x2 into ``time_sums`` (:data:`TIME_SUMS` rows) when a run is folded: the right-hand sides of the least
    squares that regress z on the design of the thresholds' fit. Under a drift ``theta(t) = theta(T) (1 + r (t -
    T))`` a pixel's log DN is ``theta_on(T) (A (1 - r T) + r z_on) - theta_off(T) (...)``, so these coefficients say
    at which time each map's thresholds hold."""
    tally = saturated.shape[0] > 0
    for row in range(image.shape[0]):
        first = (y0 + row) * width + x0
        k = first // sample_step if sample_step > 0 else 0  # i's sample, when i % sample_step == 0 (kept
        offset = first - k * sample_step if sample_step > 0 else 1  # without a division per pixel)
        for column in range(image.shape[1]):
            i = np.uint64(first + column)  # unsigned: no negative-index fix-ups
            if offset == sample_step:
                offset = 0
                k += 1
            sampled = offset == 0
            offset += 1
            if sampled_only and not sampled:
                continue
            value = image[row, column]
            if tally and value >= saturated_dn:
                saturated[i] += 1
            log_value = log_dn[value]
            if log_value != log_value or (marks[i, 0] == exposure and marks[i, 1] > max_events):
                continue
            y = log_value - log_exposure
            on = counts[i, FRAMES_ON]
            off = counts[i, FRAMES_OFF]
            if sampled:
                x1 = float(on)
                x2 = -float(off)
                n = sums[0, i] + runs[0, i]
                level = (sums[1, i] + sums[2, i] + runs[0, i] * float(run_counts[0, i] - run_counts[1, i])) / max(
                    n, 1.0)
                side = 1 if x1 + x2 > level else 0
                half[side, 0, k] += 1.0
                half[side, 1, k] += x1
                half[side, 2, k] += x2
                half[side, 3, k] += y
                half[side, 4, k] += x1 * x1
                half[side, 5, k] += x2 * x2
                half[side, 6, k] += x1 * x2
                half[side, 7, k] += x1 * y
                half[side, 8, k] += x2 * y
                half[side, 9, k] += y * y
            if on != run_counts[0, i] or off != run_counts[1, i]:
                _fold_run(sums, runs, run_counts, i, time_sums, run_times)
                run_counts[0, i] = on
                run_counts[1, i] = off
                if time_sums.shape[0] > 0:
                    run_times[FRAMES_ON, i] = times[i, FRAMES_ON]
                    run_times[FRAMES_OFF, i] = times[i, FRAMES_OFF]
                new_counts[i] += weight
            runs[0, i] += weight
            runs[1, i] += weight * y
            runs[2, i] += weight * y * y
            inverse_sums[i] += weight / (value - black)



NEIGHBOUR_AGE_BINS = 64
"""Bins of :func:`neighbour_ages`: bin k counts ages in [2^k, 2^(k+1)) us (bin 0 also 0), the last one the events
whose neighbours never fired."""
_NEVER = -(1 << 62)  # (bafilter's NEVER: a pixel that never fired)


@kernel
def neighbour_ages(t, x, y, first, stride, time_map, pixel_events, ages):  # pragma: no cover - compiled
    """For every ``stride``-th event of the stream (``first``: the stream index of ``t[0]``), the time since the
    latest event of one of its 8 neighbours (any polarity, not itself), counted in ``ages`` by its binary order of
    magnitude (:data:`NEIGHBOUR_AGE_BINS`), and at its pixel in ``pixel_events``; ``time_map`` (padded by 1,
    ``NEVER`` where none fired) gets every event's time."""
    width = time_map.shape[1]
    flat = time_map.ravel()
    never_bin = ages.shape[0] - 1
    as_float = np.zeros(1, np.float64)  # an age's binary order of magnitude: its float's exponent bits
    exponent = as_float.view(np.int64)
    for i in range(t.shape[0]):
        c = (y[i] + 1) * width + x[i] + 1
        if (first + i) & (stride - 1) != 0:  # (stride a power of 2: no division)
            flat[c] = t[i]
            continue
        pixel_events[y[i] * (width - 2) + x[i]] += 1
        above = max(max(flat[c - width - 1], flat[c - width]), flat[c - width + 1])
        below = max(max(flat[c + width - 1], flat[c + width]), flat[c + width + 1])
        latest = max(max(above, below), max(flat[c - 1], flat[c + 1]))
        flat[c] = t[i]
        if latest == _NEVER:
            ages[never_bin] += 1
        else:
            as_float[0] = t[i] - latest  # (exact below 2^53 us; 0 has exponent -1023: bin 0)
            ages[min(max((exponent[0] >> 52) - 1023, 0), never_bin - 1)] += 1
