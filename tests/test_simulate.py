"""``evtools simulate``: the pixel kernel against its naive reference, analytic and statistical checks, the CLI."""

from __future__ import annotations

import math

import cv2
import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import evtools
from evtools._kernels.pixel import _level_tables, time_order
from evtools.events import EVENT_DTYPE
from evtools.simulation import (
    DEAD_PIXEL_THRESHOLD,
    PRESETS,
    SCENES,
    DvsSimulator,
    SimulationError,
    lin_log,
    scene_frames,
    simulate_frames,
)
from tests.helpers import assert_clean_error, read_all, run
from tests.naive import naive_lin_log, simulate_naive

IDEAL = {"sigma_thres": 0.0, "leak_rate_hz": 0.0, "shot_noise_rate_hz": 0.0, "cutoff_hz": 0.0}


def inverse_lin_log(level: np.ndarray) -> np.ndarray:
    level = np.asarray(level, dtype=np.float64)
    return np.where(level <= math.log(20.0), level * 20.0 / math.log(20.0), np.exp(level))


def run_frames(simulator: DvsSimulator, frames) -> tuple[np.ndarray, np.ndarray]:
    events, labels = [], []
    for t_us, frame in frames:
        chunk, chunk_labels = simulator.process_labelled(t_us, frame)
        events.append(chunk)
        labels.append(chunk_labels)
    return np.concatenate(events, dtype=EVENT_DTYPE), np.concatenate(labels)


def random_walk_frames(width, height, n_frames, seed):
    """Frames whose intensities wander over the whole 0-255 range (both lin-log regimes), at irregular times."""
    rng = np.random.default_rng(seed)
    frame = rng.uniform(0, 255, (height, width))
    t_us = 1_000
    frames = [(t_us, frame.astype(np.float32))]
    for _ in range(n_frames - 1):
        frame = np.clip(frame + rng.normal(0, 25, frame.shape), 0, 255)
        frame[rng.random(frame.shape) < 0.05] = rng.uniform(0, 255)  # occasional big jumps
        t_us += int(rng.integers(1, 3_000))
        frames.append((t_us, frame.astype(np.float32)))
    return frames


def as_tuples(events: np.ndarray, labels: np.ndarray):
    return list(zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist(),
                    labels.tolist()))


# -- the kernel against the naive reference ------------------------------------------------------------------------

KERNEL_CASES = {
    "ideal": dict(IDEAL, sigma_thres=0.05),
    "lowpass": dict(cutoff_hz=40.0, sigma_thres=0.05, leak_rate_hz=0.0),
    "fixed-lowpass": dict(cutoff_hz=40.0, fixed_cutoff=True, sigma_thres=0.05, leak_rate_hz=0.0),
    "everything": dict(cutoff_hz=200.0, sigma_thres=0.05, leak_rate_hz=50.0, shot_noise_rate_hz=80.0,
                       refractory_us=700, hot_pixel_fraction=0.1, hot_pixel_rate_hz=400.0, dead_pixel_fraction=0.05),
}


@pytest.mark.parametrize("dtype", [np.float32, np.uint8])
@pytest.mark.parametrize("case", sorted(KERNEL_CASES))
def test_kernel_equals_naive_reference(case, dtype):
    frames = [(t, np.round(frame).astype(dtype)) for t, frame in random_walk_frames(9, 7, 40, seed=len(case))]
    simulator = DvsSimulator(9, 7, seed=11, **KERNEL_CASES[case])
    expected = simulate_naive(DvsSimulator(9, 7, seed=11, **KERNEL_CASES[case]), frames)
    events, labels = run_frames(simulator, frames)
    assert len(expected) > 100
    assert as_tuples(events, labels) == expected
    if case == "everything":
        assert set(labels.tolist()) == {0, 1, 2, 3}


def test_8bit_frames_use_tables_with_the_very_values_of_the_naive_lin_log():
    log_table, gain_table = _level_tables(1e-3 * 2.0 * math.pi * 30.0)
    assert log_table.tolist() == [naive_lin_log(float(level)) for level in range(256)]
    assert gain_table.tolist() == [min(1.0, (level + 20.0) / 275.0 * (1e-3 * 2.0 * math.pi * 30.0))
                                   for level in range(256)]
    # 16 x 16 pixels, each frame a permutation of the 256 levels: every level (linear part and log part) is seen
    rng = np.random.default_rng(4)
    frames = [(1_000 * (k + 1), rng.permutation(256).astype(np.uint8).reshape(16, 16)) for k in range(12)]
    parameters = dict(KERNEL_CASES["everything"], refractory_us=0)
    expected = simulate_naive(DvsSimulator(16, 16, seed=3, **parameters), frames)
    events, labels = run_frames(DvsSimulator(16, 16, seed=3, **parameters), frames)
    assert len(expected) > 1_000
    assert as_tuples(events, labels) == expected


def test_8bit_frames_give_the_events_of_the_same_float_frames():
    frames = [(t, np.round(frame)) for t, frame in random_walk_frames(40, 30, 25, seed=8)]
    parameters = dict(PRESETS["noisy"], refractory_us=300, hot_pixel_fraction=0.01, dead_pixel_fraction=0.01)
    as_float = run_frames(DvsSimulator(40, 30, seed=9, **parameters), [(t, f.astype(np.float32)) for t, f in frames])
    as_8bit = run_frames(DvsSimulator(40, 30, seed=9, **parameters), [(t, f.astype(np.uint8)) for t, f in frames])
    assert len(as_float[0]) > 1_000
    np.testing.assert_array_equal(as_8bit[0], as_float[0])
    np.testing.assert_array_equal(as_8bit[1], as_float[1])


@given(
    st.lists(st.integers(-3, 40), min_size=0, max_size=300),
    st.integers(-(1 << 40), 1 << 40),
)
@settings(max_examples=200, deadline=None)
def test_time_order_is_the_stable_argsort(offsets, base):
    t = np.asarray(offsets, dtype=np.int64) + base  # few distinct values: many ties
    order = np.full(len(t), -1, dtype=np.int64)
    assert time_order(t, 1 << 16, order)
    np.testing.assert_array_equal(order, np.argsort(t, kind="stable"))


