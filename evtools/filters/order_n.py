"""orderN (Khodamoradi & Kastner 2018): O(W + H) memory, a row's and a column's last event."""

from __future__ import annotations

import numpy as np

from evtools._kernels import bafilter as kernels
from evtools.filters.baf import DT_US
from evtools.filters.spec import Filter


class OrderN(Filter):
    name = "orderN"
    reference = "Khodamoradi & Kastner 2018"
    keeps = ("an adjacent row (column) last fired less than `--dt-us` ago within one pixel (Khodamoradi & Kastner; "
             "O(W+H) memory)")
    params = (DT_US,)
    defaults = {"evtools": {"dt_us": 10_000}, "jaer": {"dt_us": 25_000}}

    def __init__(self, width, height, preset, q) -> None:
        super().__init__(width, height, preset, q)
        self.row_t = np.full(height, kernels.NEVER, dtype=np.int64)
        self.row_x = np.full(height, -1, dtype=np.int64)
        self.col_t = np.full(width, kernels.NEVER, dtype=np.int64)
        self.col_y = np.full(width, -1, dtype=np.int64)

    def run(self, words, out) -> int:
        return kernels.order_n(words, self.row_t, self.row_x, self.col_t, self.col_y, self.params_used["dt_us"],
                               self.jaer, self.jaer, out)
