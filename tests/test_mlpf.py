"""MLPF (issue 17): the kernel against the slow reference on random streams and random weights, chunk invariance,
training reproducible from its seed, and clean errors on bad weights, thresholds and truth files."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from evtools.events import join, make_events
from evtools.filters import BAFilter, BAFilterError
from evtools.mlpf import FeatureMaker, MlpfError, Weights, auc, load_weights, train
from tests.helpers import cut
from tests.naive.bafilter import naive_mlpf, naive_mlpf_features


def _stream(seed: int, n: int, width: int, height: int, mean_gap_us: int) -> np.ndarray:
    """Random events, no two alike (so that a kept event is found in the input without ambiguity)."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(0, 2 * mean_gap_us + 1, n))
    events = make_events(t, rng.integers(0, width, n), rng.integers(0, height, n), rng.integers(0, 2, n))
    _, first = np.unique(np.stack([events["t"], events["x"], events["y"], events["p"]], 1),
                         axis=0, return_index=True)
    return events[np.sort(first)]


def _weights(seed: int, patch: int, hidden: int, tau_us: int, tau_scale: float = 0.0) -> Weights:
    rng = np.random.default_rng(seed)
    inputs = 2 * patch * patch + 1
    return Weights(rng.normal(0, 1, (inputs, hidden)), rng.normal(0, 0.5, hidden), rng.normal(0, 1, hidden),
                   float(rng.normal()), patch, tau_us, tau_scale)


def _tuples(events):
    return list(zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()))


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**16), patch=st.sampled_from([1, 3, 5, 7]), hidden=st.integers(1, 24),
       tau_us=st.integers(100, 50_000), width=st.integers(1, 12), height=st.integers(1, 12),
       threshold=st.floats(0.05, 0.95), gap_us=st.integers(0, 3000),
       tau_scale=st.sampled_from([0.0, 0.01, 0.1, 0.25, 1.0, 3.0]))
def test_kernel_equals_the_slow_reference(seed, patch, hidden, tau_us, width, height, threshold, gap_us, tau_scale):
    """Fixed time constants and ones that follow the stream's activity (tau_scale > 0)."""
    events = _stream(seed, 300, width, height, gap_us)
    weights = _weights(seed + 1, patch, hidden, tau_us, tau_scale)
    kept, probabilities = naive_mlpf(_tuples(events), weights.w1.tolist(), weights.b1.tolist(), weights.w2.tolist(),
                                     weights.b2, patch, tau_us, threshold, tau_scale, width * height)
    clear = np.abs(np.array(probabilities) - threshold) > 1e-9  # sums in another order may differ in the last bit
    out = BAFilter(width, height, "mlpf", threshold=threshold, weights=weights).process(events)
    chosen = np.isin(np.arange(len(events)), _indices(events, out))
    assert (chosen[clear] == np.array(kept)[clear]).all()
    assert len(out) == chosen.sum()


def test_a_time_constant_beyond_int64_is_capped_as_the_reference_caps_it():
    """Events hours apart on a large sensor with a large tau_scale ask for a time constant beyond int64: capped at
    2^62 us in the kernel as in the reference (it was an undefined float-to-int conversion)."""
    t = np.array([0, 10, 2**61, 2**61 + 7, 2**61 + 9, 2**62 - 5], np.int64)
    events = make_events(t, [5, 6, 5, 6, 5, 6], [5, 5, 6, 6, 5, 5], [1, 0, 1, 1, 0, 1])
    weights = _weights(4, 3, 5, 1000, tau_scale=100.0)
    rows = FeatureMaker(1280, 720, 3, 1000, 100.0).features(events, np.ones(len(events), bool))
    expected = np.array(naive_mlpf_features(_tuples(events), 3, 1000, 100.0, 1280 * 720), np.float32)
    np.testing.assert_allclose(rows, expected, rtol=1e-6, atol=1e-6)
    assert (rows[3:, :18] > 0).any()  # the earlier events still count: the capped tau spans the gap
    kept, _ = naive_mlpf(_tuples(events), weights.w1.tolist(), weights.b1.tolist(), weights.w2.tolist(), weights.b2,
                         3, 1000, 0.5, 100.0, 1280 * 720)
    out = BAFilter(1280, 720, "mlpf", threshold=0.5, weights=weights).process(events)
    assert len(out) == sum(kept)


