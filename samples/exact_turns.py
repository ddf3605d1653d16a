"""Issue 12's first finding, measured: log-linear triangle waves, a phase, rise, fall and amplitude per pixel.

100 pixels, each watching its own triangle wave in log intensity (rise and fall 20-150 ms, amplitude 0.9-2.5 log
units, any phase; 2 s, about 20-50 ramps per pixel), once with thresholds 0.2 +/- 0.03 and once with the target
0.2, by the independent analytic ideal pixel of ``tests/naive/ideal_pixel.py`` (exact crossing times, rounded to
whole us). The mismatched stream is corrected with its exact thresholds in every mode and compared with the ideal
stream per pixel: the count difference over the whole stream, and the timing error of matched events (each
corrected event paired with the nearest unpaired ideal event of its polarity, in order, within 50 ms).

Run from samples/ (``make exact_turns``); writes exact_turns.md. ``python exact_turns.py --repo DIR`` measures the
evtools found in DIR instead (e.g. a worktree of an older commit), for a before/after.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SEEDS = range(5)
PIXELS = 100
END_US = 2_000_000


def _ideal_pixel():
    """tests/naive/ideal_pixel.py of this checkout, by path (the measured evtools may come with other tests)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("ideal_pixel", ROOT / "tests" / "naive" / "ideal_pixel.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def waves(seed):
    triangle_corners = _ideal_pixel().triangle_corners
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(PIXELS):
        corners = triangle_corners(0, END_US, rng.uniform(-1, 1), rng.uniform(0.9, 2.5), rng.uniform(20e3, 150e3),
                                   rng.uniform(20e3, 150e3), rng.uniform(0, 1))
        out.append((corners, float(np.float32(rng.normal(0.2, 0.03))), float(np.float32(rng.normal(0.2, 0.03)))))
    return out


def stream(pixels, target=None):
    from evtools.events import make_events

    ideal_events = _ideal_pixel().ideal_events

    t, x, y, p = [], [], [], []
    for i, (corners, on, off) in enumerate(pixels):
        for when, polarity in ideal_events(corners, target or on, target or off):
            t.append(int(np.floor(when + 0.5)))
            x.append(i % 10)
            y.append(i // 10)
            p.append(polarity)
    order = np.argsort(t, kind="stable")
    return make_events(np.array(t)[order], np.array(x)[order], np.array(y)[order], np.array(p)[order])


def timing_errors(mine, theirs, limit_us=50_000):
    """Per polarity, pair events in order with the nearest unpaired one within ``limit_us``; the differences."""
    errors = []
    for polarity in (True, False):
        a, b = mine["t"][mine["p"] == polarity], theirs["t"][theirs["p"] == polarity]
        j = 0
        for t in a:
            while j < len(b) and b[j] < t - limit_us:
                j += 1
            if j < len(b) and abs(int(b[j]) - int(t)) <= limit_us:
                if j + 1 < len(b) and abs(int(b[j + 1]) - int(t)) < abs(int(b[j]) - int(t)):
                    j += 1
                errors.append(abs(int(b[j]) - int(t)))
                j += 1
    return errors


def measure(modes):
    from evtools.correction import correct_thresholds

    target = float(np.float32(0.2))
    rows = {mode: {"count": [], "timing": []} for mode in ["uncorrected", *modes]}
    for seed in SEEDS:
        pixels = waves(seed)
        raw, ideal = stream(pixels), stream(pixels, target)
        on = np.array([p[1] for p in pixels], np.float32).reshape(10, 10)
        off = np.array([p[2] for p in pixels], np.float32).reshape(10, 10)
        outputs = {"uncorrected": raw}
        for mode in modes:
            outputs[mode] = correct_thresholds(raw, 10, 10, on, off, target=target, mode=mode, start_us=0)
        for name, out in outputs.items():
            for i in range(PIXELS):
                mine = out[(out["x"] == i % 10) & (out["y"] == i // 10)]
                theirs = ideal[(ideal["x"] == i % 10) & (ideal["y"] == i // 10)]
                rows[name]["count"].append(abs(len(mine) - len(theirs)))
                rows[name]["timing"].extend(timing_errors(mine, theirs))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--repo", default=str(ROOT))
    parser.add_argument("--modes", default="exponential,highpass,turns,step,foh")
    args = parser.parse_args()
    sys.path.insert(0, args.repo)
    rows = measure(args.modes.split(","))
    lines = ["| mode | per-pixel count error, mean / max (events, 2 s) | matched timing error p50 / p95 / max (us) |",
             "|---|---|---|"]
    for name, row in rows.items():
        count, timing = np.array(row["count"]), np.array(row["timing"])
        lines.append(f"| {name} | {count.mean():.2f} / {count.max()} | {np.percentile(timing, 50):.0f} / "
                     f"{np.percentile(timing, 95):.0f} / {timing.max()} |")
    text = "\n".join(lines)
    print(text)
    if Path(args.repo).resolve() == ROOT:
        (Path(__file__).with_name("exact_turns.md")).write_text(
            "# Exact turns (issue 12): random log-linear triangle waves, exact thresholds\n\n"
            + (__doc__ or "").split("\n\n")[1] + "\n\n" + text + "\n")


if __name__ == "__main__":
    main()
