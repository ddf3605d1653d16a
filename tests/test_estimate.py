"""Threshold estimation (``evtools estimate``): kernels against the naive references, chunking, pixel order,
dead pixels, exactness on an ideal pixel, accuracy on the report's scenes, the CLI and its errors."""

from __future__ import annotations

import array
import fcntl
import json
import math
import subprocess
import sys
import termios
import time
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import evtools
from evtools.estimation import DEFAULT_MAX_FIT, EstimationError, Stimulus, ThresholdEstimator, estimate_thresholds
from evtools.events import empty_events, make_events
from evtools.metrics.thresholds import threshold_errors
from evtools.simulation import DvsSimulator, scene_frames
from evtools.events import StreamInfo
from evtools.formats import create_events
from evtools.formats.thresholds import ThresholdMap, read_thresholds, write_thresholds
from tests.helpers import assert_clean_error, cut, random_events, read_all, run
from tests.naive.ideal_pixel import ideal_events, triangle_corners
from tests.conftest import data_file
from tests.naive.estimate import (
    neighbour_ages_naive,
    naive_fit,
    naive_fitted_stimulus,
    naive_natural,
    naive_offe,
    naive_stimulus,
    robust_mean,
)

W, H = 32, 24
FLICKER = Stimulus(50.0, 200.0, 500_000.0)
GRADIENT = Stimulus.moving(50.0, 200.0, 50.0, 64.0)


def simulate(scene: str, width=W, height=H, duration_us=2_000_000, seed=0, **parameters):
    """(events, simulator) of a built-in scene with an ideal pixel (no leak, no noise) unless told otherwise."""
    parameters = {"sigma_thres": 0.03, "leak_rate_hz": 0.0, **parameters}
    simulator = DvsSimulator(width, height, seed=seed, **parameters)
    chunks = [simulator.process(t, frame) for t, frame in scene_frames(scene, width, height, duration_us)]
    chunks.append(simulator.flush())
    return np.concatenate(chunks, dtype=chunks[0].dtype), simulator


@pytest.fixture(scope="module")
def flicker():
    return simulate("flicker")


@pytest.fixture(scope="module")
def gradient():
    return simulate("gradient")


def rel_rmse(estimate, simulator):
    errors = threshold_errors(estimate.on, estimate.off, estimate.valid, simulator.on_thres, simulator.off_thres)
    return errors["on"]["rel_rmse"], errors["off"]["rel_rmse"]


def assert_same_estimate(a, b):
    for name in ("on", "off", "valid"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert (a.fit is None) == (b.fit is None)
    if a.fit is not None:
        np.testing.assert_array_equal(a.fit, b.fit, err_msg="fit")


# -- kernels against the naive references --------------------------------------------------------------------


def test_offe_matches_the_reference_steps(flicker):
    events, _ = flicker
    for segment_us in (7_000, 50_000):
        estimate = estimate_thresholds(events, W, H, "offe", max_fit=math.inf, segment_us=segment_us)
        on, off, valid, _, _ = naive_offe(events, W, H, segment_us)
        np.testing.assert_array_equal(estimate.valid, valid)
        np.testing.assert_allclose(estimate.on[valid], on[valid], rtol=1e-6)
        np.testing.assert_allclose(estimate.off[valid], off[valid], rtol=1e-6)


def test_offe_on_random_events_matches_the_reference():
    events = random_events(20_000, 6, 5, seed=3)
    estimate = estimate_thresholds(events, 6, 5, "offe", segment_us=5_000, max_fit=math.inf)
    on, off, valid, _, _ = naive_offe(events, 6, 5, 5_000)
    np.testing.assert_array_equal(estimate.valid, valid)
    np.testing.assert_allclose(estimate.on[valid], on[valid], rtol=1e-6)


@pytest.mark.parametrize("stimulus", [FLICKER, GRADIENT, Stimulus(3.4, 5.4, 300_000, 40.0, "log", 0.3),
                                      Stimulus(50, 200, 333_333.5, rise=0.8)])
def test_stimulus_with_given_phases_matches_the_reference(gradient, stimulus):
    events, _ = gradient
    # the stream is the gradient's: only GRADIENT describes it; with no fit limit every method's sums still match
    estimate = estimate_thresholds(events, W, H, "stimulus", stimulus=stimulus, phase="given", min_events=1,
                                   max_fit=math.inf)
    described = (stimulus.low, stimulus.high, stimulus.period_us, stimulus.wavelength_px, stimulus.profile,
                 stimulus.rise)
    changes = naive_stimulus(events, W, H, *described)
    fits = naive_fit(events, W, H, *described)
    checked = 0
    for (x, y), (on, off) in changes.items():
        if on and off:
            assert estimate.valid[y, x]
            assert estimate.on[y, x] == pytest.approx(robust_mean(on), rel=1e-6)  # float32 maps
            assert estimate.off[y, x] == pytest.approx(robust_mean(off), rel=1e-6)
            assert estimate.fit[y, x] == pytest.approx(fits[x, y], rel=1e-5, abs=1e-6)
            checked += 1
    assert checked > W * H // 2
    fitting = estimate.fit[estimate.valid] <= DEFAULT_MAX_FIT
    if stimulus is GRADIENT:  # the stimulus the stream shows: every pixel fits (ideal pixels: to rounding)
        assert fitting.all() and np.median(estimate.fit[estimate.valid]) < 1e-3
    else:  # another stimulus: (nearly) no pixel fits
        assert fitting.mean() < 0.1


def test_flicker_table_gives_the_same_levels_as_the_formula(flicker, monkeypatch):
    """The one-period table (no log per event) and the per-event formula agree bit for bit, over many periods."""
    import evtools.estimation as module

    events, _ = flicker
    tabulated = estimate_thresholds(events, W, H, "stimulus", stimulus=FLICKER, phase="given")
    monkeypatch.setattr(module, "MAX_TABLE_US", 0)
    computed = estimate_thresholds(events, W, H, "stimulus", stimulus=FLICKER, phase="given")
    assert_same_estimate(tabulated, computed)


def test_log_amplitude_base_level_does_not_matter():
    """A log triangle of amplitude A: thresholds are differences of L, so L0..L0+A gives those of 0..A."""
    events = ideal_log_events(amplitude=1.5, period_us=400_000, duration_us=1_600_000)[0]
    base = estimate_thresholds(events, 8, 6, "stimulus", stimulus=Stimulus.log_triangle(1.5, 400_000))
    for level in (-2.0, 4.0):
        shifted = estimate_thresholds(events, 8, 6, "stimulus", stimulus=Stimulus(level, level + 1.5, 400_000, 0, "log"))
        np.testing.assert_array_equal(shifted.valid, base.valid)
        np.testing.assert_allclose(shifted.on, base.on, rtol=1e-6)
        np.testing.assert_allclose(shifted.off, base.off, rtol=1e-6)


def ideal_log_events(amplitude, period_us, duration_us, width=8, height=6, seed=1):
    """An ideal pixel (reference = L at its last event) under a log triangle 0..amplitude; per-pixel thresholds
    0.2 +/- 0.03; event times are the exact crossing times rounded to the microsecond."""
    rng = np.random.default_rng(seed)
    on = np.clip(0.2 + 0.03 * rng.standard_normal((height, width)), 0.1, None)
    off = np.clip(0.2 + 0.03 * rng.standard_normal((height, width)), 0.1, None)
    slope = 2 * amplitude / period_us  # L per microsecond on either ramp
    rows = []
    for yy in range(height):
        for xx in range(width):
            reference = 0.0
            for ramp in range(int(np.ceil(2 * duration_us / period_us))):
                start, rising = ramp * period_us / 2, ramp % 2 == 0
                while True:
                    target = reference + on[yy, xx] if rising else reference - off[yy, xx]
                    if not 0 <= target <= amplitude:
                        break
                    time_us = start + (target if rising else amplitude - target) / slope
                    if time_us >= duration_us:
                        break
                    rows.append((round(time_us), xx, yy, rising))
                    reference = target
    rows.sort(key=lambda r: r[0])
    t, x, y, p = zip(*rows)
    return make_events(np.array(t), np.array(x), np.array(y), np.array(p)), on, off


def test_stimulus_amplitude_is_exact_on_an_ideal_pixel():
    events, on, off = ideal_log_events(amplitude=1.5, period_us=400_000, duration_us=1_600_000)
    estimate = estimate_thresholds(events, 8, 6, "stimulus", stimulus=Stimulus.log_triangle(1.5, 400_000))
    assert estimate.valid.all()
    assert np.max(np.abs(estimate.on - on) / on) < 1e-3
    assert np.max(np.abs(estimate.off - off) / off) < 1e-3


# -- chunking and pixel order ----------------------------------------------------------------------------------


def _estimate_chunked(events, method, parts, **parameters):
    estimator = ThresholdEstimator(W, H, method, **parameters)
    for part in parts:
        assert len(estimator.process(part)) == 0
    assert len(estimator.flush()) == 0
    return estimator.result()


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.integers(min_value=0, max_value=10**9), max_size=6),
       method=st.sampled_from(["offe", "stimulus", "given", "gradient"]))
def test_chunking_does_not_change_the_estimate(flicker, cuts, method):
    events, _ = flicker
    parameters = {"offe": {"segment_us": 3_000}, "stimulus": {"stimulus": FLICKER},
                  "given": {"stimulus": FLICKER, "phase": "given"},
                  "gradient": {"stimulus": GRADIENT, "max_fit": math.inf}}[method]  # (not the stream's stimulus)
    method = "offe" if method == "offe" else "stimulus"
    whole = _estimate_chunked(events, method, [events], **parameters)
    chunked = _estimate_chunked(events, method, cut(events, cuts), **parameters)
    assert_same_estimate(chunked, whole)
    assert chunked.attributes == whole.attributes


@pytest.mark.parametrize("method", ["offe", "stimulus"])
def test_estimate_does_not_depend_on_the_order_of_pixels(flicker, method):
    events, _ = flicker
    rng = np.random.default_rng(5)
    permutation = rng.permutation(W * H)  # pixel i goes to pixel permutation[i]
    index = events["y"].astype(np.int64) * W + events["x"]
    moved = events.copy()
    moved["x"], moved["y"] = permutation[index] % W, permutation[index] // W
    # offE's own estimate is per pixel; its validity is checked against the natural method's, which compares
    # neighbours: that check (max_fit) is left out here
    parameters = {"stimulus": FLICKER} if method == "stimulus" else {"max_fit": math.inf}
    a = estimate_thresholds(events, W, H, method, **parameters)
    b = estimate_thresholds(moved, W, H, method, **parameters)
    for name in ("on", "off", "valid"):
        expected = np.empty(W * H, dtype=getattr(a, name).dtype)
        expected[permutation] = getattr(a, name).reshape(-1)
        np.testing.assert_array_equal(getattr(b, name).reshape(-1), expected, err_msg=name)


# -- validity, exactness, accuracy -----------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["offe", "stimulus"])
def test_dead_pixels_are_invalid_and_get_the_median(method):
    events, simulator = simulate("flicker", 16, 12, dead_pixel_fraction=0.1, seed=2)
    dead = simulator.dead_pixels
    assert dead.any()
    estimate = estimate_thresholds(events, 16, 12, method, stimulus=FLICKER)
    assert not estimate.valid[dead].any()
    assert estimate.valid[~dead].mean() > 0.9
    assert np.all(estimate.on[dead] == np.float32(np.median(estimate.on[estimate.valid])))
    assert np.all(estimate.off[dead] == np.float32(np.median(estimate.off[estimate.valid])))


@pytest.mark.parametrize("phase", ["fit", "given"])
@pytest.mark.parametrize("scene,stimulus", [("flicker", FLICKER), ("gradient", GRADIENT)])
def test_stimulus_is_exact_on_an_ideal_pixel(scene, stimulus, phase, flicker, gradient):
    events, simulator = flicker if scene == "flicker" else gradient
    estimate = estimate_thresholds(events, W, H, "stimulus", stimulus=stimulus, phase=phase)
    assert estimate.valid.all()
    for est, true in ((estimate.on, simulator.on_thres), (estimate.off, simulator.off_thres)):
        assert np.max(np.abs(est - true) / true) < 1e-3


