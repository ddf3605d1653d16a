"""bafilter: kernels against slow references, chunk invariance, dv-processing equality, the CLI."""

from __future__ import annotations

import subprocess
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from evtools.filters import BY_NAME, BAFilter, BAFilterError, ba_filter, not_applying
from evtools.events import StreamInfo, join, make_events
from evtools.formats import create_events
from tests.conftest import data_file
from tests.helpers import EVTOOLS, assert_clean_error, assert_same_events, cut, read_all, run
from tests.naive.bafilter import (naive_baf, naive_dwf, naive_hot_pixels, naive_order_n, naive_refractory,
                                  naive_stcf, naive_stcf_polarity_maps, naive_ynoise)

W, H = 12, 9


def dense_events(n: int, seed: int, width: int = W, height: int = H, span_us: int = 40) -> np.ndarray:
    """Events on a small sensor, close in time (so that every filter both keeps and rejects), with ties."""
    rng = np.random.default_rng(seed)
    t = 1_000 + np.sort(rng.integers(0, span_us * n, n))
    return make_events(t, rng.integers(0, width, n), rng.integers(0, height, n), rng.integers(0, 2, n))


def tuples(events):
    return [(int(e["t"]), int(e["x"]), int(e["y"]), bool(e["p"])) for e in events]


def kept_mask(events, method, preset="evtools", **params):
    """The keep mask of one filter stage over ``events`` (its kernel), checked against ``ba_filter``'s output."""
    ba = BAFilter(W, H, method, preset=preset, **params)
    if method == "hotpixel":
        join([ba.process(events), ba.flush()])
        mask = ~ba.hot_map[events["y"], events["x"]]
    else:
        kept = ba.stages[0].filter(events)
        mask = np.zeros(len(events), dtype=bool)
        mask[_positions(events, kept)] = True
    assert_same_events(ba_filter(events, W, H, method, preset=preset, **params), events[mask])
    return mask


def _positions(events, kept):
    """Indices in ``events`` of the subsequence ``kept`` (records compared byte for byte, matched in order)."""
    rows = events.view(np.void)
    wanted = kept.view(np.void)
    positions, j = [], 0
    for i in range(len(rows)):
        if j < len(wanted) and rows[i] == wanted[j]:
            positions.append(i)
            j += 1
    assert j == len(wanted), "kept events are not a subsequence of the input"
    return np.array(positions, dtype=np.int64)


# -- kernels == slow references -----------------------------------------------------------------------------------


@pytest.mark.parametrize("preset", ["evtools", "dv", "jaer"])
@pytest.mark.parametrize("dt_us", [1, 150, 2_000])
def test_baf_equals_reference(preset, dt_us):
    for seed in range(3):
        events = dense_events(1_500, seed)
        expected = naive_baf(tuples(events), W, H, dt_us, preset)
        np.testing.assert_array_equal(kept_mask(events, "baf", preset, dt_us=dt_us), expected)
        assert 0 < sum(expected) < len(events) or dt_us == 1


@pytest.mark.parametrize("preset", ["evtools", "jaer"])
@pytest.mark.parametrize("k,radius,polarity", [(1, 1, False), (2, 1, True), (3, 2, False), (4, 2, True)])
def test_stcf_equals_reference(preset, k, radius, polarity):
    for seed in range(2):
        events = dense_events(1_500, seed + 10)
        expected = naive_stcf(tuples(events), W, H, 300 * k, k, radius, polarity, preset)
        got = kept_mask(events, "stcf", preset, dt_us=300 * k, k=k, radius=radius, polarity=polarity)
        np.testing.assert_array_equal(got, expected)
        assert 0 < sum(expected) < len(events)


