"""Background-activity filters as stream processors (``docs/algorithms.md`` section 2).

:class:`BAFilter` runs one or several stages in order (``"hotpixel,refractory,stcf"``); each stage sees only the
events that the stages before it kept, so its time map never holds an event an earlier stage rejected. Within a
stage, a rejected event still writes its time (as every reference implementation does). :func:`ba_filter` is the
one-shot convenience.

Methods: ``baf`` (the report's filter, Delbruck 2008), ``stcf`` (jAER's SpatioTemporalCorrelationFilter),
``dwf`` (Guo & Delbruck 2022), ``orderN`` (Khodamoradi & Kastner 2018), ``refractory`` and ``hotpixel``.

Presets (start-up behaviour and defaults):

- ``evtools`` (default): maps start "long ago", so nothing is supported by a phantom past; windows start empty.
- ``dv``: dv-processing's BackgroundActivityNoiseFilter (``baf`` only): the time map starts at 0 (every event
  with ``t < dt`` passes), ``dt`` 2 ms, ``t - T < dt``, self excluded, clipped at the border. Verified
  event for event against dv-processing 2.0.
- ``jaer``: jAER (2024 sources): correlation time 25 ms; the first event of every pixel is rejected
  (letFirstEventThrough off); STCF k = 2, polarities must match, and jAER's window clipping (the last ``r``
  columns/rows never count as neighbours); DWF windows of 256 (wlen 512), distance 5, k = 1, its first 512
  events rejected (the first 256 fill the kept window) and the rejected window pre-filled with (-1, -1);
  orderN counts the pixel itself and rejects (without storing) events on the sensor's border; refractory
  drops ``t - T <= dt``. jAER's 32-bit time wrap is not reproduced (times are int64 here).

References
----------
T. Delbruck, "Frame-free dynamic digital vision", Proc. Intl. Symp. on Secure-Life Electronics, 2008.
S. Guo, T. Delbruck, "Low Cost and Latency Event Camera Background Activity Denoising", IEEE TPAMI 45(1), 2023.
A. Khodamoradi, R. Kastner, "O(N)-Space Spatiotemporal Filter for Reducing Noise in Neuromorphic Vision
Sensors", IEEE Trans. Emerging Topics in Computing 9(1), 2021.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from evtools._kernels import bafilter as kernels
from evtools._kernels import mlpf as mlpf_kernels
from evtools.errors import EvtoolsError
from evtools.events import (EVENT_DTYPE, MAX_TIME_US, StreamChecker, StreamInfo, as_chunk, check_sensor_size,
                            empty_events, join, record_words)
from evtools.mlpf import MlpfError, Weights, load_weights

__all__ = ["METHODS", "PRESETS", "BAFilter", "BAFilterError", "ba_filter", "learn_hot_pixels"]

METHODS = ("baf", "stcf", "dwf", "orderN", "refractory", "hotpixel", "mlpf")
PRESETS = ("evtools", "dv", "jaer")

DEFAULTS: dict[str, dict[str, Any]] = {
    "evtools": {
        "baf": {"dt_us": 10_000},
        "stcf": {"dt_us": 10_000, "k": 2, "radius": 1, "polarity": True, "polarity_maps": False},
        "dwf": {"window": 36, "distance": 9, "k": 1},
        "orderN": {"dt_us": 10_000},
        "refractory": {"dt_us": 100},
        "hotpixel": {"learn_us": 1_000_000, "hot_ratio": 5.0, "hot_min_events": 20, "hot_rate_hz": 10_000.0},
        "mlpf": {"threshold": 0.5, "weights": None},
    },
    "dv": {"baf": {"dt_us": 2_000}},
    "jaer": {
        "baf": {"dt_us": 25_000},
        "stcf": {"dt_us": 25_000, "k": 2, "radius": 1, "polarity": True},
        "dwf": {"window": 256, "distance": 5, "k": 1},
        "orderN": {"dt_us": 25_000},
        "refractory": {"dt_us": 25_000},
        "hotpixel": {"learn_us": 1_000_000, "hot_ratio": 5.0, "hot_min_events": 20, "hot_rate_hz": 10_000.0},
    },
}
"""Default parameters per preset and method."""

PARAMETERS = ("dt_us", "k", "radius", "polarity", "window", "distance", "learn_us", "hot_ratio", "hot_min_events",
              "hot_rate_hz", "threshold", "weights", "polarity_maps")
MAX_LEARN_EVENTS = 1 << 22
"""The learning stretch of ``hotpixel`` ends after this many events at most (4,194,304: 64 MiB held)."""


class BAFilterError(EvtoolsError, ValueError):
    """A bad filter parameter or method name."""


def _int_param(name: str, value, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low or (
            high is not None and value > high):
        bound = f">= {low}" if high is None else f"in {low}..{high}"
        raise BAFilterError(f"{name} must be a whole number {bound}, got {value!r}")
    return int(value)


def _float_param(name: str, value, low: float) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise BAFilterError(f"{name} must be a number >= {low}, got {value!r}") from None
    if not math.isfinite(number) or number < low:
        raise BAFilterError(f"{name} must be a finite number >= {low}, got {value!r}")
    return number


def parse_methods(methods) -> list[str]:
    """``"hotpixel,stcf"`` or a list of names into a list of method names (case-insensitive)."""
    if isinstance(methods, str):
        methods = methods.split(",")
    by_lower = {m.lower(): m for m in METHODS}
    names = []
    for name in methods:
        key = str(name).strip().lower()
        if key not in by_lower:
            raise BAFilterError(f"unknown method {name!r}; choose among {', '.join(METHODS)}")
        names.append(by_lower[key])
    if not names:
        raise BAFilterError(f"no method given; choose among {', '.join(METHODS)}")
    return names


def learn_hot_pixels(counts: np.ndarray, duration_s: float, hot_ratio: float, hot_min_events: int,
                     hot_rate_hz: float) -> np.ndarray:
    """Hot pixels from per-pixel event counts over ``duration_s``.

    A pixel is hot when it has at least ``hot_min_events`` events and either its rate is at least
    ``hot_rate_hz`` (libcaer's absolute test) or its count is at least ``hot_ratio`` times the largest count of
    its 4 neighbours (faery's relative test).
    """
    counts = np.asarray(counts, dtype=np.int64)
    padded = np.pad(counts, 1)
    neighbours = np.maximum.reduce([padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]])
    relative = counts >= hot_ratio * neighbours
    absolute = counts >= hot_rate_hz * duration_s
    return (counts >= hot_min_events) & (relative | absolute)


class _Stage:
    def __init__(self, method: str, width: int, height: int, preset: str, params: dict[str, Any]) -> None:
        self.method = method
        self.params = params
        jaer = preset == "jaer"
        self.jaer = jaer
        start = 0 if preset == "dv" else kernels.NEVER
        if method == "baf":
            self.time_map = kernels.padded_map(width, height, 1, start)
        if method == "stcf" and params.get("polarity_maps"):
            self.time_map = np.stack([kernels.padded_map(width, height, params["radius"], start)] * 2)
        elif method == "stcf":
            self.time_map = kernels.padded_map(width, height, params["radius"], start) * 2  # 2 t + p
        if method == "refractory":
            self.time_map = np.full((height, width), start, dtype=np.int64)
        if method == "dwf":
            size = params["window"]
            self.kept_xy = np.zeros((size, 2), dtype=np.int32)
            self.rejected_xy = np.zeros((size, 2), dtype=np.int32)
            self.counters = np.zeros(5, dtype=np.int64)
            if jaer:
                self.rejected_xy[:] = -1
                self.counters[2] = size
                self.counters[4] = 2 * size
        if method == "orderN":
            self.row_t = np.full(height, kernels.NEVER, dtype=np.int64)
            self.row_x = np.full(height, -1, dtype=np.int64)
            self.col_t = np.full(width, kernels.NEVER, dtype=np.int64)
            self.col_y = np.full(width, -1, dtype=np.int64)
        if method == "mlpf":
            weights = params["weights"]
            self.mlpf = weights
            self.time_map = mlpf_kernels.padded_maps(width, height, weights.radius)
            self.logit = math.log(params["threshold"] / (1.0 - params["threshold"]))
            self.hidden = np.empty(len(weights.b1))
        if method == "hotpixel":
            self.hot_map = params.get("hot_map")
            self.learning = self.hot_map is None
            if self.learning:
                self.hot_map = np.zeros((height, width), dtype=bool)
                self.counts = np.zeros(height * width, dtype=np.int64)
                self.held: list[np.ndarray] = []
                self.held_events = 0
                self.t_first: int | None = None
                self.learned_duration_s = 0.0
        self.width = width

    def filter(self, chunk: np.ndarray) -> np.ndarray:
        """The events of ``chunk`` this stage keeps (state updated)."""
        if not len(chunk):
            return chunk
        words = record_words(np.ascontiguousarray(chunk))
        out = np.empty_like(words)
        q = self.params
        if self.method == "baf":
            n = kernels.baf(words, self.time_map, q["dt_us"], self.jaer, out)
        elif self.method == "stcf" and q.get("polarity_maps"):
            n = kernels.stcf_polarity_maps(words, self.time_map, q["dt_us"], q["radius"], q["k"], out)
        elif self.method == "stcf":
            n = kernels.stcf(words, self.time_map, q["dt_us"], q["radius"], q["k"],
                             q["polarity"], self.jaer, self.jaer, out)
        elif self.method == "dwf":
            n = kernels.dwf(words, self.kept_xy, self.rejected_xy, self.counters, q["distance"], q["k"], out)
        elif self.method == "orderN":
            n = kernels.order_n(words, self.row_t, self.row_x, self.col_t, self.col_y, q["dt_us"], self.jaer,
                                self.jaer, out)
        elif self.method == "refractory":
            n = kernels.refractory(words, self.time_map, q["dt_us"], self.jaer, out)
        elif self.method == "mlpf":
            w = self.mlpf
            n = mlpf_kernels.mlpf(words, self.time_map, w.radius, w.tau_us, w.w1, w.b1, w.w2, w.b2, self.logit,
                                  self.hidden, out)
        else:
            n = kernels.hot_pixels(words, self.hot_map, out)
        return out[:n].reshape(-1).view(EVENT_DTYPE)

    def process(self, chunk: np.ndarray) -> np.ndarray:
        if self.method == "hotpixel" and self.learning:
            return self._learn(chunk)
        return self.filter(chunk)

    def _learn(self, chunk: np.ndarray) -> np.ndarray:
        """Hold the learning stretch (its first ``learn_us``, at most :data:`MAX_LEARN_EVENTS` events); when it
        ends, decide the hot pixels and release it filtered."""
        if not len(chunk):
            return chunk[:0]
        if self.t_first is None:
            self.t_first = int(chunk["t"][0])
        end_t = self.t_first + self.params["learn_us"]
        n = min(int(np.searchsorted(chunk["t"], end_t, side="left")), MAX_LEARN_EVENTS - self.held_events)
        part = chunk[:n]
        self._count(part)
        self.held.append(part)
        self.held_events += n
        if self.held_events >= MAX_LEARN_EVENTS:  # the stretch ends at its event cap: its span is what it holds
            self._decide(int(part["t"][-1]) - self.t_first + 1)
        elif n < len(chunk):  # an event at or after t_first + learn_us: the stretch is learn_us long
            self._decide(self.params["learn_us"])
        else:
            return chunk[:0]
        rest = chunk[n:]
        return join([self._release(), self.filter(rest)])

    def _count(self, part: np.ndarray) -> None:
        self.counts += np.bincount(part["y"].astype(np.int64) * self.width + part["x"], minlength=len(self.counts))

    def _decide(self, duration_us: int) -> None:
        q = self.params
        self.learned_duration_s = max(duration_us, 1) * 1e-6
        self.hot_map = learn_hot_pixels(self.counts.reshape(self.hot_map.shape), self.learned_duration_s,
                                        q["hot_ratio"], q["hot_min_events"], q["hot_rate_hz"])
        self.learning = False

    def _release(self) -> np.ndarray:
        held = join(self.held) if self.held else empty_events()
        self.held = []
        return self.filter(held)

    def flush(self) -> np.ndarray:
        if self.method == "hotpixel" and self.learning:
            if self.t_first is None:  # no event at all: nothing learned
                self.learning = False
                return empty_events()
            held_t = self.held[-1]["t"][-1] if self.held_events else self.t_first
            self._decide(int(held_t) - self.t_first + 1)  # a short stream: its whole span
            return self._release()
        return empty_events()


class BAFilter:
    """One or several background-activity filter stages for a ``width x height`` sensor, run in order.

    Parameters
    ----------
    width, height : int
        Sensor size; every state array is sized from it.
    methods : str or list of str
        ``"baf"``, ``"stcf"``, ``"dwf"``, ``"orderN"``, ``"refractory"``, ``"hotpixel"``, or several separated
        by commas, applied in that order (a stage sees only what the previous ones kept).
    preset : {"evtools", "dv", "jaer"}
        Semantics and defaults (see the module documentation); ``dv`` allows ``baf`` only.
    dt_us : int, optional
        Correlation window (baf, stcf, orderN) or refractory period (refractory), microseconds, >= 1.
    k : int, optional
        Supporting events needed (stcf: neighbours, 1..(2r+1)^2-1; dwf: stored events).
    radius : int, optional
        stcf neighbourhood radius r (window (2r+1)^2).
    polarity : bool, optional
        stcf counts only neighbours of the event's polarity.
    polarity_maps : bool, optional
        stcf keeps a time map per polarity, so a neighbour's last event of the event's polarity counts even when
        one of the other polarity came after it (evtools preset; implies ``polarity``).
    threshold, weights : optional
        mlpf: the probability above which an event is kept (0 < threshold < 1, default 0.5) and the perceptron
        (a :class:`evtools.mlpf.Weights`, a path to an ``.npz``, or None: the weights shipped with evtools).
    window : int, optional
        dwf length of each of the two FIFO windows.
    distance : int, optional
        dwf L1 distance: a stored event supports when ``|dx| + |dy| < distance``.
    learn_us, hot_ratio, hot_min_events, hot_rate_hz : optional
        hotpixel learning (see :func:`learn_hot_pixels`); the events of the learning stretch are held back
        (at most :data:`MAX_LEARN_EVENTS`) and released filtered once the hot pixels are known.
    hot_map : ndarray of bool (height, width), optional
        hotpixel: the hot pixels to drop (no learning).
    check : bool, optional
        Check every chunk as a reader does (default): events on the sensor and in time order, in EVENT_DTYPE or its
        fields in another layout (converted); bad input raises :class:`evtools.InvalidEventsError` (the kernels
        index per-pixel state by the coordinates). The command line passes False: its readers have checked.

    Attributes
    ----------
    parameters : list of dict
        Per stage: the method and its resolved parameters.
    events_in, events_out : int
    """

    def __init__(self, width: int, height: int, methods="baf", *, preset: str = "evtools", check: bool = True,
                 **params) -> None:
        check_sensor_size(width, height)
        self.width, self.height = int(width), int(height)
        self._checker = StreamChecker(StreamInfo(self.width, self.height)) if check else None
        if preset not in PRESETS:
            raise BAFilterError(f"unknown preset {preset!r}; choose among {', '.join(PRESETS)}")
        self.preset = preset
        unknown = set(params) - set(PARAMETERS) - {"hot_map"}
        if unknown:
            raise BAFilterError(f"unknown parameter(s) {', '.join(sorted(unknown))}")
        given = {name: value for name, value in params.items() if value is not None}
        if given.get("polarity_maps") and preset != "evtools":
            raise BAFilterError(f"stcf polarity maps are evtools' own: use --preset evtools, not {preset}")
        self.stages = []
        self.parameters = []
        for method in parse_methods(methods):
            if method not in DEFAULTS[preset]:
                if preset == "dv":
                    raise BAFilterError(f"--preset dv is dv-processing's BackgroundActivityNoiseFilter: it has "
                                        f"method baf only, not {method}")
                raise BAFilterError(f"--preset {preset} has no method {method}; use --preset evtools")
            q = self._check({**DEFAULTS[preset][method], **{n: v for n, v in given.items()
                                                             if n in DEFAULTS[preset][method] or n == "hot_map"}},
                            method)
            self.stages.append(_Stage(method, self.width, self.height, preset, q))
            self.parameters.append({"method": method, **{n: v.info.get("file", "given") if n == "weights" else v
                                                         for n, v in q.items() if n != "hot_map"}})
        self.events_in = self.events_out = 0
        self._flushed = False

    def _check(self, q: dict[str, Any], method: str) -> dict[str, Any]:
        if "dt_us" in q:  # (at most 2^62: a window beyond the event times' range overflowed their differences)
            q["dt_us"] = _int_param("dt_us", q["dt_us"], 1, MAX_TIME_US)
        if "radius" in q:
            q["radius"] = _int_param("radius", q["radius"], 1, 10)
        if "k" in q:
            high = (2 * q["radius"] + 1) ** 2 - 1 if method == "stcf" else 1 << 31
            q["k"] = _int_param("k", q["k"], 1, high)
        if "polarity" in q:
            q["polarity"] = bool(q["polarity"])
        if q.get("polarity_maps"):
            q["polarity_maps"] = True
            if not q["polarity"]:
                raise BAFilterError("polarity maps count neighbours of the event's polarity: they cannot go with "
                                    "polarity off")
        if "window" in q:
            q["window"] = _int_param("window", q["window"], 1, 1 << 16)
        if "distance" in q:
            q["distance"] = _int_param("distance", q["distance"], 1, 1 << 16)
        if "learn_us" in q:
            q["learn_us"] = _int_param("learn_us", q["learn_us"], 1, MAX_TIME_US)
            q["hot_ratio"] = _float_param("hot_ratio", q["hot_ratio"], 1.0)
            q["hot_min_events"] = _int_param("hot_min_events", q["hot_min_events"], 1, 1 << 62)
            q["hot_rate_hz"] = _float_param("hot_rate_hz", q["hot_rate_hz"], 0.0)
        if "threshold" in q:
            threshold = q["threshold"]
            if not isinstance(threshold, (int, float)) or not 0.0 < threshold < 1.0:
                raise BAFilterError(f"threshold must be a probability strictly between 0 and 1, got {threshold!r}")
            q["threshold"] = float(threshold)
        if "weights" in q:
            try:
                q["weights"] = (q["weights"].check("weights") if isinstance(q["weights"], Weights)
                                else load_weights(q["weights"]))
            except MlpfError as error:
                raise BAFilterError(str(error)) from None
        if q.get("hot_map") is not None:
            hot = np.asarray(q["hot_map"], dtype=bool)
            if hot.shape != (self.height, self.width):
                raise BAFilterError(f"hot-pixel map is {hot.shape[1]}x{hot.shape[0]}, the sensor "
                                    f"{self.width}x{self.height}")
            q["hot_map"] = hot
        return q

    @property
    def hot_map(self) -> np.ndarray | None:
        """The hot pixels of the first ``hotpixel`` stage (learned or given), or None."""
        for stage in self.stages:
            if stage.method == "hotpixel":
                return None if stage.learning else stage.hot_map
        return None

    def released_us(self, last_us: int) -> int:
        """The time before which the output is final once the input has reached ``last_us``: ``last_us``, or the
        start of what a learning ``hotpixel`` stage holds (APS frames pass on once the output reaches them)."""
        held = [stage.t_first for stage in self.stages
                if stage.method == "hotpixel" and stage.learning and stage.t_first is not None]
        return min([last_us, *held])

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """The events of ``chunk`` that every stage keeps (those a learning stage holds come later)."""
        if self._flushed:
            raise BAFilterError("BAFilter: process() after flush(); make a new filter for a new stream")
        chunk = self._checker.check(chunk) if self._checker else as_chunk(chunk)
        self.events_in += len(chunk)
        out = self._run(chunk, 0)
        self.events_out += len(out)
        return out

    def _run(self, chunk: np.ndarray, first: int) -> np.ndarray:
        for stage in self.stages[first:]:
            if not len(chunk) and not (stage.method == "hotpixel" and stage.learning):
                return chunk
            chunk = stage.process(chunk)
        return chunk

    def flush(self) -> np.ndarray:
        """What learning stages still hold, filtered by the stages after them; ends the stream."""
        self._flushed = True
        parts = []
        for index, stage in enumerate(self.stages):
            held = stage.flush()
            if len(held):
                parts.append(self._run(held, index + 1))
        out = join(parts) if parts else empty_events()
        self.events_out += len(out)
        return out


def ba_filter(events: np.ndarray, width: int, height: int, methods="baf", *, preset: str = "evtools",
              **params) -> np.ndarray:
    """Filter a whole event array: :class:`BAFilter` ``process`` then ``flush`` (see there for the parameters).

    Examples
    --------
    >>> kept = ba_filter(events, 346, 260, "hotpixel,stcf", k=2, dt_us=10_000)   # doctest: +SKIP
    """
    ba = BAFilter(width, height, methods, preset=preset, **params)
    return join([ba.process(events), ba.flush()])
