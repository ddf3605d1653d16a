"""Faults (issue 19), one matrix over the commands that stream: a stop (SIGTERM) while waiting on a live pipe, an
upstream killed mid-stream, outputs through a symbolic link, into a FIFO and onto /dev/null, an output that names
the input, a full disk. (SIGINT, whole pipelines and the end mark at a packet boundary: tests/test_live.py and
tests/test_aedat4.py.)"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import evtools
import evtools.formats
from evtools.events import concatenate
from tests.conftest import data_file
from tests.helpers import assert_clean_error, assert_same_events, run, wait_until, wait_until_waiting_for_input

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
EVTOOLS = str(Path(sys.executable).with_name("evtools"))

STREAM_COMMANDS = {
    # name: (argv after the input, output suffix)
    "convert": ([], ".aedat4"),
    "bafilter": (["--method", "baf", "--dt-us", "50000"], ".aedat4"),
    "correct": (["--thresholds", "{truth}"], ".aedat4"),
    "simulate": (["--shot-noise-rate-hz", "1", "--seed", "1"], ".aedat4"),
    "estimate": (["--min-events", "2"], ".h5"),
    "render": (["--window-us", "50000"], ".mp4"),
}
"""Every command that reads a stream and writes a file, with options that suit the stream of :func:`stream`."""

HOLD = """
import sys, time
data = open(sys.argv[1], "rb").read()
sys.stdout.buffer.write(data[: int(len(data) * float(sys.argv[2]))])
sys.stdout.buffer.flush()
time.sleep(60)  # the pipe stays open: the reader waits for more
"""


@pytest.fixture(scope="module")
def stream(tmp_path_factory) -> tuple[Path, Path]:
    """A 64 x 48 bars stream of several packets (32,768 events each) and its camera's thresholds."""
    folder = tmp_path_factory.mktemp("faults")
    run("simulate", "scene:bars", "--size", "64x48", "--duration", "1500ms", "--seed", "3", "--truth",
        folder / "truth.h5", "-o", folder / "bars.aedat4")
    return folder / "bars.aedat4", folder / "truth.h5"


def _options(name: str, stream) -> list[str]:
    return [part.format(truth=stream[1]) for part in STREAM_COMMANDS[name][0]]


def _feed(path: Path, fraction: float) -> subprocess.Popen:
    """A writer of the first ``fraction`` of ``path``'s bytes that then keeps the pipe open."""
    return subprocess.Popen([sys.executable, "-c", HOLD, str(path), str(fraction)], stdout=subprocess.PIPE)


def _stage(name: str, output: Path, feed: subprocess.Popen, extra: list[str], keep_pipe=False) -> subprocess.Popen:
    """``evtools NAME - ... -o OUTPUT`` reading ``feed``; the test keeps its copy of the pipe's read end if asked."""
    process = subprocess.Popen([EVTOOLS, "-q", name, "-", *extra, "-o", str(output)], stdin=feed.stdout,
                               stderr=subprocess.PIPE, text=True, cwd=ROOT)
    if not keep_pipe:
        feed.stdout.close()
    return process


def _no_temporaries(folder: Path) -> None:
    assert [p.name for p in folder.iterdir() if p.name.startswith(".") or p.name.endswith(".part")] == []


@pytest.mark.parametrize("name", sorted(STREAM_COMMANDS))
def test_sigterm_while_waiting_on_a_pipe_stops_cleanly(tmp_path, stream, name):
    """SIGTERM while a command waits for more of a live pipe: exit 143, one line, no traceback, no temporary; what
    it wrote is complete (an event file readable, and a prefix of the whole run's events where it is a filter):
    a live stream stopped ends there, as a camera's recording does (a file's reading stopped early is cut:
    test_a_stopped_simulation_is_marked_cut)."""
    output = tmp_path / f"out{STREAM_COMMANDS[name][1]}"
    feed = _feed(stream[0], 0.5)
    stage = _stage(name, output, feed, _options(name, stream), keep_pipe=True)
    try:
        wait_until_waiting_for_input(stage, feed.stdout)
        feed.stdout.close()
        stage.send_signal(15)
        assert stage.wait(timeout=30) == 143
    finally:
        feed.kill()
        stage.kill()
    stderr = stage.stderr.read()
    assert "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1 and "stopped by" in stderr, stderr
    _no_temporaries(tmp_path)
    if output.exists() and output.suffix == ".aedat4":
        events, _ = evtools.read(output)
        assert run("info", output).stderr == b""
        if name in ("convert", "bafilter"):  # a filter's output is a prefix of its whole run's
            whole = tmp_path / "whole.aedat4"
            run(name, stream[0], *_options(name, stream), "-o", whole)
            assert 0 < len(events) and len(events) <= len(evtools.read(whole)[0])
            assert_same_events(events, evtools.read(whole)[0][:len(events)])


def _stopped_simulation(folder, *options) -> None:
    """A simulation of 1,000 s with ``options``, stopped by SIGINT once its output in ``folder`` is under way."""
    import signal

    process = subprocess.Popen([EVTOOLS, "simulate", "scene:flicker", "--size", "16x12", "--duration", "1000s",
                                *map(str, options)], stderr=subprocess.PIPE)
    wait_until(lambda: any(p.name.startswith(".") or p.name.endswith(".part") for p in folder.iterdir()),
               "the output under way")
    time.sleep(0.5)
    process.send_signal(signal.SIGINT)
    assert process.wait(timeout=60) == 130
    process.stderr.close()