def test_time_order_declines_a_wide_span():
    rng = np.random.default_rng(1)
    t = np.sort(rng.integers(0, 10_000, 5_000))
    order = np.full(len(t), -1, dtype=np.int64)
    assert time_order(t, 10_000, order)
    np.testing.assert_array_equal(order, np.argsort(t, kind="stable"))
    t[-1] = 10_000  # a span of 10001 us
    order[:] = -1
    assert not time_order(t, 10_000, order)
    assert np.all(order == -1)


def test_batched_frames_spanning_a_long_time_are_sorted_too():
    # one call with frames far apart: the counting sort gives way to a comparison sort; same events either way
    frames = [(t * 5_000, frame) for t, frame in random_walk_frames(12, 9, 12, seed=3)]
    one_by_one = run_frames(DvsSimulator(12, 9, seed=1, **PRESETS["noisy"]), frames)
    batched = DvsSimulator(12, 9, seed=1, **PRESETS["noisy"])
    first = batched.process_labelled(frames[0][0], frames[0][1])
    rest = batched.process_labelled([t for t, _ in frames[1:]], np.stack([f for _, f in frames[1:]]))
    assert len(first[0]) == 0 and rest[0]["t"].max() - rest[0]["t"].min() > 4 * len(rest[0]) + (1 << 16)
    np.testing.assert_array_equal(rest[0], one_by_one[0])
    np.testing.assert_array_equal(rest[1], one_by_one[1])


def test_kernel_output_space_grows_mid_frame():
    frames = random_walk_frames(9, 7, 30, seed=5)
    reference, reference_labels = run_frames(DvsSimulator(9, 7, seed=2, **KERNEL_CASES["everything"]), frames)
    small = DvsSimulator(9, 7, seed=2, **KERNEL_CASES["everything"])
    for lane in small._lanes:
        lane.columns = tuple(column[:3].copy() for column in lane.columns)
    events, labels = run_frames(small, frames)
    np.testing.assert_array_equal(events, reference)
    np.testing.assert_array_equal(labels, reference_labels)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), width=st.integers(1, 12), height=st.integers(1, 9),
       batches=st.lists(st.integers(1, 4), min_size=1, max_size=8), case=st.sampled_from(sorted(KERNEL_CASES)),
       uint8=st.booleans())
def test_lanes_of_rows_give_the_one_lane_output(seed, width, height, batches, case, uint8):
    """Large sensors are advanced in two lanes of rows on two threads (PARALLEL_PIXELS): forced on small random
    sensors, the events and labels equal the one-lane simulator's bit for bit, whatever the frame batches (ties at
    a frame's time with the next frame's first events keep frame order)."""
    from unittest import mock

    import evtools.simulation as simulation

    frames = random_walk_frames(width, height, sum(batches) + 1, seed=seed)
    if uint8:
        frames = [(t, np.round(frame).astype(np.uint8)) for t, frame in frames]
    one = run_frames(DvsSimulator(width, height, seed=seed, **KERNEL_CASES[case]), frames)
    with mock.patch.object(simulation, "PARALLEL_PIXELS", 1):
        lanes = DvsSimulator(width, height, seed=seed, **KERNEL_CASES[case])
    assert len(lanes._lanes) == 2
    events, labels, at = [], [], 1
    lanes.process_labelled(frames[0][0], frames[0][1])
    for size in batches:
        part = frames[at:at + size]
        chunk, chunk_labels = lanes.process_labelled([t for t, _ in part], np.stack([f for _, f in part]))
        events.append(chunk)
        labels.append(chunk_labels)
        at += size
    np.testing.assert_array_equal(np.concatenate(events), one[0])
    np.testing.assert_array_equal(np.concatenate(labels), one[1])


def test_lin_log_is_v2e_and_continuous():
    intensity = np.array([0.0, 10.0, 20.0, 20.0001, 100.0, 255.0])
    expected = [naive_lin_log(v) for v in intensity]
    np.testing.assert_allclose(lin_log(intensity), expected, rtol=1e-15)
    assert lin_log(20.0) == pytest.approx(math.log(20.0), rel=1e-12)
    assert lin_log(-5.0) == 0.0


# -- analytic checks with an ideal pixel -----------------------------------------------------------------------


def test_linear_log_ramp_gives_floor_of_change_over_threshold_at_analytic_times():
    width, height, duration_us = 12, 10, 1_000_000
    rng = np.random.default_rng(3)
    on = rng.uniform(0.1, 0.3, (height, width))
    off = rng.uniform(0.1, 0.3, (height, width))
    start = rng.uniform(2.5, 4.5, (height, width))
    change = rng.uniform(-2.3, 2.3, (height, width))  # rising and falling pixels, both lin-log regimes
    # only 4 frames: most crossings share a frame interval and each still gets its own time
    times = np.linspace(0, duration_us, 4).round().astype(np.int64)
    frames = [(t, inverse_lin_log(start + change * t / duration_us).astype(np.float32)) for t in times]
    simulator = DvsSimulator(width, height, thresholds=(on, off), seed=0, **IDEAL)
    events, labels = run_frames(simulator, frames)
    assert np.all(labels == 0)
    first = lin_log(frames[0][1])  # the exact levels the float32 frames carry
    last = lin_log(frames[-1][1])
    on32, off32 = simulator.on_thres.astype(np.float64), simulator.off_thres.astype(np.float64)
    for y in range(height):
        for x in range(width):
            mine = events[(events["x"] == x) & (events["y"] == y)]
            dl = last[y, x] - first[y, x]
            theta = on32[y, x] if dl > 0 else off32[y, x]
            n = math.floor(abs(dl) / theta)
            assert len(mine) == n, (x, y, dl, theta)
            assert np.all(mine["p"] == (dl > 0))
            expected_t = np.arange(1, n + 1) * theta / abs(dl) * duration_us
            np.testing.assert_allclose(mine["t"], expected_t, atol=1.0)
    assert len(events) > 500


