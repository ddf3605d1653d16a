"""Labelled noise on a real recording (``evtools simulate EVENTS``): pass-through, rates, chunking, the CLI."""

from __future__ import annotations

import subprocess
from unittest import mock

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import evtools.noise
from evtools.errors import InvalidEventsError
from evtools.events import EVENT_DTYPE, make_events
from evtools.noise import BLOCK_US, NoiseInjector, inject_noise
from evtools.simulation import SimulationError
from tests.conftest import data_file
from tests.helpers import assert_clean_error, assert_same_events, cut, EVTOOLS, read_all, run

WIDTH = HEIGHT = 128
RATES = {"shot_noise_rate_hz": 5.0, "leak_rate_hz": 0.2, "hot_pixel_fraction": 0.002, "hot_pixel_rate_hz": 100.0}


@pytest.fixture(scope="module")
def walk() -> np.ndarray:
    """The 290,292 events of dvs128_walk.aedat (DVS128, 25 s)."""
    return read_all(data_file("dvs128_walk.aedat"))[1]


def run_chunked(injector: NoiseInjector, chunks) -> tuple[np.ndarray, np.ndarray]:
    events, labels = [], []
    for chunk in chunks:
        chunk_events, chunk_labels = injector.process(chunk)
        events.append(chunk_events)
        labels.append(chunk_labels)
    chunk_events, chunk_labels = injector.flush()
    events.append(chunk_events)
    labels.append(chunk_labels)
    return np.concatenate(events, dtype=EVENT_DTYPE), np.concatenate(labels)


def assert_input_first_on_ties(events: np.ndarray, labels: np.ndarray) -> int:
    """No input event (label 0) right after a noise event of the same time; returns how many ties were seen."""
    same_t = events["t"][1:] == events["t"][:-1]
    mixed = same_t & ((labels[1:] == 0) != (labels[:-1] == 0))
    assert not np.any(same_t & (labels[:-1] != 0) & (labels[1:] == 0))
    return int(mixed.sum())


# -- the recording: pass-through and rates -----------------------------------------------------------------------


def test_walk_keeps_every_event_and_adds_noise_at_the_requested_rates(walk):
    injector = NoiseInjector(WIDTH, HEIGHT, seed=11, **RATES)
    events, labels = run_chunked(injector, cut(walk, [50_000, 50_001, 123_456, 200_000]))
    assert events.dtype == EVENT_DTYPE and len(labels) == len(events)
    assert np.all(np.diff(events["t"]) >= 0)
    assert_same_events(events[labels == 0], walk)  # every original event, unchanged, in its order
    assert set(np.unique(labels).tolist()) == {0, 1, 2, 3}

    t_first, t_last = int(walk["t"][0]), int(walk["t"][-1])
    noise = events[labels != 0]
    assert noise["t"].min() >= t_first and noise["t"].max() <= t_last  # noise spans the recording, no more
    duration_s = (t_last - t_first) * 1e-6
    pixels = WIDTH * HEIGHT
    shot, leak, hot = (events[labels == label] for label in (2, 1, 3))
    assert len(shot) / (pixels * duration_s) == pytest.approx(RATES["shot_noise_rate_hz"], rel=0.05)
    assert len(leak) / (pixels * duration_s) == pytest.approx(RATES["leak_rate_hz"], rel=0.05)
    n_hot = injector.hot_pixels.sum()
    assert n_hot == round(RATES["hot_pixel_fraction"] * pixels)
    assert len(hot) / (n_hot * duration_s) == pytest.approx(RATES["hot_pixel_rate_hz"], rel=0.05)

    balance = (shot["p"].sum() - (~shot["p"]).sum()) / len(shot)  # shot noise: ON and OFF equally likely
    assert abs(balance) < 0.02
    assert np.all(leak["p"])  # leak events are ON
    assert injector.hot_pixels[hot["y"], hot["x"]].all()
    # shot noise covers the whole sensor uniformly: every pixel fires about 125 times
    shot_counts = np.bincount(shot["y"].astype(int) * WIDTH + shot["x"], minlength=pixels)
    assert shot_counts.min() > 60 and shot_counts.std() / shot_counts.mean() < 0.15