@pytest.mark.parametrize("k,radius", [(1, 1), (2, 1), (3, 2), (5, 3)])
def test_stcf_polarity_maps_equals_reference(k, radius):
    for seed in range(2):
        events = dense_events(1_500, seed + 30)
        expected = naive_stcf_polarity_maps(tuples(events), 300 * k, k, radius)
        got = kept_mask(events, "stcf", "evtools", dt_us=300 * k, k=k, radius=radius, polarity_maps=True)
        np.testing.assert_array_equal(got, expected)
        assert 0 < sum(expected) < len(events)
    # it differs from the single map exactly where another polarity came between
    single = kept_mask(events, "stcf", "evtools", dt_us=300 * k, k=k, radius=radius)
    assert (single <= got).all()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), radius=st.integers(1, 3), k=st.integers(1, 6), dt_us=st.integers(1, 3_000),
       width=st.integers(1, 20), height=st.integers(1, 20))
def test_ynoise_equals_reference(seed, radius, k, dt_us, width, height):
    """The filter added to show what adding one takes (issue 40): its kernel against its naive reference."""
    events = dense_events(800, seed, width, height)
    expected = np.array(naive_ynoise(tuples(events), dt_us, radius, k), dtype=bool)
    assert_same_events(ba_filter(events, width, height, "ynoise", dt_us=dt_us, radius=radius, k=k), events[expected])


@pytest.mark.parametrize("preset", ["evtools", "jaer"])
@pytest.mark.parametrize("window,distance,k", [(1, 2, 1), (8, 3, 1), (20, 4, 3)])
def test_dwf_equals_reference(preset, window, distance, k):
    events = dense_events(1_500, 20)
    expected = naive_dwf(tuples(events), window, distance, k, preset)
    np.testing.assert_array_equal(kept_mask(events, "dwf", preset, window=window, distance=distance, k=k), expected)
    assert 0 < sum(expected) < len(events)


@pytest.mark.parametrize("preset", ["evtools", "jaer"])
@pytest.mark.parametrize("dt_us", [50, 400])
def test_order_n_equals_reference(preset, dt_us):
    events = dense_events(1_500, 30)
    expected = naive_order_n(tuples(events), W, H, dt_us, preset)
    np.testing.assert_array_equal(kept_mask(events, "orderN", preset, dt_us=dt_us), expected)
    assert 0 < sum(expected) < len(events)


@pytest.mark.parametrize("preset", ["evtools", "jaer"])
def test_refractory_equals_reference(preset):
    events = dense_events(1_500, 40)
    events["t"] = events["t"] // 200 * 200  # many exact multiples, so that <= and < differ
    expected = naive_refractory(tuples(events), 400, preset)
    np.testing.assert_array_equal(kept_mask(events, "refractory", preset, dt_us=400), expected)
    assert 0 < sum(expected) < len(events)


def test_hot_pixels_equal_reference_and_are_found():
    rng = np.random.default_rng(5)
    events = dense_events(3_000, 50, span_us=300)
    hot = make_events(np.sort(rng.integers(1_000, 1_000 + 300 * 3_000, 1_500)), 3, 4, 1)
    both = join([events, hot])
    both = both[np.argsort(both["t"], kind="stable")]
    params = {"learn_us": 200_000, "hot_ratio": 5.0, "hot_min_events": 20, "hot_rate_hz": 10_000.0}
    expected = naive_hot_pixels(tuples(both), W, H, **params)
    got = kept_mask(both, "hotpixel", **params)
    np.testing.assert_array_equal(got, expected)
    assert not got[(both["x"] == 3) & (both["y"] == 4)].any()  # the hot pixel is gone
    assert got[~((both["x"] == 3) & (both["y"] == 4))].mean() > 0.95


def test_a_lone_pixel_is_not_hot_for_want_of_neighbours():
    """On a 1 x 1 sensor every event was dropped: a pixel with no neighbour passed the relative test (a QA sweep).
    Only the absolute rate can make it hot; the naive reference agrees."""
    events = make_events(np.arange(0, 2_000_000, 20_000), 0, 0, 1)  # 50 Hz, 100 events
    params = {"learn_us": 1_000_000, "hot_ratio": 5.0, "hot_min_events": 20, "hot_rate_hz": 10_000.0}
    for stream, hot in ((events, False), (make_events(np.arange(0, 2_000_000, 50), 0, 0, 1), True)):  # 20 kHz
        ba = BAFilter(1, 1, "hotpixel", **params)
        kept = join([ba.process(stream), ba.flush()])
        assert bool(ba.hot_map[0, 0]) == hot and len(kept) == (0 if hot else len(stream))
        assert naive_hot_pixels(tuples(stream), 1, 1, **params) == [not hot] * len(stream)


