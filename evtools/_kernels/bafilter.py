"""Numba kernels of the background-activity filters (``docs/algorithms.md`` section 2) and of the
subsequence matching that ``metrics denoise`` uses.

The filter kernels read a chunk as its raw 16-byte records, viewed as ``words`` (n, 2) int64 (column 0 the time
in microseconds, column 1 x, y and p packed as EVENT_DTYPE lays them out: see :func:`unpack`), copy the records
they keep to ``out`` (same shape) and return how many they kept; the filter's state arrays are updated in place,
so that calling a kernel chunk after chunk gives the same result as one call on the whole stream. Copying whole
records while deciding saves a second pass over the chunk.

Time maps are padded by ``pad`` pixels on every side (:func:`padded_map`), holding :data:`NEVER` there, so the
neighbourhood loops need no bounds checks: a pad pixel never supports an event. :data:`NEVER` marks a pixel that
has not fired: ``t - NEVER`` is larger than any correlation window.
"""

from __future__ import annotations

import numpy as np

from evtools._kernels.jit import kernel
from evtools._kernels.prefetch import prefetch

AHEAD = 16
"""STCF prefetches the window rows of the event this many events ahead (its map rows are cache misses on large
sensors; measured in docs/performance.md)."""

NEVER = -(1 << 62)
"""Time-map value of "no event yet" ("long ago"): far enough that ``t - NEVER`` never overflows int64."""


def padded_map(width: int, height: int, pad: int, start: int) -> np.ndarray:
    """A (height + 2 pad, width + 2 pad) int64 time map: ``start`` on the sensor, :data:`NEVER` in the pad."""
    time_map = np.full((height + 2 * pad, width + 2 * pad), NEVER, dtype=np.int64)
    time_map[pad:pad + height, pad:pad + width] = start
    return time_map


@kernel(inline=True)
def unpack(word):
    """x, y, p of an event's second 8 bytes (x int16 at byte 8, y int16 at byte 10, p bool at byte 12)."""
    return word & 0xFFFF, (word >> 16) & 0xFFFF, ((word >> 32) & 0xFF) != 0


@kernel(inline=True)
def _keep(words, i, out, n, keep):
    """Copy record ``i`` to ``out[n]`` whether kept or not and return ``n + keep``: branch-free, because keep or
    reject is hard to predict (20 % faster on random events, measured with the bench's kernel rows)."""
    out[n, 0] = words[i, 0]
    out[n, 1] = words[i, 1]
    return n + keep


@kernel
def baf(words, time_map, dt_us, first_rejected, out):
    """BAF: keep an event when one of its 8 neighbours (not itself) fired less than ``dt_us`` before it.

    ``time_map`` is padded by 1 and gets every event's time, kept or not. ``first_rejected`` (jAER's
    letFirstEventThrough = false): an event at a pixel that never fired is rejected without a look around.
    """
    width = np.uint64(time_map.shape[1])  # (unsigned indices: numba adds no negative-index fix-up)
    flat = time_map.ravel()
    one = np.uint64(1)
    n = 0
    for i in range(words.shape[0]):
        ti = words[i, 0]
        x, y, _ = unpack(words[i, 1])
        c = (np.uint64(y) + one) * width + np.uint64(x) + one
        if first_rejected and flat[c] == NEVER:
            flat[c] = ti
            continue
        above = max(max(flat[c - width - one], flat[c - width]), flat[c - width + one])
        below = max(max(flat[c + width - one], flat[c + width]), flat[c + width + one])
        latest = max(max(above, below), max(flat[c - one], flat[c + one]))
        flat[c] = ti
        n = _keep(words, i, out, n, ti - latest < dt_us)
    return n


