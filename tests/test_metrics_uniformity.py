"""``evtools metrics uniformity``: edges, per-edge statistics, reference errors, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from evtools.events import make_events
from evtools.metrics.uniformity import UniformityError, detect_edges, edge_uniformity, edges_from_starts
from evtools.formats import create_events
from evtools.events import StreamInfo
from tests.helpers import run


def two_edges(jitter_us=0):
    """4 pixels: 3 ON events each from t=1 s, 3 OFF events each from t=2 s; pixel i shifted by i * jitter."""
    t, x, p = [], [], []
    for start, pol in ((1_000_000, 1), (2_000_000, 0)):
        for k in range(3):
            for i in range(4):
                t.append(start + k * 1000 + i * jitter_us)
                x.append(i)
                p.append(pol)
    order = np.argsort(t, kind="stable")
    return make_events(np.array(t)[order], np.array(x)[order], np.zeros(len(t)), np.array(p)[order])


def test_detects_both_edges_and_measures_the_spread():
    events = two_edges(jitter_us=100)
    edges = detect_edges(events)
    assert [e.polarity for e in edges] == [True, False]
    result = edge_uniformity(events, 4, edges)
    expected = np.std([0, 100, 200, 300]) / 1e3
    for row in result["edges"]:
        assert row["first_std_ms"] == pytest.approx(expected)
        assert row["count_cv"] == 0
    assert result["polarity_balance_mean"] == 0


def test_reference_errors_are_zero_against_itself_and_not_otherwise():
    events, shifted = two_edges(), two_edges(jitter_us=100)
    edges = edges_from_starts(events, [900_000, 1_900_000])
    assert edge_uniformity(events, 4, edges, events)["summary"]["timing_error_ms"] == 0
    assert edge_uniformity(shifted, 4, edges, events)["summary"]["timing_error_ms"] > 0
    with pytest.raises(UniformityError):
        edges_from_starts(events, [2, 1])


def test_cli_json_and_plot(tmp_path):
    path = tmp_path / "e.aedat4"
    with create_events(str(path), StreamInfo(4, 1)) as writer:
        writer.write(two_edges(50))
    result = json.loads(run("metrics", "uniformity", path, "--json", "--plot", tmp_path / "p.png",
                            "--before", path).stdout)
    assert len(result["edges"]) == 2 and (tmp_path / "p.png").stat().st_size > 0
    empty = tmp_path / "empty.csv"
    empty.write_text("t,x,y,p\n")
    assert run("metrics", "uniformity", empty, "--sensor-size", "4x1", check=False).returncode == 1


def test_a_before_stream_of_another_sensor_is_refused(tmp_path):
    """--before's pixels were read with the other stream's width, so its panel drew other pixels, silently."""
    from tests.helpers import assert_clean_error

    after, before = tmp_path / "after.aedat4", tmp_path / "before.aedat4"
    for path, size in ((after, (4, 1)), (before, (5, 1))):
        with create_events(str(path), StreamInfo(*size)) as writer:
            writer.write(two_edges(50))
    assert_clean_error(run("metrics", "uniformity", after, "--plot", tmp_path / "p.png", "--before", before,
                           check=False), "before.aedat4: --before is 5x1 but the stream is 4x1")
    assert not (tmp_path / "p.png").exists()


def test_a_stream_without_edges_is_said_not_an_empty_table_alone(tmp_path):
    """A QA sweep: a scene with no stimulus edge (a walk) printed an empty table and exit 0, not a word."""
    import evtools
    from evtools.events import StreamInfo, make_events
    from tests.helpers import run

    stream = tmp_path / "walk.aedat4"
    rng = np.random.default_rng(4)  # (steady activity: an event every 0.5 ms, no burst after a quiet spell)
    t = np.arange(0, 3_000_000, 500)
    evtools.write(stream, make_events(t, rng.integers(0, 16, len(t)), rng.integers(0, 12, len(t)),
                                      rng.integers(0, 2, len(t))), StreamInfo(16, 12))
    done = run("metrics", "uniformity", stream, "--json")
    assert json.loads(done.stdout)["edges"] == []
    assert "no stimulus edge found" in done.stderr.decode() and "--edges-at" in done.stderr.decode()
