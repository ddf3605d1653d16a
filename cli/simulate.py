"""``evtools simulate``: events from a video, a folder of images or a built-in scene, with the ground truth; or
labelled noise added to an event stream."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import sys
import time
from typing import Any, Iterator

import click
import numpy as np

from evtools import interrupt
from evtools.aps import APS_DEFAULTS, MAX_APS_RATE_HZ, ApsSensor
from evtools.cli.options import (FINITE, Duration, FiniteRange, Microseconds, aedat2_layout_option, echo_json,
                                 merged_alias, sensor_size_value, serve_early,
                                 check_compression, compression_option, input_format_option, reading_options)
from evtools.cli.progress import with_progress
from evtools.events import CHUNK_EVENTS, StreamInfo, join, parse_sensor_size
from evtools.noise import NOISE_DEFAULTS, NoiseInjector
from evtools.simulation import (
    DEFAULT_PARAMETERS,
    MIN_THRESHOLD,
    FLICKER_PROFILES,
    LABELS,
    PRESETS,
    DvsSimulator,
    lin_log,
    SimulationError,
    SimulationUsageError,
    scene_maker,
    scene_options,
)
from evtools.formats import create_events, open_events, stop_cut
from evtools.frames import FrameRelay
from evtools.formats.io import STDIO, HEAD_BYTES, TCP_PREFIX, same_file, same_target
from evtools.formats.registry import FORMATS, detect
from evtools.formats.truth import TruthWriter, create_truth
from evtools.formats.video import TIMESTAMPS_FILE, FrameSource, open_frames, read_image

log = logging.getLogger("evtools")

DEFAULT_SCENE_SIZE = "346x260"
"""A DAVIS346, the sensor v2e and the report emulate."""
DEFAULT_DURATION_US = 1_000_000

# -- frame sources -----------------------------------------------------------------------------------------------


def scene_source(name: str, size: tuple[int, int] | None, duration_us: int | None,
                 options: dict[str, Any]) -> FrameSource:
    make = scene_maker(name)
    width, height = parse_sensor_size(size or DEFAULT_SCENE_SIZE)
    duration_us = duration_us or DEFAULT_DURATION_US
    accepted = scene_options(name)
    for key in options:
        if key not in accepted:
            option = "--" + _SCENE_OPTIONS[key].replace("_", "-")
            raise SimulationUsageError(f"scene {name} has no option {option}")
    attributes = {"scene": name, "duration_us": duration_us, **options}
    if "image" in options:  # a path: the scene takes the image itself; the truth file records its name
        options = {**options, "image": read_image(options["image"])}
    frames = make(width, height, duration_us, **options)
    rate = options.get("frame_rate_hz", accepted["frame_rate_hz"].default)
    count = int(math.floor(duration_us * 1e-6 * rate + 1e-9)) + 1
    return FrameSource(f"scene:{name}", width, height, frames, count, attributes)


def open_source(source: str, size, duration, fps, timestamps, scene_options) -> FrameSource:
    if source.startswith("scene:"):
        return scene_source(source[len("scene:"):], size, duration, scene_options)
    if scene_options:
        raise click.UsageError("scene options (--period, --speed, ...) apply to scene:NAME sources only")
    if duration is not None:
        raise click.UsageError("--duration applies to scene:NAME sources only")
    if not os.path.exists(source):
        raise SimulationError(f"{source}: no such file or folder (a scene is given as scene:NAME)")
    if timestamps is not None and not os.path.isdir(source):
        raise click.UsageError("--timestamps applies to image folders only")
    return open_frames(source, fps, size, timestamps)


def is_event_stream(source: str, input_format: str | None) -> bool:
    """Whether SOURCE is an event stream: stdin, ``--input-format``, or a file the format registry recognises."""
    if source == STDIO or input_format:
        return True
    if source.startswith("scene:") or os.path.isdir(source) or not os.path.isfile(source):
        return False
    try:
        with open(source, "rb") as file:
            head = file.read(HEAD_BYTES)
    except OSError as error:
        raise SimulationError(f"{source}: cannot open ({error.strerror})") from None
    return detect(head, source) is not None


# -- the command ---------------------------------------------------------------------------------------------------

_SCENE_OPTIONS = {  # keyword of the scene functions -> command-line option
    "frame_rate_hz": "frame_rate",
    "period_s": "period",
    "profile": "profile",
    "phase": "phase",
    "phase_spread": "phase_spread",
    "speed_px_s": "speed",
    "wavelength_px": "wavelength",
    "bar_width_px": "bar_width",
    "orientation": "orientation",
    "min_level": "min_level",
    "max_level": "max_level",
    "level": "level",
    "image": "image",
}


def model_parameters(preset: str | None, given: dict[str, Any]) -> dict[str, Any]:
    """v2e's defaults, then the preset's values, then every option the user gave."""
    parameters = dict(DEFAULT_PARAMETERS)
    if preset:
        parameters.update(PRESETS[preset])
    parameters.update({key: value for key, value in given.items() if value is not None})
    return parameters


_PARAMETER_NAME = re.compile(
    r"\b(" + "|".join(sorted({*DEFAULT_PARAMETERS, *NOISE_DEFAULTS, "seed"}, key=len, reverse=True)) + r")\b"
)


def _build(model, *args, **parameters):
    """``model(*args, **parameters)`` with the options users typed (``--shot-noise-rate-hz``) in its errors in
    place of the Python parameter names (``shot_noise_rate_hz``) that the library uses."""
    try:
        return model(*args, **parameters)
    except SimulationError as error:
        flags = _PARAMETER_NAME.sub(lambda match: "--" + match.group(1).replace("_", "-"), str(error))
        raise SimulationError(flags) from None


def _progress(source: FrameSource) -> Iterator[tuple[int, np.ndarray]]:
    """Frames unchanged, with a progress bar on stderr when it is a terminal."""
    if not sys.stderr.isatty():
        yield from source.frames
        return
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    columns = [TextColumn("simulating {task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn()]
    with Progress(*columns, transient=True, console=Console(stderr=True)) as progress:
        task = progress.add_task(source.name, total=source.count)
        for item in source.frames:
            yield item
            progress.advance(task)


def _float_option(name: str, help: str, low: float | None = 0.0, high: float | None = None):
    """A number option of the pixel model, refused by click (a usage error, exit 2) outside ``low``..``high``."""
    return click.option(name, type=FiniteRange(low, high), default=None, help=help)


@click.command()
@click.argument("source", metavar="SOURCE")
@click.option(
    "-o", "--output", default="-", metavar="OUT", type=click.Path(dir_okay=False, allow_dash=True),
    callback=serve_early, help="Output event file; `-` or absent: stdout (AEDAT 4.0 unless --format says otherwise).",
)
@click.option(
    "--format", "output_format", default=None,
    type=click.Choice([f.name for f in FORMATS if f.writer], case_sensitive=False),
    help="Output format; default: from OUT's extension, AEDAT 4.0 on stdout.",
)
@click.option("--truth", type=click.Path(dir_okay=False), default=None,
              help="Write the ground truth (per-event `label`, noise maps, parameters; the thresholds maps `on`, "
                   "`off` for frame sources) to this HDF5 file.")
@click.option("--truth-frame-rate", "truth_frame_rate", type=FiniteRange(min=0), default=None, metavar="HZ",
              help="Frame sources: also store the true log intensity (`log_frames`, `log_frame_t_us`) in --truth "
                   "at this rate, for `metrics reconstruction` [default: 100; 0: none].")
@input_format_option
@click.option("--sensor-size", "sensor_size", callback=sensor_size_value, metavar="WxH", default=None, hidden=True,
              help="The same as --size (kept for older scripts).")
@aedat2_layout_option
@click.option("--size", callback=sensor_size_value, metavar="WxH", default=None,  # (out of range: exit 2)
              help=f"Sensor size of a scene (default {DEFAULT_SCENE_SIZE}); for a video or images: resize to it; "
                   "for an event stream that does not store it: its size.")
@click.option("--duration", type=Duration(), metavar="TIME", default=None,
              help="Scene length with its unit: 2s, 500ms, 1.5min (default 1s).")
@click.option("--fps", type=FiniteRange(min=0, min_open=True, max=1e6), default=None, hidden=True,
              help="The same as --frame-rate (kept for older scripts).")
@click.option("--timestamps", type=click.Path(dir_okay=False), default=None,
              help=f"Image folder: file of frame times, one per line in seconds (default: {TIMESTAMPS_FILE} "
                   "in the folder).")
@click.option("--preset", type=click.Choice(sorted(PRESETS)), default=None,
              help="v2e's parameter sets: clean (sigma 0.02, no low-pass, no noise) or noisy (sigma 0.05, "
                   "cutoff 30 Hz, leak 0.1 Hz, shot 5 Hz); options given explicitly override it.")
@_float_option("--pos-thres", "Mean ON threshold, log units (default 0.2).", low=MIN_THRESHOLD)
@_float_option("--neg-thres", "Mean OFF threshold, log units (default 0.2).", low=MIN_THRESHOLD)
@_float_option("--sigma-thres", "Per-pixel threshold standard deviation (default 0.03).")
@click.option("--thres-drift", "thres_drift", type=FINITE, default=None, metavar="PERCENT_PER_S",
              help="Every threshold drifts linearly by this percentage of its first value per second (default 0; "
                   "never below 5 % of that value).")
@_float_option("--correlated-sigma-thres", "Standard deviation of a spatially smooth threshold field (default 0).")
@_float_option("--correlated-length-px", "Correlation length of that field, pixels (default 10).")
@_float_option("--cutoff-hz", "Photoreceptor low-pass cutoff at full intensity; 0 = none (default).")
@click.option("--fixed-cutoff", is_flag=True, default=None,
              help="A plain single-pole low-pass: --cutoff-hz at every intensity (v2e's falls with intensity).")
@_float_option("--leak-rate-hz", "Leak (background activity) event rate per pixel (default 0.1; frame sources: "
               "a shot event resets the reference, so beside shot noise fewer leak events come out).")
@_float_option("--leak-spread-decades",
               "Per-pixel spread of the leak rate, decades (default 0.1; 0.5 for an event stream).")
@_float_option("--shot-noise-rate-hz",
               "Shot-noise rate per pixel in the dark (any intensity for an event stream), ON+OFF (default 0).")
@click.option("--refractory-us", type=Microseconds(minimum_us=0), default=None,
              help="Refractory period, microseconds (default 0).")
@_float_option("--hot-pixel-fraction", "Fraction of hot pixels (default 0).", high=1.0)
@_float_option("--hot-pixel-rate-hz", "Event rate of a hot pixel (default 100).")
@_float_option("--dead-pixel-fraction", "Fraction of dead pixels (default 0).", high=1.0)
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Seed of every random draw (default: a fresh one, recorded in --truth and the output's source).")
@click.option("--frame-rate", type=FiniteRange(min=0, min_open=True, max=1e6), default=None,
              help="Frame rate, Hz: of a scene (default 1000), of an image folder without timestamps, or to "
                   "override a video's.")
@click.option("--period", type=Duration(), default=None, metavar="TIME",
              help="flicker, step: period with its unit (default 500ms, 1s).")
@click.option("--profile", type=click.Choice(FLICKER_PROFILES), default=None,
              help="flicker: the wave is linear in intensity (default) or in log intensity.")
@click.option("--phase", type=FINITE, default=None, help="flicker: the wave's phase at time 0, periods (0 = valley).")
@click.option("--phase-spread", type=FiniteRange(min=0), default=None, metavar="PERIODS",
              help="flicker: delay each pixel by its own random fraction of PERIODS periods (default 0).")
@click.option("--speed", type=FINITE, default=None,
              help="gradient, bars, texture: speed in pixels per second (default 50).")
@click.option("--image", type=click.Path(dir_okay=False), default=None, metavar="FILE",
              help="texture: any image file (PNG, JPEG, ...) as the texture, in place of the built-in one.")
@click.option("--wavelength", type=FiniteRange(min=0, min_open=True), default=None,
              help="gradient: rise-and-fall length, pixels (default 64).")
@click.option("--bar-width", type=FiniteRange(min=0, min_open=True), default=None,
              help="bars: bar width, pixels (default 8).")
@click.option("--orientation", type=click.Choice(["vertical", "horizontal"]), default=None, help="bars: direction.")
@click.option("--min-level", type=FiniteRange(0, 255), default=None,
              help="Scene's darkest intensity, 0-255 (default 50).")
@click.option("--max-level", type=FiniteRange(0, 255), default=None,
              help="Scene's brightest intensity, 0-255 (default 200).")
@click.option("--level", type=FiniteRange(0, 255), default=None, help="static: intensity, 0-255 (default 128).")
@compression_option
@click.option("--aps-rate", "aps_rate_hz", type=FiniteRange(min=0, max=MAX_APS_RATE_HZ, min_open=True), default=None,
              metavar="HZ",
              help="Also record APS frames (a DAVIS camera's intensity images) at this rate, into the output with "
                   "the events (AEDAT 4.0 or HDF5) and, with --truth, their true log intensity (`aps/`).")
@click.option("--aps-exposure", "aps_exposure_us", type=Duration(minimum_us=1), default=None, metavar="TIME",
              help=f"APS exposure (global shutter) [default: {APS_DEFAULTS['aps_exposure_us'] // 1000}ms].")
@click.option("--aps-gain", type=FiniteRange(min=0), default=None, metavar="DN",
              help=f"APS gain, DN per intensity level (0-255) per ms of exposure "
                   f"[default: {APS_DEFAULTS['aps_gain']}].")
@click.option("--aps-black-level", type=FiniteRange(min=0), default=None, metavar="DN",
              help=f"APS black level [default: {APS_DEFAULTS['aps_black_level']:g}].")
@click.option("--aps-read-noise", type=FiniteRange(min=0), default=None, metavar="DN",
              help=f"APS read noise, standard deviation [default: {APS_DEFAULTS['aps_read_noise']:g}].")
@click.option("--aps-gain-fpn", type=FiniteRange(min=0), default=None, metavar="FRACTION",
              help=f"Per-pixel gain non-uniformity, standard deviation [default: {APS_DEFAULTS['aps_gain_fpn']:g}].")
@click.option("--aps-offset-fpn", type=FiniteRange(min=0), default=None, metavar="DN",
              help=f"Per-pixel offset non-uniformity, standard deviation "
                   f"[default: {APS_DEFAULTS['aps_offset_fpn']:g}].")
@click.option("--json", "as_json", is_flag=True,
              help="Print the counts as JSON (on stdout when the events go to a file, else on stderr).")
def simulate(source, output, output_format, truth, truth_frame_rate, input_format, sensor_size, aedat2_layout, size,
             duration, fps, timestamps, preset, seed, as_json, **options):
    """Simulate a DVS looking at SOURCE: a video file, a folder of images, or scene:NAME; or add labelled noise
    to SOURCE when it is an event stream (any readable format, `-` for stdin).

    Scenes: flicker, gradient, bars, step, static, texture (a natural-looking texture moving, turning and zooming;
    --image FILE to use your own). The pixel model is v2e's (lin-log, low-pass, threshold
    mismatch, leak, shot noise, hot and dead pixels) with ESIM's per-pixel crossing times. On an event stream
    only the noise is added (leak, shot, hot pixels), each noise event labelled in --truth, the stream's own
    events unchanged (label 0): the way denoisers are measured on real recordings.

    \b
    evtools simulate scene:flicker --size 64x48 --duration 2s --truth truth.h5 -o flicker.aedat4
    evtools simulate video.mp4 --preset noisy --seed 1 | evtools info -
    evtools simulate recording.aedat4 --shot-noise-rate-hz 5 --leak-rate-hz 0.2 --truth t.h5 -o noisy.aedat4
    """
    started = time.perf_counter()
    if truth is not None and truth.startswith(TCP_PREFIX):  # (before any work, and before -o is made)
        raise click.UsageError(f"--truth {truth}: the truth is HDF5, a file (it cannot be served on a network "
                               "output); give --truth FILE")
    compression = options.pop("compression")
    check_compression(compression, [(source, output)], output_format)
    aps = {name: options.pop(name) for name in ("aps_rate_hz", *APS_DEFAULTS)}
    aps = {name: value for name, value in aps.items() if value is not None}
    if aps and "aps_rate_hz" not in aps:
        named = [f"--{n.replace('_us', '').replace('_', '-')}" for n in aps]
        raise click.UsageError(f"{', '.join(named)} {'requires' if len(named) == 1 else 'require'} --aps-rate")
    size = merged_alias("--size", size, "--sensor-size", sensor_size)
    fps = options["frame_rate"] = merged_alias("--frame-rate", options["frame_rate"], "--fps", fps)
    given = {name: value for name, value in options.items() if value is not None}
    if is_event_stream(source, input_format):
        if aps:
            raise click.UsageError("--aps-rate: APS frames are simulated from a scene, a video or images, not added "
                                   "to an event stream")
        sensor_size, size = (parse_sensor_size(size) if size else None), None
        frame_only = [name for name, value in (("--size", size), ("--duration", duration),
                                               ("--timestamps", timestamps),
                                               ("--truth-frame-rate", truth_frame_rate)) if value is not None]
        frame_only += ["--" + name.replace("_", "-") for name in given if name not in NOISE_DEFAULTS]
        if frame_only:
            raise click.UsageError(
                f"{', '.join(frame_only)}: not for an event stream, which gets only noise (leak, shot, hot "
                f"pixels)"
            )
        parameters = {key: value for key, value in model_parameters(preset, {}).items() if key in NOISE_DEFAULTS}
        parameters["leak_spread_decades"] = NOISE_DEFAULTS["leak_spread_decades"]
        parameters.update({key: value for key, value in given.items()})
        reading = reading_options(format=input_format, sensor_size=sensor_size, aedat2_layout=aedat2_layout)
        _inject(source, output, (output_format, compression), truth, preset, seed, parameters, reading, as_json,
                started)
        return
    for name, value in (("--input-format", input_format), ("--aedat2-layout", aedat2_layout)):
        if value is not None:
            raise click.UsageError(f"{name} applies to event-stream sources only")
    scene_options = {}
    for keyword, name in _SCENE_OPTIONS.items():
        value = options.pop(name)
        if value is not None:
            scene_options[keyword] = value * 1e-6 if name == "period" else value
    if not source.startswith("scene:"):
        scene_options.pop("frame_rate_hz", None)  # a video's or an image folder's rate: passed as fps

    drift_percent = options.pop("thres_drift")
    if drift_percent is not None:
        options["thres_drift_per_s"] = drift_percent / 100.0
    parameters = model_parameters(preset, options)
    frames = open_source(source, size, duration, fps, timestamps, scene_options)
    simulator = _build(DvsSimulator, frames.width, frames.height, seed=seed, **parameters)
    _check_truth_path(truth, output, source)
    description = f"evtools simulate {frames.name} seed={simulator.seed}"
    info = StreamInfo(frames.width, frames.height, metadata={"source": description})
    inputs = (source,) if not source.startswith("scene:") else ()
    counts = np.zeros(len(LABELS), np.int64)
    sensor = None
    if aps:
        sensor = _build(ApsSensor, frames.width, frames.height, aps.pop("aps_rate_hz"), seed=simulator.seed, **aps)
        info.metadata["frame_size"] = (frames.width, frames.height)
    with _outputs(truth, output, info, output_format, compression, inputs) as (writer, truth_writer):
        if truth_writer is None:
            _run(simulator, frames, writer, None, counts, aps=_Aps(sensor, None) if sensor else None)
            writer.cut = frames.was_cut  # (a video broken off: its events are a cut stream)
        else:
            _start_truth(truth_writer, simulator, frames, preset)
            rate_hz = TRUTH_FRAME_RATE_HZ if truth_frame_rate is None else truth_frame_rate
            _run(simulator, frames, writer, truth_writer, counts,
                 _LogFrames(truth_writer, frames, rate_hz) if rate_hz else None,
                 _Aps(sensor, truth_writer) if sensor else None)
            writer.cut = frames.was_cut
            _mark_cut(truth_writer, frames.was_cut, inputs)
            if simulator.drift_origin_us is not None:  # (the truth's maps are the thresholds at this time)
                truth_writer.write_attributes({"thres_drift_origin_us": simulator.drift_origin_us})
    _report(source, output, counts, as_json, started)


@contextlib.contextmanager
def _outputs(truth, output, info, output_format, compression, inputs):
    """``(events writer, truth writer or None)``: the truth file is completed only after the events are (a failed
    events output, a full disk or a closed pipe, left a complete truth file of events that no output held)."""
    with contextlib.ExitStack() as stack:
        truth_writer = stack.enter_context(create_truth(truth)) if truth is not None else None
        writer = stack.enter_context(create_events(output, info, format=output_format, compression=compression,
                                                   inputs=inputs))
        yield writer, truth_writer


def _start_truth(truth: TruthWriter, simulator: DvsSimulator, frames: FrameSource, preset: str | None) -> None:
    truth.write_maps({"on": simulator.on_thres, "off": simulator.off_thres, "hot_pixels": simulator.hot_pixels,
                      "dead_pixels": simulator.dead_pixels,
                      "leak_rate_hz": simulator.leak_rate_map_hz.astype(np.float32)})
    truth.write_attributes({
        **simulator.parameters,
        "width": frames.width,
        "height": frames.height,
        "source": frames.name,
        "preset": preset or "",
        "labels": ", ".join(f"{code} {name}" for code, name in LABELS.items()),
        **{f"source_{key}": value for key, value in frames.attributes.items()},
        "source_kind": _frames_kind(frames),
    })


def _frames_kind(frames: FrameSource) -> str:
    if "scene" in frames.attributes:
        return "scene"
    return "images" if "images" in frames.attributes else "video"


class _LabelledSink:
    """Buffers events and their labels to about a million, then writes the events and appends the labels to the
    truth file (``truth``: a :class:`TruthWriter`, None: no truth file), so both stay in output order."""

    def __init__(self, writer, truth: TruthWriter | None, counts: np.ndarray) -> None:
        self.writer, self.truth, self.counts = writer, truth, counts
        self.pending, self.pending_labels, self.held = [], [], 0

    def add(self, events: np.ndarray, labels: np.ndarray) -> None:
        if len(events):
            self.counts += np.bincount(labels, minlength=len(self.counts))[:len(self.counts)]
            self.pending.append(events)
            self.pending_labels.append(labels)
            self.held += len(events)
            if self.held >= CHUNK_EVENTS:
                self.write()

    def write(self) -> None:
        if not self.held:
            return
        events = join(self.pending) if len(self.pending) > 1 else self.pending[0]
        self.writer.write(events)
        if self.truth is not None:
            self.truth.append_labels(np.concatenate(self.pending_labels), events)
        self.pending, self.pending_labels, self.held = [], [], 0


TRUTH_FRAME_RATE_HZ = 100.0
"""Default rate of the true log-intensity frames in a truth file (``--truth-frame-rate``)."""


class _LogFrames:
    """Appends the scene's true log intensity (the pixel model's lin-log of the frame) to the truth file: the first
    frame, then the first at or after every further ``1 / rate``, on the events' clock, a frame at a time."""

    def __init__(self, truth: TruthWriter, frames: FrameSource, rate_hz: float) -> None:
        self.period_us = 1e6 / rate_hz
        self.next_us = None
        self.truth = truth
        truth.start_log_frames(frames.width, frames.height, rate_hz)

    def add(self, t_us: int, frame: np.ndarray) -> None:
        if self.next_us is not None and t_us < self.next_us:
            return
        self.next_us = (t_us if self.next_us is None else self.next_us) + self.period_us
        self.truth.append_log_frame(t_us, lin_log(frame))


