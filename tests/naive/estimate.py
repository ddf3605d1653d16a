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


def naive_stimulus_level(t_us, x, low, high, period_us, wavelength_px=0.0, profile="intensity", rise=0.5):
    """L at time t of column x: a triangle of phase t/period - (x + 0.5)/wavelength, 0 at phase 0, 1 at ``rise``.

    A whole number of microseconds per period: t is reduced modulo the period first (as the kernel does).
    ``profile`` log: low and high are log levels already."""
    if period_us == int(period_us):
        t_us = t_us % int(period_us)
    phase = t_us / period_us - ((x + 0.5) / wavelength_px if wavelength_px > 0 else 0.0)
    phase -= math.floor(phase)
    tri = phase / rise if phase < rise else (1 - phase) / (1 - rise)
    if profile == "log":
        return low + (high - low) * tri
    return naive_lin_log(low + (high - low) * tri)


def naive_stimulus(events, width, height, low, high, period_us, wavelength_px=0.0, profile="intensity", rise=0.5):
    """Per pixel: lists of the ON changes and OFF changes (positive) of L between consecutive events."""
    last = {}
    changes = {}
    for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        level = naive_stimulus_level(t, x, low, high, period_us, wavelength_px, profile, rise)
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


def naive_fit(events, width, height, low, high, period_us, wavelength_px=0.0, profile="intensity", rise=0.5,
              seed_pairs=5, accept=(0.8, 1.25)):
    """{(x, y): fit}: the RMS over every change between a pixel's consecutive events of ``change / threshold - 1``
    (signed by the event's polarity), where a change outside the acceptance window around the reference (the
    median of the polarity's first ``seed_pairs`` right-signed changes) or of the wrong sign counts 1."""
    changes = naive_stimulus(events, width, height, low, high, period_us, wavelength_px, profile, rise)
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


RING = 32


def _wave(phases, low, high, rise, profile):
    """numpy: L at ``phases`` (any shape, period 1) of the triangle low at 0, high at ``rise``."""
    u = phases - np.floor(phases)
    tri = np.where(u < rise, u / rise, (1 - u) / (1 - rise))
    level = low + (high - low) * tri
    if profile == "log":
        return level
    return np.where(level <= 20.0, level * math.log(20.0) / 20.0, np.log(np.maximum(level, 20.0)))


def _phase_costs(valleys, times, ons, low, high, period_us, rise, profile):
    """For every candidate valley time: per level change between consecutive events (change / threshold - 1)^2,
    or 1 outside [0.8, 1.25] x threshold or of the wrong sign, summed. A polarity's threshold: the mean of the
    within-ramp changes (the previous event of the same polarity) within [0.8, 1.25] x their plain mean."""
    levels = _wave((times[None, :] - valleys[:, None]) / period_us, low, high, rise, profile)
    changes = np.diff(levels, axis=1) * np.where(ons[1:], 1.0, -1.0)
    within_ramp = ons[1:] == ons[:-1]
    cost = np.zeros(len(valleys))
    for polarity in (True, False):
        mine = ons[1:] == polarity
        ramp = mine & within_ramp & (changes > 0)
        with np.errstate(all="ignore"):
            plain = np.where(ramp, changes, 0.0).sum(axis=1) / ramp.sum(axis=1)
        plain = np.where(ramp.any(axis=1), plain, 1.0)
        inside = ramp & (changes >= 0.8 * plain[:, None]) & (changes <= 1.25 * plain[:, None])
        with np.errstate(all="ignore"):
            trimmed = np.where(inside, changes, 0.0).sum(axis=1) / inside.sum(axis=1)
        threshold = np.where(inside.any(axis=1), trimmed, plain)
        deviation = changes / threshold[:, None] - 1.0
        fits = (deviation >= -0.2) & (deviation <= 0.25)
        cost += np.where(mine, np.where(fits, deviation**2, 1.0), 0.0).sum(axis=1)
    return cost


def naive_fitted_phase(times_us, ons, low, high, period_us, rise=0.5, profile="log"):
    """The valley time (us, modulo the period) that best fits a pixel's events, by brute force: the cost on
    200,000 phases over the whole period, then 20,000 over the two grid steps around the best."""
    times = np.asarray(times_us, dtype=np.float64)
    origin = times[0]
    times = times - origin
    ons = np.asarray(ons, dtype=bool)
    grid = np.linspace(0.0, period_us, 200_000, endpoint=False)
    best = grid[np.argmin(_phase_costs(grid, times, ons, low, high, period_us, rise, profile))]
    step = period_us / 200_000
    fine = np.linspace(best - step, best + step, 20_001)
    best = fine[np.argmin(_phase_costs(fine, times, ons, low, high, period_us, rise, profile))]
    return (origin + best) % period_us


