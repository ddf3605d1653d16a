"""Exit codes across the whole command line (issue 18 item 5): every option of every command, given a value of the
wrong kind, is a usage error (exit 2, a message naming the option, no traceback, nothing written); an unknown
option is one too; a missing input is a data error (exit 1, one line naming the file); --help exits 0 with -q and
-v listed. The options are found by walking click's parameters, so a new option is swept without a new test."""

from __future__ import annotations

import math
import signal
import subprocess
import sys
from pathlib import Path

import click
import numpy as np
import pytest
from click.testing import CliRunner

from evtools.cli.main import COMMANDS, cli
from evtools.cli.metrics import metrics
from evtools.cli.options import Duration, Microseconds, TimeBound
from evtools.formats.thresholds import ThresholdMap, write_thresholds
from tests.conftest import data_file
from tests.helpers import assert_clean_error, read_all, run

SAMPLES = Path(__file__).resolve().parents[1] / "samples"
STEP, TRUTH = SAMPLES / "step.aedat4", SAMPLES / "step.truth.h5"

BASES = {
    "info": [str(STEP)],
    "convert": [str(STEP), "-o", "{out}.aedat4"],
    "simulate": ["scene:bars", "--size", "8x6", "--duration", "10ms", "-o", "{out}.aedat4"],
    "render": [str(STEP), "-o", "{out}.png"],
    "bafilter": [str(STEP), "-o", "{out}.aedat4"],
    "estimate": [str(STEP), "-o", "{out}.h5"],
    "correct": [str(STEP), "--thresholds", str(TRUTH), "-o", "{out}.aedat4"],
    "metrics denoise": [str(STEP), "--truth", str(TRUTH), "--input", str(STEP)],
    "metrics roc": [str(STEP), "--truth", str(TRUTH), "-m", "baf", "--sweep", "dt-us=1000,2000"],
    "metrics esr": [str(STEP)],
    "metrics thresholds": [str(TRUTH), "--truth", str(TRUTH)],
    "metrics reconstruction": [str(STEP), "--truth", str(TRUTH)],
    "metrics train-denoiser": [str(STEP), "--truth", str(TRUTH), "-o", "{out}.npz"],
    "metrics uniformity": [str(STEP)],
}
"""A valid invocation of each command (files from samples/), to which one bad option is added."""


def _commands() -> dict[str, click.Command]:
    found = {}
    for name in COMMANDS:
        command = cli.get_command(click.Context(cli), name)
        if name == "metrics":
            for sub in metrics.lazy_commands:
                found[f"metrics {sub}"] = metrics.get_command(click.Context(metrics), sub)
        else:
            found[name] = command
    return found


def _bad_value(option: click.Option) -> list[str] | None:
    """A value of the wrong kind for ``option`` (as command-line words), or None when any text is a value."""
    kind = option.type
    if isinstance(kind, click.Choice):
        bad = "nope"
    elif isinstance(kind, (click.types.IntParamType, click.types.FloatParamType)):
        bad = "abc"
    elif isinstance(kind, (TimeBound, Duration)):
        bad = "soon"
    elif isinstance(kind, click.Path) and kind.exists:
        bad = "/nonexistent/evtools-test"
    elif isinstance(kind, click.Tuple):
        return ["abc"] * option.nargs
    else:
        return None
    return [bad] * max(option.nargs, 1)


def _cases():
    cases = []
    for name, command in _commands().items():
        for option in command.params:
            if isinstance(option, click.Option) and not option.is_flag and option.opts[0] not in ("--help",):
                words = _bad_value(option)
                if words is not None:
                    cases.append(pytest.param(name, option.opts[-1], words, id=f"{name} {option.opts[-1]}"))
    return cases


def test_every_command_has_a_valid_base_invocation():
    assert set(BASES) == set(_commands())
    assert len(_cases()) >= 60  # the sweep covers the command line, not a handful of options