def test_leak_rates_spread_log_normally_and_each_pixel_is_periodic(walk):
    injector = NoiseInjector(WIDTH, HEIGHT, leak_rate_hz=0.5, seed=2)
    events, labels = inject_noise(walk, WIDTH, HEIGHT, leak_rate_hz=0.5, seed=2)
    rates = injector.leak_rate_map_hz
    assert rates.mean() == pytest.approx(0.5, rel=0.05)
    assert np.log10(rates).std() == pytest.approx(0.5, rel=0.05)  # the default spread: 0.5 decade
    leak = events[labels == 1]
    counts = np.bincount(leak["y"].astype(int) * WIDTH + leak["x"], minlength=WIDTH * HEIGHT).reshape(HEIGHT, WIDTH)
    duration_s = (walk["t"][-1] - walk["t"][0]) * 1e-6
    # periodic: every pixel fires rate * duration times, give or take one
    assert np.all(np.abs(counts - rates * duration_s) <= 1.0 + 1e-6)
    narrow = NoiseInjector(WIDTH, HEIGHT, leak_rate_hz=0.5, leak_spread_decades=0.0, seed=2)
    assert np.all(narrow.leak_rate_map_hz == 0.5)


def test_merge_equals_a_stable_sort_with_input_first_on_equal_times(walk):
    part = walk[100_000:105_000]
    events, labels = inject_noise(part, WIDTH, HEIGHT, shot_noise_rate_hz=200.0, leak_rate_hz=5.0, seed=3)
    noise, noise_labels = events[labels != 0], labels[labels != 0]
    both = np.concatenate([part, noise], dtype=EVENT_DTYPE)
    both_labels = np.concatenate([np.zeros(len(part), dtype=np.uint8), noise_labels])
    order = np.lexsort((both_labels != 0, both["t"]))  # by time, input first; lexsort is stable
    assert_same_events(events, both[order])
    np.testing.assert_array_equal(labels, both_labels[order])
    assert assert_input_first_on_ties(events, labels) > 100  # the rates are high enough for many ties


# -- chunking, seeds ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def walk_start(walk) -> np.ndarray:
    """3,000 events of the walk in 0.13 s (with 80 pairs of equal times)."""
    return walk[100_000:103_000]


PROPERTY_RATES = {"shot_noise_rate_hz": 40.0, "leak_rate_hz": 3.0, "hot_pixel_fraction": 0.01,
                  "hot_pixel_rate_hz": 500.0}


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.integers(0, 3_000), max_size=12), seed=st.integers(0, 2))
def test_chunking_does_not_change_the_output(walk_start, cuts, seed):
    expected, expected_labels = inject_noise(walk_start, WIDTH, HEIGHT, seed=seed, **PROPERTY_RATES)
    events, labels = run_chunked(NoiseInjector(WIDTH, HEIGHT, seed=seed, **PROPERTY_RATES), cut(walk_start, cuts))
    assert events.dtype == EVENT_DTYPE
    np.testing.assert_array_equal(events, expected)
    np.testing.assert_array_equal(labels, expected_labels)
    assert_input_first_on_ties(events, labels)


def test_one_event_per_chunk_and_cuts_inside_equal_times(walk_start):
    expected, expected_labels = inject_noise(walk_start, WIDTH, HEIGHT, seed=9, **PROPERTY_RATES)
    ties = np.flatnonzero(walk_start["t"][1:] == walk_start["t"][:-1]) + 1
    for chunks in (np.split(walk_start, np.arange(1, len(walk_start))), cut(walk_start, ties)):
        events, labels = run_chunked(NoiseInjector(WIDTH, HEIGHT, seed=9, **PROPERTY_RATES), chunks)
        np.testing.assert_array_equal(events, expected)
        np.testing.assert_array_equal(labels, expected_labels)


def test_a_long_gap_leaves_in_bounded_pieces_with_the_same_output():
    # two bursts 3 s apart: with pieces limited to 2,000 events the gap's noise leaves in many pieces
    t = np.concatenate([np.arange(0, 1_000, 10), np.arange(3_000_000, 3_001_000, 10)]) + 123_456
    rng = np.random.default_rng(0)
    events = make_events(t, rng.integers(0, WIDTH, len(t)), rng.integers(0, HEIGHT, len(t)), rng.integers(0, 2, len(t)))
    expected, expected_labels = inject_noise(events, WIDTH, HEIGHT, seed=4, **PROPERTY_RATES)
    with mock.patch.object(evtools.noise, "CHUNK_EVENTS", 2_000):
        injector = NoiseInjector(WIDTH, HEIGHT, seed=4, **PROPERTY_RATES)
        pieces = list(injector.process_pieces(events))
        final = injector.flush()
    assert len(pieces) > 100
    assert max(len(piece) for piece, _ in pieces) < 2_000 + 4 * BLOCK_US * 1e-6 * 40.0 * WIDTH * HEIGHT
    np.testing.assert_array_equal(np.concatenate([p for p, _ in pieces] + [final[0]], dtype=EVENT_DTYPE), expected)
    np.testing.assert_array_equal(np.concatenate([l for _, l in pieces] + [final[1]]), expected_labels)
    assert_same_events(expected[expected_labels == 0], events)


