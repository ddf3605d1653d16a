"""Numba kernels of the learned filter MLPF (Guo & Delbruck, TPAMI 2023): a time-surface patch per event into a
one-hidden-layer perceptron.

Features of an event at (x, y) and time t, for a patch of ``P = 2 radius + 1`` pixels a side: for the ON map,
then the OFF map, row by row (dy) and column by column (dx) over the patch, ``max(0, 1 - (t - T) / tau)``
where T is that pixel's last event of that polarity (0 when it never fired or fired ``tau`` or more ago);
then the event's own polarity (1 ON, 0 OFF): ``2 P^2 + 1`` inputs. The pixel itself is part of its patch (a
hot pixel's own rate is telling). The maps (padded by ``radius``, :data:`NEVER` there and before a first event)
get the event's time after its features are taken.

The time constant is fixed (``tau_us``) or follows the stream's activity (``scale`` > 0, :func:`time_constant`):
``scale`` times the running mean interval between events, where ``scale`` is the weights' ``tau_scale`` times the
sensor's pixel count, so that ``tau_scale`` 1 is the time the sensor takes to fire once per pixel on average. The
same time surfaces then describe a sparse DVS128 scene and a dense 1280 x 720 one (issue 41's leave-one-sensor-out
measurements in the README).

The filter adds only the rows of ``w1`` whose feature is not 0 (few neighbours fire within ``tau`` on
noise), so its cost is the active neighbours times the hidden units, not the whole matrix. It does so in two
passes per event, each free of unpredictable branches (a data-dependent ``if`` per neighbour cost more than
the arithmetic): a scan that lists the active patch cells and their ages, then the hidden units summed over the
list four cells at a time (a loop numba vectorises), the list padded with a zero row of ``w1``
(``docs/performance.md``).
"""

from __future__ import annotations

import numpy as np

from evtools._kernels.bafilter import AHEAD, NEVER, _keep, unpack
from evtools._kernels.jit import kernel
from evtools._kernels.prefetch import prefetch


def padded_maps(width: int, height: int, radius: int) -> np.ndarray:
    """(2, height + 2 radius, width + 2 radius) int64: the ON and the OFF time maps, :data:`NEVER` everywhere."""
    return np.full((2, height + 2 * radius, width + 2 * radius), NEVER, dtype=np.int64)


TAU_LIMIT_US = 2.0 ** 62
"""The largest time constant (evtools' time range): a stream of a few events hours apart on a large sensor would
otherwise ask for more than int64 holds."""


def new_clock(pixels: int) -> np.ndarray:
    """The state of :func:`time_constant`: events seen, mean interval (us), last time (us), averaging window
    (the sensor's pixel count, in events)."""
    return np.array([0.0, 0.0, 0.0, float(pixels)])


@kernel(inline=True)
def time_constant(clock, t, scale, tau_us):
    """The time constant (us, 1 to :data:`TAU_LIMIT_US`) for an event at ``t``: ``tau_us`` when ``scale`` is 0,
    else ``scale`` times the mean interval between events, a running mean over the first events and an exponential
    one (weight 1 / ``clock[3]``) from then on; ``clock`` (:func:`new_clock`) gets the event."""
    if scale <= 0.0:
        return tau_us
    seen = clock[0]
    if seen > 0.0:
        clock[1] += ((t - clock[2]) - clock[1]) / min(seen, clock[3])
    clock[0] = seen + 1.0
    clock[2] = t
    return max(1, int(min(scale * clock[1], TAU_LIMIT_US)))


def with_zero_row(w1: np.ndarray) -> np.ndarray:
    """``w1`` (inputs, hidden) with a row of zeros appended: the row :func:`mlpf` pads its list of cells with."""
    return np.concatenate([np.asarray(w1, np.float64), np.zeros((1, w1.shape[1]))])


def scratch(patch: int) -> tuple[np.ndarray, np.ndarray]:
    """The two lists :func:`mlpf` fills per event (active cells, uint64; their ages, int64): all inputs, plus
    padding."""
    size = 2 * patch * patch + 1 + 4
    return np.zeros(size, np.uint64), np.zeros(size, np.int64)


