"""``evtools metrics denoise | roc | esr``: how well a background-activity filter works (docs/algorithms.md
section 3)."""

from __future__ import annotations

import contextlib
import logging
import math
import signal

import click
import numpy as np

from evtools import interrupt
from evtools.cli.options import (MICROSECONDS, FileRead, echo_json, figure_path, json_option, read_options,
                                 wants_json)
from evtools.cli.progress import with_progress
from evtools.filters import METHODS, BAFilter, BAFilterError, check_preset, not_applying, parse_methods
from evtools.filters.registry import parameters
from evtools.metrics.denoise import LABEL_NAMES, DenoiseMatcher, DenoiseMetricsError, EsrMeter, roc_auc
from evtools.errors import EvtoolsError
from evtools.formats import open_events
from evtools.formats.thresholds import read_labels
from evtools.formats.truth import Fingerprint, check_labelled

log = logging.getLogger("evtools")


def _labels_for(truth: str, name: str) -> np.ndarray:
    """The labels of the stream ``name``, read once to check they are its own (count and fingerprint)."""
    labels, fingerprint = read_labels(truth)
    seen = Fingerprint()
    with open_events(name) as stream:
        for chunk in stream:
            seen.add(chunk)
    n_events = seen.sums[0]
    if len(labels) != n_events:
        raise DenoiseMetricsError(f"{truth}: {len(labels):,} labels but {name} has {n_events:,} events (give the "
                                  "truth file written with that stream)")
    check_labelled(truth, fingerprint, seen, name)
    for undefined, none_of in (("FPR (and roc's AUC)", not np.any(labels != 0)), ("TPR", not np.any(labels == 0))):
        if none_of and len(labels):  # (the rate a null in the report stands for: said, not left to guess)
            what = "noise (shot, leak, hot)" if undefined.startswith("FPR") else "signal"
            log.warning(f"{truth}: no event of {name} is labelled {what}: the {undefined} is undefined (null)")
    return labels


@contextlib.contextmanager
def _naming(filtered: str, noisy: str):
    """A matching error names both streams."""
    try:
        yield
    except DenoiseMetricsError as error:
        raise DenoiseMetricsError(f"{filtered} against {noisy}: {error}") from None


def _feed_input(matcher: DenoiseMatcher, chunk: np.ndarray, labels: np.ndarray, name: str, truth: str) -> None:
    start = matcher.inputs_seen
    if start + len(chunk) > len(labels):
        raise DenoiseMetricsError(f"{truth}: {len(labels):,} labels but {name} has more events")
    matcher.add_input(chunk, labels[start:start + len(chunk)])


def _fmt(value: float) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.4f}"


def _clean(value):
    """NaN as null in JSON."""
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_clean(v) for v in value]
    return value


def _table(title: str, columns: list[str], rows: list[list[str]]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title, show_header=True, header_style="bold")
    for column in columns:
        table.add_column(column)
    for row in rows:
        table.add_row(*row)
    Console().print(table)


