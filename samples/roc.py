"""DND21 ROC of every bafilter method on two real recordings with injected noise (run from samples/: `make roc`).

Shot noise of 5 Hz and of 1 Hz per pixel, each with 0.2 Hz/pixel leak, is injected into
../../shared/data/dvs128_walk.aedat and dvxplorer_sample.aedat4 (fixed seeds, other than the ones MLPF was trained
with: see mlpf.py); each method is swept over its main parameter with `evtools metrics roc` (mlpf: its probability
threshold, with the weights shipped in evtools/data). Writes out/ (noisy streams, truth, per-stream plots and
JSON), roc.md (the AUC table) and roc.png (the plot of the first recording at 5 Hz), and prints the table.
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
STREAMS = [("dvs128_walk.aedat", 5, 1), ("dvxplorer_sample.aedat4", 5, 2),  # (recording, shot Hz, seed)
           ("dvs128_walk.aedat", 1, 3), ("dvxplorer_sample.aedat4", 1, 4)]
DT = "dt-us=300,1000,3000,10000,30000,100000,300000"
SWEEPS = [  # (label, method, sweep, extra options)
    ("baf", "baf", DT, []),
    ("stcf", "stcf", DT, []),  # k = 2, polarity on (the defaults)
    ("stcf --polarity-maps", "stcf", DT, ["--polarity-maps"]),
    ("orderN", "orderN", DT, []),
    ("dwf", "dwf", "distance=1,2,3,4,6,9,14,20", []),
    ("refractory", "refractory", "dt-us=1000,10000,100000,1000000,3000000", []),
    ("hotpixel", "hotpixel", "hot-ratio=1,1.5,2,3,5,10", []),
    ("mlpf", "mlpf", "threshold=0.003,0.01,0.03,0.1,0.2,0.3,0.5,0.7,0.8,0.9,0.97,0.99,0.997", []),
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
    table, names = {}, []
    for recording, rate, seed in STREAMS:
        stem = f"{recording.split('.')[0]} {rate} Hz"
        names.append(stem)
        base = f"{recording.split('.')[0]}.{rate}hz"
        noisy, truth = OUT / f"{base}.noisy.aedat4", OUT / f"{base}.truth.h5"
        evtools("simulate", DATA / recording, "--shot-noise-rate-hz", rate, "--leak-rate-hz", 0.2, "--seed", seed,
                "--truth", truth, "-o", noisy)
        # one plot per stream with every method: each method gets its own sweep, so one roc call per method, and
        # the curves are drawn together afterwards from the JSON
        curves = []
        for label, method, sweep, extra in SWEEPS:
            result = json.loads(evtools("metrics", "roc", noisy, "--truth", truth, "--method", method, *extra,
                                        "--sweep", sweep, "--json"))
            entry = result["methods"][0]
            (OUT / f"{base}.{label.replace(' --', '.')}.json").write_text(json.dumps(entry, indent=1))
            table.setdefault(label, {})[stem] = (entry["auc"], best_operating_point(entry["points"]))
            curves.append((label, entry))
        draw(curves, OUT / f"{base}.roc.png", f"{recording.split('.')[0]} + {rate} Hz shot + 0.2 Hz leak")
    shutil.copy(OUT / f"{STREAMS[0][0].split('.')[0]}.{STREAMS[0][1]}hz.roc.png", "roc.png")
    lines = ["| method | swept | " + " | ".join(f"AUC {s}" for s in names) + " | "
             + " | ".join(f"TPR at FPR <= 0.1 ({s})" for s in names[:2]) + " |",
             "|---|---|" + "---|" * (len(names) + 2)]
    for label, _, sweep, _ in SWEEPS:
        cells = [f"{table[label][s][0]:.3f}" for s in names]
        for s in names[:2]:
            best = table[label][s][1]
            cells.append("-" if best is None else f"{best['tpr']:.3f} ({best['value']})")
        lines.append(f"| {label} | {sweep.split('=')[0]} | " + " | ".join(cells) + " |")
    best = {s: max(SWEEPS, key=lambda m: table[m[0]][s][0])[0] for s in names}
    lines.append("")
    lines.append("Best AUC: " + ", ".join(f"{s}: {best[s]} ({table[best[s]][s][0]:.3f})" for s in names) + ".")
    text = "\n".join(lines) + "\n"
    Path("roc.md").write_text(text)
    print(text)
    stcf_grid()


def stcf_grid() -> None:
    """STCF's AUC (its correlation window swept) over radius x k, both polarity modes, on the 5 Hz streams:
    stcf_grid.md."""
    streams = [(recording, rate) for recording, rate, _ in STREAMS if rate == 5]
    lines = ["| radius | k | " + " | ".join(f"AUC {r.split('.')[0]}, one map / polarity maps" for r, _ in streams)
             + " |", "|---|---|" + "---|" * len(streams)]
    for radius in (1, 2, 3):
        for k in (1, 2, 3, 4, 6):
            if k > (2 * radius + 1) ** 2 - 1:
                continue
            cells = []
            for recording, rate in streams:
                base = OUT / f"{recording.split('.')[0]}.{rate}hz"
                aucs = []
                for extra in ([], ["--polarity-maps"]):
                    result = json.loads(evtools("metrics", "roc", f"{base}.noisy.aedat4", "--truth", f"{base}.truth.h5",
                                                "--method", "stcf", "--sweep", DT, "--set", f"radius={radius}",
                                                "--set", f"k={k}", "--json", *extra))
                    aucs.append(result["methods"][0]["auc"])
                cells.append(f"{aucs[0]:.3f} / {aucs[1]:.3f}")
            lines.append(f"| {radius} | {k} | " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    Path("stcf_grid.md").write_text(text)
    print(text)


def draw(curves, path, title) -> None:
    """All methods' ROC curves of one stream in one figure (evtools.plots, matplotlib), every point labelled."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from evtools.formats.figures import save_figure
    from evtools.plots import roc_figure

    save_figure(roc_figure([{"label": label, "parameter": entry["parameter"], "points": entry["points"],
                      "auc": entry["auc"]} for label, entry in curves], title), path)


if __name__ == "__main__":
    main()