@pytest.mark.parametrize("name,option,words", _cases())
def test_a_value_of_the_wrong_kind_is_a_usage_error(tmp_path, name, option, words):
    base = [part.format(out=tmp_path / "out") for part in BASES[name]]
    result = CliRunner().invoke(cli, [*name.split(), *base, option, *words])
    assert result.exit_code == 2, (result.exit_code, result.stderr)
    assert option in result.stderr or option.lstrip("-") in result.stderr, result.stderr
    assert "Traceback" not in result.stderr and result.exception is None or isinstance(result.exception, SystemExit)
    assert not list(tmp_path.iterdir())  # nothing written


@pytest.mark.parametrize("name", sorted(BASES))
def test_unknown_options_missing_inputs_and_help(tmp_path, name):
    runner = CliRunner()
    base = [part.format(out=tmp_path / "out") for part in BASES[name]]
    unknown = runner.invoke(cli, [*name.split(), *base, "--no-such-option"])
    assert unknown.exit_code == 2 and "No such option" in unknown.stderr
    missing = [str(tmp_path / "missing.aedat4") if part in (str(STEP),) else part for part in base]
    if name == "simulate":  # (scene options with a file are a usage error: --duration applies to scenes only)
        assert runner.invoke(cli, ["simulate", str(STEP), "--duration", "1s", "-o", base[-1]]).exit_code == 2
        missing = [str(tmp_path / "missing.aedat4"), "-o", base[-1]]
    if name == "metrics thresholds":
        missing[0] = str(tmp_path / "missing.h5")
    data = runner.invoke(cli, [*name.split(), *missing])
    assert data.exit_code in (1, 2), data.stderr  # 2: click's own check of a path that must exist
    lines = data.stderr.strip().splitlines()
    assert "missing." in data.stderr and "Traceback" not in data.stderr
    if data.exit_code == 1:
        assert len(lines) == 1 and lines[0].startswith("evtools: error: ")
    assert not [p for p in tmp_path.iterdir()]  # nothing written
    text = runner.invoke(cli, [*name.split(), "--help"])
    assert text.exit_code == 0 and "-q, --quiet" in text.output and "-v, --verbose" in text.output


