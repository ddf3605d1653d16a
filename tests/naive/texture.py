"""Natural moving textures seen by ideal DVS pixels: an independent generator for tests of ``correct`` and
``estimate`` on the scenes users record.

Shares nothing with ``evtools.simulation``: the texture is an analytic sum of random plane waves (a multi-scale,
1/f-like log-intensity field), moved under the sensor along a random path (a pan, a hand-held wobble, or both),
sampled per pixel on a fine time grid; every pixel's events are the exact crossings of that polyline by its
reference levels (an ideal pixel: no noise, no refractory period, no low-pass). Thresholds are per pixel and
polarity; the same signal seen with uniform thresholds is the ideal sensor the corrected stream is compared with.
"""

from __future__ import annotations

import numpy as np

EVENT_FIELDS = [("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "?")]


def texture_signal(width, height, duration_us, *, seed, contrast=0.8, waves=24, min_period_px=3.0,
                   max_period_px=40.0, pan_px_s=(0.0, 0.0), wobble_px=0.0, wobble_hz=1.5, step_us=250,
                   contrast_map=None):
    """Log intensity of every pixel on a time grid: (times_us (n,), levels (n, height, width)).

    The texture is ``sum_k a_k sin(2 pi (f_k . (r - p(t))) + phi_k)`` with ``waves`` wave vectors of random
    orientation, periods log-uniform in [min_period_px, max_period_px], amplitudes proportional to the period
    (1/f) and scaled so that the field's standard deviation is ``contrast`` (log units). The path ``p(t)`` is a
    constant pan (px/s) plus a wobble: three random sinusoids of total amplitude ``wobble_px`` around
    ``wobble_hz``. ``contrast_map`` (height, width) multiplies the field per pixel (a contrast boundary)."""
    rng = np.random.default_rng(seed)
    periods = np.exp(rng.uniform(np.log(min_period_px), np.log(max_period_px), waves))
    angles = rng.uniform(0, 2 * np.pi, waves)
    fx, fy = np.cos(angles) / periods, np.sin(angles) / periods
    amplitudes = periods / np.sqrt(np.sum(periods ** 2) / 2) * contrast
    phases = rng.uniform(0, 2 * np.pi, waves)
    wobble_f = wobble_hz * rng.uniform(0.5, 2.0, (3, 2))
    wobble_a = wobble_px * rng.dirichlet(np.ones(3), 2).T
    wobble_phi = rng.uniform(0, 2 * np.pi, (3, 2))
    times = np.arange(0, duration_us + step_us, step_us, dtype=np.float64)
    seconds = times / 1e6
    path = np.outer(seconds, pan_px_s) + np.einsum(
        "kd,tkd->td", wobble_a, np.sin(2 * np.pi * wobble_f[None] * seconds[:, None, None] + wobble_phi[None]))
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    # the phase of wave k at pixel r and time t: f_k . r - f_k . p(t)
    space = 2 * np.pi * (fx[:, None, None] * xs + fy[:, None, None] * ys) + phases[:, None, None]
    shift = 2 * np.pi * (path[:, 0:1] * fx[None] + path[:, 1:2] * fy[None])  # (n, waves)
    levels = np.zeros((len(times), height, width))
    for k in range(waves):
        levels += amplitudes[k] * np.sin(space[k][None] - shift[:, k, None, None])
    if contrast_map is not None:
        levels *= np.asarray(contrast_map)[None]
    return times, levels


def crossings(times_us, levels, theta_on, theta_off, drift_per_s=0.0, step=(None, 1.0)):
    """Events of ideal pixels (thresholds (height, width) each) watching the polylines ``levels`` (n, h, w) through
    ``times_us``: an array of EVENT_FIELDS sorted by time (ties by pixel), each at its exact crossing time
    rounded to the microsecond. Every pixel's reference starts at its first level. ``drift_per_s``: every
    threshold is ``1 + drift_per_s * t`` times its value (t in seconds, taken at each step's end); ``step``
    (time us, factor): from that time on, times ``factor`` too."""
    n, height, width = levels.shape
    flat = levels.reshape(n, -1)
    on = np.broadcast_to(np.asarray(theta_on, np.float64), (height, width)).reshape(-1)
    off = np.broadcast_to(np.asarray(theta_off, np.float64), (height, width)).reshape(-1)
    reference = flat[0].copy()
    out_t, out_pixel, out_p = [], [], []
    base_on, base_off = on, off
    for i in range(1, n):
        if drift_per_s or step[0] is not None:
            factor = (1 + drift_per_s * times_us[i] * 1e-6) * (step[1] if step[0] is not None and times_us[i] >= step[0]
                                                                else 1.0)
            on, off = base_on * factor, base_off * factor
        l0, l1 = flat[i - 1], flat[i]
        slope_den = np.where(l1 != l0, l1 - l0, 1.0)
        while True:  # one level at a time: a step may cross several
            up = l1 >= reference + on
            down = l1 <= reference - off
            if not (up.any() or down.any()):
                break
            for mask, sign, theta, polarity in ((up, 1.0, on, True), (down, -1.0, off, False)):
                pixels = np.nonzero(mask)[0]
                if len(pixels) == 0:
                    continue
                reference[pixels] += sign * theta[pixels]
                fraction = (reference[pixels] - l0[pixels]) / slope_den[pixels]
                out_t.append(times_us[i - 1] + np.clip(fraction, 0.0, 1.0) * (times_us[i] - times_us[i - 1]))
                out_pixel.append(pixels)
                out_p.append(np.full(len(pixels), polarity))
    if not out_t:
        return np.zeros(0, EVENT_FIELDS)
    t = np.floor(np.concatenate(out_t) + 0.5).astype(np.int64)
    pixel = np.concatenate(out_pixel)
    events = np.zeros(len(t), EVENT_FIELDS)
    events["t"], events["x"], events["y"], events["p"] = t, pixel % width, pixel // width, np.concatenate(out_p)
    order = np.lexsort((pixel, t))  # stable within a pixel: a pixel's crossings are created in time order
    return events[order]


def smooth_field(width, height, scale_px, *, seed):
    """A smooth random field of unit standard deviation correlated over about ``scale_px`` pixels (a sum of
    random cosines of periods around ``4 scale_px``): a spatially correlated threshold mismatch."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    field = np.zeros((height, width))
    for _ in range(12):
        period = 4 * scale_px * rng.uniform(0.7, 1.4)
        angle = rng.uniform(0, 2 * np.pi)
        field += np.cos(2 * np.pi * (xs * np.cos(angle) + ys * np.sin(angle)) / period + rng.uniform(0, 2 * np.pi))
    return (field - field.mean()) / field.std()


def counts(events, width, height):
    """Per-pixel ON and OFF event counts: (2, height, width)."""
    out = np.zeros((2, height, width), np.int64)
    np.add.at(out, (events["p"].astype(int), events["y"].astype(int), events["x"].astype(int)), 1)
    return out


def count_error(events, ideal, width, height):
    """Per-pixel count error against the ideal sensor: sum over pixels and polarities of |n - n_ideal|, over the
    ideal's total."""
    a, b = counts(events, width, height), counts(ideal, width, height)
    return float(np.abs(a - b).sum() / max(b.sum(), 1))
