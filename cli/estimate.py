"""``evtools estimate``: every pixel's ON and OFF contrast thresholds from an event stream, into an HDF5 file."""

from __future__ import annotations

import contextlib
from functools import partial
import logging
import math
import signal

import click
import numpy as np

from evtools.cli.batch import Outcome, batch_options, plan, run
from evtools.cli.options import COUNT, MICROSECONDS, Duration, FiniteRange, slicing_options
from evtools.cli.progress import consume
from evtools.transform import sliced
from evtools.estimation import (
    DEFAULT_MAX_ERROR,
    DEFAULT_MAX_FIT,
    DEFAULT_MIN_EVENTS,
    DEFAULT_NOMINAL,
    DEFAULT_RADIUS_PX,
    DEFAULT_SEGMENT_US,
    METHODS,
    PHASES,
    DescriptionError,
    EstimationError,
    Stimulus,
    ThresholdEstimator,
)
from evtools.estimation_frames import DEFAULT_MAX_FRAME_FIT, FrameScaledEstimator, FrameThresholdEstimator
from evtools.events import MAX_SENSOR_SIDE, MAX_THRESHOLD
from evtools.formats import open_events
from evtools.formats.io import TCP_PREFIX, same_file
from evtools import interrupt
from evtools.errors import EvtoolsError
from evtools.formats.thresholds import ThresholdMap, camera_of, series_file, write_thresholds

log = logging.getLogger("evtools")

DEFAULT_LEVELS = (50.0, 200.0)


def _levels(ctx, param, value):
    if value is None:
        return None
    try:
        low, high = (float(v) for v in value.split(","))
    except ValueError:
        raise click.BadParameter(f"{value!r} is not LOW,HIGH (e.g. 50,200)") from None
    if not low < high or not all(map(math.isfinite, (low, high))):
        raise click.BadParameter(f"need LOW < HIGH, got {value!r}")
    return low, high


MAX_LOG_AMPLITUDE = 10.0
"""A log-intensity triangle of more than this many log units (a contrast of 22,000) is no display's: a mistake."""


def _stimulus(levels, period_us, profile, amplitude, speed, wavelength, rise) -> Stimulus:
    """The stimulus the options describe (click usage errors for contradictory ones)."""
    if (speed is None) != (wavelength is None):
        raise click.UsageError("a moving stimulus needs both --stimulus-speed and --stimulus-wavelength")
    if amplitude is not None:
        if levels is not None or profile == "intensity":
            raise click.UsageError("--stimulus-amplitude is a triangle linear in log intensity: give it without "
                                   "--stimulus-levels and --stimulus-profile intensity")
        levels, profile = (0.0, amplitude), "log"
    profile = profile or "intensity"
    if levels is None:
        if profile == "log":
            raise click.UsageError("--stimulus-profile log needs --stimulus-amplitude A or --stimulus-levels L0,L1 "
                                   "(log units)")
        levels = DEFAULT_LEVELS
    if profile == "intensity" and not 0 <= levels[0] < levels[1] <= 255:
        raise click.BadParameter(f"intensities need 0 <= LOW < HIGH <= 255, got {levels[0]:g},{levels[1]:g}",
                                 param_hint="--stimulus-levels")
    if profile == "log" and levels[1] - levels[0] > MAX_LOG_AMPLITUDE:  # (simulate's --profile log levels are 0-255)
        hint = (f": did you mean --stimulus-amplitude {math.log(levels[1] / levels[0]):.4g} (the log of "
                f"{levels[1]:g} / {levels[0]:g}, intensities as simulate's --min-level and --max-level)?"
                if 0 < levels[0] < levels[1] <= 255 else "")
        raise click.BadParameter(f"with --stimulus-profile log the levels are log intensities, and {levels[0]:g},"
                                 f"{levels[1]:g} is {levels[1] - levels[0]:g} log units peak to peak, a contrast "
                                 f"no display shows (at most {MAX_LOG_AMPLITUDE:g}){hint}", param_hint="--stimulus-levels")
    if speed is not None:
        return Stimulus.moving(*levels, speed, wavelength, profile, rise)
    return Stimulus(*levels, period_us, 0.0, profile, rise)