@pytest.mark.parametrize("args, option", [
    (["bafilter", "{S}", "-m", "baf", "--dt-us", "99999999999999999999", "-o", "{T}/o.aedat4"], "--dt-us"),
    (["bafilter", "{S}", "-m", "baf", "--dt-us", "9223372036854775807", "-o", "{T}/o.aedat4"], "--dt-us"),
    (["bafilter", "{S}", "-m", "dwf", "--distance", "99999999999999999999", "-o", "{T}/o.aedat4"], "--distance"),
    (["estimate", "{S}", "--segment-us", "99999999999999999999", "-o", "{T}/e.h5"], "--segment-us"),
    (["estimate", "{S}", "--method", "natural", "--radius", "99999999999999999999", "-o", "{T}/e.h5"], "--radius"),
    (["simulate", "scene:bars", "--size", "8x8", "--refractory-us", "99999999999999999999", "-o", "{T}/s.aedat4"],
     "--refractory-us"),
    (["simulate", "scene:bars", "--size", "8x8", "--duration", "1e20s", "-o", "{T}/s.aedat4"], "--duration"),
    (["simulate", "scene:bars", "--size", "8x8", "--speed", "nan", "-o", "{T}/s.aedat4"], "--speed"),
    (["render", "{S}", "-o", "{T}/v.mp4", "--frame-rate", "nan"], "--frame-rate"),
    (["render", "{S}", "-o", "{T}/v.mp4", "--fps", "nan"], "--fps"),
    (["convert", "{S}", "-o", "{T}/c.aedat4", "--realtime", "--speed", "1e-300"], "--speed"),
    (["simulate", "scene:bars", "--size", "8x8", "--frame-rate", "0", "-o", "{T}/s.aedat4"], "--frame-rate"),
    (["simulate", "scene:bars", "--size", "8x8", "--frame-rate", "1e9", "-o", "{T}/s.aedat4"], "--frame-rate"),
    # (each of these exited 1 as bad data, the last two naming the wrong option or none: a sweep of 0 and -1 over
    # every numeric option)
    (["simulate", "scene:bars", "--size", "8x8", "--fps", "0", "-o", "{T}/s.aedat4"], "--fps"),
    (["simulate", "scene:bars", "--size", "8x8", "--bar-width", "0", "-o", "{T}/s.aedat4"], "--bar-width"),
    (["simulate", "scene:bars", "--size", "8x8", "--min-level", "-1", "-o", "{T}/s.aedat4"], "--min-level"),
    (["simulate", "scene:static", "--size", "8x8", "--level", "-1", "-o", "{T}/s.aedat4"], "--level"),
    (["metrics", "reconstruction", str(STEP), "--truth", str(TRUTH), "--contrast", "0"], "--contrast"),
    (["metrics", "reconstruction", str(STEP), "--truth", str(TRUTH), "--cutoff-hz", "-1"], "--cutoff-hz"),
    (["metrics", "train-denoiser", str(STEP), "--truth", str(TRUTH), "--seed", "-1", "-o", "{T}/w.npz"], "--seed"),
])
def test_values_beyond_what_the_kernels_hold_are_usage_errors(tmp_path, args, option):
    """A number beyond int64 reached the numba kernels (a traceback), 2^63 - 1 us overflowed a window (every event
    kept), nan passed click's ranges: each is now a usage error naming the option, and nothing is written."""
    sample = data_file("dvxplorer_sample.aedat4")
    result = run(*[a.replace("{S}", str(sample)).replace("{T}", str(tmp_path)) for a in args], check=False)
    assert result.returncode == 2, result.stderr
    assert f"Invalid value for '{option}'" in result.stderr.decode() and b"Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args, words", [
    (["bafilter", "{S}", "-m", "stcf", "--k", "100", "-o", "{T}/o.aedat4"], "k must be a whole number in 1..8"),
    (["bafilter", "{S}", "-m", "stcf", "--radius", "2", "--k", "25", "-o", "{T}/o.aedat4"], "in 1..24"),
    (["render", "--map", "{M}", "--range", "0.3", "0.1", "-o", "{T}/r.png"], "LOW must be below HIGH"),
    (["estimate", "{S}", "--method", "stimulus", "--stimulus-speed", "50", "--stimulus-wavelength", "64",
      "--stimulus-phase", "given", "--crop", "2,0,30,48", "-o", "{T}/t.h5"], "use --stimulus-phase fit"),
    (["estimate", "{S}", "--method", "stimulus", "--stimulus-profile", "log", "--stimulus-levels", "50,200", "-o",
      "{T}/t.h5"], "did you mean --stimulus-amplitude 1.386"),
    # (exited 1 as bad data, where render said 2: a QA sweep)
    (["convert", "{S}", "-o", "{T}/c.aedat4", "--start", "50ms", "--end", "50ms"], "is not after the start"),
    (["bafilter", "{S}", "-o", "{T}/b.aedat4", "--start", "@2s", "--end", "@1s"], "is not after the start"),
    (["convert", "{S}", "-o", "{T}/c.aedat4", "--crop", "0,0,0,10"], "W and height H must be at least 1"),
])
def test_option_values_out_of_their_range_exit_2(tmp_path, args, words):
    """Values out of range that the filters or the renderer checked once the run began exited 1, as for bad data
    (a QA sweep): each is a usage error (exit 2, one line), and nothing is written."""
    sample = data_file("dvxplorer_sample.aedat4")
    maps = tmp_path.parent / f"{tmp_path.name}-maps.h5"
    write_thresholds(str(maps), ThresholdMap(np.full((4, 4), 0.2, np.float32), np.full((4, 4), 0.2, np.float32),
                                             np.ones((4, 4), bool), {"method": "natural"}))
    result = run(*[a.replace("{S}", str(sample)).replace("{T}", str(tmp_path)).replace("{M}", str(maps))
                   for a in args], check=False)
    stderr = result.stderr.decode()
    assert result.returncode == 2 and stderr.count("\n") == 1 and words in stderr, stderr
    assert list(tmp_path.iterdir()) == []


