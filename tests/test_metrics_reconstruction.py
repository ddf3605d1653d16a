"""``metrics reconstruction`` (issue 12 part 3): the high-pass filter against its slow reference, chunking, known
answers, the truth file's frames and the command's errors."""

from __future__ import annotations

import math

import h5py
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from evtools.events import make_events
from evtools.metrics.reconstruction import HighPassReconstructor, reconstruction_errors, ssim
from tests.helpers import assert_clean_error, cut, run
from tests.naive.reconstruction import reconstruct_naive

W, H = 5, 4


def random_stream(seed, n):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 200_000, n))
    return make_events(t, rng.integers(0, W, n), rng.integers(0, H, n), rng.integers(0, 2, n))


def tuples(events):
    return [(int(e["t"]), int(e["x"]), int(e["y"]), bool(e["p"])) for e in events]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), n=st.integers(0, 300), cutoff=st.sampled_from([0.0, 0.7, 5.0, 40.0]),
       cuts=st.lists(st.integers(0, 300), max_size=5), frames=st.integers(1, 8))
def test_kernel_equals_naive_and_chunking_does_not_matter(seed, n, cutoff, cuts, frames):
    rng = np.random.default_rng(seed + 1)
    events = random_stream(seed, n)
    baseline = rng.normal(4.0, 0.5, (H, W))
    on, off = rng.uniform(0.1, 0.3, (H, W)), rng.uniform(0.1, 0.3, (H, W))
    times = np.sort(rng.choice(np.arange(0, 220_000, 1000), frames, replace=False))
    whole = HighPassReconstructor(baseline, times, on, off, cutoff)
    whole.process(events)
    expected = np.array(reconstruct_naive(tuples(events), baseline.tolist(), times.tolist(), on.tolist(),
                                          off.tolist(), cutoff))
    got = whole.flush()
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    chunked = HighPassReconstructor(baseline, times, on, off, cutoff)
    for part in cut(events, cuts):
        chunked.process(part)
    np.testing.assert_array_equal(chunked.flush(), got)


@settings(max_examples=30, deadline=None)
@given(steps=st.lists(st.tuples(st.integers(1, 100), st.integers(-3, 3)), min_size=1, max_size=10),
       theta=st.floats(0.05, 0.5), base=st.floats(-1, 5))
def test_exact_contrasts_and_no_cutoff_give_the_true_frames(steps, theta, base):
    """A pixel whose log intensity moves by k thresholds between frames fires |k| events: the integration is the
    true frame again, at every frame (known answer)."""
    level, t, times, truth, ts, ps = base, 0, [0], [base], [], []
    for gap_ms, k in steps:
        for j in range(abs(k)):
            ts.append(t + 1 + j)
            ps.append(k > 0)
        t += gap_ms * 1000
        level += k * theta
        times.append(t)
        truth.append(level)
    events = make_events(np.array(ts, np.int64), np.zeros(len(ts), int), np.zeros(len(ts), int), np.array(ps, bool))
    recon = HighPassReconstructor(np.full((1, 1), base), times, theta, theta, 0.0)
    recon.process(events)
    np.testing.assert_allclose(recon.flush()[:, 0, 0], truth, atol=1e-9)


def test_cutoff_decays_as_the_closed_form():
    events = make_events([1000], [0], [0], [True])
    recon = HighPassReconstructor(np.zeros((1, 1)), [1000, 101_000], 0.2, 0.2, cutoff_hz=2.0)
    recon.process(events)
    frames = recon.flush()[:, 0, 0]
    assert frames[0] == 0.2
    assert math.isclose(frames[1], 0.2 * math.exp(-2 * math.pi * 2.0 * 0.1), rel_tol=1e-12)


def test_ssim_and_rmse_of_identical_and_different_frames():
    rng = np.random.default_rng(0)
    truth = rng.normal(4, 1, (3, 16, 16))
    same = reconstruction_errors(truth.copy(), truth)
    assert same["rmse"] == 0 and math.isclose(same["ssim"], 1.0)
    noisy = reconstruction_errors(truth + rng.normal(0, 0.5, truth.shape), truth)
    assert 0.4 < noisy["rmse"] < 0.6 and noisy["ssim"] < 0.9
    assert ssim(truth[0], 8.0 - truth[0], 8.0) < 0  # same mean, mirrored structure


