"""``evtools metrics thresholds``: estimation error of a thresholds file against the ground truth."""

from __future__ import annotations

import json
import logging

import click
import numpy as np

from evtools.cli.options import figure_path, json_option, wants_json
from evtools.metrics.thresholds import FIT_IS_ERROR, ThresholdMetricsError, fit_calibration, threshold_errors
from evtools.formats.thresholds import read_thresholds

log = logging.getLogger("evtools")

@click.command()
@click.argument("estimate_path", metavar="EST.h5", type=click.Path(dir_okay=False))
@click.option("--truth", "truth_path", required=True, metavar="TRUTH.h5", type=click.Path(dir_okay=False),
              help="The true thresholds (`evtools simulate ... --truth TRUTH.h5`).")
@click.option("--plot", "plot_path", default=None, metavar="FIG.png", type=click.Path(dir_okay=False),
              help="Also draw the estimated map, the true map and the relative error side by side.")
@json_option
def thresholds(estimate_path, truth_path, plot_path, as_json):
    """Relative RMSE, bias and correlation of ON and OFF thresholds over valid pixels, the invalid fraction, the
    valid pixels more than 10 % off, and how well the fit map predicts the error (natural, offe, frames).

    \b
    evtools metrics thresholds thresholds.h5 --truth truth.h5 --plot errors.png
    """
    estimate = read_thresholds(estimate_path)
    truth = read_thresholds(truth_path)
    if (estimate.width, estimate.height) != (truth.width, truth.height):
        raise ThresholdMetricsError(
            f"{estimate_path}: thresholds are {estimate.width}x{estimate.height} but the truth {truth_path} is "
            f"{truth.width}x{truth.height}; compare the estimate with the truth of the same sensor"
        )
    figure_path(plot_path, "--plot", (estimate_path, truth_path))
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
    if estimate.fit is not None and method in FIT_IS_ERROR:  # how well the fit map predicts the error
        result["fit"] = fit_calibration(estimate.on, estimate.off, estimate.valid & compared, estimate.fit,
                                        truth.on, truth.off)
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

        save_figure(thresholds_figure(estimate.on, estimate.off, estimate.valid & compared, truth.on, truth.off),
                    plot_path)
    if wants_json(as_json):
        click.echo(json.dumps(result, indent=2))
    else:
        _print_table(result)


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
