"""Train the MLPF weights evtools ships, and measure how MLPF generalises (run from samples/: `make mlpf`).

Training streams: shot noise of 1 Hz and 5 Hz per pixel plus 0.2 Hz leak injected into both shared recordings
(../../shared/data/dvs128_walk.aedat, dvxplorer_sample.aedat4) with the training seeds below; the evaluation
streams are roc.py's (the same recordings, other noise seeds), so no evaluated noise event was seen in training.
The shipped weights (../evtools/data/mlpf.npz) are trained on all four training streams with --seed 0. Then
each model trained on a part (one recording, one noise rate) is scored on every evaluation stream: the AUC of
`evtools metrics roc --method mlpf --sweep threshold=...`. Writes out/mlpf/, mlpf.md, and prints the table.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

EVTOOLS = os.environ.get("EVTOOLS", "../.venv/bin/evtools")
DATA = Path("../../shared/data")
OUT = Path("out/mlpf")
SHIPPED = Path("../evtools/data/mlpf.npz")
RECORDINGS = {"walk": "dvs128_walk.aedat", "dvx": "dvxplorer_sample.aedat4"}
TRAIN_SEEDS = {("walk", 1): 101, ("walk", 5): 102, ("dvx", 1): 103, ("dvx", 5): 104}
EVAL_SEEDS = {("walk", 5): 1, ("dvx", 5): 2, ("walk", 1): 3, ("dvx", 1): 4}  # roc.py's
THRESHOLDS = "threshold=0.003,0.01,0.03,0.1,0.2,0.3,0.5,0.7,0.8,0.9,0.97,0.99,0.997"
MODELS = {  # name: the training streams
    "shipped (both recordings, 1 and 5 Hz)": list(TRAIN_SEEDS),
    "walk only (1 and 5 Hz)": [("walk", 1), ("walk", 5)],
    "dvx only (1 and 5 Hz)": [("dvx", 1), ("dvx", 5)],
    "1 Hz only (both recordings)": [("walk", 1), ("dvx", 1)],
    "5 Hz only (both recordings)": [("walk", 5), ("dvx", 5)],
}


def evtools(*args) -> str:
    result = subprocess.run([EVTOOLS, *map(str, args)], capture_output=True, text=True)
    if result.returncode:
        sys.exit(f"evtools {' '.join(map(str, args))} failed:\n{result.stderr}")
    return result.stdout


def stream(recording: str, rate: int, seed: int) -> tuple[Path, Path]:
    noisy, truth = OUT / f"{recording}.{rate}hz.seed{seed}.aedat4", OUT / f"{recording}.{rate}hz.seed{seed}.truth.h5"
    if not noisy.exists():
        evtools("simulate", DATA / RECORDINGS[recording], "--shot-noise-rate-hz", rate, "--leak-rate-hz", 0.2,
                "--seed", seed, "--truth", truth, "-o", noisy)
    return noisy, truth


def train(streams: list, output: Path) -> dict:
    args = []
    for key in streams:
        noisy, truth = stream(*key, TRAIN_SEEDS[key])
        args += [noisy]
    truths = [arg for key in streams for arg in ("--truth", stream(*key, TRAIN_SEEDS[key])[1])]
    return json.loads(evtools("metrics", "train-denoiser", *args, *truths, "--seed", 0, "-o", output, "--json"))


def score(weights: Path, key) -> float:
    noisy, truth = stream(*key, EVAL_SEEDS[key])
    result = json.loads(evtools("metrics", "roc", noisy, "--truth", truth, "--method", "mlpf", "--weights", weights,
                                "--sweep", THRESHOLDS, "--json"))
    return result["methods"][0]["auc"]


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    evaluations = sorted(EVAL_SEEDS, key=lambda key: (-key[1], key[0]))
    lines = ["| model (trained on) | " + " | ".join(f"AUC {r} {hz} Hz" for r, hz in evaluations) + " | held-out AUC |",
             "|---|" + "---|" * len(evaluations) + "---|"]
    for name, streams in MODELS.items():
        weights = SHIPPED if name.startswith("shipped") else OUT / f"{name.split()[0]}.npz"
        report = train(streams, weights)
        cells = []
        for key in evaluations:
            value = score(weights, key)
            seen = key in streams
            cells.append(f"{value:.3f}" + ("" if seen else " *"))
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {report['held_out_auc']:.3f} |")
        print(lines[-1], flush=True)
    lines += ["", "`*`: the evaluated recording or noise rate was not in the training streams (generalisation). "
              "Every evaluated noise event is new (other seeds)."]
    text = "\n".join(lines) + "\n"
    Path("mlpf.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
