"""The Python API (evtools.api): its examples run, its conversions are exact, and it is the command line's
processors - the same bytes as the CLI pipeline on a real recording."""

from __future__ import annotations

import doctest
import importlib.util
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import evtools
import evtools.api
from tests.conftest import ROOT, data_file
from tests.helpers import run


def test_every_example_runs():
    failures, tried = doctest.testmod(evtools.api, optionflags=doctest.ELLIPSIS)
    assert failures == 0 and tried >= 40


def test_the_api_is_at_the_top_level():
    for name in ("read", "open", "write", "writer", "bafilter", "estimate", "correct", "simulate", "inject_noise",
                 "to_columns", "from_columns", "to_tonic", "from_tonic", "to_dv", "from_dv"):
        assert callable(getattr(evtools, name)) and getattr(evtools, name).__doc__, name
    from evtools import correction, estimation, filters, simulation  # submodules do not shadow the functions

    assert estimation.ThresholdEstimator and correction.ThresholdCorrector and filters.BAFilter
    assert simulation.DvsSimulator and callable(evtools.estimate) and callable(evtools.simulate)


events_strategy = st.integers(0, 300).flatmap(lambda n: st.tuples(
    st.lists(st.integers(0, 50), min_size=n, max_size=n), st.lists(st.integers(0, 319), min_size=n, max_size=n),
    st.lists(st.integers(0, 239), min_size=n, max_size=n), st.lists(st.booleans(), min_size=n, max_size=n)))


def _events(columns):
    steps, x, y, p = columns
    return evtools.from_columns(np.cumsum(np.asarray(steps, dtype=np.int64)), x, y, p)  # many equal times


@settings(max_examples=25, deadline=None)
@given(columns=events_strategy)
def test_tonic_and_column_round_trips_are_exact(columns):
    events = _events(columns)
    assert np.array_equal(evtools.from_tonic(evtools.to_tonic(events)), events)
    assert np.array_equal(evtools.from_columns(*evtools.to_columns(events)), events)


@settings(max_examples=8, deadline=None)
@given(columns=events_strategy, t0_us=st.sampled_from([0, -5, -2**40, 2**50]))
def test_dv_processing_round_trip_is_exact(columns, t0_us):
    """Times before 0 included: an empty EventStore refuses them, so to_dv failed with dv-processing's "Tried
    adding event store to store out of order" (a QA sweep's finding)."""
    events = _events(columns)
    events["t"] += t0_us
    store = evtools.to_dv(events, evtools.StreamInfo(320, 240))
    assert len(store) == len(events)
    assert np.array_equal(evtools.from_dv(store), events)


@pytest.mark.parametrize("store", [None, [1, 2], np.zeros(3), np.zeros(2, [("t", int)])])
def test_from_dv_says_what_it_takes(store):
    with pytest.raises(evtools.EvtoolsError, match=r"from_dv takes a dv-processing EventStore .*, got "
                                                   + type(store).__name__):
        evtools.from_dv(store)


