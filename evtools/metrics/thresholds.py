"""How well estimated thresholds match the true ones (``docs/algorithms.md`` section 6).

:func:`threshold_errors` computes, for ON and OFF separately over the pixels whose estimate is valid, the relative
RMSE ``sqrt(mean(((est - true) / true)^2))`` (the report's Table 1 figure), the bias (mean relative error), the
correlation between estimated and true thresholds, and the fraction of pixels left invalid.
:func:`evtools.plots.thresholds_figure` draws the estimated map, the true map and the relative error side by side (the
report's Figure 29).
"""

from __future__ import annotations


import numpy as np

from evtools.errors import EvtoolsError


class ThresholdMetricsError(EvtoolsError, ValueError):
    """The estimated and true maps cannot be compared."""


def _check(estimated_on, estimated_off, valid, true_on, true_off):
    arrays = [np.asarray(a) for a in (estimated_on, estimated_off, valid, true_on, true_off)]
    shape = arrays[3].shape
    if arrays[3].ndim != 2 or any(a.shape != shape for a in arrays):
        sizes = ", ".join("x".join(str(s) for s in a.shape[::-1]) for a in arrays)
        raise ThresholdMetricsError(
            f"the estimated and true maps differ in size ({sizes}): compare thresholds of the same sensor"
        )
    return arrays


def threshold_errors(estimated_on, estimated_off, valid, true_on, true_off) -> dict:
    """Relative RMSE, bias and correlation of ON and OFF over valid pixels, and the invalid fraction.

    Parameters
    ----------
    estimated_on, estimated_off : ndarray (height, width)
        Estimated thresholds (log units).
    valid : ndarray of bool (height, width)
        Pixels whose estimate counts; pixels with a non-finite or non-positive estimate or truth are left out too.
    true_on, true_off : ndarray (height, width)
        The true thresholds (``simulate --truth``).

    Returns
    -------
    dict
        ``on`` and ``off``: ``{"rel_rmse", "bias", "correlation", "mae_rel", "pixels"}`` (relative values as
        fractions, correlation None when a map is constant); ``invalid_fraction``, ``pixels``.
    """
    est_on, est_off, valid, true_on, true_off = _check(estimated_on, estimated_off, valid, true_on, true_off)
    with np.errstate(invalid="ignore"):
        usable = valid.astype(bool) & np.isfinite(est_on) & np.isfinite(est_off)
        usable &= np.isfinite(true_on) & np.isfinite(true_off) & (true_on > 0) & (true_off > 0)
    result = {"pixels": int(valid.size), "valid_pixels": int(usable.sum()),
              "invalid_fraction": float(1.0 - usable.sum() / valid.size)}
    for name, est, true in (("on", est_on, true_on), ("off", est_off, true_off)):
        e = est[usable].astype(np.float64)
        t = true[usable].astype(np.float64)
        if not len(e):
            result[name] = {"rel_rmse": None, "bias": None, "correlation": None, "mae_rel": None, "pixels": 0}
            continue
        relative = (e - t) / t
        correlation = None
        if len(e) > 1 and e.std() > 0 and t.std() > 0:
            correlation = float(np.corrcoef(e, t)[0, 1])
        result[name] = {
            "rel_rmse": float(np.sqrt(np.mean(relative**2))),
            "bias": float(relative.mean()),
            "correlation": correlation,
            "mae_rel": float(np.mean(np.abs(relative))),
            "pixels": int(len(e)),
        }
    return result
