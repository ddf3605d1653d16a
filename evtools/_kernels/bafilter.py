"""Numba kernels of the background-activity filters (``../shared/ALGORITHMS.md`` section 2) and of the
subsequence matching that ``metrics denoise`` uses.

Each filter kernel takes one chunk's columns and the filter's state arrays, writes one boolean per event into
``keep`` and updates the state in place, so that calling it chunk after chunk gives the same result as one call
on the whole stream. Times are int64 microseconds; :data:`NEVER` marks a pixel (row, column) that has not fired:
``t - NEVER`` is larger than any correlation window, so it never supports an event.
"""

from __future__ import annotations

import numpy as np
from numba import njit

NEVER = -(1 << 62)
"""Time-map value of "no event yet" ("long ago"): far enough that ``t - NEVER`` never overflows int64."""


@njit(cache=True, nogil=True)
def baf(t, x, y, time_map, dt_us, first_rejected, keep):
    """BAF: keep an event when one of its 8 neighbours (not itself) fired less than ``dt_us`` before it.

    ``time_map`` (height, width) int64 gets every event's time, kept or not. ``first_rejected`` (jAER's
    letFirstEventThrough = false): an event at a pixel that never fired is rejected without a look around.
    """
    height, width = time_map.shape
    for i in range(len(t)):
        ti = t[i]
        xi = np.int64(x[i])
        yi = np.int64(y[i])
        if first_rejected and time_map[yi, xi] == NEVER:
            time_map[yi, xi] = ti
            keep[i] = False
            continue
        bound = ti - dt_us  # supported by a neighbour with time > bound, i.e. t - T < dt_us
        x0 = xi - 1 if xi > 0 else xi
        x1 = xi + 1 if xi < width - 1 else xi
        y0 = yi - 1 if yi > 0 else yi
        y1 = yi + 1 if yi < height - 1 else yi
        found = False
        for yy in range(y0, y1 + 1):
            row = time_map[yy]
            for xx in range(x0, x1 + 1):
                if row[xx] > bound and (xx != xi or yy != yi):
                    found = True
                    break
            if found:
                break
        keep[i] = found
        time_map[yi, xi] = ti


@njit(cache=True, nogil=True)
def stcf(t, x, y, p, time_map, polarity_map, dt_us, radius, k, use_polarity, first_rejected, jaer_window, keep):
    """STCF: keep an event when at least ``k`` pixels of its (2r+1)^2 window (itself excluded) fired less than
    ``dt_us`` before it, with its polarity when ``use_polarity``.

    ``jaer_window``: jAER's neighbourhood clipping, whose upper end is ``min(c + r, size - 1 - r)``, so the last
    ``r`` columns and rows never count as neighbours. ``first_rejected`` as in :func:`baf`.
    """
    height, width = time_map.shape
    for i in range(len(t)):
        ti = t[i]
        xi = np.int64(x[i])
        yi = np.int64(y[i])
        pi = p[i]
        if first_rejected and time_map[yi, xi] == NEVER:
            time_map[yi, xi] = ti
            polarity_map[yi, xi] = pi
            keep[i] = False
            continue
        bound = ti - dt_us
        x0 = max(xi - radius, 0)
        y0 = max(yi - radius, 0)
        if jaer_window:
            x1 = min(xi + radius, width - 1 - radius)
            y1 = min(yi + radius, height - 1 - radius)
        else:
            x1 = min(xi + radius, width - 1)
            y1 = min(yi + radius, height - 1)
        count = 0
        for yy in range(y0, y1 + 1):
            for xx in range(x0, x1 + 1):
                if time_map[yy, xx] > bound and (xx != xi or yy != yi):
                    if not use_polarity or polarity_map[yy, xx] == pi:
                        count += 1
            if count >= k:
                break
        keep[i] = count >= k
        time_map[yi, xi] = ti
        polarity_map[yi, xi] = pi


@njit(cache=True, nogil=True)
def dwf(x, y, kept_xy, rejected_xy, counters, distance, k, keep):
    """DWF (Guo & Delbruck 2022): keep an event when at least ``k`` of the stored events lie at L1 distance
    ``< distance``; push it into the FIFO of kept events or of rejected ones.

    ``kept_xy``, ``rejected_xy``: (L, 2) int32 rings; ``counters`` int64: kept count, kept next slot, rejected
    count, rejected next slot, start-up events left (rejected; the first L of them fill the kept window, as
    jAER does).
    """
    size = kept_xy.shape[0]
    for i in range(len(x)):
        xi = np.int64(x[i])
        yi = np.int64(y[i])
        if counters[4] > 0:
            counters[4] -= 1
            keep[i] = False
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
            keep[i] = True
            slot = counters[1]
            kept_xy[slot, 0] = xi
            kept_xy[slot, 1] = yi
            counters[1] = (slot + 1) % size
            if counters[0] < size:
                counters[0] += 1
        else:
            keep[i] = False
            slot = counters[3]
            rejected_xy[slot, 0] = xi
            rejected_xy[slot, 1] = yi
            counters[3] = (slot + 1) % size
            if counters[2] < size:
                counters[2] += 1


@njit(cache=True, nogil=True)
def order_n(t, x, y, row_t, row_x, col_t, col_y, dt_us, self_counts, jaer_edges, keep):
    """Khodamoradi & Kastner's O(W + H) filter: one memory per row (last time, its x) and per column (last time,
    its y); keep an event when an adjacent row (y-1..y+1) last fired less than ``dt_us`` ago at x-1..x+1, or an
    adjacent column at y-1..y+1. Every event is then stored in its row and column.

    ``self_counts``: a memory holding this very pixel counts too (jAER). ``jaer_edges``: events on the sensor's
    border are rejected and not stored (jAER), else the adjacent rows and columns are clipped to the sensor.
    """
    height = row_t.shape[0]
    width = col_t.shape[0]
    for i in range(len(t)):
        ti = t[i]
        xi = np.int64(x[i])
        yi = np.int64(y[i])
        if jaer_edges and (xi <= 0 or yi <= 0 or xi >= width - 1 or yi >= height - 1):
            keep[i] = False
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
        keep[i] = found
        row_t[yi] = ti
        row_x[yi] = xi
        col_t[xi] = ti
        col_y[xi] = yi


@njit(cache=True, nogil=True)
def refractory(t, x, y, time_map, dt_us, inclusive, keep):
    """Drop an event less than ``dt_us`` after the same pixel's previous event (``<= dt_us`` when ``inclusive``,
    jAER); the previous event may itself have been dropped: every event writes its time."""
    for i in range(len(t)):
        ti = t[i]
        xi = np.int64(x[i])
        yi = np.int64(y[i])
        delta = ti - time_map[yi, xi]
        keep[i] = delta > dt_us if inclusive else delta >= dt_us
        time_map[yi, xi] = ti


@njit(cache=True, nogil=True)
def hot_pixels(x, y, hot_map, keep):
    """Drop the events of the pixels marked in ``hot_map`` (height, width) bool."""
    for i in range(len(x)):
        keep[i] = not hot_map[y[i], x[i]]


@njit(cache=True, nogil=True)
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