def _number_or(word: str, noun: str, positive: bool, largest: float = math.inf):
    """A click callback: the value as a float (positive, or from 0; at most ``largest``), or the ``word`` itself
    (or None)."""

    def callback(ctx, param, value):
        if value is None or value == word:
            return value
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise click.BadParameter(f"{value!r} is not {noun} or '{word}'") from None
        if not math.isfinite(number) or (number <= 0 if positive else number < 0) or number > largest:
            raise click.BadParameter(f"{value!r} is not {noun}")
        return number

    return callback


_nominal = _number_or("frames", f"a threshold (a positive number of log units up to {MAX_THRESHOLD:g})", positive=True,
                      largest=MAX_THRESHOLD)
_black_level = _number_or("fit", "a DN (a number from 0)", positive=False)


@click.command()
@batch_options(output_help="The thresholds file (HDF5: a file, never stdout), or with several inputs the folder that "
                           "gets one NAME.h5 per input.")
@click.option("--method", type=click.Choice(METHODS + ("frames",)), default="offe", show_default=True,
              help="offe: Wang et al.'s events-only least squares (relative, scaled by --nominal); stimulus: the "
                   "known calibration stimulus (absolute, exact for an ideal pixel); natural: an ordinary moving "
                   "scene, each pixel's event counts against its neighbours' (relative, scaled by --nominal); "
                   "frames: a DAVIS recording's events and APS frames (absolute, Wang et al.'s offEI; onEI with "
                   "--online).")
@click.option("--segment-us", type=MICROSECONDS, default=DEFAULT_SEGMENT_US, show_default=True,
              help="offe: segment length, microseconds.")
@click.option("--nominal", type=str, default=str(DEFAULT_NOMINAL), show_default=True, metavar="THETA|frames",
              callback=_nominal,
              help="offe: the median pixel's threshold; natural: the mean of on and off (log units); events alone "
                   "do not give the scale. `frames`: the scale (per polarity) from a DAVIS recording's APS frames "
                   "(offline; --black-level as for --method frames).")
@click.option("--radius", type=click.IntRange(1, MAX_SENSOR_SIDE), default=DEFAULT_RADIUS_PX, show_default=True,
              metavar="PX",
              help="natural: each pixel is compared with the pixels within PX of it.")
@click.option("--online", is_flag=True,
              help="stimulus, natural, frames: also write a map every --interval, each from the events so far "
                   "with exponential forgetting (a time series: on, off, valid with a leading time axis, and t_us); "
                   "`correct --thresholds` then uses, at each event, the latest map estimated before it.")
@click.option("--interval", type=Duration(), default=None, metavar="TIME",
              help="--online: time between maps, with its unit (default 1s).")
@click.option("--forget", type=Duration(), default=None, metavar="TIME",
              help="--online: time constant of the forgetting, with its unit (default 3 intervals).")
@click.option("--min-events", type=COUNT, default=DEFAULT_MIN_EVENTS, show_default=True,
              help="Pixels with fewer events are marked invalid (and get the median).")
@click.option("--max-fit", type=FiniteRange(min=0, min_open=True, infinite=True), default=None, metavar="F",
              help=f"Pixels that fit worse are invalid (the fit map). stimulus: the RMS deviation of their level "
                   f"changes, in thresholds (default {DEFAULT_MAX_FIT}); natural: the relative disagreement of two "
                   f"halves of the stream (and the other error terms: see the README); offe: the relative "
                   f"disagreement with the natural estimate, or natural's own fit or its own sampling error where "
                   f"larger (default {DEFAULT_MAX_ERROR}; inf: offE's reference exactly); frames: the predicted "
                   f"relative error of its thresholds (default {DEFAULT_MAX_FRAME_FIT}).")
@click.option("--stimulus-amplitude", type=FiniteRange(min=0, min_open=True), default=None, metavar="A",
              help="stimulus: a triangle linear in log intensity, A log units peak to peak (the same as "
                   "--stimulus-profile log --stimulus-levels 0,A; the base level does not matter).")