@kernel
def stcf(words, time_map, dt_us, radius, k, use_polarity, first_rejected, jaer_window, count_self, out):
    """STCF: keep an event when at least ``k`` pixels of its (2r+1)^2 window (itself excluded, unless
    ``count_self``: YNoise's event density, Feng et al. 2020) fired less than ``dt_us`` before it, with its
    polarity when ``use_polarity``.

    ``time_map`` is padded by ``radius`` and holds ``2 t + p`` of each pixel's last event (time and polarity in
    one word: one memory access per neighbour). ``jaer_window``: jAER's neighbourhood clipping, whose upper end
    is ``min(c + r, size - 1 - r)``, so the last ``r`` columns and rows never count as neighbours.
    ``first_rejected`` as in :func:`baf`.
    """
    padded_height, width = time_map.shape
    sensor_width = width - 2 * radius
    sensor_height = padded_height - 2 * radius
    flat = time_map.ravel()
    never = NEVER * 2
    n = 0
    end = words.shape[0]
    for i in range(end):
        if i + AHEAD < end:
            ahead = words[i + AHEAD, 1]
            centre = (((ahead >> 16) & 0xFFFF) + radius) * width + (ahead & 0xFFFF) + radius
            for dy in range(-radius, radius + 1):
                prefetch(flat, centre + dy * width)
        ti = words[i, 0]
        x, y, pi = unpack(words[i, 1])
        c = (y + radius) * width + x + radius
        stamp = 2 * ti + pi
        if first_rejected and flat[c] == never:
            flat[c] = stamp
            continue
        bound = 2 * (ti - dt_us) + 1  # 2 T + p > bound  <=>  T > ti - dt_us, i.e. t - T < dt_us
        dx1 = radius
        dy1 = radius
        if jaer_window:
            dx1 = min(radius, sensor_width - 1 - radius - x)
            dy1 = min(radius, sensor_height - 1 - radius - y)
        count = 0  # branch-free: polarities are random, so a branch per neighbour would mispredict
        columns = np.uint64(radius + dx1 + 1)  # (unsigned indices: numba adds no negative-index fix-up)
        for dy in range(-radius, dy1 + 1):
            row = np.uint64(c + dy * width - radius)
            if use_polarity:
                for dx in range(columns):
                    v = flat[row + dx]
                    count += (v > bound) & ((v & 1) == pi)
            else:
                for dx in range(columns):
                    count += flat[row + dx] > bound
        if dx1 >= 0 and dy1 >= 0 and not count_self:  # the window holds the pixel itself: take it out
            v = flat[c]
            count -= (v > bound) & (not use_polarity or (v & 1) == pi)
        flat[c] = stamp
        n = _keep(words, i, out, n, count >= k)
    return n


@kernel
def stcf_polarity_maps(words, maps, dt_us, radius, k, out):
    """STCF with a time map per polarity (``maps``: (2, height + 2 r, width + 2 r), ON then OFF, padded by
    ``radius``): keep an event when at least ``k`` pixels of its window (itself excluded) had an event of its
    polarity less than ``dt_us`` before it, whatever the other polarity did since."""
    width = maps.shape[2]
    cells = maps.shape[1] * width
    flat = maps.ravel()
    n = 0
    for i in range(words.shape[0]):
        ti = words[i, 0]
        x, y, pi = unpack(words[i, 1])
        c = (0 if pi else cells) + (y + radius) * width + x + radius
        count = 0
        for dy in range(-radius, radius + 1):
            row = np.uint64(c + dy * width - radius)  # (unsigned: no negative-index fix-up)
            for dx in range(np.uint64(2 * radius + 1)):
                count += ti - flat[row + dx] < dt_us
        count -= ti - flat[c] < dt_us
        flat[c] = ti
        n = _keep(words, i, out, n, count >= k)
    return n


@kernel
def dwf(words, kept_xy, rejected_xy, counters, distance, k, out):
    """DWF (Guo & Delbruck 2022): keep an event when at least ``k`` of the stored events lie at L1 distance
    ``< distance``; push it into the FIFO of kept events or of rejected ones.

    ``kept_xy``, ``rejected_xy``: (L, 2) int32 rings; ``counters`` int64: kept count, kept next slot, rejected
    count, rejected next slot, start-up events left (rejected; the first L of them fill the kept window, as
    jAER does).
    """
    size = kept_xy.shape[0]
    n = 0
    for i in range(words.shape[0]):
        xi, yi, _ = unpack(words[i, 1])
        if counters[4] > 0:
            counters[4] -= 1
            if counters[0] < size:
                kept_xy[counters[1], 0] = xi
                kept_xy[counters[1], 1] = yi
                counters[0] += 1
                counters[1] = (counters[1] + 1) % size
            continue
        count = 0
        for j in range(counters[0]):
            if abs(xi - kept_xy[j, 0]) + abs(yi - kept_xy[j, 1]) < distance:
                count += 1
                if count >= k:
                    break
        if count < k:
            for j in range(counters[2]):
                if abs(xi - rejected_xy[j, 0]) + abs(yi - rejected_xy[j, 1]) < distance:
                    count += 1
                    if count >= k:
                        break
        if count >= k:
            n = _keep(words, i, out, n, True)
            slot = counters[1]
            kept_xy[slot, 0] = xi
            kept_xy[slot, 1] = yi
            counters[1] = (slot + 1) % size
            if counters[0] < size:
                counters[0] += 1
        else:
            slot = counters[3]
            rejected_xy[slot, 0] = xi
            rejected_xy[slot, 1] = yi
            counters[3] = (slot + 1) % size
            if counters[2] < size:
                counters[2] += 1
    return n


