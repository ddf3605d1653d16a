"""The founding report's scheme through the Python API, as one would write it in a notebook: read a recording,
remove background activity, estimate every pixel's thresholds from the ordinary scene, correct the stream to one
threshold, and look at the numbers. The same as the command-line pipeline

    evtools bafilter REC -o filtered.aedat4
    evtools estimate filtered.aedat4 --method natural -o thresholds.h5
    evtools correct filtered.aedat4 --thresholds thresholds.h5 -o corrected.aedat4

and byte for byte the same files (tests/test_api.py checks it). Run: python samples/api_pipeline.py REC OUT_DIR
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import evtools


def pipeline(recording: str, out_dir: str) -> dict:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    events, info = evtools.read(recording)
    kept = evtools.bafilter(events, info)  # BAF, 10 ms window (the command line's default)
    evtools.write(out / "filtered.aedat4", kept, info)
    thresholds = evtools.estimate(kept, info, method="natural")
    corrected = evtools.correct(kept, info, thresholds)  # to the command line's target, 0.2
    evtools.write(out / "corrected.aedat4", corrected, info)
    valid = thresholds.valid
    return {
        "events": len(events), "kept": len(kept), "corrected": len(corrected),
        "valid_pixels": int(valid.sum()), "on_median": float(np.median(thresholds.on[valid])),
        "off_median": float(np.median(thresholds.off[valid])),
    }


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python samples/api_pipeline.py RECORDING OUT_DIR")
    for key, value in pipeline(sys.argv[1], sys.argv[2]).items():
        print(f"{key:>14}: {value:,}" if isinstance(value, int) else f"{key:>14}: {value:.4f}")
