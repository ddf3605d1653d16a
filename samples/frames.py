"""DAVIS frames end to end (issue 38): thresholds on the absolute scale from events and APS frames
(``estimate --method frames``, Wang et al. ACRA 2019's offEI) against events alone (``natural``), and what each
map does for a vision task: predicting the recording's own frames (``metrics reconstruction`` without a truth
file), with one constant threshold, the true maps, each estimate, and after ``correct``.

Simulated recordings come from the tests' independent DAVIS generator (``tests/naive/davis.py``: a multi-scale
texture moving under ideal pixels with exact crossings, frames integrated exactly over their exposures, per-pixel
gain and offset non-uniformity, read noise, 8-bit DN; it shares no code with ``evtools simulate``), thresholds
0.2 +/- 0.03 ON and OFF drawn independently, 64 x 48 pixels, 12 s. Setups:

- clean: 25 fps, 10 ms exposures, read noise 1.5 DN, a pan of (20, 5) px/s with a 4 px wobble;
- hard: 40 fps, 5 ms exposures (half the signal), read noise 2 DN, a faster pan (40, -10) px/s with an 8 px
  wobble, brighter (some highlights saturate);
- dim: 25 fps, 5 ms exposures of the clean scene (about 27 DN at the median: read noise and the 1 DN offsets
  weigh 2-4x more), read noise 2 DN;
- slow: 25 fps, 20 ms exposures, a slow pan (8, 2) px/s, 2 px wobble (few events a pixel).

The frames estimate calls a pixel valid when its fit (the predicted relative error, a standard deviation) is at
most 0.035, so that a valid pixel is more than 10 % off with a probability under 1 %. In the dim setup every
pixel's fit is larger (its frames' 1 DN offsets over signals of about 27 DN alone give 3.7 %): nothing is valid,
which is what the data support (with ``--max-fit inf`` its RMS error is 4.0 %).

Each setup is run with seeds 5, 6 and 7 (texture, path noise and threshold maps): the tables give the mean over
the seeds and, in brackets, the worst.

The two real DAVIS346 recordings (``../../shared/data``, when present) hold 3 and 4 frames: too few for a frames
estimate (it needs 12 usable frames a pixel), so they show the constant threshold and ``natural``'s map only.

Thresholds: ``valid`` the share of pixels the estimate calls valid (of those not mostly saturated), RMSE the
relative error over valid pixels (ON and OFF), ``> 10 %`` the share of valid pixels whose worse threshold is more
than 10 % off. ``natural`` gets the true mean threshold as its ``--nominal`` (events alone give no scale), so its
errors are the spread it gets wrong, not the scale; ``natural --nominal frames`` takes its scale (per polarity)
from the frames instead. Reconstruction: each frame predicted from the previous one and
the events between (RMSE in log units over pixels neither dark nor saturated in both), against holding the
previous frame; ``explained`` is the share of the hold's squared error the events remove.

Run from samples/ (``make frames``, about three minutes); writes frames.md.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import evtools  # noqa: E402
from evtools.estimation import EstimationError, estimate_thresholds  # noqa: E402
from evtools.estimation_frames import FrameScaledEstimator, FrameThresholdEstimator  # noqa: E402
from evtools.metrics.frames import FramePrediction  # noqa: E402
from tests.naive.davis import davis_recording  # noqa: E402

W, H = 64, 48
DURATION_US = 12_000_000
TARGET = 0.2
SEEDS = (5, 6, 7)
SETUPS = {
    "clean": dict(rate_hz=25.0, exposure_us=10_000, read_noise=1.5, pan_px_s=(20.0, 5.0), wobble_px=4.0),
    "hard": dict(rate_hz=40.0, exposure_us=5_000, read_noise=2.0, pan_px_s=(40.0, -10.0), wobble_px=8.0,
                 base_log=4.9),
    "dim": dict(rate_hz=25.0, exposure_us=5_000, read_noise=2.0, pan_px_s=(20.0, 5.0), wobble_px=4.0),
    "slow": dict(rate_hz=25.0, exposure_us=20_000, read_noise=1.5, pan_px_s=(8.0, 2.0), wobble_px=2.0),
}
REAL = {"DAVIS346 lab (3 frames)": "davis346_lab_frames.aedat4",
        "DAVIS346 street (4 frames)": "davis346_street_frames.aedat4"}


def true_maps(seed):
    rng = np.random.default_rng([seed, 1])
    return tuple(np.clip(0.2 + 0.03 * rng.standard_normal((H, W)), 0.08, None) for _ in range(2))


def accuracy(estimate, on, off, unsaturated):
    """(valid share of the unsaturated pixels, RMSE of the valid ones, share of valid pixels more than 10 % off)."""
    valid = estimate.valid & unsaturated
    if not valid.any():
        return 0.0, math.nan, math.nan
    errors = np.concatenate([estimate.on[valid] / on[valid] - 1, estimate.off[valid] / off[valid] - 1])
    worst = np.maximum(np.abs(estimate.on / on - 1), np.abs(estimate.off / off - 1))[valid]
    return float(valid.sum() / unsaturated.sum()), float(np.sqrt(np.mean(errors**2))), float(np.mean(worst > 0.10))


def prediction(events, frames, width, height, on, off):
    """metrics reconstruction's scores (no truth file) for events and frames with thresholds on, off."""
    scorer = FramePrediction(width, height, on, off, black_level=0.0)  # (the generator's frames: black 0)
    scorer.process(events)
    scorer.add_frames(frames)
    return scorer.scores()