class _Aps:
    """The APS of a simulation: its frames go to the output after the events before them (the events held are
    written first), their truth to the truth file's ``aps/`` group (:meth:`TruthWriter.start_aps`)."""

    def __init__(self, sensor: ApsSensor, truth: TruthWriter | None) -> None:
        self.sensor, self.truth = sensor, truth
        if truth is not None:
            truth.start_aps(sensor.gain_map, sensor.offset_map, sensor.parameters)

    def add(self, t_us: int, frame: np.ndarray, sink: "_LabelledSink") -> None:
        for done in self.sensor.add(t_us, frame):
            sink.write()
            sink.writer.write_frame(done.frame)
            if self.truth is not None:
                self.truth.append_aps({"t_us": done.frame.t_us, "exposure_begin_us": done.frame.exposure_begin_us,
                                       "exposure_end_us": done.frame.exposure_end_us, "log_intensity": done.true_log,
                                       "mean_intensity": done.mean_intensity})


def _run(simulator: DvsSimulator, frames: FrameSource, writer, truth: TruthWriter | None, counts,
         log_frames=None, aps: _Aps | None = None) -> None:
    sink = _LabelledSink(writer, truth, counts)
    with interrupt.consuming():  # Ctrl-C / SIGTERM: stop after the frame at hand, outputs complete
        for t_us, frame in _progress(frames):
            if log_frames is not None:
                log_frames.add(int(t_us), frame)
            sink.add(*simulator.process_labelled(t_us, frame))
            if aps is not None:
                aps.add(int(t_us), frame, sink)
            if interrupt.received() is not None:
                break
    sink.add(*simulator.flush_labelled())
    sink.write()