def test_triangle_wave_with_different_on_and_off_thresholds():
    width, height = 16, 8
    rng = np.random.default_rng(4)
    on = rng.uniform(0.12, 0.18, (height, width))
    off = rng.uniform(0.25, 0.35, (height, width))
    low, high, periods = math.log(40.0), math.log(220.0), 5
    frames = list(scene_frames("flicker", width, height, periods * 200_000, min_level=40.0, max_level=220.0,
                               period_s=0.2, frame_rate_hz=2000))
    simulator = DvsSimulator(width, height, thresholds=(on, off), seed=0, **IDEAL)
    events, _ = run_frames(simulator, frames)
    on32, off32 = simulator.on_thres.astype(np.float64), simulator.off_thres.astype(np.float64)
    # the ideal pixel's reference, half period by half period
    ref = np.full((height, width), low)
    expected_on = np.zeros((height, width), dtype=int)
    expected_off = np.zeros((height, width), dtype=int)
    for _ in range(periods):
        n = np.floor((high - ref) / on32).astype(int)
        expected_on += n
        ref = ref + n * on32
        n = np.floor((ref - low) / off32).astype(int)
        expected_off += n
        ref = ref - n * off32
    count_on = np.zeros((height, width), dtype=int)
    count_off = np.zeros((height, width), dtype=int)
    np.add.at(count_on, (events["y"][events["p"]], events["x"][events["p"]]), 1)
    np.add.at(count_off, (events["y"][~events["p"]], events["x"][~events["p"]]), 1)
    np.testing.assert_array_equal(count_on, expected_on)
    np.testing.assert_array_equal(count_off, expected_off)
    assert count_on.sum() > 1.5 * count_off.sum()  # ON threshold about half the OFF one


# -- statistics from the seed ----------------------------------------------------------------------------------------


def test_threshold_map_in_truth_file_has_requested_mean_and_sigma(tmp_path):
    truth = tmp_path / "truth.h5"
    run("simulate", "scene:static", "--size", "200x200", "--duration", "5ms", "--pos-thres", "0.25",
        "--neg-thres", "0.15", "--sigma-thres", "0.03", "--seed", "9", "--truth", truth, "-o", tmp_path / "s.aedat4")
    with h5py.File(truth, "r") as h5:
        on, off = h5["on"][()], h5["off"][()]
        assert on.shape == off.shape == (200, 200) and on.dtype == np.float32
        assert h5.attrs["seed"] == 9 and h5.attrs["sigma_thres"] == 0.03 and h5.attrs["pos_thres"] == 0.25
        assert h5["label"].dtype == np.uint8
    n = on.size
    for values, mean in ((on, 0.25), (off, 0.15)):
        assert abs(values.mean() - mean) < 4 * 0.03 / math.sqrt(n)
        assert abs(values.std() - 0.03) < 4 * 0.03 / math.sqrt(2 * n)
    assert abs(np.corrcoef(on.ravel(), off.ravel())[0, 1]) < 0.05  # drawn independently


def test_spatially_correlated_mismatch_adds_a_smooth_field():
    simulator = DvsSimulator(200, 150, sigma_thres=0.02, correlated_sigma_thres=0.04, correlated_length_px=8,
                             seed=1)
    on = simulator.on_thres.astype(np.float64)
    assert on.std() == pytest.approx(math.hypot(0.02, 0.04), rel=0.15)
    neighbours = np.corrcoef(on[:, :-1].ravel(), on[:, 1:].ravel())[0, 1]
    assert neighbours > 0.6  # white mismatch alone would give about 0
    assert np.corrcoef(on.ravel(), simulator.off_thres.ravel())[0, 1] > 0.6


def test_thresholds_are_clamped_and_dead_pixels_never_fire():
    simulator = DvsSimulator(60, 50, pos_thres=0.05, sigma_thres=0.05, dead_pixel_fraction=0.1, seed=2,
                             leak_rate_hz=20.0, shot_noise_rate_hz=20.0)
    assert simulator.on_thres.min() == pytest.approx(0.01)
    assert simulator.dead_pixels.sum() == 300
    assert np.all(simulator.on_thres[simulator.dead_pixels] == DEAD_PIXEL_THRESHOLD)
    events, _ = run_frames(simulator, scene_frames("flicker", 60, 50, 500_000, period_s=0.1))
    assert len(events) > 10_000
    assert not simulator.dead_pixels[events["y"], events["x"]].any()


def test_leak_rate_in_a_static_scene():
    width, height, duration_us, rate_hz = 100, 100, 2_000_000, 5.0
    simulator = DvsSimulator(width, height, leak_rate_hz=rate_hz, seed=5)
    events, labels = run_frames(simulator, scene_frames("static", width, height, duration_us))
    measured_hz = len(events) / (width * height * duration_us * 1e-6)
    assert measured_hz == pytest.approx(rate_hz, rel=0.05)
    assert np.all(labels == 1) and np.all(events["p"])
    # per-pixel rates spread log-normally, as set
    counts = np.bincount(events["y"].astype(int) * width + events["x"], minlength=width * height)
    assert 0.1 < counts.std() / counts.mean() < 0.5


@pytest.mark.parametrize("level", [0.0, 255.0])
def test_shot_noise_rate_and_on_off_balance_in_a_static_scene(level):
    width, height, duration_us, rate_hz = 100, 100, 1_000_000, 40.0
    simulator = DvsSimulator(width, height, shot_noise_rate_hz=rate_hz, leak_rate_hz=0.0, seed=6)
    events, labels = run_frames(simulator, scene_frames("static", width, height, duration_us, level=level))
    expected_hz = rate_hz * (1.0 - 0.75 * level / 255.0)  # v2e: a quarter of the rate at full intensity
    measured_hz = len(events) / (width * height * duration_us * 1e-6)
    assert measured_hz == pytest.approx(expected_hz, rel=0.05)
    assert np.all(labels == 2)
    balance = (events["p"].sum() - (~events["p"]).sum()) / len(events)
    assert abs(balance) < 0.02
    # a Poisson process: intervals between one pixel's events are exponential (coefficient of variation 1)
    order = np.lexsort((events["t"], events["y"], events["x"]))
    same = (np.diff(events["x"][order]) == 0) & (np.diff(events["y"][order]) == 0)
    gaps = np.diff(events["t"][order])[same]
    assert gaps.std() / gaps.mean() == pytest.approx(1.0, abs=0.05)


def test_hot_pixels_fire_at_their_rate():
    width, height, duration_us = 100, 100, 1_000_000
    simulator = DvsSimulator(width, height, hot_pixel_fraction=0.01, hot_pixel_rate_hz=200.0, leak_rate_hz=0.0,
                             seed=7)
    events, labels = run_frames(simulator, scene_frames("static", width, height, duration_us))
    assert simulator.hot_pixels.sum() == 100
    assert np.all(labels == 3)
    assert simulator.hot_pixels[events["y"], events["x"]].all()
    assert len(events) / (100 * duration_us * 1e-6) == pytest.approx(200.0, rel=0.05)


