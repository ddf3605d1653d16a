"""``evtools bafilter``: background-activity filters, one or several stages in one streaming pass."""

from __future__ import annotations

import logging
import os

import click
import numpy as np

from evtools.cli.batch import Outcome, batch_options, plan, run
from evtools.cli.options import (MICROSECONDS, FiniteRange, IntRange, check_compression, compression_option,
                                 slicing_options)
from evtools.cli.progress import process_stream
from evtools.filters import (METHODS, PRESETS, BAFilter, BAFilterError, Param, check_preset, not_applying,
                             parse_methods)
from evtools.filters.chain import checked_parameters
from evtools.filters.registry import option_help, parameters
from evtools.formats import create_events, open_events
from evtools.formats.hotpixels import HotPixelsError, read_hot_pixels, write_hot_pixels
from evtools.formats.io import STDIO, same_file, same_target
from evtools.transform import on_sliced_sensor, sliced

log = logging.getLogger("evtools")


def _check_hot_pixels_target(path: str, input: str, output: str | None) -> None:
    """The hot-pixel list may not replace the input, nor share a file or stdout with the events."""
    if path == STDIO:
        if output in (None, STDIO):
            raise HotPixelsError("--save-hot-pixels - and the events cannot both go to stdout; give -o FILE")
    elif same_file(path, input):
        raise HotPixelsError(f"{path}: the hot-pixel list would overwrite the input; choose another --save-hot-pixels")
    elif same_target(path, output):
        raise HotPixelsError(f"{path}: the hot-pixel list and the events would share a file; choose another "
                             "--save-hot-pixels")


def _methods(ctx, param, value):
    try:
        return parse_methods(value)
    except BAFilterError as error:
        raise click.BadParameter(str(error)) from None


FILTER_PREFIX = "filter_"
"""The Python names of the filter options start with this; the command takes it off."""


def _click_type(declarations: list[Param]):
    """The option's type from the parameter's declarations (one name, several filters: the loosest bounds)."""
    kind = declarations[0].kind
    lows = [p.low for p in declarations if p.low is not None]
    highs = [p.high for p in declarations]
    high = None if any(h is None or callable(h) for h in highs) else max(highs)
    if kind == "time_us":
        return MICROSECONDS
    if kind == "int":  # (at most an int32 on the command line, as every count option)
        return IntRange(min(lows), min(high, 2**31 - 1) if high is not None else 2**31 - 1)
    if kind == "float":
        return FiniteRange(min=min(lows))
    if kind == "probability":
        return FiniteRange(0.0, 1.0, min_open=True, max_open=True)
    if kind == "weights":
        return click.Path(exists=True, dir_okay=False)
    raise ValueError(f"no command-line type for {kind}")


def filter_options(command):
    """One click option per filter parameter of :data:`evtools.filters.REGISTRY` (default None: the preset's),
    typed, named and documented from the declarations; the command gets them as ``params`` (``filter_NAME``)."""
    for name, uses in reversed(list(parameters().items())):
        declarations = [param for _, param in uses]
        first = declarations[0]
        if not first.cli:
            continue
        if any(param.kind != first.kind or param.option != first.option for param in declarations):
            raise TypeError(f"filter parameter {name} is declared with different kinds or options")
        flags = [first.flag or first.option, FILTER_PREFIX + name]  # (prefixed: --polarity is the slicing's)
        if first.kind == "bool":
            switch = {} if "/" in flags[0] else {"is_flag": True}  # --on/--off, or a flag alone
            command = click.option(*flags, default=None, help=option_help(name), **switch)(command)
        else:
            command = click.option(*flags, type=_click_type(declarations), default=None,
                                   help=option_help(name))(command)
    return command


@click.command()
@batch_options
@click.option("-m", "--method", "methods", default="baf", callback=_methods, metavar="M[,M2...]", show_default=True,
              help=f"Filter(s), applied in order: {', '.join(METHODS)}.")
@click.option("--preset", type=click.Choice(PRESETS), default="evtools", show_default=True,
              help="Semantics and defaults: evtools (maps start long ago), dv (dv-processing's "
                   "BackgroundActivityNoiseFilter, baf only), jaer (jAER's filters).")
@filter_options
@click.option("--hot-pixels", "hot_pixels_path", type=click.Path(dir_okay=False), default=None,
              help="hotpixel: drop the pixels of this CSV list (`x,y` lines) instead of learning.")
@click.option("--save-hot-pixels", "save_hot_pixels", type=click.Path(dir_okay=False), default=None,
              help="hotpixel: write the hot pixels (learned or given) to this CSV file, or draw them on the "
                   "learning stretch's rate map (.png, .svg, .pdf).")
