"""The Python API (evtools.api): its examples run, its conversions are exact, and it is the command line's
processors - the same bytes as the CLI pipeline on a real recording."""

from __future__ import annotations

import doctest
import importlib.util
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import evtools
import evtools.api
from tests.conftest import ROOT, data_file
from tests.helpers import run


def test_every_example_runs():
    failures, tried = doctest.testmod(evtools.api, optionflags=doctest.ELLIPSIS)
    assert failures == 0 and tried >= 40


def test_the_api_is_at_the_top_level():
    for name in ("read", "open", "write", "writer", "bafilter", "estimate", "correct", "simulate", "inject_noise",
                 "to_columns", "from_columns", "to_tonic", "from_tonic", "to_dv", "from_dv"):
        assert callable(getattr(evtools, name)) and getattr(evtools, name).__doc__, name
    from evtools import correction, estimation, filters, simulation  # submodules do not shadow the functions

    assert estimation.ThresholdEstimator and correction.ThresholdCorrector and filters.BAFilter
    assert simulation.DvsSimulator and callable(evtools.estimate) and callable(evtools.simulate)


events_strategy = st.integers(0, 300).flatmap(lambda n: st.tuples(
    st.lists(st.integers(0, 50), min_size=n, max_size=n), st.lists(st.integers(0, 319), min_size=n, max_size=n),
    st.lists(st.integers(0, 239), min_size=n, max_size=n), st.lists(st.booleans(), min_size=n, max_size=n)))


def _events(columns):
    steps, x, y, p = columns
    return evtools.from_columns(np.cumsum(np.asarray(steps, dtype=np.int64)), x, y, p)  # many equal times


@settings(max_examples=25, deadline=None)
@given(columns=events_strategy)
def test_tonic_and_column_round_trips_are_exact(columns):
    events = _events(columns)
    assert np.array_equal(evtools.from_tonic(evtools.to_tonic(events)), events)
    assert np.array_equal(evtools.from_columns(*evtools.to_columns(events)), events)


@settings(max_examples=8, deadline=None)
@given(columns=events_strategy)
def test_dv_processing_round_trip_is_exact(columns):
    pytest.importorskip("dv_processing")
    events = _events(columns)
    store = evtools.to_dv(events, evtools.StreamInfo(320, 240))
    assert len(store) == len(events)
    assert np.array_equal(evtools.from_dv(store), events)


def test_api_pipeline_gives_the_cli_pipeline_bytes(tmp_path):
    """samples/api_pipeline.py (read, bafilter, estimate natural, correct) against the three commands."""
    recording = data_file("dvs128_walk.aedat")
    spec = importlib.util.spec_from_file_location("api_pipeline", ROOT / "samples" / "api_pipeline.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    summary = module.pipeline(str(recording), str(tmp_path / "api"))
    assert summary["valid_pixels"] > 1000 and summary["kept"] < summary["events"]
    cli = tmp_path / "cli"
    cli.mkdir()
    run("bafilter", recording, "-o", cli / "filtered.aedat4")
    run("estimate", cli / "filtered.aedat4", "--method", "natural", "-o", cli / "thresholds.h5")
    run("correct", cli / "filtered.aedat4", "--thresholds", cli / "thresholds.h5", "-o", cli / "corrected.aedat4")
    for name in ("filtered.aedat4", "corrected.aedat4"):
        assert (tmp_path / "api" / name).read_bytes() == (cli / name).read_bytes(), name


def test_correct_takes_an_online_series_and_a_file(tmp_path):
    events, truth = evtools.simulate("flicker", width=8, height=6, duration_us=3_000_000, seed=4, leak_rate_hz=0)
    info = evtools.StreamInfo(8, 6)
    online = evtools.estimate(events, info, method="stimulus", interval_us=1_000_000)
    assert online.series is not None and len(online.series.t_us) == 3
    from evtools.correction import correct_thresholds

    direct = correct_thresholds(events, 8, 6, online.series.on, online.series.off, online.series.valid,
                                t_us=online.series.t_us, target=0.2)
    assert np.array_equal(evtools.correct(events, info, online), direct)
    with pytest.raises(evtools.EvtoolsError):
        evtools.simulate([(0, np.zeros((2, 2)))], scene={"period_s": 1})
    assert os.path.exists(ROOT / "samples" / "api_pipeline.py")