@pytest.mark.parametrize("suffix", [".aedat4", ".h5", ".csv"])
def test_a_stopped_simulation_is_marked_cut(tmp_path, suffix):
    """A run stopped before its input's end (here a simulation of 1,000 s stopped once under way; likewise a file
    read halfway) writes what it made, readable, and says it was cut (it looked whole: a QA sweep scored a stopped
    filter's output as a better filter); the next command carries the mark on."""
    output = tmp_path / f"long{suffix}"
    _stopped_simulation(tmp_path, "-o", output)
    said = run("info", output).stderr.decode()
    assert ("without the end mark" if suffix == ".aedat4" else "stopped by SIGINT") in said, said
    run("convert", output, "-o", tmp_path / "copy.h5")
    assert b"cut" in run("info", tmp_path / "copy.h5").stderr


def test_a_stopped_simulations_truth_is_marked_cut_like_its_events(tmp_path):
    """The truth file of a simulation stopped under way says it was cut (``cut``, ``cut_by``), as its events file
    does (it looked whole: its labels, APS truth and times end where the events do); a whole run's does not, and
    noise injected into a cut recording marks its truth cut by the input."""
    import h5py

    output, truth = tmp_path / "long.aedat4", tmp_path / "long.truth.h5"
    _stopped_simulation(tmp_path, "--truth", truth, "-o", output)
    with h5py.File(truth) as h5:
        assert h5.attrs["cut"] and h5.attrs["cut_by"] == "stopped by SIGINT", dict(h5.attrs)
    whole = tmp_path / "whole.truth.h5"
    run("simulate", "scene:flicker", "--size", "16x12", "--duration", "200ms", "--truth", whole,
        "-o", tmp_path / "whole.aedat4")
    with h5py.File(whole) as h5:
        assert "cut" not in h5.attrs
    noisy_truth = tmp_path / "noisy.truth.h5"
    run("simulate", output, "--shot-noise-rate-hz", "1", "--truth", noisy_truth, "-o", tmp_path / "noisy.aedat4")
    with h5py.File(noisy_truth) as h5:
        assert h5.attrs["cut"] and h5.attrs["cut_by"] == "a cut input", dict(h5.attrs)


@pytest.mark.parametrize("name", sorted(STREAM_COMMANDS))
def test_an_upstream_killed_mid_stream_is_an_error_without_output(tmp_path, stream, name):
    """The writer of the pipe killed (SIGKILL) after 60 % of a stream: the command does not pass the part as whole:
    exit 1, one line naming stdin, no output, no temporary."""
    output = tmp_path / f"out{STREAM_COMMANDS[name][1]}"
    feed = _feed(stream[0], 0.6)
    stage = _stage(name, output, feed, _options(name, stream))
    try:
        time.sleep(1.0)
        feed.kill()
        assert stage.wait(timeout=30) == 1
    finally:
        stage.kill()
    stderr = stage.stderr.read()
    assert "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert stderr.startswith("evtools: error: <stdin>") or "stdin" in stderr, stderr
    assert not output.exists()
    _no_temporaries(tmp_path)


@pytest.mark.parametrize("name", sorted(STREAM_COMMANDS))
def test_outputs_through_links_fifos_and_devices_and_never_over_the_input(tmp_path, stream, name):
    """-o through a symbolic link: the link stays, its target gets the output (what a regular file gets); -o a
    FIFO: the reader gets the output, the FIFO stays (HDF5 and MP4, which seek or are written by path, are refused
    on a FIFO in one line); -o /dev/null: exit 0, still a device; -o naming the input (through a link): refused,
    the input unchanged."""
    extra, suffix = _options(name, stream), STREAM_COMMANDS[name][1]
    source = tmp_path / "in.aedat4"
    source.write_bytes(stream[0].read_bytes())
    regular = tmp_path / f"regular{suffix}"
    run(name, source, *extra, "-o", regular)
    target, link = tmp_path / f"target{suffix}", tmp_path / f"link{suffix}"
    target.write_bytes(b"old")
    link.symlink_to(target)
    run(name, source, *extra, "-o", link)
    assert link.is_symlink() and os.readlink(link) == str(target)
    if suffix == ".aedat4":
        assert target.read_bytes() == regular.read_bytes()
    else:
        assert target.stat().st_size > 100 and target.read_bytes()[:4] == regular.read_bytes()[:4]
    fifo = tmp_path / f"fifo{suffix}"
    os.mkfifo(fifo)
    copy = tmp_path / f"copy{suffix}"
    reader = subprocess.Popen([sys.executable, "-c", f"open({str(copy)!r}, 'wb').write(open({str(fifo)!r}, 'rb').read())"])
    written = run(name, source, *extra, "-o", fifo, *(["--format", "aedat4"] if name in ("convert", "simulate") else []),
                  check=False)
    if suffix == ".aedat4":  # a FIFO is a live output: flushed chunk by chunk, so its packets may be cut otherwise
        assert written.returncode == 0 and reader.wait(timeout=30) == 0, written.stderr
        assert_same_events(evtools.read(copy)[0], evtools.read(regular)[0])
    else:
        reader.kill()  # (HDF5 into a FIFO: the output named cannot take the format, a usage error)
        assert written.returncode == 2 and written.stderr.decode().count("\n") == 1, written.stderr
        assert b"fifo" in written.stderr
    assert fifo.is_fifo()
    if suffix == ".aedat4":
        assert run(name, source, *extra, "-o", "/dev/null").returncode == 0 and Path("/dev/null").is_char_device()
    before = hashlib.sha256(source.read_bytes()).hexdigest()
    alias = tmp_path / f"alias{suffix}"
    alias.symlink_to(source)
    refused = run(name, source, *extra, "-o", alias, check=False)
    assert refused.returncode == 1 and b"input" in refused.stderr and refused.stderr.count(b"\n") == 1, refused.stderr
    assert hashlib.sha256(source.read_bytes()).hexdigest() == before


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