def test_refractory_period_is_never_violated():
    width, height, refractory_us = 40, 30, 2_000
    parameters = dict(PRESETS["noisy"], hot_pixel_fraction=0.02, hot_pixel_rate_hz=2000.0, shot_noise_rate_hz=50.0)
    frames = list(scene_frames("bars", width, height, 400_000, speed_px_s=400.0, bar_width_px=5, min_level=10.0,
                               max_level=250.0))
    free, _ = run_frames(DvsSimulator(width, height, seed=8, **parameters), frames)
    events, labels = run_frames(DvsSimulator(width, height, seed=8, **dict(parameters, refractory_us=refractory_us)),
                                frames)
    assert 0 < len(events) < len(free)
    assert set(labels.tolist()) >= {0, 2, 3}
    order = np.lexsort((events["t"], events["y"], events["x"]))
    same = (np.diff(events["x"][order]) == 0) & (np.diff(events["y"][order]) == 0)
    assert np.diff(events["t"][order])[same].min() >= refractory_us
    order = np.lexsort((free["t"], free["y"], free["x"]))
    same = (np.diff(free["x"][order]) == 0) & (np.diff(free["y"][order]) == 0)
    assert np.diff(free["t"][order])[same].min() < refractory_us  # the test had something to remove


# -- reproducibility and chunking ------------------------------------------------------------------------------


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cuts=st.lists(st.integers(1, 34), max_size=8), seed=st.integers(0, 3))
def test_frame_batching_does_not_change_the_output(cuts, seed):
    parameters = dict(KERNEL_CASES["everything"], seed=seed)
    frames = random_walk_frames(11, 6, 35, seed=seed)
    expected, expected_labels = simulate_frames(frames, 11, 6, **parameters)
    times = np.array([t for t, _ in frames])
    stack = np.stack([f for _, f in frames])
    simulator = DvsSimulator(11, 6, **parameters)
    events, labels = [], []
    for part in np.split(np.arange(len(frames)), sorted(set(cuts))):
        if len(part):
            chunk, chunk_labels = simulator.process_labelled(times[part], stack[part])
            events.append(chunk)
            labels.append(chunk_labels)
    events = np.concatenate(events, dtype=EVENT_DTYPE)
    assert events.dtype == EVENT_DTYPE
    assert np.all(np.diff(events["t"]) >= 0)
    np.testing.assert_array_equal(events, expected)
    np.testing.assert_array_equal(np.concatenate(labels), expected_labels)


def test_same_seed_same_bytes_other_seed_other_events(tmp_path):
    outputs = []
    for name, seed in (("a", 4), ("b", 4), ("c", 5)):
        run("simulate", "scene:bars", "--size", "40x30", "--duration", "300ms", "--preset", "noisy",
            "--leak-rate-hz", "2", "--hot-pixel-fraction", "0.01", "--seed", seed, "-o", tmp_path / f"{name}.aedat4",
            "--truth", tmp_path / f"{name}.h5")
        with h5py.File(tmp_path / f"{name}.h5", "r") as h5:
            outputs.append(((tmp_path / f"{name}.aedat4").read_bytes(), h5["label"][()], h5["on"][()]))
    assert outputs[0][0] == outputs[1][0]
    np.testing.assert_array_equal(outputs[0][1], outputs[1][1])
    assert outputs[0][0] != outputs[2][0]
    assert not np.array_equal(outputs[0][2], outputs[2][2])
    info, events = read_all(tmp_path / "a.aedat4")
    assert (info.width, info.height) == (40, 30) and len(events) == len(outputs[0][1])
    assert set(np.unique(outputs[0][1]).tolist()) >= {0, 1, 2, 3}


# -- scenes ----------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(SCENES))
def test_scenes_are_frame_generators(name):
    frames = list(scene_frames(name, 24, 16, 100_000))
    times = np.array([t for t, _ in frames])
    assert times[0] == 0 and times[-1] == 100_000 and np.all(np.diff(times) == 1_000)
    for _, frame in frames:
        assert frame.shape == (16, 24) and frame.dtype == np.float32
        assert frame.min() >= 0 and frame.max() <= 255


def test_gradient_moves_right_and_bars_move_along_their_direction():
    frames = list(scene_frames("gradient", 64, 4, 200_000, speed_px_s=100.0, wavelength_px=32.0))
    np.testing.assert_allclose(np.roll(frames[0][1][0], 20), frames[-1][1][0], atol=1e-3)  # 20 px in 0.2 s
    for orientation, axis in (("vertical", 1), ("horizontal", 0)):
        frames = list(scene_frames("bars", 32, 32, 80_000, speed_px_s=100.0, bar_width_px=4.0,
                                   orientation=orientation))
        first, last = frames[0][1], frames[-1][1]
        np.testing.assert_allclose(np.roll(first, 8, axis=axis), last, atol=1e-3)  # 8 px in 80 ms
        assert np.ptp(first, axis=1 - axis).max() == 0  # constant along the bars


def test_flicker_phase_spread_delays_each_pixel_by_its_own_fraction():
    """--phase-spread S: pixel (x, y) sees the flicker delayed by d(x, y) in [0, S) periods, the same every run."""
    period_us = 400_000
    frames = dict(scene_frames("flicker", 6, 4, 400_000, phase_spread=0.5, period_s=0.4, profile="log"))
    again = dict(scene_frames("flicker", 6, 4, 400_000, phase_spread=0.5, period_s=0.4, profile="log"))
    assert all(np.array_equal(frames[t], again[t]) for t in frames)
    # each pixel's darkest frame (its valley) comes d * period after t = 0, d within [0, 0.5)
    stack = np.stack([frames[t] for t in sorted(frames)])
    valley_us = np.array(sorted(frames))[np.argmin(stack, axis=0)]
    assert np.all(valley_us < 0.5 * period_us + 1_000) and len(np.unique(valley_us)) > 10
    plain = dict(scene_frames("flicker", 6, 4, 10_000))
    assert all(np.ptp(frame) == 0 for frame in plain.values())


