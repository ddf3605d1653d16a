"""DWF, the double window filter (Guo & Delbruck 2022): enough of the last kept and rejected events are near."""

from __future__ import annotations

import numpy as np

from evtools._kernels import bafilter as kernels
from evtools.filters.spec import Filter, Param


class Dwf(Filter):
    name = "dwf"
    reference = "Guo & Delbruck 2022"
    keeps = ("at least `--k` of the last `--window` kept and last `--window` rejected events lie at L1 distance "
             "`< --distance` (Guo & Delbruck 2022)")
    params = (
        Param("window", "int", "length of each FIFO window", 1, 1 << 16),
        Param("distance", "int", "L1 distance, support when < this", 1, 1 << 16),
        Param("k", "int", "stored events needed", 1, 2**31 - 1),
    )
    defaults_from = "E-MLB's"
    defaults = {"evtools": {"window": 36, "distance": 9, "k": 1}, "jaer": {"window": 256, "distance": 5, "k": 1}}

    def __init__(self, width, height, preset, q) -> None:
        super().__init__(width, height, preset, q)
        size = q["window"]
        self.kept_xy = np.zeros((size, 2), dtype=np.int32)
        self.rejected_xy = np.zeros((size, 2), dtype=np.int32)
        self.counters = np.zeros(5, dtype=np.int64)
        if self.jaer:  # the rejected window pre-filled with (-1, -1); the first 2 L events rejected
            self.rejected_xy[:] = -1
            self.counters[2] = size
            self.counters[4] = 2 * size

    def run(self, words, out) -> int:
        q = self.params_used
        return kernels.dwf(words, self.kept_xy, self.rejected_xy, self.counters, q["distance"], q["k"], out)
