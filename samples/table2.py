"""The report's Table 2 (section 5.3) with evtools: std across pixels of the first and last event time per edge.

Fixed setup (not tuned): scene:step, log step amplitude 1.5 (40 -> 179.25), low-pass cut-off 8 Hz, 10 x 10 pixels,
thresholds 0.2 +/- 0.03, no leak, 3 s (5 edges), seeds 0-9; corrected with the exact thresholds and with 1% and
5% Gaussian estimation error, in every mode; mean and spread over the seeds. Run from samples/; writes table2.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
from pathlib import Path

import numpy as np

EVTOOLS = os.environ.get("EVTOOLS", "../.venv/bin/evtools")
STEP = ["scene:step", "--size", "10x10", "--min-level", "40", "--max-level", "179.25", "--cutoff-hz", "8",
        "--duration", "3s", "--leak-rate-hz", "0"]
REPORT = {"before": (0.57, 15.0), "exact": (0.46, 2.23), "1%": (0.74, 12.2), "5%": (0.72, 12.3)}
MODES = ("highpass", "foh", "step")


def evtools(*args) -> bytes:
    result = subprocess.run([EVTOOLS, *map(str, args)], capture_output=True)
    if result.returncode != 0:
        raise SystemExit(f"evtools {' '.join(map(str, args))} failed: {result.stderr.decode()}")
    return result.stdout


def uniformity(path, reference) -> dict:
    return json.loads(evtools("metrics", "uniformity", path, "--reference", reference, "--json"))["summary"]


def main() -> None:
    from formats.thresholds import ThresholdMap, read_thresholds, write_thresholds

    rows: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for seed in range(10):
            raw, truth, ideal = tmp / f"raw{seed}.aedat4", tmp / f"t{seed}.h5", tmp / f"ideal{seed}.aedat4"
            evtools("simulate", *STEP, "--seed", seed, "--truth", truth, "-o", raw)
            evtools("simulate", *STEP, "--seed", seed, "--sigma-thres", "0", "-o", ideal)
            rows.setdefault("before", []).append(uniformity(raw, ideal))
            true = read_thresholds(str(truth))
            for label, error in (("exact", 0.0), ("1%", 0.01), ("5%", 0.05)):
                rng = np.random.default_rng(1000 + seed)
                path = tmp / f"e{seed}_{label}.h5"
                write_thresholds(str(path), ThresholdMap(true.on * (1 + rng.normal(0, error, true.on.shape)),
                                                         true.off * (1 + rng.normal(0, error, true.on.shape)),
                                                         true.valid))
                for mode in MODES:
                    out = tmp / f"c{seed}_{label}_{mode}.aedat4"
                    evtools("correct", raw, "--thresholds", path, "--target", "0.2", "--mode", mode, "-o", out)
                    rows.setdefault(f"{label} {mode}", []).append(uniformity(out, ideal))
    lines = ["| setup | first std ms | last std ms | count err | timing err ms | report first / last |",
             "|---|---|---|---|---|---|"]
    for name, values in rows.items():
        def stat(key):
            v = np.array([r[key] for r in values])
            return f"{v.mean():.2f} +/- {v.std():.2f}"
        report = REPORT.get(name.split()[0])
        lines.append(f"| {name} | {stat('first_std_ms')} | {stat('last_std_ms')} | {stat('count_error')} | "
                     f"{stat('timing_error_ms')} | {'%.2f / %.2f' % report if report else ''} |")
    text = "\n".join(lines) + "\n"
    print(text)
    Path("table2.md").write_text("# Table 2 (report section 5.3), evtools, seeds 0-9\n\n" + text)


if __name__ == "__main__":
    main()