def test_texture_scene_moves_a_texture_or_a_given_image(tmp_path):
    """The texture scene: levels within [min, max], every frame different (it moves), the view's first frame is
    the texture's centre; ``image`` takes any grey image in its place (its own levels), and the command line's
    --image reads a file (a missing or unreadable one: a clean error)."""
    frames = [f for _, f in scene_frames("texture", 40, 30, 50_000, min_level=60.0, max_level=180.0)]
    assert min(f.min() for f in frames) >= 60.0 - 1e-3 and max(f.max() for f in frames) <= 180.0 + 1e-3
    assert all(np.abs(a - b).max() > 0 for a, b in zip(frames, frames[1:]))
    assert frames[0].std() > 10  # a texture, not a flat field
    image = np.zeros((50, 70), dtype=np.float32)
    image[:, 35:] = 200.0  # a vertical edge at the image's centre
    first = next(scene_frames("texture", 40, 30, 10_000, image=image))[1]
    assert set(np.unique(np.round(first))) <= set(np.round(np.linspace(0, 200, 201)))
    assert first[:, :5].max() < 100 < first[:, -5:].min()  # the edge in view, dark left, bright right
    import cv2

    cv2.imwrite(str(tmp_path / "edge.png"), image.astype(np.uint8))
    out = tmp_path / "t.aedat4"
    run("simulate", "scene:texture", "--image", tmp_path / "edge.png", "--size", "24x16", "--duration", "200ms",
        "-o", out)
    _, events = read_all(out)
    assert len(events) > 0
    (tmp_path / "bad.png").write_bytes(b"not an image")
    for name, needle in (("bad.png", "cannot read this image"), ("missing.png", "no such image file")):
        result = run("simulate", "scene:texture", "--image", tmp_path / name, "-o", tmp_path / "x.aedat4",
                     check=False)
        assert_clean_error(result, name, needle)
    result = run("simulate", "scene:flicker", "--image", tmp_path / "edge.png", "-o", tmp_path / "x.aedat4",
                 check=False)
    assert result.returncode in (1, 2) and b"--image" in result.stderr


def test_step_scene_through_the_lowpass_spreads_the_events():
    width, height = 10, 10
    frames = list(scene_frames("step", width, height, 900_000, period_s=1.0))
    sharp, _ = run_frames(DvsSimulator(width, height, seed=1, **IDEAL), frames)
    smooth, _ = run_frames(DvsSimulator(width, height, seed=1, **dict(IDEAL, cutoff_hz=20.0)), frames)
    assert np.all(sharp["p"]) and np.ptp(sharp["t"]) <= 1_000  # every crossing in the step's frame interval
    assert smooth["t"].min() >= 500_000 and np.ptp(smooth["t"]) > 10_000  # the filter delays and spreads them


def test_bad_parameters_raise_clear_errors():
    with pytest.raises(SimulationError, match="shot_noise_rate_hz"):
        DvsSimulator(10, 10, shot_noise_rate_hz=-1)
    with pytest.raises(SimulationError, match="hot_pixel_fraction"):
        DvsSimulator(10, 10, hot_pixel_fraction=1.5)
    with pytest.raises(ValueError, match="width"):
        DvsSimulator(0, 10)
    from evtools.noise import NoiseInjector

    for model in (DvsSimulator, NoiseInjector):  # (the simulator took True as seed 1, the injector refused it)
        for seed in (True, -1, 1.5, "3"):
            with pytest.raises(SimulationError, match="seed must be an integer >= 0"):
                model(10, 10, seed=seed)
    simulator = DvsSimulator(10, 10)
    simulator.process(0, np.zeros((10, 10)))
    with pytest.raises(SimulationError, match="increase"):
        simulator.process(0, np.zeros((10, 10)))
    with pytest.raises(SimulationError, match="10x10"):
        simulator.process(5, np.zeros((8, 10)))
    for colour in (np.zeros((10, 10, 3), np.uint8), np.zeros((2, 10, 10, 4))):  # said "frames of shape (10, 3)"
        with pytest.raises(SimulationError, match=r"frames of shape \(.*10, 10, [34]\) are colour .* gray first"):
            simulator.process([5, 6][:len(colour) if colour.ndim == 4 else 1], colour)
    tiny = DvsSimulator(3, 3)  # a batch of three 3x3 frames is not taken for one colour frame
    assert len(tiny.process([0, 1, 2], np.zeros((3, 3, 3)))) == 0


# -- video and images through the command line ------------------------------------------------------------------


def test_video_events_only_where_and_as_the_intensity_changed(tmp_path):
    width, height, n_frames, fps = 64, 48, 20, 50.0
    video = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), fps, (width, height))
    assert writer.isOpened()
    levels = np.concatenate([np.linspace(60, 200, 10), np.linspace(200, 60, 10)])
    for level in levels:
        frame = np.full((height, width, 3), 100, dtype=np.uint8)
        frame[:, 32:] = np.array([0.6, 1.0, 0.8]) * level  # coloured (BGR): luma follows the level
        writer.write(frame)
    writer.release()
    out = tmp_path / "clip.aedat4"
    run("simulate", video, "--preset", "clean", "--seed", 1, "-o", out)
    info, events = read_all(out)
    assert (info.width, info.height) == (width, height)
    assert len(events) > 1000
    assert events["x"].min() >= 32  # nothing where the image stayed still
    turn_us = 9 * 1e6 / fps  # the brightest frame
    rising = events["t"] <= turn_us
    assert np.all(events["p"][rising]) and not np.any(events["p"][~rising])
    assert rising.sum() > 100 and (~rising).sum() > 100
    assert events["t"].max() <= (n_frames - 1) * 1e6 / fps