@pytest.mark.parametrize("scene,stimulus", [("flicker", FLICKER), ("gradient", GRADIENT)])
def test_best_method_within_2_percent_and_offe_beats_a_constant_guess(scene, stimulus, flicker, gradient):
    events, simulator = flicker if scene == "flicker" else gradient
    # offE's estimates are valid only where its fit could check them against the natural method's; on the
    # gradient none can be (issue 36): refused saying so, and taken unchecked with max_fit inf
    unchecked = {"max_fit": math.inf} if scene == "gradient" else {}
    if scene == "gradient":
        with pytest.raises(EstimationError, match="could be checked"):
            estimate_thresholds(events, W, H, "offe")
    best = min(max(rel_rmse(estimate_thresholds(events, W, H, m, stimulus=stimulus,
                                                **(unchecked if m == "offe" else {})), simulator))
               for m in ("offe", "stimulus"))
    assert best <= 0.02
    offe = rel_rmse(estimate_thresholds(events, W, H, "offe", **unchecked), simulator)
    constant = ThresholdEstimateLike(np.full((H, W), 0.2), np.full((H, W), 0.2), np.ones((H, W), bool))
    guess = rel_rmse(constant, simulator)
    assert offe[0] < guess[0] and offe[1] < guess[1]


class ThresholdEstimateLike:
    def __init__(self, on, off, valid):
        self.on, self.off, self.valid = on, off, valid


def test_parameters_are_checked():
    for kwargs in ({"method": "nope"}, {"nominal": 0}, {"segment_us": 0}, {"min_events": 0}, {"method": "stimulus"}):
        with pytest.raises(EstimationError):
            ThresholdEstimator(W, H, **kwargs)
    for bad in ((200, 50, 1000), (-1, 50, 1000), (0, 1, 0), (0, 1, 1000, -1), (1, 2, 1000, 0, "gamma")):
        with pytest.raises(EstimationError):
            Stimulus(*bad)
    Stimulus(-3, -1, 1000, 0, "log")  # log levels may be negative
    with pytest.raises(EstimationError):
        Stimulus.log_triangle(0, 1000)
    with pytest.raises(EstimationError):
        estimate_thresholds(empty_events(), W, H)


# -- the CLI ---------------------------------------------------------------------------------------------------


def write_stream(path, events, width=W, height=H):
    with create_events(str(path), StreamInfo(width, height)) as writer:
        writer.write(events)


def test_cli_writes_maps_and_attributes(tmp_path, flicker):
    events, simulator = flicker
    write_stream(tmp_path / "f.aedat4", events)
    run("estimate", tmp_path / "f.aedat4", "-o", tmp_path / "t.h5", "--method", "stimulus",
        "--stimulus-levels", "50,200", "--stimulus-period", "500ms")
    result = read_thresholds(str(tmp_path / "t.h5"))
    assert result.on.shape == (H, W) and result.valid.all()
    np.testing.assert_allclose(result.on, simulator.on_thres, rtol=1e-3)
    with h5py.File(tmp_path / "t.h5") as h5:
        assert h5.attrs["method"] == "stimulus" and h5.attrs["events"] == len(events)
        assert (h5.attrs["width"], h5.attrs["height"]) == (W, H)
    # stdin, offe
    run("estimate", "-", "-o", tmp_path / "o.h5", "--segment-us", "20000",
        input=(tmp_path / "f.aedat4").read_bytes())
    with h5py.File(tmp_path / "o.h5") as h5:
        assert h5.attrs["method"] == "offe" and h5.attrs["segment_us"] == 20000


def test_cli_errors(tmp_path, flicker):
    events, _ = flicker
    write_stream(tmp_path / "f.aedat4", events)
    write_stream(tmp_path / "empty.aedat4", empty_events())
    write_stream(tmp_path / "one.aedat4", make_events([5], [1], [1], [True]))
    out = tmp_path / "t.h5"
    assert_clean_error(run("estimate", tmp_path / "empty.aedat4", "-o", out, check=False), "no events")
    assert_clean_error(run("estimate", tmp_path / "one.aedat4", "-o", out, check=False), "longer than the stream")
    assert_clean_error(run("estimate", tmp_path / "f.aedat4", "-o", out, "--segment-us", "5000000", check=False),
                       "longer than the stream")
    assert_clean_error(run("estimate", tmp_path / "f.aedat4", "-o", out, "--segment-us", "1500000", check=False),
                       "segments")
    assert_clean_error(run("estimate", tmp_path / "empty.aedat4", "-o", out, "--method", "stimulus", check=False),
                       "no events")
    for args in (["-o", "-"], []):  # HDF5 needs a file: one line, before reading anything (a usage error, exit 2)
        done = run("estimate", tmp_path / "f.aedat4", *args, check=False)
        assert done.returncode == 2 and done.stderr.decode().count("\n") == 1 and b"-o THRESHOLDS.h5" in done.stderr
    assert not out.exists()
    stimulus = ["-o", out, "--method", "stimulus"]
    for args in (["-o", out, "--stimulus-levels", "9"], stimulus + ["--stimulus-speed", "5"],
                 stimulus + ["--stimulus-amplitude", "1", "--stimulus-levels", "0,1"],
                 stimulus + ["--stimulus-amplitude", "1", "--stimulus-profile", "intensity"],
                 stimulus + ["--stimulus-profile", "log"], stimulus + ["--stimulus-levels", "50,300"],
                 stimulus + ["--stimulus-amplitude", "0"], stimulus + ["--stimulus-rise", "1"],
                 stimulus + ["--stimulus-rise", "0"], stimulus + ["--stimulus-rise", "-0.2"],
                 stimulus + ["--stimulus-phase", "zero"]):
        result = run("estimate", tmp_path / "f.aedat4", *args, check=False)
        assert result.returncode == 2 and result.stdout == b"", args
        assert b"Traceback" not in result.stderr and b"--stimulus" in result.stderr or b"Usage" in result.stderr
    assert not out.exists()


def test_cli_fitted_phases_and_rise(tmp_path):
    """The CLI finds per-pixel phases by default (a sawtooth-like rise of 0.8, a random phase per pixel), writes the
    phase map; --stimulus-phase given on the same stream is refused as not fitting."""
    rng = np.random.default_rng(3)
    events, on, off = _triangle_stream(rng, 6, 4, 400_000, 1.5, 0.8, 3_200_000)
    write_stream(tmp_path / "s.aedat4", events, 6, 4)
    out = tmp_path / "t.h5"
    common = ["--method", "stimulus", "--stimulus-amplitude", "1.5", "--stimulus-period", "400ms",
              "--stimulus-rise", "0.8"]
    run("estimate", tmp_path / "s.aedat4", "-o", out, *common)
    estimate = read_thresholds(str(out))
    assert estimate.valid.all() and np.abs(estimate.on / on - 1).max() < 1e-3
    assert estimate.attributes["stimulus_rise"] == 0.8 and estimate.attributes["stimulus_phase"] == "fit"
    with h5py.File(out) as h5:
        phase_us = h5["phase_us"][()]
    assert phase_us.shape == (4, 6) and np.all((phase_us >= 0) & (phase_us < 400_000))
    assert np.unique(np.round(phase_us, -3)).size > 12  # the phases really differ from pixel to pixel
    refused = run("estimate", tmp_path / "s.aedat4", "-o", tmp_path / "g.h5", *common, "--stimulus-phase", "given",
                  check=False)
    assert_clean_error(refused, "s.aedat4", "do not fit the described stimulus")


def test_cli_stimulus_amplitude(tmp_path):
    events, on, off = ideal_log_events(amplitude=1.5, period_us=400_000, duration_us=1_600_000)
    write_stream(tmp_path / "log.aedat4", events, 8, 6)
    for name, args in (("a", ["--stimulus-amplitude", "1.5"]),
                       ("l", ["--stimulus-profile", "log", "--stimulus-levels", "2,3.5"])):
        run("estimate", tmp_path / "log.aedat4", "-o", tmp_path / f"{name}.h5", "--method", "stimulus",
            "--stimulus-period", "400ms", *args)
    a, levels = read_thresholds(str(tmp_path / "a.h5")), read_thresholds(str(tmp_path / "l.h5"))
    np.testing.assert_allclose(a.on, on, rtol=1e-3)
    np.testing.assert_allclose(levels.off, a.off, rtol=1e-6)
    with h5py.File(tmp_path / "a.h5") as h5:
        assert h5.attrs["stimulus_profile"] == "log" and h5.attrs["stimulus_log_amplitude"] == 1.5


def test_with_noise_and_bafilter_first_the_best_method_stays_within_3_percent(tmp_path):
    """The report's scheme: leak 0.1 Hz and shot noise 1 Hz added, `evtools bafilter` before `estimate`."""

    worst = {}
    for scene, stimulus_args in (("flicker", ["--stimulus-period", "500ms"]),
                                 ("gradient", ["--stimulus-speed", "50", "--stimulus-wavelength", "64"])):
        noisy, truth, kept = tmp_path / f"{scene}.aedat4", tmp_path / f"{scene}.h5", tmp_path / f"{scene}.f.aedat4"
        run("simulate", f"scene:{scene}", "--size", "32x24", "--duration", "2s", "--sigma-thres", "0.03",
            "--leak-rate-hz", "0.1", "--shot-noise-rate-hz", "1", "--seed", "0", "--truth", truth, "-o", noisy)
        filtered = run("bafilter", noisy, "-o", kept, "--method", "stcf", "--k", "1", "--dt-us", "100000",
                       check=False)
        if filtered.returncode != 0:
            pytest.skip(f"evtools bafilter is not available: {filtered.stderr.decode().strip()}")
        true = read_thresholds(str(truth))
        best = 1.0
        for method in ("offe", "stimulus"):
            out = tmp_path / f"{scene}.{method}.h5"
            unchecked = ["--max-fit", "inf"] if (scene, method) == ("gradient", "offe") else []  # see above
            run("estimate", kept, "-o", out, "--method", method, *stimulus_args, *unchecked)
            estimate = read_thresholds(str(out))
            if method == "stimulus":  # the noise left by the filter spoils few pixels' fit
                assert estimate.fit is not None and estimate.valid.mean() > 0.8, estimate.valid.mean()
                report = json.loads(run("metrics", "thresholds", out, "--truth", truth, "--json").stdout)
                assert report["rejected_by_fit"] == estimate.attributes["rejected_by_fit"]
            errors = threshold_errors(estimate.on, estimate.off, estimate.valid, true.on, true.off)
            best = min(best, max(errors["on"]["rel_rmse"], errors["off"]["rel_rmse"]))
        worst[scene] = best
    assert max(worst.values()) <= 0.03, worst


# -- goodness of fit decides validity (issue 13) ----------------------------------------------------------------


def _ideal_pixels(seed, corners_of, width=8, height=6):
    """Ideal pixels (tests/naive/ideal_pixel.py, not the simulator), thresholds 0.2 +- 0.03 drawn per pixel, each
    watching the log-intensity polyline ``corners_of(rng)`` gives it; the events and the thresholds."""
    rng = np.random.default_rng(seed)
    on = rng.normal(0.2, 0.03, (height, width)).clip(0.1)
    off = rng.normal(0.2, 0.03, (height, width)).clip(0.1)
    rows = []
    for j in range(height):
        for i in range(width):
            rows += [(math.floor(t + 0.5), i, j, p) for t, p in ideal_events(corners_of(rng), on[j, i], off[j, i])]
    rows.sort(key=lambda row: row[0])
    t, x, y, p = zip(*rows)
    return make_events(t, x, y, p), on, off


