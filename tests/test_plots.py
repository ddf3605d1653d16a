"""matplotlib figures (issue 18 item 1): every plot to PNG, SVG and PDF, axes and clipping checked in the SVG."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evtools.formats.thresholds import ThresholdMap, write_thresholds
from evtools.formats.figures import FigureError, save_figure
from evtools.plots import roc_figure, thresholds_figure
from tests.helpers import run

CURVES = [{"label": "stcf", "parameter": "dt_us", "auc": 0.9,
           "points": [{"value": 1000, "fpr": 0.05, "tpr": 0.6}, {"value": 10000, "fpr": 0.2, "tpr": 0.9}]},
          {"label": "mlpf", "parameter": "threshold", "auc": 0.95,
           "points": [{"value": 0.5, "fpr": 0.02, "tpr": 0.85}, {"value": 0.1, "fpr": 0.1, "tpr": 0.95}]}]


def _maps(seed=0):
    rng = np.random.default_rng(seed)
    true_on, true_off = rng.normal(0.2, 0.02, (12, 16)), rng.normal(0.25, 0.02, (12, 16))
    return true_on, true_off


@pytest.mark.parametrize("suffix, magic", [(".png", b"\x89PNG"), (".svg", b"<?xml"), (".pdf", b"%PDF")])
def test_every_figure_in_every_format(tmp_path, suffix, magic):
    true_on, true_off = _maps()
    estimated_on = true_on * 1.02
    estimated_on[3, 4] = true_on[3, 4] * 1.93  # one pixel 93 % off: the scales must not be flattened by it
    valid = np.ones(true_on.shape, bool)
    valid[0, 0] = False
    for name, figure in (("roc", roc_figure(CURVES)),
                         ("maps", thresholds_figure(estimated_on, true_off, valid, true_on, true_off))):
        path = tmp_path / f"{name}{suffix}"
        save_figure(figure, path)
        data = path.read_bytes()
        assert data.startswith(magic) and len(data) > 5000, (name, len(data))
        if suffix == ".svg":
            text = data.decode()
            if name == "roc":
                assert "FPR" in text and "TPR" in text and "AUC 0.950" in text and "10000" in text
            else:
                assert "clipped at the 2nd and 98th percentiles" in text and "98th percentile of |error|" in text
                assert "error, % of the true value" in text


def test_colour_scales_are_robust_and_the_error_scale_is_centred():
    true_on, true_off = _maps(1)
    estimated_on = true_on * 1.02
    estimated_on[3, 4] = true_on[3, 4] * 1.93
    figure = thresholds_figure(estimated_on, true_off, np.ones(true_on.shape, bool), true_on, true_off)
    images = [axis.images[0] for axis in figure.axes if axis.images]
    low, high = images[0].get_clim()
    assert high < estimated_on[3, 4]  # the outlier is clipped, not the top of the scale
    assert images[0].get_clim() == images[1].get_clim()  # estimate and truth share the scale
    error_low, error_high = images[2].get_clim()
    assert error_low == -error_high and error_high < 93  # centred on 0, the 93 % pixel clipped


def test_cli_plots_by_extension_and_refuses_others(tmp_path):
    true_on, true_off = _maps()
    write_thresholds(str(tmp_path / "t.h5"), ThresholdMap(true_on, true_off, np.ones(true_on.shape, bool)))
    write_thresholds(str(tmp_path / "e.h5"), ThresholdMap(true_on * 1.1, true_off, np.ones(true_on.shape, bool)))
    for suffix in (".svg", ".pdf", ".png"):
        run("metrics", "thresholds", tmp_path / "e.h5", "--truth", tmp_path / "t.h5", "--plot",
            tmp_path / f"m{suffix}", "--json")
        assert (tmp_path / f"m{suffix}").stat().st_size > 5000
    bad = run("metrics", "thresholds", tmp_path / "e.h5", "--truth", tmp_path / "t.h5", "--plot", tmp_path / "m.gif",
              check=False)
    assert bad.returncode == 2 and b".png, .svg, .pdf" in bad.stderr
    with pytest.raises(FigureError, match="m.bmp"):
        save_figure(roc_figure(CURVES), tmp_path / "m.bmp")
    assert json.loads(run("metrics", "thresholds", tmp_path / "e.h5", "--truth", tmp_path / "t.h5",
                          "--json").stdout)["on"]["rel_rmse"] > 0


def test_edge_levels_figure_in_svg_with_labelled_axes(tmp_path):
    """metrics uniformity --plot: per-pixel staircases against time in ms, before and after side by side."""
    samples = __import__("pathlib").Path(__file__).resolve().parents[1] / "samples"
    figure = tmp_path / "edges.svg"
    run("metrics", "uniformity", samples / "step.aedat4", "--before", samples / "step.aedat4", "--plot", figure,
        "--json")
    text = figure.read_text()
    assert "time since the edge began, ms" in text and "ON minus OFF" in text and "before: " in text
    bad = run("metrics", "uniformity", samples / "step.aedat4", "--plot", tmp_path / "e.jpg", check=False)
    assert bad.returncode == 2


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**16), n=st.integers(1, 3000), span_us=st.integers(1, 10_000_000),
       cuts=st.lists(st.integers(0, 3000), max_size=6), max_bins=st.integers(2, 64))
def test_rate_counter_counts_every_event_whatever_the_chunks(seed, n, span_us, cuts, max_bins):
    from evtools.events import make_events
    from evtools.plots import RateCounter
    from tests.helpers import cut

    rng = np.random.default_rng(seed)
    events = make_events(np.sort(rng.integers(0, span_us, n)), rng.integers(0, 7, n), rng.integers(0, 5, n),
                         rng.integers(0, 2, n))
    whole, parts = RateCounter(7, 5, max_bins=max_bins), RateCounter(7, 5, max_bins=max_bins)
    whole.add(events)
    for part in cut(events, cuts):
        parts.add(part)
    for counter in (whole, parts):
        assert counter.bins.shape[1] <= max_bins
        assert counter.bins[1].sum() == events["p"].sum() and counter.bins.sum() == n
        assert (counter.pixels == np.bincount(events["y"].astype(int) * 7 + events["x"], minlength=35)).all()
        # each bin holds the events of its time span
        edges = counter.first_us + np.arange(counter.bins.shape[1] + 1) * counter.bin_us
        assert (counter.bins.sum(axis=0) == np.histogram(events["t"], edges)[0]).all()
    assert (whole.bins == parts.bins).all() and whole.bin_us == parts.bin_us


def test_render_rate_draws_the_rates_figure(tmp_path):
    from tests.conftest import data_file

    recording = data_file("dvxplorer_sample.aedat4")
    for suffix in (".png", ".svg"):
        run("render", recording, "--rate", "-o", tmp_path / f"r{suffix}")
        assert (tmp_path / f"r{suffix}").stat().st_size > 10_000
    assert "events/s per pixel" in (tmp_path / "r.svg").read_text()
    refused = run("render", recording, "--rate", "--window-us", 100, "-o", tmp_path / "x.png", check=False)
    assert refused.returncode == 2 and b"--window-us does not apply to --rate" in refused.stderr


def test_bafilter_draws_the_hot_pixels_on_their_rates(tmp_path):
    """--save-hot-pixels map.svg draws the learned hot pixels, circled, on the learning stretch's rate map; a .csv
    name still writes the list."""
    from tests.conftest import data_file

    noisy = tmp_path / "hot.aedat4"
    run("simulate", data_file("dvs128_walk.aedat"), "--hot-pixel-fraction", "0.001", "--seed", 3, "-o", noisy)
    run("bafilter", noisy, "--method", "hotpixel", "--save-hot-pixels", tmp_path / "hot.svg", "-o", tmp_path / "a.aedat4")
    run("bafilter", noisy, "--method", "hotpixel", "--save-hot-pixels", tmp_path / "hot.csv", "-o", tmp_path / "b.aedat4")
    count = len((tmp_path / "hot.csv").read_text().splitlines()) - 1
    assert count > 0 and f"hot pixels: {count} of 16,384" in (tmp_path / "hot.svg").read_text()


def test_a_plot_never_replaces_an_input(tmp_path):
    """Issue 37 item 1: `metrics ... --plot` naming one of the command's inputs (directly, through a symbolic link
    or a hard link) is a usage error before any work, and the input is untouched."""
    import os

    stream, truth, estimate = tmp_path / "s.aedat4", tmp_path / "t.h5", tmp_path / "e.h5"
    run("simulate", "scene:flicker", "--size", "8x6", "--duration", "1s", "--seed", "1", "--truth", truth,
        "-o", stream)
    run("estimate", stream, "--method", "stimulus", "-o", estimate)
    link, hard = tmp_path / "link.png", tmp_path / "hard.png"
    link.symlink_to(truth)
    os.link(estimate, hard)
    before = {path: path.read_bytes() for path in (stream, truth, estimate)}
    cases = [("thresholds", estimate, "--truth", truth, "--plot", truth),
             ("thresholds", estimate, "--truth", truth, "--plot", link),
             ("thresholds", estimate, "--truth", truth, "--plot", hard),
             ("uniformity", stream, "--plot", stream),
             ("reconstruction", stream, "--truth", truth, "--contrast", "0.2", "--plot", link)]
    for case in cases:
        done = run("metrics", *case, check=False)
        assert done.returncode == 2, (case, done.stderr.decode())
        assert "an input of this command" in done.stderr.decode() and "Traceback" not in done.stderr.decode()
    assert all(path.read_bytes() == data for path, data in before.items())


@pytest.mark.parametrize("suffix, magic", [(".png", b"\x89PNG"), (".svg", b"<?xml"), (".pdf", b"%PDF")])
def test_the_reconstruction_figure_is_what_its_name_says(tmp_path, suffix, magic):
    """Issue 39: `metrics reconstruction --plot recon.pdf` (or .svg) wrote PNG bytes; the figure is matplotlib's,
    in the format of the extension, with its times and the log-intensity scale."""
    from tests.helpers import run

    run("simulate", "scene:step", "--size", "16x12", "--duration", "1s", "--truth", tmp_path / "t.h5",
        "-o", tmp_path / "s.aedat4")
    figure = tmp_path / f"recon{suffix}"
    run("metrics", "reconstruction", tmp_path / "s.aedat4", "--truth", tmp_path / "t.h5", "--plot", figure)
    data = figure.read_bytes()
    assert data.startswith(magic)
    if suffix == ".svg":
        text = data.decode()  # (text as <text>, not outlines)
        assert "log intensity" in text and ">990 ms<" in text and ">RMSE " in text and ">x, px<" in text


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31), spread=st.integers(0, 6))
def test_the_rate_map_draws_black_only_where_no_event_came(seed, spread):
    """The slowest pixels were drawn black (magma's lowest colour), as were those below the scale's floor, beside a
    label saying "black: no event" (a QA sweep): a pixel that fired is never black, one that did not always is."""
    from evtools.events import make_events
    from evtools.plots import RateCounter, rate_figure

    rng = np.random.default_rng(seed)
    width, height = 12, 9
    counts = np.round(10 ** rng.uniform(0, spread, width * height)).astype(np.int64)
    counts[rng.random(width * height) < 0.2] = 0
    pixel = np.repeat(np.arange(width * height), counts)
    t = np.sort(rng.integers(0, 1_000_000, len(pixel)))
    counter = RateCounter(width, height)
    counter.add(make_events(t, pixel % width, pixel // width, np.ones(len(pixel), bool)))
    figure = rate_figure(counter)
    image = figure.axes[1].images[0]
    rgba = image.to_rgba(image.get_array()).reshape(height, width, 4)
    black = np.all(rgba[..., :3] < 0.05, axis=-1)
    assert np.array_equal(black.ravel(), counts == 0)
    import matplotlib.pyplot as plt

    plt.close(figure)
