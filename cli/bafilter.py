"""``evtools bafilter``: background-activity filters, one or several stages in one streaming pass."""

from __future__ import annotations

import logging
import os

import click
import numpy as np

from evtools.cli.batch import Outcome, batch_options, plan, run
from evtools.cli.options import (COUNT, MICROSECONDS, FiniteRange, check_compression, compression_option,
                                 slicing_options)
from evtools.cli.progress import process_stream
from evtools.filters import DEFAULTS, METHODS, PRESETS, BAFilter, BAFilterError, parse_methods
from evtools.formats import create_events, open_events
from evtools.formats.hotpixels import HotPixelsError, read_hot_pixels, write_hot_pixels
from evtools.formats.io import STDIO, same_file
from evtools.transform import on_sliced_sensor, sliced

log = logging.getLogger("evtools")


def _check_hot_pixels_target(path: str, input: str, output: str | None) -> None:
    """The hot-pixel list may not replace the input, nor share a file or stdout with the events."""
    if path == STDIO:
        if output in (None, STDIO):
            raise HotPixelsError("--save-hot-pixels - and the events cannot both go to stdout; give -o FILE")
    elif input != STDIO and same_file(path, input):
        raise HotPixelsError(f"{path}: the hot-pixel list would overwrite the input; choose another --save-hot-pixels")
    elif output not in (None, STDIO) and (os.path.abspath(path) == os.path.abspath(output) or same_file(path, output)):
        raise HotPixelsError(f"{path}: the hot-pixel list and the events would share a file; choose another "
                             "--save-hot-pixels")


def _methods(ctx, param, value):
    try:
        return parse_methods(value)
    except BAFilterError as error:
        raise click.BadParameter(str(error)) from None




@click.command()
@batch_options
@click.option("-m", "--method", "methods", default="baf", callback=_methods, metavar="M[,M2...]", show_default=True,
              help=f"Filter(s), applied in order: {', '.join(METHODS)}.")
@click.option("--preset", type=click.Choice(PRESETS), default="evtools", show_default=True,
              help="Semantics and defaults: evtools (maps start long ago), dv (dv-processing's "
                   "BackgroundActivityNoiseFilter, baf only), jaer (jAER's filters).")
@click.option("--dt-us", type=MICROSECONDS, default=None,
              help="Correlation window (baf, stcf, orderN) or refractory period, us [evtools: 10000, refractory "
                   "100; dv: 2000; jaer: 25000].")
@click.option("--k", type=COUNT, default=None, help="stcf: correlated neighbours needed [2]; dwf: events [1].")
@click.option("--radius", type=click.IntRange(1, 10), default=None, help="stcf neighbourhood radius [1].")
@click.option("--same-polarity/--any-polarity", "same_polarity", default=None,
              help="stcf: count neighbours of the event's polarity only, or of any [same].")
@click.option("--polarity-maps", is_flag=True, default=None,
              help="stcf: a time map per polarity: a neighbour's last event of the event's polarity counts even if "
                   "one of the other polarity came after it.")
@click.option("--window", type=click.IntRange(1, 1 << 16), default=None,
              help="dwf: length of each FIFO window [36; jaer 256].")
@click.option("--distance", type=click.IntRange(1, 1 << 16), default=None,
              help="dwf: L1 distance, support when < this [9; jaer 5].")
@click.option("--learn-us", type=MICROSECONDS, default=None, help="hotpixel: learning stretch, us [1000000].")
@click.option("--hot-ratio", type=FiniteRange(min=1.0), default=None,
              help="hotpixel: hot when >= this times its 4 neighbours' largest count [5].")
@click.option("--hot-rate-hz", type=FiniteRange(min=0.0), default=None,
              help="hotpixel: hot when its rate is at least this [10000].")
@click.option("--hot-min-events", type=COUNT, default=None,
              help="hotpixel: a hot pixel has at least this many events in the stretch [20].")
@click.option("--hot-pixels", "hot_pixels_path", type=click.Path(dir_okay=False), default=None,
              help="hotpixel: drop the pixels of this CSV list (`x,y` lines) instead of learning.")
@click.option("--save-hot-pixels", "save_hot_pixels", type=click.Path(dir_okay=False), default=None,
              help="hotpixel: write the hot pixels (learned or given) to this CSV file, or draw them on the "
                   "learning stretch's rate map (.png, .svg, .pdf).")
@click.option("--threshold", type=FiniteRange(0.0, 1.0, min_open=True, max_open=True), default=None,
              help="mlpf: keep an event when its probability of being signal is above this [0.5].")
@click.option("--weights", type=click.Path(exists=True, dir_okay=False), default=None,
              help="mlpf: weights from `evtools metrics train-denoiser` [the ones shipped with evtools].")
