"""The committed sample streams are exactly what `make -C samples` makes (reproducible from their seeds)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SAMPLES = Path(__file__).resolve().parent.parent / "samples"
NAMES = ["flicker.aedat4", "flicker.truth.h5", "gradient.aedat4", "gradient.truth.h5", "step.aedat4", "step.truth.h5"]


@pytest.mark.slow
def test_samples_are_reproduced_byte_for_byte(tmp_path):
    shutil.copy(SAMPLES / "Makefile", tmp_path / "Makefile")
    evtools = Path(sys.executable).with_name("evtools")
    subprocess.run(["make", "-s", "-C", str(tmp_path), f"EVTOOLS={evtools}"], check=True, capture_output=True)
    for name in NAMES:
        assert (tmp_path / name).read_bytes() == (SAMPLES / name).read_bytes(), name
