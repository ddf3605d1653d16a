"""Hot pixels: learned over the stream's first ``learn_us`` (libcaer's absolute rate test, faery's relative one),
or given; their events are dropped."""

from __future__ import annotations

import numpy as np

from evtools._kernels import bafilter as kernels
from evtools.events import empty_events, join
from evtools.filters.spec import BAFilterError, Filter, Param

MAX_LEARN_EVENTS = 1 << 22
"""The learning stretch of ``hotpixel`` ends after this many events at most (4,194,304: 64 MiB held)."""


def learn_hot_pixels(counts: np.ndarray, duration_s: float, hot_ratio: float, hot_min_events: int,
                     hot_rate_hz: float) -> np.ndarray:
    """Hot pixels from per-pixel event counts over ``duration_s``.

    A pixel is hot when it has at least ``hot_min_events`` events and either its rate is at least
    ``hot_rate_hz`` (libcaer's absolute test) or its count is at least ``hot_ratio`` times the largest count of
    its 4 neighbours (faery's relative test; a 1 x 1 sensor's pixel has none: only the absolute test, it was
    always hot).
    """
    counts = np.asarray(counts, dtype=np.int64)
    padded = np.pad(counts, 1)
    neighbours = np.maximum.reduce([padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]])
    relative = (counts >= hot_ratio * neighbours) & (counts.size > 1)  # (a lone pixel has none to compare with)
    absolute = counts >= hot_rate_hz * duration_s
    return (counts >= hot_min_events) & (relative | absolute)


LEARNING = {"learn_us": 1_000_000, "hot_ratio": 5.0, "hot_min_events": 20, "hot_rate_hz": 10_000.0, "hot_map": None}


class HotPixel(Filter):
    name = "hotpixel"
    keeps = "its pixel is not hot (learned over the first `--learn-us`, or `--hot-pixels FILE`)"
    params = (
        Param("learn_us", "time_us", "learning stretch, us"),
        Param("hot_ratio", "float", "hot when >= this times its 4 neighbours' largest count", 1.0),
        Param("hot_rate_hz", "float", "hot when its rate is at least this", 0.0),
        Param("hot_min_events", "int", "a hot pixel has at least this many events in the stretch", 1, 1 << 62),
        Param("hot_map", "pixels", "the hot pixels to drop, (height, width) bool (no learning)", sweepable=False,
              cli=False),
    )
    defaults = {"evtools": LEARNING, "jaer": LEARNING}

    @classmethod
    def prepare(cls, q, width, height):
        if q.get("hot_map") is not None:
            hot = np.asarray(q["hot_map"], dtype=bool)
            if hot.shape != (height, width):
                raise BAFilterError(f"hot-pixel map is {hot.shape[1]}x{hot.shape[0]}, the sensor {width}x{height}")
            q["hot_map"] = hot
        return q

    def __init__(self, width, height, preset, q) -> None:
        super().__init__(width, height, preset, q)
        self.hot_map = q.get("hot_map")
        self.learning = self.hot_map is None
        self.learned_duration_s = 0.0
        if self.learning:
            self.hot_map = np.zeros((height, width), dtype=bool)
            self.counts = np.zeros(height * width, dtype=np.int64)
            self.held: list[np.ndarray] = []
            self.held_events = 0
            self.t_first: int | None = None

    def run(self, words, out) -> int:
        return kernels.hot_pixels(words, self.hot_map, out)

    def process(self, chunk: np.ndarray) -> np.ndarray:
        return self._learn(chunk) if self.learning else self.filter(chunk)

    def held_since(self) -> int | None:
        return self.t_first if self.learning else None

    def _learn(self, chunk: np.ndarray) -> np.ndarray:
        """Hold the learning stretch (its first ``learn_us``, at most :data:`MAX_LEARN_EVENTS` events); when it
        ends, decide the hot pixels and release it filtered."""
        if not len(chunk):
            return chunk[:0]
        if self.t_first is None:
            self.t_first = int(chunk["t"][0])
        learn_us = self.params_used["learn_us"]
        n = min(int(np.searchsorted(chunk["t"], self.t_first + learn_us, side="left")),
                MAX_LEARN_EVENTS - self.held_events)
        part = chunk[:n]
        self.counts += np.bincount(part["y"].astype(np.int64) * self.width + part["x"], minlength=len(self.counts))
        self.held.append(part)
        self.held_events += n
        if self.held_events >= MAX_LEARN_EVENTS:  # the stretch ends at its event cap: its span is what it holds
            self._decide(int(part["t"][-1]) - self.t_first + 1)
        elif n < len(chunk):  # an event at or after t_first + learn_us: the stretch is learn_us long
            self._decide(learn_us)
        else:
            return chunk[:0]
        return join([self._release(), self.filter(chunk[n:])])

    def _decide(self, duration_us: int) -> None:
        q = self.params_used
        self.learned_duration_s = max(duration_us, 1) * 1e-6
        self.hot_map = learn_hot_pixels(self.counts.reshape(self.hot_map.shape), self.learned_duration_s,
                                        q["hot_ratio"], q["hot_min_events"], q["hot_rate_hz"])
        self.learning = False

    def _release(self) -> np.ndarray:
        held = join(self.held) if self.held else empty_events()
        self.held = []
        return self.filter(held)

    def flush(self) -> np.ndarray:
        if not self.learning:
            return empty_events()
        if self.t_first is None:  # no event at all: nothing learned
            self.learning = False
            return empty_events()
        held_t = self.held[-1]["t"][-1] if self.held_events else self.t_first
        self._decide(int(held_t) - self.t_first + 1)  # a short stream: its whole span
        return self._release()