def _ideal_triangles(seed, period_us, phases, amplitude=1.5, rise=0.5, span_us=4_000_000):
    """Ideal pixels under a log triangle; per-pixel phases when ``phases``, else every pixel at its valley at t = 0
    (the stimulus method's convention)."""
    return _ideal_pixels(seed, lambda rng: triangle_corners(0, span_us, 0.0, amplitude, rise * period_us,
                                                             (1 - rise) * period_us,
                                                             rng.uniform(0, 1) if phases else 0.0))


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10**6), wrong=st.sampled_from([0.7, 0.8, 0.9, 1.1, 1.2, 1.3]), phases=st.booleans())
def test_a_stream_that_does_not_show_the_described_stimulus_gives_no_confident_values(seed, wrong, phases):
    period_us = 400_000
    events, on, off = _ideal_triangles(seed, period_us, phases)
    if not phases:  # the described stimulus: every pixel valid, exact to the microsecond rounding
        right = estimate_thresholds(events, 8, 6, "stimulus", stimulus=Stimulus.log_triangle(1.5, period_us))
        assert right.valid.all() and np.abs(right.on / on - 1).max() < 1e-3 and right.fit.max() < 0.01
    else:  # per-pixel phases: found from the events, exact; taken as given (all at the valley at t = 0), refused
        right = estimate_thresholds(events, 8, 6, "stimulus", stimulus=Stimulus.log_triangle(1.5, period_us))
        assert right.valid.mean() > 0.9 and np.abs(right.on / on - 1)[right.valid].max() < 1e-3
    for stimulus, phase in ([(Stimulus.log_triangle(1.5, period_us), "given")] if phases else []) + [
            (Stimulus.log_triangle(1.5, wrong * period_us), "fit"),
            (Stimulus.log_triangle(1.5, wrong * period_us), "given")]:
        try:
            estimate = estimate_thresholds(events, 8, 6, "stimulus", stimulus=stimulus, phase=phase)
        except EstimationError as error:
            assert "do not fit the described stimulus" in str(error)
            continue
        # the pixels it keeps are those whose events happen to fit: few, and their values are right
        assert estimate.valid.mean() <= 0.25
        kept = estimate.valid
        assert np.abs(estimate.on[kept] / on[kept] - 1).max() < 0.05
        assert np.abs(estimate.off[kept] / off[kept] - 1).max() < 0.05
        assert estimate.attributes["rejected_by_fit"] >= 1


def _ideal_intensity_triangles(seed, low, high, period_us, span_us=3_000_000):
    """Ideal pixels under a triangle linear in intensity from ``low`` to ``high`` (above the photoreceptor's knee,
    so log intensity is ln I), every pixel at its own phase: the intensity triangle's corners, each side cut into
    400 pieces in log intensity."""
    def corners_of(rng):
        corners = triangle_corners(0, span_us, low, high - low, period_us / 2, period_us / 2, rng.uniform(0, 1))
        dense = [(t0 + (t1 - t0) * k / 400, math.log(v0 + (v1 - v0) * k / 400))
                 for (t0, v0), (t1, v1) in zip(corners, corners[1:]) for k in range(400)]
        return dense + [(corners[-1][0], math.log(corners[-1][1]))]

    return _ideal_pixels(seed, corners_of)


@settings(max_examples=10, deadline=None)
# (ratios >= 2.1: a 3 s stream of 85..150 leaves a fifth of the pixels under 8 changes, unfitted)
@given(seed=st.integers(0, 10**6), low=st.floats(30, 70), high=st.floats(150, 250),
       wrong=st.sampled_from([0.5, 0.7, 0.8, 1.25, 1.4]))
def test_wrong_stimulus_levels_are_refused_not_called_valid(seed, low, high, wrong):
    """A triangle linear in intensity: with the levels given right every pixel is valid and exact; with the low
    level 20 % or more off (every threshold 10-50 % off) the estimate is refused, naming levels that fit (a QA
    sweep: levels 2x off gave 64-93 % valid pixels at 38-49 % error). Unchecked (max_fit inf) it still runs."""
    period_us = 400_000
    events, on, off = _ideal_intensity_triangles(seed, low, high, period_us)
    right = estimate_thresholds(events, 8, 6, "stimulus", stimulus=Stimulus(low, high, period_us))
    assert right.valid.mean() > 0.9 and np.abs(right.on / on - 1)[right.valid].max() < 0.01
    given_low = min(low * wrong, high / 1.2)
    stimulus = Stimulus(given_low, high, period_us)
    with pytest.raises(EstimationError) as refused:
        estimate_thresholds(events, 8, 6, "stimulus", stimulus=stimulus)
    assert "do not fit the described stimulus" in str(refused.value)
    if "levels near" in str(refused.value):  # the levels it names are nearer the truth than those given
        named = float(str(refused.value).split("levels near ")[1].split(",")[0])
        assert abs(math.log(named / low)) < abs(math.log(given_low / low))
    unchecked = estimate_thresholds(events, 8, 6, "stimulus", stimulus=stimulus, max_fit=math.inf)
    assert unchecked.valid.any()


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10**6), wrong=st.sampled_from([0.97, 0.98, 0.99, 1.01, 1.02, 1.03]),
       log=st.booleans())
@example(seed=151, wrong=1.02, log=True)  # (median deviation 0.0097: taken under the old floor of 0.01, 3.07 % off)
def test_a_wrong_stimulus_period_is_refused_not_called_valid(seed, wrong, log):
    """A period 2 % off (490 ms for 500 ms) called every pixel valid at 8.6 % error (a QA sweep): 1-3 % off, on
    ideal pixels under a triangle in intensity or in log intensity (phases per pixel, fitted), the estimate is
    refused and names a period nearer the truth (a log triangle, whose changes stay uniform: refused, or within
    the period's error + 1 %); the true one is valid and exact."""
    period_us = 400_000
    if log:
        events, on, off = _ideal_triangles(seed, period_us, phases=True)
        stimulus = Stimulus.log_triangle(1.5, period_us)
    else:
        events, on, off = _ideal_intensity_triangles(seed, 50.0, 200.0, period_us)
        stimulus = Stimulus(50.0, 200.0, period_us)
    right = estimate_thresholds(events, 8, 6, "stimulus", stimulus=stimulus)
    assert right.valid.mean() > 0.9 and np.abs(right.on / on - 1)[right.valid].max() < 0.01
    wrong_stimulus = replace(stimulus, period_us=period_us * wrong)
    if log:  # a triangle linear in log: a period p off rescales the thresholds by about p, as an amplitude would,
        try:  # and the changes stay uniform: refused, or every valid pixel within p + 1 % (1 % off: 1.75 %, 80 seeds)
            close = estimate_thresholds(events, 8, 6, "stimulus", stimulus=wrong_stimulus)
        except EstimationError:
            pass
        else:
            assert np.abs(close.on / on - 1)[close.valid].max() < abs(wrong - 1) + 0.01
            assert np.abs(close.off / off - 1)[close.valid].max() < abs(wrong - 1) + 0.01
            return
    with pytest.raises(EstimationError) as refused:
        estimate_thresholds(events, 8, 6, "stimulus", stimulus=wrong_stimulus)
    message = str(refused.value)
    assert "do not fit the described stimulus" in message
    if "a period near" in message:
        named = float(message.split("a period near ")[1].split(" ms")[0]) * 1e3
        assert abs(named - period_us) < abs(period_us * wrong - period_us)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10**6), rise=st.floats(0.35, 0.65), wrong=st.sampled_from([-0.15, -0.1, 0.1, 0.15]))
def test_a_wrong_stimulus_rise_is_refused_not_called_valid(seed, rise, wrong):
    """A QA sweep: a rise of 0.6 for 0.5 called every pixel valid, ON 10 % low and OFF 15 % high (median fit 0.035);
    0.4, 0.7 and 0.3 alike. On ideal pixels under log triangles of a random rise (per-pixel phases), the true rise
    gives exact values and a rise 0.1-0.15 off is refused, naming a rise nearer the truth."""
    period_us = 400_000
    events, on, off = _ideal_triangles(seed, period_us, phases=True, rise=rise)
    stimulus = Stimulus.log_triangle(1.5, period_us, rise=rise)
    right = estimate_thresholds(events, 8, 6, "stimulus", stimulus=stimulus)
    assert right.valid.mean() > 0.9 and np.abs(right.on / on - 1)[right.valid].max() < 0.01
    with pytest.raises(EstimationError) as refused:
        estimate_thresholds(events, 8, 6, "stimulus", stimulus=replace(stimulus, rise=rise + wrong))
    message = str(refused.value)
    assert "do not fit the described stimulus" in message and "--stimulus-rise" in message
    named = float(message.split("a rise near ")[1].split(" of the period")[0])
    assert abs(named - rise) < abs(wrong)


def test_a_natural_scene_is_no_stimulus(tmp_path, dvxplorer_events):
    """A real street scene, denoised as a calibration would be: not one pixel is claimed to fit the default flicker."""
    path = tmp_path / "street.aedat4"
    with create_events(str(path), StreamInfo(640, 480)) as sink:
        sink.write(dvxplorer_events)
    filtered = tmp_path / "filtered.aedat4"
    run("bafilter", path, "--method", "stcf", "--k", "1", "--dt-us", "100000", "-o", filtered)
    for extra in ([], ["--min-events", "3"]):
        result = run("estimate", filtered, "--method", "stimulus", "-o", tmp_path / "t.h5", *extra, check=False)
        assert_clean_error(result, "filtered.aedat4", "do not fit the described stimulus")
        assert not (tmp_path / "t.h5").exists()


# -- the phase found from each pixel's own events (issue 13, part 1) ------------------------------------------------


def _triangle_stream(rng, width, height, period_us, amplitude, rise, span_us, profile="log", levels=(50.0, 200.0)):
    """Ideal pixels (tests/naive/ideal_pixel.py) under a triangle of its own random phase each, thresholds
    0.2 +/- 0.03, times rounded to the microsecond. ``profile`` intensity: the triangle is linear in intensity
    from ``levels[0]`` to ``levels[1]`` and the pixel sees its log, as a dense polyline (a chord of 1/4000 of a
    ramp: 1e-6 of a threshold off the curve)."""
    on = rng.normal(0.2, 0.03, (height, width)).clip(0.1)
    off = rng.normal(0.2, 0.03, (height, width)).clip(0.1)
    rows = []
    for j in range(height):
        for i in range(width):
            phase = rng.uniform(0, 1)
            if profile == "log":
                corners = triangle_corners(0, span_us, 0.0, amplitude, rise * period_us, (1 - rise) * period_us, phase)
            else:
                linear = triangle_corners(0, span_us, levels[0], levels[1] - levels[0], rise * period_us,
                                          (1 - rise) * period_us, phase)
                corners = [(linear[0][0], math.log(linear[0][1]))]
                for (t0, v0), (t1, v1) in zip(linear, linear[1:]):
                    for k in range(1, 4001):
                        corners.append((t0 + (t1 - t0) * k / 4000, math.log(v0 + (v1 - v0) * k / 4000)))
            rows += [(math.floor(t + 0.5), i, j, p) for t, p in ideal_events(corners, on[j, i], off[j, i])]
    rows.sort(key=lambda row: row[0])
    t, x, y, p = zip(*rows)
    return make_events(t, x, y, p), on, off


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rise=st.floats(0.1, 0.9), amplitude=st.floats(0.8, 4.0),
       period_us=st.integers(100_000, 2_000_000), width=st.integers(2, 9), height=st.integers(1, 6))
