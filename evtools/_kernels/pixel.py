"""DVS pixel kernel: advances every pixel from one frame of intensity to the next and emits its events.

The pixel model is v2e's (lin-log photoreceptor, intensity-dependent first-order low-pass, per-pixel thresholds,
leak, intensity-dependent shot noise) with ESIM's timing: within one frame interval the comparator input is the
straight line between the two frames' (filtered) log intensities, and every threshold crossing gets its own time on
that line. All per-pixel state lives in arrays owned by :class:`evtools.simulate.DvsSimulator`; a pixel's state is
written back only after all of its events for the interval fit into the output arrays, so a call that runs out of
space can be repeated from the pixel it stopped at. ``tests/naive.py`` holds the pure-Python reference.

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
from numba import njit

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


@njit(cache=True, nogil=True, inline="always")
def _mix64(z):  # pragma: no cover - compiled
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@njit(cache=True, nogil=True)
def random_bits(key, pixel, draw):  # pragma: no cover - compiled
    """64 random bits for draw number ``draw`` of pixel ``pixel`` in the stream ``key`` (all uint64)."""
    return _mix64(_mix64(key + pixel * _GOLDEN) + draw * _GOLDEN)


@njit(cache=True, nogil=True, inline="always")
def _lin_log(intensity):  # pragma: no cover - compiled
    if intensity <= LIN_LOG_KNEE:
        return intensity * LIN_LOG_SLOPE
    return math.log(intensity)


@njit(cache=True, nogil=True)
def lin_log_frame(frame, out):  # pragma: no cover - compiled
    """``out[i] = lin_log(frame[i])`` (negative or NaN intensities count as 0)."""
    for i in range(frame.size):
        intensity = float(frame[i])
        if not intensity >= 0.0:
            intensity = 0.0
        out[i] = _lin_log(intensity)


@njit(cache=True, nogil=True)
def advance_pixels(
    frame, t0_us, t1_us, width, cutoff_hz, refractory_us,
    on_thres, off_thres, leak_rate_hz, shot_rate_hz, hot_rate_hz, shot_key, hot_key,
    lp_log, ref_log, last_event_us, shot_budget, hot_budget, shot_draws, hot_draws,
    out_t_us, out_x, out_y, out_p, out_label, count, first_pixel,
):  # pragma: no cover - compiled
    """Advance pixels ``first_pixel..`` from time ``t0_us`` to the frame ``frame`` at ``t1_us``; emit their events.

    Per pixel ``i`` (raster order, ``x = i % width``): the intensity I (0-255) becomes ``L = lin_log(I)``; the
    low-pass state moves ``lp += eps * (L - lp)`` with ``eps = min(1, ((I + 20) / 275) * dt * 2 pi cutoff_hz)``
    (``lp = L`` when ``cutoff_hz`` is 0); between the two frames the comparator sees ``lp`` on a straight line
    and a reference that drifts down by ``leak_rate_hz[i] * on_thres[i] * dt`` (leak). An ON event fires where
    ``lp - ref`` reaches ``on_thres`` (then ``ref += on_thres``), an OFF event where ``ref - lp`` reaches
    ``off_thres`` (then ``ref -= off_thres``), each at its own interpolated time (ESIM). Shot noise fires as a
    Poisson process of rate ``shot_rate_hz[i] * (1 - 0.75 * I / 255)`` (ON or OFF with equal probability) and
    resets the reference to the signal; hot pixels fire at ``hot_rate_hz[i]`` without touching the reference.
    An event within ``refractory_us`` of the pixel's previous output event is dropped; a dropped crossing still
    moves the reference (ESIM), a dropped shot or hot event does not happen at all.

    Parameters
    ----------
    frame : ndarray of float32, shape (n_pixels,)
        The new frame, raster order.
    t0_us, t1_us : int
        Times of the previous frame (the state's time) and of ``frame``; ``t1_us > t0_us``.
    width : int
        Sensor width (pixel ``i`` is at ``x = i % width``, ``y = i // width``).
    cutoff_hz : float
        Photoreceptor cutoff at full intensity; 0 disables the low-pass.
    refractory_us : int
        Refractory period; 0 disables it.
    on_thres, off_thres, leak_rate_hz, shot_rate_hz, hot_rate_hz : ndarray of float64, shape (n_pixels,)
        Per-pixel thresholds (log units, > 0) and rates (Hz; shot rate is the rate in the dark).
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
    first_pixel : int
        First pixel to advance (0, or where a previous call ran out of space).

    Returns
    -------
    count : int
        Number of events in the output arrays after the call.
    next_pixel : int
        ``n_pixels`` when every pixel was advanced; otherwise the pixel whose events did not fit (its state is
        unchanged): grow the output arrays and call again from there.
    """
    n_pixels = frame.size
    capacity = out_t_us.size
    dt_us = float(t1_us - t0_us)
    dt_s = dt_us * 1e-6
    lowpass_gain = dt_s * 2.0 * math.pi * cutoff_hz
    shot_slope = (1.0 - SHOT_NOISE_FULL_SCALE_FACTOR) / 255.0
    inf = math.inf
    for i in range(first_pixel, n_pixels):
        start_count = count
        intensity = float(frame[i])
        if not intensity >= 0.0:
            intensity = 0.0
        log_now = _lin_log(intensity)
        lp_start = lp_log[i]
        if cutoff_hz > 0.0:
            eps = (intensity + LOWPASS_INTENSITY_OFFSET) / LOWPASS_INTENSITY_SCALE * lowpass_gain
            if eps > 1.0:
                eps = 1.0
            lp_end = lp_start + eps * (log_now - lp_start)
        else:
            lp_end = log_now
        signal_change = lp_end - lp_start
        on = float(on_thres[i])
        off = float(off_thres[i])
        leak_drift = leak_rate_hz[i] * on * dt_s
        slope = signal_change + leak_drift  # d(lp - ref)/ds, s = (t - t0) / dt in [0, 1]
        on_label = LABEL_LEAK if signal_change <= 0.0 else LABEL_SIGNAL
        ref = ref_log[i]  # the reference at s = 0; at s it is ref - leak_drift * s

        darkness = 1.0 - shot_slope * min(intensity, 255.0)
        shot_mass = shot_rate_hz[i] * darkness * dt_s  # expected shot events in this interval
        shot_next = shot_budget[i] / shot_mass if shot_mass > 0.0 else inf
        hot_mass = hot_rate_hz[i] * dt_s
        hot_next = hot_budget[i] / hot_mass if hot_mass > 0.0 else inf

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
                last = last_event_us[i]
                shot_n = shot_draws[i]
                hot_n = hot_draws[i]
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
                bits = random_bits(shot_key, np.uint64(i), shot_n)
                shot_n += _ONE
                polarity = (bits & _ONE) == _ONE
                u = float(bits >> _S11) * _TWO_POW_M53
                shot_next = s + -math.log(1.0 - u) / shot_mass
                label = LABEL_SHOT
                if free:
                    ref = lp_start + (signal_change + leak_drift) * s  # reset to the signal: lp - ref = 0
            else:
                bits = random_bits(hot_key, np.uint64(i), hot_n)
                hot_n += _ONE
                polarity = (bits & _ONE) == _ONE
                u = float(bits >> _S11) * _TWO_POW_M53
                hot_next = s + -math.log(1.0 - u) / hot_mass
                label = LABEL_HOT
            if free:
                if count >= capacity:
                    full = True
                    break
                out_t_us[count] = t_us
                out_x[count] = i % width
                out_y[count] = i // width
                out_p[count] = polarity
                out_label[count] = label
                count += 1
                last = t_us
        if full:
            return start_count, i
        lp_log[i] = lp_end
        ref_log[i] = ref - leak_drift
        if shot_mass > 0.0:
            shot_budget[i] = (shot_next - 1.0) * shot_mass
        if hot_mass > 0.0:
            hot_budget[i] = (hot_next - 1.0) * hot_mass
        if busy:
            last_event_us[i] = last
            shot_draws[i] = shot_n
            hot_draws[i] = hot_n
    return count, n_pixels