# -- chunk invariance ---------------------------------------------------------------------------------------------

CHAINS = ["baf", "stcf", "dwf", "orderN", "refractory", "hotpixel", "ynoise", "hotpixel,refractory,stcf",
          "refractory,hotpixel,dwf", "orderN,baf", "refractory,ynoise"]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cuts=st.lists(st.integers(0, 2_000), max_size=10), chain=st.sampled_from(CHAINS),
       preset=st.sampled_from(["evtools", "jaer"]), seed=st.integers(0, 3))
def test_chunking_does_not_change_the_output(cuts, chain, preset, seed):
    events = dense_events(2_000, seed, span_us=100)
    if any(preset not in BY_NAME[method].defaults for method in chain.split(",")):
        preset = "evtools"  # (jAER has no ynoise)
    params = applying(chain, preset, learn_us=30_000, hot_min_events=5, dt_us=300, window=10, distance=3)
    expected = ba_filter(events, W, H, chain, preset=preset, **params)
    ba = BAFilter(W, H, chain, preset=preset, **params)
    got = join([ba.process(part) for part in cut(events, cuts)] + [ba.flush()])
    assert_same_events(got, expected)
    assert ba.events_in == len(events) and ba.events_out == len(expected)


def applying(chain, preset, **params):
    """Those of ``params`` some stage of ``chain`` has (the others are refused, as on the command line)."""
    stray = not_applying(chain.split(","), preset, params)
    return {name: value for name, value in params.items() if name not in stray}


def test_a_parameter_no_stage_has_is_refused():
    """(It was ignored: `ba_filter(..., "baf", k=3)` ran baf as if k were not there.)"""
    with pytest.raises(BAFilterError, match=r"k, window do\(es\) not apply to baf,refractory \(preset evtools\)"):
        ba_filter(dense_events(10, 0), W, H, "baf,refractory", k=3, window=4, dt_us=100)
    with pytest.raises(BAFilterError, match="polarity_maps do"):
        BAFilter(W, H, "stcf", preset="jaer", polarity_maps=True)


@settings(max_examples=30, deadline=None)
@given(cuts=st.lists(st.integers(0, 2_000), max_size=10), seed=st.integers(0, 3), radius=st.integers(1, 3))
def test_stcf_polarity_maps_chunking_does_not_change_the_output(cuts, seed, radius):
    events = dense_events(2_000, seed, span_us=100)
    expected = ba_filter(events, W, H, "stcf", dt_us=300, radius=radius, polarity_maps=True)
    ba = BAFilter(W, H, "stcf", dt_us=300, radius=radius, polarity_maps=True)
    assert_same_events(join([ba.process(part) for part in cut(events, cuts)] + [ba.flush()]), expected)


def test_learning_stretch_cap_is_chunk_invariant(monkeypatch):
    import evtools.filters.hotpixel

    monkeypatch.setattr(evtools.filters.hotpixel, "MAX_LEARN_EVENTS", 100)
    events = dense_events(1_000, 3)
    expected = ba_filter(events, W, H, "hotpixel", hot_min_events=3, hot_ratio=2.0)
    for cuts in ([100], [50, 100], [99], [101, 500]):
        ba = BAFilter(W, H, "hotpixel", hot_min_events=3, hot_ratio=2.0)
        got = join([ba.process(part) for part in cut(events, cuts)] + [ba.flush()])
        assert_same_events(got, expected)
    assert len(expected) < len(events)


def test_chain_later_stages_see_only_kept_events():
    events = dense_events(2_000, 7)
    first = ba_filter(events, W, H, "refractory", dt_us=300)
    assert_same_events(ba_filter(events, W, H, "refractory,baf", dt_us=300), ba_filter(first, W, H, "baf",
                                                                                         dt_us=300))