def test_phases_found_from_the_events_give_exact_thresholds(seed, rise, amplitude, period_us, width, height):
    """Random per-pixel phases, rise fractions, amplitudes, periods and sizes: every pixel's phase is found from its
    own events; where the fit is under 0.5 % (at least 90 % of the valid pixels) the thresholds are exact to 0.1 %
    RMSE (only the microsecond rounding of the times remains: on the fastest ramps, up to 1 us in the shortest time
    between two events) and none is off by more than 1 %, a valid pixel with a wider fit is within 3 fits, and a
    pixel is left invalid only when its events never show two in a row of
    one polarity (changes across a turn are left out: a denoiser often removes the event after a turn)."""
    rng = np.random.default_rng(seed)
    events, on, off = _triangle_stream(rng, width, height, period_us, amplitude, rise, 6 * period_us)
    estimate = estimate_thresholds(events, width, height, "stimulus",
                                   stimulus=Stimulus.log_triangle(amplitude, period_us, rise=rise))
    valid = estimate.valid
    runs = np.zeros((height, width, 2), dtype=bool)  # per pixel: two ON in a row, two OFF in a row seen
    order = np.lexsort((events["t"], events["x"], events["y"]))
    ordered = events[order]
    same_pixel = (ordered["x"][1:] == ordered["x"][:-1]) & (ordered["y"][1:] == ordered["y"][:-1])
    for polarity in (True, False):
        run = same_pixel & (ordered["p"][1:] == polarity) & (ordered["p"][:-1] == polarity)
        runs[ordered["y"][1:][run], ordered["x"][1:][run], 0 if polarity else 1] = True
    # only changes within a ramp are counted; a pixel also needs 8 of them to show its fit
    assert not (valid & ~runs.all(axis=2)).any()
    assert (runs.all(axis=2) & ~valid).sum() <= estimate.attributes["rejected_by_fit"]
    assert valid.mean() >= 0.9 or amplitude < 1.0
    # the times' rounding (+-0.5 us) against the time between two events: on the fastest ramps (4 log units
    # rising in 12.5 ms, a threshold of 0.1: 312 us) it alone is 0.3 % of an interval
    # exact where the fit says so; a pixel whose fit is wider (a phase found slightly off on a near-sawtooth: one
    # in 27 pixels at rise 0.9, 0.84 % off with fit 0.017, found by hypothesis) is off by no more than its fit says
    exact = valid & (estimate.fit <= 0.005)
    for est, true, ramp_us in ((estimate.on, on, rise * period_us), (estimate.off, off, (1 - rise) * period_us)):
        relative = est[exact] / true[exact] - 1
        rounding = 1.0 / (true[valid].min() * ramp_us / amplitude) if valid.any() else 0.0
        if exact.any():
            assert np.sqrt(np.mean(relative**2)) <= max(1e-3, rounding)
            assert np.abs(relative).max() <= max(1e-2, 3 * rounding)
        wider = valid & ~exact
        assert (np.abs(est[wider] / true[wider] - 1) <= 3 * estimate.fit[wider] + max(1e-2, 3 * rounding)).all()
    assert exact.sum() >= 0.9 * valid.sum() - 1  # (a 2 x 2 sensor may have one wider pixel)


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rise=st.floats(0.2, 0.8), period_us=st.integers(200_000, 1_000_000))
def test_phases_found_on_a_triangle_in_intensity(seed, rise, period_us):
    """The simulator's kind of stimulus, linear in intensity (L = log I, so the slope of L changes along a ramp):
    the phase matters for every change, and is found to the same 0.1 %."""
    rng = np.random.default_rng(seed)
    events, on, off = _triangle_stream(rng, 4, 3, period_us, None, rise, 5 * period_us, "intensity")
    estimate = estimate_thresholds(events, 4, 3, "stimulus", stimulus=Stimulus(50.0, 200.0, period_us, rise=rise))
    assert estimate.valid.mean() >= 0.9
    for est, true in ((estimate.on, on), (estimate.off, off)):
        relative = est[estimate.valid] / true[estimate.valid] - 1
        assert np.sqrt(np.mean(relative**2)) <= 1e-3


@pytest.mark.parametrize("rise,profile", [(0.5, "log"), (0.3, "log"), (0.7, "intensity")])
def test_fitted_phases_match_the_brute_force_reference(rise, profile):
    """The kernel's phase search (turn brackets, a grid, golden section) against a brute-force search of the same
    cost over 200,000 phases (tests/naive/estimate.py): the same phase, so the same thresholds."""
    rng = np.random.default_rng(7)
    period_us = 300_000
    low, high = (0.0, 1.7) if profile == "log" else (50.0, 200.0)
    events, _, _ = _triangle_stream(rng, 3, 3, period_us, 1.7, rise, 5 * period_us, profile)
    stimulus = Stimulus(low, high, period_us, profile=profile, rise=rise)
    estimate = estimate_thresholds(events, 3, 3, "stimulus", stimulus=stimulus, min_events=1, max_fit=math.inf)
    reference = naive_fitted_stimulus(events, low, high, period_us, rise, profile)
    assert len(reference) == 9
    for (x, y), (valley_us, on, off) in reference.items():
        gap = abs((estimate.phase_us[y, x] - valley_us + period_us / 2) % period_us - period_us / 2)
        assert gap < 1.0, (x, y)  # within a microsecond (the cost is flat to the rounding of the times)
        assert estimate.on[y, x] == pytest.approx(robust_mean(on), rel=1e-5)
        assert estimate.off[y, x] == pytest.approx(robust_mean(off), rel=1e-5)


def test_a_moving_gradient_needs_only_its_period(gradient):
    """The simulator's gradient described by its period alone (no speed, wavelength or offset): every column's
    phase is found, and the thresholds are exact; the fitted phases advance by 1/64 period per column."""
    events, simulator = gradient
    flicker_like = Stimulus(50.0, 200.0, GRADIENT.period_us)
    estimate = estimate_thresholds(events, W, H, "stimulus", stimulus=flicker_like)
    assert estimate.valid.all()
    for est, true in ((estimate.on, simulator.on_thres), (estimate.off, simulator.off_thres)):
        assert np.max(np.abs(est - true) / true) < 1e-3
    step = np.diff(np.median(estimate.phase_us, axis=0)) % GRADIENT.period_us
    np.testing.assert_allclose(step, GRADIENT.period_us / 64, rtol=0.02)


# -- natural scenes ---------------------------------------------------------------------------------------------------


def _spread_events(seed, n, width, height, duration_us):
    """``n`` random events over ``duration_us`` (many of the natural method's 100 ms blocks)."""
    rng = np.random.default_rng(seed)
    return make_events(np.sort(rng.integers(0, duration_us, n)), rng.integers(0, width, n),
                       rng.integers(0, height, n), rng.integers(0, 2, n))


def _excursions(rng, turns):
    """Corners of a log-intensity signal that turns ``turns`` times, each excursion 0.1-1.2 log units at 0.5-5
    log units per second: what a pixel sees as edges of random contrast pass over it. Its falls are scaled to sum
    to its rises (a random walk drifts: one draw ended 14 log units down after 89 up), so that it ends where it
    began: a net rise or fall shared by every pixel is not observable from events (it reads as ON thresholds
    smaller or larger than OFF; README, ``evtools.estimation.NOT_OBSERVABLE``)."""
    sizes = rng.uniform(0.1, 1.2, turns)
    speeds = rng.uniform(0.5, 5.0, turns)
    sizes[1::2] *= sizes[0::2].sum() / max(sizes[1::2].sum(), 1e-9)
    t_us, level, corners = 0.0, 0.0, [(0.0, 0.0)]
    for k in range(turns):
        level += sizes[k] if k % 2 == 0 else -sizes[k]
        t_us += sizes[k] / speeds[k] * 1e6
        corners.append((t_us, level))
    return corners


def _natural_stream(seed, width, height, sigma, turns, shared):
    """Ideal pixels (tests/naive/ideal_pixel.py), thresholds 0.2 +/- sigma, each watching the same random signal
    (``shared``) or one of its own with the same statistics."""
    rng = np.random.default_rng(seed)
    on = rng.normal(0.2, sigma, (height, width)).clip(0.08)
    off = rng.normal(0.2, sigma, (height, width)).clip(0.08)
    common = _excursions(rng, turns)
    rows = []
    for j in range(height):
        for i in range(width):
            corners = common if shared else _excursions(np.random.default_rng([seed, i, j]), turns)
            rows += [(math.floor(t + 0.5), i, j, p) for t, p in ideal_events(corners, on[j, i], off[j, i])]
    rows.sort(key=lambda row: row[0])
    t, x, y, p = zip(*rows)
    return make_events(t, x, y, p), on, off


def test_natural_matches_the_plain_python_reference():
    """Counts, reversals, the turns' share and the neighbours' mean against tests/naive/estimate.py."""
    events = _spread_events(3, 30_000, 13, 11, 3_000_000)
    estimate = estimate_thresholds(events, 13, 11, "natural", max_fit=math.inf, min_events=5, radius_px=2)
    on, off, usable = naive_natural(events, 13, 11, radius_px=2, min_events=5)
    assert usable.sum() > 100
    np.testing.assert_array_equal(estimate.valid, usable)
    np.testing.assert_allclose(estimate.on[usable], on[usable], rtol=1e-6)  # float32 maps
    np.testing.assert_allclose(estimate.off[usable], off[usable], rtol=1e-6)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cuts=st.lists(st.integers(0, 10**6), max_size=6))
def test_natural_does_not_depend_on_chunking(seed, cuts):
    events = _spread_events(seed, 5_000, 9, 7, 1_000_000)
    whole = ThresholdEstimator(9, 7, "natural", min_events=3, max_fit=math.inf)
    whole.process(events)
    chunked = ThresholdEstimator(9, 7, "natural", min_events=3, max_fit=math.inf)
    for part in cut(events, cuts):
        chunked.process(part)
    a, b = whole.result(), chunked.result()
    for name in ("on", "off", "valid", "fit"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), width=st.integers(9, 14), height=st.integers(8, 11),
       sigma=st.floats(0.03, 0.05), shared=st.booleans())
@example(seed=10, width=9, height=9, sigma=0.046875, shared=True)
def test_natural_scene_thresholds_from_counts(seed, width, height, sigma, shared):
    """Ideal pixels under 300 random excursions (about 700 events a pixel), all seeing one signal or each its
    own: every pixel valid, the relative RMSE under 15 % and at most 0.75x the constant guess's (its error is the
    spread itself), the fit map (the halves' disagreement) below its 25 % limit. (The bounds were 10 % and 0.6x,
    which about one draw in 15 exceeds: 60 draws of these parameters gave at most 12.3 % and 0.62x, both with one
    shared signal; hypothesis found seed 10 on 9 x 9 at 11.4 %.)"""
    events, on, off = _natural_stream(seed, width, height, sigma, 300, shared)
    estimate = estimate_thresholds(events, width, height, "natural")
    assert estimate.valid.all()
    for est, true in ((estimate.on, on), (estimate.off, off)):
        error = np.sqrt(np.mean((est / true - 1) ** 2))
        constant = np.sqrt(np.mean((0.2 / true - 1) ** 2))
        assert error <= 0.15 and error <= 0.75 * constant, (error, constant)
    assert np.nanmax(estimate.fit) <= 0.25


def test_natural_refuses_a_stream_too_short(tmp_path):
    """A few events a pixel: no confident values, an error that says why."""
    events = _spread_events(0, 500, 20, 20, 1_000_000)
    with pytest.raises(EstimationError, match="events per pixel"):
        estimate_thresholds(events, 20, 20, "natural")


def test_natural_on_the_texture_scene_beats_offe(tmp_path):
    """The simulator's texture scene (known thresholds, noisy preset: spread 25 %, low-pass, leak and shot noise),
    denoised, through the command line: natural >= 90 % valid, an error at least 2x below offE's (the reference,
    --max-fit inf) and 3x below the constant guess's. offE's fit (its disagreement with natural) rejects its
    worst pixels: the error of those it keeps is lower than the reference's."""
    stream = tmp_path / "texture.aedat4"
    truth = tmp_path / "truth.h5"
    run("simulate", "scene:texture", "--size", "48x36", "--duration", "12s", "--speed", "120", "--seed", "5",
        "--preset", "noisy", "--frame-rate", "500", "--truth", truth, "-o", stream)
    filtered = run("bafilter", stream).stdout
    with h5py.File(truth) as file:
        on, off = file["on"][()], file["off"][()]
    errors, valid_share = {}, {}
    for name, args in (("offe", ["--method", "offe", "--max-fit", "inf"]), ("offe fitted", ["--method", "offe"]),
                       ("natural", ["--method", "natural"])):
        out = tmp_path / f"{name}.h5"
        run("estimate", "-", *args, "-o", out, input=filtered)
        result = read_thresholds(out)
        valid = result.valid
        valid_share[name] = valid.mean()
        errors[name] = max(np.sqrt(np.mean((result.on[valid] / on[valid] - 1) ** 2)),
                           np.sqrt(np.mean((result.off[valid] / off[valid] - 1) ** 2)))
    constant = np.sqrt(np.mean((0.2 / on - 1) ** 2))
    assert valid_share["natural"] >= 0.9 and valid_share["offe"] >= 0.9
    assert errors["natural"] <= 0.5 * errors["offe"] and errors["natural"] <= constant / 3, (errors, constant)
    assert errors["offe fitted"] < 0.8 * errors["offe"] and valid_share["offe fitted"] < valid_share["offe"]


def test_natural_on_the_walk_recording(tmp_path):
    """The real DVS128 recording (25 s) through bafilter | estimate --method natural. 78 % of its pixels have no
    OFF event at all, so no method can give them thresholds; of the pixels with 50 events of each polarity at
    least 85 % are valid, and no valid pixel has fewer than 16 of either (the fit's counting floor)."""
    path = data_file("dvs128_walk.aedat")
    stream = tmp_path / "filtered.aedat4"
    run("bafilter", path, "-o", stream)
    out = tmp_path / "t.h5"
    run("estimate", stream, "--method", "natural", "-o", out)
    result = read_thresholds(out)
    counts = _polarity_counts(stream, 128, 128)
    assert counts[result.valid].min() >= 16
    assert result.valid[(counts >= 50).all(axis=-1)].mean() >= 0.85
    assert result.valid.sum() >= 1000
    assert 0.1 < np.median(result.on[result.valid]) < 0.3 and 0.1 < np.median(result.off[result.valid]) < 0.3


