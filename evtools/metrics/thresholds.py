"""How well estimated thresholds match the true ones (``docs/algorithms.md`` section 6).

:func:`threshold_errors` computes, for ON and OFF separately over the pixels whose estimate is valid, the relative
RMSE ``sqrt(mean(((est - true) / true)^2))`` (the report's Table 1 figure), the bias (mean relative error), the
correlation between estimated and true thresholds, the fraction of pixels left invalid, and the share of valid
pixels more than 10 % off (the larger of ON and OFF). :func:`fit_calibration` says how well an estimate's fit map
predicts its error (issue 36: a fit that predicts the error).
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


def threshold_errors(estimated_on, estimated_off, valid, true_on, true_off, true_valid=None) -> dict:
    """Relative RMSE, bias and correlation of ON and OFF over valid pixels, and the invalid fraction.

    Parameters
    ----------
    estimated_on, estimated_off : ndarray (height, width)
        Estimated thresholds (log units).
    valid : ndarray of bool (height, width)
        Pixels whose estimate counts; pixels with a non-finite or non-positive estimate or truth are left out too.
    true_on, true_off : ndarray (height, width)
        The true thresholds (``simulate --truth``).
    true_valid : ndarray of bool (height, width), optional
        Where the truth holds a value (a "truth" that is another estimate: its invalid pixels hold a placeholder);
        the other pixels are left out of every figure, the invalid fraction included.

    Returns
    -------
    dict
        ``on`` and ``off``: ``{"rel_rmse", "bias", "correlation", "mae_rel", "pixels"}`` (relative values as
        fractions, correlation None when a map is constant); ``invalid_fraction`` and ``pixels`` (of the pixels
        the truth holds), ``truth_invalid_pixels`` (those it does not, when there are any).
    """
    est_on, est_off, valid, true_on, true_off = _check(estimated_on, estimated_off, valid, true_on, true_off)
    compared = np.ones(valid.shape, bool) if true_valid is None else \
        _check(est_on, est_off, true_valid, true_on, true_off)[2].astype(bool)
    with np.errstate(invalid="ignore"):
        usable = valid.astype(bool) & compared & np.isfinite(est_on) & np.isfinite(est_off) & (est_on > 0)
        usable &= est_off > 0  # (a threshold at or below 0 is no estimate: correct takes none of them either)
        usable &= np.isfinite(true_on) & np.isfinite(true_off) & (true_on > 0) & (true_off > 0)
    pixels = int(compared.sum())
    result = {"pixels": pixels, "valid_pixels": int(usable.sum()),
              "invalid_fraction": float(1.0 - usable.sum() / pixels) if pixels else 1.0}
    if pixels < compared.size:
        result["truth_invalid_pixels"] = int(compared.size - pixels)
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
    worst = _worst_error(est_on, est_off, true_on, true_off)[usable]
    result["off_by_10_percent"] = float(np.mean(worst > 0.1)) if len(worst) else None
    return result


def _worst_error(est_on, est_off, true_on, true_off) -> np.ndarray:
    """Per pixel, the larger of the ON and OFF relative errors (float64; NaN where a threshold is not finite)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.fmax(np.abs(est_on / true_on - 1.0), np.abs(est_off / true_off - 1.0)).astype(np.float64)


FIT_IS_ERROR = ("natural", "offe", "frames")
"""Methods whose fit map is a predicted relative error of the thresholds (stimulus's is the RMS deviation of the
level changes, in thresholds)."""


def fit_calibration(estimated_on, estimated_off, valid, fit, true_on, true_off) -> dict | None:
    """How well ``fit`` (a predicted relative error per pixel) predicts the error, over the valid pixels with a
    finite positive fit: ``error_over_fit_rms``, the RMS of the larger of the ON and OFF relative errors over the
    fit (about 1 where the fit is the error's size, below 1 where it is conservative); ``beyond_two_fits``, the
    share of those pixels off by more than twice their fit; ``rank_correlation`` (Spearman) of fit and error, None
    when either is constant; and ``pixels``. None when no pixel has a fit."""
    est_on, est_off, valid, true_on, true_off = _check(estimated_on, estimated_off, valid, true_on, true_off)
    fit = np.asarray(fit, dtype=np.float64)
    if fit.shape != true_on.shape:
        raise ThresholdMetricsError("the fit map must have the shape of the thresholds")
    worst = _worst_error(est_on, est_off, true_on, true_off)
    with np.errstate(invalid="ignore"):  # (a threshold not positive is not an estimate: as threshold_errors has it)
        usable = valid.astype(bool) & np.isfinite(worst) & np.isfinite(fit) & (fit > 0) & (est_on > 0) & (est_off > 0)
    if not usable.any():
        return None
    error, predicted = worst[usable], fit[usable]
    spread = len(error) > 2 and np.ptp(error) > 0 and np.ptp(predicted) > 0  # (std: > 0 by rounding alone)
    return {"error_over_fit_rms": float(np.sqrt(np.mean((error / predicted) ** 2))),
            "beyond_two_fits": float(np.mean(error > 2.0 * predicted)),
            "rank_correlation": rank_correlation(predicted, error) if spread else None,
            "pixels": int(usable.sum())}


def rank_correlation(a, b) -> float:
    """Spearman's rank correlation of ``a`` and ``b``: Pearson's of their ranks, tied values given their average
    rank (a fit takes few distinct values: ranks broken by the pixels' order made the result depend on it, -0.109
    or +0.058 for the same maps flipped where the true value was -0.027, a QA sweep)."""
    return float(np.corrcoef(average_ranks(a), average_ranks(b))[0, 1])


def average_ranks(values) -> np.ndarray:
    """The ranks (0-based) of ``values``, each run of equal values given the mean of the ranks it spans."""
    values = np.asarray(values)
    order = np.argsort(values, kind="stable")
    ordered = values[order]
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    ends = np.r_[starts[1:], len(values)]
    ranks = np.empty(len(values))
    ranks[order] = np.repeat((starts + ends - 1) / 2.0, ends - starts)
    return ranks
