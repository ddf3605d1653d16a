"""``estimate --method frames`` (issue 38 item 3: offEI, onEI) and ``simulate --aps-rate`` (item 2): the count kernel
against plain Python, chunk and frame-arrival invariance, accuracy on an independent DAVIS generator
(tests/naive/davis.py, written by dv-processing's writer), the APS model's own equation, bad input."""

from __future__ import annotations

import json
import logging
import math
import re

import h5py
import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

import evtools
from evtools._kernels.estimate import (FRAMES_OFF, FRAMES_ON, FRAMES_ROW, TIME_SUMS, count_times, exposure_counts,
                                       fold_runs, frame_sums, log_levels, polarity_counts)
from evtools.estimation import EstimationError, estimate_thresholds
from evtools.estimation_frames import BRIGHTNESS_SLOPE_DN, FrameThresholdEstimator, _lags, _least_squares
from evtools.formats.thresholds import read_thresholds
from tests.helpers import assert_clean_error, cut, random_events, run, unread_bytes, wait_until
from tests.naive.davis import davis_recording, write_with_dv
from tests.naive.estimate import naive_count_times, naive_frame_sums, naive_frame_time_sums, naive_polarity_counts

W, H = 32, 24


@settings(max_examples=20, deadline=None)
@given(n=st.integers(0, 3000), seed=st.integers(0, 2**32 - 1), cuts=st.lists(st.integers(0, 3000), max_size=6))
def test_polarity_counts_against_plain_python(n, seed, cuts):
    events = random_events(n, 7, 5, seed=seed)
    counts = np.zeros((35, FRAMES_ROW), np.int64)
    for chunk in cut(events, cuts):
        polarity_counts(chunk["x"], chunk["y"], chunk["p"], 7, counts)
    expected = naive_polarity_counts(events, 7, 5)
    for i in range(35):
        assert [counts[i, FRAMES_ON], counts[i, FRAMES_OFF]] == expected.get((i % 7, i // 7), [0, 0])


@settings(max_examples=20, deadline=None)
@given(n=st.integers(0, 2000), seed=st.integers(0, 2**32 - 1), cuts=st.lists(st.integers(0, 2000), max_size=6),
       plan=st.lists(st.tuples(st.integers(0, 3), st.booleans()), min_size=7, max_size=7))
def test_exposure_counts_against_plain_python(n, seed, cuts, plan):
    """Each chunk's events go to exposure ``plan[k][0]`` (counted too when ``plan[k][1]``): a pixel's marks are the
    latest exposure it took part in and its events since its first one in it, and its counts are those of the
    counted chunks, as plain Python has them."""
    events = random_events(n, 7, 5, seed=seed)
    counts, marks = np.zeros((35, FRAMES_ROW), np.int64), np.full((35, 2), -1, np.int32)
    expected_counts, expected_fired, expected_stamp = [0] * 35, [0] * 35, [-1] * 35
    for (exposure, count), chunk in zip(plan, cut(events, cuts)):
        exposure_counts(chunk["x"], chunk["y"], chunk["p"], 7, counts, marks, exposure, count)
        for x, y, p in zip(chunk["x"].tolist(), chunk["y"].tolist(), chunk["p"].tolist()):
            i = y * 7 + x
            if expected_stamp[i] != exposure:
                expected_stamp[i], expected_fired[i] = exposure, 0
            expected_fired[i] += 1
            expected_counts[i] += count
    assert marks[:, 0].tolist() == expected_stamp
    assert [fired for fired, stamp in zip(marks[:, 1].tolist(), expected_stamp) if stamp >= 0] == [
        fired for fired, stamp in zip(expected_fired, expected_stamp) if stamp >= 0]
    assert (counts[:, FRAMES_ON] + counts[:, FRAMES_OFF]).tolist() == expected_counts


def _random_exposure(rng, counts, marks, exposure: int, width: int, height: int, bits: int):
    """One random exposure for the per-frame kernels' tests: new counts for half the pixels (added to ``counts``),
    70 % of the pixels marked with events in it (the others keep their old marks; ``marks`` updated), and a random
    region's image. Returns the new counts, each pixel's events in this exposure, the region's corner and image."""
    pixels = width * height
    new = rng.integers(0, 3, (pixels, 2)) * (rng.random((pixels, 1)) < 0.5)
    counts[:, :2] += new
    in_exposure = rng.random(pixels) < 0.7
    marks[in_exposure, 0] = exposure
    marks[:, 1] = rng.integers(0, 4, pixels)
    effective = np.where(marks[:, 0] == exposure, marks[:, 1], 0)
    x0, y0 = int(rng.integers(0, width)), int(rng.integers(0, height))
    image = rng.integers(0, 256 if bits == 8 else 400, (int(rng.integers(1, height - y0 + 1)),
                                                       int(rng.integers(1, width - x0 + 1))))
    return new, effective, x0, y0, image.astype(np.uint8 if bits == 8 else np.uint16)


@settings(max_examples=20, deadline=None)
@given(n=st.integers(0, 3000), seed=st.integers(0, 2**32 - 1), cuts=st.lists(st.integers(0, 3000), max_size=6),
       origin_us=st.integers(-10**6, 10**6))
def test_count_times_against_plain_python(n, seed, cuts, origin_us):
    """onEI's event-time sums (seconds after an origin, ON and OFF apart), chunk by chunk, against plain Python."""
    events = random_events(n, 7, 5, seed=seed)
    times = np.zeros((35, FRAMES_ROW))
    for chunk in cut(events, cuts):
        count_times(chunk["t"], chunk["x"], chunk["y"], chunk["p"], 7, origin_us, times)
    expected = naive_count_times(events, origin_us)
    for i in range(35):
        np.testing.assert_allclose(times[i, [FRAMES_ON, FRAMES_OFF]], expected.get((i % 7, i // 7), [0.0, 0.0]),
                                   rtol=1e-9, atol=1e-9)


def _drifting_pixel(seed: int, rate: float, t_s: float):
    """One pixel's frames with exact logs under ``theta(t) = theta(T) (1 + rate (t - T))``, T = ``t_s`` (random
    thresholds, event times and polarities, the same for every rate): its sums, event-time sums and true thresholds."""
    rng = np.random.default_rng(seed)
    theta_on, theta_off = rng.uniform(0.1, 0.4, 2)
    rows, counts, times_s, logs = [], [0, 0], [0.0, 0.0], [0.0, 0.0]
    last_s = t_s - 6.0
    for frame_s in np.sort(rng.uniform(t_s - 5.0, t_s, int(rng.integers(8, 40)))):
        for event_s in np.sort(rng.uniform(last_s, frame_s, int(rng.integers(0, 4)))):
            polarity = 0 if rng.random() < 0.5 else 1
            counts[polarity] += 1
            times_s[polarity] += event_s
            logs[polarity] += (theta_on, theta_off)[polarity] * (1 + rate * (event_s - t_s))
        last_s = frame_s
        rows.append((counts[0], -counts[1], 1.5 + logs[0] - logs[1], *times_s))
    x1, x2, y, z_on, z_off = (np.array(column, np.float64)[None] for column in zip(*rows))
    sums = np.stack([np.sum(v, axis=1) for v in (x1 ** 0, x1, x2, y, x1 * x1, x2 * x2, x1 * x2, x1 * y, x2 * y, y * y)])
    time_sums = np.stack([np.sum(v, axis=1) for v in (z_on, x1 * z_on, x2 * z_on, z_off, x1 * z_off, x2 * z_off)])
    return sums, time_sums, (theta_on, theta_off)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rate=st.floats(0.005, 0.02), sign=st.sampled_from([-1, 1]),
       t_s=st.floats(2.0, 1000.0))
def test_lags_give_where_the_fitted_thresholds_hold_under_a_drift(seed, rate, sign, t_s):
    """``_lags`` on one pixel's frames with exact logs under a linear drift (random event times, counts and
    thresholds): the least-squares thresholds are ``theta(T) (1 + r lag)`` to first order in r. The error of that
    shrinks as r^2 (at a tenth of the rate, at least 30 times smaller), where the drift's own effect (the fitted
    thresholds against theta(T)) shrinks as r."""
    errors = []
    for r in (sign * rate, sign * rate / 10):
        sums, time_sums, truth = _drifting_pixel(seed, r, t_s)
        fit = _least_squares(sums, np.ones(1), np.zeros(1))
        assume(bool(fit["solved"][0]))
        lags = _lags(sums, time_sums, fit["on"], fit["off"], t_s)
        errors.append(max(abs(fit[key][0] / (true * (1 + r * lags[k, 0])) - 1)
                          for k, (key, true) in enumerate(zip(("on", "off"), truth))))
    assert errors[1] <= errors[0] / 30 + 1e-9, errors


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), width=st.integers(1, 9), height=st.integers(1, 7), frames=st.integers(1, 8),
       black=st.sampled_from([0.0, 4.0, 16.0]), step=st.integers(0, 5), bits=st.sampled_from([8, 16]),
       timed=st.booleans(), sampled_only=st.booleans())
def test_frame_sums_against_plain_python(seed, width, height, frames, black, step, bits, timed, sampled_only):
    """The frames method's per-frame kernel (its frames summed in runs, folded when a pixel's counts change) against
    a pixel-by-pixel loop adding every sum at every frame, over several frames of random regions, each with its
    weight (the sums, the halves of the black level's test, the inverse signal, the new-count tally, the saturated
    frames and, when ``timed``, onEI's event-time sums all carried); ``sampled_only``: the sampled pixels alone."""
    sampled_only = sampled_only and step > 0
    rng = np.random.default_rng(seed)
    pixels = width * height
    samples = -(-pixels // step) if step else 0
    kernel_sums, naive_sums = np.zeros((10, pixels)), np.zeros((10, pixels))
    kernel_half, naive_half = np.zeros((2, 10, samples)), np.zeros((2, 10, samples))
    kernel_extra = [np.zeros(pixels), np.zeros(pixels), np.zeros(pixels, np.int64)]  # 1 / signal, new, saturated
    naive_extra = [np.zeros(pixels), np.zeros(pixels), np.zeros(pixels, np.int64)]
    runs, run_counts, last_state = np.zeros((3, pixels)), np.full((2, pixels), -1, np.int64), np.full(pixels, -1)
    counts = np.zeros((pixels, FRAMES_ROW), np.int64)
    marks = np.full((pixels, 2), -1, np.int32)
    times = np.zeros((pixels if timed else 0, FRAMES_ROW))  # each pixel's sums of its event times, by polarity
    kernel_times, naive_times = np.zeros((TIME_SUMS, pixels)), np.zeros((TIME_SUMS, pixels))
    run_times = np.zeros((FRAMES_ROW, pixels))
    if not timed:
        kernel_times, run_times = np.zeros((0, 0)), np.zeros((0, 0))
    log_dn = np.empty(2**bits)
    log_levels(log_dn, black, 8.0, 250.0)
    for exposure in range(frames):
        new, effective, x0, y0, image = _random_exposure(rng, counts, marks, exposure, width, height, bits)
        if timed:
            times += new * (exposure + rng.random((pixels, 2)))
        weight = float(rng.choice([0.5, 1.0, 2.0, 4.0]))  # onEI's forgetting: a frame's weight (a power of two: the
        # halves' side is a comparison with the weighted mean count level, which must not round differently)
        frame_sums(image, x0, y0, width, counts, marks, exposure, log_dn, black, -4.6, 1, 250.0, kernel_sums,
                   runs, run_counts, kernel_half, step, kernel_extra[0], kernel_extra[1], kernel_extra[2], weight,
                   times, kernel_times, run_times, sampled_only)
        naive_frame_sums(image, x0, y0, width, counts, effective, black, -4.6, 1, 8.0, 250.0, naive_sums,
                         naive_half, step, naive_extra[0], naive_extra[1], last_state, naive_extra[2], weight,
                         sampled_only)
        if timed:
            naive_frame_time_sums(image, x0, y0, width, counts, times, effective, black, 1, 8.0, 250.0, naive_times,
                                  weight, step if sampled_only else 0)
    fold_runs(kernel_sums, runs, run_counts, kernel_times, run_times)
    assert not runs.any()
    for got, expected in zip([kernel_sums, kernel_half] + kernel_extra, [naive_sums, naive_half] + naive_extra):
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    if timed:
        np.testing.assert_allclose(kernel_times, naive_times, rtol=1e-12, atol=1e-12)


def _thresholds(seed):
    rng = np.random.default_rng(seed)
    return (np.clip(0.2 + 0.03 * rng.standard_normal((H, W)), 0.08, None),
            np.clip(0.2 + 0.03 * rng.standard_normal((H, W)), 0.08, None))


@pytest.fixture(scope="module")
def davis(tmp_path_factory):
    """A 12 s DAVIS recording of a moving texture (25 fps, 10 ms exposures: issue 38's clean setup), written by
    dv-processing."""
    pytest.importorskip("dv_processing", reason="dv-processing (the test extra) writes the recording")
    on, off = _thresholds(11)
    events, frames = davis_recording(W, H, 12_000_000, seed=11, theta_on=on, theta_off=off, exposure_us=10_000,
                                     pan_px_s=(30.0, -8.0), wobble_px=6.0, black_level=0.0)
    path = tmp_path_factory.mktemp("davis") / "davis.aedat4"
    write_with_dv(path, events, frames, W, H)
    return path, on, off


@settings(max_examples=8, deadline=None)
@given(chunk_events=st.integers(200, 40_000), frames_late=st.integers(0, 5), online=st.booleans())
def test_the_estimate_does_not_depend_on_chunks_or_when_frames_arrive(davis, chunk_events, frames_late, online):
    """Chunks of any size, and frames handed over up to 5 chunks after their events: the same maps, offline and
    online (every map of the series: the event-time sums of onEI's lags are counted chunk by chunk too)."""
    path = davis[0]
    events, _, frames = evtools.read(path, frames=True)
    options = {"interval_us": 1_000_000, "max_fit": 0.1} if online else {}
    reference = FrameThresholdEstimator(W, H, **options)
    reference.process(events)
    reference.add_frames(frames)
    expected = reference.result()
    estimator, waiting = FrameThresholdEstimator(W, H, **options), list(frames)
    for index, start in enumerate(range(0, len(events), chunk_events)):
        chunk = events[start:start + chunk_events]
        estimator.process(chunk)
        due = [f for f in waiting if f.exposure_end_us <= int(chunk["t"][-1])]
        if index % (frames_late + 1) == 0:
            estimator.add_frames(due)
            waiting = waiting[len(due):]
    estimator.add_frames(waiting)
    got = estimator.result()
    np.testing.assert_array_equal(got.valid, expected.valid)
    np.testing.assert_allclose(got.on, expected.on, rtol=1e-9)
    np.testing.assert_allclose(got.off, expected.off, rtol=1e-9)
    if online:
        assert len(got.series.t_us) == len(expected.series.t_us) >= 10 and got.series.valid.any()
        np.testing.assert_array_equal(got.series.valid, expected.series.valid)
        np.testing.assert_allclose(got.series.on, expected.series.on, rtol=1e-6)


@pytest.mark.parametrize("keep", ["start", "end"])
@pytest.mark.parametrize("online", [False, True])
def test_frames_outside_the_events_span_are_left_out(davis, keep, online):
    """Events cut (the first or the last 6 s of 12 kept) with every frame kept, as when the event stream was cut
    while the APS ran on: of the frames whose exposure lies outside the events' span only the one next to it is used
    (the others counted), so the maps are those of the frames within it; before, the frames past the events' end
    made maps from frames alone, the last map's time went back (a series no command could read) and offline the
    events and the frames were said to disagree."""
    events, _, frames = evtools.read(davis[0], frames=True)
    cut_us = 6_000_000
    events = events[events["t"] < cut_us] if keep == "start" else events[events["t"] >= cut_us]
    first, last = int(events["t"][0]), int(events["t"][-1])
    before = [k for k, f in enumerate(frames) if f.exposure_end_us < first]
    after = [k for k, f in enumerate(frames) if f.exposure_begin_us > last]
    used = set(range(len(frames))) - set(before[:-1]) - set(after[1:])
    inside = [f for k, f in enumerate(frames) if k in used]
    assert 0 < len(inside) < len(frames) - 100
    options = {"interval_us": 1_000_000, "max_fit": 0.1} if online else {}
    got, expected = FrameThresholdEstimator(W, H, **options), FrameThresholdEstimator(W, H, **options)
    for estimator, given_frames in ((got, frames), (expected, inside)):
        estimator.process(events)
        estimator.add_frames(given_frames)
    chunked = FrameThresholdEstimator(W, H, **options)  # (chunks, each frame handed over once its exposure ended)
    waiting = list(frames)
    for start in range(0, len(events), 3_000):
        chunk = events[start:start + 3_000]
        chunked.process(chunk)
        due = [f for f in waiting if f.exposure_end_us <= int(chunk["t"][-1])]
        chunked.add_frames(due)
        waiting = waiting[len(due):]
    chunked.add_frames(waiting)
    got, expected, chunked = got.result(), expected.result(), chunked.result()
    np.testing.assert_array_equal(chunked.on, got.on)
    np.testing.assert_array_equal(chunked.valid, got.valid)
    assert chunked.attributes["frames_beyond_events"] == got.attributes["frames_beyond_events"]
    assert got.attributes["frames_beyond_events"] == len(frames) - len(inside)
    assert expected.attributes["frames_beyond_events"] == 0 and "disagreement" not in got.attributes
    np.testing.assert_array_equal(got.valid, expected.valid)
    np.testing.assert_array_equal(got.on, expected.on)
    assert got.valid.mean() > 0.5
    if online:
        times = got.series.t_us
        assert np.all(np.diff(times) > 0) and times[-1] == last + 1 and times[0] > first
        np.testing.assert_array_equal(times, expected.series.t_us)


def test_a_frame_before_the_events_waiting_for_the_next_holds_bounded_memory(davis, monkeypatch):
    """The review of the rule above: a frame before the first event waits for the next frame (is it the last before
    the events?), and while it waited the held events were never counted: one frame at the start and no other held
    every event (12.6 M against HOLD_EVENTS 4.2 M). Past the bound the frame is used at once."""
    import evtools.estimation_frames as module

    monkeypatch.setattr(module, "HOLD_EVENTS", 5_000)
    events, _, frames = evtools.read(davis[0], frames=True)
    events = events[events["t"] > frames[0].exposure_end_us]
    estimator = FrameThresholdEstimator(W, H)
    estimator.add_frames(frames[:1])
    most = 0
    for start in range(0, len(events), 2_000):
        estimator.process(events[start:start + 2_000])
        most = max(most, estimator.held_events)
    assert most <= 5_000 + 2_000 and estimator.frames_used == 1
    frames_only = FrameThresholdEstimator(W, H)  # (frames and no event: was "no APS frames")
    frames_only.add_frames(frames[:5])
    with pytest.raises(EstimationError, match="5 APS frames but no event during them"):
        frames_only.result()


def test_online_frames_maps_beyond_the_memory_bound_are_refused(davis, monkeypatch):
    """onEI held its maps without a bound (natural and stimulus had one): the same bound, the same message."""
    import evtools.estimation as estimation

    events, _, frames = evtools.read(davis[0], frames=True)
    monkeypatch.setattr(estimation, "MAX_SERIES_BYTES", 13 * W * H * 5)  # five maps
    estimator = FrameThresholdEstimator(W, H, interval_us=1_000_000)
    estimator.add_frames(frames)
    with pytest.raises(EstimationError, match=rf"online maps every 1,000,000 us: 6 maps of {W}x{H} would take"):
        estimator.process(events)
    assert estimator.maps.count == 5 and len(estimator.maps_so_far().t_us) == 5


def test_the_frames_give_absolute_thresholds_better_than_events_alone(davis, tmp_path):
    """On the independent generator (ideal pixels, 1 DN offset non-uniformity, 1.5 DN read noise), through the
    command line, issue 38's goals for a clean setup: at least 90 % of the pixels valid, RMS error within 3 %, at
    most 1 % of the valid pixels 10 % off, at least 2x below the natural method's error (which is even given the
    true mean threshold as its scale), and the scale says absolute."""
    path, on, off = davis
    run("estimate", path, "--method", "frames", "-o", tmp_path / "frames.h5")
    with h5py.File(tmp_path / "frames.h5") as f:
        est_on, est_off, valid = f["on"][()], f["off"][()], f["valid"][()]
        assert f.attrs["scale"] == "absolute" and f.attrs["method"] == "frames"
    assert valid.mean() >= 0.9
    errors = np.concatenate([est_on[valid] / on[valid] - 1, est_off[valid] / off[valid] - 1])
    frames_rmse = float(np.sqrt(np.mean(errors**2)))
    assert frames_rmse <= 0.03, frames_rmse
    worst = np.maximum(np.abs(est_on / on - 1), np.abs(est_off / off - 1))[valid]
    assert np.mean(worst > 0.10) <= 0.01
    events = evtools.read(path)[0]
    natural = estimate_thresholds(events, W, H, "natural", nominal=float((on.mean() + off.mean()) / 2))
    usable = natural.valid
    natural_errors = np.concatenate([natural.on[usable] / on[usable] - 1, natural.off[usable] / off[usable] - 1])
    assert 2 * frames_rmse <= np.sqrt(np.mean(natural_errors**2)), (frames_rmse, natural_errors)


def test_natural_takes_its_scale_from_the_frames(davis, tmp_path):
    """estimate --method natural --nominal frames: one scale per polarity from the frames, so the map is absolute
    (within 2 % of the true mean ON and OFF thresholds here, measured 0.2-0.9 % on samples/frames.py's setups)
    and as accurate as natural given the true mean as --nominal (within 0.5 points of RMS error); the scale's
    error in the attributes and in every pixel's fit."""
    path, on, off = davis
    run("estimate", path, "--method", "natural", "--nominal", "frames", "-o", tmp_path / "scaled.h5")
    with h5py.File(tmp_path / "scaled.h5") as f:
        est_on, est_off, valid, fit = f["on"][()], f["off"][()], f["valid"][()], f["fit"][()]
        attributes = dict(f.attrs)
    assert attributes["scale"] == "absolute" and attributes["nominal"] == "frames"
    assert abs(np.median(est_on[valid] / on[valid]) - 1) <= 0.02
    assert abs(np.median(est_off[valid] / off[valid]) - 1) <= 0.02
    assert 0 < attributes["scale_error"] < 0.02 and np.all(fit[valid] >= attributes["scale_error"] * 0.999)
    errors = np.concatenate([est_on[valid] / on[valid] - 1, est_off[valid] / off[valid] - 1])
    events = evtools.read(path)[0]
    natural = estimate_thresholds(events, W, H, "natural", nominal=float((on.mean() + off.mean()) / 2))
    usable = natural.valid
    natural_errors = np.concatenate([natural.on[usable] / on[usable] - 1, natural.off[usable] / off[usable] - 1])
    assert np.sqrt(np.mean(errors**2)) <= np.sqrt(np.mean(natural_errors**2)) + 0.005
    no_frames = tmp_path / "events.aedat4"
    evtools.write(no_frames, events, evtools.StreamInfo(W, H))
    done = run("estimate", no_frames, "--method", "natural", "--nominal", "frames", "-o", tmp_path / "t.h5",
               check=False)
    assert_clean_error(done, "events.aedat4", "no APS frames")
    assert not (tmp_path / "t.h5").exists()
    for options in (["--method", "stimulus", "--nominal", "frames"], ["--online", "--nominal", "frames"],
                    ["--nominal", "framez"], ["--nominal", "-0.2"]):
        done = run("estimate", path, "--method", "natural", *options, "-o", tmp_path / "t.h5", check=False)
        assert done.returncode == 2 and "--nominal" in done.stderr.decode(), (options, done.stderr)
    assert not (tmp_path / "t.h5").exists()


def test_a_scale_from_frames_with_a_fitted_black_level_carries_its_error(tmp_path):
    """A QA sweep: --nominal frames on frames with a 30 DN black level (not given: fitted at 33 DN) had its scale
    3.6 / 4.7 % off with scale_error 0.002. The fitted level's error (3 DN) over the pixels' signals is now in it,
    and so in every pixel's fit; with the level given no such term."""
    out, truth = tmp_path / "bl.aedat4", tmp_path / "bl.h5"
    run("simulate", "scene:texture", "--size", "64x48", "--duration", "6s", "--seed", "3", "--speed", "200",
        "--aps-rate", "25", "--aps-exposure", "10ms", "--aps-black-level", "30", "--truth", truth, "-o", out)
    errors = {}
    for level in ([], ["--black-level", "30"]):
        estimate = tmp_path / f"n{len(level)}.h5"
        run("-q", "estimate", out, "--method", "natural", "--nominal", "frames", *level, "-o", estimate)
        report = json.loads(run("metrics", "thresholds", estimate, "--truth", truth, "--json").stdout)
        with h5py.File(estimate) as f:
            errors[bool(level)] = float(f.attrs["scale_error"])
        if not level:
            bias = max(abs(report["on"]["bias"]), abs(report["off"]["bias"]))
            assert bias < 2 * errors[False], (bias, errors)
    assert errors[False] > 0.02 and errors[True] < 0.01, errors
    done = run("-q", "estimate", out, "--method", "natural", "--nominal", "frames", "--black-level", "0", "-o",
               tmp_path / "wrong.h5", check=False)  # (the check finds 30: was a map 17 % low, scale_error 0.2 %)
    assert_clean_error(done, "the frames give no scale", "black level looks about 3")


def test_frames_on_another_clock_are_said_to_disagree(davis, tmp_path):
    """Frames whose times are 0.3 s off the events' (another clock): the estimate says the events and the frames
    disagree (attribute) and calls no pixel valid, so the command refuses in one line saying why (exit 1, no file);
    on the events' clock it says nothing."""
    path, on, off = davis
    events, info, frames = evtools.read(path, frames=True)
    shifted = tmp_path / "shifted.aedat4"
    frames = [evtools.Frame(frame.image, frame.t_us + 300_000, frame.exposure_begin_us + 300_000,
                            frame.exposure_end_us + 300_000) for frame in frames]
    evtools.write(shifted, events, info, frames=frames)
    done = run("estimate", shifted, "--method", "frames", "-o", tmp_path / "shifted.h5", check=False)
    assert_clean_error(done, "shifted.aedat4", "no pixel could be estimated", "disagree", "clock")
    assert not (tmp_path / "shifted.h5").exists()
    estimator = FrameThresholdEstimator(W, H)
    estimator.process(events)
    estimator.add_frames(frames)
    result = estimator.result()  # (from Python: the estimate, every pixel with its reason)
    assert result.attributes["residual_ratio_median"] > 2 and "disagreement" in result.attributes
    assert not result.valid.any()
    done = run("estimate", path, "--method", "frames", "-o", tmp_path / "aligned.h5")
    assert "disagree" not in done.stderr.decode()
    with h5py.File(tmp_path / "aligned.h5") as f:
        assert f.attrs["residual_ratio_median"] < 2 and "disagreement" not in f.attrs


FIT_SCALE = 1.5
"""How far the fit may be from the RMS error it predicts (a factor): its model leaves out the pan's speed."""


@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), exposure_ms=st.integers(8, 20), rate_hz=st.sampled_from([20.0, 25.0, 40.0]),
       read_noise=st.floats(1.0, 2.0), speed=st.floats(10, 40), direction=st.floats(0, 2 * np.pi),
       wobble=st.floats(0, 8))