def _mark_cut(truth: TruthWriter, input_cut: bool, inputs: tuple[str, ...]) -> None:
    """A truth file whose events file is marked cut (its input was cut, or a stop ended the reading of the input or
    the simulation early) says so too (attributes ``cut``, ``cut_by``): its labels end where the events do."""
    stop = stop_cut(inputs)
    if input_cut or stop is not None:
        truth.write_attributes({"cut": True, "cut_by": "a cut input" if input_cut else f"stopped by {stop}"})


# -- noise on an event stream --------------------------------------------------------------------------------------


def _check_truth_path(truth: str | None, output: str | None, source: str) -> None:
    if truth is None:
        return
    if same_target(truth, output):
        raise SimulationError("--truth and -o name the same file; give two different files")
    if same_file(truth, source):
        raise SimulationError(f"{truth}: --truth would overwrite the input; choose another file")


def _inject(source, output, written_as, truth, preset, seed, parameters, reading, as_json, started) -> None:
    counts = np.zeros(len(LABELS), np.int64)
    _inject_into(source, output, written_as, truth, preset, seed, parameters, reading, counts)
    _report(source, output, counts, as_json, started, events_in=int(counts[0]))  # (label 0: the input's events)


def _report(source: str, output: str | None, counts: np.ndarray, as_json: bool, started: float,
            events_in: int | None = None) -> None:
    """The one-line summary on stderr (not with -q); with --json, the same as JSON (on stdout when the events go
    to a file, else on stderr), with the other commands' keys (``input``, ``output``, ``seconds``; an event
    stream's noise: ``events_in`` and ``events_out`` too)."""
    per_label = {name: int(counts[code]) for code, name in LABELS.items()}
    summary = {"command": "simulate", "input": source, "output": output or STDIO, "events": int(counts.sum()),
               **per_label}
    if events_in is not None:
        summary.update(events_in=events_in, events_out=summary["events"])
    summary["seconds"] = round(time.perf_counter() - started, 6)
    if as_json:
        echo_json(summary, err=output in (None, STDIO))
        return
    log.info(f"simulate: {summary['events']:,} events ("
             + ", ".join(f"{count:,} {name}" for name, count in per_label.items()) + ")")