@compression_option
@slicing_options
def bafilter(inputs, input_format, sensor_size, aedat2_layout, output, jobs, scheduler, as_json, methods, preset,
             dt_us, k, radius, same_polarity, window, distance, learn_us, hot_ratio, hot_rate_hz, hot_min_events,
             hot_pixels_path, save_hot_pixels, threshold, weights, polarity_maps, compression, slicing):
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
    missing = [method for method in methods if method not in DEFAULTS[preset]]
    if missing:
        raise click.UsageError(f"--preset {preset} has no method {', '.join(missing)} (it has "
                               f"{', '.join(DEFAULTS[preset])}); use --preset evtools")
    used = {name for method in methods for name in DEFAULTS[preset][method]}
    unused = [flag for flag, name, value in (
        ("--dt-us", "dt_us", dt_us), ("--k", "k", k), ("--radius", "radius", radius),
        ("--same-polarity/--any-polarity", "polarity", same_polarity),
        ("--polarity-maps", "polarity_maps", polarity_maps), ("--window", "window", window),
        ("--distance", "distance", distance), ("--learn-us", "learn_us", learn_us),
        ("--hot-ratio", "hot_ratio", hot_ratio), ("--hot-rate-hz", "hot_rate_hz", hot_rate_hz),
        ("--hot-min-events", "hot_min_events", hot_min_events)) if value is not None and name not in used]
    if unused:  # (was ignored: `-m baf --k 3` ran baf as if --k were not there)
        raise click.UsageError(f"{', '.join(unused)} do(es) not apply to --method {','.join(methods)} "
                               f"(--preset {preset})")
    if (hot_pixels_path or save_hot_pixels) and "hotpixel" not in methods:
        raise click.UsageError("--hot-pixels and --save-hot-pixels need --method hotpixel")
    if (threshold is not None or weights) and "mlpf" not in methods:
        raise click.UsageError("--threshold and --weights need --method mlpf")
    if save_hot_pixels == STDIO and output in (None, STDIO):
        raise click.UsageError("--save-hot-pixels - and the events cannot both go to stdout; give -o FILE")
    pairs = plan(inputs, output, ".aedat4", check=lambda pairs: check_compression(compression, pairs))
    if save_hot_pixels and len(pairs) > 1:
        raise click.UsageError("--save-hot-pixels writes one file: give one input")
    options = dict(input_format=input_format, sensor_size=sensor_size, aedat2_layout=aedat2_layout, methods=methods,
                   preset=preset, dt_us=dt_us, k=k, radius=radius, polarity=same_polarity, window=window,
                   distance=distance, learn_us=learn_us, hot_ratio=hot_ratio, hot_rate_hz=hot_rate_hz,
                   hot_min_events=hot_min_events, hot_pixels_path=hot_pixels_path, save_hot_pixels=save_hot_pixels,
                   threshold=threshold, weights=weights, polarity_maps=polarity_maps, compression=compression,
                   slicing=slicing)
    run(filter_one, pairs, options, jobs, scheduler, as_json)


def filter_one(input, output, *, input_format, sensor_size, aedat2_layout, methods, preset, dt_us, k, radius,
               polarity, window, distance, learn_us, hot_ratio, hot_rate_hz, hot_min_events, hot_pixels_path,
               save_hot_pixels, threshold=None, weights=None, polarity_maps=None, compression=None,
               slicing=None) -> Outcome:
    """Filter one file (the command's whole work for one input): its :class:`Outcome` (events in, kept); ``slicing``: the
    shared slicing options (:func:`evtools.transform.sliced`), applied as the events are read."""
    if save_hot_pixels:
        _check_hot_pixels_target(save_hot_pixels, input, output)
    with open_events(input, format=input_format, sensor_size=sensor_size, aedat2_layout=aedat2_layout) as opened:
        stream = sliced(opened, slicing)
        info = stream.info
        hot_map = None
        if hot_pixels_path:  # the list is in the file's coordinates
            hot_map = on_sliced_sensor(stream, read_hot_pixels(hot_pixels_path, opened.info.width,
                                                               opened.info.height))
        ba = BAFilter(info.width, info.height, methods, preset=preset, dt_us=dt_us, k=k, radius=radius,
                      polarity=polarity, window=window, distance=distance, learn_us=learn_us, hot_ratio=hot_ratio,
                      hot_rate_hz=hot_rate_hz, hot_min_events=hot_min_events, hot_map=hot_map, threshold=threshold,
                      weights=weights, polarity_maps=polarity_maps, check=False)  # checked by the reader
        with create_events(output, info, compression=compression, inputs=(input,)) as writer:
            process_stream(stream, ba, writer, f"filtering {stream.name}")
            if save_hot_pixels:  # inside the output's block: when the list cannot be written, no output is left
                hot = ba.hot_map if ba.hot_map is not None else np.zeros((info.height, info.width), bool)
                if os.path.splitext(save_hot_pixels)[1].lower() in (".png", ".svg", ".pdf"):
                    from evtools.formats.figures import save_figure
                    from evtools.plots import hot_pixels_figure

                    stage = next(stage for stage in ba.stages if stage.method == "hotpixel")
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
    return Outcome(ba.events_in, ba.events_out, {"kept_fraction": round(kept, 6)}, f"{100 * kept:.1f} % kept")