def test_the_fit_holds_between_the_halves_of_a_real_recording(tmp_path):
    """A real camera has no truth, but two halves of one recording are two independent estimates of the same
    thresholds: where both call a pixel valid, their difference must lie within what their fits predict. The
    DVS128 walk (after bafilter), cut at its middle (12.5 s each): the fits are conservative there (RMS of
    |log ratio| / hypot(fits) 0.65-0.69, at most 1 % past 2 fits, measured, both methods). offE's fit was its
    disagreement with natural alone: 1.16-1.19, 8 % past 2 fits (the two count the same events and err together);
    natural's own fit is now its floor (evtools.estimation._offe_fit)."""
    filtered = tmp_path / "filtered.aedat4"
    run("bafilter", data_file("dvs128_walk.aedat"), "-o", filtered)
    info, events = read_all(filtered)
    middle = events["t"][0] + (events["t"][-1] - events["t"][0]) // 2
    maps = {}
    for half, part in (("first", events[events["t"] < middle]), ("second", events[events["t"] >= middle])):
        source = tmp_path / f"{half}.aedat4"
        evtools.write(source, part, info)
        for method in ("natural", "offe"):
            out = tmp_path / f"{half}_{method}.h5"
            run("estimate", source, "--method", method, "-o", out)
            maps[half, method] = read_thresholds(out)
    for method, most_rms, most_beyond in (("natural", 0.9, 0.02), ("offe", 0.9, 0.02)):
        first, second = maps["first", method], maps["second", method]
        both = first.valid & second.valid
        assert both.sum() >= (500 if method == "natural" else 150)
        fits = np.hypot(first.fit[both], second.fit[both])
        for name in ("on", "off"):
            differences = np.abs(np.log(getattr(first, name)[both] / getattr(second, name)[both]))
            assert np.sqrt(np.mean((differences / fits) ** 2)) <= most_rms, (method, name)
            assert np.mean(differences > 2 * fits) <= most_beyond, (method, name)


def _polarity_counts(path, width, height):
    _, events = read_all(path)
    index = events["y"].astype(np.int64) * width + events["x"]
    return np.stack([np.bincount(index[events["p"] == p], minlength=width * height).reshape(height, width)
                     for p in (1, 0)], axis=-1)


def test_natural_on_the_short_dvxplorer_recording(tmp_path):
    """The real DVXplorer recording has 1.5 events a pixel (0.59 s): the default refuses with the reason; with
    --min-events 2 only pixels with 16 events of each polarity can be valid (never confident values from two or
    three events), and the halves' disagreement rejects some of those too."""
    path = data_file("dvxplorer_sample.aedat4")
    stream = tmp_path / "filtered.aedat4"
    run("bafilter", path, "-o", stream)
    refused = run("estimate", stream, "--method", "natural", "-o", tmp_path / "u.h5", check=False)
    assert_clean_error(refused, "events per pixel")
    assert not (tmp_path / "u.h5").exists()
    out = tmp_path / "t.h5"
    run("estimate", stream, "--method", "natural", "--min-events", "2", "--max-fit", "0.35", "-o", out)
    result = read_thresholds(out)
    counts = _polarity_counts(stream, 320, 240)
    assert result.valid.sum() > 0 and counts[result.valid].min() >= 9  # 1 / sqrt(9) = 0.33 <= 0.35


# -- online estimation and drift ----------------------------------------------------------------------------------

LOG_FLICKER = ["--profile", "log", "--min-level", "25", "--max-level", "250", "--period", "1s", "--leak-rate-hz", "0"]
LOG_STIMULUS = ["--method", "stimulus", "--stimulus-profile", "log", "--stimulus-period", "1s",
                "--stimulus-levels", f"{math.log(25)},{math.log(250)}"]


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), cuts=st.lists(st.integers(0, 10**6), max_size=6),
       method=st.sampled_from(["natural", "given", "fit"]))
def test_online_maps_do_not_depend_on_chunking(seed, cuts, method):
    """The maps are taken at fixed times (every interval from the first event), whatever the chunks."""
    events = _spread_events(seed, 6_000, 7, 5, 2_000_000)
    kind = "natural" if method == "natural" else "stimulus"
    options = dict(interval_us=300_000, forget_us=500_000, min_events=2, max_fit=math.inf)
    if kind == "stimulus":
        options.update(stimulus=Stimulus(period_us=400_000), phase=method)
    whole = ThresholdEstimator(7, 5, kind, **options)
    whole.process(events)
    chunked = ThresholdEstimator(7, 5, kind, **options)
    for part in cut(events, cuts):
        chunked.process(part)
    a, b = whole.result().series, chunked.result().series
    np.testing.assert_array_equal(a.t_us, b.t_us)
    for name in ("on", "off", "valid", "fit"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.t_us[0] == events["t"][0] + 300_000 and np.all(np.diff(a.t_us[:-1]) == 300_000)


def test_online_estimate_follows_a_drift_and_its_correction_beats_one_map(tmp_path):
    """simulate --thres-drift 2 (%/s) on a log flicker for 16 s: the online maps (1 s interval, 1 s forgetting)
    follow the thresholds within 4 % at every map time (they lag by about the forgetting time); correcting with the
    series leaves a count error against the ideal uniform-threshold stream at least 4x below that of a single map
    calibrated on the first 2 s (the founding scheme's calibrate-once), and below that of the uncorrected stream."""
    common = ["scene:flicker", "--size", "16x12", "--duration", "16s", *LOG_FLICKER, "--seed", "3"]
    run("simulate", *common, "--thres-drift", "2", "--truth", tmp_path / "truth.h5", "-o", tmp_path / "drift.aedat4")
    run("simulate", *common, "--sigma-thres", "0", "-o", tmp_path / "ideal.aedat4")
    info, events = read_all(tmp_path / "drift.aedat4")
    with create_events(str(tmp_path / "calib.aedat4"), info) as writer:
        writer.write(events[events["t"] < 2_000_000])
    run("estimate", tmp_path / "calib.aedat4", *LOG_STIMULUS, "-o", tmp_path / "calib.h5")
    run("estimate", tmp_path / "drift.aedat4", *LOG_STIMULUS, "--online", "--interval", "1s", "--forget", "1s",
        "-o", tmp_path / "series.h5")
    series = read_thresholds(tmp_path / "series.h5", series=True)
    truth = read_thresholds(tmp_path / "truth.h5")
    assert series.on.shape == (16, 12, 16) and series.t_us[0] > 1_000_000  # 15 boundaries and the final map
    later = series.t_us > 2_000_000
    for maps, first in ((series.on, truth.on), (series.off, truth.off)):
        ratio = np.nanmedian(maps[later] / first, axis=(1, 2))
        expected = 1 + 0.02 * (series.t_us[later] / 1e6 - 1.0)  # a lag of about the forgetting time
        assert np.all(np.abs(ratio / expected - 1) < 0.04), ratio
        assert np.all(np.diff(ratio) > 0)
    # the single latest map is what render sees; metrics compares a map with the truth at the map's time (it
    # once compared the last map, at 16 s, with the truth at 0 s: +31 %, every pixel more than 10 % off)
    assert read_thresholds(tmp_path / "series.h5").on.shape == (12, 16)
    assert truth.attributes["thres_drift_origin_us"] == 0
    for k in (3, -1):
        result = run("metrics", "thresholds", tmp_path / "series.h5", "--truth", tmp_path / "truth.h5",
                     "--map", str(k), "--json")
        figures = json.loads(result.stdout)
        assert figures["map"]["t_us"] == figures["truth_at_us"] == series.t_us[k]
        assert abs(figures["on"]["bias"]) < 0.04 and abs(figures["off"]["bias"]) < 0.04, figures
        assert "taken at" in result.stderr.decode()
    for name in ("calib", "series"):
        run("correct", tmp_path / "drift.aedat4", "--thresholds", tmp_path / f"{name}.h5", "--target", "0.2",
            "-o", tmp_path / f"{name}.corrected.aedat4")

    def count_error(path):
        counts = [np.bincount(e["y"].astype(np.int64) * 16 + e["x"], minlength=192)
                  for e in (read_all(path)[1], read_all(tmp_path / "ideal.aedat4")[1])]
        return np.abs(counts[0] - counts[1]).sum() / counts[1].sum()

    raw, calibrated, online = (count_error(tmp_path / name) for name in
                               ("drift.aedat4", "calib.corrected.aedat4", "series.corrected.aedat4"))
    assert online * 4 <= calibrated and online < raw, (raw, calibrated, online)


def test_online_usage_and_series_errors(tmp_path):
    stream = tmp_path / "f.aedat4"
    run("simulate", "scene:flicker", "--size", "8x6", "--duration", "2s", "-o", stream)
    for args, needle in ((["--online", "--interval", "1"], "no unit"), (["--interval", "1s"], "--online"),
                         (["--online"], "stimulus, natural or frames")):
        result = run("estimate", stream, "-o", tmp_path / "x.h5", *args, check=False)
        assert result.returncode == 2 and needle in result.stderr.decode(), result.stderr
    import h5py as h5

    with h5.File(tmp_path / "bad.h5", "w") as file:
        file["on"] = np.full((3, 6, 8), 0.2, np.float32)
        file["off"] = np.full((3, 6, 8), 0.2, np.float32)
        file["t_us"] = np.array([0, 2_000, 1_000], dtype=np.int64)
    result = run("correct", stream, "--thresholds", tmp_path / "bad.h5", "-o", tmp_path / "c.aedat4", check=False)
    assert_clean_error(result, "bad.h5", "out of order")
    assert not (tmp_path / "c.aedat4").exists()


@settings(max_examples=40, deadline=None)
@given(height=st.integers(1, 12), width=st.integers(1, 12), radius_px=st.integers(1, 4), seed=st.integers(0, 2**16))
def test_neighbour_sums_equal_a_loop_over_the_window(height, width, radius_px, seed):
    """The box sum around each pixel (itself left out, nothing outside the sensor) against a plain double loop."""
    from evtools.estimation import _around

    values = np.random.default_rng(seed).random((height, width))
    expected = np.zeros_like(values)
    for y in range(height):
        for x in range(width):
            for v in range(max(0, y - radius_px), min(height, y + radius_px + 1)):
                for u in range(max(0, x - radius_px), min(width, x + radius_px + 1)):
                    if (v, u) != (y, x):
                        expected[y, x] += values[v, u]
    np.testing.assert_allclose(_around(values, radius_px), expected, rtol=1e-12, atol=1e-12)


def test_a_zstd_compressed_map_is_read_and_a_plain_one_needs_no_plugin(tmp_path):
    """hdf5plugin (6 MiB, ~30 ms) is loaded only for a map whose datasets need one of its filters: a map written by
    another tool with Zstd reads the same; reading evtools' own (uncompressed) map does not import it."""
    import subprocess
    import sys

    import hdf5plugin

    on = np.random.default_rng(1).uniform(0.1, 0.3, (6, 8)).astype(np.float32)
    with h5py.File(tmp_path / "z.h5", "w") as h5:
        h5.create_dataset("on", data=on, **hdf5plugin.Zstd())
        h5.create_dataset("off", data=on + 0.01, **hdf5plugin.Zstd())
    plain = tmp_path / "plain.h5"
    write_thresholds(str(plain), ThresholdMap(on, on + 0.01, np.ones(on.shape, bool), {"method": "test"}))
    probe = ("import sys; from evtools.formats.thresholds import read_thresholds as r; a = r(sys.argv[1]); "
             "b = r(sys.argv[2]); print(float(abs(a.on - b.on).max()), 'hdf5plugin' in sys.modules)")
    only_plain = subprocess.run([sys.executable, "-c", probe, str(plain), str(plain)], capture_output=True, text=True,
                                check=True).stdout.split()
    assert only_plain == ["0.0", "False"]
    both = subprocess.run([sys.executable, "-c", probe, str(tmp_path / "z.h5"), str(plain)], capture_output=True,
                          text=True, check=True).stdout.split()
    assert both == ["0.0", "True"]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), pixels=st.integers(1, 60), samples=st.integers(3, 400),
       huge=st.floats(0.0, 1.0))
