"""What a filter is: its parameters declared once (:class:`Param`) and a stage class (:class:`Filter`).

Everything else is derived from these declarations: the checks and the "does not apply to this method" rule
(:mod:`evtools.filters.chain`), the command line's options and ``metrics roc``'s sweepable parameters
(``cli/bafilter.py``, ``cli/metrics_denoise.py``), the README's table and the API's signatures
(:mod:`evtools.filters.registry`). Adding a filter is a kernel, one module here, one naive reference in
``tests/naive/bafilter.py`` and one line in :data:`evtools.filters.registry.REGISTRY`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar

import numpy as np

from evtools._kernels.bafilter import NEVER
from evtools.errors import EvtoolsError, UsageMistake
from evtools.events import EVENT_DTYPE, MAX_TIME_US, empty_events, record_words

PRESETS = ("evtools", "dv", "jaer")
"""Semantics and defaults: evtools' own, dv-processing's, jAER's (see :mod:`evtools.filters`)."""

KINDS = ("time_us", "int", "float", "probability", "bool", "weights", "pixels")
"""What a parameter holds: a time in microseconds, a whole number, a number, a probability (strictly between 0
and 1), a switch, MLPF weights (a path or :class:`evtools.mlpf.Weights`), a per-pixel mask (Python only)."""


class BAFilterError(EvtoolsError, ValueError):
    """A bad filter parameter or method name."""


class BAFilterSettingsError(BAFilterError, UsageMistake):
    """Filter parameters that do not go together (polarity maps without polarity): a usage error (exit 2)."""


@dataclass(frozen=True)
class Param:
    """One parameter of one filter.

    ``name`` is the Python keyword (units in the name: ``dt_us``, ``hot_rate_hz``) and, with ``-`` for ``_``, the
    command-line option, unless ``flag`` gives it (``"--same-polarity/--any-polarity"``). ``low`` and ``high``
    bound it (inclusive; ``high`` may be a function of the parameters checked before it, e.g. STCF's ``k`` of
    its ``radius``). ``help`` says what it does for this filter, without its default (the defaults are the
    filter's :attr:`Filter.defaults`). ``sweepable``: ``metrics roc --sweep`` may vary it. ``cli``: False for a
    parameter the command line gives in another form (a hot-pixel mask from ``--hot-pixels FILE``)."""

    name: str
    kind: str
    help: str
    low: float | None = None
    high: float | Callable[[dict], float] | None = None
    flag: str | None = None
    sweepable: bool = True
    cli: bool = True

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"{self.name}: kind {self.kind!r} is not one of {KINDS}")

    @property
    def option(self) -> str:
        """The command-line option (its first name)."""
        return (self.flag or "--" + self.name.replace("_", "-")).split("/")[0]

    def check(self, value, checked: dict[str, Any]):
        """``value`` checked and converted (``checked``: the parameters checked before it), or BAFilterError."""
        high = self.high(checked) if callable(self.high) else self.high
        if self.kind in ("time_us", "int"):
            low = int(self.low if self.low is not None else 1)
            high = MAX_TIME_US if self.kind == "time_us" and high is None else high
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low or (
                    high is not None and value > high):
                bound = f">= {low}" if high is None else f"in {low}..{int(high)}"
                raise BAFilterError(f"{self.name} must be a whole number {bound}, got {value!r}")
            return int(value)
        if self.kind == "float":
            try:
                number = float(value)
            except (TypeError, ValueError):
                raise BAFilterError(f"{self.name} must be a number >= {self.low}, got {value!r}") from None
            if not math.isfinite(number) or number < self.low:
                raise BAFilterError(f"{self.name} must be a finite number >= {self.low}, got {value!r}")
            return number
        if self.kind == "probability":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value < 1.0:
                raise BAFilterError(f"{self.name} must be a probability strictly between 0 and 1, got {value!r}")
            return float(value)
        if self.kind == "bool":
            return bool(value)
        return value  # weights and pixels: their filter checks them (Filter.prepare)


class Filter:
    """One stage of a filter chain for a ``width x height`` sensor; a subclass per method.

    Class attributes: ``name`` (the method's name), ``keeps`` (when an event passes, for the README's table),
    ``params`` (its :class:`Param` s, checked in this order), ``defaults`` (preset -> parameter -> value; a
    preset the filter lacks is not a key; a parameter a preset lacks does not apply under it). The stage's
    checked parameters are ``params_used``.

    A stage copies the records it keeps (:meth:`run`: its kernel on a chunk's raw words); stages that hold
    events back (``hotpixel`` while it learns) override :meth:`process`, :meth:`flush` and :meth:`held_since`.
    """

    name: ClassVar[str]
    keeps: ClassVar[str]
    params: ClassVar[tuple[Param, ...]]
    defaults: ClassVar[dict[str, dict[str, Any]]]
    reference: ClassVar[str] = ""
    """Whose method it is, short (``"Delbruck 2008"``), for the API's docstring; the module's docstring cites it."""
    defaults_from: ClassVar[str] = ""
    """Whose defaults evtools' are, when they are someone's (the README's table)."""
    default_notes: ClassVar[dict[str, str]] = {}
    """Parameter -> what its default means, where the value alone does not say (None: "the shipped ones")."""

    def __init__(self, width: int, height: int, preset: str, q: dict[str, Any]) -> None:
        self.width, self.height, self.preset, self.params_used = width, height, preset, q
        self.jaer = preset == "jaer"
        self.start = 0 if preset == "dv" else NEVER  # dv-processing's time map starts at 0

    @classmethod
    def prepare(cls, q: dict[str, Any], width: int, height: int) -> dict[str, Any]:
        """Checks across parameters and conversions of those :meth:`Param.check` leaves (override)."""
        return q

    def record(self) -> dict[str, Any]:
        """The parameters as ``BAFilter.parameters`` reports them (JSON-friendly)."""
        return {name: value for name, value in self.params_used.items()
                if next(p for p in self.params if p.name == name).kind != "pixels"}

    def run(self, words: np.ndarray, out: np.ndarray) -> int:
        """The kernel: copy the kept records of ``words`` to ``out``, return how many."""
        raise NotImplementedError

    def filter(self, chunk: np.ndarray) -> np.ndarray:
        """The events of ``chunk`` this stage keeps (state updated)."""
        if not len(chunk):
            return chunk
        words = record_words(np.ascontiguousarray(chunk))
        out = np.empty_like(words)
        n = self.run(words, out)
        return out[:n].reshape(-1).view(EVENT_DTYPE)

    def process(self, chunk: np.ndarray) -> np.ndarray:
        return self.filter(chunk)

    def flush(self) -> np.ndarray:
        """What the stage still holds at the end of the stream (filtered)."""
        return empty_events()

    def held_since(self) -> int | None:
        """The time of the first event the stage holds back, or None."""
        return None
