"""STCF, jAER's SpatioTemporalCorrelationFilter: at least ``k`` neighbours of a (2r+1)^2 window fired less than
``dt_us`` ago (Guo & Delbruck 2022)."""

from __future__ import annotations

import numpy as np

from evtools._kernels import bafilter as kernels
from evtools.filters.baf import DT_US
from evtools.filters.spec import BAFilterSettingsError, Filter, Param


RADIUS = Param("radius", "int", "neighbourhood radius r, window (2r+1)^2", 1, 10)
"""The window's radius, as every window filter declares it."""


class Stcf(Filter):
    name = "stcf"
    reference = "Guo & Delbruck 2022"
    keeps = ("at least `--k` pixels of its (2r+1)^2 window (not itself) fired less than `--dt-us` ago, of its "
             "polarity with `--same-polarity` (the default; `--any-polarity`: of any)")
    params = (
        DT_US,
        RADIUS,
        Param("k", "int", "correlated neighbours needed", 1, lambda q: (2 * q["radius"] + 1) ** 2 - 1),
        Param("polarity", "bool", "count neighbours of the event's polarity only, or of any",
              flag="--same-polarity/--any-polarity", sweepable=False),
        Param("polarity_maps", "bool", "a time map per polarity: a neighbour's last event of the event's polarity "
              "counts even if one of the other polarity came after it", flag="--polarity-maps", sweepable=False),
    )
    defaults = {"evtools": {"dt_us": 10_000, "radius": 1, "k": 2, "polarity": True, "polarity_maps": False},
                "jaer": {"dt_us": 25_000, "radius": 1, "k": 2, "polarity": True}}

    @classmethod
    def prepare(cls, q, width, height):
        if q.get("polarity_maps") and not q["polarity"]:
            raise BAFilterSettingsError("polarity maps count neighbours of the event's polarity: they cannot go with "
                                "polarity off")
        return q

    def __init__(self, width, height, preset, q) -> None:
        super().__init__(width, height, preset, q)
        one = kernels.padded_map(width, height, q["radius"], self.start)
        self.time_map = np.stack([one] * 2) if q.get("polarity_maps") else one * 2  # per polarity, or 2 t + p

    def run(self, words, out) -> int:
        q = self.params_used
        if q.get("polarity_maps"):
            return kernels.stcf_polarity_maps(words, self.time_map, q["dt_us"], q["radius"], q["k"], out)
        return kernels.stcf(words, self.time_map, q["dt_us"], q["radius"], q["k"], q["polarity"], self.jaer,
                            self.jaer, False, out)