def _indices(events, out):
    """Positions in ``events`` of the events of ``out`` (a subsequence)."""
    positions, j = [], 0
    for i in range(len(events)):
        if j < len(out) and events[i].tobytes() == out[j].tobytes():
            positions.append(i)
            j += 1
    assert j == len(out), "the output is not a subsequence of the input"
    return positions


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**16), patch=st.sampled_from([1, 3, 7]), tau_us=st.integers(100, 20_000),
       gap_us=st.integers(0, 1000), tau_scale=st.sampled_from([0.0, 0.05, 0.5, 2.0]),
       cuts=st.lists(st.integers(0, 200)))
def test_features_equal_the_slow_reference(seed, patch, tau_us, gap_us, tau_scale, cuts):
    """Whatever the chunks (the activity clock and the maps carry over)."""
    events = _stream(seed, 200, 9, 7, gap_us)
    take = np.random.default_rng(seed).random(len(events)) < 0.5
    maker = FeatureMaker(9, 7, patch, tau_us, tau_scale)
    bounds = [0, *sorted(cuts), len(events)]
    rows = np.concatenate([maker.features(events[a:b], take[a:b]) for a, b in zip(bounds, bounds[1:]) if b >= a])
    expected = np.array(naive_mlpf_features(_tuples(events), patch, tau_us, tau_scale, 63), np.float32)[take]
    np.testing.assert_allclose(rows, expected, rtol=1e-6, atol=1e-6)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), cuts=st.lists(st.integers(0, 400), max_size=6))
def test_chunking_does_not_change_the_output(seed, cuts):
    events = _stream(seed, 400, 16, 12, 200)
    weights = _weights(seed, 5, 8, 5_000, tau_scale=0.3)
    whole = BAFilter(16, 12, "mlpf", weights=weights, threshold=0.4).process(events)
    mlpf = BAFilter(16, 12, "mlpf", weights=weights, threshold=0.4)
    parts = join([mlpf.process(part) for part in cut(events, cuts)] + [mlpf.flush()])
    assert parts.tobytes() == whole.tobytes()


