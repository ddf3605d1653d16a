"""correct and estimate on natural moving textures (issue 36): the table samples/natural.md.

The scenes come from the independent generator of the tests (``tests/naive/texture.py``: a random multi-scale log
texture moved along a random path under ideal pixels with exact crossing times; it shares no code with evtools'
simulator): 48 x 36 pixels, 6 s, thresholds 0.2 +/- 0.03 (independent per pixel and polarity), seeds 1-3.

- wobble: hand-held, 4 px at ~1.5 Hz;
- pan: 6 px/s and 2 px/s, with a 0.5 px wobble;
- boundary: the wobble, the right half of the texture at 0.3 of the left's contrast;
- correlated: the wobble, thresholds with a smooth component (10 % over ~8 px) on top of the independent spread;
- noisy pan: the pan with shot noise (2 Hz a pixel) and leak (0.2 Hz) added (``evtools.inject_noise``) and BAF
  (50 ms) before estimating.

Correction: the mismatched stream re-sampled to 0.2 with the exact thresholds and with 1 % and 5 % estimation
error (Gaussian, per pixel and polarity), each mode; against the ideal sensor (every threshold 0.2) watching the
same signal: the per-pixel count error (sum over pixels and polarities of |n - n_ideal| over the ideal's total) and
the total count. Estimation: natural and offE (defaults): the valid fraction, the relative RMSE over valid pixels
(ON and OFF together), the share of valid pixels more than 10 % off, the rank correlation of the fit with the
error over fitted pixels, and how well the fit predicts the error's size over valid pixels (``metrics
thresholds``: the RMS of the larger of the ON and OFF relative errors over the fit, about 1 where the fit is the
error's size, and the share off by more than two fits). Beside the rank correlation, the one a fit exact in size
would reach: errors drawn at random at the size the fit predicts (the true error is such a draw), so a pixel's
luck is not in it; where the fits of the pixels differ little, no fit reaches 0.5. Run from samples/
(``make natural``); writes natural.md.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import evtools  # noqa: E402
from evtools.correction import correct_thresholds  # noqa: E402
from evtools.estimation import EstimationError, estimate_thresholds  # noqa: E402
from evtools.events import make_events  # noqa: E402
from evtools.filters import ba_filter  # noqa: E402
from evtools.metrics import thresholds as thresholds_metrics  # noqa: E402
from evtools.metrics.thresholds import fit_calibration  # noqa: E402
from tests.naive.texture import count_error, crossings, smooth_field, texture_signal  # noqa: E402

WIDTH, HEIGHT, DURATION_US = 48, 36, 6_000_000
SEEDS = (1, 2, 3)
MODES = ("exponential", "turns", "highpass", "step", "foh")
ERRORS = (0.0, 0.01, 0.05)


def scene(name: str, seed: int):
    """(events of the mismatched sensor, events of the ideal sensor, true on, true off)."""
    contrast_map = None
    path = {"wobble_px": 4.0}
    if name in ("pan", "noisy pan"):
        path = {"pan_px_s": (6.0, 2.0), "wobble_px": 0.5}
    if name == "boundary":
        contrast_map = np.where(np.arange(WIDTH)[None, :] < WIDTH // 2, 1.0, 0.3) * np.ones((HEIGHT, 1))
    times, levels = texture_signal(WIDTH, HEIGHT, DURATION_US, seed=seed, contrast_map=contrast_map, **path)
    rng = np.random.default_rng(100 + seed)
    on, off = rng.normal(0.2, 0.03, (2, HEIGHT, WIDTH))
    if name == "correlated":
        field = smooth_field(WIDTH, HEIGHT, 8, seed=seed)
        on, off = on * (1 + 0.1 * field), off * (1 + 0.1 * field)
    on, off = np.clip(on, 0.05, None).astype(np.float32), np.clip(off, 0.05, None).astype(np.float32)
    given, ideal = crossings(times, levels, on, off), crossings(times, levels, np.float32(0.2), np.float32(0.2))
    return (make_events(given["t"], given["x"], given["y"], given["p"]),
            make_events(ideal["t"], ideal["x"], ideal["y"], ideal["p"]), on, off)


def correction_rows(name: str) -> list[str]:
    figures = {}
    for seed in SEEDS:
        events, ideal, on, off = scene(name, seed)
        figures.setdefault(("input", 0.0), []).append((count_error(events, ideal, WIDTH, HEIGHT),
                                                       len(events) / len(ideal) - 1))
        rng = np.random.default_rng(seed)
        for error in ERRORS:
            known_on = (on * (1 + rng.normal(0, error, on.shape))).astype(np.float32)
            known_off = (off * (1 + rng.normal(0, error, off.shape))).astype(np.float32)
            for mode in MODES:
                out = correct_thresholds(events, WIDTH, HEIGHT, known_on, known_off, target=0.2, mode=mode,
                                         start_us=0)
                figures.setdefault((mode, error), []).append((count_error(out, ideal, WIDTH, HEIGHT),
                                                              len(out) / len(ideal) - 1))
    rows = []
    for (mode, error), values in figures.items():
        values = np.array(values)
        label = "uncorrected" if mode == "input" else f"{mode}, {'exact' if error == 0 else f'{error:.0%} error'}"
        rows.append(f"| {name} | {label} | {values[:, 0].mean():.3f} ({values[:, 0].min():.3f}-"
                    f"{values[:, 0].max():.3f}) | {100 * values[:, 1].mean():+.1f} % |")
    return rows


def rank_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's (ties at their average rank, as metrics thresholds has it); NaN for fewer than 3 pixels."""
    return thresholds_metrics.rank_correlation(a, b) if len(a) > 2 else float("nan")


