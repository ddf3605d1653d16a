"""BAF, the founding report's filter (Delbruck 2008): a neighbour fired less than ``dt_us`` ago."""

from __future__ import annotations

from evtools._kernels import bafilter as kernels
from evtools.filters.spec import Filter, Param

DT_US = Param("dt_us", "time_us", "correlation window, us")
"""The correlation window, as every correlation filter declares it."""


class Baf(Filter):
    name = "baf"
    reference = "Delbruck 2008"
    keeps = "one of its 8 neighbours (not itself) fired less than `--dt-us` ago (the report's filter)"
    params = (DT_US,)
    defaults = {"evtools": {"dt_us": 10_000}, "dv": {"dt_us": 2_000}, "jaer": {"dt_us": 25_000}}

    def __init__(self, width, height, preset, q) -> None:
        super().__init__(width, height, preset, q)
        self.time_map = kernels.padded_map(width, height, 1, self.start)

    def run(self, words, out) -> int:
        return kernels.baf(words, self.time_map, self.params_used["dt_us"], self.jaer, out)