def _labelled(seed: int, n: int = 6000):
    """Signal: events along a moving bar (neighbours fire together); noise: uniform random events."""
    rng = np.random.default_rng(seed)
    t_signal = np.sort(rng.integers(0, 1_000_000, n // 2))
    x_signal = (t_signal // 20_000) % 32
    y_signal = rng.integers(0, 24, n // 2)
    t_noise = np.sort(rng.integers(0, 1_000_000, n // 2))
    t = np.concatenate([t_signal, t_noise])
    order = np.argsort(t, kind="stable")
    x = np.concatenate([x_signal, rng.integers(0, 32, n // 2)])[order]
    y = np.concatenate([y_signal, rng.integers(0, 24, n // 2)])[order]
    labels = np.concatenate([np.ones(n // 2), np.zeros(n // 2)])[order]
    events = make_events(t[order], x, y, rng.integers(0, 2, n))
    return events, labels


def test_training_is_reproducible_and_learns_a_tiny_problem():
    events, labels = _labelled(3)
    features = FeatureMaker(32, 24, 5, 20_000).features(events, np.ones(len(events), bool))
    validation = np.arange(len(events)) >= 0.8 * len(events)
    first, report = train(features, labels, validation, patch=5, tau_us=20_000, hidden=8, seed=11, epochs=15)
    second, _ = train(features, labels, validation, patch=5, tau_us=20_000, hidden=8, seed=11, epochs=15)
    for a, b in zip((first.w1, first.b1, first.w2), (second.w1, second.b1, second.w2)):
        assert a.tobytes() == b.tobytes()
    assert first.b2 == second.b2
    assert report.validation_auc > 0.85, report
    other, _ = train(features, labels, validation, patch=5, tau_us=20_000, hidden=8, seed=12, epochs=15)
    assert other.w1.tobytes() != first.w1.tobytes()


@settings(max_examples=30, deadline=None)
@given(scores=st.lists(st.integers(0, 5), min_size=2, max_size=30), labels=st.lists(st.booleans(), min_size=2,
                                                                                     max_size=30))
def test_auc_is_the_pairwise_probability(scores, labels):
    n = min(len(scores), len(labels))
    scores, labels = np.array(scores[:n], float), np.array(labels[:n])
    positives, negatives = scores[labels], scores[~labels]
    if not len(positives) or not len(negatives):
        return
    expected = np.mean([(p > q) + 0.5 * (p == q) for p in positives for q in negatives])
    assert auc(scores, labels) == pytest.approx(expected)


def test_weights_files_from_before_tau_scale_keep_their_fixed_time_constant(tmp_path):
    """A weights file written before ``tau_scale`` existed (round 2's) loads with a fixed ``tau_us`` and filters
    as those weights did; a file with ``tau_scale`` keeps it; a negative or infinite one is refused."""
    old = _weights(3, 5, 6, 7000)
    np.savez(tmp_path / "old.npz", w1=old.w1, b1=old.b1, w2=old.w2, b2=np.float64(old.b2), patch=np.int64(5),
             tau_us=np.int64(7000))
    loaded = load_weights(tmp_path / "old.npz")
    assert loaded.tau_scale == 0.0 and loaded.tau_us == 7000
    events = _stream(5, 400, 16, 12, 300)
    assert (BAFilter(16, 12, "mlpf", weights=loaded).process(events).tobytes()
            == BAFilter(16, 12, "mlpf", weights=old).process(events).tobytes())
    scaled = _weights(3, 5, 6, 0, tau_scale=0.4)
    scaled.save(tmp_path / "new.npz")
    assert load_weights(tmp_path / "new.npz").tau_scale == 0.4
    for bad in (-0.1, float("inf")):
        with pytest.raises(MlpfError, match="tau_scale"):
            _weights(3, 5, 6, 0, tau_scale=bad).check("w")


def test_bad_weights_and_thresholds(tmp_path):
    weights = _weights(0, 5, 6, 1000)
    for threshold in (0.0, 1.0, -0.1, 1.5):
        with pytest.raises(BAFilterError, match="threshold"):
            BAFilter(8, 8, "mlpf", weights=weights, threshold=threshold)
    weights.save(tmp_path / "w.npz")
    assert load_weights(tmp_path / "w.npz").w1.tobytes() == weights.w1.tobytes()
    wrong = Weights(weights.w1[:-1], weights.b1, weights.w2, weights.b2, 5, 1000)
    with pytest.raises(MlpfError, match="do not fit a 5x5 patch"):
        wrong.check("w")
    wrong.save(tmp_path / "wrong.npz")
    with pytest.raises(BAFilterError, match="wrong.npz"):
        BAFilter(8, 8, "mlpf", weights=str(tmp_path / "wrong.npz"))
    other_patch = Weights(weights.w1, weights.b1, weights.w2, weights.b2, 7, 1000)
    with pytest.raises(MlpfError, match="7x7"):
        other_patch.check("w")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(BAFilterError, match="junk.npz"):
        BAFilter(8, 8, "mlpf", weights=str(tmp_path / "junk.npz"))
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(BAFilterError, match="not MLPF weights"):
        BAFilter(8, 8, "mlpf", weights=str(tmp_path / "other.npz"))


@pytest.mark.slow
@pytest.mark.parametrize("name, seed, margin", [("dvs128_walk.aedat", 1, -0.02), ("dvxplorer_sample.aedat4", 2, 0.03)])
def test_the_shipped_mlpf_against_the_best_stcf(tmp_path, name, seed, margin):
    """5 Hz shot + 0.2 Hz leak injected into two shared recordings (noise seeds that training did not use): the AUC
    of mlpf's threshold sweep with the shipped weights against STCF's correlation-window sweep at the defaults and
    at the best radius / k of samples/stcf_grid.md. What the README says: above it by 0.06 on the DVXplorer, 0.004
    below it on the DVS128 walk (samples/mlpf.md); the margins leave room for these three STCF settings."""
    import json

    from tests.conftest import data_file
    from tests.helpers import run

    noisy, truth = tmp_path / "noisy.aedat4", tmp_path / "truth.h5"
    run("simulate", data_file(name), "--shot-noise-rate-hz", 5, "--leak-rate-hz", 0.2, "--seed", seed,
        "--truth", truth, "-o", noisy)

    def auc_of(method, sweep, *options):
        result = run("metrics", "roc", noisy, "--truth", truth, "--method", method, "--sweep", sweep, *options,
                     "--json")
        return json.loads(result.stdout)["methods"][0]["auc"]

    dt = "dt-us=1000,3000,10000,30000,100000"
    stcf = max(auc_of("stcf", dt), auc_of("stcf", dt, "--set", "radius=2", "--set", "k=6"),  # the grid's best
               auc_of("stcf", dt, "--set", "radius=3", "--set", "k=6", "--polarity-maps"))
    mlpf = auc_of("mlpf", "threshold=0.003,0.01,0.03,0.1,0.3,0.5,0.7,0.9,0.97,0.99,0.997")
    assert mlpf > stcf + margin, (mlpf, stcf)


def test_cli_trains_filters_and_refuses_bad_input(tmp_path):
    """train-denoiser on a small simulated stream with injected noise, then bafilter --method mlpf with those
    weights; one-line errors: a threshold outside (0, 1) (usage, 2), weights of another shape, a truth file
    without labels, a truth file of another stream (1), and -o naming an input."""
    import json

    from tests.helpers import assert_clean_error, run

    clean, noisy, truth = tmp_path / "clean.aedat4", tmp_path / "noisy.aedat4", tmp_path / "truth.h5"
    run("simulate", "scene:bars", "--size", "32x24", "--duration", "1s", "--seed", "3", "--truth",
        tmp_path / "scene.h5", "-o", clean)
    run("simulate", clean, "--shot-noise-rate-hz", 20, "--leak-rate-hz", 0.5, "--seed", 4, "--truth", truth,
        "-o", noisy)
    weights = tmp_path / "w.npz"
    report = json.loads(run("metrics", "train-denoiser", noisy, "--truth", truth, "--patch", 5, "--hidden", 8,
                            "--epochs", 10, "-o", weights, "--json").stdout)
    assert report["held_out_auc"] > 0.8 and weights.exists()
    out = tmp_path / "out.aedat4"
    run("bafilter", noisy, "--method", "mlpf", "--weights", weights, "-o", out)
    assert out.exists()
    for threshold in ("0", "1", "1.5"):
        bad = run("bafilter", noisy, "--method", "mlpf", "--threshold", threshold, "-o", tmp_path / "x.aedat4",
                  check=False)
        assert bad.returncode == 2 and b"--threshold" in bad.stderr
    _weights(0, 3, 4, 1000).save(tmp_path / "small.npz")
    wrong = Weights(np.zeros((10, 4)), np.zeros(4), np.zeros(4), 0.0, 3, 1000)
    np.savez(tmp_path / "wrong.npz", w1=wrong.w1, b1=wrong.b1, w2=wrong.w2, b2=0.0, patch=3, tau_us=1000)
    assert_clean_error(run("bafilter", noisy, "--method", "mlpf", "--weights", tmp_path / "wrong.npz", "-o",
                           tmp_path / "x.aedat4", check=False), "wrong.npz", "3x3 patch")
    assert_clean_error(run("metrics", "train-denoiser", noisy, "--truth", tmp_path / "scene.h5", "-o",
                           tmp_path / "w2.npz", check=False), "labels")
    assert_clean_error(run("metrics", "train-denoiser", clean, "--truth", truth, "-o", tmp_path / "w2.npz",
                           check=False), "truth.h5")
    assert not (tmp_path / "x.aedat4").exists() and not (tmp_path / "w2.npz").exists()
    refused = run("metrics", "train-denoiser", noisy, "--truth", truth, "-o", noisy, check=False)
    assert refused.returncode == 2 and noisy.read_bytes()[:4] == b"#!AE"


def _texture(width, height, duration_us, *, seed, pan, wobble):
    """A natural moving texture seen by ideal pixels (tests/naive/texture.py): the signal events."""
    from tests.naive.texture import crossings, texture_signal

    times, levels = texture_signal(width, height, duration_us, seed=seed, pan_px_s=pan, wobble_px=wobble)
    return crossings(times, levels, 0.2, 0.2)


def _with_noise(signal, width, height, duration_us, *, shot_hz, leak_hz, noise_seed):
    """``signal`` with background activity drawn by plain numpy (tests/naive/noise.py): evtools records and a label
    per event (0 signal, 1 noise)."""
    from tests.naive.noise import background_activity, merge

    events, labels = merge(signal, background_activity(width, height, 0, duration_us, shot_hz=shot_hz,
                                                       leak_hz=leak_hz, seed=noise_seed))
    return make_events(events["t"], events["x"], events["y"], events["p"]), labels


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(shot_hz=st.floats(0.5, 5.0), leak_hz=st.sampled_from([0.0, 0.2, 0.5]), seed=st.integers(0, 2**16),
       cuts=st.lists(st.integers(0, 50_000), max_size=4))
@example(shot_hz=5.0, leak_hz=0.5, seed=457, cuts=[])  # CI's draw: 0.27 Hz of leak for 0.5
def test_the_noise_meter_measures_background_activity(shot_hz, leak_hz, seed, cuts):
    """Shot and leak noise drawn by independent code over a 48 x 32 sensor whose left third sees a moving texture:
    the rates measured on the quiet pixels, whatever the chunks. Shot: bounds from 30 draws at 0.5-8 Hz (seeds 1,
    2), -10.5 % to +2.2 %. Leak (ON beyond OFF): its error is statistical, the ON - OFF count of a pixel having a
    variance of its noise events, so its standard error is sqrt((shot + leak) / (pixels x duration)): the bound is
    3.5 of those plus 0.05 Hz of bias (13 draws at 5 Hz shot, 0.5 Hz leak: mean 0.455 Hz, sd 0.10 Hz against a
    standard error of 0.08; hypothesis drew 0.27 Hz, 2.9 of them, which a fixed 0.15 Hz bound refused)."""
    from evtools.mlpf import NoiseMeter

    events, _ = _with_noise(_texture(16, 32, 2_000_000, seed=seed, pan=(10.0, 0.0), wobble=4.0), 48, 32, 2_000_000,
                            shot_hz=shot_hz, leak_hz=leak_hz, noise_seed=seed + 1)
    meter = NoiseMeter(48, 32)
    for part in cut(events, cuts):
        meter.process(part)
    rates = meter.rates()
    assert rates.source == "quiet pixels" and rates.pixels >= 100
    assert abs(rates.shot_hz / shot_hz - 1) < 0.15, rates
    standard_error = math.sqrt((rates.shot_hz + rates.leak_hz) / (rates.pixels * rates.duration_us * 1e-6))
    assert abs(rates.leak_hz - leak_hz) < 3.5 * standard_error + 0.05, (rates, standard_error)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**16), cuts=st.lists(st.integers(0, 3000), max_size=5))
def test_self_labelling_does_not_depend_on_the_chunks(seed, cuts):
    from evtools.mlpf import NoiseRates, SelfLabeller

    events = _stream(seed, 3000, 20, 16, 300)
    rates = NoiseRates(3.0, 0.3, 100, "given", len(events), int(events["t"][-1] - events["t"][0]))
    whole = SelfLabeller(20, 16, rates, seed)
    first = [whole.process(events), whole.flush()]
    parts = SelfLabeller(20, 16, rates, seed)
    second = [parts.process(part) for part in cut(events, cuts)] + [parts.flush()]
    assert join([e for e, _ in first]).tobytes() == join([e for e, _ in second]).tobytes()
    assert np.concatenate([l for _, l in first]).tobytes() == np.concatenate([l for _, l in second]).tobytes()
    labels = np.concatenate([l for _, l in first])
    assert (labels == 0).sum() <= len(events) and (labels != 0).any()  # events kept as signal, noise injected


def _write_labelled(path, truth, events, labels, width, height):
    import h5py

    import evtools

    evtools.write(path, events, evtools.StreamInfo(width, height))
    with h5py.File(truth, "w") as h5:
        h5["label"] = labels.astype(np.uint8)


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["wobble", "pan and wobble"])
def test_a_model_trained_without_labels_is_as_good_as_one_trained_on_the_truth(tmp_path, scene):
    """Issue 41's measure: a natural texture (independent generator) with 5 Hz shot + 0.2 Hz leak noise (independent
    code); `train-denoiser` on it without --truth and with its true labels; both scored on another noise draw with
    the true labels: AUC within 0.01. (A third setup, a pure pan of a dense texture at 1 Hz with no quiet pixel,
    measures 8.7 Hz of noise and lands 0.018 below: written in the README.)"""
    import json

    from tests.helpers import run

    pan, wobble = {"wobble": ((0.0, 0.0), 6.0), "pan and wobble": ((20.0, 5.0), 3.0)}[scene]
    signal = _texture(96, 72, 2_000_000, seed=7, pan=pan, wobble=wobble)
    for name, noise_seed in (("train", 101), ("eval", 202)):
        events, labels = _with_noise(signal, 96, 72, 2_000_000, shot_hz=5.0, leak_hz=0.2, noise_seed=noise_seed)
        _write_labelled(tmp_path / f"{name}.aedat4", tmp_path / f"{name}.h5", events, labels, 96, 72)
    report = json.loads(run("metrics", "train-denoiser", tmp_path / "train.aedat4", "-o", tmp_path / "self.npz",
                            "--json").stdout)
    assert report["labels"] == "self" and report["noise"][0]["shot_rate_hz"] > 0
    run("metrics", "train-denoiser", tmp_path / "train.aedat4", "--truth", tmp_path / "train.h5", "-o",
        tmp_path / "truth.npz")

    def auc_of(weights):
        result = run("metrics", "roc", tmp_path / "eval.aedat4", "--truth", tmp_path / "eval.h5", "--method", "mlpf",
                     "--weights", weights, "--sweep", "threshold=0.003,0.01,0.03,0.1,0.2,0.3,0.5,0.7,0.8,0.9,0.97,"
                     "0.99,0.997", "--json")
        return json.loads(result.stdout)["methods"][0]["auc"]

    self_trained, truth_trained = auc_of(tmp_path / "self.npz"), auc_of(tmp_path / "truth.npz")
    assert truth_trained > 0.8
    assert self_trained > truth_trained - 0.01, (self_trained, truth_trained)


def test_training_without_labels_from_the_command_line(tmp_path):
    """Recordings alone train a model that filters; the noise rate measured (or given) is reported; mistakes are
    one-line errors: --noise-rate-hz with --truth (usage, 2), a recording of one instant (1)."""
    import json

    import evtools
    from tests.helpers import assert_clean_error, run

    events, _ = _with_noise(_texture(48, 36, 1_000_000, seed=3, pan=(10.0, 0.0), wobble=3.0), 48, 36, 1_000_000,
                            shot_hz=2.0, leak_hz=0.1, noise_seed=4)
    recording = tmp_path / "rec.aedat4"
    evtools.write(recording, events, evtools.StreamInfo(48, 36))
    report = json.loads(run("metrics", "train-denoiser", recording, recording, "-o", tmp_path / "w.npz", "--epochs",
                            5, "--json").stdout)
    assert len(report["noise"]) == 2 and report["held_out_auc"] > 0.7
    assert report["noise"][0]["measured_on"] in ("quiet pixels", "rejected events")
    given = json.loads(run("metrics", "train-denoiser", recording, "--noise-rate-hz", 3, "-o", tmp_path / "g.npz",
                           "--epochs", 3, "--json").stdout)
    assert given["noise"][0] == {**given["noise"][0], "shot_rate_hz": 3.0, "leak_rate_hz": 0.0, "measured_on": "given"}
    out = tmp_path / "out.aedat4"
    run("bafilter", recording, "--method", "mlpf", "--weights", tmp_path / "w.npz", "-o", out)
    kept = evtools.read(out)[0]
    assert 0 < len(kept) < len(events)
    truth = tmp_path / "t.h5"
    _write_labelled(tmp_path / "x.aedat4", truth, events, np.zeros(len(events)), 48, 36)
    usage = run("metrics", "train-denoiser", recording, "--truth", truth, "--noise-rate-hz", 1, "-o",
                tmp_path / "u.npz", check=False)
    assert usage.returncode == 2 and b"--noise-rate-hz" in usage.stderr
    instant = tmp_path / "instant.aedat4"
    evtools.write(instant, make_events([5, 5], [1, 2], [1, 1], [1, 0]), evtools.StreamInfo(48, 36))
    assert_clean_error(run("metrics", "train-denoiser", instant, "-o", tmp_path / "i.npz", check=False),
                       "instant.aedat4", "too short")
    assert not (tmp_path / "u.npz").exists() and not (tmp_path / "i.npz").exists()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16), signal=st.integers(0, 60), noise=st.integers(0, 60))
def test_each_stream_trains_on_as_much_noise_as_signal(seed, signal, noise):
    """train-denoiser's per-stream balance: the commoner kind thinned to the rarer's count, rows in their order
    with their held-out flags; a stream of one kind kept whole."""
    from evtools.cli.metrics_train import _balanced

    rng = np.random.default_rng(seed)
    labels = rng.permutation(np.r_[np.ones(signal, bool), np.zeros(noise, bool)])
    rows = np.arange(len(labels), dtype=np.float32)[:, None] * np.ones((1, 3), np.float32)
    check = rng.random(len(labels)) < 0.3
    features, kept_signal, kept_check = _balanced((rows, labels, check), np.random.default_rng(seed + 1))
    if min(signal, noise) == 0:
        assert len(features) == len(labels)
        return
    index = features[:, 0].astype(int)
    assert kept_signal.sum() == (~kept_signal).sum() == min(signal, noise)
    assert (np.diff(index) > 0).all()
    assert (labels[index] == kept_signal).all() and (check[index] == kept_check).all()


@pytest.mark.parametrize("labelled", [False, True])
def test_training_stopped_while_reading_makes_no_weights(tmp_path, labelled):
    """A QA sweep: Ctrl-C while train-denoiser read its recording either said "too few labelled events" (exit 1) or
    wrote weights trained on a fifth of the sample under the final name, unmarked. A stop while reading now
    makes no weights file and exits 130."""
    import signal
    import subprocess
    import sys
    from pathlib import Path

    from tests.helpers import run, wait_until

    recording, truth = tmp_path / "big.aedat4", tmp_path / "t.h5"
    run("simulate", "scene:bars", "--size", "346x260", "--duration", "3s", "--seed", "1", "--shot-noise-rate-hz",
        "5", "--truth", truth, "-o", recording)
    out = tmp_path / "w.npz"
    process = subprocess.Popen([str(Path(sys.executable).parent / "evtools"), "metrics", "train-denoiser",
                                str(recording), *(["--truth", str(truth)] if labelled else []), "-o", str(out)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    def read_some() -> bool:  # (the process has read into its recording: a state, not a time)
        with open(f"/proc/{process.pid}/io") as io:
            return int(next(line for line in io if line.startswith("rchar")).split()[1]) > 4_000_000

    try:
        wait_until(read_some, "train-denoiser reading its recording")
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 130 and b"Traceback" not in stderr, stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.aedat4", "t.h5"]  # (no weights, no temporary)


def test_training_on_too_little_names_the_recording(tmp_path):
    """A QA sweep: train-denoiser on a 2-event file said "too few labelled events to train (0) and check (0)",
    naming no file; no weights are written."""
    import evtools
    from tests.helpers import assert_clean_error, run

    two = tmp_path / "two.aedat4"
    evtools.write(two, evtools.from_columns([0, 1000], [1, 2], [1, 2], [1, 0]), evtools.StreamInfo(8, 8))
    done = run("metrics", "train-denoiser", two, "--noise-rate-hz", "5", "-o", tmp_path / "w.npz", check=False)
    assert_clean_error(done, "two.aedat4: too few labelled events")
    assert not (tmp_path / "w.npz").exists()
