"""YNoise, the event-density filter (Feng et al. 2020): enough pixels of a window, the event's own included, fired
with its polarity less than ``dt_us`` ago.

Y. Feng, H. Lv, H. Liu, Y. Zhang, Y. Xiao, C. Han, "Event Density Based Denoising Method for Dynamic Vision
Sensor", Applied Sciences 10(6), 2020. The window holds each pixel's last event (time and polarity), as the
filter's published implementations do; defaults theirs (10 ms, L = 3, density 2).
"""

from __future__ import annotations

from evtools._kernels import bafilter as kernels
from evtools.filters.baf import DT_US
from evtools.filters.spec import Filter, Param
from evtools.filters.stcf import RADIUS


class YNoise(Filter):
    name = "ynoise"
    reference = "Feng et al. 2020"
    keeps = ("at least `--k` pixels of its (2r+1)^2 window, itself included, last fired with its polarity less than "
             "`--dt-us` ago (Feng et al. 2020's event density; a pixel firing twice supports itself)")
    params = (
        DT_US,
        RADIUS,
        Param("k", "int", "density needed: pixels of the window, itself included", 1,
              lambda q: (2 * q["radius"] + 1) ** 2),
    )
    defaults = {"evtools": {"dt_us": 10_000, "radius": 1, "k": 2}}
    defaults_from = "Feng et al.'s"

    def __init__(self, width, height, preset, q) -> None:
        super().__init__(width, height, preset, q)
        self.time_map = kernels.padded_map(width, height, q["radius"], kernels.NEVER) * 2  # 2 t + p

    def run(self, words, out) -> int:
        q = self.params_used
        # STCF's kernel with the pixel itself counted, polarity matched, the whole window, no start-up rejection
        return kernels.stcf(words, self.time_map, q["dt_us"], q["radius"], q["k"], True, False, False, True, out)
