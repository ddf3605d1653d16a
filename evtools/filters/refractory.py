"""The refractory filter: a pixel's event less than ``dt_us`` after its previous one is dropped."""

from __future__ import annotations

import numpy as np

from evtools._kernels import bafilter as kernels
from evtools.filters.spec import Filter, Param


class Refractory(Filter):
    name = "refractory"
    keeps = "the same pixel's previous event is at least `--dt-us` old"
    params = (Param("dt_us", "time_us", "refractory period, us"),)
    defaults_from = "libcaer's"
    defaults = {"evtools": {"dt_us": 100}, "jaer": {"dt_us": 25_000}}

    def __init__(self, width, height, preset, q) -> None:
        super().__init__(width, height, preset, q)
        self.time_map = np.full((height, width), self.start, dtype=np.int64)

    def run(self, words, out) -> int:
        return kernels.refractory(words, self.time_map, self.params_used["dt_us"], self.jaer, out)
