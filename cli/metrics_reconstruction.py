"""``evtools metrics reconstruction``: how well EVENTS reconstruct the true log intensity (issue 12 part 3), or
predict their own APS frames (issue 38 item 4)."""

from __future__ import annotations

import os

import click
import numpy as np

from evtools.cli.options import FiniteRange, echo_json, figure_path, json_option, wants_json
from evtools.cli.progress import consume
from evtools.metrics.reconstruction import HighPassReconstructor, ReconstructionError, reconstruction_errors
from evtools.formats import open_events
from evtools.formats.thresholds import read_thresholds
from evtools.inputs import note_input

DEFAULT_CUTOFF_HZ = 0.0
"""Pure integration by default: what threshold mismatch does to a reconstruction shows undamped (a cut-off hides
it as it forgets); give ``--cutoff-hz`` for the paper's high-pass (a few Hz there)."""


def read_true_frames(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(times us, log frames) of a truth file, or a one-line error saying how to make them."""
    import h5py

    if os.path.isdir(path):
        raise ReconstructionError(f"{path}: a folder, not a truth file")
    note_input(path)
    try:
        with h5py.File(path, "r") as h5:
            if "log_frames" not in h5 or "log_frame_t_us" not in h5 or len(h5["log_frame_t_us"]) == 0:
                raise ReconstructionError(
                    f"{path}: no true log-intensity frames; make them with `evtools simulate SOURCE --truth {path} "
                    f"--truth-frame-rate 100` (frame sources only)")
            return h5["log_frame_t_us"][:].astype(np.int64), h5["log_frames"][:].astype(np.float64)
    except OSError as error:
        raise ReconstructionError(f"{path}: not a readable HDF5 truth file ({' '.join(str(error).split())})") \
            from None


@click.command()
@click.argument("events_path", metavar="EVENTS")
@click.option("--truth", "truth_path", default=None, metavar="TRUTH.h5", type=click.Path(),
              help="`evtools simulate ... --truth TRUTH.h5` (with its true log frames, `--truth-frame-rate`); "
                   "without it, EVENTS' own APS frames: each predicted from the one before and the events between.")
@click.option("--black-level", default=None, type=FiniteRange(min=0), metavar="DN",
              help="Without --truth: the APS frames' value of no light [default: the --thresholds map's "
                   "black_level_used (estimate --method frames), else 0 (DV's frames), with a warning when the "
                   "frames never read near 0].")
@click.option("--thresholds", "thresholds_path", default=None, metavar="TH.h5", type=click.Path(),
              help="Each pixel's contrast per event (`estimate`'s output or a truth file); default --contrast.")
@click.option("--contrast", default=0.2, show_default=True, type=FiniteRange(min=0, min_open=True),
              help="What one event adds (log units) when no --thresholds: e.g. correct's --target.")
@click.option("--cutoff-hz", default=DEFAULT_CUTOFF_HZ, show_default=True, type=FiniteRange(min=0),
              help="High-pass cut-off (alpha / 2 pi); 0: pure integration.")
@click.option("--plot", "plot_path", default=None, metavar="FIG.png", type=click.Path(dir_okay=False),
              help="Also draw true (top) and reconstructed (bottom) log intensity at five frames.")
@json_option
def reconstruction(events_path, truth_path, black_level, thresholds_path, contrast, cutoff_hz, plot_path, as_json):
    """RMSE and SSIM of the log intensity reconstructed from EVENTS against the true frames of TRUTH.h5; without
    --truth, how well EVENTS predict their own APS frames (a DAVIS recording).

    Each pixel integrates its events (+contrast ON, -contrast OFF) from the first true frame, decaying towards
    it at --cutoff-hz: the complementary filter of Scheerlinck, Barnes, Mahony (ACCV 2018). Run it on a stream
    before and after `correct` to see what correction changes for a vision task.

    \b
    evtools metrics reconstruction step.aedat4 --truth t.h5 --thresholds t.h5
    evtools metrics reconstruction corrected.aedat4 --truth t.h5 --contrast 0.2 --plot recon.png
    evtools metrics reconstruction davis.aedat4 --thresholds frames.h5       # real frames, an estimated map
    """
    figure_path(plot_path, "--plot", (events_path, truth_path, thresholds_path))
    if truth_path is None:
        if plot_path is not None or cutoff_hz != DEFAULT_CUTOFF_HZ:
            raise click.UsageError("--plot and --cutoff-hz apply with --truth (against the APS frames each frame is "
                                   "predicted from the one before)")
        _against_frames(events_path, thresholds_path, contrast, black_level, as_json)
        return
    times, truth = read_true_frames(truth_path)
    height, width = truth.shape[1:]
    if thresholds_path is not None:
        maps = read_thresholds(thresholds_path)
        maps.check_size(width, height, thresholds_path)
        on, off = maps.on, maps.off
    else:
        on = off = contrast
    try:
        recon = HighPassReconstructor(truth[0], times, on, off, cutoff_hz)
    except ReconstructionError as error:
        raise ReconstructionError(f"{thresholds_path or '--contrast'}: {error}") from None
    with open_events(events_path) as stream:
        if (stream.info.width, stream.info.height) != (width, height):
            raise ReconstructionError(f"{events_path}: the stream is {stream.info.width}x{stream.info.height} but "
                                      f"the truth {truth_path} is {width}x{height}")
        for chunk in stream:
            recon.process(chunk)
    estimated = recon.flush()
    result = {"events": events_path, "truth": truth_path, "contrast": thresholds_path or contrast,
              "cutoff_hz": cutoff_hz, **reconstruction_errors(estimated, truth)}
    if plot_path is not None:
        _plot(plot_path, truth, estimated, times)
    if wants_json(as_json):
        echo_json(result, indent=2)
    else:
        from rich.console import Console

        Console().print(f"{events_path}: {result['frames']} frames, RMSE {result['rmse']:.4f} log units, "
                        f"SSIM {result['ssim']:.4f} (cut-off {cutoff_hz:g} Hz)")


def _against_frames(events_path, thresholds_path, contrast, black_level, as_json) -> None:
    """Each APS frame of EVENTS predicted from the one before and the events between (see
    :mod:`evtools.metrics.frames`)."""
    from evtools.metrics.frames import FramePrediction

    black_level_from = "--black-level" if black_level is not None else "default"
    with open_events(events_path) as stream:
        width, height = stream.info.width, stream.info.height
        on = off = contrast
        if thresholds_path is not None:
            maps = read_thresholds(thresholds_path)
            maps.check_size(width, height, thresholds_path)
            usable = maps.usable() if maps.t_us is None else maps.usable()[-1]
            on = np.where(usable, maps.on if maps.t_us is None else maps.on[-1], np.nan)
            off = np.where(usable, maps.off if maps.t_us is None else maps.off[-1], np.nan)
            middle = (np.nanmedian(on), np.nanmedian(off)) if usable.any() else (contrast, contrast)
            on, off = np.where(usable, on, middle[0]), np.where(usable, off, middle[1])  # as correct uses a map
            if black_level is None and "black_level_used" in maps.attributes:  # (the level the map was made at)
                black_level, black_level_from = float(maps.attributes["black_level_used"]), "thresholds"
        scorer = FramePrediction(width, height, on, off, black_level=black_level, check=False)
        consume(stream, scorer, f"scoring {stream.name}")
    try:
        result = {"events": events_path, "contrast": thresholds_path or contrast, **scorer.scores(),
                  "black_level_from": black_level_from}
    except ReconstructionError as error:
        raise ReconstructionError(f"{events_path}: {error}") from None
    if wants_json(as_json):
        echo_json(result, indent=2)
    else:
        from rich.console import Console

        Console().print(f"{events_path}: {result['pairs']} frame pairs, prediction RMSE {result['rmse']:.4f} log "
                        f"units (holding the previous frame {result['rmse_hold']:.4f}; the events explain "
                        f"{100 * result['explained']:.1f} % of its squared error)")


def _plot(path: str, truth: np.ndarray, estimated: np.ndarray, times: np.ndarray) -> None:
    from evtools.formats.figures import save_figure
    from evtools.plots import reconstruction_figure

    save_figure(reconstruction_figure(truth, estimated, times), path)