def oracle_rank_correlation(fit: np.ndarray, seed: int, draws: int = 20) -> float:
    """The rank correlation of ``fit`` with errors drawn at exactly the size it predicts (ON and OFF independent
    normals of standard deviation ``fit``, the larger taken, as for the true error): what a fit that knew each
    pixel's error distribution would reach, since the error itself is a random draw from it."""
    rng = np.random.default_rng(seed)
    return float(np.mean([rank_correlation(fit, np.abs(rng.normal(0, 1, (2, fit.size)) * fit).max(axis=0))
                          for _ in range(draws)]))


def estimation_rows(name: str) -> list[str]:
    figures = {}
    for seed in SEEDS:
        events, _, on, off = scene(name, seed)
        info = evtools.StreamInfo(WIDTH, HEIGHT)
        if name == "noisy pan":
            events, _ = evtools.inject_noise(events, info, shot_noise_rate_hz=2, leak_rate_hz=0.2, seed=seed)
            events = ba_filter(events, WIDTH, HEIGHT, "baf", dt_us=50_000)
        for method in ("natural", "offe"):
            try:
                result = estimate_thresholds(events, WIDTH, HEIGHT, method)
            except EstimationError:
                figures.setdefault(method, []).append((0.0, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan))
                continue
            errors = np.stack([result.on / on - 1, result.off / off - 1])
            worst = np.abs(errors).max(axis=0)
            valid = result.valid
            fitted = np.isfinite(result.fit) & (result.on > 0)
            calibration = fit_calibration(result.on, result.off, valid, result.fit, on, off) or {}
            figures.setdefault(method, []).append((
                valid.mean(), float(np.sqrt(np.mean(errors[:, valid] ** 2))) if valid.any() else np.nan,
                float(np.mean(worst[valid] > 0.1)) if valid.any() else np.nan,
                rank_correlation(result.fit[fitted], worst[fitted]), oracle_rank_correlation(result.fit[fitted], seed),
                calibration.get("error_over_fit_rms", np.nan), calibration.get("beyond_two_fits", np.nan)))
    rows = []
    for method, values in figures.items():
        values = np.array(values, dtype=float)
        means = [np.nanmean(values[:, k]) if np.isfinite(values[:, k]).any() else np.nan for k in range(7)]
        rows.append(f"| {name} | {method} | {100 * means[0]:.0f} % | {100 * means[1]:.1f} % | "
                    f"{100 * means[2]:.0f} % | {means[3]:.2f} | {means[4]:.2f} | {means[5]:.2f} | "
                    f"{100 * means[6]:.0f} % |")
    return rows


def main() -> None:
    started = time.time()
    lines = ["# correct and estimate on natural moving textures", "",
             __doc__.split("\n\n", 1)[1].strip(), "",
             "## Correction: per-pixel count error against the ideal sensor (mean and range over 3 seeds), total count",
             "", "| scene | stream | count error | total vs ideal |", "|---|---|---|---|"]
    for name in ("wobble", "pan", "boundary", "correlated"):
        lines += correction_rows(name)
    lines += ["", "## Estimation (mean over 3 seeds)", "",
              "| scene | method | valid | RMSE (valid) | valid > 10 % off | rank corr. fit vs error | "
              "the same, errors drawn at the fit's size | error / fit (RMS, valid) | valid past two fits |",
              "|---|---|---|---|---|---|---|---|---|"]
    for name in ("wobble", "pan", "boundary", "correlated", "noisy pan"):
        lines += estimation_rows(name)
    lines += ["", f"({time.time() - started:.0f} s)"]
    Path("natural.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
