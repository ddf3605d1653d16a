"""DVS pixel kernel: advances every pixel from one frame of intensity to the next and emits its events.

The pixel model is v2e's (lin-log photoreceptor, intensity-dependent first-order low-pass, per-pixel thresholds,
leak, intensity-dependent shot noise) with ESIM's timing: within one frame interval the comparator input is the
straight line between the two frames' (filtered) log intensities, and every threshold crossing gets its own time on
that line. All per-pixel state lives in arrays owned by :class:`evtools.simulation.DvsSimulator`; a pixel's state is
written back only after all of its events for the interval fit into the output arrays, so a call that runs out of
space can be repeated from the pixel it stopped at. ``tests/naive`` holds the pure-Python reference.

Speed (the video benchmark is about 10 ns per pixel and frame): 8-bit frames take lin-log and the low-pass gain
from per-level tables built with the per-pixel expressions (so the results are the same bits); a pixel that only
drifts in an interval - most of them - is settled before the event loop; maps that are zero everywhere are not
read; and :func:`time_order` sorts an interval's events by a counting sort on their microsecond.

Random draws for shot noise and hot pixels come from a counter-based generator (SplitMix64's finaliser applied to
``(key, pixel, draw number)``): each pixel has its own sequence, consumed in time order, so the events depend on
neither how frames are batched into calls nor on the order pixels are visited.

References
----------
Y. Hu, S.-C. Liu, T. Delbruck, "v2e: From Video Frames to Realistic DVS Events", CVPR Workshops, 2021.
H. Rebecq, D. Gehrig, D. Scaramuzza, "ESIM: an Open Event Camera Simulator", Conference on Robot Learning, 2018.
G. Steele, D. Lea, C. Flood, "Fast splittable pseudorandom number generators", OOPSLA 2014 (SplitMix64).
"""

from __future__ import annotations

import math

import numpy as np

from evtools._kernels.jit import deferred, kernel

LIN_LOG_KNEE = 20.0
"""Below this intensity (0-255 scale) the photoreceptor response is linear, above it logarithmic (v2e)."""
LIN_LOG_SLOPE = math.log(LIN_LOG_KNEE) / LIN_LOG_KNEE
"""Slope of the linear part, so that the curve is continuous at the knee."""
LOWPASS_INTENSITY_OFFSET = 20.0
LOWPASS_INTENSITY_SCALE = 275.0
"""v2e's intensity-dependent bandwidth: ``eps = min(1, ((I + 20) / 275) * dt / tau)``."""
SHOT_NOISE_FULL_SCALE_FACTOR = 0.25
"""v2e: shot noise rate at full intensity (255) relative to the rate in the dark, linear in between."""

LABEL_SIGNAL = 0
LABEL_LEAK = 1
LABEL_SHOT = 2
LABEL_HOT = 3

NEVER_US = -(1 << 62)
"""``last_event_us`` of a pixel that has not fired yet."""

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_ONE = np.uint64(1)
_ZERO = np.uint64(0)
_TWO_POW_M53 = 1.0 / 9007199254740992.0


@kernel(inline=True)
def _mix64(z):  # pragma: no cover - compiled
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@kernel
def random_bits(key, pixel, draw):  # pragma: no cover - compiled
    """64 random bits for draw number ``draw`` of pixel ``pixel`` in the stream ``key`` (all uint64)."""
    return _mix64(_mix64(key + pixel * _GOLDEN) + draw * _GOLDEN)


@kernel(inline=True)
def _noise_draw(key, pixel, draw, s, mass):  # pragma: no cover - compiled
    """A noise event of a Poisson process at ``s``: its polarity (a fair coin) and the process's next event,
    ``s`` plus an exponential gap of rate ``mass``, both from draw number ``draw`` of ``pixel`` in stream ``key``."""
    bits = random_bits(key, pixel, draw)
    u = float(bits >> _S11) * _TWO_POW_M53
    return (bits & _ONE) == _ONE, s + -math.log(1.0 - u) / mass


@kernel(inline=True)
def _lin_log(intensity):  # pragma: no cover - compiled
    if intensity <= LIN_LOG_KNEE:
        return intensity * LIN_LOG_SLOPE
    return math.log(intensity)


@kernel
def lin_log_frame(frame, out):  # pragma: no cover - compiled
    """``out[i] = lin_log(frame[i])`` (negative or NaN intensities count as 0)."""
    for i in range(frame.size):
        intensity = float(frame[i])
        if not intensity >= 0.0:
            intensity = 0.0
        out[i] = _lin_log(intensity)


LEVELS = 256
"""Intensities of an 8-bit frame: its pixels take their lin-log (and low-pass gain) from tables of this size."""