def test_offe_fit_is_the_exact_fit(seed, pixels, samples, huge):
    """offE's line fit from the sums equals the exact rational arithmetic (Fractions, rounded once), bit for bit,
    whichever path a pixel takes: int64 (small sums) or Python integers (sums whose products overflow int64)."""
    from fractions import Fraction

    from evtools._kernels.estimate import SUM_E, SUM_EE, SUM_EP, SUM_P, SUM_PP
    from evtools.estimation import RCOND_LIMIT, offe_fit

    rng = np.random.default_rng(seed)
    sums = np.zeros((5, pixels), np.int64)
    k = samples
    for i in range(pixels):
        if rng.random() < huge:  # any sums up to 2^40-2^62: the products overflow int64
            sums[:, i] = [int(rng.integers(-(2**40), 2**40)), int(rng.integers(-(2**40), 2**40)),
                          int(rng.integers(0, 2**62)), int(rng.integers(-(2**61), 2**61)), int(rng.integers(0, 2**62))]
            continue
        if rng.random() < 0.5:  # sums whose products lie about 2^50-2^62: beyond a float's 53 bits, within int64
            sums[:, i] = [int(rng.integers(-(2**12), 2**12)), int(rng.integers(-(2**12), 2**12)),
                          int(rng.integers(0, 2**22)), int(rng.integers(-(2**21), 2**21)), int(rng.integers(0, 2**22))]
            continue
        e = rng.integers(0, int(rng.choice([2, 50, 5000])), samples).tolist()  # a pixel's samples (E, P)
        slope = float(rng.normal(0, 2))
        p = [int(round(slope * v + rng.normal(0, rng.choice([0.0, 1.0, 30.0])))) for v in e]
        if rng.random() < 0.2:
            e = [e[0]] * samples  # one value: a singular fit
        sums[[SUM_E, SUM_P, SUM_EE, SUM_EP, SUM_PP], i] = [sum(e), sum(p), sum(v * v for v in e),
                                                          sum(a * b for a, b in zip(e, p)), sum(v * v for v in p)]
    m, r, fitted = offe_fit(sums, float(k))
    for i in range(pixels):
        s_e, s_p, s_ee, s_ep, s_pp = (int(sums[j, i]) for j in (SUM_E, SUM_P, SUM_EE, SUM_EP, SUM_PP))
        det, cov, var_p = k * s_ee - s_e * s_e, k * s_ep - s_e * s_p, k * s_pp - s_p * s_p
        norm1 = float(max(s_ee + abs(s_e), k + abs(s_e)))
        ok = float(det) > RCOND_LIMIT * norm1 * norm1
        assert fitted[i] == ok
        assert m[i] == (float(Fraction(cov, det)) if ok else 0.0)
        mse = float(Fraction(var_p * det - cov * cov, det * k * k)) if ok else 0.0
        assert r[i] == math.sqrt(max(mse, 0.0))


def test_online_maps_beyond_the_memory_bound_are_refused(monkeypatch):
    """`--online --interval 1us` kept a map per microsecond without a bound (killed for memory on a 1 s stream):
    the series is refused, saying why, once its maps would pass MAX_SERIES_BYTES."""
    import evtools.estimation as estimation

    monkeypatch.setattr(estimation, "MAX_SERIES_BYTES", 13 * 8 * 6 * 10)  # ten maps of 8 x 6 (float32 and bool)
    events = _spread_events(3, 20_000, 8, 6, 100_000)
    within = estimation.ThresholdEstimator(8, 6, "natural", interval_us=10_000, min_events=1, max_fit=math.inf)
    within.process(events)  # (maps at each interval's end as the stream passes it)
    assert 5 <= within._maps.count <= 10
    beyond = estimation.ThresholdEstimator(8, 6, "natural", interval_us=1_000, min_events=1, max_fit=math.inf)
    with pytest.raises(EstimationError, match=r"online maps every 1,000 us: 11 maps of 8x6 would take more than"):
        beyond.process(events)


def test_online_maps_given_to_a_sink_are_neither_held_nor_bounded(monkeypatch):
    """With a ``map_sink`` (the command line's way to the file) the maps are passed on as they are made: none is
    held, no memory bound applies, the final map comes once however often the result is asked for, and the maps
    are those an estimator holding them makes."""
    import evtools.estimation as estimation

    events = _spread_events(3, 20_000, 8, 6, 1_000_000)
    options = dict(interval_us=50_000, min_events=1, max_fit=math.inf)
    held = estimation.ThresholdEstimator(8, 6, "natural", **options)
    held.process(events)
    series = held.result().series
    monkeypatch.setattr(estimation, "MAX_SERIES_BYTES", 13 * 8 * 6 * 10)  # ten maps
    sent = []
    streamed = estimation.ThresholdEstimator(8, 6, "natural", map_sink=lambda *entry: sent.append(entry), **options)
    for chunk in cut(events, [5_000, 5_001, 17_000]):
        streamed.process(chunk)
    result = streamed.result()
    streamed.result()
    assert result.series is None and streamed.maps_so_far() is None
    assert len(sent) == result.attributes["maps"] == len(series.t_us) > 10
    assert [entry[0] for entry in sent] == series.t_us.tolist()
    for k, name in enumerate(("on", "off", "valid", "fit"), start=1):
        assert np.array_equal(np.stack([entry[k] for entry in sent]), getattr(series, name), equal_nan=True), name


def test_online_maps_in_the_file_are_the_estimators(tmp_path):
    """`estimate --online` writes each map to the file as it is made: the file holds exactly the series the
    estimator makes in memory (natural and stimulus), and `correct` reads it."""
    stream = tmp_path / "flicker.aedat4"
    run("simulate", "scene:flicker", "--size", "16x12", "--duration", "4s", *LOG_FLICKER, "--seed", "5", "-o", stream)
    info, events = read_all(stream)
    for method, args, options in (
            ("natural", ["--method", "natural", "--min-events", "2"], dict(min_events=2)),
            ("stimulus", LOG_STIMULUS, dict(stimulus=Stimulus(math.log(25), math.log(250), 1_000_000.0,
                                                              profile="log")))):
        out = tmp_path / f"{method}.h5"
        run("estimate", stream, *args, "--online", "--interval", "500ms", "-o", out)
        estimator = ThresholdEstimator(16, 12, method, interval_us=500_000, **options)
        estimator.process(events)
        series = estimator.result().series
        written = read_thresholds(out, series=True)
        assert np.array_equal(written.t_us, series.t_us) and len(series.t_us) >= 8
        for name in ("on", "off", "valid", "fit"):
            assert np.array_equal(getattr(written, name), getattr(series, name), equal_nan=True), (method, name)
        assert written.attributes["maps"] == len(series.t_us) and "partial" not in written.attributes
        run("correct", stream, "--thresholds", out, "-o", tmp_path / f"{method}.corrected.aedat4")


def test_a_stop_between_online_maps_keeps_them(tmp_path):
    """One chunk can make any number of maps (a gap in the stream, a short interval: a busy 40 ms and an event 1,000 s
    later at --interval 1ms are a million maps), and the reader sees a stop only at its next chunk: the maps' way to
    the file sees it at the next map. SIGINT once the maps are under way: exit 130, and the maps made are a complete
    file marked partial, stopped by SIGINT."""
    import signal

    stream = tmp_path / "gap.aedat4"
    busy = random_events(2000, 8, 6, seed=1)  # (over 40 ms)
    evtools.write(stream, np.concatenate([busy, make_events([1_000_000_000], [3], [3], [0])]), StreamInfo(8, 6))
    out = tmp_path / "series.h5"
    process = subprocess.Popen([str(Path(sys.executable).with_name("evtools")), "estimate", stream, "--method",
                                "natural", "--max-fit", "inf", "--online", "--interval", "1ms", "-o", out],
                               stderr=subprocess.PIPE)
    # until the maps' file is made and grows: the maps are under way (with the kernels compiled first, as under
    # EVTOOLS_KERNELS=numba on a fresh machine, a stop 0.5 s after the file appeared came before any map: CI)
    sizes = []
    for _ in range(1200):
        made = [path for path in tmp_path.iterdir() if path != stream]
        try:
            sizes.append(made[0].stat().st_size if made else -1)
        except OSError:  # (renamed meanwhile: the run is over)
            break
        if sizes[-1] > 0 and sizes[-1] > min(size for size in sizes if size > 0):
            break
        time.sleep(0.05)
    time.sleep(0.2)
    first = ""
    process.send_signal(signal.SIGINT)
    message = first + process.stderr.read().decode()
    assert process.wait(timeout=60) == 130, message
    assert "Traceback" not in message and "stopped by SIGINT" in message, message
    written = read_thresholds(out, series=True)
    assert written.attributes["partial"] and written.attributes["stopped_by"] == "stopped by SIGINT"
    assert 10 <= len(written.t_us) < 1_000_000 and np.all(np.diff(written.t_us) == 1_000)


def test_online_maps_that_would_be_empty_are_refused(tmp_path):
    """Maps at an interval too short for the stream (each adding less than 0.01 events a pixel) would fill the disk
    with empty maps (`--interval 1us` on a 1 s stream asked for 9.3 GiB, with only a warning: a QA sweep): after
    ten maps the run stops, exit 1, one line naming the interval that would do; the ten maps are kept, marked
    partial."""
    stream = tmp_path / "sparse.aedat4"
    evtools.write(stream, random_events(400, 32, 24, seed=2), StreamInfo(32, 24))  # (over 8 ms)
    out = tmp_path / "series.h5"
    refused = run("estimate", stream, "--method", "natural", "--online", "--interval", "100us", "-o", out,
                  check=False)
    refused.stderr = refused.stderr.decode()
    assert refused.returncode == 1 and refused.stderr.count("\n") == 1, refused.stderr
    assert "would be empty" in refused.stderr and "give an --interval of at least" in refused.stderr
    suggested = refused.stderr.split("at least ")[1].split(" ")[0]
    assert read_thresholds(str(out), series=True).attributes["partial"]
    # the interval it names makes maps of about one event a pixel: accepted (no longer refused for emptiness)
    again = run("estimate", stream, "--method", "natural", "--max-fit", "inf", "--online", "--interval", suggested,
                "-o", tmp_path / "ok.h5", check=False)
    assert b"would be empty" not in again.stderr, again.stderr


@pytest.mark.parametrize("factor", [0.5, 0.7, 1.3, 1.5])
def test_online_stimulus_survives_a_threshold_step(tmp_path, factor):
    """Issue 36 item 3: a log flicker whose thresholds step by ``factor`` at 10 s (two recordings of one camera
    joined). The stimulus method no longer refuses the stream: a pixel whose changes leave its acceptance window
    seeds anew (and fits its phase anew), its maps are invalid and marked stale (fit inf) until then, and no map
    calls a wrong value valid: every valid pixel of every map is within 10 % of the thresholds in force at the
    map's time (before the step: the first recording's, after: the second's). A step down is acquired again
    within three forgetting times (>= 90 % valid); a step up leaves fewer valid (>= 30 % measured at x1.5)."""
    common = ["scene:flicker", "--size", "16x12", "--duration", "10s", *LOG_FLICKER, "--seed", "3"]
    run("simulate", *common, "--truth", tmp_path / "a.h5", "-o", tmp_path / "a.aedat4")
    run("simulate", *common, "--pos-thres", str(0.2 * factor), "--neg-thres", str(0.2 * factor),
        "--sigma-thres", str(0.03 * factor), "--truth", tmp_path / "b.h5", "-o", tmp_path / "b.aedat4")
    (info, a), (_, b) = read_all(tmp_path / "a.aedat4"), read_all(tmp_path / "b.aedat4")
    b["t"] += 10_000_000
    with create_events(str(tmp_path / "step.aedat4"), info) as writer:
        writer.write(np.concatenate([a, b]))
    run("estimate", tmp_path / "step.aedat4", *LOG_STIMULUS, "--online", "--interval", "1s", "--forget", "1s",
        "-o", tmp_path / "series.h5")
    series = read_thresholds(tmp_path / "series.h5", series=True)
    truths = [read_thresholds(tmp_path / name) for name in ("a.h5", "b.h5")]
    for k, when in enumerate(series.t_us):
        truth = truths[0] if when <= 10_000_000 else truths[1]
        valid = series.valid[k]
        if when > 10_000_000 and when <= 11_000_000 or not valid.any():
            continue  # a map whose forgetting window holds the step: checked by the stale marks below
        for maps, true in ((series.on, truth.on), (series.off, truth.off)):
            assert np.all(np.abs(maps[k][valid] / true[valid] - 1) < 0.1), (k, when)
    after = series.t_us >= 13_000_000  # three forgetting times after the step
    assert series.valid[after].mean() >= (0.9 if factor < 1 else 0.3)
    stale = np.isinf(series.fit)
    assert stale[(series.t_us > 10_000_000) & (series.t_us <= 12_000_000)].any()  # the step is marked
    assert not (stale & series.valid).any()