@click.option("--stimulus-levels", callback=_levels, default=None, metavar="LOW,HIGH",
              help="stimulus: the triangle's ends: intensities 0-255 (profile intensity, default 50,200: "
                   "simulate's --min-level, --max-level) or log intensities (profile log).")
@click.option("--stimulus-period", type=Duration(), default="500ms", show_default=True, metavar="TIME",
              help="stimulus: time of one rise and fall, with its unit (flicker; simulate's --period).")
@click.option("--stimulus-profile", type=click.Choice(["intensity", "log"]), default=None,
              help="stimulus: the triangle is linear in intensity (default; simulate's scenes) or in log intensity.")
@click.option("--stimulus-rise", type=FiniteRange(0, 1, min_open=True, max_open=True), default=0.5,
              show_default=True, metavar="FRACTION",
              help="stimulus: the fraction of a period spent rising (0.5 a symmetric triangle, 0.9 nearly a sawtooth).")
@click.option("--stimulus-phase", type=click.Choice(PHASES), default="fit", show_default=True,
              help="stimulus: fit each pixel's phase to its own events (any delay, start time or moving pattern), "
                   "or take it as given: the low end at t = 0 (simulate's scenes; a gradient delayed by column).")
@click.option("--stimulus-speed", type=FiniteRange(min=0, min_open=True), default=None, metavar="PX/S",
              help="stimulus: a moving gradient's speed (simulate's --speed); with --stimulus-wavelength it "
                   "replaces --stimulus-period.")
@click.option("--stimulus-wavelength", type=FiniteRange(min=0, min_open=True), default=None, metavar="PX",
              help="stimulus: a moving gradient's rise-and-fall length (simulate's --wavelength).")
@click.option("--black-level", default=None, metavar="DN|fit", callback=_black_level,
              help="frames: the APS frames' value of no light [default: 0, as DV's black-subtracted DAVIS frames]; "
                   "`fit`: estimated from the data (approximate: give it when known).")