def naive_fitted_stimulus(events, low, high, period_us, rise=0.5, profile="log"):
    """{(x, y): (valley_us, on changes, off changes)}: each pixel's phase fitted to the first 32 of its events
    that show both a valley (OFF then ON) and a peak (ON then OFF), or to its last 32 events when none do, and
    the level changes within a ramp (between two events of one polarity) of those events and every later one."""
    per_pixel = {}
    for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        per_pixel.setdefault((x, y), []).append((t, p))
    results = {}
    for pixel, pixel_events in per_pixel.items():
        if len(pixel_events) < 2:
            continue
        start = max(0, len(pixel_events) - RING)
        for end in range(RING, len(pixel_events) + 1):
            window = [p for _, p in pixel_events[end - RING:end]]
            pairs = list(zip(window, window[1:]))
            if (False, True) in pairs and (True, False) in pairs:
                start = end - RING
                break
        ring = pixel_events[start:start + RING]
        valley = naive_fitted_phase([t for t, _ in ring], [p for _, p in ring], low, high, period_us, rise, profile)
        used = pixel_events[start:]
        levels = _wave((np.array([t for t, _ in used], dtype=float) - valley) / period_us, low, high, rise, profile)
        on, off = [], []
        for (_, previous), (_, p), change in zip(used, used[1:], np.diff(levels)):
            if p != previous:  # only changes within a ramp are counted
                continue
            if p and change > 0:
                on.append(float(change))
            elif not p and change < 0:
                off.append(float(-change))
        results[pixel] = (valley, on, off)
    return results


