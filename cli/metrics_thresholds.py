"""``evtools metrics thresholds``: estimation error of a thresholds file against the ground truth."""

from __future__ import annotations

import json

import click
import numpy as np

from evtools.cli.options import json_option, wants_json
from evtools.metrics.thresholds import ThresholdMetricsError, estimation_picture, threshold_errors
from evtools.formats.io import output_stream
from evtools.formats.thresholds import read_thresholds

PICTURE_EXTENSIONS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".bmp": "BMP", ".tif": "TIFF", ".tiff": "TIFF"}


@click.command()
@click.argument("estimate_path", metavar="EST.h5", type=click.Path(dir_okay=False))
@click.option("--truth", "truth_path", required=True, metavar="TRUTH.h5", type=click.Path(dir_okay=False),
              help="The true thresholds (`evtools simulate ... --truth TRUTH.h5`).")
@click.option("--plot", "plot_path", default=None, metavar="FIG.png", type=click.Path(dir_okay=False),
              help="Also draw the estimated map, the true map and the relative error side by side.")
@json_option
def thresholds(estimate_path, truth_path, plot_path, as_json):
    """Relative RMSE, bias and correlation of ON and OFF thresholds over valid pixels, and the invalid fraction.

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
    if plot_path is not None:
        extension = "." + plot_path.rsplit(".", 1)[-1].lower() if "." in plot_path else ""
        if extension not in PICTURE_EXTENSIONS:
            raise click.BadParameter(f"{plot_path}: give a picture name ending in "
                                     f"{', '.join(PICTURE_EXTENSIONS)}", param_hint="--plot")
    try:
        result = threshold_errors(estimate.on, estimate.off, estimate.valid, truth.on, truth.off)
    except ThresholdMetricsError as error:
        raise ThresholdMetricsError(f"{estimate_path}: {error}") from None
    result = {"estimate": estimate_path, "truth": truth_path, "method": estimate.attributes.get("method"), **result}
    if "rejected_by_fit" in estimate.attributes:  # pixels with enough events whose events did not fit the model
        result["rejected_by_fit"] = int(estimate.attributes["rejected_by_fit"])
    if plot_path is not None:
        _write_picture(plot_path, extension, estimation_picture(
            estimate.on, estimate.off, estimate.valid, truth.on, truth.off))
    if wants_json(as_json):
        click.echo(json.dumps(result, indent=2))
    else:
        _print_table(result)


def _write_picture(path: str, extension: str, rgb: np.ndarray) -> None:
    import cv2

    ok, encoded = cv2.imencode(extension, np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise ThresholdMetricsError(f"{path}: OpenCV could not encode the picture")
    with output_stream(path, binary_name=PICTURE_EXTENSIONS[extension], needs_seek=True) as stream:
        stream.write(encoded.tobytes())


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
    if "rejected_by_fit" in result:
        table.add_row("of which rejected by fit", str(result["rejected_by_fit"]), "")
    Console().print(table)