def test_api_pipeline_gives_the_cli_pipeline_bytes(tmp_path):
    """samples/api_pipeline.py (read, bafilter, estimate natural, correct) against the three commands."""
    recording = data_file("dvs128_walk.aedat")
    spec = importlib.util.spec_from_file_location("api_pipeline", ROOT / "samples" / "api_pipeline.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    summary = module.pipeline(str(recording), str(tmp_path / "api"))
    assert summary["valid_pixels"] > 1000 and summary["kept"] < summary["events"]
    cli = tmp_path / "cli"
    cli.mkdir()
    run("bafilter", recording, "-o", cli / "filtered.aedat4")
    run("estimate", cli / "filtered.aedat4", "--method", "natural", "-o", cli / "thresholds.h5")
    run("correct", cli / "filtered.aedat4", "--thresholds", cli / "thresholds.h5", "-o", cli / "corrected.aedat4")
    for name in ("filtered.aedat4", "corrected.aedat4"):
        assert (tmp_path / "api" / name).read_bytes() == (cli / name).read_bytes(), name


def test_correct_takes_an_online_series_and_a_file(tmp_path):
    events, truth = evtools.simulate("flicker", size=(8, 6), duration_us=3_000_000, seed=4, leak_rate_hz=0)
    info = evtools.StreamInfo(8, 6)
    online = evtools.estimate(events, info, method="stimulus", interval_us=1_000_000)
    assert online.series is not None and len(online.series.t_us) == 3
    from evtools.correction import correct_thresholds

    direct = correct_thresholds(events, 8, 6, online.series.on, online.series.off, online.series.valid,
                                t_us=online.series.t_us, target=0.2)
    assert np.array_equal(evtools.correct(events, info, online), direct)
    with pytest.raises(evtools.EvtoolsError):
        evtools.simulate([(0, np.zeros((2, 2)))], scene={"period_s": 1})
    assert os.path.exists(ROOT / "samples" / "api_pipeline.py")


def _doors(folder):
    """Every door of the API that takes events, as ``door(events, info)``."""
    maps = {"on": np.full((240, 320), 0.3, np.float32), "off": np.full((240, 320), 0.25, np.float32)}
    return {
        "bafilter": lambda events, info: evtools.bafilter(events, info),
        "stcf": lambda events, info: evtools.bafilter(events, info, method="stcf", k=1),
        "estimate": lambda events, info: evtools.estimate(events, info, method="natural", min_events=1).on,
        "correct": lambda events, info: evtools.correct(events, info, maps, target=0.2),
        "inject_noise": lambda events, info: evtools.inject_noise(events, info, shot_noise_rate_hz=50, seed=1)[0],
        "write": lambda events, info: evtools.write(folder / "out.aedat4", events, info),
    }


def _outcome(door, events, info):
    """What ``door`` gives: its result, or its error's type and message."""
    try:
        return door(events, info)
    except evtools.EvtoolsError as error:
        return type(error), str(error)


@settings(max_examples=40, deadline=None)
@given(columns=events_strategy.filter(lambda c: len(c[0]) >= 1), where=st.integers(0, 10**6),
       fault=st.sampled_from(["x beyond", "x negative", "y beyond", "y negative", "time backwards"]),
       door=st.sampled_from(["bafilter", "stcf", "estimate", "correct", "inject_noise", "write"]))
def test_bad_events_raise_a_clear_error_at_every_door(tmp_path_factory, columns, where, fault, door):
    """An event off the sensor or earlier than the one before it is refused at every door with the event's index,
    before any kernel sees it: the kernels index per-pixel state by the coordinates (an event at y = -3 once
    crashed the process in bafilter and correct, one at x = 5000 was read and written outside the state)."""
    events = _events(columns)
    i = where % len(events)
    if fault == "time backwards":
        if i == 0:
            i = len(events)
            events = np.concatenate([events, events[-1:]])
        events["t"][i] = events["t"][i - 1] - 1
    else:
        axis, sign = fault.split()
        events[axis][i] = {"x": 320, "y": 240}[axis] + where % 5000 if sign == "beyond" else -1 - where % 5000
    folder = tmp_path_factory.mktemp("door")
    with pytest.raises(evtools.InvalidEventsError, match=rf"^events: (time goes backwards at )?event {i}\b"):
        _doors(folder)[door](events, evtools.StreamInfo(320, 240))
    assert not (folder / "out.aedat4").exists()


@settings(max_examples=15, deadline=None)
@given(columns=events_strategy, minus_one=st.booleans())
def test_a_tonic_array_is_taken_as_its_events(tmp_path_factory, columns, minus_one):
    """tonic's layout (x, y, t, p as int64, p 0/1 or -1/+1) is converted by field name at every door: the same
    result as its events (numpy's own cast between structured types goes by position: x became t)."""
    events = _events(columns)
    tonic = evtools.to_tonic(events)
    if minus_one:
        tonic["p"] = np.where(events["p"], 1, -1)
    info = evtools.StreamInfo(320, 240)
    for name, door in _doors(tmp_path_factory.mktemp("tonic")).items():
        expected, got = _outcome(door, events, info), _outcome(door, tonic, info)
        if name == "write":
            continue
        if isinstance(expected, tuple):
            assert got == expected, name
        else:
            assert np.array_equal(got, expected, equal_nan=expected.dtype.kind == "f"), name


def test_arrays_that_do_not_convert_exactly_are_refused():
    from evtools.events import as_chunk

    array = np.zeros(2, dtype=[("t", float), ("x", int), ("y", int), ("p", int)])
    array["t"] = [1.0, 2.0]
    assert as_chunk(array)["t"].tolist() == [1, 2]  # whole microseconds as floats: taken
    array["t"][1] = 2.5
    with pytest.raises(evtools.InvalidEventsError, match=r"field t \(float64\) holds a value that is not a whole"):
        as_chunk(array)
    array["t"][1] = 2.0
    array["x"][0] = 1 << 16  # would wrap to 0
    with pytest.raises(evtools.InvalidEventsError, match=r"field x \(int64\) holds a value that is not an int16"):
        as_chunk(array)
    no_polarity = np.zeros(1, dtype=[("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("label", "?")])
    with pytest.raises(evtools.InvalidEventsError, match="from_columns, from_tonic and from_dv convert"):
        evtools.bafilter(no_polarity, evtools.StreamInfo(4, 4))
    with pytest.raises(evtools.EvtoolsError, match="this one lacks p"):
        evtools.from_tonic(no_polarity)


@pytest.mark.parametrize("polarity", [0.5, 2, np.nan, 255, -3])
def test_an_array_whose_polarity_is_not_a_polarity_is_refused(polarity):
    """A structured array passed straight to a processor is held to from_columns' rule: before, p = 0.5, 2, 255 or
    NaN was silently taken as ON (``p > 0``) and filtered as if real (a QA sweep's finding)."""
    array = np.zeros(3, dtype=[("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "<f4" if polarity != 255 else "u1")])
    array["t"] = array["x"] = [0, 1, 2]
    array["p"] = [0, 1, polarity]
    with pytest.raises(evtools.InvalidEventsError, match=r"field p holds .*; a polarity is a bool, 0/1 or -1/\+1"):
        evtools.bafilter(array, evtools.StreamInfo(4, 4), method="refractory")
    array["p"][2] = 0
    assert evtools.bafilter(array, evtools.StreamInfo(4, 4), method="refractory")["p"].tolist() == [False, True, False]


def test_the_peers_arrays_are_taken_as_their_events(tmp_path):
    """faery's arrays (and aedat's, and tonic's read_aedat4: the same dtype) call the polarity ``on`` with the
    title ``p``, times uint64: taken at every door as the events they hold (refused before)."""
    import faery

    from tests.conftest import data_file

    path = data_file("dvxplorer_sample.aedat4")
    events, info = evtools.read(path)
    array = faery.events_stream_from_file(path).to_array()
    assert array.dtype.names == ("t", "x", "y", "on") and array.dtype.fields["p"][2] == "p"
    assert np.array_equal(evtools.from_tonic(array), events)
    untitled = np.zeros(len(events), [("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("on", "?")])
    for name in ("t", "x", "y", "on"):
        untitled[name] = array[name]
    for door in _doors(tmp_path).values():
        expected = _outcome(door, events, info)
        for peer in (array, untitled):
            got = _outcome(door, peer, info)
            if isinstance(expected, tuple) or expected is None:  # (an error, or the write door's None)
                assert got == expected
            else:
                assert np.array_equal(got, expected, equal_nan=expected.dtype.kind == "f")


@pytest.mark.parametrize("columns, message", [
    (([1.5, 2], [1, 2], [1, 2], [1, 0]), r"field t \(float64\) holds a value that is not a whole number"),
    ((np.array([2**63 + 5], np.uint64), [1], [1], [1]), r"field t \(uint64\) holds a value that is not a whole"),
    (([1], [1], [1], [2]), r"p holds 2; a polarity is a bool, 0/1 or -1/\+1"),
    (([1], [1], [1], [0.5]), r"p holds 0.5"),
    (([1], [1.5], [1], [1]), r"field x \(float64\) holds a value that is not an int16 coordinate"),
    (([1], [70000], [1], [1]), r"field x \(int64\) holds a value that is not an int16 coordinate"),
    (([1, 2], [1], [1], [1]), r"four 1-D columns of one length are needed, got shapes t \(2,\), x \(1,\)"),
    (([1], [1], [1], ["a"]), r"p holds <U1 values, not numbers"),
])
def test_columns_the_events_cannot_hold_are_refused_not_rounded(columns, message):
    """from_columns (and from_tonic, through it) refuse what would change: before, 1.5 us became 1, p = 2 or 0.5
    became ON, 2^63 + 5 wrapped negative, and a coordinate of 70,000 or columns of two lengths raised numpy's own
    errors."""
    with pytest.raises(evtools.InvalidEventsError, match=message):
        evtools.from_columns(*columns)
    assert evtools.from_columns([0, 2.0], [5, 6], [1, 1], [True, False])["t"].tolist() == [0, 2]


@pytest.mark.parametrize("extension", [".aedat4", ".aedat", ".h5", ".raw", ".csv", ".txt"])
def test_a_stream_read_a_second_time_says_so(tmp_path, extension):
    """Found by a QA sweep: iterating an opened stream again read on from where the first pass ended and reported the
    file damaged ("time goes backwards", "truncated record") or gave nothing."""
    path = tmp_path / f"events{extension}"
    events = evtools.from_columns([0, 1, 2], [1, 2, 3], [1, 1, 1], [1, 0, 1])
    evtools.write(path, events, evtools.StreamInfo(8, 8))
    with evtools.open(path) as stream:
        assert sum(len(chunk) for chunk in stream) == 3
        with pytest.raises(evtools.EvtoolsError, match=rf"{path.name}: this stream has been read already; .* open "
                                                       "it again"):
            iter(stream)
    with evtools.open(path) as stream:
        assert len(stream.read_all()) == 3
        with pytest.raises(evtools.EvtoolsError, match="read already"):
            stream.read_all()


def test_the_doors_say_what_info_and_thresholds_must_be():
    events = evtools.from_columns([0, 1], [1, 2], [1, 2], [1, 0])
    for door in (lambda info: evtools.bafilter(events, info), lambda info: evtools.estimate(events, info),
                 lambda info: evtools.inject_noise(events, info),
                 lambda info: evtools.write("/tmp/x.aedat4", events, info)):
        with pytest.raises(evtools.EvtoolsError, match=r"info must be an evtools.StreamInfo or a sensor size.*8x"):
            door("8x")
        with pytest.raises(evtools.EvtoolsError, match=r"info must be an evtools.StreamInfo or a sensor size"):
            door(None)
    with pytest.raises(evtools.EvtoolsError, match=r"thresholds must be an estimate .* got float \(a target"):
        evtools.correct(events, evtools.StreamInfo(8, 6), 0.2)
    with pytest.raises(evtools.InvalidEventsError, match=r"sensor width 8.5 is not a whole number of pixels"):
        evtools.StreamInfo(8.5, 5)


def test_a_sensor_size_is_taken_as_a_pair_or_as_the_command_lines_text(tmp_path):
    """Issue 39: evtools.read(path, sensor_size="32x24") printed a logging traceback and raised 'too many values to
    unpack'; the API takes (W, H) and "WxH", and anything else is one clear error."""
    path = tmp_path / "e.csv"
    evtools.write(path, evtools.from_columns([1, 2], [0, 31], [0, 23], [1, 0]), evtools.StreamInfo(32, 24))
    assert evtools.read(path, sensor_size="40x30")[1].size == (40, 30)
    assert evtools.read(path, sensor_size=(40, 30))[1].size == (40, 30)
    for bad in (32, "32", (1, 2, 3), "axb", (32.5, 24)):
        with pytest.raises(evtools.InvalidEventsError, match="sensor"):
            evtools.read(path, sensor_size=bad)
    events, _ = evtools.simulate("flicker", size=(32, 24), duration_us=1_000_000, seed=0)
    for size in ("32x24", (32, 24), [32, 24], evtools.StreamInfo(32, 24)):  # every door that takes a sensor
        assert np.array_equal(evtools.bafilter(events, size, method="refractory", dt_us=1), events)
        assert evtools.inject_noise(events, size, seed=1)[0].size >= events.size
        assert evtools.estimate(events, size).on.shape == (24, 32)
        evtools.write(tmp_path / "s.aedat4", events, size)
        assert evtools.read(tmp_path / "s.aedat4")[1].size == (32, 24)
        assert evtools.simulate("bars", size=size if not isinstance(size, evtools.StreamInfo) else size.size,
                                duration_us=100_000, seed=0)[1]["on"].shape == (24, 32)


def test_correct_has_one_default_target_everywhere():
    """Issue 40 item 5: the class said 'median', the function and the command line 0.2. One default (0.2, in
    CORRECT_DEFAULTS) for the processor, the function, the API and the command's help."""
    import inspect

    from click.testing import CliRunner

    from evtools.cli.main import cli
    from evtools.correction import CORRECT_DEFAULTS, ThresholdCorrector

    assert CORRECT_DEFAULTS["target"] == 0.2
    assert inspect.signature(ThresholdCorrector).parameters["target"].default == CORRECT_DEFAULTS["target"]
    on = np.full((3, 4), 0.3)
    assert ThresholdCorrector(4, 3, on, on).target_on == pytest.approx(0.2)  # (float32, as the maps)
    events = evtools.from_columns([0, 10, 20], [1, 1, 1], [1, 1, 1], [1, 1, 1])
    assert np.array_equal(evtools.correct(events, (4, 3), {"on": on, "off": on}),
                          evtools.correct(events, (4, 3), {"on": on, "off": on}, target=0.2))
    assert "[default: 0.2]" in CliRunner().invoke(cli, ["correct", "--help"]).output


def test_simulate_takes_a_video_or_an_image_folder_from_python(tmp_path):
    """Issue 40 item 4: video and image-folder sources live in formats/ (formats/video.py), so
    evtools.simulate("clip.mp4") works from Python as `evtools simulate clip.mp4` does: the same events."""
    import cv2

    from tests.helpers import run

    folder = tmp_path / "frames"
    folder.mkdir()
    for i, level in enumerate((40, 90, 160, 220)):
        cv2.imwrite(str(folder / f"{i}.png"), np.full((12, 16), level, np.uint8))
    events, truth = evtools.simulate(folder, frame_rate=50, seed=3, leak_rate_hz=0)
    run("simulate", folder, "--frame-rate", 50, "--seed", 3, "--leak-rate-hz", 0, "-o", tmp_path / "cli.aedat4")
    cli_events, info = evtools.read(tmp_path / "cli.aedat4")
    assert info.size == (16, 12) and len(events) > 100 and np.array_equal(events, cli_events)
    assert truth["on"].shape == (12, 16)
    resized, _ = evtools.simulate(str(folder), frame_rate=50, size="8x6", seed=3)
    assert resized["x"].max() < 8 and resized["y"].max() < 6
    with pytest.raises(evtools.EvtoolsError, match="no such file or folder"):
        evtools.simulate(tmp_path / "missing.mp4")
    with pytest.raises(evtools.EvtoolsError, match="no timestamps.txt; give --timestamps FILE or --frame-rate"):
        evtools.simulate(folder)  # no timestamps.txt and no frame rate


def test_reading_options_are_one_object_from_python_and_the_command_line(tmp_path):
    """Issue 40 item 2: how to read an input is one ReadOptions, built once by the command line's input options
    (the global --max-latency and --timeout in it, no module global) and the same object from Python; its fields
    may also be given as keywords, and a name that is none of them is refused."""
    import dataclasses

    import click
    from click.testing import CliRunner

    from evtools.cli.options import input_options

    path = tmp_path / "e.csv"
    evtools.write(path, evtools.from_columns([1, 2], [0, 1], [0, 0], [1, 0]), evtools.StreamInfo(2, 1))
    options = evtools.ReadOptions(sensor_size=(5, 4), chunk_events=1)
    events, info = evtools.read(path, options=options)
    assert (info.width, info.height) == (5, 4) and len(events) == 2
    assert evtools.read(path, options=options, sensor_size="3x2")[1].size == (3, 2)  # a keyword replaces a field
    with pytest.raises(TypeError, match="aedat2layout"):
        evtools.read(path, aedat2layout="dvs128")
    seen = []

    @click.command()
    @input_options
    def probe(reading):
        seen.append(reading)

    from evtools.cli.main import GLOBAL_OPTIONS

    for make in GLOBAL_OPTIONS:
        probe.params.append(make())
    result = CliRunner().invoke(probe, ["--sensor-size", "7x3", "--max-latency", "5ms", "--timeout", "2s",
                                        "--input-format", "csv"])
    assert result.exit_code == 0, result.output
    assert dataclasses.asdict(seen[0]) == dataclasses.asdict(evtools.ReadOptions(
        format="csv", sensor_size=(7, 3), max_latency_s=0.005, connect_timeout_s=2.0, read_timeout_s=2.0))
    import evtools.formats.io as io_module

    assert not [name for name in vars(io_module) if name.isupper() and name.endswith(("_S", "_TIMEOUT"))]


def test_the_api_signatures_say_what_they_take():
    """Issue 40 item 5: help() and tab completion list each function's keywords, from the processor that declares
    them (no second list to drift); a name that is none of them is refused."""
    import inspect

    from evtools.correction import ThresholdCorrector
    from evtools.estimation import ThresholdEstimator
    from evtools.noise import NoiseInjector
    from evtools.simulation import DvsSimulator

    for function, target, internal in ((evtools.estimate, ThresholdEstimator, {"check"}),
                                       (evtools.correct, ThresholdCorrector, {"check", "t_us", "stale", "start_us"}),
                                       (evtools.simulate, DvsSimulator, set()),
                                       (evtools.inject_noise, NoiseInjector, set())):
        declared = {name for name, p in inspect.signature(target).parameters.items()
                    if p.kind is inspect.Parameter.KEYWORD_ONLY} - internal
        shown = inspect.signature(function).parameters
        assert declared <= set(shown), (function.__name__, declared - set(shown))
        assert all(shown[name].default == inspect.signature(target).parameters[name].default for name in declared)
        assert not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in shown.values())
    events = evtools.from_columns([0, 10], [0, 1], [0, 0], [1, 0])
    with pytest.raises(TypeError, match="nominl"):
        evtools.estimate(events, (2, 1), nominl=0.2)
    with pytest.raises(TypeError, match="sigma_thre"):
        evtools.simulate("flicker", size=(4, 3), duration_us=100_000, sigma_thre=0.1)


def test_every_method_and_mode_the_api_documents_exists():
    """Issue 40 item 6 (the docstring once offered ynoise and knoise, which did not exist): the choices listed in the
    API's docstrings are the ones the processors take, no more and no fewer."""
    import re

    from evtools.correction import MODES
    from evtools.estimation import METHODS as ESTIMATE_METHODS

    listed = set(re.findall(r'"(\w+)"', evtools.estimate.__doc__.split("method : ")[1].splitlines()[0]))
    assert listed == set(ESTIMATE_METHODS)
    modes = evtools.correct.__doc__.split("``mode`` (")[1].split(")")[0]
    assert set(re.findall(r"\w+", modes)) == set(MODES)
