"""Numba kernels of the learned filter MLPF (Guo & Delbruck, TPAMI 2023): a time-surface patch per event into a
one-hidden-layer perceptron.

Features of an event at (x, y) and time t, for a patch of ``P = 2 radius + 1`` pixels a side: for the ON map,
then the OFF map, row by row (dy) and column by column (dx) over the patch, ``max(0, 1 - (t - T) / tau_us)``
where T is that pixel's last event of that polarity (0 when it never fired or fired ``tau_us`` or more ago);
then the event's own polarity (1 ON, 0 OFF): ``2 P^2 + 1`` inputs. The pixel itself is part of its patch (a
hot pixel's own rate is telling). The maps (padded by ``radius``, :data:`NEVER` there and before a first event)
get the event's time after its features are taken.

The filter adds only the columns of ``w1`` whose feature is not 0 (few neighbours fire within ``tau_us`` on
noise), so its cost is the active neighbours times the hidden units, not the whole matrix.
"""

from __future__ import annotations

import numpy as np

from evtools._kernels.bafilter import AHEAD, NEVER, _keep, unpack
from evtools._kernels.jit import kernel
from evtools._kernels.prefetch import prefetch


def padded_maps(width: int, height: int, radius: int) -> np.ndarray:
    """(2, height + 2 radius, width + 2 radius) int64: the ON and the OFF time maps, :data:`NEVER` everywhere."""
    return np.full((2, height + 2 * radius, width + 2 * radius), NEVER, dtype=np.int64)


@kernel
def mlpf(words, maps, radius, tau_us, w1, b1, w2, b2, logit_threshold, hidden, out):
    """Keep an event when the perceptron's logit ``w2 . relu(w1^T f + b1) + b2`` exceeds ``logit_threshold``
    (the probability threshold's logit); ``w1`` is (inputs, hidden), ``hidden`` scratch of the hidden size."""
    size = 2 * radius + 1
    plane = size * size
    width = maps.shape[2]
    flat = maps.ravel()
    map_cells = maps.shape[1] * width
    units = b1.shape[0]
    inverse_tau = 1.0 / tau_us
    n = 0
    end = words.shape[0]
    for i in range(end):
        if i + AHEAD < end:  # the patch rows of a later event: cache misses on large sensors
            ahead = words[i + AHEAD, 1]
            corner = ((ahead >> 16) & 0xFFFF) * width + (ahead & 0xFFFF)
            for c in range(2):
                for dy in range(size):
                    prefetch(flat, c * map_cells + corner + dy * width)
                    prefetch(flat, c * map_cells + corner + dy * width + size - 1)
        t = words[i, 0]
        x, y, p = unpack(words[i, 1])
        for j in range(units):
            hidden[j] = b1[j]
        if p:
            for j in range(units):
                hidden[j] += w1[2 * plane, j]
        for c in range(2):
            for dy in range(size):
                row = c * map_cells + (y + dy) * width + x
                for dx in range(size):
                    age = t - flat[row + dx]
                    if age < tau_us:
                        f = 1.0 - age * inverse_tau
                        k = c * plane + dy * size + dx
                        for j in range(units):
                            hidden[j] += f * w1[k, j]
        z = b2
        for j in range(units):
            z += max(hidden[j], 0.0) * w2[j]
        flat[(0 if p else map_cells) + (y + radius) * width + x + radius] = t
        n = _keep(words, i, out, n, z > logit_threshold)
    return n


@kernel
def mlpf_features(words, maps, radius, tau_us, take, features):
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
        if take[i]:
            for c in range(2):
                for dy in range(size):
                    row = c * map_cells + (y + dy) * width + x
                    for dx in range(size):
                        age = t - flat[row + dx]
                        features[n, c * plane + dy * size + dx] = 1.0 - age / tau_us if age < tau_us else 0.0
            features[n, 2 * plane] = 1.0 if p else 0.0
            n += 1
        flat[(0 if p else map_cells) + (y + radius) * width + x + radius] = t
    return n
