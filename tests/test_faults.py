"""Faults (issue 19): a full disk. Outputs on FIFOs, symlinks and /dev/null, stops by signal and a killed upstream
are covered in tests/test_live.py and tests/test_aedat4.py."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from tests.helpers import assert_clean_error, run

SAMPLES = Path(__file__).resolve().parents[1] / "samples"


@pytest.fixture
def small_disk(tmp_path):
    """A 256 KiB tmpfs (needs root and mount; skipped otherwise)."""
    mount = tmp_path / "small"
    mount.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount)],
                                           capture_output=True).returncode:
        pytest.skip("a small tmpfs needs root and mount (not available here)")
    yield mount
    subprocess.run(["umount", str(mount)], capture_output=True)


@pytest.mark.parametrize("suffix", [".aedat4", ".csv"])
def test_a_full_disk_names_the_output_and_leaves_nothing(small_disk, suffix):
    """Writing 300 KB onto 256 KiB: one line naming the user's output (not a temporary), exit 1, no file left."""
    target = small_disk / f"out{suffix}"
    result = run("convert", SAMPLES / "flicker.aedat4", "-o", target, check=False)
    assert_clean_error(result, str(target), "No space left on device")
    assert os.listdir(small_disk) == []


def test_a_video_on_a_full_disk_fails_in_one_line_and_leaves_nothing(small_disk):
    """render to MP4 used to exit 0 after hundreds of "Failed to write frame" lines, a truncated video left."""
    target = small_disk / "v.mp4"
    result = run("render", SAMPLES / "flicker.aedat4", "-o", target, "--window-us", "2000", check=False)
    assert_clean_error(result, str(target), "No space left on device")
    assert os.listdir(small_disk) == []