def test_seed_reproduces_and_noise_sources_are_independent(walk_start):
    a = inject_noise(walk_start, WIDTH, HEIGHT, seed=7, **PROPERTY_RATES)
    b = inject_noise(walk_start, WIDTH, HEIGHT, seed=7, **PROPERTY_RATES)
    c = inject_noise(walk_start, WIDTH, HEIGHT, seed=8, **PROPERTY_RATES)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[0][a[1] == 2], c[0][c[1] == 2])
    # switching hot pixels and leak off leaves the shot noise as it was
    shot_only = inject_noise(walk_start, WIDTH, HEIGHT, seed=7, shot_noise_rate_hz=40.0, leak_rate_hz=0.0)
    np.testing.assert_array_equal(shot_only[0][shot_only[1] == 2], a[0][a[1] == 2])


def test_no_noise_is_a_copy_and_an_empty_stream_stays_empty(walk_start):
    events, labels = inject_noise(walk_start, WIDTH, HEIGHT, leak_rate_hz=0.0, seed=1)
    assert_same_events(events, walk_start)
    assert not labels.any()
    injector = NoiseInjector(WIDTH, HEIGHT, seed=1, **PROPERTY_RATES)
    assert len(injector.process(np.empty(0, dtype=EVENT_DTYPE))[0]) == 0
    events, labels = injector.flush()
    assert len(events) == len(labels) == 0


def test_bad_parameters_and_inputs_raise_clear_errors(walk_start):
    for parameters, needle in (
        ({"shot_noise_rate_hz": -1.0}, "shot_noise_rate_hz"),
        ({"leak_rate_hz": float("nan")}, "leak_rate_hz"),
        ({"hot_pixel_fraction": 1.5}, "hot_pixel_fraction"),
        ({"seed": -3}, "seed"),
        ({"block_us": 0}, "block_us"),
    ):
        with pytest.raises(SimulationError, match=needle):
            NoiseInjector(WIDTH, HEIGHT, **parameters)
    injector = NoiseInjector(WIDTH, HEIGHT, seed=1)
    injector.process(walk_start[100:200])
    with pytest.raises(InvalidEventsError, match="backwards"):
        injector.process(walk_start[:100])
    injector.flush()
    with pytest.raises(SimulationError, match="after flush"):
        injector.process(walk_start[200:300])


# -- the command line -------------------------------------------------------------------------------------------------


def test_cli_same_seed_same_bytes_and_a_truth_file_for_events(tmp_path):
    walk_path = data_file("dvs128_walk.aedat")
    outputs = []
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        run("simulate", walk_path, "--shot-noise-rate-hz", "5", "--leak-rate-hz", "0.2", "--hot-pixel-fraction",
            "0.001", "--seed", seed, "--truth", tmp_path / f"{name}.h5", "-o", tmp_path / f"{name}.aedat4")
        with h5py.File(tmp_path / f"{name}.h5", "r") as h5:
            outputs.append(((tmp_path / f"{name}.aedat4").read_bytes(), h5["label"][()]))
    assert outputs[0][0] == outputs[1][0]
    np.testing.assert_array_equal(outputs[0][1], outputs[1][1])
    assert outputs[0][0] != outputs[2][0]

    info, events = read_all(tmp_path / "a.aedat4")
    _, walk = read_all(walk_path)
    labels = outputs[0][1]
    assert (info.width, info.height) == (WIDTH, HEIGHT) and len(labels) == len(events)
    assert_same_events(events[labels == 0], walk)
    with h5py.File(tmp_path / "a.h5", "r") as h5:
        assert "on" not in h5 and "off" not in h5  # no thresholds are known for a recording
        assert h5.attrs["source_kind"] == "events"
        assert h5.attrs["shot_noise_rate_hz"] == 5.0 and h5.attrs["seed"] == 5
        assert h5.attrs["leak_spread_decades"] == 0.5
        assert h5.attrs["t_first_us"] == walk["t"][0] and h5.attrs["t_last_us"] == walk["t"][-1]
        assert h5["hot_pixels"].shape == (HEIGHT, WIDTH) and h5["hot_pixels"][()].sum() == 16
        assert h5["leak_rate_hz"].shape == (HEIGHT, WIDTH)
    # the same events as the library makes from the same seed
    expected, expected_labels = inject_noise(walk, WIDTH, HEIGHT, seed=5, shot_noise_rate_hz=5.0, leak_rate_hz=0.2,
                                             hot_pixel_fraction=0.001)
    assert_same_events(events, expected)
    np.testing.assert_array_equal(labels, expected_labels)