@pytest.mark.parametrize("suffix", [".aedat4", ".csv", ".h5"])
def test_a_full_disk_names_the_output_and_leaves_nothing(small_disk, suffix, tmp_path):
    """Writing more than 256 KiB onto 256 KiB: one line naming the user's output (not a temporary), exit 1, no file
    left. HDF5 too: h5py crashed (SIGSEGV) freeing the objects of the failed file, after the clean line."""
    source = SAMPLES / "flicker.aedat4"
    if suffix == ".h5":  # HDF5 compresses the small sample below the limit: a longer stream
        source = tmp_path / "long.aedat4"
        run("simulate", "scene:bars", "--size", "128x96", "--duration", "2s", "--seed", "1", "-o", source)
    target = small_disk / f"out{suffix}"
    result = run("convert", source, "-o", target, check=False)
    assert_clean_error(result, str(target), "No space left on device")
    assert os.listdir(small_disk) == []


@pytest.mark.parametrize("online", [False, True])
def test_a_thresholds_map_on_a_full_disk_names_it(small_disk, tmp_path, online):
    """estimate's HDF5 map onto a full disk: the map's name in the one line (was "No space left on device" alone),
    exit 1 (not a crash), no file. Online, the maps go to the file as they are made: the disk fills between two
    maps, and the same holds (no partial file: the maps could not be written)."""
    target = small_disk / "t.h5"
    if online:  # 100 maps of 12 KiB
        result = run("estimate", SAMPLES / "flicker.aedat4", "--method", "natural", "--online", "--interval", "20ms",
                     "-o", target, check=False)
        assert_clean_error(result, str(target), "No space left on device")
        assert os.listdir(small_disk) == []
        return
    filler = small_disk / "filler"
    filler.write_bytes(b"\0" * (250 * 1024))
    result = run("estimate", SAMPLES / "flicker.aedat4", "-o", target, check=False)
    assert_clean_error(result, str(target), "No space left on device")
    assert sorted(os.listdir(small_disk)) == ["filler"]


def test_a_video_on_a_full_disk_fails_in_one_line_and_leaves_nothing(small_disk):
    """render to MP4 used to exit 0 after hundreds of "Failed to write frame" lines, a truncated video left."""
    target = small_disk / "v.mp4"
    result = run("render", SAMPLES / "flicker.aedat4", "-o", target, "--window-us", "2000", check=False)
    assert_clean_error(result, str(target), "No space left on device")
    assert os.listdir(small_disk) == []


@pytest.mark.parametrize("name", ["bafilter", "convert", "correct"])
def test_a_stage_whose_input_was_cut_does_not_end_its_output_as_whole(tmp_path, stream, name):
    """Issue 37 item 2: `head -c N s.aedat4 | evtools NAME - | evtools bafilter - -o x.aedat4`: the middle stage
    fails (its input was cut) and writes no end mark, so the last stage fails too instead of writing a whole-looking
    file of part of the events."""
    output = tmp_path / "x.aedat4"
    size = stream[0].stat().st_size
    options = " ".join(_options(name, stream))
    script = (f"head -c {size // 2} {stream[0]} | {EVTOOLS} -q {name} - {options} "
              f"| {EVTOOLS} -q bafilter - -o {output}; echo ${{PIPESTATUS[@]}}")
    done = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120, cwd=ROOT)
    statuses = done.stdout.split()
    assert statuses[1:] == ["1", "1"], (statuses, done.stderr)
    assert "Traceback" not in done.stderr and not output.exists()
    _no_temporaries(tmp_path)


