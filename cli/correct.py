"""``evtools correct``: online threshold-mismatch correction, every pixel re-sampled at one target threshold."""

from __future__ import annotations

import logging
from dataclasses import replace
from functools import partial

import click
import numpy as np

from evtools.cli.batch import Outcome, batch_options, plan, run
from evtools.cli.options import (MICROSECONDS, Microseconds, check_compression, compression_option,
                                 slicing_options)
from evtools.cli.progress import process_stream
from evtools.correction import CORRECT_DEFAULTS, MAX_WINDOW_US, MODES, CorrectionError, ThresholdCorrector
from evtools.events import MAX_THRESHOLD, MAX_TIME_US
from evtools.formats import create_events, open_events
from evtools.formats.thresholds import camera_of, open_thresholds, per_map
from evtools.transform import on_sliced_sensor, sliced

log = logging.getLogger("evtools")


def _target(ctx, param, value):
    if value.strip().lower() == "median":
        return "median"
    try:
        number = float(value)
    except ValueError:
        raise click.BadParameter(f"{value!r} is neither a number nor 'median'") from None
    if not 0 < number <= MAX_THRESHOLD:
        raise click.BadParameter(f"the target threshold must be a positive number of log units up to "
                                 f"{MAX_THRESHOLD:g}, got {value}")
    return number


@click.command()
@batch_options
@click.option("--thresholds", "thresholds_path", required=True, metavar="FILE.h5",
              type=click.Path(),
              help="Per-pixel thresholds: from `evtools estimate` or the truth file of `evtools simulate`.")
@click.option("--target", default=str(CORRECT_DEFAULTS["target"]), show_default=True, callback=_target,
              metavar="THETA|median",
              help="The threshold every pixel is re-sampled at (log units), or the median of the maps.")
@click.option("--mode", type=click.Choice(list(MODES)), default=CORRECT_DEFAULTS["mode"], show_default=True,
              help="foh: the report's first-order hold; step: its step-aware variant (held over gaps > --hold-us); "
                   "turns: step anchored at the stream's start, each polarity reversal's extremum where the lines "
                   "of the runs on both sides meet (exact on log-linear ramps); "
                   "exponential: turns, and where a run slows down the exponential approach through its last three "
                   "events, with the tail the pixel no longer fires for (a photoreceptor low-pass after a step); "
                   "highpass: turns plus a decay of the carried level over rests. foh, step and highpass are kept "
                   "for comparison: each can make a stream worse than no correction (README).")
@click.option("--hold-us", type=Microseconds(maximum_us=MAX_WINDOW_US), default=CORRECT_DEFAULTS["hold_us"],
              show_default=True,
              help="All but foh: a gap longer than this is a rest (held constant, no interpolation).")
@click.option("--max-gap-us", type=Microseconds(maximum_us=MAX_WINDOW_US), default=CORRECT_DEFAULTS["max_gap_us"],
              show_default=True, help="Interpolation never reaches further back than this: bounds latency/memory; "
                                      "all but foh: a longer gap is a rest (the hold at most this).")
@click.option("--tau-us", type=MICROSECONDS, default=int(CORRECT_DEFAULTS["tau_us"]),
              show_default=True, help="highpass: time constant of the decay of the carried level over a rest.")
@click.option("--start-us", type=Microseconds(minimum_us=-MAX_TIME_US), default=None, metavar="T",
              help="exponential, turns, highpass: time the sensor started (every pixel at its reference), at or "
                   "before the first event; default: the first event.")
@compression_option
@slicing_options
def correct(inputs, reading, output, jobs, scheduler, as_json, thresholds_path,
            target, mode, hold_us, max_gap_us, tau_us, start_us, compression, slicing):
    """Re-sample every pixel of IN (default stdin) at one target threshold; write -o OUT (default stdout).

    Several inputs (one camera's recordings) go to the folder -o FOLDER.

    Each pixel's events are read as samples of its log intensity at its own thresholds (--thresholds), the
    signal reconstructed between them and sampled again at --target: the founding report's section 4.2, online
    and event by event. Pixels without a usable estimate are passed on as they are.

    \b
    evtools correct flicker.aedat4 --thresholds thresholds.h5 -o corrected.aedat4
    evtools correct step.aedat4 --thresholds step.truth.h5 --mode foh | evtools info -
    evtools correct drifting.aedat4 --thresholds series.h5 --target 0.2 -o corrected.aedat4  # estimate --online
    """
    pairs = plan(inputs, output, ".aedat4", check=lambda pairs: check_compression(compression, pairs))
    options = dict(reading=reading,
                   thresholds_path=thresholds_path, target=target, mode=mode, hold_us=hold_us,
                   max_gap_us=max_gap_us, tau_us=tau_us, start_us=start_us, compression=compression, slicing=slicing)
    run(correct_one, pairs, options, jobs, scheduler, as_json)


