"""The distribution installs one top-level package, ``evtools`` (the repository's cli/ and formats/ inside it)."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_the_wheel_has_one_top_level_package(tmp_path):
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(tmp_path),
                            str(ROOT)], capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    (wheel,) = tmp_path.glob("evtools-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {name.split("/")[0] for name in names}
    assert {t for t in top if not t.endswith(".dist-info")} == {"evtools"}, top
    assert "evtools/cli/main.py" in names and "evtools/formats/aedat4.py" in names
    assert "evtools/_kernels/correct.py" in names and "evtools/metrics/thresholds.py" in names
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    assert "evtools = evtools.cli.main:main" in zipfile.ZipFile(wheel).read(entry_points).decode()