def _inject_into(source, output, written_as, truth, preset, seed, parameters, reading, counts) -> None:
    """``evtools simulate EVENTS``: the stream's events unchanged plus labelled noise, chunk by chunk; the output
    ``written_as`` (format, compression)."""
    output_format, compression = written_as
    _check_truth_path(truth, output, source)
    with open_events(source, reading) as stream:
        width, height = stream.info.width, stream.info.height
        injector = _build(NoiseInjector, width, height, seed=seed, **parameters)
        info = StreamInfo(width, height, metadata={"source": f"evtools simulate {stream.name} seed={injector.seed}"})
        if "frame_size" in stream.info.metadata:  # (an AEDAT 4.0 output declares its frame stream up front)
            info.metadata["frame_size"] = stream.info.metadata["frame_size"]
        with _outputs(truth, output, info, output_format, compression, (source,)) as (writer, truth_writer):
            if truth_writer is None:
                _run_injector(injector, stream, writer, None, counts)
                writer.cut = getattr(stream, "was_cut", False)  # (a cut input's output says so too)
                return
            truth_writer.write_maps({"hot_pixels": injector.hot_pixels,
                                     "leak_rate_hz": injector.leak_rate_map_hz.astype(np.float32)})
            truth_writer.write_attributes({
                **injector.parameters,
                "width": width,
                "height": height,
                "source": stream.name,
                "source_kind": "events",
                "source_format": stream.info.format,
                "preset": preset or "",
                "labels": ", ".join(f"{code} {name}" for code, name in LABELS.items()),
            })
            first, last = _run_injector(injector, stream, writer, truth_writer, counts)
            writer.cut = getattr(stream, "was_cut", False)
            _mark_cut(truth_writer, writer.cut, (source,))
            if first is not None:  # the noise spans the input's events, these two times included
                truth_writer.write_attributes({"t_first_us": first, "t_last_us": last})


def _run_injector(injector: NoiseInjector, stream, writer, truth: TruthWriter | None, counts) -> tuple[int, int]:
    """Feed the stream through the injector into the writer (and the labels into the truth file); returns the
    times of the first and last input events."""
    sink = _LabelledSink(writer, truth, counts)
    frames = FrameRelay(stream, writer)  # the input's APS frames, each once the output has reached it
    first = last = None

    for chunk in with_progress(stream, stream, f"adding noise to {stream.name}"):
        if first is None:
            first = int(chunk["t"][0])
        last = int(chunk["t"][-1])
        for events, labels in injector.process_pieces(chunk):
            sink.add(events, labels)
        if frames.due(last):  # (the output is final before the last input event: noise there is held)
            sink.write()
            frames.release(last)
    sink.add(*injector.flush())
    sink.write()
    frames.release(None)
    return first, last