def _check_camera(map_camera, stream_source, thresholds_path: str, name: str) -> None:
    """Warn when the map was estimated on another camera than the stream's (both named by DV's source, model and
    serial, e.g. DAVIS346_00000104): a pixel's thresholds are its own camera's (another camera's map was applied
    without a word, a QA sweep)."""
    stream_camera = camera_of(stream_source)
    if map_camera and stream_camera and str(map_camera) != stream_camera:
        log.warning(f"{thresholds_path}: its thresholds were estimated on camera {map_camera}, but {name} was "
                    f"recorded by {stream_camera}: each pixel's thresholds are its own camera's")


class _EndBound:
    """The corrector's output within ``--end``: a run's excess and a tail re-sampled after a pixel's last event lie
    up to 3 tau beyond it (the output ran 200 ms past the slice, so corrected windows overlapped end to end)."""

    def __init__(self, corrector: ThresholdCorrector, transform) -> None:
        self.corrector, self.transform = corrector, transform
        self.released_us = corrector.released_us

    def _within(self, parts):
        for part in parts:
            yield part[:int(np.searchsorted(part["t"], self.transform.end_us(), "left"))]

    def process_parts(self, chunk):
        return self._within(self.corrector.process_parts(chunk))

    def flush_parts(self):
        return self._within(self.corrector.flush_parts())


def correct_one(input, output, *, reading, thresholds_path, target, mode, hold_us,
                max_gap_us, tau_us, start_us, compression=None, slicing=None) -> Outcome:
    """Correct one file: its :class:`Outcome` (events in and out); ``slicing``: the shared slicing options
    (:func:`evtools.transform.sliced`), the thresholds map cut and turned with the events."""
    # (a series' maps stay in its file, read as the stream reaches them)
    with open_thresholds(thresholds_path) as thresholds, open_events(input, reading) as opened:
        thresholds.check_size(opened.info.width, opened.info.height, thresholds_path)  # the file's sensor
        _check_camera(thresholds.attributes.get("camera"), opened.info.metadata.get("source"), thresholds_path,
                      opened.name)
        stream = sliced(opened, slicing)
        on_sensor = partial(on_sliced_sensor, stream)
        thresholds = replace(thresholds, **{name: per_map(getattr(thresholds, name), on_sensor)
                                            for name in ("on", "off", "valid", "fit")
                                            if getattr(thresholds, name) is not None})
        try:
            corrector = ThresholdCorrector(
                stream.info.width, stream.info.height, thresholds.on, thresholds.off, thresholds.valid,
                target=target, mode=mode, hold_us=hold_us, max_gap_us=max_gap_us, tau_us=tau_us, start_us=start_us,
                t_us=thresholds.t_us, stale=thresholds.stale(), check=False,  # (the reader has checked the events)
            )
        except CorrectionError as error:
            raise CorrectionError(f"{thresholds_path}: {error}") from None
        transform = getattr(stream, "transform", None)
        processor = _EndBound(corrector, transform) if transform is not None and transform.end is not None \
            else corrector
        with create_events(output, stream.info, compression=compression, inputs=(input, thresholds_path)) as writer:
            try:
                events_in, events_out = process_stream(stream, processor, writer, f"correcting {stream.name}")
            except CorrectionError as error:  # (what only the stream can show: the start after its first event)
                raise CorrectionError(f"{stream.name}: {error}") from None
    unknown = int((~corrector.usable).sum())
    if unknown:
        log.info(f"correct: {unknown:,} of {corrector.usable.size:,} pixels have no usable threshold estimate: their "
                 "events are passed on as they are")
    log.info(f"correct {mode}: {events_in:,} events in, {events_out:,} out (target {corrector.target_on:.4g} ON, "
             f"{corrector.target_off:.4g} OFF)")
    if events_in and not events_out:
        log.warning(f"correct: {stream.name}: {events_in:,} events in, none out: the target is above every change its "
                    "pixels saw")
    change = events_out / events_in - 1 if events_in else 0.0
    return Outcome(events_in, events_out, {"events_change": round(change, 6)}, f"{100 * change:+.1f} % events",
                   stream.was_cut)
