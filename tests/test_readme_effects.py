"""The README's examples that estimate or correct do what they claim (issue 36 item 4): each is run as
``tests/test_readme.py`` runs it, in a folder of its own, and then the direction of its effect is checked on the
files it made: an estimate closer to the truth than guessing 0.2 everywhere, a corrected stream closer to the ideal
sensor than the stream it corrected. (The Python example asserts its own effect.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from evtools.formats.thresholds import read_thresholds
from tests.test_readme import ROOT, blocks


def block_with(text: str) -> str:
    """The README's one runnable shell block that contains ``text``."""
    found = [code for _, language, code, reason in blocks() if language == "sh" and not reason and text in code]
    assert len(found) == 1, (text, len(found))
    return found[0]


def run_block(code: str, folder: Path) -> None:
    (folder / "samples").symlink_to(ROOT / "samples")
    environment = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
                   "HOME": str(folder)}
    done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", code], cwd=folder, env=environment,
                          capture_output=True, timeout=600)
    assert done.returncode == 0, done.stderr.decode()[-3000:]


def evtools(*args, folder: Path) -> dict:
    done = subprocess.run([str(Path(sys.executable).parent / "evtools"), *map(str, args)], cwd=folder,
                          capture_output=True, timeout=600)
    assert done.returncode == 0, done.stderr.decode()[-2000:]
    return json.loads(done.stdout)


def better_than_a_guess(estimate_path: Path, truth_path: Path) -> tuple[float, float]:
    """(the estimate's relative RMSE over its valid pixels, a constant 0.2's over the same pixels), ON and OFF
    together; the estimate must be valid somewhere."""
    estimate, truth = read_thresholds(str(estimate_path)), read_thresholds(str(truth_path))
    valid = estimate.valid
    assert valid.any()
    errors = np.concatenate([(estimate.on / truth.on - 1)[valid], (estimate.off / truth.off - 1)[valid]])
    guess = np.concatenate([(0.2 / truth.on - 1)[valid], (0.2 / truth.off - 1)[valid]])
    return float(np.sqrt(np.mean(errors**2))), float(np.sqrt(np.mean(guess**2)))


def test_the_first_pipeline_estimates_and_corrects_one_camera(tmp_path):
    run_block(block_with("after.json"), tmp_path)
    mine, guess = better_than_a_guess(tmp_path / "thresholds.h5", tmp_path / "truth.h5")
    assert mine < 0.6 * guess
    before = json.loads((tmp_path / "before.json").read_text())["summary"]
    after = json.loads((tmp_path / "after.json").read_text())["summary"]
    assert after["count_cv"] < 0.8 * before["count_cv"], (before, after)
    assert after["count_error"] < before["count_error"]
    assert after["last_std_ms"] < before["last_std_ms"]


def test_the_batch_example_estimates_every_camera(tmp_path):
    run_block(block_with("maps/ --method stimulus"), tmp_path)
    for seed in (1, 2, 3):
        mine, guess = better_than_a_guess(tmp_path / "maps" / f"camera{seed}.h5", tmp_path / f"truth{seed}.h5")
        assert mine < 0.1 * guess
        assert read_thresholds(str(tmp_path / "maps" / f"camera{seed}.h5")).valid.mean() > 0.95


def test_the_estimation_examples_come_closer_to_the_truth_than_a_guess(tmp_path):
    run_block(block_with("--method natural   # any long moving scene"), tmp_path)
    truth = tmp_path / "flicker.truth.h5"
    for made, factor in (("thresholds.h5", 0.6), ("t.h5", 0.3)):  # offE; the noisy monitor's stimulus, filtered
        mine, guess = better_than_a_guess(tmp_path / made, truth)
        assert mine < factor * guess, (made, mine, guess)


def test_the_correction_example_brings_the_step_closer_to_the_ideal(tmp_path):
    run_block(block_with("--before step.aedat4 --plot edge.png"), tmp_path)
    before = evtools("metrics", "uniformity", "step.aedat4", "--reference", "ideal.aedat4", "--json",
                     folder=tmp_path)["summary"]
    after = evtools("metrics", "uniformity", "corrected.aedat4", "--reference", "ideal.aedat4", "--json",
                    folder=tmp_path)["summary"]
    assert after["count_cv"] < 0.8 * before["count_cv"], (before, after)
    assert after["count_error"] < before["count_error"]


def test_the_reconstruction_example_improves_the_reconstruction(tmp_path):
    run_block(block_with("metrics reconstruction corrected.aedat4"), tmp_path)
    before = evtools("metrics", "reconstruction", "step.aedat4", "--truth", "t.h5", "--contrast", "0.2", "--json",
                     folder=tmp_path)
    after = evtools("metrics", "reconstruction", "corrected.aedat4", "--truth", "t.h5", "--contrast", "0.2",
                    "--json", folder=tmp_path)
    key = next(k for k in before if "rmse" in k.lower() and isinstance(before[k], (int, float)))
    assert after[key] < before[key], (key, before[key], after[key])


@pytest.mark.parametrize("text", ["after.json", "maps/ --method stimulus", "--method natural   # any long",
                                  "--before step.aedat4 --plot edge.png", "metrics reconstruction corrected"])
def test_each_checked_block_is_in_the_readme(text):
    assert block_with(text)
