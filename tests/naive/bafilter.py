"""Slow references of the background-activity filters (evtools/_kernels/bafilter.py), one event at a time.

Each takes a list of ``(t, x, y, p)`` tuples and returns the list of booleans "kept", written from the method's
description (docs/algorithms.md section 2) with dictionaries for the state: a missing key is a pixel that never fired.
"""

from __future__ import annotations

DV_START = 0  # dv-processing's time map starts at 0


def naive_baf(events, width, height, dt_us, preset="evtools"):
    last = {}  # (x, y) -> time of the pixel's last event
    if preset == "dv":
        last = {(x, y): DV_START for x in range(width) for y in range(height)}
    kept = []
    for t, x, y, p in events:
        if preset == "jaer" and (x, y) not in last:
            kept.append(False)
        else:
            neighbours = [(x + dx, y + dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if (dx, dy) != (0, 0)]
            kept.append(any(n in last and t - last[n] < dt_us for n in neighbours))
        last[(x, y)] = t
    return kept


def naive_stcf(events, width, height, dt_us, k, radius, polarity, preset="evtools"):
    last = {}  # (x, y) -> (time, polarity)
    kept = []
    for t, x, y, p in events:
        if preset == "jaer" and (x, y) not in last:
            kept.append(False)
        else:
            count = 0
            for nx in range(x - radius, x + radius + 1):
                for ny in range(y - radius, y + radius + 1):
                    if (nx, ny) == (x, y) or (nx, ny) not in last:
                        continue
                    if preset == "jaer" and (nx > width - 1 - radius or ny > height - 1 - radius):
                        continue  # jAER's NnbRange never reaches the last r columns and rows
                    nt, np_ = last[(nx, ny)]
                    if t - nt < dt_us and (not polarity or np_ == p):
                        count += 1
            kept.append(count >= k)
        last[(x, y)] = (t, p)
    return kept


def naive_dwf(events, window, distance, k, preset="evtools"):
    kept_window, rejected_window = [], []  # oldest first
    startup = 0
    if preset == "jaer":
        rejected_window = [(-1, -1)] * window
        startup = 2 * window
    kept = []
    for t, x, y, p in events:
        if startup:
            startup -= 1
            kept.append(False)
            if len(kept_window) < window:
                kept_window.append((x, y))
            continue
        support = sum(abs(x - sx) + abs(y - sy) < distance for sx, sy in kept_window + rejected_window)
        target = kept_window if support >= k else rejected_window
        kept.append(support >= k)
        target.append((x, y))
        if len(target) > window:
            target.pop(0)
    return kept


def naive_order_n(events, width, height, dt_us, preset="evtools"):
    rows, cols = {}, {}  # y -> (t, x); x -> (t, y)
    jaer = preset == "jaer"
    kept = []
    for t, x, y, p in events:
        if jaer and (x == 0 or y == 0 or x == width - 1 or y == height - 1):
            kept.append(False)
            continue
        ok = False
        for ny in (y - 1, y, y + 1):
            if ny in rows:
                rt, rx = rows[ny]
                if t - rt < dt_us and abs(rx - x) <= 1 and (jaer or (rx, ny) != (x, y)):
                    ok = True
        for nx in (x - 1, x, x + 1):
            if nx in cols:
                ct, cy = cols[nx]
                if t - ct < dt_us and abs(cy - y) <= 1 and (jaer or (nx, cy) != (x, y)):
                    ok = True
        kept.append(ok)
        rows[y] = (t, x)
        cols[x] = (t, y)
    return kept


def naive_refractory(events, dt_us, preset="evtools"):
    last = {}
    kept = []
    for t, x, y, p in events:
        if (x, y) not in last:
            kept.append(True)
        elif preset == "jaer":
            kept.append(t - last[(x, y)] > dt_us)
        else:
            kept.append(t - last[(x, y)] >= dt_us)
        last[(x, y)] = t
    return kept


def naive_hot_pixels(events, width, height, learn_us, hot_ratio, hot_min_events, hot_rate_hz):
    """Count each pixel over [t0, t0 + learn_us) (the whole stream when shorter), mark the hot ones, drop them."""
    if not events:
        return []
    t0 = events[0][0]
    learned = [e for e in events if e[0] < t0 + learn_us]
    duration_us = learn_us if len(learned) < len(events) else learned[-1][0] - t0 + 1
    counts = {}
    for t, x, y, p in learned:
        counts[(x, y)] = counts.get((x, y), 0) + 1
    hot = set()
    for (x, y), n in counts.items():
        neighbours = max(counts.get(q, 0) for q in ((x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)))
        alone = width * height == 1  # (no neighbour to compare with: the absolute test only)
        if n >= hot_min_events and (n >= hot_rate_hz * duration_us * 1e-6 or (not alone and n >= hot_ratio * neighbours)):
            hot.add((x, y))
    return [(x, y) not in hot for t, x, y, p in events]


def naive_mlpf_features(events, patch, tau_us, tau_scale=0.0, pixels=1):
    """Per event: the ON then OFF time-surface patch (1 - age / tau, 0 when never or tau or more ago) row by row,
    then the polarity (1 ON, 0 OFF); the patch includes the pixel itself. tau is ``tau_us``, or with
    ``tau_scale`` > 0 that times ``pixels`` times the mean interval between events so far (a plain mean over the
    first ``pixels`` intervals, then m += (interval - m) / pixels), in whole microseconds, 1 to 2^62."""
    r = patch // 2
    last = ({}, {})  # ON, OFF: (x, y) -> time of the pixel's last event of that polarity
    rows = []
    mean_interval, previous = 0.0, None
    for index, (t, x, y, p) in enumerate(events):
        tau = tau_us
        if tau_scale > 0:
            if previous is not None:
                mean_interval += ((t - previous) - mean_interval) / min(index, pixels)
            previous = t
            tau = max(1, int(min(tau_scale * pixels * mean_interval, 2.0 ** 62)))
        row = []
        for polarity_map in last:
            for ny in range(y - r, y + r + 1):
                for nx in range(x - r, x + r + 1):
                    seen = polarity_map.get((nx, ny))
                    row.append(0.0 if seen is None or t - seen >= tau else 1.0 - (t - seen) / tau)
        row.append(1.0 if p else 0.0)
        rows.append(row)
        last[0 if p else 1][(x, y)] = t
    return rows


def naive_mlpf(events, w1, b1, w2, b2, patch, tau_us, threshold, tau_scale=0.0, pixels=1):
    """Kept or not per event: sigmoid(w2 . relu(w1^T f + b1) + b2) > threshold, one dot product at a time."""
    import math

    kept, probabilities = [], []
    for row in naive_mlpf_features(events, patch, tau_us, tau_scale, pixels):
        hidden = [max(0.0, b1[j] + sum(row[i] * w1[i][j] for i in range(len(row)))) for j in range(len(b1))]
        z = b2 + sum(h * w for h, w in zip(hidden, w2))
        probability = 1.0 / (1.0 + math.exp(-z))
        probabilities.append(probability)
        kept.append(probability > threshold)
    return kept, probabilities


def naive_stcf_polarity_maps(events, dt_us, k, radius):
    """STCF counting, in the window around the event (itself excluded), the pixels whose last event of the event's
    own polarity is less than dt_us old, whatever the other polarity did since."""
    last = ({}, {})  # OFF, ON: (x, y) -> time of the pixel's last event of that polarity
    kept = []
    for t, x, y, p in events:
        same = last[1 if p else 0]
        count = sum(1 for nx in range(x - radius, x + radius + 1) for ny in range(y - radius, y + radius + 1)
                    if (nx, ny) != (x, y) and (nx, ny) in same and t - same[(nx, ny)] < dt_us)
        kept.append(count >= k)
        same[(x, y)] = t
    return kept


def naive_ynoise(events, dt_us, radius, k):
    """YNoise (Feng et al. 2020): the window's pixels (the event's own included) whose last event has its polarity
    and is less than ``dt_us`` old; kept when at least ``k``."""
    last = {}  # (x, y) -> (time, polarity)
    kept = []
    for t, x, y, p in events:
        density = sum(1 for nx in range(x - radius, x + radius + 1) for ny in range(y - radius, y + radius + 1)
                      if (nx, ny) in last and last[(nx, ny)][1] == p and t - last[(nx, ny)][0] < dt_us)
        kept.append(density >= k)
        last[(x, y)] = (t, p)
    return kept
