"""Slow, obviously correct references of the threshold-estimation kernels (evtools/_kernels/estimate.py).

offE is done the way ``EventOnlyCalib.m`` and ``GenSumESumP.m`` do it: store every pixel's cumulative (E, P) at
every segment boundary, then fit each pixel's line by ``numpy.linalg.lstsq`` and take the RMS residual.
"""

from __future__ import annotations

import math

import numpy as np


def naive_offe(events, width, height, segment_us, nominal=0.2, min_events=10):
    """(on, off, valid, slope, rms) maps by the reference's steps, with a stored (K, pixels) sample table."""
    n = width * height
    cum_e, cum_p = [0] * n, [0] * n
    samples_e, samples_p = [], []
    origin = int(events["t"][0])
    boundary = origin + segment_us
    for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        while t >= boundary:  # one snapshot per boundary passed
            samples_e.append(list(cum_e))
            samples_p.append(list(cum_p))
            boundary += segment_us
        i = y * width + x
        cum_e[i] += 1
        cum_p[i] += 1 if p else -1
    samples_e.append(list(cum_e))  # the last, partial segment
    samples_p.append(list(cum_p))
    E = np.array(samples_e, dtype=np.float64)
    P = np.array(samples_p, dtype=np.float64)
    k = E.shape[0]
    slope, rms = np.zeros(n), np.full(n, np.nan)
    for i in range(n):
        A = np.stack([E[:, i], np.ones(k)], axis=1)
        normal = A.T @ A
        if np.linalg.cond(normal, 1) > 1e14 or not np.isfinite(np.linalg.cond(normal, 1)):
            continue
        (m, d), *_ = np.linalg.lstsq(A, P[:, i], rcond=None)
        slope[i] = m
        rms[i] = math.sqrt(np.mean((P[:, i] - (m * E[:, i] + d)) ** 2))
    total = E[-1]
    valid = np.isfinite(rms) & (rms > 0) & (total >= min_events)
    c = np.full(n, np.nan)
    c[valid] = np.median(nominal * rms[valid]) / rms[valid]
    valid &= c <= 10 * nominal
    b = -c * slope
    shape = (height, width)
    return (c + b).reshape(shape), (c - b).reshape(shape), valid.reshape(shape), slope.reshape(shape), rms.reshape(shape)


def naive_lin_log(intensity):
    return intensity * math.log(20.0) / 20.0 if intensity <= 20.0 else math.log(intensity)


def naive_stimulus_level(t_us, x, low, high, period_us, wavelength_px=0.0, profile="intensity"):
    """L at time t of column x: a triangle of phase t/period - (x + 0.5)/wavelength, 0 at phase 0, 1 at 1/2.

    A whole number of microseconds per period: t is reduced modulo the period first (as the kernel does).
    ``profile`` log: low and high are log levels already."""
    if period_us == int(period_us):
        t_us = t_us % int(period_us)
    phase = t_us / period_us - ((x + 0.5) / wavelength_px if wavelength_px > 0 else 0.0)
    phase -= math.floor(phase)
    tri = 2 * phase if phase < 0.5 else 2 - 2 * phase
    if profile == "log":
        return low + (high - low) * tri
    return naive_lin_log(low + (high - low) * tri)


def naive_stimulus(events, width, height, low, high, period_us, wavelength_px=0.0, profile="intensity"):
    """Per pixel: lists of the ON changes and OFF changes (positive) of L between consecutive events."""
    last = {}
    changes = {}
    for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        level = naive_stimulus_level(t, x, low, high, period_us, wavelength_px, profile)
        if (x, y) in last:
            change = level - last[(x, y)]
            on, off = changes.setdefault((x, y), ([], []))
            if p and change > 0:
                on.append(change)
            elif not p and change < 0:
                off.append(-change)
        last[(x, y)] = level
    return changes


def robust_mean(changes, seed_pairs=5, low=0.8, high=1.25):
    """The stimulus method's per-pixel value from one polarity's changes: the median of the first ``seed_pairs``
    is the reference; the mean of the changes within [low, high] x reference (fewer than ``seed_pairs``: their
    median)."""
    if len(changes) < seed_pairs:
        return float(np.median(changes))
    reference = float(np.median(changes[:seed_pairs]))
    kept = [c for c in changes if low * reference <= c <= high * reference]
    return float(np.mean(kept))


def naive_fit(events, width, height, low, high, period_us, wavelength_px=0.0, profile="intensity", seed_pairs=5,
              accept=(0.8, 1.25)):
    """{(x, y): fit}: the RMS over every change between a pixel's consecutive events of ``change / threshold - 1``
    (signed by the event's polarity), where a change outside the acceptance window around the reference (the
    median of the polarity's first ``seed_pairs`` right-signed changes) or of the wrong sign counts 1."""
    changes = naive_stimulus(events, width, height, low, high, period_us, wavelength_px, profile)
    total = {}
    last = {}
    for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        if (x, y) in last:
            on_off = total.setdefault((x, y), [0, 0])
            on_off[0 if p else 1] += 1
        last[(x, y)] = True
    fits = {}
    for pixel, counts in total.items():
        misfit = 0.0
        for polarity, kept in enumerate(changes.get(pixel, ([], []))):
            if not kept:
                misfit += counts[polarity]
                continue
            threshold = robust_mean(kept, seed_pairs, *accept)
            if len(kept) < seed_pairs:
                inside = kept
            else:
                reference = float(np.median(kept[:seed_pairs]))
                inside = [c for c in kept if accept[0] * reference <= c <= accept[1] * reference]
            misfit += sum((c / threshold - 1.0) ** 2 for c in inside) + (counts[polarity] - len(inside))
        fits[pixel] = math.sqrt(misfit / sum(counts))
    return fits