def test_empty_and_single_event():
    for chain in CHAINS:
        assert len(ba_filter(dense_events(0, 0), W, H, chain)) == 0
        one = dense_events(1, 0)
        # one event has no neighbour: BA filters drop it, refractory and hotpixel keep it
        assert len(ba_filter(one, W, H, chain)) == (1 if chain in ("refractory", "hotpixel") else 0)
    assert len(ba_filter(make_events([5], [1], [1], [1]), W, H, "baf", preset="dv", dt_us=10)) == 1  # t < dt


def test_bad_parameters():
    for kwargs, needle in (({"methods": "bogus"}, "unknown method"), ({"dt_us": 0}, "dt_us"),
                           ({"methods": "stcf", "k": 9}, "k must"), ({"methods": "dwf", "window": 0}, "window"),
                           ({"methods": "stcf", "preset": "dv"}, r"has no method stcf \(it has baf\)"), ({"preset": "x"}, "preset"),
                           ({"methods": "hotpixel", "hot_map": np.zeros((2, 2), bool)}, "hot-pixel map")):
        with pytest.raises(BAFilterError, match=needle):
            BAFilter(W, H, **{"methods": "baf", **kwargs})


# -- dv-processing: exactly the same events -------------------------------------------------------------------


def dv_filtered(tmp_path, events, width, height, dt_us=2_000):
    """What dv-processing's BackgroundActivityNoiseFilter keeps (fed dv's own reading of an AEDAT 4.0 file)."""
    import dv_processing as dv

    path = tmp_path / "in.aedat4"
    with create_events(path, StreamInfo(width, height)) as writer:
        writer.write(events)
    recording = dv.io.MonoCameraRecording(str(path))
    noise_filter = dv.noise.BackgroundActivityNoiseFilter((width, height),
                                                          backgroundActivityDuration=timedelta(microseconds=dt_us))
    parts = []
    while recording.isRunning():
        batch = recording.getNextEventBatch()
        if batch is not None:
            noise_filter.accept(batch)
            parts.append(noise_filter.generateEvents().numpy())
    kept = np.concatenate(parts)
    return make_events(kept["timestamp"], kept["x"], kept["y"], kept["polarity"])


@pytest.mark.parametrize("name", ["dvs128_walk.aedat", "dvxplorer_sample.aedat4"])
def test_preset_dv_keeps_exactly_what_dv_processing_keeps(tmp_path, name):
    info, events = read_all(data_file(name))
    expected = dv_filtered(tmp_path, events, info.width, info.height)
    got = ba_filter(events, info.width, info.height, "baf", preset="dv")
    assert 0.05 * len(events) < len(expected) < 0.95 * len(events)
    assert_same_events(got, expected)


def test_preset_dv_on_a_random_stream_with_start_up(tmp_path):
    events = dense_events(20_000, 8, width=40, height=30, span_us=3)
    for dt_us in (1, 37, 2_000):
        expected = dv_filtered(tmp_path, events, 40, 30, dt_us)
        assert_same_events(ba_filter(events, 40, 30, "baf", preset="dv", dt_us=dt_us), expected)
    assert len(expected) > 0


# -- the command line ---------------------------------------------------------------------------------------------


def test_cli_filters_a_file_and_reports_counts(tmp_path):
    path = data_file("dvs128_walk.aedat")
    out = tmp_path / "out.aedat4"
    result = run("bafilter", path, "-o", out, "--method", "hotpixel,refractory,stcf", "--dt-us", "5000")
    info, events = read_all(path)
    _, kept = read_all(out)
    assert_same_events(kept, ba_filter(events, info.width, info.height, "hotpixel,refractory,stcf", dt_us=5_000))
    stderr = result.stderr.decode()
    assert f"{len(events):,} in" in stderr and f"{len(kept):,} kept" in stderr and stderr.count("\n") == 1
    assert run("-q", "bafilter", path, "-o", out, "--method", "baf").stderr == b""