@slicing_options
def estimate(inputs, reading, output, jobs, scheduler, as_json,
             method, segment_us, nominal, radius, online,
             interval, forget, min_events,
             max_fit, stimulus_amplitude, stimulus_levels, stimulus_period, stimulus_profile, stimulus_rise,
             stimulus_phase, stimulus_speed, stimulus_wavelength, black_level, slicing):
    """Estimate every pixel's ON and OFF contrast thresholds from IN (default stdin), streaming, into -o FILE.

    Several inputs go to the folder -o FOLDER, one NAME.h5 each, --jobs at a time.

    \b
    evtools estimate flicker.aedat4 -o thresholds.h5                       # offE, 10 ms segments
    evtools estimate flicker.aedat4 -o t.h5 --method stimulus --stimulus-levels 50,200 --stimulus-period 500ms
    evtools estimate monitor.aedat4 -o t.h5 --method stimulus --stimulus-amplitude 1.5 --stimulus-period 2s
    evtools estimate gradient.aedat4 -o t.h5 --method stimulus --stimulus-speed 50 --stimulus-wavelength 64
    evtools bafilter noisy.aedat4 --method stcf --k 1 --dt-us 100000 | evtools estimate - -o t.h5 --method stimulus
    evtools bafilter street.aedat4 | evtools estimate - -o t.h5 --method natural      # any long moving scene
    evtools estimate davis.aedat4 -o t.h5 --method natural --nominal frames  # scale from a DAVIS's APS frames
    evtools estimate drifting.aedat4 -o series.h5 --method stimulus --online --interval 1s   # maps over time
    """
    if output is None or output == "-":
        raise click.UsageError("the thresholds file is HDF5 and cannot go to stdout: give -o THRESHOLDS.h5 (or -o "
                               "FOLDER for several inputs)")
    if not online and (interval is not None or forget is not None):
        raise click.UsageError("--interval and --forget apply to --online estimation")
    scaled_by_frames = nominal == "frames"
    if scaled_by_frames and method not in ("natural", "offe"):
        raise click.UsageError("--nominal frames scales --method natural or offe (--method frames is absolute already)")
    if scaled_by_frames and online:
        raise click.UsageError("--nominal frames works offline (an online map needs --nominal as a number)")
    if method != "frames" and not scaled_by_frames and black_level is not None:
        raise click.UsageError("--black-level applies to --method frames and --nominal frames")
    if online and method == "offe":
        raise click.UsageError("--online works with --method stimulus, natural or frames (offE fits each pixel's "
                               "whole history)")
    interval_us = (interval or 1_000_000) if online else None
    stimulus = None
    if method == "stimulus":
        stimulus = _stimulus(stimulus_levels, stimulus_period, stimulus_profile, stimulus_amplitude, stimulus_speed,
                             stimulus_wavelength, stimulus_rise)
        slices = slicing or {}
        moved = (slices.get("crop") or (0,))[0] != 0 or slices.get("flip_x") or slices.get("transpose")
        if stimulus.wavelength_px and stimulus_phase == "given" and moved:  # (the delay is the camera's column's)
            raise click.UsageError("--stimulus-phase given delays the camera's columns, which --crop (from a column "
                                   "other than 0), --flip-x and --transpose move: use --stimulus-phase fit")
    if output is not None and output.startswith(TCP_PREFIX):  # (before any work: the map is HDF5)
        raise click.UsageError(f"-o {output}: the thresholds map is HDF5, a file (it cannot be served on a network "
                               "output); give -o FILE")
    pairs = plan(inputs, output, ".h5", second_is_output=False)
    options = dict(reading=reading,
                   parameters=dict(method=method, nominal=nominal, segment_us=segment_us, stimulus=stimulus,
                                   phase=stimulus_phase, min_events=min_events, max_fit=max_fit, radius_px=radius,
                                   interval_us=interval_us, forget_us=forget,
                                   **({"black_level": black_level} if method == "frames" or scaled_by_frames
                                      else {})), slicing=slicing)
    run(estimate_one, pairs, options, jobs, scheduler, as_json)


SPARSE_CHECK_MAPS = 10
"""Online: after this many maps the command line checks how much each adds (:class:`_MapsToFile`)."""
SPARSE_MAP_EVENTS = 0.01
"""Online: maps that add fewer events a pixel than this each are mostly empty (the walk at ``--interval 100us``:
6e-6): an error, since nothing bounds the file but the disk (a map is 13 bytes a pixel; ``--interval 1us`` on a
1 s flicker asked for 9.3 GiB, a QA sweep)."""


def _duration(us: float) -> str:
    """``us`` with a unit --interval takes (3 digits)."""
    return f"{us / 1e6:.3g}s" if us >= 1e6 else f"{us / 1e3:.3g}ms" if us >= 1e3 else f"{us:.3g}us"


class _Stopped(Exception):
    """A stop signal seen between two online maps (:class:`_MapsToFile`)."""


class _MapsToFile:
    """The online maps' way into the file (the estimator's ``map_sink``): each written as it comes, a warning after
    :data:`SPARSE_CHECK_MAPS` when they are mostly empty, and, while the stream is consumed, a stop (Ctrl-C) seen at
    the next map (:class:`_Stopped`): one chunk of a sparse stream, or a short interval, can make thousands of maps,
    and the reader sees a stop only at its next chunk."""

    def __init__(self, maps_file, name: str, width: int, height: int, to_camera) -> None:
        self.file, self.name, self.width, self.height = maps_file, name, width, height
        self.to_camera = to_camera  # a map of the (sliced) stream's sensor on the camera's
        self.estimator = None
        self.consuming = True

    def __call__(self, t_us, on, off, valid, fit) -> None:
        if self.consuming and interrupt.received() is not None:
            raise _Stopped
        self.file.append(t_us, *self.to_camera(on, off, valid, fit))
        if self.file.count == SPARSE_CHECK_MAPS and self.estimator is not None:
            per_map = self.estimator.events / (self.file.count * self.width * self.height)
            if per_map < SPARSE_MAP_EVENTS:  # (an error: nothing else would stop it before the disk is full)
                interval_us = self.estimator.interval_us
                raise EstimationError(
                    f"each online map adds {per_map:.2g} events a pixel (over the first {self.file.count}): the maps "
                    f"would be empty and the file grow by {13 * self.width * self.height / 2**20:.2g} MiB a map, "
                    f"{1e6 / interval_us * 13 * self.width * self.height / 2**30:.3g} GiB a second of the stream; "
                    f"give an --interval of at least {_duration(interval_us / per_map)} (about one event a pixel a "
                    "map)")

    def finish_partial(self, message: str) -> None:
        """The maps so far as a complete file, marked as stopped by ``message``."""
        estimator = self.estimator
        self.file.finish({**estimator.parameters, "input": self.name, "partial": True, "stopped_by": message,
                          "stopped_at_us": int(estimator.t_last_us or 0),
                          "width": self.file.datasets["on"].shape[2], "height": self.file.datasets["on"].shape[1]})