def test_image_folder_with_timestamps(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, level in enumerate([50, 80, 120, 180, 120]):
        cv2.imwrite(str(folder / f"frame_{i}.png"), np.full((12, 16), level, dtype=np.uint8))
    (folder / "timestamps.txt").write_text("\n".join(str(1.0 + 0.01 * i) for i in range(5)) + "\n")
    out = tmp_path / "images.aedat4"
    truth = tmp_path / "truth.h5"
    run("simulate", folder, "--preset", "clean", "--seed", 3, "-o", out, "--truth", truth)
    info, events = read_all(out)
    assert (info.width, info.height) == (16, 12)
    assert events["t"].min() > 0 and events["t"].max() <= 40_000  # times relative to the first image
    assert np.all(events["p"][events["t"] <= 30_000]) and not np.any(events["p"][events["t"] > 30_000])
    with h5py.File(truth, "r") as h5:
        assert len(h5["label"]) == len(events) and h5.attrs["source_images"] == 5
    assert b"timestamps are read as seconds" not in run("simulate", folder, "--preset", "clean", "-o", out).stderr
    # microseconds given where seconds are read: the frames would be 10,000 s apart (days of leak noise): warned
    (folder / "timestamps.txt").write_text("\n".join(str(1_000_000 + 10_000 * i) for i in range(5)) + "\n")
    warned = run("simulate", folder, "--preset", "clean", "-o", out, check=False).stderr
    assert b"the frames are 10,000 s apart (median): timestamps are read as seconds" in warned
    # (QA sweep: a first column of frame numbers was read as seconds, and --frame-rate beside timestamps ignored)
    (folder / "timestamps.txt").write_text("".join(f"{i} {0.01 * i}\n" for i in range(5)))
    assert_clean_error(run("simulate", folder, "-o", out, check=False), "timestamps.txt: its first column counts 0, "
                       "1, 2... (frame numbers")
    (folder / "timestamps.txt").write_text("".join(f"{i} frame_{i}.png\n" for i in range(5)))  # (rpg's t image, 1 fps)
    run("simulate", folder, "--preset", "clean", "-o", out)
    for timing in ([], ["--timestamps", folder / "timestamps.txt"]):
        done = run("simulate", folder, *timing, "--frame-rate", "10", "-o", out, check=False)
        assert done.returncode == 2 and b"both time the images: give one" in done.stderr
    (folder / "timestamps.txt").write_text("\n".join(str(1.0 + 0.01 * i) for i in range(5)) + "\n")
    with pytest.raises(evtools.EvtoolsError, match="both time the images"):  # (Python took the rate, silently)
        evtools.simulate(str(folder), frame_rate=25)
    done = run("simulate", "scene:bars", "--size", "0x10", "-o", out, check=False)  # (was exit 1, no option named)
    assert done.returncode == 2 and b"Invalid value for '--size': sensor width 0" in done.stderr


def test_normalised_frames_from_python_are_warned(caplog):
    """The simulator takes 0-255; frames normalised to 0-1 (common in Python pipelines) were silently simulated as a
    very dark scene."""
    frames = [(0, np.full((4, 6), 0.5)), (1000, np.full((4, 6), 0.9))]
    with caplog.at_level("WARNING", logger="evtools"):
        evtools.simulate(frames, seed=1)
    assert "intensities lie within 0-1, but simulate takes 0-255" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING", logger="evtools"):
        evtools.simulate([(t, frame * 255) for t, frame in frames], seed=1)
        evtools.simulate([(t, (frame * 255).astype(np.uint8)) for t, frame in frames], seed=1)
    assert "0-1" not in caplog.text


def test_float_images_keep_intensities_above_white(tmp_path):
    """A float image (TIFF, EXR) holds 0-1 with 1.0 the 8-bit white; brighter (an HDR highlight) was clipped at 1.0,
    so a highlight brightening from 1.0 to 4.0 fired nothing: now it fires ln 4 / 0.2 ~ 7 ON events a pixel."""
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, level in enumerate([1.0, 2.0, 4.0]):
        image = np.full((6, 8), 0.25, np.float32)
        image[:, :4] = level
        assert cv2.imwrite(str(folder / f"frame_{i}.tiff"), image)
    (folder / "timestamps.txt").write_text("0.0\n0.01\n0.02\n")
    out = tmp_path / "hdr.aedat4"
    run("simulate", folder, "--preset", "clean", "--sigma-thres", "0", "--seed", 1, "-o", out)
    _, events = read_all(out)
    assert np.all(events["x"] < 4) and np.all(events["p"])
    per_pixel = np.bincount(events["y"].astype(int) * 8 + events["x"], minlength=48).reshape(6, 8)[:, :4]
    assert np.all(np.abs(per_pixel - np.log(4.0) / 0.2) <= 1), per_pixel


def test_cli_bad_inputs_give_one_line_errors(tmp_path):
    out = tmp_path / "out.aedat4"
    for option, value in (("--shot-noise-rate-hz", "-2"), ("--seed", "-1"), ("--size", "0x10")):  # usage errors (2)
        refused = run("simulate", "scene:static", option, value, "-o", out, check=False)
        assert refused.returncode == 2 and option.encode() in refused.stderr and b"Traceback" not in refused.stderr
    assert_clean_error(
        run("simulate", "scene:static", "--hot-pixel-fraction", "0.7", "--dead-pixel-fraction", "0.5", "-o", out,
            check=False),
        "--hot-pixel-fraction + --dead-pixel-fraction",
    )
    unknown = run("simulate", "scene:nothing", "-o", out, check=False)  # a usage mistake (issue 39): exit 2
    assert unknown.returncode == 2 and unknown.stderr.startswith(b"evtools: usage: unknown scene")
    assert unknown.stderr.count(b"\n") == 1
    empty = tmp_path / "empty"
    empty.mkdir()
    assert_clean_error(run("simulate", empty, "-o", out, check=False), "no images")
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i}.png"), np.zeros((4, 4), dtype=np.uint8))
    (folder / "timestamps.txt").write_text("0\n0.1\n")
    assert_clean_error(run("simulate", folder, "-o", out, check=False), "2 timestamps for 3 images")
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"this is not a video\n" * 10)
    assert_clean_error(run("simulate", broken, "-o", out, check=False), "cannot read")
    assert_clean_error(run("simulate", tmp_path / "missing.mp4", "-o", out, check=False), "no such file")
    assert not out.exists()


def test_fixed_cutoff_is_a_single_pole_filter_at_every_intensity():
    """A step of log amplitude A through a plain single-pole low-pass (tau = 1/(2 pi fc)): the pixel with
    threshold theta fires first where A (1 - exp(-t/tau)) = theta, the same at a dark and at a bright level."""
    cutoff_hz, amplitude = 8.0, 1.5
    tau_s = 1.0 / (2.0 * np.pi * cutoff_hz)
    for low in (30.0, 100.0):
        high = low * np.exp(amplitude)
        times = np.arange(0, 400_001, 1_000)
        frames = [(int(t), np.full((4, 3), low if t == 0 else high, np.float32)) for t in times]
        simulator = DvsSimulator(3, 4, seed=2, **dict(IDEAL, sigma_thres=0.03, cutoff_hz=cutoff_hz, fixed_cutoff=True))
        events, _ = run_frames(simulator, frames)
        first = np.array([events["t"][(events["x"] == x) & (events["y"] == y)].min() for y in range(4) for x in range(3)])
        theta = simulator.on_thres.reshape(-1).astype(np.float64)
        eps = 1e-3 / tau_s  # the filter moves by eps of the gap per 1 ms frame
        expected_us = 1e3 * np.log(1.0 - theta / amplitude) / np.log(1.0 - eps)
        np.testing.assert_allclose(first, expected_us, atol=1_000)  # within the frame where it crosses