@kernel
def order_n(words, row_t, row_x, col_t, col_y, dt_us, self_counts, jaer_edges, out):
    """Khodamoradi & Kastner's O(W + H) filter: one memory per row (last time, its x) and per column (last time,
    its y); keep an event when an adjacent row (y-1..y+1) last fired less than ``dt_us`` ago at x-1..x+1, or an
    adjacent column at y-1..y+1. Every event is then stored in its row and column.

    ``self_counts``: a memory holding this very pixel counts too (jAER). ``jaer_edges``: events on the sensor's
    border are rejected and not stored (jAER), else the adjacent rows and columns are clipped to the sensor.
    """
    height = row_t.shape[0]
    width = col_t.shape[0]
    n = 0
    for i in range(words.shape[0]):
        ti = words[i, 0]
        xi, yi, _ = unpack(words[i, 1])
        if jaer_edges and (xi <= 0 or yi <= 0 or xi >= width - 1 or yi >= height - 1):
            continue
        bound = ti - dt_us
        found = False
        for yy in range(max(yi - 1, 0), min(yi + 1, height - 1) + 1):
            if row_t[yy] > bound and abs(row_x[yy] - xi) <= 1 and (self_counts or yy != yi or row_x[yy] != xi):
                found = True
                break
        if not found:
            for xx in range(max(xi - 1, 0), min(xi + 1, width - 1) + 1):
                if col_t[xx] > bound and abs(col_y[xx] - yi) <= 1 and (self_counts or xx != xi or col_y[xx] != yi):
                    found = True
                    break
        n = _keep(words, i, out, n, found)
        row_t[yi] = ti
        row_x[yi] = xi
        col_t[xi] = ti
        col_y[xi] = yi
    return n


@kernel
def refractory(words, time_map, dt_us, inclusive, out):
    """Drop an event less than ``dt_us`` after the same pixel's previous event (``<= dt_us`` when ``inclusive``,
    jAER); the previous event may itself have been dropped: every event writes its time. ``time_map`` unpadded."""
    width = time_map.shape[1]
    flat = time_map.ravel()
    n = 0
    for i in range(words.shape[0]):
        ti = words[i, 0]
        x, y, _ = unpack(words[i, 1])
        c = y * width + x
        delta = ti - flat[c]
        flat[c] = ti
        n = _keep(words, i, out, n, (delta > dt_us) if inclusive else (delta >= dt_us))
    return n


@kernel
def hot_pixels(words, hot_map, out):
    """Drop the events of the pixels marked in ``hot_map`` (height, width) bool."""
    width = hot_map.shape[1]
    flat = hot_map.ravel()
    n = 0
    for i in range(words.shape[0]):
        x, y, _ = unpack(words[i, 1])
        n = _keep(words, i, out, n, not flat[y * width + x])
    return n


@kernel
def match_subsequence(t, x, y, p, labels, start, ft, fx, fy, fp, fstart, kept_per_label):
    """Match filtered events (``ft..fp`` from ``fstart``) to the input events (``t..p`` from ``start``) in order.

    Each filtered event is matched to the first input event at or after the current position with the same
    (t, x, y, p); ``kept_per_label[labels[i]]`` counts the matched input events. Returns ``(i, j, ok)``: where
    the scan stopped in the input and in the filtered events (one of them is exhausted, or not ``ok``: the
    filtered event ``j`` is earlier than input event ``i``, so it is in no input).
    """
    i = start
    j = fstart
    n = len(t)
    m = len(ft)
    while i < n and j < m:
        tj = ft[j]
        ti = t[i]
        if ti == tj and x[i] == fx[j] and y[i] == fy[j] and p[i] == fp[j]:
            kept_per_label[labels[i]] += 1
            j += 1
        elif ti > tj:
            return i, j, False
        i += 1
    return i, j, True
