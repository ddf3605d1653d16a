"""``evtools metrics thresholds``: estimation error of a thresholds file against the ground truth."""

from __future__ import annotations

import logging

import click
import numpy as np

from evtools.cli.options import echo_json, figure_path, json_option, wants_json
from evtools.metrics.thresholds import FIT_IS_ERROR, ThresholdMetricsError, fit_calibration, threshold_errors
from evtools.formats.thresholds import ThresholdMap, open_thresholds, read_thresholds

log = logging.getLogger("evtools")

@click.command()
@click.argument("estimate_path", metavar="EST.h5", type=click.Path())
@click.option("--truth", "truth_path", required=True, metavar="TRUTH.h5", type=click.Path(),
              help="The true thresholds (`evtools simulate ... --truth TRUTH.h5`).")
@click.option("--plot", "plot_path", default=None, metavar="FIG.png", type=click.Path(dir_okay=False),
              help="Also draw the estimated map, the true map and the relative error side by side.")
@click.option("--map", "map_index", type=int, default=-1, show_default=True, metavar="K",
              help="A series (`estimate --online`): which map to compare (0 the first, -1 the last).")
@json_option
def thresholds(estimate_path, truth_path, plot_path, map_index, as_json):
    """Relative RMSE, bias and correlation of ON and OFF thresholds over valid pixels, the invalid fraction, the
    valid pixels more than 10 % off, and how well the fit map predicts the error (natural, offe, frames).

    A truth whose thresholds drift (`simulate --thres-drift`) is taken at the estimate's time: a series' map at
    its own time, a single map at the middle of the stream it was estimated from.

    \b
    evtools metrics thresholds thresholds.h5 --truth truth.h5 --plot errors.png
    """
    estimate, at_us = _estimate_map(estimate_path, map_index)
    truth = read_thresholds(truth_path)
    if (estimate.width, estimate.height) != (truth.width, truth.height):
        raise ThresholdMetricsError(
            f"{estimate_path}: thresholds are {estimate.width}x{estimate.height} but the truth {truth_path} is "
            f"{truth.width}x{truth.height}; compare the estimate with the truth of the same sensor"
        )
    figure_path(plot_path, "--plot", (estimate_path, truth_path))
    truth_at_us = _truth_at(truth, truth_path, estimate_path, at_us)
    with np.errstate(invalid="ignore"):
        not_positive = estimate.valid & ~((estimate.on > 0) & (estimate.off > 0))
    if not_positive.any():  # (NaN, inf, 0 or below: no estimate, as correct takes them)
        log.warning(f"{estimate_path}: {int(not_positive.sum()):,} pixels marked valid hold a threshold that is not "
                    "finite and positive: counted as invalid")
    if not truth.valid.all():  # another estimate as the truth: its invalid pixels hold a placeholder
        log.warning(f"{truth_path}: {int((~truth.valid).sum()):,} of {truth.valid.size:,} pixels hold no valid "
                    "value (dead pixels, or another estimate's invalid ones): left out of every figure")
    compared = truth.valid
    outside = None
    if "sliced" in estimate.attributes:  # estimated on a crop: the pixels outside it (NaN) were never estimated
        with np.errstate(invalid="ignore"):
            outside = ~estimate.valid & ~(np.isfinite(estimate.on) & np.isfinite(estimate.off))
        compared = truth.valid & ~outside
    try:
        result = threshold_errors(estimate.on, estimate.off, estimate.valid, truth.on, truth.off, compared)
    except ThresholdMetricsError as error:
        raise ThresholdMetricsError(f"{estimate_path}: {error}") from None
    if outside is not None and outside.any():  # (not counted as the truth's: said apart)
        result["outside_crop_pixels"] = int(outside.sum())
        result.pop("truth_invalid_pixels", None)
        if (~truth.valid & ~outside).any():
            result["truth_invalid_pixels"] = int((~truth.valid & ~outside).sum())
    method = estimate.attributes.get("method")
    result = {"estimate": estimate_path, "truth": truth_path, "method": method, **result}
    if estimate.t_us is not None:
        result["map"] = {"index": at_us[1], "t_us": at_us[0], "maps": at_us[2]}
    if truth_at_us is not None:
        result["truth_at_us"] = truth_at_us
    if estimate.fit is not None and method in FIT_IS_ERROR:  # how well the fit map predicts the error
        result["fit"] = fit_calibration(estimate.on, estimate.off, estimate.valid & ~not_positive & compared,
                                        estimate.fit, truth.on, truth.off)
    if "rejected_by_fit" in estimate.attributes:  # pixels with enough events whose events did not fit the model
        result["rejected_by_fit"] = int(estimate.attributes["rejected_by_fit"])
    if "unchecked" in estimate.attributes:  # offE: estimates its fit could not check (not valid)
        result["unchecked"] = int(estimate.attributes["unchecked"])
    for key in ("scale", "not_observable"):  # what the estimate's scale is, and what events alone cannot give
        if key in estimate.attributes:
            result[key] = str(estimate.attributes[key])
    if plot_path is not None:
        from evtools.formats.figures import save_figure
        from evtools.plots import thresholds_figure

        save_figure(thresholds_figure(estimate.on, estimate.off, estimate.valid & ~not_positive & compared, truth.on,
                                      truth.off),
                    plot_path)
    if wants_json(as_json):
        echo_json(result, indent=2)
    else:
        _print_table(result)