def test_flicker_log_profile_is_linear_in_log_intensity_and_phase_shifts_it():
    frames = list(scene_frames("flicker", 2, 2, 500_000, profile="log", phase=0.25, period_s=0.5))
    t_us = np.array([t for t, _ in frames])
    log_level = np.log(np.array([frame[0, 0] for _, frame in frames], dtype=np.float64))
    wave = 1.0 - np.abs(2.0 * np.mod(t_us / 500_000 + 0.25, 1.0) - 1.0)
    expected = math.log(50.0) + math.log(200.0 / 50.0) * wave
    assert np.abs(log_level - expected).max() < 1e-6  # float32 frames
    assert frames[0][1][0, 0] == pytest.approx(100.0, rel=1e-6)  # a quarter period in: half way in log, sqrt(50 x 200)


def test_flicker_profile_errors(tmp_path):
    with pytest.raises(SimulationError, match="profile"):
        list(scene_frames("flicker", 2, 2, 1000, profile="sine"))
    with pytest.raises(SimulationError, match="min level > 0"):
        list(scene_frames("flicker", 2, 2, 1000, profile="log", min_level=0))
    refused = run("simulate", "scene:step", "--profile", "log", "-o", tmp_path / "x.aedat4", check=False)
    assert refused.returncode == 2 and b"scene step has no option --profile" in refused.stderr  # usage: exit 2
    assert refused.stderr.count(b"\n") == 1 and not (tmp_path / "x.aedat4").exists()


def test_older_option_names_are_aliases(tmp_path):
    """--sensor-size and --fps are other names of --size and --frame-rate (one option each in --help): the same
    output, a usage error when both disagree, and --size gives an event stream's size when it does not store it."""
    run("simulate", "scene:bars", "--size", "16x16", "--duration", "100ms", "--frame-rate", 500, "--seed", 1,
        "-o", tmp_path / "a.aedat4")
    run("simulate", "scene:bars", "--sensor-size", "16x16", "--duration", "100ms", "--fps", 500, "--seed", 1,
        "-o", tmp_path / "b.aedat4")
    assert (tmp_path / "a.aedat4").read_bytes() == (tmp_path / "b.aedat4").read_bytes()
    both = run("simulate", "scene:bars", "--size", "16x16", "--sensor-size", "8x8", "-o", tmp_path / "c.aedat4",
               check=False)
    assert both.returncode == 2 and b"another name for --size" in both.stderr
    text = run("simulate", "--help").stdout.decode()
    assert "--sensor-size" not in text and "--fps" not in text
    (tmp_path / "s.csv").write_text("t,x,y,p\n10,1,1,1\n20,2,2,0\n")
    run("simulate", tmp_path / "s.csv", "--size", "8x6", "--shot-noise-rate-hz", 1, "--seed", 2, "-o",
        tmp_path / "n.aedat4")
    info, _ = read_all(tmp_path / "n.aedat4")
    assert (info.width, info.height) == (8, 6)


@pytest.mark.parametrize("bad", [np.inf, np.nan, -1.0])
def test_a_frame_with_an_impossible_intensity_is_refused(bad):
    """A QA sweep: one inf pixel made the simulator grow to 24 GB (OOM-killed); NaN or a negative value made a fake
    burst of events. Now refused, naming the frame and the pixel."""
    frames = np.full((3, 4, 5), 100.0, np.float32)
    frames[1, 2, 3] = bad
    with pytest.raises(SimulationError, match="the frame at 1000 us has intensity .* at x=3, y=2"):
        DvsSimulator(5, 4, seed=0).process(np.arange(3) * 1000, frames)
    pieces = [(t, frames[k]) for k, t in enumerate(range(0, 3000, 1000))]  # (a frame at a time: was "frame 0")
    with pytest.raises(SimulationError, match="the frame at 1000 us has intensity"):
        evtools.simulate(pieces)


def test_frame_times_and_shapes_that_cannot_be_are_refused_in_one_line():
    """A QA sweep: a frame time of 2**63 was said as -9223372036854775808 (wrapped), a string time and a 1-D frame
    raised Python's own errors."""
    image = np.full((4, 5), 100.0)
    for frames, said in (([(0, image), (2**63, image)], "frame time 9223372036854775808 us is beyond"),
                         ([(0, image), ("5", image)], "frame times must be numbers"),
                         ([(0, np.zeros(5))], "a frame is an image, height x width")):
        with pytest.raises(evtools.EvtoolsError, match=said):
            evtools.simulate(frames)
    with pytest.raises(evtools.EvtoolsError, match=r"scene flicker has no option periodd \(it has .*period_s"):
        evtools.simulate("flicker", scene={"periodd": 1})


@pytest.mark.parametrize("scene", ["flicker", "gradient", "bars", "step", "static", "texture"])
def test_a_long_duration_costs_no_memory_up_front(scene):
    """The frame times are made as the frames are read: a scene of 30 years at 1 kHz (about 10^12 frames; all at
    once they took 24 bytes a frame: `--duration 1e5s` ran out of memory, a QA sweep) starts at once, its first
    frames those of a short one, and a fractional duration is named as such."""
    import tracemalloc

    tracemalloc.start()
    frames = scene_frames(scene, 8, 6, 10**15)
    first = [next(frames) for _ in range(3)]
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 32 << 20, peak
    short = list(scene_frames(scene, 8, 6, 2_000))
    assert [t for t, _ in first] == [t for t, _ in short[:3]] == [0, 1000, 2000]
    assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(first, short))
    with pytest.raises(SimulationError, match="whole number of microseconds"):
        scene_frames(scene, 8, 6, 100_000.5)


