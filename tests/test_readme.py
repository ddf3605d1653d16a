"""Every code block of the README runs (issue 18 item 4) and shows the effect it claims (issue 39 item 3: a block's
checker in :data:`EFFECTS` reads what it made): each in an empty folder of its own, with only the
repository's ``samples/`` beside it (as ``samples``) and the environment's ``evtools`` first on the PATH. A block
makes the files it reads in its own earlier lines. A block that cannot run here says why in an HTML comment on the
line before it (``<!-- not run: REASON -->``), which the README shows to nobody; there are few, and each names its
reason. The set-up block's ``make demo`` runs in the repository (its ``.venv`` exists: ``make test`` made it), and
its ``make test`` is this suite."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import evtools

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
NOT_RUN = re.compile(r"<!-- not run: (.+?) -->")


def blocks() -> list[tuple[int, str, str, str | None]]:
    """(first line number, language, code, reason it is not run or None) of every fenced block."""
    lines = README.read_text().splitlines()
    found, i = [], 0
    while i < len(lines):
        fence = re.match(r"^```(\w*)\s*$", lines[i])
        if not fence:
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        reason = NOT_RUN.search(lines[i - 1]) if i else None
        found.append((i + 1, fence.group(1), "\n".join(lines[i + 1:end]) + "\n", reason and reason.group(1)))
        i = end + 1
    return found


def test_the_readme_has_blocks_and_few_are_not_run():
    found = blocks()
    assert len(found) >= 15 and all(language in ("sh", "python") for _, language, _, _ in found)
    skipped = [(line, reason) for line, _, _, reason in found if reason]
    assert len(skipped) <= 2, skipped
    assert all(len(reason) > 20 for _, reason in skipped)


RUNNABLE = [block for block in blocks() if not block[3]]


@pytest.mark.parametrize("line,language,code,reason", RUNNABLE, ids=[f"line{block[0]}" for block in RUNNABLE])
def test_a_readme_block_runs(tmp_path, line, language, code, reason):
    if code.startswith("make demo"):  # the set-up block: `make test` is what runs this test
        assert "make test" in code
        code = "make demo\n"
        tmp_path = ROOT
    if tmp_path != ROOT:
        (tmp_path / "samples").symlink_to(ROOT / "samples")
    environment = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
                   "HOME": str(tmp_path),  # (the completion block writes into ~)
                   "XDG_CACHE_HOME": os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")}  # the kernels
    argv = ["bash", "-e", "-o", "pipefail", "-c", code] if language == "sh" else [sys.executable, "-c", code]
    run = subprocess.run(argv, cwd=tmp_path, env=environment, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, f"README line {line}: exit {run.returncode}\n{run.stderr[-3000:]}"
    assert "Traceback" not in run.stderr, f"README line {line}:\n{run.stderr[-3000:]}"
    effect = _checker(code)
    if effect is not None:
        effect(tmp_path, run)


def _checker(code: str):
    found = [check for key, check in EFFECTS.items() if key in code]
    assert len(found) <= 1, "two checkers claim one block: make their keys unique"
    return found[0] if found else None


def test_every_block_that_makes_something_is_checked():
    """A block that runs has a checker (the set-up block's effect is `make demo` itself; the live block's is read
    by a client in tests/test_network.py)."""
    unchecked = [line for line, _, code, _ in RUNNABLE if _checker(code) is None and not code.startswith("make demo")]
    assert not unchecked, f"README blocks at lines {unchecked} have no checker in EFFECTS"


def _evtools_json(folder: Path, *args) -> dict:
    import json

    done = subprocess.run([Path(sys.executable).parent / "evtools", *map(str, args), "--json"], cwd=folder,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


def _count(path: Path) -> int:
    return len(evtools.read(path)[0])


def _better_than_a_guess(estimate_path: Path, truth_path: Path) -> tuple[float, float]:
    """(the estimate's relative RMSE over its valid pixels, a constant 0.2's over the same pixels), ON and OFF
    together; the estimate must be valid somewhere (issue 36 item 4: an estimate must beat guessing)."""
    from evtools.formats.thresholds import read_thresholds

    estimate, truth = read_thresholds(str(estimate_path)), read_thresholds(str(truth_path))
    valid = estimate.valid
    assert valid.any()
    errors = np.concatenate([(estimate.on / truth.on - 1)[valid], (estimate.off / truth.off - 1)[valid]])
    guess = np.concatenate([(0.2 / truth.on - 1)[valid], (0.2 / truth.off - 1)[valid]])
    return float(np.sqrt(np.mean(errors**2))), float(np.sqrt(np.mean(guess**2)))


def _valid_and_error(folder: Path, estimate: str, truth: str) -> tuple[float, float]:
    """(valid fraction, ON relative RMSE over valid pixels) of a thresholds map against a truth file."""
    result = _evtools_json(folder, "metrics", "thresholds", estimate, "--truth", truth)
    return result["valid_pixels"] / result["pixels"], result["on"]["rel_rmse"]


def _quickstart(folder, run):  # "~7 % error, 95 % valid"; "count CV 0.19 -> 0.12, count error 0.91 -> 0.58"
    import json

    valid, error = _valid_and_error(folder, "thresholds.h5", "truth.h5")
    assert valid > 0.9 and error < 0.1, (valid, error)
    mine, guess = _better_than_a_guess(folder / "thresholds.h5", folder / "truth.h5")
    assert mine < 0.6 * guess, (mine, guess)
    before, after = (json.loads((folder / name).read_text())["summary"] for name in ("before.json", "after.json"))
    assert after["count_cv"] < 0.8 * before["count_cv"], (before, after)
    assert after["count_error"] < 0.8 * before["count_error"], (before, after)
    assert after["last_std_ms"] < before["last_std_ms"], (before, after)


def _formats(folder, run):  # every format holds the same events; the slice is the window and the crop
    counts = {name: _count(folder / name) for name in ("recording.aedat4", "recording.aedat", "recording.h5",
                                                         "recording.raw", "lz4.aedat4", "data.csv", "data.h5")}
    assert len(set(counts.values())) == 1 and counts["recording.aedat4"] > 10_000, counts
    assert 0 < _count(folder / "clean.aedat4") < counts["lz4.aedat4"]
    events = evtools.read(folder / "recording.aedat4")[0]
    part, info = evtools.read(folder / "part.aedat4")
    assert info.size == (64, 64) and len(part) > 0
    first = int(events["t"][0])
    assert first + 200_000 <= part["t"].min() and part["t"].max() < first + 700_000
    assert b"lz4" in (folder / "lz4.aedat4").read_bytes()[:400].lower()


def _completion(folder, run):
    for script in (folder / ".evtools-complete.zsh", folder / ".config/fish/completions/evtools.fish"):
        assert "evtools" in script.read_text() and len(script.read_text()) > 200, script


def _batch(folder, run):  # one output per input; maps "100 % valid, < 1 % error"
    for seed in (1, 2, 3):
        assert 0 < _count(folder / f"clean/bars{seed}.aedat4") < _count(folder / f"recordings/bars{seed}.aedat4")
        assert _count(folder / f"converted/bars{seed}.h5") == _count(folder / f"recordings/bars{seed}.aedat4")
        valid, error = _valid_and_error(folder, f"maps/camera{seed}.h5", f"truth{seed}.h5")
        assert valid == 1.0 and error < 0.01, (seed, valid, error)
        mine, guess = _better_than_a_guess(folder / f"maps/camera{seed}.h5", folder / f"truth{seed}.h5")
        assert mine < 0.1 * guess, (seed, mine, guess)


def _noise_sources(folder, run):  # a video, images and a recording become events; noise is added with labels
    import h5py

    for name in ("video.aedat4", "frames.aedat4"):
        assert _count(folder / name) > 1_000, name
    noisy = _count(folder / "noisy.aedat4")
    assert noisy > _count(folder / "flicker.aedat")
    with h5py.File(folder / "t.h5") as truth:
        labels = truth["label"][:]
    assert len(labels) == noisy and (labels == 0).sum() == _count(folder / "flicker.aedat")
    assert (labels == 1).any() and (labels == 2).any()


def _davis(folder, run):  # "APS frames 300 (25 /s) ... 64x48"; frames pass through cropped
    events, info, frames = evtools.read(folder / "davis.aedat4", frames=True)
    assert len(frames) == 300 and frames[0].image.shape == (48, 64)
    _, part_info, part_frames = evtools.read(folder / "part.h5", frames=True)
    assert part_info.size == (32, 24) and len(part_frames) == 300 and part_frames[0].image.shape == (24, 32)
    valid, error = _valid_and_error(folder, "absolute.h5", "davis.truth.h5")
    assert valid > 0.5 and error < 0.15, (valid, error)


def _render(folder, run):
    import cv2

    for name in ("frame.png", "part.png", "thresholds.png"):
        image = cv2.imread(str(folder / name))
        assert image is not None and image.shape[0] >= 200 and image.std() > 5, name
    video = cv2.VideoCapture(str(folder / "bars.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) >= 20


def _bafilter(folder, run):  # each filter removes events; the hot pixels are found and dropped in another take
    import csv

    noisy, other = _count(folder / "noisy.aedat4"), _count(folder / "other.aedat4")
    for name in ("clean.aedat4", "dv.aedat4", "mlpf.aedat4", "a.aedat4"):
        assert 0 < _count(folder / name) < noisy, name
    with open(folder / "hot.csv") as file:
        hot = {(int(row["x"]), int(row["y"])) for row in csv.DictReader(file)}
    assert len(hot) >= 5  # --hot-pixel-fraction 0.001 of 128 x 96: about 12
    events = evtools.read(folder / "other.aedat4")[0]
    kept = evtools.read(folder / "b.aedat4")[0]
    at_hot = lambda e: sum(int(((e["x"] == x) & (e["y"] == y)).sum()) for x, y in hot)  # noqa: E731
    assert at_hot(events) > 100 * len(hot) and at_hot(kept) == 0 and len(kept) < other


def _train(folder, run):
    import json

    assert json.loads(run.stdout[:run.stdout.index("}") + 1])["held_out_auc"] > 0.8  # (JSON: stdout is a pipe)
    assert (folder / "weights.npz").stat().st_size > 1_000
    assert 0 < _count(folder / "denoised.aedat4") < _count(folder / "other.aedat4")


def _train_self(folder, run):  # no labels: the noise it measured, a model that learned, a filter that removes
    import json

    report = json.loads(run.stdout[:run.stdout.rindex("}") + 1])
    assert report["labels"] == "self" and 1.0 < report["noise"][0]["shot_rate_hz"] < 15.0, report["noise"]
    assert report["held_out_auc"] > 0.8
    assert 0 < _count(folder / "denoised.aedat4") < 0.9 * _count(folder / "mine.aedat4")


def _denoise_metrics(folder, run):
    assert (folder / "roc.svg").read_bytes().lstrip()[:5] in (b"<?xml", b"<svg ")
    roc = _evtools_json(folder, "metrics", "roc", "noisy.aedat4", "--truth", "t.h5", "--method", "stcf", "--sweep",
                        "dt-us=1000,10000")
    assert roc["methods"][0]["auc"] > 0.8


def _estimate(folder, run):  # offE and the stimulus methods on the same camera
    for name, factor in (("thresholds.h5", 0.6), ("t.h5", 0.3)):  # offE; the noisy monitor's stimulus, filtered
        valid, error = _valid_and_error(folder, name, "flicker.truth.h5")
        assert valid > 0.9 and error < 0.12, (name, valid, error)
        mine, guess = _better_than_a_guess(folder / name, folder / "flicker.truth.h5")
        assert mine < factor * guess, (name, mine, guess)
    valid, error = _valid_and_error(folder, "gradient.h5", "flicker.truth.h5")
    assert valid > 0.9 and error < 0.12, ("gradient", valid, error)
    valid, error = _valid_and_error(folder, "natural.h5", "flicker.truth.h5")
    assert valid > 0.85 and error < 0.1, ("natural", valid, error)  # guessing the median: 17 % off
    assert (folder / "errors.png").stat().st_size > 10_000


def _correct(folder, run):  # the corrected step is more uniform than the raw one
    before = _evtools_json(folder, "metrics", "uniformity", "step.aedat4", "--reference", "ideal.aedat4")
    after = _evtools_json(folder, "metrics", "uniformity", "corrected.aedat4", "--reference", "ideal.aedat4")
    assert after["summary"]["count_cv"] < 0.8 * before["summary"]["count_cv"], (before["summary"], after["summary"])
    assert after["summary"]["count_error"] < before["summary"]["count_error"]
    assert (folder / "edge.png").stat().st_size > 10_000


def _reconstruction(folder, run):
    raw = _evtools_json(folder, "metrics", "reconstruction", "step.aedat4", "--truth", "t.h5", "--contrast", "0.2")
    fixed = _evtools_json(folder, "metrics", "reconstruction", "corrected.aedat4", "--truth", "t.h5", "--contrast",
                          "0.2")
    assert fixed["rmse"] < 0.8 * raw["rmse"] and fixed["ssim"] > raw["ssim"], (raw["rmse"], fixed["rmse"])
    assert fixed["ssim"] > 0.95, fixed["ssim"]  # the table below the example: 0.995 (measured 0.990 as written)
    assert (folder / "recon.png").stat().st_size > 10_000


def _prediction(folder, run):  # the true maps predict the frames better than one threshold for every pixel
    true = _evtools_json(folder, "metrics", "reconstruction", "davis.aedat4", "--thresholds", "davis.truth.h5")
    flat = _evtools_json(folder, "metrics", "reconstruction", "davis.aedat4", "--contrast", "0.2")
    assert true["rmse"] < flat["rmse"], (true["rmse"], flat["rmse"])


def _replay(folder, run):  # served to no client: said, not a silent success
    assert "no client" in run.stderr, run.stderr


EFFECTS = {
    "evtools metrics uniformity step.aedat4 --reference ideal.aedat4 > before.json": _quickstart,
    "evtools convert recording.aedat4 -o part.aedat4": _formats,
    "_EVTOOLS_COMPLETE=bash_source": _completion,
    "evtools estimate flicker/*.aedat4 -o maps/": _batch,
    "evtools simulate flicker.aedat --shot-noise-rate-hz 5": _noise_sources,
    "--truth davis.truth.h5 -o davis.aedat4   ": _davis,
    "evtools render --map truth.h5": _render,
    "--save-hot-pixels hot.csv": _bafilter,
    "evtools metrics train-denoiser noisy.aedat4": _train,
    "evtools metrics train-denoiser mine.aedat4": _train_self,
    "evtools metrics esr rec.aedat4": _denoise_metrics,
    "evtools bafilter street.aedat4 | evtools estimate - -o natural.h5": _estimate,
    "--before step.aedat4 --plot edge.png": _correct,
    "--contrast 0.2 --plot recon.png": _reconstruction,
    "evtools metrics reconstruction davis.aedat4 --thresholds": _prediction,
    "--thresholds samples/step.truth.h5 -o tcp://:7778": _replay,
    "evtools.simulate(\"flicker\"": lambda folder, run: None,  # the block asserts its own effect (the count CV)
}
"""A distinctive line of each block -> its checker: what the block's comments claim, read from what it made."""


def test_the_filters_keep_of_the_real_recordings_what_the_readme_says():
    """The README's table of what each filter keeps of the real recordings at its defaults (a QA sweep: orderN
    kept 7 % of the Gen4.1 clip and nothing said so), recomputed: every share within a percentage point."""
    from tests.conftest import data_file

    files = {"DVXplorer": "dvxplorer_sample.aedat4", "DAVIS346": "davis346_lab_frames.aedat4",
             "DVS128": "dvs128_walk.aedat", "Gen4.1": "gen41_sample.evt3.raw"}
    text = (ROOT / "README.md").read_text()
    header = "| recording | baf | stcf | dwf | orderN |"
    assert header in text
    rows = text.split(header, 1)[1].split("\n\n", 1)[0].strip().splitlines()[1:]
    assert len(rows) == len(files)
    for row in rows:
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        name = next(camera for camera in files if cells[0].startswith(f"{camera} "))
        events, info = evtools.read(data_file(files[name]))
        for method, cell in zip(("baf", "stcf", "dwf", "orderN"), cells[1:]):
            kept = len(evtools.bafilter(events, info, method)) / len(events)
            assert abs(100 * kept - float(cell.rstrip(" %"))) <= 1.0, (name, method, kept, cell)
