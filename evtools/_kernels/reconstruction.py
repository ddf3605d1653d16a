"""Per-event kernel of the high-pass (complementary) filter reconstruction, see :mod:`evtools.metrics.reconstruction`.

References
----------
C. Scheerlinck, N. Barnes, R. Mahony, "Continuous-time Intensity Estimation Using Event Cameras", ACCV 2018.
"""

from __future__ import annotations

import math

from evtools._kernels.jit import kernel


@kernel
def integrate_events(t, x, y, p, width, level, last_us, contrast_on, contrast_off,
                     rate_per_us):  # pragma: no cover - compiled
    """Per event: the pixel's state (log intensity minus the baseline) decays by ``exp(-rate (t - last))`` since
    its previous event, then moves by ``+contrast_on`` (ON) or ``-contrast_off`` (OFF); ``level`` and ``last_us``
    are per pixel (index ``y * width + x``), updated in place."""
    for i in range(t.shape[0]):
        pixel = y[i] * width + x[i]
        value = level[pixel]
        if rate_per_us > 0.0:
            value *= math.exp(-rate_per_us * (t[i] - last_us[pixel]))
        level[pixel] = value + (contrast_on[pixel] if p[i] else -contrast_off[pixel])
        last_us[pixel] = t[i]