def _is_8bit(frame):  # pragma: no cover - used at compile time
    from numba import types

    return isinstance(frame.dtype, types.Integer) and frame.dtype.bitwidth == 8 and not frame.dtype.signed


def _pixel_log(frame, i, log_table):  # pragma: no cover - compiled: see its overload
    """``(intensity, lin_log(intensity))`` of pixel ``i``; an 8-bit frame reads the log from ``log_table``."""
    raise NotImplementedError


def _pixel_log_overload(frame, i, log_table):  # pragma: no cover - compiled
    if _is_8bit(frame):
        return lambda frame, i, log_table: (float(frame[i]), log_table[frame[i]])

    def computed(frame, i, log_table):
        intensity = float(frame[i])
        if not intensity >= 0.0:
            intensity = 0.0
        return intensity, _lin_log(intensity)

    return computed


def _pixel_gain(frame, i, intensity, gain_table, lowpass_gain):  # pragma: no cover - compiled: see its overload
    """The low-pass gain of pixel ``i`` (``intensity``); an 8-bit frame reads it from ``gain_table``."""
    raise NotImplementedError


def _pixel_gain_overload(frame, i, intensity, gain_table, lowpass_gain):  # pragma: no cover - compiled
    if _is_8bit(frame):
        return lambda frame, i, intensity, gain_table, lowpass_gain: gain_table[frame[i]]
    return lambda frame, i, intensity, gain_table, lowpass_gain: _lowpass_eps(intensity, lowpass_gain)


def _register_overloads():
    from numba.extending import overload

    overload(_pixel_log, inline="always")(_pixel_log_overload)
    overload(_pixel_gain, inline="always")(_pixel_gain_overload)
    return True


_OVERLOADS = deferred(_register_overloads)


@kernel(inline=True)
def _lowpass_eps(intensity, lowpass_gain):  # pragma: no cover - compiled
    eps = (intensity + LOWPASS_INTENSITY_OFFSET) / LOWPASS_INTENSITY_SCALE * lowpass_gain
    return 1.0 if eps > 1.0 else eps


@kernel
def _level_tables(lowpass_gain):  # pragma: no cover - compiled
    """``lin_log`` and the low-pass gain of every level of an 8-bit frame, by the per-pixel expressions."""
    log_table = np.empty(LEVELS)
    gain_table = np.empty(LEVELS)
    for k in range(LEVELS):
        log_table[k] = _lin_log(float(k))
        gain_table[k] = _lowpass_eps(float(k), lowpass_gain)
    return log_table, gain_table


