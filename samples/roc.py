"""DND21 ROC of every bafilter method on two real recordings with injected noise (run from samples/: `make roc`).

5 Hz/pixel shot noise and 0.2 Hz/pixel leak are injected into ../../shared/data/dvs128_walk.aedat and
dvxplorer_sample.aedat4 (fixed seeds); each method is swept over its main parameter with `evtools metrics roc`.
Writes out/ (noisy streams, truth, per-recording plots and JSON), roc.md (the AUC table) and roc.png (the plot of
the first recording), and prints the table.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

EVTOOLS = os.environ.get("EVTOOLS", "../.venv/bin/evtools")
DATA = Path("../../shared/data")
OUT = Path("out")
RECORDINGS = [("dvs128_walk.aedat", 1), ("dvxplorer_sample.aedat4", 2)]
DT = "dt-us=300,1000,3000,10000,30000,100000,300000"
SWEEPS = [
    ("baf", DT),
    ("stcf", DT),  # k = 2, polarity on (the defaults)
    ("orderN", DT),
    ("dwf", "distance=1,2,3,4,6,9,14,20"),
    ("refractory", "dt-us=1000,10000,100000,1000000,3000000"),
    ("hotpixel", "hot-ratio=1,1.5,2,3,5,10"),
]


def evtools(*args) -> str:
    result = subprocess.run([EVTOOLS, *map(str, args)], capture_output=True, text=True)
    if result.returncode:
        sys.exit(f"evtools {' '.join(map(str, args))} failed:\n{result.stderr}")
    return result.stdout


def best_operating_point(points):
    """The highest TPR among the points that remove at least 90 % of the noise (FPR <= 0.1), or None."""
    good = [p for p in points if p["fpr"] is not None and p["fpr"] <= 0.1]
    return max(good, key=lambda p: p["tpr"]) if good else None


def main() -> None:
    OUT.mkdir(exist_ok=True)
    table = {}
    for name, seed in RECORDINGS:
        stem = name.split(".")[0]
        noisy, truth = OUT / f"{stem}.noisy.aedat4", OUT / f"{stem}.truth.h5"
        evtools("simulate", DATA / name, "--shot-noise-rate-hz", 5, "--leak-rate-hz", 0.2, "--seed", seed,
                "--truth", truth, "-o", noisy)
        # one plot per recording with every method: each method gets its own sweep, so one roc call per method,
        # and the curves are drawn together afterwards from the JSON
        curves = []
        for method, sweep in SWEEPS:
            result = json.loads(evtools("metrics", "roc", noisy, "--truth", truth, "--method", method,
                                        "--sweep", sweep, "--json"))
            entry = result["methods"][0]
            (OUT / f"{stem}.{method}.json").write_text(json.dumps(entry, indent=1))
            table.setdefault(method, {})[stem] = (entry["auc"], best_operating_point(entry["points"]))
            curves.append((method, entry))
        draw(curves, OUT / f"{stem}.roc.png", f"{stem} + 5 Hz shot + 0.2 Hz leak")
    shutil.copy(OUT / f"{RECORDINGS[0][0].split('.')[0]}.roc.png", "roc.png")
    stems = [name.split(".")[0] for name, _ in RECORDINGS]
    lines = ["| method | swept | " + " | ".join(f"AUC {s} | TPR at FPR <= 0.1 ({s})" for s in stems) + " |",
             "|---|---|" + "---|---|" * len(stems)]
    for method, sweep in SWEEPS:
        cells = []
        for s in stems:
            auc, best = table[method][s]
            cells += [f"{auc:.3f}", "-" if best is None else f"{best['tpr']:.3f} ({best['value']})"]
        lines.append(f"| {method} | {sweep.split('=')[0]} | " + " | ".join(cells) + " |")
    best = {s: max(SWEEPS, key=lambda m: table[m[0]][s][0])[0] for s in stems}
    lines.append("")
    lines.append("Best AUC: " + ", ".join(f"{s}: {best[s]} ({table[best[s]][s][0]:.3f})" for s in stems) + ".")
    text = "\n".join(lines) + "\n"
    Path("roc.md").write_text(text)
    print(text)


def draw(curves, path, title) -> None:
    """All methods' ROC curves of one recording in one PNG (evtools' OpenCV drawing)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from evtools.cli.metrics_denoise import draw_roc
    from evtools.metrics.denoise import roc_auc

    drawn = []
    for method, entry in curves:
        curve, area = roc_auc([(p["fpr"], p["tpr"]) for p in entry["points"]])
        drawn.append((method, curve, area))
    draw_roc(path, drawn, title)


if __name__ == "__main__":
    main()