@pytest.mark.parametrize("min_level, max_level", [(50.0, 0.0), (0.0, 200.0), (255.0, 0.0)])
def test_bars_reaching_level_0_never_go_below_it(min_level, max_level):
    """`simulate scene:bars --max-level 0` failed: "frame 0 has intensity -1.4e-14" (the covered fraction of a
    pixel, rounded above 1, took the level below 0)."""
    from evtools.simulation import bars_scene

    frames = [frame for _, frame in bars_scene(8, 6, 20_000, min_level=min_level, max_level=max_level)]
    low, high = min(min_level, max_level), max(min_level, max_level)
    assert min(float(f.min()) for f in frames) >= low and max(float(f.max()) for f in frames) <= high


class _Capture:
    """A stand-in for cv2.VideoCapture: ``stamps_ms`` are the container's frame times (CAP_PROP_POS_MSEC after each
    read), ``declared`` its frame count, 10 fps its nominal rate."""

    def __init__(self, stamps_ms, declared):
        self.stamps, self.declared, self.read_frames = stamps_ms, declared, 0

    def isOpened(self):
        return True

    def read(self):
        if self.read_frames == len(self.stamps):
            return False, None
        self.read_frames += 1
        return True, np.full((4, 6, 3), 40 * self.read_frames, np.uint8)

    def get(self, prop):
        return {cv2.CAP_PROP_FPS: 10.0, cv2.CAP_PROP_FRAME_COUNT: float(self.declared),
                cv2.CAP_PROP_POS_MSEC: self.stamps[self.read_frames - 1] if self.read_frames else 0.0}[prop]

    def release(self):
        pass


@pytest.mark.parametrize("stamps_ms, declared, fps, expected_us, cut", [
    ([0, 40, 80, 280, 320], 5, None, [0, 40_000, 80_000, 280_000, 320_000], False),  # variable rate: its own times
    ([500, 540, 580], 3, None, [0, 40_000, 80_000], False),                         # relative to the first frame
    ([0, 40, 80, 280], 4, 25.0, [0, 40_000, 80_000, 120_000], False),               # --frame-rate overrides them
    ([0, 40, 40, 0], 4, None, [0, 40_000, 140_000, 240_000], False),                # not increasing: the rate (10 fps)
    ([0, 100, 200], 10, None, [0, 100_000, 200_000], True),                         # 3 of 10 frames: broken off
])
def test_video_frames_take_the_containers_times_and_a_broken_video_is_cut(monkeypatch, caplog, stamps_ms, declared,
                                                                          fps, expected_us, cut):
    """A QA sweep: frames were timed index / nominal fps, so a variable-frame-rate video (0, 40, 80, 280 ms) put the
    80-280 ms change at 80-120 ms and everything after it 200 ms early, and a copy broken off after 3 of its 10
    frames read as a whole, shorter video."""
    from evtools.formats import video

    monkeypatch.setattr(cv2, "VideoCapture", lambda path: _Capture(stamps_ms, declared))
    monkeypatch.setattr(video, "note_input", lambda path: None)
    source = video.video_source("clip.mp4", fps, None)
    assert [t for t, _ in source.frames] == expected_us
    assert source.was_cut == cut and ("ends after 3 of the 10 frames" in caplog.text) == cut
    assert ("stop increasing at frame 2" in caplog.text) == (stamps_ms == [0, 40, 40, 0])


def test_a_broken_video_is_one_line_even_where_opencv_prints_its_own(tmp_path):
    """A QA sweep: OpenCV's AVI parser printed `Unexpected element. Expected: LIST. Got: JUNK.` before evtools' own
    error, so the error was two lines (even with -q)."""
    video = tmp_path / "flick.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25, (64, 48))
    for i in range(10):
        writer.write(np.full((48, 64, 3), 50 if i % 2 else 200, np.uint8))
    writer.release()
    broken = tmp_path / "broken.avi"
    broken.write_bytes(video.read_bytes()[:5000])
    assert_clean_error(run("-q", "simulate", broken, "-o", tmp_path / "x.aedat4", check=False), "broken.avi",
                       "cannot read it as a video")


def test_frames_too_far_apart_for_the_low_pass_are_said(caplog):
    """A QA sweep: the low-pass moves min(1, dt / tau) a frame (v2e's update), so at 30 fps an 8 Hz cutoff (tau
    19.9 ms) filtered nothing, silently. Frames more than LOWPASS_MAX_STEP time constants apart are now said once;
    the scenes' default 1 ms frames under the noisy preset's 30 Hz are not."""
    from evtools.simulation import LOWPASS_MAX_STEP

    frames = np.full((20, 4, 4), 100.0)
    tau_us = 1e6 / (2 * np.pi * 8)
    for step_us, said in ((int(tau_us * LOWPASS_MAX_STEP) - 1, False), (33_333, True)):
        caplog.clear()
        with caplog.at_level("WARNING", logger="evtools"):
            simulator = DvsSimulator(4, 4, cutoff_hz=8, fixed_cutoff=True, seed=1)
            simulator.process(np.arange(20) * step_us, frames)
            simulator.process(np.arange(20, 40) * step_us, frames)
        assert caplog.text.count("coarse for the 8 Hz low-pass") == int(said), (step_us, caplog.text)
    caplog.clear()
    with caplog.at_level("WARNING", logger="evtools"):
        DvsSimulator(4, 4, cutoff_hz=30, seed=1).process(np.arange(20) * 1000, frames)
    assert "coarse" not in caplog.text


def test_out_of_range_scene_and_aps_values_are_usage_errors(tmp_path):
    """A QA sweep: --phase-spread -1, --wavelength 0 and --aps-rate 2e6 were errors (exit 1) where every other value
    out of its range is a usage error (exit 2); `--aps-exposure` alone said "require"; `--truth -` said "give -o
    FILE" of the truth's option."""
    out = tmp_path / "x.aedat4"
    for scene, option, said in (("flicker", ["--phase-spread", "-1"], "'--phase-spread'"),
                                ("gradient", ["--wavelength", "0"], "'--wavelength'"),
                                ("flicker", ["--aps-rate", "2000000"], "'--aps-rate'"),
                                ("flicker", ["--aps-exposure", "5ms"], "--aps-exposure requires --aps-rate"),
                                ("flicker", ["--truth", "-"], "give --truth FILE")):
        done = run("simulate", f"scene:{scene}", "--size", "4x4", "--duration", "100ms", *option, "-o", out,
                   check=False)
        assert done.returncode == 2 and said in done.stderr.decode(), (option, done.stderr)
        assert not out.exists()