@kernel
def advance_pixels(
    frame, t0_us, t1_us, width, cutoff_hz, fixed_cutoff, refractory_us,
    on_thres, off_thres, leak_rate_hz, shot_rate_hz, hot_rate_hz, any_leak, any_shot, any_hot, shot_key, hot_key,
    lp_log, ref_log, last_event_us, shot_budget, hot_budget, shot_draws, hot_draws,
    out_t_us, out_x, out_y, out_p, out_label, count, first_pixel, last_pixel,
):  # pragma: no cover - compiled
    """Advance pixels ``first_pixel..last_pixel - 1`` from time ``t0_us`` to the frame ``frame`` at ``t1_us``; emit their events.

    Per pixel ``i`` (raster order, ``x = i % width``): the intensity I (0-255) becomes ``L = lin_log(I)``; the
    low-pass state moves ``lp += eps * (L - lp)`` with ``eps = min(1, ((I + 20) / 275) * dt * 2 pi cutoff_hz)``
    (``lp = L`` when ``cutoff_hz`` is 0; ``eps = min(1, dt * 2 pi cutoff_hz)`` at every intensity when
    ``fixed_cutoff``, a plain single-pole filter); between the two frames the comparator sees ``lp`` on a straight line
    and a reference that drifts down by ``leak_rate_hz[i] * on_thres[i] * dt`` (leak). An ON event fires where
    ``lp - ref`` reaches ``on_thres`` (then ``ref += on_thres``), an OFF event where ``ref - lp`` reaches
    ``off_thres`` (then ``ref -= off_thres``), each at its own interpolated time (ESIM). Shot noise fires as a
    Poisson process of rate ``shot_rate_hz[i] * (1 - 0.75 * I / 255)`` (ON or OFF with equal probability) and
    resets the reference to the signal; hot pixels fire at ``hot_rate_hz[i]`` without touching the reference.
    An event within ``refractory_us`` of the pixel's previous output event is dropped; a dropped crossing still
    moves the reference (ESIM), a dropped shot or hot event does not happen at all.

    Parameters
    ----------
    frame : ndarray of float32 or uint8, shape (n_pixels,)
        The new frame, raster order, intensity 0-255 (uint8: from per-level tables, the same values).
    t0_us, t1_us : int
        Times of the previous frame (the state's time) and of ``frame``; ``t1_us > t0_us``.
    width : int
        Sensor width (pixel ``i`` is at ``x = i % width``, ``y = i // width``).
    cutoff_hz : float
        Photoreceptor cutoff at full intensity; 0 disables the low-pass.
    fixed_cutoff : bool
        The cutoff does not fall with intensity (a plain single-pole low-pass instead of v2e's).
    refractory_us : int
        Refractory period; 0 disables it.
    on_thres, off_thres : ndarray of float32; leak_rate_hz, shot_rate_hz, hot_rate_hz : ndarray of float64
        Per-pixel thresholds (log units, > 0) and rates (Hz; shot rate is the rate in the dark).
    any_leak, any_shot, any_hot : bool
        Whether the leak, shot and hot rates are anywhere > 0 (when not, those maps are not read).
    shot_key, hot_key : uint64
        Keys of the random streams of shot noise and hot pixels.
    lp_log, ref_log : ndarray of float64
        State: low-pass log intensity and reference level at ``t0_us``; updated in place.
    last_event_us : ndarray of int64
        State: time of each pixel's last output event.
    shot_budget, hot_budget : ndarray of float64
        State: the remaining unit-rate exponential "budget" until the next shot / hot event.
    shot_draws, hot_draws : ndarray of uint64
        State: how many random numbers each pixel has used from each stream.
    out_t_us, out_x, out_y, out_p, out_label : ndarray
        Output arrays (int64, int16, int16, bool, uint8); events are written from index ``count`` on, in pixel
        order and, within a pixel, in time order.
    count : int
        Number of events already in the output arrays.
    first_pixel, last_pixel : int
        The pixels to advance, ``first_pixel`` to ``last_pixel - 1`` (a lane of rows; ``first_pixel`` where a previous
        call ran out of space).

    Returns
    -------
    count : int
        Number of events in the output arrays after the call.
    next_pixel : int
        ``last_pixel`` when every pixel was advanced; otherwise the pixel whose events did not fit (its state is
        unchanged): grow the output arrays and call again from there.
    """
    capacity = out_t_us.size
    dt_us = float(t1_us - t0_us)
    dt_s = dt_us * 1e-6
    lowpass_gain = dt_s * 2.0 * math.pi * cutoff_hz
    lowpass = cutoff_hz > 0.0
    fixed_eps = min(1.0, lowpass_gain)
    # 8-bit frames: per-level tables instead of a log and a division per pixel (same expressions, same bits)
    log_table, gain_table = _level_tables(lowpass_gain)
    shot_slope = (1.0 - SHOT_NOISE_FULL_SCALE_FACTOR) / 255.0
    inf = math.inf
    x = first_pixel % width
    y = first_pixel // width
    for i in range(first_pixel, last_pixel):
        start_count = count
        at = np.uint64(i)  # unsigned: indexing needs no code for negative indices
        intensity, log_now = _pixel_log(frame, at, log_table)
        lp_start = lp_log[at]
        if lowpass:
            eps = fixed_eps if fixed_cutoff else _pixel_gain(frame, at, intensity, gain_table, lowpass_gain)
            lp_end = lp_start + eps * (log_now - lp_start)
        else:
            lp_end = log_now
        signal_change = lp_end - lp_start
        on = float(on_thres[at])
        off = float(off_thres[at])
        # maps that are zero everywhere are not read at all (the values would be the same: no drift, no noise)
        leak_drift = leak_rate_hz[at] * on * dt_s if any_leak else 0.0
        slope = signal_change + leak_drift  # d(lp - ref)/ds, s = (t - t0) / dt in [0, 1]
        on_label = LABEL_LEAK if signal_change <= 0.0 else LABEL_SIGNAL
        ref = ref_log[at]  # the reference at s = 0; at s it is ref - leak_drift * s

        shot_mass = 0.0  # expected shot events in this interval
        shot_next = inf
        if any_shot:
            darkness = 1.0 - shot_slope * min(intensity, 255.0)
            shot_mass = shot_rate_hz[at] * darkness * dt_s
            if shot_mass > 0.0:
                shot_next = shot_budget[at] / shot_mass
        hot_mass = 0.0
        hot_next = inf
        if any_hot:
            hot_mass = hot_rate_hz[at] * dt_s
            if hot_mass > 0.0:
                hot_next = hot_budget[at] / hot_mass

        # most pixels do nothing but drift in an interval: the first step of the loop below, on its own
        level = lp_start - ref
        cross_next = inf
        if slope > 0.0:
            cross_next = (on - level) / slope
        elif slope < 0.0:
            cross_next = (-off - level) / slope
        if min(cross_next, min(shot_next, hot_next)) > 1.0:
            lp_log[at] = lp_end
            ref_log[at] = ref - leak_drift
            if shot_mass > 0.0:
                shot_budget[at] = (shot_next - 1.0) * shot_mass
            if hot_mass > 0.0:
                hot_budget[at] = (hot_next - 1.0) * hot_mass
            x += 1
            if x == width:
                x = 0
                y += 1
            continue

        s = 0.0
        busy = False  # whether the pixel did anything but drift in this interval
        last = NEVER_US
        shot_n = _ZERO
        hot_n = _ZERO
        full = False
        while True:
            level = lp_start - ref  # lp - ref at s = 0, with the current reference
            cross_next = inf
            cross_on = True
            if slope > 0.0:
                cross_next = (on - level) / slope
            elif slope < 0.0:
                cross_next = (-off - level) / slope
                cross_on = False
            if cross_next < s:
                cross_next = s
            s_next = min(cross_next, min(shot_next, hot_next))
            if s_next > 1.0:
                break
            if not busy:  # the rest of the pixel's state is read only when it is needed
                busy = True
                last = last_event_us[at]
                shot_n = shot_draws[at]
                hot_n = hot_draws[at]
            s = s_next
            t_us = np.int64(math.floor(t0_us + s * dt_us + 0.5))
            free = t_us - last >= refractory_us
            if cross_next == s:
                if cross_on:
                    ref += on
                    polarity = True
                    label = on_label
                else:
                    ref -= off
                    polarity = False
                    label = LABEL_SIGNAL
            elif shot_next == s:
                polarity, shot_next = _noise_draw(shot_key, at, shot_n, s, shot_mass)
                shot_n += _ONE
                label = LABEL_SHOT
                if free:
                    ref = lp_start + (signal_change + leak_drift) * s  # reset to the signal: lp - ref = 0
            else:
                polarity, hot_next = _noise_draw(hot_key, at, hot_n, s, hot_mass)
                hot_n += _ONE
                label = LABEL_HOT
            if free:
                if count >= capacity:
                    full = True
                    break
                out_t_us[count] = t_us
                out_x[count] = x
                out_y[count] = y
                out_p[count] = polarity
                out_label[count] = label
                count += 1
                last = t_us
        if full:
            return start_count, i
        lp_log[at] = lp_end
        ref_log[at] = ref - leak_drift
        if shot_mass > 0.0:
            shot_budget[at] = (shot_next - 1.0) * shot_mass
        if hot_mass > 0.0:
            hot_budget[at] = (hot_next - 1.0) * hot_mass
        if busy:
            last_event_us[at] = last
            shot_draws[at] = shot_n
            hot_draws[at] = hot_n
        x += 1
        if x == width:
            x = 0
            y += 1
    return count, last_pixel