def test_drawn_davis_recordings_are_estimated_within_their_fit(seed, exposure_ms, rate_hz, read_noise, speed,
                                                                direction, wobble):
    """Drawn setups (exposure 8-20 ms, 20-40 fps, read noise 1-2 DN, pans of 10-40 px/s in any direction with a
    wobble): the fit a standard deviation of the error (median |error| / fit near a normal's 0.674), the valid
    pixels' errors as their fits predict (RMS error / fit within FIT_SCALE, and the count of pixels 10 % off
    within what a normal error of FIT_SCALE fits gives: a valid fit may be up to 0.04, so 10 % is 2.5 of its
    deviations), every invalid pixel with its reason, and nothing valid where the frames are mostly saturated.

    (Written before as fixed bounds - RMS error <= 5 %, <= 2 % of valid pixels 10 % off, at least one valid - which
    hypothesis broke at the slowest pans with the shortest exposures: 0 valid of 768 (honest: too few events), 6
    valid at RMS 5.3 % with fits of 0.037-0.038, 3 of 42 valid 10-12 % off with fits 0.034-0.039; the errors were
    what the fits said, the bounds asked for more than a fit of 0.04 promises.)"""
    on, off = _thresholds(seed % 1000)
    events, frames = davis_recording(W, H, 5_000_000, seed=seed, theta_on=on, theta_off=off, rate_hz=rate_hz,
                                     exposure_us=exposure_ms * 1000, read_noise=read_noise,
                                     pan_px_s=(speed * np.cos(direction), speed * np.sin(direction)),
                                     wobble_px=wobble, black_level=0.0)
    estimator = FrameThresholdEstimator(W, H)
    every = FrameThresholdEstimator(W, H, max_fit=np.inf)  # every pixel the data let fit, to check the fit itself
    for each in (estimator, every):
        each.process(evtools.make_events(events["t"], events["x"], events["y"], events["p"]))
        each.add_frames([evtools.Frame(image, (b + e) // 2, b, e) for b, e, image in frames])
    fitted = every.result()
    checked = fitted.valid & np.isfinite(fitted.fit)
    ratio = np.maximum(np.abs(fitted.on / on - 1), np.abs(fitted.off / off - 1))[checked] / fitted.fit[checked]
    assert 0.45 <= np.median(ratio) <= 1.0, np.median(ratio)
    result = estimator.result()
    valid = result.valid
    reasons = sum(value for key, value in result.attributes.items() if key.startswith("invalid_"))
    assert reasons == (~valid).sum(), result.attributes  # (a slow pan leaves pixels too few events: said)
    if valid.any():
        fit = result.fit[valid]
        errors = np.concatenate([result.on[valid] / on[valid] - 1, result.off[valid] / off[valid] - 1])
        n = len(errors)
        # the RMS of error / fit: 1 where the fit is the error's deviation (measured 0.82-1.19 over 12 setups, and
        # 1.19 where hypothesis drew the slowest pan at the shortest exposure): within a factor FIT_SCALE, plus
        # what n samples leave to chance
        ratio = np.sqrt(np.mean(errors**2 / np.concatenate([fit, fit]) ** 2))
        assert ratio <= FIT_SCALE * (1 + 3 / np.sqrt(2 * n)), (ratio, n)
        worst = np.maximum(np.abs(result.on / on - 1), np.abs(result.off / off - 1))[valid]
        one_side = np.array([math.erfc(0.10 / (FIT_SCALE * f) / math.sqrt(2)) for f in fit])  # P(|error| > 10 %)
        expected = np.sum(1 - (1 - one_side) ** 2)  # of the worse of ON and OFF
        assert (worst > 0.10).sum() <= expected + 3 * np.sqrt(expected) + 1, ((worst > 0.10).sum(), expected)
    dn = np.stack([image for _, _, image in frames])
    saturated = (dn >= 250).mean(0) > 0.5
    assert not (valid & saturated).any()


def test_simulated_aps_frames_follow_the_documented_model(tmp_path):
    """simulate --aps-rate: DN = offset + gain * exposure_ms * mean intensity + read noise, rounded and clipped,
    against the truth's own maps and mean intensities; the estimate of the simulated recording is absolute and
    close to the truth."""
    out, truth = tmp_path / "davis.aedat4", tmp_path / "truth.h5"
    run("simulate", "scene:texture", "--size", "32x24", "--duration", "12s", "--seed", "4", "--speed", "200",
        "--aps-rate", "25", "--aps-exposure", "10ms", "--aps-read-noise", "1", "--truth", truth, "-o", out)
    _, info, frames = evtools.read(out, frames=True)
    assert info.metadata["frame_size"] == (32, 24) and len(frames) == 300
    with h5py.File(truth) as f:
        aps = f["aps"]
        predicted = aps["offset"][()] + aps["gain"][()] * 10 * aps["mean_intensity"][()]
        assert np.array_equal(aps["exposure_end_us"][()], [frame.exposure_end_us for frame in frames])
        true_on = f["on"][()]
    dn = np.stack([frame.image for frame in frames]).astype(float)
    inside = (predicted > 3) & (predicted < 250)
    residual = (dn - predicted)[inside]
    assert abs(residual.mean()) < 0.1 and 0.9 < residual.std() < 1.2  # read noise 1 DN and rounding
    run("estimate", out, "--method", "frames", "-o", tmp_path / "t.h5")
    with h5py.File(tmp_path / "t.h5") as f:
        valid, est_on = f["valid"][()], f["on"][()]
    assert valid.mean() > 0.15  # 12 s (53 % valid): pixels whose frames span too little of their range have too
    # wide a fit (6 s: 7 % valid at RMS 4.1 %, since the fit counts a pixel's offset over its darkest frames)
    assert np.sqrt(np.mean((est_on[valid] / true_on[valid] - 1) ** 2)) < 0.08


def test_bad_frame_inputs_are_one_line_errors(tmp_path, davis):
    no_frames = tmp_path / "events.aedat4"
    evtools.write(no_frames, random_events(1000, W, H), evtools.StreamInfo(W, H))
    done = run("estimate", no_frames, "--method", "frames", "-o", tmp_path / "t.h5", check=False)
    assert_clean_error(done, "events.aedat4", "no APS frames")
    assert not (tmp_path / "t.h5").exists()
    done = run("estimate", davis[0], "--method", "frames", "--black-level", "-3", "-o", tmp_path / "t.h5",
               check=False)
    assert done.returncode == 2 and "--black-level" in done.stderr.decode()
    done = run("estimate", no_frames, "--black-level", "4", "-o", tmp_path / "t.h5", check=False)
    assert done.returncode == 2 and "--method frames" in done.stderr.decode()
    done = run("simulate", "scene:flicker", "--aps-exposure", "5ms", "-o", tmp_path / "x.aedat4", check=False)
    assert done.returncode == 2 and "--aps-rate" in done.stderr.decode()
    done = run("simulate", "scene:flicker", "--aps-rate", "100", "--aps-exposure", "20ms", "-o",
               tmp_path / "x.aedat4", check=False)  # (two options that do not go together: a usage error)
    said = done.stderr.decode()
    assert done.returncode == 2 and "shorter than the frame interval" in said and said.count("\n") == 1, said


@pytest.mark.parametrize("name", ["davis346_lab_frames.aedat4", "davis346_street_frames.aedat4"])
def test_the_real_davis_recordings_are_estimated_honestly(tmp_path, name):
    """Three or four frames are far too few to fit a pixel: no pixel can be estimated, and the command says so in
    one line naming the reason (few frames), exit 1 and no file, as every method does when no pixel is estimable
    (it wrote a map of nothing valid and exited 0: found by a QA sweep); online, the maps made are kept."""
    from tests.conftest import data_file

    done = run("estimate", data_file(name), "--method", "frames", "-o", tmp_path / "t.h5", check=False)
    assert_clean_error(done, name, "no pixel could be estimated by frames", "fewer than 12 frames")
    assert not (tmp_path / "t.h5").exists()
    done = run("estimate", data_file(name), "--method", "frames", "--online", "--interval", "50ms", "-o",
               tmp_path / "s.h5", check=False)
    assert_clean_error(done, "no pixel could be estimated by frames", "written to")
    with h5py.File(tmp_path / "s.h5") as f:
        assert not f["valid"][()].any() and f.attrs["partial"] and len(f["t_us"]) >= 2


def test_metrics_reconstruction_predicts_the_recordings_own_frames(tmp_path):
    """Issue 38 item 4: without --truth, each APS frame is predicted from the one before and the events between;
    the true thresholds predict best, a constant too small or too large worse, all better than holding the frame;
    bad input is one line."""
    out, truth = tmp_path / "davis.aedat4", tmp_path / "truth.h5"
    run("simulate", "scene:texture", "--size", "32x24", "--duration", "4s", "--seed", "4", "--speed", "200",
        "--sigma-thres", "0.05", "--aps-rate", "25", "--aps-exposure", "10ms", "--truth", truth, "-o", out)

    def score(*options):
        return json.loads(run("metrics", "reconstruction", out, *options, "--json").stdout)

    true, small, large = score("--thresholds", truth), score("--contrast", "0.1"), score("--contrast", "0.3")
    assert true["pairs"] == true["frames"] - 1 == 99
    assert true["rmse"] < min(small["rmse"], large["rmse"]) and true["rmse"] < true["rmse_hold"]
    assert true["explained"] > 0.5
    events_only = tmp_path / "events.aedat4"
    evtools.write(events_only, evtools.read(out)[0], evtools.StreamInfo(32, 24))
    done = run("metrics", "reconstruction", events_only, check=False)
    assert_clean_error(done, "events.aedat4", "no APS frames")
    done = run("metrics", "reconstruction", out, "--plot", tmp_path / "x.png", check=False)
    assert done.returncode == 2 and "--truth" in done.stderr.decode()


def test_metrics_reconstruction_warns_of_a_black_level_left_in_the_frames(tmp_path):
    """A QA sweep: frames with a 30 DN black level scored at the default 0 ranked a contrast of 0.12 best for true
    0.2, silently. A first frame that never reads near 0 is now warned of; a frames estimate's map brings the level
    it was made at (black_level_used), and the true contrast then predicts better than a smaller one."""
    out = tmp_path / "bl.aedat4"
    run("simulate", "scene:texture", "--size", "64x48", "--duration", "6s", "--seed", "3", "--speed", "200",
        "--aps-rate", "25", "--aps-exposure", "10ms", "--aps-black-level", "30", "-o", out)

    def score(*options):
        done = run("metrics", "reconstruction", out, *options, "--json")
        return json.loads(done.stdout), done.stderr.decode()

    (small, said), (right, _) = score("--contrast", "0.12"), score("--contrast", "0.2")
    assert "never reads below" in said and "--black-level" in said and small["frames_floor_dn"] >= 30
    assert small["black_level_from"] == "default" and small["rmse"] < right["rmse"]  # (the bias the warning names)
    (small, said), (right, _) = score("--contrast", "0.12", "--black-level", "30"), score("--contrast", "0.2",
                                                                                         "--black-level", "30")
    assert "never reads below" not in said and right["rmse"] < small["rmse"]
    estimate = tmp_path / "bl.h5"
    run("estimate", out, "--method", "frames", "-o", estimate)
    with h5py.File(estimate) as f:
        used = float(f.attrs["black_level_used"])
    mapped, said = score("--thresholds", estimate)
    assert mapped["black_level_from"] == "thresholds" and mapped["black_level"] == pytest.approx(used)
    assert abs(used - 30) < 6 and "never reads below" not in said
    # a level that is not a number is refused (FramePrediction(black_level="fit"), the estimator's, scored with 0)
    from evtools.metrics.frames import FramePrediction, ReconstructionError

    for level in ("fit", -1, float("nan"), True):
        with pytest.raises(ReconstructionError, match="black level must be a number"):
            FramePrediction(4, 3, 0.2, 0.2, black_level=level)


@pytest.mark.parametrize("name", ["davis346_lab_frames.aedat4", "davis346_street_frames.aedat4"])
def test_metrics_reconstruction_runs_on_the_real_davis_recordings(name):
    """The two DAVIS346 recordings: every pair of consecutive frames scored, most pixels compared."""
    from tests.conftest import data_file

    result = json.loads(run("metrics", "reconstruction", data_file(name), "--json").stdout)
    assert result["pairs"] == result["frames"] - 1 >= 2
    assert result["pixels_per_pair"] > 0.5 * 346 * 260 and 0 < result["rmse"] < 1 and 0 < result["rmse_hold"] < 1


def test_an_online_frames_run_cut_midway_keeps_its_maps(tmp_path):
    """onEI on a pipe cut midway: exit 1 naming stdin, and the maps made so far written, marked partial."""
    import subprocess
    import sys
    from pathlib import Path

    out = tmp_path / "davis.aedat4"
    run("simulate", "scene:texture", "--size", "64x48", "--duration", "4s", "--seed", "2", "--speed", "200",
        "--aps-rate", "25", "--aps-exposure", "10ms", "-o", out)
    data = out.read_bytes()
    process = subprocess.Popen([str(Path(sys.executable).with_name("evtools")), "estimate", "-", "--method",
                                "frames", "--online", "--interval", "1s", "--max-fit", "0.5", "-o",
                                str(tmp_path / "series.h5")], stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdin.write(data[: len(data) * 3 // 4])  # most of the stream (several event packets) at once
    process.stdin.flush()
    wait_until(lambda: unread_bytes(process.stdin) == 0, "the command to read its input")
    process.stdin.write(data[len(data) * 3 // 4: len(data) * 3 // 4 + 100])  # then a packet cut short
    process.stdin.close()
    message = process.stderr.read().decode()
    assert process.wait(timeout=60) == 1 and "<stdin>" in message and "partial" in message, message
    with h5py.File(tmp_path / "series.h5") as f:
        assert f.attrs["partial"] and f["on"].ndim == 3 and len(f["t_us"]) >= 1


@settings(max_examples=2, deadline=None)  # (and the examples: 7 s a run; 122 runs measured, see the docstring)
@given(seed=st.integers(0, 2**32 - 1), drift=st.sampled_from([-0.02, 0.02]))
@example(seed=165, drift=-0.02)  # CI's draw of an earlier session: 3.7 % with a fixed lag of one memory
@example(seed=10, drift=0.02)  # a suite run's draw: 4.8 % with a fixed lag of 1.3 memories (this scene's: 1.5-4.2 s)
def test_online_maps_follow_a_drift_shared_by_all_pixels(seed, drift):
    """onEI (1 s maps, 3 s memory) on the independent generator with every threshold drifting by 2 %/s either way:
    from two forgetting times on, each map's median ratio to the true thresholds of its time is within issue 38's
    3 %. Measured over 122 runs (seeds 1-60 and 165, both signs) with each pixel's lag measured (``_lags``): the
    worst map of a run 0.4-2.6 % off (mean 1.4 %); with a fixed lag of 1.3 memories seed 10 reached 4.8 % (its
    lag went 1.5 s -> 4.2 s -> 2.3 s with the scene) and with one memory seed 165 3.7 %; without the shared trend's
    correction the maps lagged by 5.4-8.5 % at 12 s. The same run without drift stays within 2 %, and no drift is
    taken for a step."""
    on, off = _thresholds(seed % 1000)
    results = {}
    for rate in (drift, 0.0):
        events, frames = davis_recording(W, H, 12_000_000, seed=seed, theta_on=on, theta_off=off, exposure_us=10_000,
                                         pan_px_s=(30.0, -8.0), wobble_px=6.0, black_level=0.0, drift_per_s=rate)
        estimator = FrameThresholdEstimator(W, H, max_fit=0.1, interval_us=1_000_000)
        estimator.process(evtools.make_events(events["t"], events["x"], events["y"], events["p"]))
        estimator.add_frames([evtools.Frame(image, (b + e) // 2, b, e) for b, e, image in frames])
        result = estimator.result()
        assert result.attributes["steps_seen"] == 0  # a drift is not a step
        results[rate] = result.series
    series = results[drift]
    checked = 0
    for k, t_us in enumerate(series.t_us):
        valid = series.valid[k]
        if t_us < series.t_us[0] + 2 * 3_000_000 or valid.sum() < 100:
            continue
        scale = 1 + drift * t_us * 1e-6
        for estimated, true in ((series.on[k], on), (series.off[k], off)):
            assert abs(np.median(estimated[valid] / (true[valid] * scale)) - 1) <= 0.03, (t_us, drift)
        checked += 1
    assert checked >= 5
    still = results[0.0]
    last = still.valid[-1]
    assert abs(np.median(still.on[-1][last] / on[last]) - 1) <= 0.02


def _first_maps_after(series, interval_us=500_000, step_us=7_000_000):
    """The times of the first two maps whose interval lies wholly after a step (in the first, the short memory,
    forgotten over one interval, still holds a third of the frames from before the step)."""
    return series.t_us[series.t_us - interval_us >= step_us][:2].tolist()


@settings(max_examples=2, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), factor=st.sampled_from([1.3, 1 / 1.3]))
@example(seed=3, factor=1.3)  # a false step at 3.5 s when the shared trend read the black level's moves as drift
@example(seed=16925, factor=1.3)  # 7.2 % off at 2 s when the black level's test ran across the step (to 18-19 DN)
@example(seed=7790, factor=1 / 1.3)  # not seen when the shared trend read the maps' black-level moves as drift
def test_online_steps_are_seen_with_the_black_level_fitted(seed, factor):
    """onEI with --black-level fit (the recording's black level 16 DN): a x1.3 or /1.3 step at 7 s is seen in the
    first or second map after it (a short memory per black-level candidate, compared at the one in use; 12 runs, 6
    seeds: all in the first, its shift 5.0-10.4 % against STEP_SHARE's 5 %) and the maps follow
    it: from two seconds after (the first map with 100 pixels valid), within 6 % of the new thresholds. Measured over
    12 runs (seeds 1-6, both steps): 0.1-3.6 % (mean 1.7 %), every later map within 4.5 %, the fitted black level
    14.9-17.0 DN; while the black level's test ran on across the step (its sums mixing both thresholds): 0.5-7.6 %
    (mean 2.5 %), later maps up to 8.9 %, the level 13.5-19.1 DN, and 7.2 % in a draw of seed 16925; without step
    detection 0.8-8.5 %. Without a step none is seen (with the black level's early moves read as a drift, seed 3
    saw one at 3.5 s; and seed 7790 missed its /1.3 step: the maps' small black-level moves had made a -0.9 %/s
    drift, which took most of the step's shift; read at one candidate since, 2.6 % off at 1 s)."""
    on, off = _thresholds(seed % 1000)
    for step in ((7_000_000, factor), (None, 1.0)):
        events, frames = davis_recording(W, H, 10_000_000, seed=seed, theta_on=on, theta_off=off, exposure_us=10_000,
                                         pan_px_s=(30.0, -8.0), wobble_px=6.0, black_level=16.0, threshold_step=step)
        estimator = FrameThresholdEstimator(W, H, max_fit=0.1, interval_us=500_000, black_level="fit")
        estimator.process(evtools.make_events(events["t"], events["x"], events["y"], events["p"]))
        estimator.add_frames([evtools.Frame(image, (b + e) // 2, b, e) for b, e, image in frames])
        result = estimator.result()
        if step[0] is None:
            assert result.attributes["steps_seen"] == 0
            continue
        series = result.series
        assert result.attributes["steps_seen"] == 1 and result.attributes["steps_us"][0] in _first_maps_after(series)
        after = [k for k, t_us in enumerate(series.t_us) if t_us >= 9_000_000 and series.valid[k].sum() >= 100]
        assert after, "no map with 100 pixels valid two seconds after the step"
        valid = series.valid[after[0]]
        for estimated, true in ((series.on[after[0]], on), (series.off[after[0]], off)):
            assert abs(np.median(estimated[valid] / (true[valid] * factor)) - 1) <= 0.06, factor


def test_online_forgetting_is_the_same_whenever_the_weights_start_again(monkeypatch):
    """onEI forgets lazily (each frame added with a weight growing as exp(t / forget), the sums read divided by it,
    see ``_forget``): with the weights started again from 1 every few frames (MAX_WEIGHT 3 instead of 1e100) the
    maps, the fit, the steps seen and the valid pixels are those of the default, a step's restart included."""
    import evtools.estimation_frames as frames_module

    on, off = _thresholds(5)
    events, frames = davis_recording(W, H, 5_000_000, seed=5, theta_on=on, theta_off=off, exposure_us=10_000,
                                     pan_px_s=(30.0, -8.0), wobble_px=6.0, black_level=0.0,
                                     threshold_step=(2_500_000, 1.3))
    results = []
    for max_weight in (frames_module.MAX_WEIGHT, 3.0):
        monkeypatch.setattr(frames_module, "MAX_WEIGHT", max_weight)
        estimator = FrameThresholdEstimator(W, H, max_fit=0.1, interval_us=500_000)
        estimator.process(evtools.make_events(events["t"], events["x"], events["y"], events["p"]))
        estimator.add_frames([evtools.Frame(image, (b + e) // 2, b, e) for b, e, image in frames])
        results.append(estimator.result())
    default, restarted = results
    assert default.attributes["steps_us"] == restarted.attributes["steps_us"] and default.attributes["steps_seen"] == 1
    np.testing.assert_array_equal(default.series.valid, restarted.series.valid)
    assert default.series.valid[-1].sum() >= 100
    for key in ("on", "off", "fit"):
        np.testing.assert_allclose(getattr(default.series, key), getattr(restarted.series, key), rtol=1e-4)


@settings(max_examples=1, deadline=None)  # (and the example: 40 s a run)
@given(seed=st.integers(0, 2**32 - 1), factor=st.sampled_from([1.3, 1 / 1.3]))
@example(seed=322, factor=1 / 1.3)  # a scene that shows the step slowly: 3.4, 4.0, 3.0 % (seen at 10.5 s before the
def test_online_maps_recover_from_a_threshold_step(seed, factor):  # two-maps rule; CI drew its x1.3: 3.9, 8.8 %)
    """onEI (0.5 s maps, 1.5 s memory) on the independent generator, every threshold stepping x1.3 or /1.3 at 7 s:
    the step is seen in the first or second map after it (the short memory against the long one: in the first, at
    0.53 s, in 16 of 18 runs, its shift 5.3-10.7 % against STEP_SHARE's 5 %; seed 322's scene shows it slowly, 3.9 %
    (x1.3) and 3.4 % (/1.3) at the first map: seen at the second, by the shift beyond STEP_SHARE_TWICE in both),
    and from two seconds after it each map's median ratio to the new thresholds is within 5.5 %. Measured over 18
    runs (seeds 1-8 and 322 x both steps): at 2 s 0.1-3.2 % off (within 3 % in 17; mean 1.3 %), every later map
    within 3.4 % (the 1.5 s memory's own noise; seed 322 /1.3 8.4 % at 2 s when its step was seen at 10.5 s); with
    the long memory restarted from the short one at full weight (its frames from before the step unaged): 0.6-4.4 %
    at 2 s (mean 1.9 %) and 6-17 % off on up to 262 valid pixels in the first map after the step; before the step
    detection, with the drift correction alone: 0.5-5.7 % at 2 s then an overshoot to 6.9 %; with neither,
    6.2-10.9 % at 2 s."""
    on, off = _thresholds(seed % 1000)
    events, frames = davis_recording(W, H, 14_000_000, seed=seed, theta_on=on, theta_off=off, exposure_us=10_000,
                                     pan_px_s=(30.0, -8.0), wobble_px=6.0, black_level=0.0,
                                     threshold_step=(7_000_000, factor))
    estimator = FrameThresholdEstimator(W, H, max_fit=0.1, interval_us=500_000)
    estimator.process(evtools.make_events(events["t"], events["x"], events["y"], events["p"]))
    estimator.add_frames([evtools.Frame(image, (b + e) // 2, b, e) for b, e, image in frames])
    result = estimator.result()
    series = result.series
    assert result.attributes["steps_seen"] == 1 and result.attributes["steps_us"][0] in _first_maps_after(series)
    checked = 0
    for k, t_us in enumerate(series.t_us):
        valid = series.valid[k]
        if t_us < 9_000_000 or valid.sum() < 100:
            continue
        for estimated, true in ((series.on[k], on), (series.off[k], off)):
            assert abs(np.median(estimated[valid] / (true[valid] * factor)) - 1) <= 0.055, (t_us, factor)
        checked += 1
    assert checked >= 8


def test_an_online_frames_run_ends_with_its_summary(tmp_path):
    """`estimate --method frames --online` (the README's drift command) ended every good run with a KeyError
    traceback, exit 1, though its maps file was whole (a QA sweep): exit 0, the summary names the maps."""
    stream, truth, out = tmp_path / "d.aedat4", tmp_path / "d.truth.h5", tmp_path / "d.h5"
    run("simulate", "scene:texture", "--size", "32x24", "--duration", "12s", "--seed", "8", "--speed", "200",
        "--aps-rate", "25", "--aps-exposure", "10ms", "--truth", truth, "-o", stream)
    done = run("estimate", stream, "--method", "frames", "--online", "--interval", "2s", "-o", out, check=False)
    assert done.returncode == 0 and b"Traceback" not in done.stderr, done.stderr
    written = read_thresholds(str(out), series=True)
    assert b"%d maps over time" % len(written.t_us) in done.stderr and "partial" not in written.attributes
    assert written.attributes["maps"] == len(written.t_us)


@settings(max_examples=2, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), too_low_dn=st.floats(8, 24), exposure_ms=st.integers(10, 20))
@example(seed=6, too_low_dn=16.0, exposure_ms=10)  # (the slope -6.1 +- 2.5: not said by it)
@example(seed=4, too_low_dn=16.0, exposure_ms=20)
def test_a_black_level_too_low_is_said_and_no_pixel_left_valid_by_it(seed, too_low_dn, exposure_ms):
    """Frames not black-subtracted read with the default black level 0 (here: the recording's black 20 + d DN, the
    estimator told 20): 65-100 % of the valid pixels were more than 10 % off, their fits unaware (a QA sweep). The
    thresholds' dependence on brightness across the pixels says it where it shows, and the fits then take its bias:
    no valid pixel more than 10 % off; with the black level right, nothing is said. It does not always show (seed 6:
    slopes -2.8 +- 2.2 DN at 8 DN too low, -6.1 +- 2.5 at 16 with 10 ms exposures, found by hypothesis), and on
    evtools' simulator never (+1.3 DN at 16 too low, a later QA sweep): the level given is also checked against a fit
    of it when the frames' floor lies far above it (the fits take the excess's bias, and it is said), so the valid
    pixels hold either way from 16 DN too low (the fit reads 0.5-12 DN low on this generator, so below that it may
    miss: 8 DN with seed 1, 19 ms exposures left 1,365 of 2,180 valid pixels off, and 12 DN with seed 4, 20 ms, found
    20.4 for 32, 1,232 valid, 95 % of them off, neither saying it; one draw in five at 12 DN)."""
    from tests.naive.davis import davis_recording

    width, height = 64, 48  # (the slope's standard error needs a few thousand pixels)
    rng = np.random.default_rng(seed % 1000)
    on, off = (np.clip(0.2 + 0.03 * rng.standard_normal((height, width)), 0.08, None) for _ in range(2))
    for error_dn in (too_low_dn, 0.0):
        events, frames = davis_recording(width, height, 5_000_000, seed=seed, theta_on=on, theta_off=off,
                                         black_level=20.0 + error_dn, exposure_us=exposure_ms * 1000,
                                         pan_px_s=(30.0, -8.0), wobble_px=6.0)
        estimator = FrameThresholdEstimator(width, height, black_level=20.0)
        estimator.process(evtools.make_events(events["t"], events["x"], events["y"], events["p"]))
        estimator.add_frames([evtools.Frame(image, (b + e) // 2, b, e) for b, e, image in frames])
        result = estimator.result()
        worst = np.maximum(np.abs(result.on / on - 1), np.abs(result.off / off - 1))
        said = "brightness_dependence" in result.attributes or "black_level_disagrees" in result.attributes
        if error_dn >= 16 or (error_dn > 0 and said):  # (below 16 DN the check's fit, 0.5-12 DN low here, may miss)
            assert (worst[result.valid] > 0.10).sum() <= 0.05 * max(result.valid.sum(), 1), result.attributes
            assert said or result.valid.mean() < 0.05, result.attributes
            if "brightness_dependence" in result.attributes and "black_level_disagrees" not in result.attributes:
                assert result.attributes["brightness_slope_dn"] < -BRIGHTNESS_SLOPE_DN
        elif error_dn == 0:
            assert not said, result.attributes
            assert result.valid.mean() > 0.3 and (worst[result.valid] > 0.10).mean() < 0.05


def test_a_black_level_given_wrong_on_evtools_simulator_is_refused(tmp_path):
    """A QA sweep: frames with a 16 DN black level estimated with --black-level 0 gave 79 % valid pixels, 99.8 % of
    them more than 10 % off, exit 0 (the brightness slope +1.3 DN here); now the level given is checked against the
    frames (their floor far above it) and no pixel stays valid: one line naming the level found. Given right, the
    check says nothing and the map is made."""
    out = tmp_path / "b16.aedat4"
    run("simulate", "scene:texture", "--size", "64x48", "--duration", "6s", "--seed", "3", "--speed", "200",
        "--aps-rate", "25", "--aps-exposure", "10ms", "--aps-black-level", "16", "-o", out)
    done = run("-q", "estimate", out, "--method", "frames", "--black-level", "0", "-o", tmp_path / "t.h5", check=False)
    assert_clean_error(done, "b16.aedat4", "above the 0 given")
    found = int(re.search(r"black level looks about (\d+) DN", done.stderr.decode()).group(1))
    assert abs(found - 16) <= 3, found
    done = run("estimate", out, "--method", "frames", "--black-level", "16", "-o", tmp_path / "t.h5")
    assert b"warning" not in done.stderr
    with h5py.File(tmp_path / "t.h5") as f:
        assert abs(f.attrs["black_level_fitted_dn"] - 16) < 5 and f.attrs["black_level_used"] == 16
        assert f["valid"][()].sum() > 100  # (6 s of frames: a few hundred pixels fit well enough)


@settings(max_examples=2, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), black_dn=st.sampled_from([0.0, 12.0, 16.0, 24.0]),
       exposure_ms=st.integers(10, 20))
@example(seed=1, black_dn=0.0, exposure_ms=15)
@example(seed=2, black_dn=16.0, exposure_ms=12)
@example(seed=0, black_dn=12.0, exposure_ms=19)
@example(seed=1, black_dn=12.0, exposure_ms=18)  # (found 6.8 DN: 12.9 % of the valid pixels 10 % off)
def test_a_black_level_not_given_is_fitted_when_the_frames_floor_says_so(seed, black_dn, exposure_ms):
    """A QA sweep: frames not black-subtracted (a 16 DN black level) read with the default 0 made 99.7 % of the
    valid pixels more than 10 % off, fits under 3.5 %, and nothing was said. Not given (None, as the command line
    passes it), the black level is now fitted when the first frame's floor is 8 DN or more, and used when the fit
    finds it 6 DN or more (said in black_level_fitted), as `--black-level fit` would: at most 15 % of the valid
    pixels 10 % off (the fit is approximate and reads low on this generator: seed 0 at 12 DN found 6.9, 5.8 % of them
    off; seed 1 with 18 ms exposures 6.8, 12.9 %, a CI draw; left at 0, all of them). Where the fit finds it near 0 the
    map is the default's, bit for bit."""
    width, height = 64, 48
    rng = np.random.default_rng(seed % 1000)
    on, off = (np.clip(0.2 + 0.03 * rng.standard_normal((height, width)), 0.08, None) for _ in range(2))
    events, frames = davis_recording(width, height, 5_000_000, seed=seed, theta_on=on, theta_off=off,
                                     black_level=black_dn, exposure_us=exposure_ms * 1000, pan_px_s=(30.0, -8.0),
                                     wobble_px=6.0)
    results = {}
    said_lines = []
    handler = logging.Handler()
    handler.emit = lambda record: said_lines.append(record.getMessage())
    logger = logging.getLogger("evtools")
    logger.addHandler(handler)
    level = logger.level
    logger.setLevel(logging.INFO)
    try:
        for said in (None, 0.0):
            estimator = FrameThresholdEstimator(width, height, black_level=said)
            estimator.process(evtools.make_events(events["t"], events["x"], events["y"], events["p"]))
            estimator.add_frames([evtools.Frame(image, (b + e) // 2, b, e) for b, e, image in frames])
            results[said] = estimator.result()
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    auto = results[None]
    assert auto.attributes["frames_floor_dn"] >= black_dn - 5  # (read noise and offsets below the black level)
    fitting_said = [line for line in said_lines if "the black level is fitted over" in line]
    assert len(fitting_said) == (auto.attributes["frames_floor_dn"] >= 8)  # (its cost said, once, only then)
    if "black_level_fitted" in auto.attributes:
        assert auto.attributes["black_level_used"] >= 6.0
        worst = np.maximum(np.abs(auto.on / on - 1), np.abs(auto.off / off - 1))[auto.valid]
        assert (worst > 0.10).sum() <= 0.15 * max(auto.valid.sum(), 1), (worst > 0.10).mean()
    else:
        assert black_dn < 12  # (a black level of 12 DN or more is found)
        np.testing.assert_array_equal(auto.on, results[0.0].on)
        np.testing.assert_array_equal(auto.valid, results[0.0].valid)