def test_a_radius_wider_than_the_sensor_is_the_sensor():
    """(was "out of memory": a box-sum buffer of the radius's size) the same map as a radius of the sensor's side.
    (Unchecked, --max-fit inf: against the whole sensor's mean every pixel's scene error is large.)"""
    import evtools

    events, info = evtools.read(data_file("dvxplorer_sample.aedat4"))
    wide = evtools.estimate(events, info, method="natural", radius_px=100_000, min_events=1, max_fit=math.inf)
    side = evtools.estimate(events, info, method="natural", radius_px=320, min_events=1, max_fit=math.inf)
    assert np.array_equal(wide.on, side.on, equal_nan=True) and wide.valid.any()


@pytest.mark.parametrize("args, message", [
    (["-m", "baf", "--k", "3"], "--k do(es) not apply to --method baf (--preset evtools)"),
    (["-m", "stcf", "--window", "9", "--learn-us", "5"], "--window, --learn-us do(es) not apply to --method stcf"),
    (["--preset", "dv", "-m", "orderN"], "--preset dv has no method orderN (it has baf)"),
    (["-m", "hotpixel", "--hot-pixels", str(STEP), "--learn-us", "5000"],  # (learned nothing, silently)
     "--learn-us: nothing is learned with --hot-pixels FILE"),
])
def test_filter_options_no_chosen_method_uses_are_usage_errors(tmp_path, args, message):
    """(`-m baf --k 3` ran baf as if --k were not given; a preset without the method was a data error)"""
    result = run("bafilter", data_file("dvxplorer_sample.aedat4"), *args, "-o", tmp_path / "o.aedat4", check=False)
    assert result.returncode == 2 and message in result.stderr.decode()
    assert list(tmp_path.iterdir()) == []


def test_a_picture_too_large_and_a_full_device_are_named(tmp_path):
    from tests.helpers import assert_clean_error

    gen4 = data_file("gen41_sample.evt3.raw")
    assert_clean_error(run("render", gen4, "-o", tmp_path / "g.png", "--scale", "64", check=False), "g.png",
                       "a 1280x720 picture at scale 64 would be 81920x46080 pixels (10.5 GB): give a smaller --scale")
    assert list(tmp_path.iterdir()) == []
    assert_clean_error(run("convert", data_file("dvxplorer_sample.aedat4"), "-o", "/dev/full", check=False),
                       "/dev/full: cannot write (No space left on device)")