@pytest.mark.parametrize("interval", ["1s", "500ms"])
def test_online_stimulus_drops_a_stepped_pixel_within_an_interval_with_the_default_forgetting(tmp_path, interval):
    """A QA sweep: with the default forgetting (three intervals) the decayed counts still held the step's old changes,
    most of them accepted, so the map an interval after a x1.3 step had 141 of 192 pixels valid, all 23.5 % off
    (500 ms maps: 164). A pixel whose changes since the last map fall mostly outside its window is dropped too:
    in the maps whose interval lies after the step and began within two stimulus periods of it, at most 12 % of the
    pixels are valid and more than 10 % off (measured: 2 % at 1 s maps, 11 % and 6 % at 500 ms; before, 73-85 %),
    at most 2 % later (0.5 %)."""
    common = ["scene:flicker", "--size", "16x12", "--duration", "6s", "--seed", "7"]  # (the QA's: the default flicker)
    run("simulate", *common, "--truth", tmp_path / "a.h5", "-o", tmp_path / "a.aedat4")
    run("simulate", *common, "--pos-thres", "0.26", "--neg-thres", "0.26", "--truth", tmp_path / "b.h5", "-o",
        tmp_path / "b.aedat4")
    (info, a), (_, b) = read_all(tmp_path / "a.aedat4"), read_all(tmp_path / "b.aedat4")
    b["t"] += 6_000_000
    with create_events(str(tmp_path / "step.aedat4"), info) as writer:
        writer.write(np.concatenate([a, b]))
    run("estimate", tmp_path / "step.aedat4", "--method", "stimulus", "--online", "--interval", interval,
        "-o", tmp_path / "series.h5")
    series = read_thresholds(tmp_path / "series.h5", series=True)
    truth = read_thresholds(tmp_path / "b.h5")
    step_us = 6_000_000
    interval_us = int(np.diff(series.t_us)[0])
    for k, when in enumerate(series.t_us):
        if when < step_us + interval_us:
            continue
        off = (np.abs(series.on[k] / truth.on - 1) > 0.1) | (np.abs(series.off[k] / truth.off - 1) > 0.1)
        wrong = (series.valid[k] & off).mean()
        assert wrong <= (0.12 if when - interval_us < step_us + 1_000_000 else 0.02), (k, when, wrong)


def test_correct_does_not_carry_a_stale_estimate(tmp_path):
    """A pixel marked stale in map 1 takes map 1's median there, not its map-0 value; where not stale it keeps it."""
    on = np.full((3, 2, 2), 0.2, np.float32)
    on[1] = [[np.nan, 0.3], [0.3, 0.3]]
    on[2] = 0.3
    valid = np.isfinite(on)
    stale = np.zeros(on.shape, bool)
    stale[1, 0, 0] = True
    from evtools.correction import SeriesMaps
    series = SeriesMaps([0, 1, 2], on, on, valid, stale)
    assert series.filled(1)[0][0, 0] == np.float32(0.3) and series.filled(2)[0][0, 0] == np.float32(0.3)
    series = SeriesMaps([0, 1, 2], on, on, valid)
    assert series.filled(1)[0][0, 0] == np.float32(0.2)  # not stale: carried


def test_an_online_run_stopped_midway_keeps_its_maps(tmp_path, monkeypatch):
    """Issue 36 item 3: an error midway (time going backwards at 3 s of a 4 s stream) writes the maps made so far
    (a complete file, marked partial) and exits 1 naming the time and the file."""
    run("simulate", "scene:flicker", "--size", "16x12", "--duration", "4s", *LOG_FLICKER, "--seed", "3",
        "-o", tmp_path / "f.aedat4")
    info, events = read_all(tmp_path / "f.aedat4")
    late = events[events["t"] >= 3_000_000].copy()
    late["t"][10:] -= 500_000  # the clock jumps back
    monkeypatch.setattr("evtools.formats.aedat4.PACKET_EVENTS", 1000)  # many packets
    with create_events(str(tmp_path / "back.aedat4"), info) as writer:  # (the writer stores what it is given)
        writer.write(events[events["t"] < 3_000_000])
        writer.write(late)
    out = tmp_path / "series.h5"
    data = (tmp_path / "back.aedat4").read_bytes()
    # through a pipe, in two writes: a chunk is what has arrived, so the first 3 s are estimated before the rest
    process = subprocess.Popen([str(Path(sys.executable).parent / "evtools"), "estimate", "-", *LOG_STIMULUS,
                                "--online", "--interval", "1s", "-o", str(out)], stdin=subprocess.PIPE,
                               stderr=subprocess.PIPE)
    process.stdin.write(data[:len(data) * 3 // 4])
    process.stdin.flush()
    waiting = array.array("i", [1])
    deadline = time.monotonic() + 120
    while waiting[0] and time.monotonic() < deadline:  # until the command has read the first part (however busy
        fcntl.ioctl(process.stdin.fileno(), termios.FIONREAD, waiting)  # the machine): its chunk ends there
        time.sleep(0.05)
    time.sleep(0.2)
    process.stdin.write(data[len(data) * 3 // 4:])
    process.stdin.close()
    message = process.stderr.read().decode()
    assert process.wait(timeout=120) == 1 and "Traceback" not in message, message
    assert "maps made up to" in message and str(out) in message and "us" in message, message
    series = read_thresholds(str(out), series=True)
    assert series.attributes["partial"] and 2 <= len(series.t_us) <= 3 and series.valid[-1].mean() > 0.9


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(4, 60), pixels=st.integers(1, 20))
def test_offe_sampling_error_is_the_line_fits_standard_errors(seed, k, pixels):
    """offE's sampling error from its sums against numpy's least squares (polyfit's covariance, scaled as the
    unbiased residual variance): the slope's standard error over 1 - |m|, floored by the residual's own
    sampling error 1 / sqrt(2 (k - 2))."""
    from evtools._kernels.estimate import SUM_E, SUM_EE, SUM_EP, SUM_P, SUM_PP
    from evtools.estimation import _offe_sampling_error, offe_fit

    rng = np.random.default_rng(seed)
    e = rng.integers(0, 40, (pixels, k))
    p = np.round(rng.uniform(-0.5, 0.5, (pixels, 1)) * e + rng.normal(0, 3, (pixels, k))).astype(np.int64)
    sums = np.zeros((5, pixels), np.int64)
    sums[SUM_E], sums[SUM_P], sums[SUM_EE] = e.sum(1), p.sum(1), (e * e).sum(1)
    sums[SUM_EP], sums[SUM_PP] = (e * p).sum(1), (p * p).sum(1)
    m, r, fitted = offe_fit(sums, k)
    error = _offe_sampling_error(sums, k, m, r)
    for i in range(pixels):
        if not fitted[i] or np.ptp(e[i]) == 0:
            continue
        (slope, _), covariance = np.polyfit(e[i], p[i], 1, cov="unscaled")
        residual = p[i] - np.polyval([slope, _], e[i])
        se = math.sqrt(covariance[0, 0] * (residual @ residual) / (k - 2))
        expected = max(1 / math.sqrt(2 * (k - 2)), se / max(1 - abs(slope), 1e-3))
        assert error[i] == pytest.approx(expected, rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("segment_us", [666_666, 400_000])
def test_offe_through_a_few_segments_is_refused_not_called_valid(tmp_path, segment_us):
    """A QA sweep: offE's line through 3-5 long segments of a 2 s flicker called 84-95 % of the pixels valid with
    97-100 % of them more than 10 % off (ON +16 %, OFF -14 %). Its sampling error (0.71 and 0.41 there) is now part
    of its fit: refused, naming the segments; the default 10 ms segments stay valid and within 10 %."""
    stream = tmp_path / "flicker.aedat4"
    run("simulate", "scene:flicker", "--size", "64x48", "--sigma-thres", "0.03", "--seed", "7", "--duration", "2s",
        "--truth", tmp_path / "truth.h5", "-o", stream)
    result = run("estimate", stream, "--segment-us", str(segment_us), "-o", tmp_path / "few.h5", check=False)
    assert_clean_error(result, "segments alone leaves a median error")
    assert not (tmp_path / "few.h5").exists()
    run("estimate", stream, "-o", tmp_path / "many.h5")
    errors = json.loads(run("metrics", "thresholds", tmp_path / "many.h5", "--truth", tmp_path / "truth.h5",
                            "--json").stdout)
    assert errors["invalid_fraction"] < 0.05 and errors["off_by_10_percent"] < 0.01


def test_online_natural_that_remembers_too_few_events_says_so(tmp_path):
    """Online, natural's sums forget over 3 intervals: a short interval leaves a few events a pixel remembered
    although the recording holds plenty; the error named the recording's length (a QA sweep), now the forgetting."""
    stream = tmp_path / "tex.aedat4"
    run("simulate", "scene:texture", "--size", "48x36", "--duration", "3s", "--seed", "2", "-o", stream)
    run("estimate", stream, "--method", "natural", "-o", tmp_path / "whole.h5")  # (the recording is enough)
    result = run("estimate", stream, "--method", "natural", "--online", "--interval", "20ms", "-o",
                 tmp_path / "short.h5", check=False)
    assert_clean_error(result, "the sums forget over 0.06 s")
    assert "give a longer --forget" in result.stderr.decode() and "longer recording" not in result.stderr.decode()


def test_online_checks_the_stimulus_description_as_offline(tmp_path):
    """A description the events refuse offline is refused online too (it ran unchecked: every map at half the true
    thresholds, exit 0, a QA sweep), once the stream holds four periods or at its end, and no map made with it is
    kept; the right description runs as before."""
    stream = tmp_path / "f.aedat4"
    run("simulate", "scene:flicker", "--size", "32x24", "--duration", "6s", "--seed", "7", "-o", stream)
    for wrong in (["--stimulus-levels", "100,200"], ["--stimulus-period", "490ms"]):
        for extra in ([], ["--online", "--interval", "500ms"]):
            out = tmp_path / "x.h5"
            result = run("estimate", stream, "--method", "stimulus", *wrong, *extra, "-o", out, check=False)
            assert_clean_error(result, "do not fit the described stimulus")
            assert not out.exists()
    run("estimate", stream, "--method", "stimulus", "--online", "--interval", "500ms", "-o", tmp_path / "right.h5")
    assert read_thresholds(str(tmp_path / "right.h5"), series=True).valid[-1].mean() > 0.9
    estimator = ThresholdEstimator(32, 24, "stimulus", stimulus=Stimulus(100.0, 200.0, 500_000),
                                   interval_us=500_000)
    events = read_all(stream)[1]
    with pytest.raises(EstimationError, match="do not fit the described stimulus"):
        estimator.process(events[events["t"] < events["t"][0] + 2_600_000])  # (the check: at the map at 2 s)
    assert estimator._maps.count == 3  # (the maps before it, held by the library: its caller's to drop)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), width=st.integers(1, 12), height=st.integers(1, 12),
       bounds=st.lists(st.integers(-15, 15), min_size=4, max_size=4))
def test_rectangle_sums_match_a_plain_loop(seed, width, height, bounds):
    """The natural method's excitation gradient sums the neighbours in half windows from a summed-area table
    (constant work a pixel whatever the radius: a radius as wide as the sensor took minutes as a loop over offsets)."""
    from evtools.estimation import _integral, _rectangle_sum

    x0, x1 = sorted(bounds[:2])
    y0, y1 = sorted(bounds[2:])
    values = np.random.default_rng(seed).random((height, width))
    got = _rectangle_sum(_integral(values), x0, x1, y0, y1)
    for y in range(height):
        for x in range(width):
            inside = [values[j, i] for j in range(y + y0, y + y1 + 1) for i in range(x + x0, x + x1 + 1)
                      if 0 <= j < height and 0 <= i < width]
            assert math.isclose(got[y, x], sum(inside), rel_tol=1e-9, abs_tol=1e-9)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale_px=st.floats(1.5, 6.0), scene=st.floats(0.05, 0.3),
       own=st.floats(0.05, 0.2), radius_px=st.integers(1, 3))
@example(seed=2, scale_px=6.0, scene=0.25, own=0.0625, radius_px=3)
def test_natural_scene_error_predicts_the_excursions_error(seed, scale_px, scene, own, radius_px):
    """The scene error (issue 36) predicted from a map's spatial autocovariance against the true RMS of
    ``s_i - mean_j z_j`` over the window, for a smooth random excursion field s (Gaussian-blurred noise, std
    ``scene``, scale 1.5-6 px) under independent per-pixel parts (std ``own``): within 0.25-3x of it. Measured over
    324 such fields: median 0.99, 5-95 % 0.80-1.56, extremes 0.32-2.64 (a rough field's share at lag 0 is
    under-extrapolated; a very smooth one's errors are small and over-predicted, as the example, 2.0x). A
    prediction of the error's size, not of each field's to 10 %."""
    import cv2

    from evtools.estimation import _scene_error

    width, height, pad = 64, 48, 20
    rng = np.random.default_rng(seed)
    smooth = cv2.GaussianBlur(rng.normal(size=(height + 2 * pad, width + 2 * pad)), (0, 0), scale_px)
    s = smooth[pad:-pad, pad:-pad]
    s = scene * (s - s.mean()) / s.std()
    z = s + own * rng.normal(size=(height, width))
    inverse = np.repeat(np.exp(-z)[..., None] / 2, 2, axis=-1)  # u_on + u_off = exp(-z)
    predicted = _scene_error(inverse, np.ones((height, width), bool), radius_px)
    r = radius_px
    errors = []
    for y in range(r, height - r):
        for x in range(r, width - r):
            window = z[y - r:y + r + 1, x - r:x + r + 1]
            errors.append(s[y, x] - (window.sum() - z[y, x]) / (window.size - 1))
    errors = np.array(errors)
    actual = np.sqrt(np.mean((errors - errors.mean()) ** 2))
    assert 0.25 * actual <= predicted <= 3.0 * actual, (predicted, actual)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 400), width=st.integers(1, 7), height=st.integers(1, 6),
       cuts=st.lists(st.integers(0, 400), max_size=4), method=st.sampled_from(["natural", "offe"]))
