"""``evtools metrics thresholds``: the error figures against hand-made maps, the picture, the CLI and its errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from evtools.metrics.thresholds import ThresholdMetricsError, fit_calibration, threshold_errors
from evtools.formats.thresholds import ThresholdMap, write_thresholds
from tests.helpers import assert_clean_error, run


def maps(seed=0, shape=(6, 8)):
    rng = np.random.default_rng(seed)
    return (0.2 + 0.03 * rng.standard_normal(shape)).astype(np.float32), (0.2 + 0.03 * rng.standard_normal(shape)).astype(np.float32)


def test_errors_by_their_definitions():
    true_on, true_off = maps()
    est_on, est_off = true_on * 1.1, true_off.copy()
    est_off[0, 0] = true_off[0, 0] * 0.5
    valid = np.ones(true_on.shape, bool)
    valid[1, 1] = False
    est_on[1, 1] = 99  # invalid: ignored
    result = threshold_errors(est_on, est_off, valid, true_on, true_off)
    assert result["on"]["rel_rmse"] == pytest.approx(0.1, rel=1e-5)
    assert result["on"]["bias"] == pytest.approx(0.1, rel=1e-5)
    assert result["on"]["correlation"] == pytest.approx(1.0)
    n = valid.sum()
    assert result["off"]["rel_rmse"] == pytest.approx(np.sqrt(0.25 / n), rel=1e-5)
    assert result["off"]["bias"] == pytest.approx(-0.5 / n, rel=1e-5)
    assert result["invalid_fraction"] == pytest.approx(1 / valid.size)
    assert result["on"]["pixels"] == n


def test_fit_calibration_by_its_definitions():
    """The larger of the ON and OFF relative errors against the fit, over valid pixels with a finite fit: RMS of
    their ratio, the share past two fits, the rank correlation; and the share of valid pixels 10 % off."""
    true_on, true_off = maps(shape=(4, 5))
    errors = np.linspace(0.015, 0.205, 20).reshape(4, 5)  # (none at 0.1 itself)
    est_on, est_off = true_on * (1 + errors), true_off * (1 - errors / 2)
    fit = (errors / 1.5).astype(np.float32)  # every error 1.5 times its fit
    fit[0, 0] = np.nan  # not fitted: left out
    valid = np.ones((4, 5), bool)
    valid[3, 4] = False  # not valid: left out
    result = fit_calibration(est_on, est_off, valid, fit, true_on, true_off)
    assert result["pixels"] == 18 and result["error_over_fit_rms"] == pytest.approx(1.5, rel=1e-5)
    assert result["beyond_two_fits"] == 0 and result["rank_correlation"] == pytest.approx(1)
    # reversed: the largest errors get the smallest fits (the NaN fit lands on the invalid pixel: 19 pixels, of
    # which e_k > 2 e_(19-k) / 1.5 for k = 12..18)
    result = fit_calibration(est_on, est_off, valid, fit[::-1, ::-1], true_on, true_off)
    assert result["pixels"] == 19 and result["rank_correlation"] == pytest.approx(-1)
    assert result["beyond_two_fits"] == pytest.approx(7 / 19)
    assert fit_calibration(est_on, est_off, valid, np.full((4, 5), np.nan), true_on, true_off) is None
    assert threshold_errors(est_on, est_off, valid, true_on, true_off)["off_by_10_percent"] == pytest.approx(10 / 19)
    negative = est_on.copy()  # (a threshold not positive is no estimate: left out here as by threshold_errors)
    negative.flat[[3, 4]] = -0.05
    assert fit_calibration(negative, est_off, valid, fit, true_on, true_off)["pixels"] == 18 - 2
    assert threshold_errors(negative, est_off, valid, true_on, true_off)["on"]["pixels"] == 19 - 2


def test_wrong_size_is_an_error():
    true_on, true_off = maps()
    with pytest.raises(ThresholdMetricsError, match="differ in size"):
        threshold_errors(true_on[:, :4], true_off[:, :4], np.ones((6, 4), bool), true_on, true_off)


def test_cli_json_plot_and_errors(tmp_path):
    true_on, true_off = maps()
    write_thresholds(str(tmp_path / "truth.h5"), ThresholdMap(true_on, true_off, np.ones(true_on.shape, bool)))
    write_thresholds(str(tmp_path / "est.h5"),
                     ThresholdMap(true_on * 0.9, true_off, np.ones(true_on.shape, bool), {"method": "offe"}))
    result = run("metrics", "thresholds", tmp_path / "est.h5", "--truth", tmp_path / "truth.h5",
                 "--plot", tmp_path / "fig.png", "--json")
    figures = json.loads(result.stdout)
    assert figures["on"]["rel_rmse"] == pytest.approx(0.1, rel=1e-5)
    assert figures["off"]["rel_rmse"] == pytest.approx(0.0, abs=1e-7)
    assert figures["method"] == "offe"
    assert cv2.imread(str(tmp_path / "fig.png")) is not None
    small_on, small_off = maps(shape=(3, 4))
    write_thresholds(str(tmp_path / "small.h5"), ThresholdMap(small_on, small_off, np.ones((3, 4), bool)))
    assert_clean_error(run("metrics", "thresholds", tmp_path / "small.h5", "--truth", tmp_path / "truth.h5",
                           check=False), "4x3", "8x6")
    assert_clean_error(run("metrics", "thresholds", tmp_path / "nope.h5", "--truth", tmp_path / "truth.h5",
                           check=False), "nope.h5")
    bad = run("metrics", "thresholds", tmp_path / "est.h5", "--truth", tmp_path / "truth.h5", "--plot",
              tmp_path / "fig.xyz", check=False)
    assert bad.returncode == 2 and not (tmp_path / "fig.xyz").exists()


def test_an_events_only_estimate_says_its_scale_is_relative_and_what_it_cannot_see(tmp_path):
    """Issue 36: the map and `metrics thresholds` say plainly what events alone cannot give; a stimulus's map is
    absolute."""
    stream, truth = tmp_path / "f.aedat4", tmp_path / "t.h5"
    run("simulate", "scene:flicker", "--size", "16x12", "--duration", "2s", "--seed", "1", "--truth", truth,
        "-o", stream)
    for method, scale in (("offe", "relative"), ("stimulus", "absolute")):
        out = tmp_path / f"{method}.h5"
        run("estimate", stream, "--method", method, "-o", out)
        report = json.loads(run("metrics", "thresholds", out, "--truth", truth, "--json").stdout)
        assert report["scale"] == scale
        # offE's fit is a predicted relative error (checked against the truth); stimulus's is in thresholds
        assert ("fit" in report) == (method == "offe") and 0 <= report["off_by_10_percent"] <= 1
        if method == "offe":
            assert report["fit"]["pixels"] > 0 and report["fit"]["error_over_fit_rms"] > 0
        assert ("absolute scale" in report.get("not_observable", "")) == (scale == "relative")


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), shape=st.tuples(st.integers(1, 9), st.integers(1, 9)),
       valid_share=st.floats(0, 1), truth_share=st.floats(0, 1))
def test_pixels_the_truth_does_not_hold_are_left_out(seed, shape, valid_share, truth_share):
    """A QA sweep: a "truth" that is another estimate (two halves of a recording compared) holds a placeholder at
    its invalid pixels, and the figures counted them. Every figure is now the one computed on the pixels valid in
    the truth alone; the invalid fraction is of those; how many were left out is said."""
    rng = np.random.default_rng(seed)
    true_on, true_off = maps(seed, shape)
    est_on, est_off = maps(seed + 1, shape)
    valid = rng.random(shape) < valid_share
    truth_valid = rng.random(shape) < truth_share
    result = threshold_errors(est_on, est_off, valid, true_on, true_off, truth_valid)
    kept = [a[truth_valid] for a in (est_on, est_off, valid, true_on, true_off)]
    alone = threshold_errors(*[a.reshape(1, -1) for a in kept]) if truth_valid.any() else None
    assert result.get("truth_invalid_pixels", 0) == int((~truth_valid).sum())
    assert result["pixels"] == int(truth_valid.sum())
    if alone is None:
        assert result["valid_pixels"] == 0
        return
    for key in ("valid_pixels", "invalid_fraction", "off_by_10_percent", "on", "off"):
        assert result[key] == alone[key], key


def test_the_cli_leaves_out_what_the_truth_does_not_hold_and_says_so(tmp_path):
    true_on, true_off = maps(3, (10, 12))
    holds = np.ones(true_on.shape, bool)
    holds[:, :6] = False
    placeholder_on, placeholder_off = true_on.copy(), true_off.copy()
    placeholder_on[~holds], placeholder_off[~holds] = 5.0, 5.0  # (absurd: counted, they would dominate every figure)
    write_thresholds(tmp_path / "truth.h5", ThresholdMap(placeholder_on, placeholder_off, holds, {"method": "offe"}))
    write_thresholds(tmp_path / "est.h5", ThresholdMap(true_on * 1.05, true_off, np.ones(true_on.shape, bool),
                                                       {"method": "offe"}))
    done = run("metrics", "thresholds", tmp_path / "est.h5", "--truth", tmp_path / "truth.h5", "--json")
    result = json.loads(done.stdout)
    assert result["truth_invalid_pixels"] == 60 and result["valid_pixels"] == 60
    assert result["on"]["rel_rmse"] == pytest.approx(0.05, rel=1e-4) and result["off"]["rel_rmse"] < 1e-6
    assert "60 of 120 pixels hold no valid value" in done.stderr.decode()


def test_a_map_estimated_on_a_crop_is_measured_on_the_crop(tmp_path):
    """A QA sweep: estimated on a crop (the map is the camera's, NaN outside), the same map said "6.1 % valid" in
    estimate and "95.7 % invalid" in metrics (of the whole camera). The pixels outside the crop are left out and
    counted apart (outside_crop_pixels)."""
    stream, truth, estimate = tmp_path / "flicker.aedat4", tmp_path / "truth.h5", tmp_path / "half.h5"
    run("simulate", "scene:flicker", "--size", "32x24", "--duration", "2s", "--seed", "5", "--truth", truth,
        "-o", stream)
    run("estimate", stream, "-o", estimate, "--method", "stimulus", "--crop", "0,0,16,24")
    result = json.loads(run("metrics", "thresholds", estimate, "--truth", truth, "--json").stdout)
    assert result["outside_crop_pixels"] == 16 * 24 and result["pixels"] == 16 * 24
    assert result["invalid_fraction"] < 0.1 and "truth_invalid_pixels" not in result


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31), drift=st.floats(-0.04, 0.05).filter(lambda d: abs(d) > 1e-3),
       origin_us=st.integers(0, 10**7), maps_count=st.integers(1, 5))
def test_a_drifting_truth_is_taken_at_the_estimates_time(tmp_path_factory, seed, drift, origin_us, maps_count):
    """A truth drifting linearly (simulate --thres-drift) against estimates that follow it exactly: a series' map
    compared at its own time and a single map at the middle of its stream show no error (the last map was once
    compared with the truth at the start: +31 % after 16 s at 2 %/s)."""
    tmp_path = tmp_path_factory.mktemp("drift")
    on, off = maps(seed)
    truth = ThresholdMap(on, off, np.ones(on.shape, bool),
                         {"thres_drift_per_s": drift, "thres_drift_origin_us": origin_us})
    write_thresholds(str(tmp_path / "truth.h5"), truth)
    t_us = origin_us + 1_000_000 * np.arange(1, maps_count + 1)
    factors = (1 + drift * (t_us - origin_us) * 1e-6).astype(np.float32)[:, None, None]
    series = ThresholdMap(on * factors, off * factors, np.ones((maps_count, *on.shape), bool), {"method": "stimulus"},
                          t_us=t_us)
    write_thresholds(str(tmp_path / "series.h5"), series)
    for k in range(maps_count):
        figures = json.loads(run("metrics", "thresholds", tmp_path / "series.h5", "--truth", tmp_path / "truth.h5",
                                 "--map", str(k), "--json").stdout)
        assert figures["truth_at_us"] == t_us[k] and figures["map"] == {"index": k, "t_us": int(t_us[k]),
                                                                          "maps": maps_count}
        assert figures["on"]["rel_rmse"] < 1e-5 and figures["off"]["rel_rmse"] < 1e-5
    first, last = origin_us, int(t_us[-1])  # a single map estimated over [first, last]: the truth at the middle
    middle = 1 + drift * ((first + last) // 2 - origin_us) * 1e-6
    single = ThresholdMap(on * np.float32(middle), off * np.float32(middle), np.ones(on.shape, bool),
                          {"method": "natural", "t_first_us": first, "t_last_us": last})
    write_thresholds(str(tmp_path / "single.h5"), single)
    figures = json.loads(run("metrics", "thresholds", tmp_path / "single.h5", "--truth", tmp_path / "truth.h5",
                             "--json").stdout)
    assert figures["on"]["rel_rmse"] < 1e-5 and figures["truth_at_us"] == (first + last) // 2


def test_thresholds_marked_valid_but_not_positive_count_as_invalid(tmp_path):
    """A pixel marked valid that holds 0, a negative value or NaN is no estimate (correct takes none of them):
    counted invalid, with a warning, not scored as a value."""
    on, off = maps(3)
    estimate_on = on.copy()
    estimate_on[0, 0], estimate_on[1, 2], estimate_on[2, 3] = -0.2, 0.0, np.nan
    write_thresholds(str(tmp_path / "est.h5"), ThresholdMap(estimate_on, off, np.ones(on.shape, bool)))
    write_thresholds(str(tmp_path / "truth.h5"), ThresholdMap(on, off, np.ones(on.shape, bool)))
    result = run("metrics", "thresholds", tmp_path / "est.h5", "--truth", tmp_path / "truth.h5", "--json")
    figures = json.loads(result.stdout)
    assert figures["valid_pixels"] == on.size - 3 and figures["on"]["rel_rmse"] < 1e-6
    assert "3 pixels marked valid hold a threshold that is not finite and positive" in result.stderr.decode()
    direct = threshold_errors(estimate_on, off, np.ones(on.shape, bool), on, off)
    assert direct["valid_pixels"] == on.size - 3


@settings(max_examples=60, deadline=None)
@given(pairs=st.lists(st.tuples(st.integers(0, 6), st.floats(0, 1, allow_nan=False)), min_size=3, max_size=40),
       seed=st.integers(0, 2**32 - 1))
def test_rank_correlation_is_spearmans_with_ties_at_their_average_rank(pairs, seed):
    """A QA sweep: ties (a fit takes few distinct values) were ranked by the pixels' order, so the same maps flipped
    gave -0.109 and +0.058 where Spearman's is -0.027. Against the textbook definition, in any order."""
    from evtools.metrics.thresholds import rank_correlation
    from tests.naive import naive_spearman

    a = np.array([p[0] for p in pairs], float)
    b = np.array([p[1] for p in pairs])
    assume(len(set(a.tolist())) > 1 and len(set(b.tolist())) > 1)
    expected = naive_spearman(a, b)
    order = np.random.default_rng(seed).permutation(len(a))
    assert rank_correlation(a, b) == pytest.approx(expected, abs=1e-9)
    assert rank_correlation(a[order], b[order]) == pytest.approx(expected, abs=1e-9)
