"""A chain of filter stages as one stream processor (:class:`BAFilter`), and the one-shot :func:`ba_filter`."""

from __future__ import annotations

from typing import Any

import numpy as np

from evtools.events import StreamChecker, StreamInfo, as_chunk, check_sensor_size, empty_events, join
from evtools.filters.registry import BY_NAME, METHODS, document
from evtools.filters.spec import PRESETS, BAFilterError, Filter


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


def check_preset(methods: list[str], preset: str) -> None:
    """Every method of the chain exists under ``preset``, or BAFilterError."""
    if preset not in PRESETS:
        raise BAFilterError(f"unknown preset {preset!r}; choose among {', '.join(PRESETS)}")
    missing = [method for method in methods if preset not in BY_NAME[method].defaults]
    if missing:
        has = ", ".join(f.name for f in BY_NAME.values() if preset in f.defaults)
        raise BAFilterError(f"--preset {preset} has no method {', '.join(missing)} (it has {has}); use --preset "
                            "evtools")


def not_applying(methods: list[str], preset: str, names) -> list[str]:
    """The parameter names among ``names`` that no method of the chain has under ``preset``."""
    used = {name for method in methods for name in BY_NAME[method].defaults[preset]}
    return [name for name in names if name not in used]


def checked_parameters(methods: list[str], preset: str, given: dict[str, Any]) -> list[dict[str, Any]]:
    """Each method's parameters: the preset's defaults with ``given`` over them, each checked
    (:meth:`evtools.filters.spec.Param.check`; BAFilterError), before any stage is made (the command line checks
    them so, as usage)."""
    checked = []
    for method in methods:
        kind = BY_NAME[method]
        defaults = kind.defaults[preset]
        q: dict[str, Any] = {}
        for param in kind.params:
            if param.name in defaults:
                value = given.get(param.name, defaults[param.name])
                q[param.name] = value if value is None else param.check(value, q)
        checked.append(q)
    return checked


class BAFilter:
    """One or several background-activity filter stages for a ``width x height`` sensor, run in order.

    Parameters
    ----------
    width, height : int
        Sensor size; every state array is sized from it.
    methods : str or list of str
        One of :data:`evtools.filters.METHODS`, or several separated by commas, applied in that order (a stage
        sees only what the previous ones kept).
    preset : {"evtools", "dv", "jaer"}
        Semantics and defaults (see :mod:`evtools.filters`); ``dv`` allows ``baf`` only.
    check : bool, optional
        Check every chunk as a reader does (default): events on the sensor and in time order, in EVENT_DTYPE or its
        fields in another layout (converted); bad input raises :class:`evtools.InvalidEventsError` (the kernels
        index per-pixel state by the coordinates). The command line passes False: its readers have checked.
    **params
        The filters' parameters (below; None or absent: the preset's default). A parameter that no method of
        the chain has under the preset is refused, as on the command line.

    Attributes
    ----------
    stages : list of Filter
    parameters : list of dict
        Per stage: the method and its resolved parameters.
    events_in, events_out : int
    """

    def __init__(self, width: int, height: int, methods="baf", *, preset: str = "evtools", check: bool = True,
                 **params) -> None:
        check_sensor_size(width, height)
        self.width, self.height = int(width), int(height)
        self._checker = StreamChecker(StreamInfo(self.width, self.height)) if check else None
        names = parse_methods(methods)
        check_preset(names, preset)
        self.preset = preset
        given = {name: value for name, value in params.items() if value is not None}
        known = {param.name for f in BY_NAME.values() for param in f.params}
        unknown = sorted(set(params) - known)
        if unknown:
            raise BAFilterError(f"unknown parameter(s) {', '.join(unknown)}")
        stray = not_applying(names, preset, given)
        if stray:
            raise BAFilterError(f"{', '.join(stray)} do(es) not apply to {','.join(names)} (preset {preset})")
        self.stages: list[Filter] = [
            BY_NAME[method](self.width, self.height, preset, BY_NAME[method].prepare(q, self.width, self.height))
            for method, q in zip(names, checked_parameters(names, preset, given))]
        self.parameters = [{"method": stage.name, **stage.record()} for stage in self.stages]
        self.events_in = self.events_out = 0
        self._flushed = False

    @property
    def hot_map(self) -> np.ndarray | None:
        """The hot pixels of the first ``hotpixel`` stage (learned or given), or None."""
        for stage in self.stages:
            if stage.name == "hotpixel":
                return None if stage.learning else stage.hot_map
        return None

    def released_us(self, last_us: int) -> int:
        """The time before which the output is final once the input has reached ``last_us``: ``last_us``, or the
        first event a stage holds back (APS frames pass on once the output reaches them)."""
        held = [stage.held_since() for stage in self.stages]
        return min([last_us, *(t for t in held if t is not None)])

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
            if not len(chunk):
                return chunk
            chunk = stage.process(chunk)
        return chunk

    def flush(self) -> np.ndarray:
        """What stages still hold, filtered by the stages after them; ends the stream."""
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
    """Filter a whole event array: :class:`BAFilter` ``process`` then ``flush`` (parameters below).

    Examples
    --------
    >>> kept = ba_filter(events, 346, 260, "hotpixel,stcf", k=2, dt_us=10_000)   # doctest: +SKIP
    """
    ba = BAFilter(width, height, methods, preset=preset, **params)
    return join([ba.process(events), ba.flush()])


document(ba_filter, "events", "width", "height")
document(BAFilter)