@click.command()
@click.argument("filtered", type=click.Path(dir_okay=False, allow_dash=True))
@click.option("--truth", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Truth file of the noisy stream (`evtools simulate ... --truth`): one label per event.")
@click.option("--input", "noisy", required=True, type=FileRead(),
              help="The noisy stream the filter read (FILTERED must be a subsequence of it).")
@json_option
def denoise(filtered, truth, noisy, as_json):
    """TPR (signal kept), FPR (noise kept), precision, F1 and per-label counts of FILTERED against NOISY.

    \b
    evtools simulate rec.aedat4 --shot-noise-rate-hz 5 --truth t.h5 -o noisy.aedat4
    evtools bafilter noisy.aedat4 --method stcf | evtools metrics denoise - --truth t.h5 --input noisy.aedat4
    """
    labels = _labels_for(truth, noisy)
    matcher = DenoiseMatcher()
    with open_events(noisy) as source, open_events(filtered) as output, _naming(output.name, noisy):
        inputs = iter(source)
        for chunk in with_progress(output, output, f"matching {output.name}"):
            matcher.add_output(chunk)
            while matcher._outputs:  # more input is needed to match what is held
                part = next(inputs, None)
                if part is None:
                    break
                _feed_input(matcher, part, labels, noisy, truth)
        for part in inputs:
            _feed_input(matcher, part, labels, noisy, truth)
        if output.was_cut and source.was_cut:  # (a filter's output of a cut input is marked cut too: a rescued
            # recording's filter is scored over what the input holds)
            log.warning(f"{output.name} and its input {noisy} are both marked cut: scored as the filter's whole "
                        "run over what the input holds (a filter stopped early would read as removing the rest)")
        elif output.was_cut:  # (a part of the filter's output scored against the whole input reads as a better filter)
            raise EvtoolsError(f"{output.name} was cut (its filter stopped early or its copy broken off): its score "
                               "against the whole input would count the missing part as removed; filter the whole "
                               "input again")
        score = matcher.finish()
    result = {"file": output.name, "input": noisy, **score.as_dict()}
    if wants_json(as_json):
        echo_json(_clean(result), indent=2)
        return
    rows = [[name, f"{result['labels'][name]['kept']:,}", f"{result['labels'][name]['total']:,}"]
            for name in LABEL_NAMES]
    _table(f"{output.name}: TPR {_fmt(score.tpr)}  FPR {_fmt(score.fpr)}  precision {_fmt(score.precision)}  "
           f"F1 {_fmt(score.f1)}", ["label", "kept", "total"], rows)


SWEEPABLE = {name.replace("_", "-"): uses[0][1].kind for name, uses in parameters().items()
             if uses[0][1].sweepable and uses[0][1].cli}
"""The filter parameters ``--sweep`` and ``--set`` take (command-line spelling -> kind), from the filters'
declarations."""


def _sweep(ctx, param, value):
    if "=" not in value:
        raise click.BadParameter("give PARAM=v1,v2,... e.g. dt-us=1000,2000,5000")
    name, values = value.split("=", 1)
    name = name.strip().lstrip("-").replace("_", "-")
    if name not in SWEEPABLE:
        raise click.BadParameter(f"cannot sweep {name!r}; choose among {', '.join(SWEEPABLE)}")
    if SWEEPABLE[name] == "time_us":  # times: microseconds, or with a unit (dt-us=1ms,3ms), as the options
        numbers = [MICROSECONDS.convert(v, param, ctx) for v in values.split(",") if v.strip()]
    else:
        try:
            numbers = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            raise click.BadParameter(f"values of {name} must be numbers, got {values!r}") from None
    if not numbers:
        raise click.BadParameter("no value to sweep")
    if SWEEPABLE[name] == "int":
        numbers = [int(v) if v == int(v) else v for v in numbers]
    return name.replace("-", "_"), numbers


def _settings(ctx, param, values):
    settings = {}
    for value in values:
        name, numbers = _sweep(ctx, param, value)
        if len(numbers) != 1:
            raise click.BadParameter(f"give one value: {value!r}")
        settings[name] = numbers[0]
    return settings


def _point_params(settings: dict, name: str, value, weights, polarity_maps: bool, stages) -> dict:
    """The filter parameters of one ROC point."""
    return {**settings, name: value, **({"weights": weights} if weights and "mlpf" in stages else {}),
            **({"polarity_maps": True} if polarity_maps and "stcf" in stages else {})}


def _score_filter(noisy: str, labels: np.ndarray, methods: str, preset: str, params: dict):
    matcher = DenoiseMatcher()
    with open_events(noisy) as stream:
        ba = BAFilter(stream.info.width, stream.info.height, methods, preset=preset, check=False, **params)
        for chunk in stream:
            matcher.add_input(chunk, labels[matcher.inputs_seen:matcher.inputs_seen + len(chunk)])
            matcher.add_output(ba.process(chunk))
        matcher.add_output(ba.flush())
    return matcher.finish()


@click.command()
@click.argument("noisy", type=FileRead())
@click.option("--truth", required=True, type=click.Path(exists=True, dir_okay=False),
              help="Truth file of NOISY (`evtools simulate ... --truth`).")
@click.option("-m", "--method", "methods", multiple=True, required=True, metavar="M[,M2...]",
              help=f"Filter (or chain) to sweep; repeat for several curves. Among {', '.join(METHODS)}.")
@click.option("--sweep", required=True, callback=_sweep, metavar="PARAM=v1,v2,...",
              help=f"Parameter and its values, one ROC point each ({', '.join(SWEEPABLE)}).")
@click.option("--preset", type=click.Choice(["evtools", "dv", "jaer"]), default="evtools", show_default=True)
@click.option("--weights", type=click.Path(exists=True, dir_okay=False), default=None,
              help="mlpf: weights from `evtools metrics train-denoiser` [the ones shipped with evtools].")
@click.option("--polarity-maps", is_flag=True, help="stcf: a time map per polarity (see bafilter).")
@click.option("--set", "settings", multiple=True, callback=_settings, metavar="PARAM=VALUE",
              help="Hold another parameter at a value for every point (repeat: --set radius=2 --set k=3).")
@click.option("--plot", type=click.Path(dir_okay=False), default=None,
              help="Draw the ROC curves, every point with its swept value, into this figure (.png, .svg, .pdf).")
@json_option
def roc(noisy, truth, methods, sweep, preset, weights, polarity_maps, settings, plot, as_json):
    """DND21 ROC of each --method over --sweep on NOISY: (FPR, TPR) per value, (0,0) and (1,1), trapezoid AUC.

    \b
    evtools metrics roc noisy.aedat4 --truth t.h5 --method baf --method stcf --sweep dt-us=1000,3000,10000,30000
    """
    name, values = sweep
    if name in settings:  # (the sweep's values were used, and "held" reported the --set one: a QA sweep)
        raise click.UsageError(f"{name.replace('_', '-')} is both swept (--sweep) and held (--set): give it once")
    for chain in methods:
        try:
            stages = parse_methods(chain)
            check_preset(stages, preset)
        except BAFilterError as error:
            raise click.BadParameter(str(error), param_hint="--method") from None
        unused = not_applying(stages, preset, [name, *settings])
        if unused:  # (every point would have been the same filter)
            raise click.UsageError(f"{', '.join(n.replace('_', '-') for n in unused)} do(es) not apply to --method "
                                   f"{chain} (--preset {preset})")
    chains = [parse_methods(chain) for chain in methods]
    for option, given, stage in (("--weights", weights, "mlpf"), ("--polarity-maps", polarity_maps, "stcf")):
        if given and not any(stage in stages for stages in chains):  # (silently ignored: a QA sweep)
            raise click.UsageError(f"{option} applies to --method {stage}, which no --method here runs")
    with open_events(noisy) as stream:  # every point's filter checked before any is run (exit 2, as bafilter's)
        width, height = stream.info.width, stream.info.height
    for chain, stages in zip(methods, chains):
        for value in values:
            try:
                BAFilter(width, height, chain, preset=preset, check=False,
                         **_point_params(settings, name, value, weights, polarity_maps, stages))
            except BAFilterError as error:
                if settings:  # (a held value may be the bad one: both named, not the sweep alone)
                    held = ", ".join(f"{key.replace('_', '-')}={number}" for key, number in settings.items())
                    raise click.UsageError(f"--method {chain} with {name.replace('_', '-')}={value} and --set "
                                           f"{held}: {error}") from None
                raise click.BadParameter(f"{name.replace('_', '-')}={value}: {error}", param_hint="--sweep") \
                    from None
    figure_path(plot, "--plot", (noisy, truth, weights))
    labels = _labels_for(truth, noisy)
    results, curves = [], []
    stopped = None  # a stop (Ctrl-C) ends the sweep: the point under way read part of the stream and is dropped
    for chain, stages in zip(methods, chains):
        points, rows = [], []
        for value in values:
            params = _point_params(settings, name, value, weights, polarity_maps, stages)
            score = _score_filter(noisy, labels, chain, preset, params)
            if interrupt.received() is not None:
                stopped = (f"stopped by {signal.Signals(interrupt.received()).name} at {chain} {name}={value}: "
                           "the curves after it are missing, this one's AUC is not given")
                break
            rows.append({"value": value, **score.as_dict()})
            points.append((score.fpr, score.tpr))
        if rows:
            curve, area = roc_auc(points)
            results.append({"method": chain, "parameter": name, "held": settings, "points": rows,
                            "auc": None if stopped else area, **({"complete": False} if stopped else {})})
            curves.append((chain, curve, area))
        if stopped:
            break
    if plot:
        from evtools.formats.figures import save_figure
        from evtools.plots import roc_figure

        save_figure(roc_figure([{"label": result["method"], "parameter": result["parameter"],
                                 "points": result["points"], "auc": result["auc"]} for result in results
                                if result["auc"] is not None]), plot)
    if stopped:
        log.warning(f"{noisy}: {stopped}")
    if wants_json(as_json):
        echo_json(_clean({"file": noisy, "preset": preset, "methods": results,
                          **({"stopped": stopped} if stopped else {})}), indent=2)
        return
    rows = []
    for result in results:
        for point in result["points"]:
            rows.append([result["method"], str(point["value"]), _fmt(point["tpr"]), _fmt(point["fpr"]),
                         _fmt(point["precision"]), _fmt(point["f1"]), ""])
        rows.append([result["method"], "", "", "", "", "", _fmt(result["auc"])])
    _table(f"ROC of {noisy}", ["method", name, "TPR", "FPR", "precision", "F1", "AUC"], rows)


@click.command()
@read_options
@click.option("--slice-events", type=click.IntRange(min=2), default=30_000, show_default=True,
              help="Events per slice (E-MLB: 30,000).")
@json_option
def esr(input, reading, slice_events, as_json):
    """E-MLB's event structural ratio per slice of IN and its mean, MESR (higher is better; no labels needed).

    Full slices only; a stream shorter than one slice is one slice (fewer than two events: no ESR, said).
    """
    with open_events(input, reading) as stream:
        meter = EsrMeter(stream.info.width, stream.info.height, slice_events)
        for chunk in with_progress(stream, stream, f"measuring {stream.name}"):
            meter.add(chunk)
        result = {"file": stream.name, **meter.finish()}
    if result["mesr"] is None or not np.isfinite(result["mesr"]):  # (null and exit 0 said nothing: a QA sweep)
        log.warning(f"{result['file']}: no ESR: a slice needs two events or more, and the stream has fewer")
    if wants_json(as_json):
        echo_json(_clean(result), indent=2)
        return
    _table(f"{result['file']}: MESR {_fmt(result['mesr'])}", ["slices", "slice events", "MESR"],
           [[str(result["slices"]), f"{slice_events:,}", _fmt(result["mesr"])]])