def test_simulate_stores_true_log_frames_and_the_command_measures_them(tmp_path):
    out, truth = tmp_path / "s.aedat4", tmp_path / "t.h5"
    run("simulate", "scene:step", "--size", "16x12", "--duration", "1s", "--truth", str(truth),
        "--truth-frame-rate", "50", "-o", str(out))
    with h5py.File(truth) as h5:
        assert h5["log_frames"].shape == (51, 12, 16)
        assert np.all(np.diff(h5["log_frame_t_us"][:]) == 20_000)
        step = h5["log_frames"][:]
    assert step.max() - step.min() > 1  # the scene's step, in log units
    raw = run("metrics", "reconstruction", str(out), "--truth", str(truth), "--json")
    exact = run("metrics", "reconstruction", str(out), "--truth", str(truth), "--thresholds", str(truth), "--json")
    import json

    raw, exact = json.loads(raw.stdout), json.loads(exact.stdout)
    assert raw["frames"] == 51 and exact["frames"] == 51
    assert exact["rmse"] < raw["rmse"]  # each pixel's own thresholds integrate its steps better than the nominal
    picture = tmp_path / "r.png"
    run("metrics", "reconstruction", str(out), "--truth", str(truth), "--plot", str(picture), "--json")
    assert picture.stat().st_size > 1000


def test_errors(tmp_path):
    out, truth = tmp_path / "s.aedat4", tmp_path / "t.h5"
    run("simulate", "scene:step", "--size", "16x12", "--duration", "0.2s", "--truth", str(truth),
        "--truth-frame-rate", "0", "-o", str(out))
    assert_clean_error(run("metrics", "reconstruction", str(out), "--truth", str(truth), check=False),
                       "--truth-frame-rate")
    other = tmp_path / "o.h5"
    run("simulate", "scene:step", "--size", "8x6", "--duration", "0.2s", "--truth", str(other), "-o",
        str(tmp_path / "o.aedat4"))
    assert_clean_error(run("metrics", "reconstruction", str(out), "--truth", str(other), check=False), "8x6")
    result = run("metrics", "reconstruction", str(tmp_path / "o.aedat4"), "--truth", str(other), "--contrast", "nan",
                 check=False)  # (a usage error: click's range let nan through to the metric, exit 1 before)
    assert result.returncode == 2 and b"Invalid value for '--contrast': 'nan' is not a finite number" in result.stderr
    assert_clean_error(run("metrics", "reconstruction", str(tmp_path / "o.aedat4"), "--truth", str(other),
                           "--thresholds", str(truth), check=False), "16x12")


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 40), st.integers(1, 6), st.integers(0, 2**31 - 1))
def test_the_figure_shows_settled_frames_never_a_step_edge(frames, steps, seed):
    """Issue 39 item 6: the reconstruction figure sampled exactly at step edges, where the reconstruction lags, so
    truth and reconstruction disagreed in every panel. Each of its frames is the one of its stretch longest after
    the truth last changed (checked by brute force over every frame of the stretch)."""
    from evtools.plots import steady_frames

    rng = np.random.default_rng(seed)
    levels = np.zeros(frames)
    for edge in rng.integers(1, frames, steps):
        levels[edge:] += rng.uniform(0.1, 1.0)
    truth = np.broadcast_to(levels[:, None, None], (frames, 3, 4)).copy()
    picks = steady_frames(truth)
    assert len(picks) == min(5, frames) and np.all(np.diff(picks) > 0)

    def since_change(k):
        return next(k - j for j in range(k, -1, -1) if j == 0 or levels[j] != levels[j - 1])

    bounds = np.linspace(0, frames, min(5, frames) + 1).round().astype(int)
    for pick, start, stop in zip(picks, bounds[:-1], bounds[1:]):
        assert start <= pick < stop
        assert since_change(pick) == max(since_change(k) for k in range(start, stop))