def test_cli_pipe_head_empty_single_and_hot_pixels_file(tmp_path):
    path = data_file("dvs128_walk.aedat")
    pipeline = f"'{EVTOOLS}' bafilter '{path}' --method baf | head -c 1000 > /dev/null"
    result = subprocess.run(["bash", "-c", pipeline], capture_output=True, timeout=60)
    assert result.returncode == 0 and b"Traceback" not in result.stderr, result.stderr

    one = tmp_path / "one.csv"
    one.write_text("t,x,y,p\n10,3,4,1\n")
    out = tmp_path / "one.aedat4"
    run("bafilter", one, "--sensor-size", "8x8", "--method", "refractory", "-o", out)
    assert len(read_all(out)[1]) == 1
    empty = tmp_path / "empty.csv"
    empty.write_text("t,x,y,p\n")
    result = run("bafilter", empty, "--sensor-size", "8x8", "-o", tmp_path / "e.aedat4", check=False)
    assert result.returncode in (0, 1) and b"Traceback" not in result.stderr

    hot = tmp_path / "hot.csv"
    run("bafilter", path, "--method", "hotpixel", "--learn-us", "5000000", "--save-hot-pixels", hot,
        "-o", tmp_path / "a.aedat4")
    lines = hot.read_text().splitlines()
    assert lines[0] == "x,y"
    run("bafilter", path, "--method", "hotpixel", "--hot-pixels", hot, "-o", tmp_path / "b.aedat4")
    _, a = read_all(tmp_path / "a.aedat4")
    _, b = read_all(tmp_path / "b.aedat4")
    # the saved list drops the same pixels: the outputs match from the end of the learning stretch on
    marked = {tuple(map(int, line.split(","))) for line in lines[1:]}
    assert not any((int(e["x"]), int(e["y"])) in marked for e in b)
    assert_same_events(a, b)


def test_cli_bad_parameters(tmp_path):
    path = data_file("dvs128_walk.aedat")
    out = tmp_path / "out.aedat4"
    bad = run("bafilter", path, "--method", "bogus", "-o", out, check=False)
    assert bad.returncode == 2 and b"bogus" in bad.stderr
    assert run("bafilter", path, "--dt-us", "0", "-o", out, check=False).returncode == 2
    dv_stcf = run("bafilter", path, "--method", "stcf", "--preset", "dv", "-o", out, check=False)
    assert dv_stcf.returncode == 2 and b"--preset dv has no method stcf (it has baf)" in dv_stcf.stderr
    wrong = tmp_path / "hot.csv"
    wrong.write_text("x,y\n500,3\n")
    assert_clean_error(run("bafilter", path, "--method", "hotpixel", "--hot-pixels", wrong, "-o", out, check=False),
                       "hot.csv")
    assert not out.exists()
    # an event file given as the list (it was a traceback: a QA sweep)
    assert_clean_error(run("bafilter", path, "--method", "hotpixel", "--hot-pixels", path, "-o", out, check=False),
                       "dvs128_walk.aedat", "not a hot-pixel list")


def test_save_hot_pixels_never_replaces_the_input_goes_to_stdout_and_fails_whole(tmp_path):
    """Issue 19: `--save-hot-pixels` naming the input used to turn the recording into an `x,y` list; `-` made a
    file named `-`; an unwritable list left the complete main output behind."""
    source = tmp_path / "in.csv"
    run("convert", Path(__file__).resolve().parents[1] / "samples" / "flicker.aedat4", "-o", source)
    original = source.read_bytes()
    refused = run("-q", "bafilter", source, "--method", "hotpixel", "--save-hot-pixels", source, "-o",
                  tmp_path / "out.csv", check=False)
    assert refused.returncode == 1 and source.read_bytes() == original
    assert refused.stderr.decode().count("\n") == 1 and "overwrite the input" in refused.stderr.decode()
    assert not (tmp_path / "out.csv").exists()
    listed = run("-q", "bafilter", source, "--method", "hotpixel", "--save-hot-pixels", "-", "-o",
                 tmp_path / "out.csv", cwd=tmp_path)
    assert listed.stdout.decode().startswith("x,y\n") and not (tmp_path / "-").exists()
    failed = run("-q", "bafilter", source, "--method", "hotpixel", "--save-hot-pixels",
                 tmp_path / "missing" / "hot.csv", "-o", tmp_path / "after.csv", check=False)
    assert failed.returncode == 1 and not (tmp_path / "after.csv").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.csv", "out.csv"]  # no temporary left either