@kernel
def time_order(t_us, max_span_us, order):  # pragma: no cover - compiled
    """The stable sort of ``t_us`` (``np.argsort(t_us, kind="stable")``) into ``order``, as a counting sort.

    One frame interval's events lie within that interval, a span of microseconds small next to their number,
    so counting each microsecond's events beats a comparison sort. Returns False (``order`` untouched) when
    the times span more than ``max_span_us`` microseconds: then sort them otherwise.
    """
    n = t_us.size
    if n == 0:
        return True
    lo = t_us[0]
    hi = lo
    for k in range(n):
        v = t_us[k]
        if v < lo:
            lo = v
        elif v > hi:
            hi = v
    span = hi - lo + 1
    if span > max_span_us:
        return False
    starts = np.zeros(span + 1, dtype=np.int64)  # starts[b + 1] counts the events at lo + b, then becomes where
    for k in range(n):                           # the events at lo + b + 1 start
        starts[t_us[k] - lo + 1] += 1
    for b in range(1, span + 1):
        starts[b] += starts[b - 1]
    for k in range(n):  # in input order: equal times keep it
        b = t_us[k] - lo
        order[starts[b]] = k
        starts[b] += 1
    return True


@kernel
def sort_events(t_us, x, y, p, label, max_span_us, out_t_us, out_x, out_y, out_p, out_label):  # pragma: no cover
    """The events (five columns) into ``out_*`` in the order of :func:`time_order` (stable, by time).

    The outputs may be fields of an event array. Returns False (nothing written) when the times span more than
    ``max_span_us``.
    """
    order = np.empty(t_us.size, dtype=np.int64)
    if not time_order(t_us, max_span_us, order):
        return False
    for k in range(order.size):
        j = order[k]
        out_t_us[k] = t_us[j]
        out_x[k] = x[j]
        out_y[k] = y[j]
        out_p[k] = p[j]
        out_label[k] = label[j]
    return True