def test_cli_pipe_convert_simulate_info(tmp_path):
    walk_path = data_file("dvs128_walk.aedat")
    truth = tmp_path / "t.h5"
    pipeline = (f"'{EVTOOLS}' convert '{walk_path}' - | '{EVTOOLS}' simulate - --shot-noise-rate-hz 5 --seed 1 "
                f"--truth '{truth}' | '{EVTOOLS}' info -")
    result = subprocess.run(["bash", "-o", "pipefail", "-c", pipeline], capture_output=True, timeout=120)
    assert result.returncode == 0, result.stderr.decode()
    import json

    summary = json.loads(result.stdout)
    with h5py.File(truth, "r") as h5:
        labels = h5["label"][()]
        assert h5.attrs["source"] == "<stdin>" and h5.attrs["source_format"] == "aedat4"
    assert summary["events"] == len(labels) and summary["width"] == WIDTH
    assert (labels == 0).sum() == 290_292
    duration_s = summary["duration_s"]
    assert (labels == 2).sum() / (WIDTH * HEIGHT * duration_s) == pytest.approx(5.0, rel=0.05)


def test_cli_bad_inputs_give_one_line_errors(tmp_path):
    walk_path = data_file("dvs128_walk.aedat")
    out = tmp_path / "out.aedat4"
    for option, value in (("--shot-noise-rate-hz", "-5"), ("--leak-rate-hz", "-0.1"), ("--hot-pixel-fraction", "2"),
                          ("--cutoff-hz", "30")):  # out of range, or a frame option on an event stream: usage errors
        refused = run("simulate", walk_path, option, value, "-o", out, check=False)
        assert refused.returncode == 2 and option.encode() in refused.stderr and b"Traceback" not in refused.stderr
    smaller = run("simulate", walk_path, "--size", "64x64", "-o", out, check=False)  # --size: the stream's size
    assert smaller.returncode == 1 and b"outside the 64x64 sensor" in smaller.stderr
    assert_clean_error(run("simulate", walk_path, "--truth", walk_path, "-o", out, check=False), "overwrite")
    assert_clean_error(run("simulate", "-", "-o", out, check=False, input=b""), "empty input")
    layout = run("simulate", "scene:static", "--aedat2-layout", "dvs128", "-o", out, check=False)
    assert layout.returncode == 2 and b"event-stream sources only" in layout.stderr
    assert not out.exists()


def test_no_pixel_leaks_more_than_once_a_microsecond():
    """A QA sweep: a mean leak rate of 1 MHz passed the per-pixel bound, and the log-normal spread took pixels to
    1.43 MHz: 25,202 pairs of events of one pixel in one microsecond. Each pixel's rate is now capped at 1 MHz, in
    the pixel model and in the injector."""
    from evtools.simulation import DvsSimulator, run_simulator, scene_frames

    simulator = DvsSimulator(4, 4, leak_rate_hz=1e6, leak_spread_decades=0.5, shot_noise_rate_hz=0, seed=3)
    assert simulator.leak_rate_map_hz.max() <= 1e6
    events, _ = run_simulator(simulator, scene_frames("static", 4, 4, duration_us=20_000))
    key = events["t"].astype(np.int64) * 16 + events["y"].astype(np.int64) * 4 + events["x"]
    assert len(events) > 100_000 and len(np.unique(key)) == len(key)
    stream = make_events(np.arange(0, 20_000, 100), np.zeros(200, int), np.zeros(200, int), np.ones(200, bool))
    noisy, labels = inject_noise(stream, 4, 4, leak_rate_hz=1e6, leak_spread_decades=0.5, seed=3)
    leaks = noisy[labels == 1]
    key = leaks["t"].astype(np.int64) * 16 + leaks["y"].astype(np.int64) * 4 + leaks["x"]
    assert len(leaks) > 100_000 and len(np.unique(key)) == len(key)