def _stopped_by() -> str:
    """The ``stopped_by`` attribute of a map made when a stop signal ended the run."""
    return f"stopped by {signal.Signals(interrupt.received()).name}"


def _part_of_the_stream(stream, estimator) -> dict:
    """The attributes of a map made from part of its stream: a stop signal ended the stream (``partial``,
    ``stopped_by``, ``stopped_at_us``, as a stopped online run's maps), or its file was cut (``cut``); readers of
    the map say so (:func:`evtools.formats.thresholds.open_thresholds`)."""
    said = {}
    if interrupt.received() is not None:
        said = {"partial": True, "stopped_by": _stopped_by(),
                "stopped_at_us": int(estimator.t_last_us or 0)}
    if stream.was_cut:
        said["cut"] = "estimated from a recording that was cut (its events up to the cut)"
    return said


def _on_camera(transform, *maps):
    """``maps`` (of the stream's sensor: sliced by ``transform``, or None) on the camera's whole sensor: not valid
    (False, NaN) outside the crop (:meth:`evtools.transform.Transform.camera_pixels`); None stays None."""
    if transform is None or not transform.moves_pixels:
        return maps
    return tuple(None if values is None else transform.camera_pixels(
        np.asarray(values), False if np.asarray(values).dtype == bool else np.nan) for values in maps)


def _slicing_argv(slicing: dict) -> list[str]:
    """The geometry options of ``slicing`` as the command line gives them (for the map's attributes)."""
    said = [f"--crop {','.join(map(str, slicing['crop']))}"] if slicing.get("crop") else []
    return said + [f"--{name.replace('_', '-')}" for name in ("flip_x", "flip_y", "transpose") if slicing.get(name)]