def naive_natural(events, width, height, nominal=0.2, radius_px=3, min_events=10, block_us=100_000):
    """(on, off, usable) by the natural-scene method, pixel by pixel in plain Python: per pixel the ON and OFF
    events and polarity reversals of the whole stream; b = reversals / 4; (u_on, u_off) solves
    u_on (N_on + b) + u_off b = 1 and u_off (N_off + b) + u_on b = 1; a pixel with at least ``min_events`` of
    each polarity is usable; its thresholds are nominal * 2 u / (the mean of u_on + u_off over the usable pixels
    within ``radius_px`` of it, itself left out)."""
    n_on = {}
    n_off = {}
    reversals = {}
    last = {}
    for x, y, p in zip(events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        key = (x, y)
        if p:
            n_on[key] = n_on.get(key, 0) + 1
        else:
            n_off[key] = n_off.get(key, 0) + 1
        if key in last and last[key] != p:
            reversals[key] = reversals.get(key, 0) + 1
        last[key] = p
    u = {}
    for key in last:
        a, d = n_on.get(key, 0), n_off.get(key, 0)
        if a >= min_events and d >= min_events:
            b = reversals.get(key, 0) / 4
            # Cramer's rule on [[a + b, b], [b, d + b]] u = (1, 1)
            det = (a + b) * (d + b) - b * b
            u[key] = ((d + b - b) / det, (a + b - b) / det)
    on = np.full((height, width), np.nan)
    off = np.full((height, width), np.nan)
    for (x, y), (u_on, u_off) in u.items():
        around = [sum(u[(i, j)]) for i in range(x - radius_px, x + radius_px + 1)
                  for j in range(y - radius_px, y + radius_px + 1) if (i, j) != (x, y) and (i, j) in u]
        if len(around) >= 8:
            mean = sum(around) / len(around)
            on[y, x] = nominal * 2 * u_on / mean
            off[y, x] = nominal * 2 * u_off / mean
    return on, off, np.isfinite(on)


def naive_polarity_counts(events, width: int, height: int) -> dict:
    """{(x, y): [on count, off count]} of ``events``, in plain Python."""
    counts: dict = {}
    for x, y, p in zip(events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        counts.setdefault((x, y), [0, 0])[0 if p else 1] += 1
    return counts


def naive_frame_sums(image, x0, y0, width, counts, fired, black, log_exposure, max_events, min_signal,
                     saturated_dn, sums, half, sample_step, inverse_sums, new_counts, last_state, saturated,
                     weight=1.0, sampled_only=False) -> None:
    """The frames method's sums for one frame, pixel by pixel in plain Python (see
    ``evtools._kernels.estimate.frame_sums``), every sum added at every frame: a pixel of the frame (``image``, its
    corner at ``x0, y0``) counts in ``saturated`` when it is; a usable one (at most ``max_events`` events in its
    exposure: ``fired[i]``, not saturated, at least ``min_signal`` above black) adds (1, A, -B, y, A^2, B^2, -AB,
    Ay, -By, y^2) to ``sums``, with A, B its ``counts`` at the exposure's middle, and 1 / (DN - black) to
    ``inverse_sums``; with ``sample_step``, every such pixel also to ``half[side]`` by its level against its mean
    so far, and with ``sampled_only`` no other pixel adds anything. The frame weighs ``weight`` in ``sums``,
    ``inverse_sums`` and ``new_counts`` (1 in ``half``)."""
    for row in range(image.shape[0]):
        for column in range(image.shape[1]):
            i = (y0 + row) * width + x0 + column
            if sampled_only and i % sample_step != 0:
                continue
            dn = float(image[row][column])
            saturated[i] += dn >= saturated_dn
            if fired[i] > max_events or dn >= saturated_dn or dn - black < min_signal:
                continue
            y = math.log(dn - black) - log_exposure
            a, b = float(counts[i][0]), -float(counts[i][1])
            row_of_sums = [1.0, a, b, y, a * a, b * b, a * b, a * y, b * y, y * y]
            if sample_step and i % sample_step == 0:
                mean_level = (sums[1][i] + sums[2][i]) / max(sums[0][i], 1.0)
                side = 1 if a + b > mean_level else 0
                for r in range(10):
                    half[side][r][i // sample_step] += row_of_sums[r]
            for r in range(10):
                sums[r][i] += weight * row_of_sums[r]
            inverse_sums[i] += weight / (dn - black)
            state = int(counts[i][0]) + int(counts[i][1])
            if state != last_state[i]:
                new_counts[i] += weight
                last_state[i] = state


def naive_count_times(events, origin_us: int) -> dict:
    """{(x, y): [sum of ON event times, sum of OFF event times]} of ``events`` (seconds after ``origin_us``), in
    plain Python."""
    times: dict = {}
    for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        times.setdefault((x, y), [0.0, 0.0])[0 if p else 1] += (t - origin_us) / 1e6
    return times


def naive_frame_time_sums(image, x0, y0, width, counts, times, fired, black, max_events, min_signal, saturated_dn,
                          time_sums, weight=1.0, only_every=0) -> None:
    """onEI's event-time sums for one frame, pixel by pixel in plain Python (see
    ``evtools._kernels.estimate.frame_sums`` with time sums): a usable pixel (as :func:`naive_frame_sums` has it) adds
    (z_on, A z_on, -B z_on, z_off, A z_off, -B z_off), with z its event-time sums and A, B its counts; with
    ``only_every``, only every such pixel (by index)."""
    for row in range(image.shape[0]):
        for column in range(image.shape[1]):
            i = (y0 + row) * width + x0 + column
            if only_every and i % only_every != 0:
                continue
            dn = float(image[row][column])
            if fired[i] > max_events or dn >= saturated_dn or dn - black < min_signal:
                continue
            a, b = float(counts[i][0]), -float(counts[i][1])
            z_on, z_off = float(times[i][0]), float(times[i][1])
            for r, value in enumerate((z_on, a * z_on, b * z_on, z_off, a * z_off, b * z_off)):
                time_sums[r][i] += weight * value


def neighbour_ages_naive(events, width, height, stride=1, bins=64):
    """Per event of every ``stride``-th (by its index in the stream), the time since the latest earlier event (in stream order) at one of its 8 neighbours, counted by
    floor(log2(age)) (0 for an age of 0; at most bins - 2), the last bin for an event none of whose neighbours has
    fired; and those events per pixel. Looks back through the whole stream for each event."""
    ages = [0] * bins
    per_pixel = [0] * (width * height)
    for i, (t, x, y) in enumerate(zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist())):
        if i % stride:
            continue
        per_pixel[y * width + x] += 1
        latest = None
        for j in range(i - 1, -1, -1):
            dx, dy = events["x"][j] - x, events["y"][j] - y
            if max(abs(dx), abs(dy)) == 1:
                latest = int(events["t"][j])
                break
        if latest is None:
            ages[bins - 1] += 1
            continue
        age = t - latest
        k = 0
        while k < bins - 2 and 2 ** (k + 1) <= age:
            k += 1
        ages[k] += 1
    return ages, per_pixel
