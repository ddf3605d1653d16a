"""The command line as a user meets it: real processes, real pipes, exit codes, one-line errors, atomic outputs."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

from evtools.events import StreamInfo
from evtools.formats import create_events
from evtools.formats.aedat4 import Aedat4Writer
from evtools.formats.registry import WriteOptions
from tests.conftest import data_file
from tests.helpers import EVTOOLS, aedat4_packets, assert_clean_error, assert_same_events, random_events, read_all, run


@pytest.fixture
def sample(tmp_path) -> tuple[Path, np.ndarray]:
    events = random_events(20_000, seed=7, t0_us=5_000)
    path = tmp_path / "sample.aedat4"
    with create_events(path, StreamInfo(346, 260)) as writer:
        writer.write(events)
    return path, events


def test_info_json_on_the_real_recordings():
    result = run("info", data_file("dvxplorer_sample.aedat4"), data_file("dvs128_walk.aedat"), "--json")
    first, second = json.loads(result.stdout)
    assert (first["format"], first["width"], first["height"], first["events"]) == ("aedat4", 320, 240, 111_954)
    assert first["metadata"]["skipped_streams"] == ["imu", "triggers"]
    assert 0.4 < first["on_fraction"] < 0.6
    assert (second["format"], second["width"], second["height"], second["events"]) == ("aedat2", 128, 128, 290_292)
    assert second["duration_s"] == pytest.approx(25.1, abs=0.05)


def test_info_prints_json_when_stdout_is_not_a_terminal(sample):
    path, events = sample
    summary = json.loads(run("info", path).stdout)
    assert summary["events"] == len(events)
    assert summary["t_first_us"] == events["t"][0] and summary["t_last_us"] == events["t"][-1]
    assert summary["rate_hz"] == pytest.approx(len(events) / ((events["t"][-1] - events["t"][0]) * 1e-6))


def test_info_on_several_files_shows_the_good_ones_beside_a_bad_one(sample, tmp_path):
    """One bad file hid every other file's summary (a QA sweep): each bad one is said on stderr and in the JSON,
    the good ones are shown, exit 1."""
    path, events = sample
    bad = tmp_path / "bad.aedat4"
    bad.write_bytes(path.read_bytes()[:20])  # (cut inside its header)
    result = run("info", path, bad, tmp_path / "missing.aedat4", path, "--json", check=False)
    assert result.returncode == 1 and b"Traceback" not in result.stderr
    rows = json.loads(result.stdout)
    assert [row.get("events") for row in rows] == [len(events), None, None, len(events)]
    assert "bad.aedat4" in rows[1]["error"] and "missing.aedat4" in rows[2]["error"]
    assert result.stderr.decode().count("evtools: error: ") == 2


@pytest.mark.parametrize("ext", ["aedat4", "aedat", "h5", "csv", "txt"])
def test_convert_round_trips_every_writable_format(sample, tmp_path, ext):
    path, events = sample
    run("convert", path, "-o", tmp_path / f"out.{ext}")
    run("convert", tmp_path / f"out.{ext}", "-o", tmp_path / "back.aedat4", "--sensor-size", "346x260")
    info, back = read_all(tmp_path / "back.aedat4")
    assert (info.width, info.height) == (346, 260)
    assert_same_events(back, events)


def test_pipe_between_two_processes(sample, tmp_path):
    path, events = sample
    shell = f"'{EVTOOLS}' convert '{path}' - | '{EVTOOLS}' convert - -o '{tmp_path / 'b.h5'}'"
    subprocess.run(["bash", "-o", "pipefail", "-c", shell], check=True, timeout=120)
    info, back = read_all(tmp_path / "b.h5")
    assert (info.width, info.height) == (346, 260)
    assert_same_events(back, events)


def test_real_recording_through_a_pipe_keeps_every_event(tmp_path, dvxplorer_events):
    source = data_file("dvs128_walk.aedat")
    shell = f"'{EVTOOLS}' convert '{source}' - | '{EVTOOLS}' convert - '{tmp_path / 'walk.csv'}'"
    subprocess.run(["bash", "-o", "pipefail", "-c", shell], check=True, timeout=120)
    _, direct = read_all(source)
    _, piped = read_all(tmp_path / "walk.csv", sensor_size=(128, 128))
    assert len(direct) == 290_292
    assert_same_events(piped, direct)


def test_closing_the_pipe_early_ends_quietly(sample):
    path, _ = sample
    shell = f"'{EVTOOLS}' convert '{path}' - | head -c 100 > /dev/null; echo ${{PIPESTATUS[0]}}"
    result = subprocess.run(["bash", "-c", shell], capture_output=True, timeout=60)
    assert result.stderr == b""
    assert result.stdout.strip() in (b"0", b"141")


def test_hdf5_to_stdout_is_refused(sample):
    path, _ = sample
    refused = run("convert", path, "--format", "hdf5", check=False)  # (a choice of the command line: exit 2)
    assert refused.returncode == 2 and b"stdout" in refused.stderr and b"-o FILE" in refused.stderr
    assert refused.stderr.count(b"\n") == 1 and refused.stdout == b""


def test_text_goes_to_a_terminal_and_binary_does_not(sample, tmp_path):
    """CSV and text on a terminal, to look at a few events (they were refused as binary: a QA sweep); AEDAT 4.0 on
    a terminal is refused, exit 2."""
    import os
    import pty

    path, events = sample
    for output_format, expected in (("csv", 0), ("txt", 0), ("aedat4", 2)):
        controller, terminal = pty.openpty()
        try:
            done = subprocess.run([EVTOOLS, "-q", "convert", path, "--format", output_format, "--end", "1ms"],
                                  stdout=terminal, stderr=subprocess.PIPE, timeout=120)
            shown = os.read(controller, 1 << 16).decode(errors="replace") if expected == 0 else ""
        finally:
            os.close(terminal)
            os.close(controller)
        assert done.returncode == expected, done.stderr
        if expected == 0:
            assert f"{events['x'][0]}" in shown and shown.count("\n") >= 2
        else:
            assert b"refusing to write binary" in done.stderr


# --- bad inputs: one line naming the file and the problem, exit 1, no output file left behind ---


def _bad_inputs(tmp_path: Path) -> dict[str, tuple[Path, list[str], tuple[str, ...]]]:
    cases = {}
    empty = tmp_path / "empty.aedat4"
    empty.write_bytes(b"")
    cases["empty file"] = (empty, [], ("empty.aedat4", "empty"))
    noise = tmp_path / "noise.bin"
    noise.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    cases["random bytes"] = (noise, [], ("noise.bin", "unknown format"))
    good = tmp_path / "good.aedat4"
    with create_events(good, StreamInfo(64, 48)) as writer:
        writer.write(random_events(5000, 64, 48))
    damaged = bytearray(good.read_bytes())  # (a file cut inside a packet is read up to it: tests/test_faults.py)
    first = aedat4_packets(bytes(damaged))[0]
    damaged[first + 4:first + 8] = (1 << 31).to_bytes(4, "little")  # a size no packet has
    (tmp_path / "damaged.aedat4").write_bytes(damaged)
    cases["damaged AEDAT 4.0 packet"] = (tmp_path / "damaged.aedat4", [], ("damaged.aedat4", "damaged"))
    letters = tmp_path / "letters.csv"
    letters.write_text("t,x,y,p\n1,2,3,1\n2,3,oops,0\n")
    cases["CSV line with letters"] = (letters, ["--sensor-size", "10x10"], ("letters.csv", "line 3"))
    no_events = tmp_path / "no_events.h5"
    with h5py.File(no_events, "w") as f:
        f["something/else"] = np.arange(3)
    cases["HDF5 without events"] = (no_events, [], ("no_events.h5",))
    outside = tmp_path / "outside.aedat4"
    with outside.open("wb") as stream:
        writer = Aedat4Writer(stream, StreamInfo(10, 10), WriteOptions())
        writer.write(random_events(100, 12, 10, seed=9))
        writer.close()
    cases["coordinates outside the sensor"] = (outside, [], ("outside.aedat4", "outside the 10x10 sensor", "event ",
                                                             "the size the file states: a damaged file"))
    backwards = tmp_path / "backwards.aedat4"
    events = random_events(100, 10, 10)
    events["t"][50] = events["t"][49] - 1
    with backwards.open("wb") as stream:
        writer = Aedat4Writer(stream, StreamInfo(10, 10), WriteOptions())
        writer.write(events)
        writer.close()
    cases["time going backwards"] = (backwards, [], ("backwards.aedat4", "time goes backwards at event 50"))
    cases["missing file"] = (tmp_path / "missing.aedat4", [], ("missing.aedat4", "no such file"))
    return cases


BAD = ["empty file", "random bytes", "damaged AEDAT 4.0 packet",
       "CSV line with letters", "HDF5 without events", "coordinates outside the sensor", "time going backwards",
       "missing file"]


@pytest.mark.parametrize("case", BAD)
def test_bad_input_gives_one_line_and_no_output_file(tmp_path, case):
    path, extra, needles = _bad_inputs(tmp_path)[case]
    out = tmp_path / "out" / "converted.h5"
    out.parent.mkdir()
    assert_clean_error(run("convert", path, "-o", out, *extra, check=False), *needles)
    assert list(out.parent.iterdir()) == [], "a failed run must leave no file, not even a temporary one"
    assert_clean_error(run("info", path, *extra, check=False), *needles)


def test_bad_input_on_stdin_is_named_stdin(tmp_path):
    assert_clean_error(run("info", "-", input=b"\x00\x01garbage" * 10, check=False), "<stdin>", "unknown format")
    assert_clean_error(run("convert", "-", "-o", tmp_path / "o.h5", input=b"", check=False), "<stdin>", "empty")


def test_output_equal_to_input_is_refused(sample):
    path, _ = sample
    before = path.read_bytes()
    assert_clean_error(run("convert", path, "-o", path, check=False), "overwrite the input")
    assert path.read_bytes() == before


def test_unknown_output_extension_asks_for_format(sample, tmp_path):
    path, _ = sample
    result = run("convert", path, "-o", tmp_path / "out.xyz", check=False)  # a usage mistake (issue 39): exit 2
    stderr = result.stderr.decode()
    assert result.returncode == 2 and stderr.count("\n") == 1 and stderr.startswith("evtools: usage: "), stderr
    assert "out.xyz" in stderr and "--format" in stderr and not (tmp_path / "out.xyz").exists()


def test_usage_errors_exit_2(sample):
    path, _ = sample
    assert run("convert", path, "--format", "nope", check=False).returncode == 2
    assert run("info", path, "--sensor-size", "0x3", check=False).returncode == 2


STREAM_WRITERS = [  # every command that writes an event stream, with its arguments on the sample
    ("convert", ["{sample}"]),
    ("bafilter", ["{sample}", "--preset", "dv"]),
    ("correct", ["{sample}", "--thresholds", "{thresholds}"]),
    ("simulate", ["{sample}", "--shot-noise-rate-hz", "2", "--seed", "3"]),
]


def _stream_arguments(arguments, sample_path: Path, tmp_path: Path) -> list[str]:
    thresholds = tmp_path / "thresholds.h5"
    if not thresholds.exists():
        rng = np.random.default_rng(5)
        with h5py.File(thresholds, "w") as h5:
            for name in ("on", "off"):
                h5[name] = rng.uniform(0.15, 0.35, (260, 346)).astype(np.float32)
    return [argument.format(sample=sample_path, thresholds=thresholds) for argument in arguments]


@pytest.mark.parametrize("compression", ["lz4", "zstd"])
@pytest.mark.parametrize("command, arguments", STREAM_WRITERS)
def test_every_stream_command_writes_the_compression_asked(sample, tmp_path, command, arguments, compression):
    args = _stream_arguments(arguments, sample[0], tmp_path)
    run(command, *args, "-o", tmp_path / "plain.aedat4")
    run(command, *args, "-o", tmp_path / "packed.aedat4", "--compression", compression)
    _, plain = read_all(tmp_path / "plain.aedat4")
    info, packed = read_all(tmp_path / "packed.aedat4")
    assert info.metadata["compression"] == compression.upper()
    assert len(plain) > 100  # (the dv filter keeps 1 % of random events)
    assert_same_events(packed, plain)
    assert (tmp_path / "packed.aedat4").stat().st_size < (tmp_path / "plain.aedat4").stat().st_size


@pytest.mark.parametrize("command, arguments", STREAM_WRITERS)
def test_a_compression_the_output_format_lacks_is_a_usage_error(sample, tmp_path, command, arguments):
    args = _stream_arguments(arguments, sample[0], tmp_path)
    for name, compression, needle in (("out.csv", "lz4", "is written uncompressed"),
                                      ("out.aedat4", "gzip", "none, lz4, lz4-high, zstd, zstd-high"),
                                      ("out.h5", "lz4", "none, zstd, gzip, lzf")):
        result = run(command, *args, "-o", tmp_path / name, "--compression", compression, check=False)
        stderr = result.stderr.decode()
        assert result.returncode == 2, stderr
        assert "--compression" in stderr and name in stderr and needle in stderr and "Traceback" not in stderr
        assert not (tmp_path / name).exists()


@pytest.mark.parametrize("command", ["convert", "bafilter", "correct"])
def test_a_wrong_compression_into_a_folder_leaves_no_folder(sample, tmp_path, command):
    """Several inputs into -o FOLDER/: the compression is checked before the folder is made."""
    args = _stream_arguments(dict(STREAM_WRITERS)[command], sample[0], tmp_path)
    second = tmp_path / "again.aedat4"
    second.write_bytes(sample[0].read_bytes())
    args.insert(1, str(second))  # two inputs: the sample under two names
    result = run(command, *args, "-o", f"{tmp_path / 'out'}{os.sep}", "--compression", "gzip", check=False)
    assert result.returncode == 2, result.stderr.decode()
    assert "gzip" in result.stderr.decode() and not (tmp_path / "out").exists()


def test_compression_names_agree_with_the_writers(tmp_path):
    from evtools.formats import FormatError
    from evtools.formats.aedat4 import COMPRESSION_CODES
    from evtools.formats.registry import BY_NAME

    assert set(BY_NAME["aedat4"].compressions) == set(COMPRESSION_CODES)
    assert COMPRESSION_CODES[BY_NAME["aedat4"].compressions[0]] == 0  # the default is the header's "none"
    with pytest.raises(FormatError, match="uncompressed"):  # the Python API refuses it too, before creating
        with create_events(tmp_path / "x.csv", StreamInfo(8, 8), compression="zstd"):
            pass
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.parametrize("command, option, good", [
    (["simulate", "scene:flicker", "--size", "8x6", "-o", "{out}.aedat4"], "--duration", "0.25s"),
    (["simulate", "scene:flicker", "--size", "8x6", "-o", "{out}.aedat4"], "--period", "250ms"),
    (["estimate", "{sample}", "--method", "stimulus", "-o", "{out}.h5"], "--stimulus-period", "0.5min"),
    (["render", "{sample}", "-o", "{out}.png"], "--start", "0us"),
])
def test_every_time_option_wants_its_unit(sample, tmp_path, command, option, good):
    args = [part.format(sample=sample[0], out=tmp_path / "out") for part in command]
    for value in ("0.25", "soon", "2 hours"):  # a bare number (seconds? microseconds?) and nonsense: usage errors
        bad = run(*args, option, value, check=False)
        assert bad.returncode == 2, bad.stderr
        assert b"2s, 500ms, 250us, 1.5min" in bad.stderr and option.encode() in bad.stderr
        assert not list(tmp_path.glob("out.*"))
    accepted = run(*args, option, good, check=False)
    assert b"no unit" not in accepted.stderr and accepted.returncode in (0, 1), accepted.stderr


def test_output_files_get_ordinary_permissions(sample, tmp_path):
    path, _ = sample
    run("convert", path, "-o", tmp_path / "out.h5")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "out.h5").stat().st_mode & 0o777 == 0o666 & ~umask


def test_group_help_lists_the_commands_own_summaries_without_importing_them():
    import importlib
    import sys

    from evtools.cli.main import COMMANDS
    from evtools.cli.metrics import metrics

    for group in (COMMANDS, metrics.lazy_commands):
        for name, (target, summary) in group.items():
            module, function = target.split(":")
            command = getattr(importlib.import_module(module), function)
            assert summary == command.get_short_help_str(limit=1000), name
    # `evtools --help` and `evtools metrics --help` list them without loading numba (0.3 s) or h5py
    probe = ("import sys; from click.testing import CliRunner; from evtools.cli.main import cli; r = CliRunner(); "
             "a = r.invoke(cli, ['--help']); b = r.invoke(cli, ['metrics', '--help']); "
             "print(a.exit_code, b.exit_code, 'bafilter' in a.output, 'uniformity' in b.output, "
             "'numba' in sys.modules, 'h5py' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.split() == ["0", "0", "True", "True", "False", "False"]


def test_quiet_and_verbose_before_or_after_the_subcommand(tmp_path):
    """-q / -v are accepted after every subcommand (metrics' too), not only before it; -q after bafilter silences
    its counts line, as before it."""
    from evtools.cli.main import COMMANDS
    from evtools.cli.metrics import metrics

    names = [[name] for name in COMMANDS if name != "metrics"] + [["metrics", name] for name in metrics.lazy_commands]
    for name in names:
        text = run(*name, "--help").stdout.decode()
        assert "-q, --quiet" in text and "-v, --verbose" in text, name
    source = Path(__file__).resolve().parents[1] / "samples" / "step.aedat4"
    loud = run("bafilter", source, "-o", tmp_path / "a.aedat4")
    assert b"kept" in loud.stderr
    for args in (["-q", "bafilter", source, "-o", tmp_path / "b.aedat4"],
                 ["bafilter", source, "-o", tmp_path / "c.aedat4", "-q"]):
        assert run(*args).stderr == b""
    assert b"kept" in run("bafilter", source, "-v", "-o", tmp_path / "d.aedat4").stderr


def test_devices_take_the_pipe_format_and_hints_name_the_real_option(tmp_path):
    """`-o /dev/null` needs no --format (a device is a stream, like stdout: AEDAT 4.0); an unknown input's hint
    names --input-format, the option that exists."""
    source = Path(__file__).resolve().parents[1] / "samples" / "step.aedat4"
    assert run("simulate", "scene:bars", "--size", "16x16", "--duration", "50ms", "-o", "/dev/null").returncode == 0
    assert run("bafilter", source, "-o", "/dev/null").returncode == 0
    (tmp_path / "x.xyz").write_text("garbage\n")
    unknown = run("info", tmp_path / "x.xyz", check=False)
    assert unknown.returncode == 1 and b"--input-format" in unknown.stderr


def test_json_counts_of_the_stream_commands(tmp_path):
    """--json on bafilter, convert, correct and simulate: the counts as one JSON object, on stdout when the events
    go to a file and on stderr when they go to stdout (stdout carries data only); a batch gives every file."""
    samples = Path(__file__).resolve().parents[1] / "samples"
    source, truth = samples / "step.aedat4", samples / "step.truth.h5"
    filtered = json.loads(run("bafilter", source, "-o", tmp_path / "a.aedat4", "--json").stdout)
    assert filtered["command"] == "bafilter" and filtered["events_in"] == 14_811
    _, kept = read_all(tmp_path / "a.aedat4")
    assert filtered["events_out"] == len(kept)
    converted = json.loads(run("convert", source, "-o", tmp_path / "b.csv", "--json").stdout)
    assert converted["events_in"] == converted["events_out"] == 14_811
    piped = run("correct", source, "--thresholds", truth, "--json")
    assert piped.stdout.startswith(b"#!AER-DAT4.0")
    corrected = json.loads(piped.stderr)
    assert corrected["command"] == "correct" and corrected["output"] == "-" and corrected["events_out"] > 0
    simulated = json.loads(run("simulate", "scene:bars", "--size", "16x16", "--duration", "100ms", "--seed", 1,
                               "-o", tmp_path / "c.aedat4", "--json").stdout)
    assert simulated["events"] == simulated["signal"] + simulated["leak"] + simulated["shot"] + simulated["hot"]
    assert simulated["events"] == len(read_all(tmp_path / "c.aedat4")[1])
    # the other commands' keys (a QA sweep: simulate said "source" and no seconds), and an event stream's noise
    # counts its events in and out
    noisy = json.loads(run("simulate", tmp_path / "c.aedat4", "--shot-noise-rate-hz", "5", "-o", tmp_path / "d.aedat4",
                           "--json").stdout)
    for counts in (simulated, noisy):
        assert {"command", "input", "output", "seconds"} <= counts.keys() and "source" not in counts
    assert noisy["input"] == str(tmp_path / "c.aedat4") and noisy["events_in"] == simulated["events"]
    assert noisy["events_out"] == noisy["events"] == len(read_all(tmp_path / "d.aedat4")[1])
    batch = json.loads(run("convert", source, samples / "flicker.aedat4", "-o", tmp_path / "many", "--json").stdout)
    assert [f["events_in"] for f in batch["files"]] == [14_811, 19_382] and batch["failed"] == 0


def test_shell_completion_offers_subcommands_and_options():
    """The completion documented in the README: bash_complete answers with the subcommand and its options."""
    def complete(words: str, index: int) -> str:
        env = {**os.environ, "COMP_WORDS": words, "COMP_CWORD": str(index), "_EVTOOLS_COMPLETE": "bash_complete"}
        return subprocess.run([EVTOOLS], env=env, capture_output=True, text=True, timeout=60).stdout

    assert "plain,bafilter" in complete("evtools baf", 1)
    assert "plain,--polarity-maps" in complete("evtools bafilter --polarity", 2)
    assert "_evtools_completion" in subprocess.run([EVTOOLS], env={**os.environ, "_EVTOOLS_COMPLETE": "bash_source"},
                                                    capture_output=True, text=True, timeout=60).stdout


@pytest.mark.parametrize("unbuffered", [False, True])
def test_text_to_a_pipe_is_whole_or_ends_with_141(sample, tmp_path, unbuffered):
    """A CSV larger than a pipe's buffer: a reader that takes it all gets the file's bytes; one that closes early
    gets exit 141 from evtools. Under PYTHONUNBUFFERED=1 (python -u, common in containers) stdout's binary layer is
    raw, and a raw write may write part of its bytes: the rest of the CSV went missing and the exit code was 0."""
    path, _ = sample
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"} | (
        {"PYTHONUNBUFFERED": "1"} if unbuffered else {})
    run("convert", path, "-o", tmp_path / "file.csv")
    piped = tmp_path / "piped.csv"
    shell = f"'{EVTOOLS}' convert '{path}' --format csv -o - | cat > '{piped}'; echo ${{PIPESTATUS[0]}}"
    result = subprocess.run(["bash", "-c", shell], capture_output=True, timeout=60, env=env)
    assert result.stdout.strip() == b"0" and piped.read_bytes() == (tmp_path / "file.csv").read_bytes()
    assert len(piped.read_bytes()) > 1 << 17  # (more than a pipe holds)
    shell = f"'{EVTOOLS}' convert '{path}' --format csv -o - | head -c 100 > /dev/null; echo ${{PIPESTATUS[0]}}"
    result = subprocess.run(["bash", "-c", shell], capture_output=True, timeout=60, env=env)
    assert result.stdout.strip() == b"141" and result.stderr == b""


@pytest.mark.parametrize("command", ["convert", "bafilter", "estimate", "correct", "simulate", "render", "info",
                                     "metrics denoise", "metrics roc", "metrics esr", "metrics thresholds",
                                     "metrics uniformity", "metrics reconstruction", "metrics train-denoiser"])
def test_help_shows_no_implementation_noise(command):
    """Issue 39: help texts showed `[x<=None]` (an unbounded number) and `[1<=x<=4611686018427387904]` (the time
    type's technical limit); ranges now show only bounds a user types."""
    done = run(*command.split(), "--help")
    text = done.stdout.decode()
    assert "Usage:" in text
    for noise in ("None]", "<=None", "4611686018427387904", "2147483647"):
        assert noise not in text, (command, noise)
    if command == "estimate":  # its output is an HDF5 file, never stdout: the help said `-` or absent would do
        assert "absent: stdout" not in text and "never stdout" in " ".join(text.split())


def test_no_output_replaces_a_file_the_command_reads(tmp_path):
    """Whichever option names an input (a hot-pixel list, an image, a folder's frame, timestamps), an
    output of the same file is refused and the input is left as it was (issue 36's rule; found by a QA sweep: each
    of these was replaced, exit 0)."""
    import cv2

    import evtools
    from evtools.events import make_events

    rng = np.random.default_rng(0)
    n = 2000
    events = tmp_path / "in.aedat4"
    evtools.write(events, make_events(np.sort(rng.integers(0, 200_000, n)), rng.integers(0, 32, n),
                                      rng.integers(0, 24, n), rng.integers(0, 2, n)), StreamInfo(32, 24))
    hot = tmp_path / "hot.csv"
    hot.write_text("x,y\n1,0\n")
    image = tmp_path / "photo.png"
    cv2.imwrite(str(image), (rng.random((24, 32)) * 255).astype(np.uint8))
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(3):
        cv2.imwrite(str(folder / f"{k}.png"), (rng.random((24, 32)) * 255).astype(np.uint8))
    stamps = tmp_path / "stamps.txt"
    stamps.write_text("0.0\n0.033\n0.066\n")
    cases = [
        (hot, ["bafilter", events, "--method", "hotpixel", "--hot-pixels", hot, "-o", hot]),
        (image, ["simulate", "scene:texture", "--image", image, "--size", "32x24", "--duration", "50ms", "-o", image,
                 "--format", "aedat4"]),
        (folder / "1.png", ["simulate", folder, "--frame-rate", "30", "-o", folder / "1.png", "--format", "aedat4"]),
        (stamps, ["simulate", folder, "--timestamps", stamps, "-o", stamps, "--format", "aedat4"]),
    ]
    for named, args in cases:
        before = named.read_bytes()
        assert_clean_error(run("-q", *args, check=False), str(named), "is an input of this command")
        assert named.read_bytes() == before, args
        assert not [p for p in tmp_path.rglob("*.part*")], "a refused output leaves no temporary file"


def test_stdin_redirected_from_the_output_is_an_input_and_dev_stdout_a_pipe(tmp_path):
    """Found by a QA sweep: `bafilter - -o rec.aedat4 < rec.aedat4` replaced the recording (exit 0: stdin was not
    an input); `-o /dev/stdout` into a pipe failed naming a temporary beside a /proc path, and an output where no
    file can be made named the temporary, not the user's path."""
    import subprocess

    import evtools

    events = tmp_path / "rec.aedat4"
    evtools.write(events, random_events(3000, 32, 24, seed=2), StreamInfo(32, 24))
    before = events.read_bytes()
    for command in (["bafilter", "-"], ["convert", "-", "--polarity", "on"], ["estimate", "-", "--method", "offe", "--max-fit", "inf"]):
        output = events if command[0] != "estimate" else tmp_path / "rec.h5"
        if command[0] == "estimate":
            evtools.write(output, random_events(3000, 32, 24, seed=2), StreamInfo(32, 24))
        kept = output.read_bytes()
        with open(output, "rb") as stdin:
            done = subprocess.run([EVTOOLS, *command, "-o", str(output)], stdin=stdin, capture_output=True)
        assert_clean_error(done, f"{output}: is an input of this command (<stdin>, redirected from it)")
        assert output.read_bytes() == kept
    assert events.read_bytes() == before
    piped = run("bafilter", events, "-o", "/dev/stdout").stdout
    assert piped == run("bafilter", events, "-o", "-").stdout and len(piped) > 1000
    assert_clean_error(run("convert", events, "-o", "/proc/evtools-test.aedat4", check=False),
                       "/proc/evtools-test.aedat4: cannot write there")


def test_python_may_write_back_a_file_it_read(tmp_path):
    """The guard is the command line's: a Python session that reads a file and later writes it back on purpose
    is not refused."""
    import evtools
    from evtools.events import make_events

    path = tmp_path / "x.aedat4"
    evtools.write(path, make_events([1, 2], [0, 1], [0, 0], [1, 0]), StreamInfo(4, 4))
    events, info = evtools.read(path)
    evtools.write(path, events[:1], info)
    assert len(evtools.read(path)[0]) == 1


def test_an_output_format_that_is_only_read_and_a_crop_off_the_sensor_name_the_file(tmp_path):
    """A QA sweep: `-o y.aedat3` said "AEDAT 3.1 ... cannot be written" with exit 1 and no file named (an unknown
    extension is a usage error naming it), and a crop outside the sensor named no input (with several, which?)."""
    samples = Path(__file__).resolve().parents[1] / "samples"
    done = run("convert", samples / "step.aedat4", "-o", tmp_path / "y.aedat3", check=False)
    assert done.returncode == 2 and f"{tmp_path / 'y.aedat3'}: AEDAT 3.1" in done.stderr.decode()
    assert "is read, not written" in done.stderr.decode() and not (tmp_path / "y.aedat3").exists()
    for command in ("convert", "bafilter"):
        done = run(command, samples / "step.aedat4", "--crop", "300,230,21,10", "-o", tmp_path / "c.aedat4",
                   check=False)
        assert_clean_error(done, "step.aedat4: crop 300,230,21,10 is not inside the 32x24 sensor")