@kernel
def mlpf(words, maps, radius, clock, scale, tau_us, w1, b1, w2, b2, logit_threshold, cells, ages, hidden, out):
    """Keep an event when the perceptron's logit ``w2 . relu(w1^T f + b1) + b2`` exceeds ``logit_threshold``
    (the probability threshold's logit); the time constant from ``clock``, ``scale`` and ``tau_us``
    (:func:`time_constant`); ``w1`` is :func:`with_zero_row` of the (inputs, hidden) weights, ``cells`` and
    ``ages`` the lists of :func:`scratch`, ``hidden`` scratch of the hidden size."""
    u = np.uint64  # every index unsigned: numba then adds no negative-index fix-up (one a cell and a unit)
    size = u(2 * radius + 1)
    plane = size * size
    zero_row = u(2) * plane + u(1)
    width = u(maps.shape[2])
    flat = maps.ravel()
    map_cells = u(maps.shape[1]) * width
    units = u(b1.shape[0])
    one = u(1)
    n = 0
    end = words.shape[0]
    for i in range(end):
        if i + AHEAD < end:  # the patch rows of a later event: cache misses on large sensors
            ahead = words[i + AHEAD, 1]
            corner = u(((ahead >> 16) & 0xFFFF) * maps.shape[2] + (ahead & 0xFFFF))
            for c in range(u(2)):
                for dy in range(size):
                    prefetch(flat, c * map_cells + corner + dy * width)
                    prefetch(flat, c * map_cells + corner + dy * width + size - one)
        t = words[i, 0]
        x, y, p = unpack(words[i, 1])
        tau = time_constant(clock, t, scale, tau_us)
        inverse_tau = 1.0 / tau
        # the scan: every cell written, the count advanced by 1 where active
        active = u(0)
        for c in range(u(2)):
            for dy in range(size):
                row = c * map_cells + (u(y) + dy) * width + u(x)
                first = c * plane + dy * size
                for dx in range(size):
                    age = t - flat[row + dx]
                    cells[active] = first + dx
                    ages[active] = age
                    active += u((age - tau) >> 63) & one  # age < tau
        if p:
            cells[active] = u(2) * plane  # the polarity input: 1, as a cell of age 0
            ages[active] = 0
            active += one
        for q in range(u(4)):
            cells[active + q] = zero_row
            ages[active + q] = 0
        for j in range(units):
            hidden[j] = b1[j]
        for m in range(u(0), active, u(4)):
            ra, rb, rc, rd = cells[m], cells[m + u(1)], cells[m + u(2)], cells[m + u(3)]
            fa, fb = 1.0 - ages[m] * inverse_tau, 1.0 - ages[m + u(1)] * inverse_tau
            fc, fd = 1.0 - ages[m + u(2)] * inverse_tau, 1.0 - ages[m + u(3)] * inverse_tau
            for j in range(units):
                hidden[j] += (fa * w1[ra, j] + fb * w1[rb, j]) + (fc * w1[rc, j] + fd * w1[rd, j])
        z = b2
        for j in range(units):
            z += max(hidden[j], 0.0) * w2[j]
        flat[(u(0) if p else map_cells) + (u(y) + u(radius)) * width + u(x) + u(radius)] = t
        n = _keep(words, i, out, n, z > logit_threshold)
    return n


@kernel
def mlpf_features(words, maps, radius, clock, scale, tau_us, take, features):
    """The features (see the module) of the events where ``take`` is true, in order, into the rows of
    ``features``; every event updates the maps. Returns the number of rows written."""
    size = 2 * radius + 1
    plane = size * size
    width = maps.shape[2]
    flat = maps.ravel()
    map_cells = maps.shape[1] * width
    n = 0
    for i in range(words.shape[0]):
        t = words[i, 0]
        x, y, p = unpack(words[i, 1])
        tau = time_constant(clock, t, scale, tau_us)
        if take[i]:
            for c in range(2):
                for dy in range(size):
                    row = c * map_cells + (y + dy) * width + x
                    for dx in range(size):
                        age = t - flat[row + dx]
                        features[n, c * plane + dy * size + dx] = 1.0 - age / tau if age < tau else 0.0
            features[n, 2 * plane] = 1.0 if p else 0.0
            n += 1
        flat[(0 if p else map_cells) + (y + radius) * width + x + radius] = t
    return n