@compression_option
@slicing_options
def bafilter(inputs, reading, output, jobs, scheduler, as_json, methods, preset,
             hot_pixels_path, save_hot_pixels, compression, slicing, **params):
    """Remove background activity from IN (default stdin), writing OUT or -o OUT (default stdout).

    Several inputs go to the folder -o FOLDER (the same names), --jobs at a time.

    \b
    evtools bafilter recording.aedat4 -o clean.aedat4 --method stcf --k 2
    evtools bafilter noisy.aedat4 --method hotpixel,refractory,stcf | evtools info -
    evtools bafilter rec.aedat4 --method baf --preset dv -o dv.aedat4   # dv-processing's exact output
    evtools bafilter recordings/*.aedat4 -o clean/ --jobs 4           # one output per input, same names

    A stage sees only the events the stages before it kept; within a stage a rejected event still updates the
    time map. Prints `N in, K kept, R removed` on stderr (not with -q).
    """
    try:
        check_preset(methods, preset)
    except BAFilterError as error:
        raise click.UsageError(str(error)) from None
    given = {name[len(FILTER_PREFIX):]: value for name, value in params.items() if value is not None}
    unused = not_applying(methods, preset, given)
    if unused:  # (was ignored: `-m baf --k 3` ran baf as if --k were not there)
        flags = ", ".join(next(param.option for _, param in parameters()[name]) for name in unused)
        raise click.UsageError(f"{flags} do(es) not apply to --method {','.join(methods)} (--preset {preset})")
    try:  # (a value out of its range is a usage error: exit 2)
        checked_parameters(methods, preset, given)
    except BAFilterError as error:
        raise click.UsageError(str(error)) from None
    if (hot_pixels_path or save_hot_pixels) and "hotpixel" not in methods:
        raise click.UsageError("--hot-pixels and --save-hot-pixels need --method hotpixel")
    learning = [name for name in ("learn_us", "hot_ratio", "hot_rate_hz", "hot_min_events") if name in given]
    if hot_pixels_path and learning:  # (a list given learns nothing: they were accepted and ignored, a QA sweep)
        raise click.UsageError(f"{', '.join('--' + name.replace('_', '-') for name in learning)}: nothing is learned "
                               "with --hot-pixels FILE (the list is the hot pixels)")
    if save_hot_pixels == STDIO and output in (None, STDIO):
        raise click.UsageError("--save-hot-pixels - and the events cannot both go to stdout; give -o FILE")
    pairs = plan(inputs, output, ".aedat4", check=lambda pairs: check_compression(compression, pairs))
    if save_hot_pixels and len(pairs) > 1:
        raise click.UsageError("--save-hot-pixels writes one file: give one input")
    options = dict(reading=reading, methods=methods,
                   preset=preset, params=given, hot_pixels_path=hot_pixels_path, save_hot_pixels=save_hot_pixels,
                   compression=compression, slicing=slicing)
    run(filter_one, pairs, options, jobs, scheduler, as_json)


def filter_one(input, output, *, reading, methods, preset, params=None,
               hot_pixels_path=None, save_hot_pixels=None, compression=None, slicing=None) -> Outcome:
    """Filter one file (the command's whole work for one input): its :class:`Outcome` (events in, kept).

    ``reading``: how to read the input (:class:`evtools.formats.ReadOptions`); ``params``: the filters'
    parameters given (:class:`evtools.filters.BAFilter`); ``slicing``: the shared slicing options
    (:func:`evtools.transform.sliced`), applied as the events are read."""
    if save_hot_pixels:
        _check_hot_pixels_target(save_hot_pixels, input, output)
    with open_events(input, reading) as opened:
        stream = sliced(opened, slicing)
        info = stream.info
        hot_map = None
        if hot_pixels_path:  # the list is in the file's coordinates
            hot_map = on_sliced_sensor(stream, read_hot_pixels(hot_pixels_path, opened.info.width,
                                                               opened.info.height))
        ba = BAFilter(info.width, info.height, methods, preset=preset, check=False,  # checked by the reader
                      **(params or {}), **({"hot_map": hot_map} if hot_map is not None else {}))
        with create_events(output, info, compression=compression, inputs=(input,)) as writer:
            process_stream(stream, ba, writer, f"filtering {stream.name}")
            if save_hot_pixels:  # inside the output's block: when the list cannot be written, no output is left
                hot = ba.hot_map if ba.hot_map is not None else np.zeros((info.height, info.width), bool)
                if os.path.splitext(save_hot_pixels)[1].lower() in (".png", ".svg", ".pdf"):
                    from evtools.formats.figures import save_figure
                    from evtools.plots import hot_pixels_figure

                    stage = next(stage for stage in ba.stages if stage.name == "hotpixel")
                    counts = getattr(stage, "counts", None)
                    save_figure(hot_pixels_figure(hot, None if counts is None else counts.reshape(hot.shape),
                                                  getattr(stage, "learned_duration_s", 0.0)), save_hot_pixels)
                else:
                    write_hot_pixels(save_hot_pixels, hot)
    removed = ba.events_in - ba.events_out
    share = removed / ba.events_in if ba.events_in else 0.0
    log.info(f"bafilter {','.join(methods)}: {ba.events_in:,} in, {ba.events_out:,} kept, {removed:,} removed "
             f"({100 * share:.1f} %)")
    kept = 1 - share if ba.events_in else 0.0
    return Outcome(ba.events_in, ba.events_out, {"kept_fraction": round(kept, 6)}, f"{100 * kept:.1f} % kept",
                   stream.was_cut)