def simulated_rows(name, setup, seed):
    on, off = true_maps(seed)
    raw, frame_list = davis_recording(W, H, DURATION_US, seed=seed, theta_on=on, theta_off=off, black_level=0.0,
                                      **setup)
    events = evtools.make_events(raw["t"], raw["x"], raw["y"], raw["p"])
    frames = [evtools.Frame(image, (b + e) // 2, b, e) for b, e, image in frame_list]
    dn = np.stack([image for _, _, image in frame_list])
    unsaturated = (dn >= 250).mean(0) <= 0.5
    info = evtools.StreamInfo(W, H)
    estimator = FrameThresholdEstimator(W, H)
    estimator.process(events)
    estimator.add_frames(frames)
    by_frames = estimator.result()
    natural = estimate_thresholds(events, W, H, "natural", nominal=float((on.mean() + off.mean()) / 2))
    scaled = FrameScaledEstimator(W, H, "natural")
    scaled.process(events)
    scaled.add_frames(frames)
    accuracy_rows = [(name, "frames", accuracy(by_frames, on, off, unsaturated)),
                     (name, "natural (the true mean as --nominal)", accuracy(natural, on, off, unsaturated)),
                     (name, "natural --nominal frames", accuracy(scaled.result(), on, off, unsaturated))]
    maps = {"constant 0.2": (TARGET, TARGET), "the true maps": (on, off), "natural's map": (natural.on, natural.off)}
    if by_frames.valid.any():  # (none valid: no map to use, and nothing to correct with)
        maps["frames' map"] = (by_frames.on, by_frames.off)  # (invalid pixels hold the valid ones' median)
    recon_rows = [(name, label, prediction(events, frames, W, H, *pair)) for label, pair in maps.items()]
    if by_frames.valid.any():
        corrected = evtools.correct(events, info, by_frames, target=TARGET)
        recon_rows.append((name, "corrected with frames' map, then 0.2",
                           prediction(corrected, frames, W, H, TARGET, TARGET)))
    return accuracy_rows, recon_rows, len(events), len(frames)


def real_rows(name, file):
    path = ROOT.parent / "shared" / "data" / file
    if not path.exists():
        return []
    events, info, frames = evtools.read(path, frames=True)
    rows = [(name, "constant 0.2", prediction(events, frames, info.width, info.height, TARGET, TARGET))]
    try:
        natural = estimate_thresholds(events, info.width, info.height, "natural", nominal=TARGET)
    except EstimationError as error:  # too few events a pixel: said in the table
        return rows + [(name, f"natural's map: none ({len(events) / (info.width * info.height):.1f} events a pixel; "
                              f"{str(error).split(':')[0]})", None)]
    rows.append((name, "natural's map (nominal 0.2)", prediction(events, frames, info.width, info.height,
                                                                 natural.on, natural.off)))
    corrected = evtools.correct(events, info, natural, target=TARGET)
    rows.append((name, "corrected with natural's map, then 0.2",
                 prediction(corrected, frames, info.width, info.height, TARGET, TARGET)))
    return rows


def merged(rows, worst):
    """Rows of (name, label, values) from every seed: per (name, label), each value's mean over the seeds and its
    worst (``worst[k]``: max or min; None: none)."""
    groups: dict = {}
    for name, label, values in rows:
        groups.setdefault((name, label), []).append(values)
    out = []
    for (name, label), runs in groups.items():
        if len(runs) < len(SEEDS):
            label += f" ({len(runs)} of {len(SEEDS)} seeds: the others have no valid pixel)"
        columns = np.array(runs, float).T
        out.append((name, label, [(float(np.mean(c)), float(pick(c)) if pick else None)
                                  for c, pick in zip(columns, worst)]))
    return out


def cell(value, worst, scale=1.0, digits=1, unit=""):
    if not math.isfinite(value):
        return "-"  # (no valid pixel)
    text = f"{scale * value:.{digits}f}{unit}"
    return text if worst is None or len(SEEDS) == 1 else f"{text} ({scale * worst:.{digits}f})"


def main() -> None:
    started = time.time()
    accuracy_rows, recon_rows, sizes = [], [], {}
    for name, setup in SETUPS.items():
        for seed in SEEDS:
            more_accuracy, more_recon, n_events, n_frames = simulated_rows(name, setup, seed)
            accuracy_rows += more_accuracy
            recon_rows += [(n, label, (sc["rmse"], sc["rmse_hold"], sc["explained"])) for n, label, sc in more_recon]
            sizes.setdefault(name, []).append((n_events, n_frames))
    real = []
    for name, file in REAL.items():
        real += real_rows(name, file)
    lines = ["# DAVIS frames: absolute thresholds and frame prediction (issue 38)", "",
             __doc__.split("\n\n", 1)[1].split("\n\nRun from")[0], "",
             "Recordings (per seed): " + "; ".join(
                 f"{k} {int(np.mean([e for e, _ in v])):,} events, {v[0][1]} frames" for k, v in sizes.items()) + ".",
             "", "## Thresholds", "", "| setup | method | valid | RMSE | valid > 10 % off |", "|---|---|---|---|---|"]
    for name, label, ((valid, valid_worst), (rmse, rmse_worst), (off, off_worst)) in merged(
            accuracy_rows, [np.min, np.max, np.max]):
        lines.append(f"| {name} | {label} | {cell(valid, valid_worst, 100, 1, ' %')} | "
                     f"{cell(rmse, rmse_worst, 100, 2, ' %')} | {cell(off, off_worst, 100, 2, ' %')} |")
    lines += ["", "## Predicting the recording's own frames (`metrics reconstruction`, no truth)", "",
              "| recording | thresholds | prediction RMSE (log) | holding the frame | explained |",
              "|---|---|---|---|---|"]
    for name, label, ((rmse, rmse_worst), (hold, _), (explained, _)) in merged(recon_rows, [np.max, None, None]):
        lines.append(f"| {name} | {label} | {cell(rmse, rmse_worst, 1, 4)} | {hold:.4f} | {100 * explained:.0f} % |")
    for name, label, scores in real:
        if scores is None:
            lines.append(f"| {name} | {label} | - | - | - |")
            continue
        lines.append(f"| {name} | {label} | {scores['rmse']:.4f} | {scores['rmse_hold']:.4f} | "
                     f"{100 * scores['explained']:.0f} % |")
    lines += ["", f"({time.time() - started:.0f} s)", ""]
    text = "\n".join(lines)
    print(text)
    (Path(__file__).parent / "frames.md").write_text(text)


if __name__ == "__main__":
    main()