def estimate_one(input, output, *, reading, parameters, slicing=None
                 ) -> Outcome:
    """Estimate one file's thresholds into ``output``: its :class:`Outcome` (events in, valid pixels);
    ``slicing``: the shared slicing options (:func:`evtools.transform.sliced`): estimated on the sliced stream,
    the map is the camera's (not valid outside the crop), as ``correct`` takes it.

    Online, the maps go to the file as they are made (:func:`series_file`: no bound on the run's length but the
    disk's), and a run that stops midway keeps them: on an error in the stream, or a stop signal between maps, the
    file is complete, with the attributes ``partial``, ``stopped_by`` and ``stopped_at_us``."""
    if same_file(output, input):
        raise EstimationError(f"{output}: the thresholds file would overwrite the input; choose another -o")
    online = parameters.get("interval_us") is not None
    failure = sink = None
    with open_events(input, reading) as opened:
        stream = sliced(opened, slicing)
        width, height = stream.info.width, stream.info.height
        to_camera = partial(_on_camera, getattr(stream, "transform", None))
        with series_file(output, opened.info.width, opened.info.height) if online else contextlib.nullcontext() \
                as maps_file:
            if online:
                sink = _MapsToFile(maps_file, stream.name, width, height, to_camera)
            try:
                kind = (FrameThresholdEstimator if parameters["method"] == "frames" else FrameScaledEstimator
                        if parameters["nominal"] == "frames" else ThresholdEstimator)
                estimator = kind(width, height, check=False, **parameters, **({"map_sink": sink} if online else {}))
                if online:
                    sink.estimator = estimator
                consume(stream, estimator, f"estimating from {stream.name}")
                if online:
                    sink.consuming = False  # (the final map is written whatever comes)
                result = estimator.result()
                if parameters["method"] == "frames" and not (result.valid.any() or online and maps_file.any_valid):
                    raise EstimationError(estimator.why_none_valid(result.attributes))
            except _Stopped:
                if maps_file.count == 0:
                    raise interrupt.StopReading from None  # (no map: no file)
                sink.finish_partial(_stopped_by())
                return Outcome(estimator.events, None, {"maps": maps_file.count, "partial": True},
                               f"{maps_file.count} maps (stopped)")
            except EvtoolsError as error:
                if online and maps_file.failed:
                    raise  # (the file could not be written: its own error, no partial file)
                if interrupt.received() is not None and not (online and maps_file.count):
                    # a stop ended the stream before it held enough to estimate from: the stop's word, not the
                    # data's ("no events", "too few events a pixel")
                    raise interrupt.StopReading from None
                message = str(error) if str(error).startswith(stream.name) else f"{stream.name}: {error}"
                if not online or maps_file.count == 0 or sink.estimator is None or isinstance(error, DescriptionError):
                    raise type(error)(message) from None  # (maps made with a refused description: none kept)
                sink.finish_partial(message)
                failure = EstimationError(f"{message} (at {estimator.t_last_us:,} us); the {maps_file.count} maps "
                                          f"made up to {maps_file.last_t_us:,} us are written to {output} "
                                          "(attribute partial)")
            else:
                camera = camera_of(opened.info.metadata.get("source"))  # (correct says when it meets another)
                attributes = {**result.attributes, "input": stream.name, **({"camera": camera} if camera else {}),
                              **_part_of_the_stream(stream, estimator)}
                for said in ("disagreement", "brightness_dependence", "black_level_fitted", "black_level_disagrees",
                              "polarity_balance"):
                    if said in attributes:
                        log.warning(f"{stream.name}: {attributes[said]}")
                if getattr(stream, "transform", None) is not None and stream.transform.moves_pixels:
                    attributes["sliced"] = ("the map is the camera's; estimated on its events cut and turned "
                                            f"({' '.join(_slicing_argv(slicing))}): other pixels are not valid")
                    attributes["width"], attributes["height"] = opened.info.width, opened.info.height
                if online:
                    phase_us, = to_camera(result.phase_us) if result.phase_us is not None else (None,)
                    maps_file.finish(attributes, phase_us)
    if failure is not None:
        raise failure
    thresholds = ThresholdMap(result.on, result.off, result.valid, attributes, result.fit, result.phase_us)
    if not online:
        on, off, valid, fit, phase_us = to_camera(result.on, result.off, result.valid, result.fit, result.phase_us)
        write_thresholds(output, ThresholdMap(on, off, valid, attributes, fit, phase_us))
    usable = thresholds.usable()  # (the stream's pixels: the counts below are of those estimated from)
    on, off = thresholds.on, thresholds.off
    medians = f", median ON {np.median(on[usable]):.3g} OFF {np.median(off[usable]):.3g}" if usable.any() else ""
    maps = f", {attributes['maps']} maps over time" if online else ""
    log.info(f"estimate {parameters['method']}: {result.attributes['events']:,} events, {int(usable.sum()):,} of "
             f"{usable.size:,} pixels estimated ({100 * usable.mean():.1f} %){medians}{maps} -> {output}")
    valid = int(usable.sum())
    return Outcome(result.attributes["events"], None,
                   {"valid_pixels": valid, "pixels": int(usable.size), "valid_fraction": round(valid / usable.size, 6)},
                   f"{valid:,} of {usable.size:,} pixels valid ({100 * valid / usable.size:.1f} %)",
                   "cut" in attributes)