@pytest.mark.parametrize("fmt", ["csv", "txt", "aedat2"])
def test_a_stage_whose_input_was_cut_says_so_in_a_text_stream_that_went_out(tmp_path, stream, fmt):
    """A stage that fails after its events went out as CSV or text (standard output, a pipe) ends them with the cut
    comment, so the next stage marks its output cut (they ended as if whole: the next stage wrote a whole-looking
    HDF5 file of half the events, exit 0); AEDAT 2.0, with nowhere to say it, is said on stderr."""
    output = tmp_path / "x.h5"
    size = stream[0].stat().st_size
    script = (f"head -c {size // 2} {stream[0]} | {EVTOOLS} convert - --format {fmt} "
              f"| {EVTOOLS} convert - --sensor-size 64x48 -o {output}; "
              "echo ${PIPESTATUS[@]}")
    done = subprocess.run(["bash", "-c", script], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert done.stdout.split() == ["0", "1", "0"] and "Traceback" not in done.stderr, done.stderr
    events, info = evtools.read(output)
    assert len(events) > 0
    if fmt == "aedat2":
        assert "the events that went out are a cut stream, unmarked (AEDAT 2.0" in done.stderr
        assert not info.metadata.get("cut")
    else:
        assert "written by a run that failed before its input's end" in done.stderr and info.metadata.get("cut")


def test_a_replaced_output_keeps_its_permissions_and_a_read_only_one_is_not_replaced(tmp_path, stream):
    """Issue 37 item 11: -o over a 0600 file left 0644; over a 0444 file replaced it without a word."""
    private, locked = tmp_path / "private.aedat4", tmp_path / "locked.aedat4"
    for path, mode in ((private, 0o600), (locked, 0o444)):
        path.write_bytes(b"old")
        path.chmod(mode)
    run("convert", stream[0], "-o", private)
    assert private.stat().st_mode & 0o777 == 0o600 and len(evtools.read(private)[0]) > 0
    done = run("convert", stream[0], "-o", locked, check=False)
    assert_clean_error(done, "locked.aedat4", "read-only")
    assert locked.read_bytes() == b"old"
    _no_temporaries(tmp_path)


BOMBS = [
    (["simulate", "scene:flicker", "--size", "64x48", "--duration", "1s", "--shot-noise-rate-hz", "1e12"],
     "--shot-noise-rate-hz"),
    (["simulate", "scene:flicker", "--size", "64x48", "--duration", "1s", "--leak-rate-hz", "1e12"], "--leak-rate-hz"),
    (["simulate", "scene:flicker", "--size", "346x260", "--duration", "1s", "--shot-noise-rate-hz", "1e5"],
     "events/s"),
]  # (--frame-rate 1e9, once here, is a usage error now: its range is checked with the options, test_exit_codes)


@pytest.mark.parametrize("argv, named", BOMBS, ids=[b[1] for b in BOMBS])
def test_values_that_would_exhaust_memory_are_refused_in_bounded_memory(tmp_path, argv, named):
    """Issue 37 item 8: each ran until killed for memory (1.8 GiB and growing, > 3 GiB); under a 1 GB address
    space each now exits 1 with one line naming the value and its limit, nothing written."""
    out = tmp_path / "x.aedat4"
    done = subprocess.run(["prlimit", "--as=1000000000", EVTOOLS, *argv, "-o", str(out)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 1, done.stderr
    assert named in done.stderr and "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_uniformity_over_a_huge_time_gap_runs_in_bounded_memory(tmp_path):
    """A QA sweep: four events 4e15 us apart ran `metrics uniformity` out of memory (a histogram of every ms of the
    span; 1 GB for a 1e12 us gap). Its bins are now the ones that hold events: under a 1 GB address space the
    command runs and finds no edge (a warning), exit 0."""
    gap = tmp_path / "gap.csv"
    gap.write_text("t,x,y,p\n0,1,1,1\n1000,1,1,1\n4000000000000000,2,2,0\n4000000000001000,2,2,1\n")
    done = subprocess.run(["prlimit", "--as=1000000000", EVTOOLS, "metrics", "uniformity", str(gap), "--sensor-size",
                           "10x10", "--json"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert json.loads(done.stdout)["edges"] == [] and "no stimulus edge found" in done.stderr


def test_an_inferred_sensor_larger_than_any_camera_is_refused(tmp_path):
    """Issue 37 item 8: a 3-line CSV reaching x = 8191 inferred an 8192 x 8192 sensor and took 2-3 GiB in estimate,
    bafilter and render; an inferred side beyond 2048 is refused, --sensor-size still sets any size."""
    source = tmp_path / "three.csv"
    source.write_text("0,1,1,1\n10,8191,2,0\n20,3,3,1\n")
    done = run("bafilter", source, "-o", tmp_path / "x.aedat4", check=False)
    assert_clean_error(done, "three.csv", "--sensor-size")
    run("bafilter", source, "--sensor-size", "8192x4", "-o", tmp_path / "x.aedat4")


def test_a_truth_file_on_a_full_disk_names_it(small_disk, tmp_path):
    """Issue 37 item 11: simulate --truth on a full disk did not name the file; the events go elsewhere."""
    filler = small_disk / "filler"
    filler.write_bytes(bytes(240 * 1024))
    done = run("simulate", "scene:flicker", "--size", "64x48", "--duration", "2s", "--truth", small_disk / "t.h5",
               "-o", tmp_path / "s.aedat4", check=False)
    assert done.returncode == 1 and "Traceback" not in done.stderr.decode()
    assert str(small_disk / "t.h5") in done.stderr.decode(), done.stderr.decode()
    assert sorted(os.listdir(small_disk)) == ["filler"]


@pytest.mark.parametrize("source", ["scene", "events", "video"])
def test_a_failed_simulation_leaves_no_truth_file_and_never_overwrites_its_input(tmp_path, stream, source):
    """A QA sweep: `simulate --truth t.h5 -o /dev/full` failed (exit 1) and left a complete t.h5 of events that no
    output held (a Makefile rule then took it as up to date); the truth file is now completed only after the events.
    And a video's --truth naming the video was not refused (events inputs were)."""
    import cv2

    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25, (64, 48))
    for i in range(10):
        writer.write(np.full((48, 64, 3), 50 if i % 2 else 200, np.uint8))
    writer.release()
    given = {"scene": ["scene:bars", "--size", "64x48", "--duration", "1s"], "events": [stream[0]],
             "video": [video]}[source]
    truth = tmp_path / "t.h5"
    for output in (["-o", "/dev/full"], ["--format", "csv", "-o", "/dev/full"]):
        done = run("simulate", *given, "--truth", truth, *output, check=False)
        assert done.returncode == 1 and "No space left on device" in done.stderr.decode() and not truth.exists()
    link = tmp_path / "link.h5"  # a link to a file not made yet and that file's name are one output (a QA sweep)
    link.symlink_to(tmp_path / "same.h5")
    for truth_name, output_name in ((tmp_path / "same.h5", link), (link, tmp_path / "same.h5")):
        done = run("simulate", *given, "--truth", truth_name, "-o", output_name, check=False)
        assert done.returncode == 1 and "--truth and -o name the same file" in done.stderr.decode(), done.stderr
        assert not (tmp_path / "same.h5").exists()
    if source != "scene":
        before = given[0].read_bytes()
        done = run("simulate", *given, "--truth", given[0], "-o", tmp_path / "x.aedat4", check=False)
        assert_clean_error(done, "--truth would overwrite the input")
        assert given[0].read_bytes() == before and not (tmp_path / "x.aedat4").exists()


@pytest.mark.parametrize("name", ["convert", "bafilter", "correct"])
def test_a_cut_file_input_gives_an_output_that_reads_as_cut(tmp_path, stream, name):
    """Issue 37 item 2, its file half: a file whose end mark is missing is read with a warning; the output of a
    stage then ends without the end mark too, so the next reader warns as well (it looked complete)."""
    from evtools.formats.aedat4 import Aedat4Writer
    from evtools.formats.registry import WriteOptions

    events, info = evtools.read(stream[0])
    cut = tmp_path / "cut.aedat4"
    with open(cut, "wb") as file:
        writer = Aedat4Writer(file, info, WriteOptions())
        writer.write(events[: len(events) // 2])
        writer.abort()  # no end mark: a writer killed between two packets
    output = tmp_path / "out.aedat4"
    done = run(name, cut, *_options(name, stream), "-o", output)
    assert "ends without the end mark" in done.stderr.decode()
    assert "ends without the end mark" in run("info", output).stderr.decode()
    whole = tmp_path / "whole.aedat4"
    run(name, stream[0], *_options(name, stream), "-o", whole)
    assert "end mark" not in run("info", whole).stderr.decode()


def _catches_sigterm(pid: int) -> bool:
    """The process has its own SIGTERM handler (its caught-signals mask in /proc says so)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(caught & (1 << (15 - 1)))


@pytest.mark.parametrize("where", ["click.Command._main_shell_completion", "click.Group.parse_args",
                                   "click.Context.__enter__"])
@pytest.mark.parametrize("signal_number", [2, 15])
def test_a_stop_anywhere_in_the_command_lines_start_exits_128_plus_the_signal(where, signal_number):
    """A stop while the command line starts ends like any other stop: 128 + signal and one line. click's standalone
    mode said "Aborted!" and exit 1 for a stop that landed outside the group's handling: while the global options
    were parsed (their callbacks import numpy), and (CI, a busy machine descheduling the process between the
    handlers' installation and the parsing: the test below, 0.1 of a run into `convert`) around it."""
    owner, name = where.rsplit(".", 1)
    script = f"""
import os, time, click
from evtools.cli.main import main
def stopped(*args, **kwargs):  # the signal lands here (its handler raises in the sleep)
    os.kill(os.getpid(), {signal_number})
    time.sleep(10)
{owner}.{name} = stopped
main()
"""
    done = subprocess.run([sys.executable, "-c", script, "info", "x.aedat4"], capture_output=True, text=True,
                          cwd=ROOT, timeout=120)
    assert done.returncode == 128 + signal_number, done.stderr
    assert done.stderr.strip() == "evtools: interrupted", done.stderr


@pytest.mark.parametrize("signal_number", [2, 15])
def test_a_stop_at_any_moment_of_an_hdf5_write_is_clean(tmp_path, signal_number):
    """Issue 37 item 7: SIGINT / SIGTERM 0.6-0.9 s into `convert big.aedat4 -o x.h5` crashed (SIGSEGV) in 7 of 11
    runs: the signal landed while HDF5 committed the file (or made the writer), raising inside its writes through a
    Python file object. At moments spread over the whole run (its start, the stream, the commit, the exit): exit
    0 (it had ended), 130 / 143, never a crash or a traceback; an output left behind is a readable HDF5 file."""
    source = tmp_path / "big.aedat4"
    events, _ = evtools.simulate("bars", size=(128, 96), duration_us=1_500_000, seed=4)
    evtools.write(source, events, evtools.StreamInfo(128, 96))
    out = tmp_path / "x.h5"
    started = time.monotonic()
    run("convert", source, "-o", out)
    whole_run_s = time.monotonic() - started
    out.unlink()
    for moment in np.linspace(0.0, 1.1, 12):
        stage = subprocess.Popen([EVTOOLS, "convert", str(source), "-o", str(out)], stderr=subprocess.PIPE, text=True,
                                 cwd=ROOT)
        wait_until(lambda: _catches_sigterm(stage.pid), "the command's handlers (the interpreter's start is before)")
        time.sleep(moment * whole_run_s)
        stage.send_signal(signal_number)
        code, stderr = stage.wait(timeout=60), stage.stderr.read()
        assert code in (0, 128 + signal_number) and "Traceback" not in stderr, (moment, code, stderr)
        if out.exists():
            assert evtools.read(out)[0].size <= len(events)
            out.unlink()
        _no_temporaries(tmp_path)


# --- a file cut inside a record or packet: the whole ones before the cut are read, the stream marked cut ---

CUT_KINDS = {"aedat4": ("aedat4", "none"), "aedat4 lz4": ("aedat4", "lz4"), "aedat": ("aedat", None),
             "raw": ("raw", None)}
"""The writable formats whose files are records or packets (a cut can fall inside one): suffix, compression."""


def _whole_ends(path: Path, suffix: str) -> list[int]:
    """The byte offsets at which a cut of ``path`` loses no part of a record or packet (after the header)."""
    from tests.helpers import aedat4_packets

    data = path.read_bytes()
    if suffix == "aedat4":
        return aedat4_packets(data)
    with evtools.open(path) as stream:
        header_bytes = stream.reader.header_bytes
    record_bytes = 8 if suffix == "aedat" else 4  # (AEDAT 2.0: address and time; EVT 2.0: 32-bit words)
    return list(range(header_bytes, len(data) + 1, record_bytes))


def _read_cut(path: Path) -> tuple[np.ndarray, bool]:
    with evtools.open(path) as stream:
        events = concatenate(stream)
        return events, stream.was_cut


@settings(max_examples=40, deadline=None)
@given(kind=st.sampled_from(sorted(CUT_KINDS)), n=st.integers(1, 2000), seed=st.integers(0, 2**31),
       chunks=st.lists(st.integers(0, 2000), max_size=6), at=st.floats(0, 1, exclude_max=True))
@example(kind="aedat", n=667, seed=1, chunks=[], at=0.5)  # (its first event's first byte is '#': not written)
def test_a_file_cut_anywhere_keeps_every_whole_record_before_the_cut(tmp_path_factory, kind, n, seed, chunks, at):
    """A recording whose copy broke off (or whose camera crashed) inside a record or packet was refused whole: every
    event lost. Now the whole records/packets before the cut are read (the same events as a cut at the start of the
    broken one), a warning names the file, and the stream is marked cut."""
    from tests.helpers import cut, random_events

    suffix, compression = CUT_KINDS[kind]
    folder = tmp_path_factory.mktemp("cut")
    events = random_events(n, 64, 48, seed=seed)
    whole = folder / f"whole.{suffix}"
    with evtools.formats.create_events(whole, evtools.StreamInfo(64, 48), compression=compression) as writer:
        for part in cut(events, chunks):  # (AEDAT 4.0: a packet a write)
            writer.write(part)
    ends = _whole_ends(whole, suffix)
    data = whole.read_bytes()
    position = ends[0] + int(at * (len(data) - ends[0]))
    inside = position not in ends
    broken = folder / f"broken.{suffix}"
    broken.write_bytes(data[:position])
    clean = folder / f"clean.{suffix}"
    clean.write_bytes(data[:max(end for end in ends if end <= position)])
    got, was_cut = _read_cut(broken)
    expected, _ = _read_cut(clean)
    written, _ = _read_cut(whole)  # (AEDAT 2.0 drops a leading event whose first byte reads as a header's '#')
    assert_same_events(got, expected)
    assert_same_events(got, written[:len(got)])
    assert was_cut == (inside or suffix == "aedat4")  # (AEDAT 4.0 of evtools: its end mark is missing too)


def test_a_file_cut_inside_a_packet_goes_through_a_command_marked_cut(tmp_path):
    """On the command line: exit 0, one warning line naming the file and the cut, the events before it written and
    the output marked cut (read back: said again); through a pipe (a live input: its writer stopped mid-write) it
    stays an error, one line, and a damaged size field inside the file is an error."""
    from tests.helpers import aedat4_packets, random_events

    events = random_events(100_000, 64, 48, seed=2)
    whole = tmp_path / "whole.aedat4"
    evtools.write(whole, events, evtools.StreamInfo(64, 48))
    data = whole.read_bytes()
    second = aedat4_packets(data)[1]
    (tmp_path / "at_boundary.aedat4").write_bytes(data[:second])
    in_first = len(evtools.read(tmp_path / "at_boundary.aedat4")[0])  # (the first packet's events)
    assert 0 < in_first < len(events)
    broken = tmp_path / "broken.aedat4"
    broken.write_bytes(data[:second + 500])
    out = tmp_path / "out.h5"
    result = run("convert", broken, "-o", out, check=False)
    stderr = result.stderr.decode()
    assert result.returncode == 0 and stderr.count("warning") == 1 and "Traceback" not in stderr, stderr
    assert "broken.aedat4" in stderr and f"packet at byte {second:,}" in stderr and "cut" in stderr
    with evtools.open(out) as stream:
        assert_same_events(concatenate(stream), events[:in_first])
        assert stream.was_cut
    piped = run("convert", "-", "-o", tmp_path / "piped.h5", input=broken.read_bytes(), check=False)
    assert_clean_error(piped, "<stdin>", "truncated AEDAT 4.0 packet")
    assert not (tmp_path / "piped.h5").exists()
    damaged = bytearray(data)
    damaged[second + 4:second + 8] = (1 << 31).to_bytes(4, "little")  # a size field no packet has, inside the file
    (tmp_path / "damaged.aedat4").write_bytes(damaged)
    assert_clean_error(run("info", tmp_path / "damaged.aedat4", check=False), "damaged.aedat4", "damaged")


def test_cut_files_are_said_the_same_through_python_and_slices_and_damage_is_not_a_cut(tmp_path, caplog):
    """(A QA sweep of the cut files' salvage.) evtools.read of a cut file gives info.metadata["cut"], and
    evtools.write of it marks its output cut (AEDAT 2.0: refused); a slice that ends before the cut is whole; a
    last CSV field cut from "-1" to "-" is the cut, not an OFF event; a packet of a stream id the header never
    declared, and one that runs past the data table of a DV file that reaches it, are damage (errors), not cuts;
    an AEDAT 3.1 file cut short is said once even when its size is scanned."""
    from tests.helpers import aedat4_packets, random_events

    events = random_events(100_000, 64, 48, seed=4)
    whole = tmp_path / "whole.aedat4"
    evtools.write(whole, events, evtools.StreamInfo(64, 48))
    data = whole.read_bytes()
    packets = aedat4_packets(data)
    broken = tmp_path / "broken.aedat4"
    broken.write_bytes(data[:packets[2] + 100])
    read, info = evtools.read(broken)
    assert info.metadata["cut"] is True
    evtools.write(tmp_path / "again.h5", read, info)
    with evtools.open(tmp_path / "again.h5") as again:
        assert again.was_cut
    with pytest.raises(evtools.EvtoolsError, match="nowhere to say so"):
        evtools.write(tmp_path / "again.aedat", read, info)
    assert not (tmp_path / "again.aedat").exists()
    end_us = int(events["t"][1000] - events["t"][0])  # (inside the first packet: the slice is whole)
    run("convert", broken, "--end", f"{end_us}us", "-o", tmp_path / "slice.aedat4")
    with evtools.open(tmp_path / "slice.aedat4") as sliced:
        assert len(concatenate(sliced)) == 1000 and not sliced.was_cut
    signs = tmp_path / "signs.csv"
    signs.write_text("t,x,y,p\n1,2,3,1\n2,3,4,-")
    with evtools.open(signs, sensor_size=(8, 8)) as stream:
        assert len(concatenate(stream)) == 1 and stream.was_cut
    undeclared = bytearray(data)
    undeclared[packets[1]:packets[1] + 4] = (77).to_bytes(4, "little")
    (tmp_path / "undeclared.aedat4").write_bytes(undeclared)
    assert_clean_error(run("info", tmp_path / "undeclared.aedat4", check=False), "undeclared.aedat4",
                       "stream id 77")


def test_a_dv_file_whose_packet_runs_past_its_data_table_is_damaged_not_cut(tmp_path):
    dv = pytest.importorskip("dv_processing", reason="dv-processing (the test extra) writes a file with its table")
    from tests.helpers import random_events

    events = random_events(20_000, 64, 48, seed=6)
    config = dv.io.MonoCameraWriter.Config("test")
    config.addEventStream((64, 48))
    writer = dv.io.MonoCameraWriter(str(tmp_path / "dv.aedat4"), config)
    for start in range(0, len(events), 5000):
        store = dv.EventStore()
        for event in events[start:start + 5000]:
            store.push_back(int(event["t"]), int(event["x"]), int(event["y"]), bool(event["p"]))
        writer.writeEvents(store)
    del writer
    data = bytearray((tmp_path / "dv.aedat4").read_bytes())
    first = len(b"#!AER-DAT4.0\r\n") + 4 + int.from_bytes(data[14:18], "little")
    size = int.from_bytes(data[first + 4:first + 8], "little")
    data[first + 4:first + 8] = (size + 40_000).to_bytes(4, "little")  # within the file, past its data table
    (tmp_path / "damaged.aedat4").write_bytes(data)
    assert_clean_error(run("info", tmp_path / "damaged.aedat4", check=False), "damaged.aedat4", "data table")


@pytest.mark.parametrize("signal_number", [2, 15])
def test_render_stops_between_frames(tmp_path, signal_number):
    """A QA sweep: `render walk.aedat --window-us 1` went on drawing the first chunk's millions of windows for
    minutes after SIGINT or SIGTERM (the reader's stop waits for the next chunk). Now it stops at the next frame:
    exit 128 + signal, the frames drawn so far a readable video."""
    import cv2

    stream = tmp_path / "sparse.aedat4"
    t = np.arange(0, 900_000, 50_000)  # an event every 50 ms for 0.9 s: 900,000 windows of 1 us (under MAX_FRAMES)
    evtools.write(stream, evtools.make_events(t, t % 8, t % 6, t % 2), evtools.StreamInfo(8, 6))
    output = tmp_path / "frames.avi"
    process = subprocess.Popen([EVTOOLS, "render", str(stream), "-o", str(output), "--window-us", "1"],
                               stderr=subprocess.PIPE)
    wait_until(lambda: any(p.name.startswith(".") for p in tmp_path.iterdir()), "the video under way")
    time.sleep(0.5)
    process.send_signal(signal_number)
    assert process.wait(timeout=60) == 128 + signal_number  # (a hang guard: the old code drew on for minutes)
    process.stderr.close()
    video = cv2.VideoCapture(str(output))
    assert video.get(cv2.CAP_PROP_FRAME_COUNT) > 0
    video.release()


@pytest.mark.parametrize("stop_at", ["after the last event", "after the first chunk"])
def test_a_stop_cuts_an_output_only_when_it_cut_the_reading(tmp_path, monkeypatch, stop_at):
    """A QA sweep: SIGINT landing once every event was read (the work done, the output being closed) marked a
    complete output as cut. The stop is set where the signal's handler would set it."""
    import signal

    from evtools import interrupt
    from evtools.formats import create_events, open_events

    for name, value in (("_received", None), ("_begun", 0), ("_whole", 0)):
        monkeypatch.setattr(interrupt, name, value, raising=False)
    source = tmp_path / "in.aedat4"
    t = np.arange(0, 10_000_000, 100)
    evtools.write(source, evtools.make_events(t, t % 32, t % 24, t % 3 == 0), evtools.StreamInfo(32, 24))
    output = tmp_path / "out.aedat4"
    with open_events(str(source), chunk_events=10_000) as stream, \
            create_events(str(output), stream.info, inputs=(str(source),)) as writer:
        for chunk in stream:
            writer.write(chunk)
            if stop_at == "after the first chunk":
                interrupt._received = signal.SIGINT
        interrupt._received = signal.SIGINT
    monkeypatch.setattr(interrupt, "_received", None)
    with evtools.open(output) as copy:
        events = sum(len(chunk) for chunk in copy)
        assert copy.was_cut == (stop_at == "after the first chunk")
    assert (events == len(t)) == (stop_at == "after the last event")


@pytest.mark.parametrize("upstream", ["file", "live"])
def test_a_pipelines_ctrl_c_marks_its_output_cut_when_a_file_was_being_read(tmp_path, upstream):
    """A terminal's Ctrl-C stops every stage. `convert FILE | bafilter - -o OUT` once left OUT marked whole with
    14 M of a file's 35 M events (a QA sweep): the stopped bafilter took its pipe's stop for the stream's end. It
    now reads on for the upstream's own end: convert, stopped while reading a file, ends its output without the
    end mark, so OUT is marked cut (and readable). When the upstream read a live pipe (its stop is its end) it ends
    with the mark and OUT is whole."""
    import signal

    output = tmp_path / "out.aedat4"
    if upstream == "file":  # 25 s, sent at its own pace: still going when the signal comes
        source = f"exec {EVTOOLS} convert {data_file('dvs128_walk.aedat')} - --realtime"
    else:  # a camera's stream (DV's, no end mark promised) trickling in through a pipe, relayed by convert
        trickle = ("import signal, sys, time; signal.signal(signal.SIGINT, signal.SIG_DFL); "
                   "data = open(sys.argv[1], 'rb').read(); "
                   "[(sys.stdout.buffer.write(data[k:k + 4096]), sys.stdout.flush(), time.sleep(0.02)) "
                   "for k in range(0, len(data), 4096)]")
        source = (f"{sys.executable} -c \"{trickle}\" {data_file('dvxplorer_sample.aedat4')} | "
                  f"{EVTOOLS} convert -")
    pipeline = subprocess.Popen(["bash", "-c", f"{source} | {EVTOOLS} bafilter - -o {output}"],
                                start_new_session=True, stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: any(p.name != "out.aedat4" and p.stat().st_size > 65536 for p in tmp_path.iterdir()),
                   "bafilter's first packets written")
        os.killpg(pipeline.pid, signal.SIGINT)
        assert pipeline.wait(timeout=60) == 130
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(pipeline.pid, signal.SIGKILL)
    stderr = pipeline.stderr.read()
    assert "Traceback" not in stderr, stderr
    events, _ = evtools.read(output)
    assert 0 < len(events)
    info = json.loads(run("info", output, "--json").stdout)
    assert info["cut"] == (upstream == "file"), (info, stderr)


def test_two_aedat4_streams_joined_end_to_end_are_said_as_such(tmp_path):
    """A QA sweep: `cat a.aedat4 b.aedat4 | evtools convert -` said "damaged AEDAT 4.0 packet header" (the second
    file's first line read as a packet's size). It names what it found: a second AEDAT file, at its byte."""
    source = data_file("dvxplorer_sample.aedat4")
    first, second = tmp_path / "a.aedat4", tmp_path / "b.aedat4"
    run("convert", source, "--end", "300ms", "-o", first)
    run("convert", source, "--start", "300ms", "-o", second)
    joined = tmp_path / "ab.aedat4"
    joined.write_bytes(first.read_bytes() + second.read_bytes())
    assert_clean_error(run("info", joined, check=False), f"a second AEDAT file begins at byte "
                       f"{first.stat().st_size:,}", "separate inputs")