def _estimate_map(path: str, index: int):
    """The estimate to compare (a series' map ``index``, its ``t_us`` kept as a one-element array) and its time:
    (the map's time, the index, the number of maps) for a series; the middle of ``t_first_us``, ``t_last_us`` for
    a single map (the mean of a linear drift over the stream); None when the file says neither."""
    with open_thresholds(path) as maps:
        if maps.t_us is None:
            first, last = maps.attributes.get("t_first_us"), maps.attributes.get("t_last_us")
            middle = None if first is None or last is None else (int(first) + int(last)) // 2
            return maps, middle
        count = len(maps.t_us)
        if not -count <= index < count:
            raise click.BadParameter(f"{path} holds {count} maps: give an index from {-count} to {count - 1}",
                                     param_hint="--map")
        k = index % count
        chosen = ThresholdMap(maps.on[k], maps.off[k], maps.valid[k], maps.attributes,
                              None if maps.fit is None else maps.fit[k], maps.phase_us, maps.t_us[k:k + 1])
        return chosen, (int(maps.t_us[k]), k, count)


def _truth_at(truth, truth_path: str, estimate_path: str, at) -> int | None:
    """A drifting truth's thresholds (``thres_drift_per_s``: the simulator's linear drift from its first frame,
    ``thres_drift_origin_us``) scaled in place to the estimate's time; returns that time (None: no drift)."""
    drift = float(truth.attributes.get("thres_drift_per_s", 0.0) or 0.0)
    if drift == 0.0:
        return None
    at_us = at[0] if isinstance(at, tuple) else at
    if at_us is None:
        log.warning(f"{truth_path}: its thresholds drift ({100 * drift:+g} %/s) but {estimate_path} says not when "
                    "it was estimated: compared with the truth at its start")
        return None
    from evtools.simulation import drift_factor

    factor = drift_factor(drift, at_us - int(truth.attributes.get("thres_drift_origin_us", 0)))
    truth.on, truth.off = truth.on * np.float32(factor), truth.off * np.float32(factor)
    what = f"map {at[1]}'s time" if isinstance(at, tuple) else "the middle of the stream it was estimated from"
    log.info(f"{truth_path}: its thresholds drift {100 * drift:+g} %/s: taken at {at_us:,} us ({what}), "
             f"{factor:.4g} times those at the start")
    return at_us


def _print_table(result: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    def percent(value):
        return "-" if value is None else f"{100 * value:.2f} %"

    table = Table(title=f"{result['estimate']} vs {result['truth']}", header_style="bold")
    for column in ("", "ON", "OFF"):
        table.add_column(column)
    for label, key, fmt in (("relative RMSE", "rel_rmse", percent), ("bias (mean rel. error)", "bias", percent),
                            ("mean abs. rel. error", "mae_rel", percent),
                            ("correlation", "correlation", lambda v: "-" if v is None else f"{v:.4f}"),
                            ("pixels", "pixels", str)):
        table.add_row(label, fmt(result["on"][key]), fmt(result["off"][key]))
    table.add_row("invalid pixels", f"{100 * result['invalid_fraction']:.2f} %", "")
    if result.get("outside_crop_pixels"):
        table.add_row("left out (outside the crop estimated)", f"{result['outside_crop_pixels']:,} pixels", "")
    if result.get("truth_invalid_pixels"):
        table.add_row("left out (no valid truth)", f"{result['truth_invalid_pixels']:,} pixels", "")
    table.add_row("valid pixels > 10 % off", percent(result["off_by_10_percent"]), "")
    if result.get("fit"):
        fit = result["fit"]
        rank = "-" if fit["rank_correlation"] is None else f"{fit['rank_correlation']:.2f}"
        table.add_row("error / fit (RMS; < 1: fit conservative)", f"{fit['error_over_fit_rms']:.2f}", "")
        table.add_row("off by more than 2 fits", percent(fit["beyond_two_fits"]), "")
        table.add_row("fit-error rank correlation", rank, "")
    if "rejected_by_fit" in result:
        table.add_row("rejected by fit (the estimate's, all pixels)", str(result["rejected_by_fit"]), "")
    if "unchecked" in result:
        table.add_row("unchecked (the estimate's, all pixels)", str(result["unchecked"]), "")
    if "scale" in result:
        table.add_row("scale", result["scale"], "")
    Console().print(table)
    if "not_observable" in result:
        Console(stderr=True, highlight=False).print(f"note: {result['not_observable']}")