def test_neighbour_ages_match_the_naive_reference_whatever_the_chunks(seed, n, width, height, cuts, method):
    """The scene check's kernel (each event's lag behind its neighbours' latest event, by binary order of
    magnitude, and the events per pixel) against a look back through the whole stream, chunked anyhow."""
    rng = np.random.default_rng(seed)
    events = make_events(np.sort(rng.integers(0, rng.choice([50, 5000, 10**9]), n)), rng.integers(0, width, n),
                         rng.integers(0, height, n), rng.integers(0, 2, n))
    estimator = ThresholdEstimator(width, height, method)
    for chunk in cut(events, cuts):
        estimator.process(chunk)
    from evtools.estimation import SCENE_STRIDE

    ages, per_pixel = neighbour_ages_naive(events, width, height, SCENE_STRIDE)
    assert estimator._neighbour_ages.tolist() == ages
    assert estimator._pixel_events.tolist() == per_pixel


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 2**16), rate_hz=st.floats(20.0, 60.0), method=st.sampled_from(["natural", "offe"]))
def test_events_alone_refuse_a_stream_of_noise_and_take_a_moving_texture(seed, rate_hz, method):
    """Found by a QA sweep: on pure noise natural and offE called 19-36 % of the pixels valid, at thresholds
    uncorrelated with the true ones (r 0.02), exit 0. Independent Poisson pixels (drawn here, at a random rate high
    enough for the methods to call pixels valid: 20-60 Hz) are refused saying so; a texture moving under ideal
    pixels (tests/naive/texture.py) is not taken for noise."""
    from tests.naive.texture import crossings, texture_signal

    rng = np.random.default_rng(seed)
    width, height, span_us = 24, 18, 2_000_000
    n = rng.poisson(rate_hz * width * height * span_us * 1e-6)
    noise = make_events(np.sort(rng.integers(0, span_us, n)), rng.integers(0, width, n), rng.integers(0, height, n),
                        rng.integers(0, 2, n))
    with pytest.raises(EstimationError, match=r"the events show no scene: .* as independent noise at the same "
                                              r"rates gives"):
        estimate_thresholds(noise, width, height, method, min_events=2)
    assert estimate_thresholds(noise, width, height, method, min_events=2, max_fit=np.inf).valid.any()  # unchecked
    times, levels = texture_signal(width, height, span_us, seed=seed, wobble_px=3.0)
    given = crossings(times, levels, np.float32(0.2), np.float32(0.2))
    texture = make_events(given["t"], given["x"], given["y"], given["p"])
    try:
        estimate_thresholds(texture, width, height, method, min_events=2)
    except EstimationError as error:  # (too few events for a fit, say: not taken for noise)
        assert "no scene" not in str(error)


@pytest.mark.parametrize("method", ["stimulus", "natural", "offe"])
def test_a_stream_of_one_polarity_is_named_as_such(tmp_path, method):
    """`--polarity on` left a flicker's ON events alone, and the estimate said "fewer than 10 events or no usable
    pair of events everywhere" of pixels with dozens (a QA sweep): the message names the one polarity."""
    stream = tmp_path / "f.aedat4"
    run("simulate", "scene:flicker", "--size", "8x6", "--duration", "2s", "-o", stream)
    done = run("estimate", stream, "--method", method, "--polarity", "on", "-o", tmp_path / "t.h5", check=False)
    assert_clean_error(done, "events are all ON", "--polarity")


def _stop_after(monkeypatch, chunks: int, chunk_events: int) -> None:
    """A SIGINT as if received once the estimator has taken ``chunks`` chunks of ``chunk_events`` (the reader then
    ends the stream)."""
    import dataclasses
    import signal

    import evtools.cli.estimate as estimate_command
    from evtools import interrupt

    opening = estimate_command.open_events
    monkeypatch.setattr(estimate_command, "open_events", lambda path, reading: opening(
        path, dataclasses.replace(reading, chunk_events=chunk_events)))

    taken = []
    process = ThresholdEstimator.process

    def processing(self, chunk):
        taken.append(len(chunk))
        if len(taken) == chunks:
            monkeypatch.setattr(interrupt, "_received", signal.SIGINT)
        return process(self, chunk)

    monkeypatch.setattr(ThresholdEstimator, "process", processing)
    monkeypatch.setattr(interrupt, "_received", None)


def test_an_offline_map_of_a_stopped_run_is_marked_partial_and_its_readers_say_so(tmp_path, monkeypatch, caplog):
    """A QA sweep: `estimate` stopped by Ctrl-C midway wrote a map of the first half of the stream under its final
    name with no mark (only exit 130 said it), and `correct` then used it without a word. The map now carries
    partial, stopped_by and stopped_at_us (as a stopped online run's maps), and every reader of it warns."""
    from click.testing import CliRunner

    from evtools.cli.main import cli

    stream = tmp_path / "long.csv"
    events, _ = evtools.simulate("texture", size=(32, 24), duration_us=3_000_000, seed=3)
    evtools.write(stream, events, StreamInfo(32, 24))
    out = tmp_path / "map.h5"
    _stop_after(monkeypatch, chunks=2, chunk_events=len(events) // 3)
    done = CliRunner().invoke(cli, ["estimate", str(stream), "--max-fit", "inf", "-o", str(out)])
    assert done.exit_code == 130, done.output
    written = read_thresholds(out)
    assert written.attributes["partial"] and written.attributes["stopped_by"] == "stopped by SIGINT"
    assert written.attributes["events"] < len(events)
    assert 0 < written.attributes["stopped_at_us"] < int(events["t"][-1])
    monkeypatch.undo()
    import logging

    monkeypatch.setattr(logging.getLogger("evtools"), "handlers", [caplog.handler])
    caplog.clear()
    read_thresholds(out)
    assert any("estimated from part of its stream (stopped by SIGINT" in r.getMessage() for r in caplog.records)


def test_a_stop_before_the_stream_held_enough_exits_130_not_an_error_about_the_data(tmp_path, monkeypatch):
    """A stop after one small chunk left too few events to estimate from: the run said the recording had no
    events or was too short (exit 1), never the stop. Now exit 130 and "interrupted", and no map."""
    from click.testing import CliRunner

    from evtools.cli.main import cli

    stream = tmp_path / "long.csv"
    events, _ = evtools.simulate("texture", size=(32, 24), duration_us=3_000_000, seed=3)
    evtools.write(stream, events, StreamInfo(32, 24))
    out = tmp_path / "map.h5"
    _stop_after(monkeypatch, chunks=1, chunk_events=50)
    done = CliRunner().invoke(cli, ["estimate", str(stream), "--method", "natural", "-o", str(out)])
    assert done.exit_code == 130, done.output
    assert "interrupted" in done.output and "events" not in done.output, done.output
    assert not out.exists()


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31), busy=st.integers(400, 4000), ratio_on_off=st.floats(0.5, 2.0))
def test_a_busy_pixel_among_quiet_neighbours_is_not_a_valid_natural_estimate(seed, busy, ratio_on_off):
    """A QA sweep: on the DVXplorer recording, `--method natural --min-events 1` (as the refusal advised) called five
    pixels valid at 1/13 to 1/130 of the nominal, fits 0.17-0.24: busy pixels (hot, flickering) among neighbours
    with an event or two. No chip's mismatch is a factor 4 from its neighbours: such a pixel is not valid, and
    counted as rejected_as_implausible."""
    rng = np.random.default_rng(seed)
    width, height = 12, 10
    quiet = random_events(30 * width * height, width, height, seed=seed % 2**16)  # (about 30 events a pixel)
    quiet["t"] *= 40  # (over about 3 s: natural's two halves alternate every 100 ms)
    n_on = int(busy * ratio_on_off / (1 + ratio_on_off)) + 1
    t = np.sort(rng.integers(int(quiet["t"][0]), int(quiet["t"][-1]) + 1, busy + 2))
    hot = make_events(t, [5] * len(t), [4] * len(t), (np.arange(len(t)) < n_on).astype(int)[rng.permutation(len(t))])
    events = np.sort(np.concatenate([quiet, hot]), order="t", kind="stable")
    estimate = estimate_thresholds(events, width, height, method="natural", min_events=1, max_fit=float("inf"))
    assert estimate.valid.sum() > width * height // 2  # (the quiet pixels are estimated)
    assert not estimate.valid[4, 5]
    assert estimate.attributes["rejected_as_implausible"] >= 1


@pytest.mark.parametrize("output", [None, "-"])
def test_a_thresholds_file_to_stdout_is_a_usage_error(tmp_path, output):
    """The map is HDF5 and cannot go to stdout: a mistake in the command line (exit 2), not in the data (it was 1)."""
    stream = tmp_path / "s.aedat4"
    evtools.write(stream, random_events(500, 8, 6, seed=1), StreamInfo(8, 6))
    done = run("estimate", stream, *([] if output is None else ["-o", output]), check=False)
    stderr = done.stderr.decode()
    assert done.returncode == 2 and stderr.count("\n") == 1 and "cannot go to stdout" in stderr, stderr


@pytest.mark.parametrize("on_off", [(0.2, 0.2), (0.1, 0.3), (0.3, 0.12)])
def test_an_events_only_map_says_when_its_on_off_balance_is_far_from_even(on_off):
    """A QA sweep: natural on the DAVIS346 lab recording gave ON 0.070 against OFF 0.29 with fits near 0.2 and no
    word; events alone cannot tell the pixels' balance from a scene that ends brighter or darker. Beyond a factor
    2 the map says so (polarity_balance); a balanced camera's does not."""
    events, _ = evtools.simulate("texture", size=(32, 24), duration_us=6_000_000, pos_thres=on_off[0],
                                 neg_thres=on_off[1], leak_rate_hz=0.0, seed=8)
    estimate = estimate_thresholds(events, 32, 24, "natural", max_fit=math.inf)
    ratio = estimate.attributes["on_median"] / estimate.attributes["off_median"]
    assert ("polarity_balance" in estimate.attributes) == (not 0.5 <= ratio <= 2.0)
    assert ("polarity_balance" in estimate.attributes) == (max(on_off) / min(on_off) > 2)
