"""A stream processor pickled midway (multiprocessing, joblib, a notebook's checkpoint) goes on as if it had not been:
the same output as one that never left the process."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from evtools.correction import ThresholdCorrector
from evtools.estimation import ThresholdEstimator
from evtools.filters import METHODS, BAFilter
from evtools.noise import NoiseInjector
from evtools.render import EventFramer
from tests.helpers import assert_same_events, random_events

W, H = 24, 18


def _corrector():
    rng = np.random.default_rng(3)
    on, off = (rng.uniform(0.15, 0.3, (H, W)) for _ in range(2))
    return ThresholdCorrector(W, H, on, off, target=0.2, hold_us=2000, max_gap_us=5000)


PROCESSORS = {
    **{f"bafilter {method}": (lambda method=method: BAFilter(W, H, method)) for method in METHODS},
    "correct": _corrector,
    "estimate offe": lambda: ThresholdEstimator(W, H, "offe", max_fit=np.inf),
    "estimate natural online": lambda: ThresholdEstimator(W, H, "natural", interval_us=20_000, min_events=2,
                                                               max_fit=np.inf),
    "noise": lambda: NoiseInjector(W, H, seed=5, shot_noise_rate_hz=2.0),
    "render": lambda: EventFramer(W, H, 7000),
}


def _taken(out):
    """A processor's output, a generator's (the framer's) drawn."""
    return out if isinstance(out, (np.ndarray, tuple)) or out is None else list(out)


def _outputs(processor, chunks) -> list:
    """Everything ``processor`` gives for ``chunks`` then its flush (and its result, where it has one)."""
    given = [_taken(processor.process(chunk)) for chunk in chunks] + [_taken(processor.flush())]
    if hasattr(processor, "result"):
        given.append(processor.result())
    return given


def _same(a, b) -> None:
    if isinstance(a, np.ndarray) and a.dtype.names:
        assert_same_events(a, b)
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _same(x, y)
    elif isinstance(a, np.ndarray):
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    elif hasattr(a, "__dict__"):
        _same(list(vars(a).values()), list(vars(b).values()))
    else:
        assert a == b or (a != a and b != b)


@pytest.mark.parametrize("name", PROCESSORS)
def test_a_processor_pickled_midway_gives_what_it_would_have(name):
    """Found by a QA sweep: a pickled ThresholdCorrector failed at its next part ("cannot resize this array: it does
    not own its data": an unpickled array is a view of the pickle's bytes)."""
    events = random_events(6000, W, H, seed=11)
    first, second = events[:2500], events[2500:]
    make = PROCESSORS[name]
    straight = _outputs(make(), [first, second])
    processor = make()
    before = _taken(processor.process(first))
    for protocol in (pickle.HIGHEST_PROTOCOL, 2):
        copy = pickle.loads(pickle.dumps(processor, protocol=protocol))
        after = _outputs(copy, [second])
        _same([before] + after, straight)