def test_a_report_on_a_full_stdout_names_it(tmp_path):
    """A command's JSON report to a full device said "No space left on device" alone (a QA sweep): it names
    stdout now, exit 1."""
    stream = data_file("dvxplorer_sample.aedat4")
    with open("/dev/full", "wb") as full:
        for args in (["info", stream], ["metrics", "uniformity", stream]):
            result = subprocess.run([str(Path(sys.executable).parent / "evtools"), "-q", *map(str, args)],
                                    stdout=full, stderr=subprocess.PIPE, timeout=300)
            stderr = result.stderr.decode()
            assert result.returncode == 1 and "Traceback" not in stderr, stderr
            assert stderr == "evtools: error: <stdout>: cannot write (No space left on device)\n", stderr


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_while_the_command_line_is_imported_is_one_line(signum):
    """Issue 37 item 7: SIGINT in the first ~0.1 s (imports) printed a KeyboardInterrupt traceback and SIGTERM
    took its default action; the console script now handles both before it imports the command line."""
    code = ("import os, signal, time; from evtools.cli import stop_early; "
            "signal.signal(signal.SIGINT, stop_early); signal.signal(signal.SIGTERM, stop_early); "
            f"os.kill(os.getpid(), {int(signum)}); time.sleep(5)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert done.returncode == 128 + signum and done.stderr == "evtools: interrupted\n"


BAD_FILE = {"metrics thresholds": "{bad}.h5"}
"""The input of each command that a damaged file replaces (the first input; a thresholds map for ``metrics
thresholds``)."""


@pytest.mark.parametrize("name", sorted(BASES))
def test_one_grammar_usage_mistakes_exit_2_and_bad_files_exit_1_each_in_one_line(tmp_path, name):
    """Issue 39 item 5, table-driven over every command: an unknown option and a value of the wrong kind are usage
    mistakes (exit 2, one line naming them, nothing written); a damaged input file is a data error (exit 1, one
    line naming the file, nothing written); ``--help`` shows no ``None`` and no raw limits."""
    bad = tmp_path / "bad"
    bad.mkdir()
    damaged = bad / "damaged.aedat4"
    damaged.write_bytes(b"#!AER-DAT4.0\r\n" + bytes(range(256)) * 4)
    (bad / "damaged.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(200))
    out = tmp_path / "out"
    out.mkdir()
    base = [part.format(out=out / "o") for part in BASES[name]]
    for words in (["--no-such-option"], ["--quiet", "--no-such-option"]):
        result = run(*name.split(), *base, *words, check=False)
        stderr = result.stderr.decode()
        assert result.returncode == 2, stderr
        assert stderr.count("\n") == 1 and "--no-such-option" in stderr, stderr
    first = BASES[name][0]
    replaced = str(bad / "damaged.h5") if name in BAD_FILE else str(damaged)
    args = [replaced if part == first else part.format(out=out / "o") for part in BASES[name]]
    if name == "simulate":
        args = [str(damaged), "-o", str(out / "o.aedat4")]
    result = run(*name.split(), *args, check=False)
    stderr = result.stderr.decode()
    assert result.returncode == 1, (result.returncode, stderr)
    assert stderr.count("\n") == 1 and "damaged" in stderr and "Traceback" not in stderr, stderr
    assert not list(out.iterdir())
    text = CliRunner().invoke(cli, [*name.split(), "--help"]).output
    assert "None" not in text and "4611686018427387904" not in text


@pytest.mark.parametrize("args", [
    ["convert", str(STEP), "-o", "{out}/y.xyz"],
    ["bafilter", str(STEP), "-o", "{out}/y.xyz"],
    ["simulate", "scene:bars", "--size", "8x6", "--duration", "10ms", "-o", "{out}/y.xyz"],
    ["render", str(STEP), "-o", "{out}/f.gif"],
    ["simulate", "scene:nope", "-o", "{out}/s.aedat4"],
    ["bafilter", str(STEP), "--method", "foo", "-o", "{out}/b.aedat4"],
    ["metrics", "reconstruction", str(STEP), "--truth", str(TRUTH), "--plot", "{out}/x.xyz"],
    ["bafilter", str(STEP), "-m", "stcf", "--polarity-maps", "--any-polarity", "-o", "{out}/b.aedat4"],  # (was 1)
    ["simulate", "scene:flicker", "--aps-rate", "50", "--aps-exposure", "20ms", "-o", "{out}/s.aedat4"],  # (was 1)
])
def test_the_same_kind_of_mistake_gets_the_same_exit_code(tmp_path, args):
    """Issue 39: an output whose extension names nothing and an unknown scene or method are all usage mistakes
    (`convert -o y.xyz` and `simulate scene:nope` exited 1, `render -o f.gif` and `bafilter --method foo` 2)."""
    result = run(*(a.format(out=tmp_path) for a in args), check=False)
    stderr = result.stderr.decode()
    assert result.returncode == 2, stderr
    assert stderr.startswith("evtools: usage: ") and stderr.count("\n") == 1, stderr
    assert not list(tmp_path.iterdir())


def _time_options() -> list[tuple[str, click.Option]]:
    return [(name, option) for name, command in _commands().items() for option in command.params
            if isinstance(option, click.Option) and isinstance(option.type, Duration)]


def test_every_time_option_takes_a_duration_with_its_unit():
    """Issue 39 item 5: every time option of every command accepts ``10ms``; one named with its unit
    (``--dt-us``) also takes a bare number in that unit; an option whose name ends in ``-us`` is never a plain
    integer, and an option described as a time is never a plain number."""
    options = _time_options()
    assert len(options) >= 15
    for name, command in _commands().items():
        for option in command.params:
            if not isinstance(option, click.Option):
                continue
            if option.opts[0].endswith("-us"):
                assert isinstance(option.type, Microseconds), (name, option.opts)
            if isinstance(option.type, (click.types.IntParamType, click.types.FloatParamType)):
                assert not any(word in (option.help or "") for word in (" us", "microsecond")), (name, option.opts)
    for name, option in options:
        context = click.Context(click.Command(name))
        assert option.type.convert("10ms", option, context) == 10_000, (name, option.opts)
        assert option.type.convert("0.5s", option, context) == 500_000, (name, option.opts)
        bare = "10000"
        if isinstance(option.type, Microseconds):
            assert option.type.convert(bare, option, context) == 10_000, (name, option.opts)
        else:
            with pytest.raises(click.BadParameter, match="has no unit"):
                option.type.convert(bare, option, context)


def test_a_time_with_its_unit_runs_as_the_same_time_in_microseconds(tmp_path):
    """End to end: ``--dt-us 10ms`` filters as ``--dt-us 10000``, ``--edges-at`` takes times with units, and the
    sweep of a ``-us`` parameter takes them too."""
    a, b = tmp_path / "a.aedat4", tmp_path / "b.aedat4"
    run("bafilter", STEP, "--dt-us", "10ms", "-o", a)
    run("bafilter", STEP, "--dt-us", "10000", "-o", b)
    assert a.read_bytes() == b.read_bytes()
    assert run("bafilter", STEP, "--dt-us", "3", "-o", a, "-q").returncode == 0
    assert a.read_bytes() != b.read_bytes()  # (the option is used)
    first = read_first_time_us(STEP)
    relative = run("metrics", "uniformity", STEP, "--edges-at", "0ms,500ms", "--json").stdout
    absolute = run("metrics", "uniformity", STEP, "--edges-at", f"@{first}us,@{first + 500_000}us",
                   "--json").stdout
    assert relative == absolute and b'"edges"' in relative
    sweep = [run("metrics", "roc", STEP, "--truth", TRUTH, "-m", "baf", "--sweep", words, "--json").stdout
             for words in ("dt-us=1ms,3ms", "dt-us=1000,3000")]
    assert sweep[0] == sweep[1]


def read_first_time_us(path) -> int:
    import evtools

    return int(evtools.read(path)[0]["t"][0])


@pytest.mark.parametrize("name", sorted(BASES))
def test_global_options_are_taken_after_the_subcommand_too(tmp_path, name):
    """Issue 39 item 5: ``--max-latency``, ``--timeout``, ``-q`` and ``-v`` anywhere on the line (``--max-latency``
    worked only before the subcommand); a bad value is a usage error naming it, wherever it is."""
    base = [part.format(out=tmp_path / "out") for part in BASES[name]]
    runner = CliRunner()
    for words in (["--max-latency", "5ms"], ["--timeout", "3s"], ["-q"]):
        after = runner.invoke(cli, [*name.split(), *base, *words, "--help"])
        assert after.exit_code == 0, (words, after.stderr)
    for where in ("before", "after"):
        argv = (["--max-latency", "soon", *name.split(), *base] if where == "before"
                else [*name.split(), *base, "--max-latency", "soon"])
        result = runner.invoke(cli, argv)
        assert result.exit_code == 2 and "--max-latency" in result.stderr, (where, result.stderr)
    assert not list(tmp_path.iterdir())


def test_an_option_missing_its_values_points_to_the_subcommands_help(tmp_path):
    """click's parser reports a missing option value without a context: the hint must still name the subcommand
    (it said `see evtools --help`)."""
    done = run("render", tmp_path / "x.aedat4", "-o", tmp_path / "x.png", "--range", "0.1", check=False)
    stderr = done.stderr.decode()
    assert done.returncode == 2 and stderr.count("\n") == 1 and "(see evtools render --help)" in stderr, stderr


def test_a_stop_that_escapes_the_reader_ends_in_one_line(monkeypatch, tmp_path):
    """A stop signal that ends a wait for input (StopReading) past the reader's own handling ends the command as a
    Ctrl-C does: one line, exit 130, no traceback (a QA sweep saw one traceback through the group's invoke in a
    stopped three-stage pipeline, not reproduced since)."""
    import evtools.cli.info as info_module
    from evtools import interrupt

    def stopped(*args, **kwargs):
        raise interrupt.StopReading

    monkeypatch.setattr(info_module, "open_events", stopped)
    result = CliRunner().invoke(cli, ["info", str(tmp_path / "x.aedat4")])
    assert result.exit_code == 130 and result.stderr == "evtools: interrupted\n", (result.exit_code, result.stderr)


def test_a_thresholds_path_that_is_no_file_is_one_line_exit_1(tmp_path):
    """A folder given for a thresholds or truth file was click's usage error (exit 2) where a missing file was a
    data error (exit 1); `-` said "no such file" (a QA sweep). Every such input is now exit 1, named."""
    from tests.helpers import assert_clean_error

    stream = data_file("dvxplorer_sample.aedat4")
    for args, needle in ((["correct", stream, "--thresholds", "-"], "-: a thresholds or truth file is HDF5"),
                         (["correct", stream, "--thresholds", tmp_path], "a folder, not a thresholds file"),
                         (["correct", stream, "--thresholds", tmp_path / "none.h5"], "no such file"),
                         (["metrics", "thresholds", tmp_path, "--truth", tmp_path], "a folder, not a thresholds"),
                         (["metrics", "reconstruction", stream, "--truth", tmp_path], "a folder, not a truth file"),
                         (["render", "--map", tmp_path, "-o", tmp_path / "m.png"], "a folder, not a thresholds")):
        assert_clean_error(run(*args, check=False), needle)
    assert list(tmp_path.iterdir()) == []


def test_a_stream_whose_size_was_inferred_smaller_than_the_map_is_told_how_to_set_it(tmp_path):
    """A CSV stores no sensor size: inferred from its events it is smaller than the thresholds' sensor, and the
    error now names the --sensor-size that makes them match (a QA sweep); given, the correction runs."""
    from tests.helpers import assert_clean_error

    run("simulate", "scene:flicker", "--size", "64x48", "--duration", "1s", "--seed", "1", "--truth",
        tmp_path / "truth.h5", "-o", tmp_path / "f.aedat4")
    _, events = read_all(tmp_path / "f.aedat4")
    part = events[(events["x"] < 40) & (events["y"] < 30)]
    np.savetxt(tmp_path / "f.csv", np.c_[part["t"], part["x"], part["y"], part["p"].astype(int)], fmt="%d",
               delimiter=",")
    result = run("-q", "correct", tmp_path / "f.csv", "--thresholds", tmp_path / "truth.h5", "-o",
                 tmp_path / "c.aedat4", check=False)
    assert_clean_error(result, "thresholds are 64x48 but the stream is 40x30", "give --sensor-size 64x48")
    run("-q", "correct", tmp_path / "f.csv", "--sensor-size", "64x48", "--thresholds", tmp_path / "truth.h5", "-o",
        tmp_path / "c.aedat4")
    assert len(read_all(tmp_path / "c.aedat4")[1]) > 0


def test_a_large_report_to_a_closed_pipe_exits_141(tmp_path):
    """A QA sweep: `metrics esr ... | head -c 100` exited 0 with 535 KB of JSON lost (Python's buffered write
    dropped the rest after the pipe's partial write); a report now goes out whole or the command exits 141."""
    stream = tmp_path / "rec.aedat4"
    run("simulate", "scene:bars", "--size", "32x24", "--duration", "1s", "--seed", "1", "-o", stream)
    whole = run("metrics", "esr", stream, "--slice-events", "2").stdout
    assert len(whole) > 100_000  # (more than a pipe holds: 64 KiB)
    command = f"{Path(sys.executable).parent / 'evtools'} metrics esr {stream} --slice-events 2"
    result = subprocess.run(["bash", "-c", f"{command} | head -c 100 > /dev/null; echo ${{PIPESTATUS[0]}}"],
                            capture_output=True, text=True, timeout=300)
    assert result.stdout.strip() == "141", result


def test_stdin_where_a_file_is_read_twice_says_so(tmp_path):
    """A QA sweep: `metrics train-denoiser -` said "File '-' does not exist". Commands that read their input twice
    (count then match, or sample) say that stdin cannot be, exit 2."""
    stream = tmp_path / "rec.aedat4"
    run("simulate", "scene:bars", "--size", "16x12", "--duration", "100ms", "--seed", "1", "-o", stream)
    for args in (["metrics", "train-denoiser", "-", "-o", tmp_path / "w.npz"],
                 ["metrics", "roc", "-", "--truth", stream, "--method", "stcf", "--sweep", "k=1"],
                 ["metrics", "denoise", stream, "--truth", stream, "--input", "-"]):
        result = subprocess.run([str(Path(sys.executable).parent / "evtools"), *map(str, args)],
                                stdin=open(stream, "rb"), capture_output=True, timeout=120)
        assert result.returncode == 2 and b"cannot be read twice" in result.stderr, result.stderr


def test_a_format_that_contradicts_the_extension_is_said(tmp_path):
    """A QA sweep: `convert --format csv -o y.aedat4` wrote CSV under an AEDAT 4.0 name without a word, and evtools
    then refused to read it back. The write warns; the file is what --format asked for."""
    stream = tmp_path / "rec.aedat4"
    run("simulate", "scene:bars", "--size", "16x12", "--duration", "100ms", "--seed", "1", "-o", stream)
    result = run("convert", stream, "--format", "csv", "-o", tmp_path / "y.aedat4")
    assert "its extension says AEDAT 4.0" in result.stderr.decode()
    assert (tmp_path / "y.aedat4").read_bytes().startswith(b"t,x")  # (CSV's header line)
    quiet = run("convert", stream, "--format", "csv", "-o", tmp_path / "y.csv")
    assert "extension says" not in quiet.stderr.decode()


def test_a_malformed_network_address_is_a_usage_error_and_a_taken_port_is_not():
    """A QA sweep: `convert tcp://127.0.0.1` (no port) was exit 1 while `-o tcp://...` on a port in use was exit 2.
    An address that is not one is a usage error wherever it is given (exit 2); a port another process holds is
    the environment's (exit 1)."""
    import socket

    for args in (["convert", "tcp://127.0.0.1", "-o", "x.aedat4"], ["info", "tcp://127.0.0.1:99999"],
                 ["convert", data_file("dvxplorer_sample.aedat4"), "-o", "tcp://127.0.0.1"]):
        result = run(*args, check=False)
        assert result.returncode == 2 and "not a network address" in result.stderr.decode(), result.stderr
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = run("convert", data_file("dvxplorer_sample.aedat4"), "-o", f"tcp://127.0.0.1:{port}", check=False)
    assert_clean_error(result, "cannot listen")
