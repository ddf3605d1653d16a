"""Online threshold-mismatch correction: every pixel re-sampled at one target threshold (``evtools correct``).

The founding report's section 4.2: a pixel's events are samples of its log intensity taken at that pixel's own
thresholds; reconstruct the signal (first-order hold between the pixel's events) and sample it again at one target
threshold, so that every pixel behaves as if it had the same threshold. :class:`ThresholdCorrector` is the stream
processor, :func:`correct_thresholds` the one-shot convenience; ``evtools/_kernels/correct.py`` holds the
per-event loop and the three modes (``foh``, ``step``, ``highpass``).

Ordering. A re-sampled event lies between its pixel's previous original event (or the interpolation start, never
earlier than ``max_gap_us`` before the current event) and the current one, so the events created for one input
event may precede events already created for others. The corrector keeps the created events in a reorder buffer
and releases, sorted by time (ties in creation order, a stable sort), those no later event can precede: every
future event is created at or after ``bound = max(min over pixels of their last event time, t_now - window)``,
with ``window`` = ``max_gap_us`` (``hold_us`` in ``step`` and ``highpass`` when smaller). So the latency and the
buffer are bounded by ``window`` of output, whatever the gaps. When every pixel's thresholds equal the target,
each input event creates exactly itself, and the output is the input, bit for bit and in its order.

References
----------
The founding report (``../shared/seed``), sections 4.2, 5.2, 5.3.
C. Scheerlinck, N. Barnes, R. Mahony, "Continuous-time Intensity Estimation Using Event Cameras", ACCV 2018.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from evtools._kernels.correct import MODE_FOH, MODE_HIGHPASS, MODE_STEP, NO_EVENT_US, correct_events
from evtools.errors import EvtoolsError
from evtools.events import EVENT_DTYPE, check_sensor_size, empty_events, join

__all__ = ["CORRECT_DEFAULTS", "MODES", "CorrectionError", "ThresholdCorrector", "correct_thresholds"]

MODES = {"foh": MODE_FOH, "step": MODE_STEP, "highpass": MODE_HIGHPASS}
"""Reconstruction modes by name (see :mod:`evtools._kernels.correct`)."""

CORRECT_DEFAULTS: dict[str, Any] = {
    "mode": "highpass",
    "hold_us": 300_000,
    "max_gap_us": 1_000_000,
    "tau_us": 100_000.0,
}
"""Defaults: the drift-free ``highpass`` mode, 300 ms hold, 100 ms decay time constant, a 1 s reordering bound."""


class CorrectionError(EvtoolsError, ValueError):
    """Bad parameters or thresholds for the correction."""


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise CorrectionError(f"{name} must be a whole number of microseconds >= 1, got {value!r}")
    return int(value)


def resolve_target(target, on: np.ndarray, off: np.ndarray, usable: np.ndarray) -> tuple[float, float]:
    """The target (ON, OFF) thresholds: a positive number for both, or ``"median"`` of the usable pixels' maps.

    The value is rounded to float32, the precision of the threshold maps, so that a map equal to the target
    (``0.2`` stored as float32) is recognised as such and passes through unchanged.
    """
    if isinstance(target, str):
        if target.strip().lower() != "median":
            try:
                target = float(target)
            except ValueError:
                raise CorrectionError(f"target must be a positive number or 'median', got {target!r}") from None
        else:
            if not usable.any():
                raise CorrectionError("no pixel has a usable threshold estimate: cannot take the median")
            return float(np.float32(np.median(on[usable]))), float(np.float32(np.median(off[usable])))
    try:
        value = float(target)
    except (TypeError, ValueError):
        raise CorrectionError(f"target must be a positive number or 'median', got {target!r}") from None
    if not np.isfinite(value) or value <= 0 or np.float32(value) <= 0:
        raise CorrectionError(f"target threshold must be a positive number of log units, got {target!r}")
    value = float(np.float32(value))
    return value, value


class ThresholdCorrector:
    """Re-samples every pixel of a ``width x height`` sensor at one target threshold, chunk by chunk.

    Parameters
    ----------
    width, height : int
        Sensor size in pixels.
    on, off : array_like, shape (height, width)
        Each pixel's ON and OFF contrast thresholds (log units), e.g. from ``evtools estimate`` or the truth file
        of ``evtools simulate``.
    valid : array_like of bool, shape (height, width), optional
        Pixels that hold an estimate; pixels not valid (or whose thresholds are not finite and positive) take the
        median of the usable pixels' thresholds, ON and OFF separately.
    target : float or "median"
        The threshold every pixel is re-sampled at (one value for ON and OFF), or the median of the maps.
    mode : {"highpass", "foh", "step"}
        ``foh``: the report's first-order hold; ``step``: stepwise over gaps longer than ``hold_us`` (the report's
        section 5.2); ``highpass`` (default): ``step`` plus an exponential decay of the carried level with time
        constant ``tau_us``, which keeps estimation errors from accumulating (drift-free).
    hold_us : int
        ``step`` and ``highpass``: gaps longer than this are held constant until the next event.
    max_gap_us : int
        Interpolation never starts earlier than this before the current event: bounds the reordering window.
    tau_us : float
        ``highpass``: time constant of the decay of the carried level towards the pixel's own reference.

    References
    ----------
    The founding report, sections 4.2 and 5.2; Scheerlinck, Barnes, Mahony, ACCV 2018 (high-pass decay).
    """

    def __init__(self, width: int, height: int, on, off, valid=None, *, target="median",
                 mode: str = CORRECT_DEFAULTS["mode"], hold_us: int = CORRECT_DEFAULTS["hold_us"],
                 max_gap_us: int = CORRECT_DEFAULTS["max_gap_us"], tau_us: float = CORRECT_DEFAULTS["tau_us"]):
        check_sensor_size(width, height)
        self.width, self.height = int(width), int(height)
        on = np.asarray(on, dtype=np.float32)
        off = np.asarray(off, dtype=np.float32)
        if on.shape != (self.height, self.width) or off.shape != on.shape:
            raise CorrectionError(
                f"thresholds are {on.shape[1] if on.ndim == 2 else '?'}x{on.shape[0] if on.ndim == 2 else '?'} "
                f"but the sensor is {self.width}x{self.height}; give the thresholds of this sensor"
            )
        valid = np.ones(on.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
        if valid.shape != on.shape:
            raise CorrectionError("the valid map must have the shape of the thresholds")
        with np.errstate(invalid="ignore"):
            usable = valid & np.isfinite(on) & np.isfinite(off) & (on > 0) & (off > 0)
        if not usable.any():
            raise CorrectionError("no pixel has a usable threshold (valid, finite and positive): nothing to correct")
        if mode not in MODES:
            raise CorrectionError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.target_on, self.target_off = resolve_target(target, on, off, usable)
        self.mode = mode
        self.hold_us = _positive_int("hold_us", hold_us)
        self.max_gap_us = _positive_int("max_gap_us", max_gap_us)
        tau_us = float(tau_us)
        if not np.isfinite(tau_us) or tau_us <= 0:
            raise CorrectionError(f"tau_us must be a positive number of microseconds, got {tau_us!r}")
        self.tau_us = tau_us
        on = np.where(usable, on, np.median(on[usable])).astype(np.float32)
        off = np.where(usable, off, np.median(off[usable])).astype(np.float32)
        self._on = on.astype(np.float64).reshape(-1)
        self._off = off.astype(np.float64).reshape(-1)
        # pixels already at the target need no work (and their events stay bit for bit what they were)
        self._use = ~((self._on == self.target_on) & (self._off == self.target_off))
        self.usable = usable
        self.window_us = self.max_gap_us if mode == "foh" else min(self.max_gap_us, self.hold_us)
        n = self.width * self.height
        self._last_us = np.full(n, NO_EVENT_US, dtype=np.int64)
        self._level = np.zeros(n, dtype=np.float64)
        self._held = empty_events()
        self._t_now: int | None = None
        self.parameters: dict[str, Any] = {
            "target_on": self.target_on, "target_off": self.target_off, "mode": mode, "hold_us": self.hold_us,
            "max_gap_us": self.max_gap_us, "tau_us": self.tau_us,
        }

    def _resample(self, chunk: np.ndarray) -> np.ndarray:
        """Every event that ``chunk`` creates, in creation order."""
        t, x, y, p = chunk["t"], chunk["x"], chunk["y"], chunk["p"]
        parts = []
        start = 0
        capacity = max(1024, 2 * len(chunk))
        mode = MODES[self.mode]
        while True:
            out = np.empty(capacity, dtype=EVENT_DTYPE)
            start, n = correct_events(
                t, x, y, p, start, self.width, self._on, self._off, self._use, self.target_on, self.target_off,
                self._last_us, self._level, mode, self.hold_us, self.max_gap_us, self.tau_us,
                out["t"], out["x"], out["y"], out["p"],
            )
            parts.append(out[:n])
            if start >= len(chunk):
                break
            if n == 0:
                capacity *= 2
        return parts[0] if len(parts) == 1 else join(parts)

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """The corrected events that are final once ``chunk`` (time-sorted, after the previous ones) is seen."""
        if len(chunk) == 0:
            return empty_events()
        if chunk.dtype != EVENT_DTYPE:
            raise CorrectionError(f"chunk has dtype {chunk.dtype}, expected EVENT_DTYPE")
        created = self._resample(chunk)
        self._t_now = int(chunk["t"][-1])
        bound = max(int(self._last_us.min()) if self._use.any() else self._t_now, self._t_now - self.window_us)
        bound = min(bound, self._t_now)
        pending = created if len(self._held) == 0 else join([self._held, created])
        if len(pending) and np.any(pending["t"][1:] < pending["t"][:-1]):
            pending = pending[np.argsort(pending["t"], kind="stable")]
        cut = int(np.searchsorted(pending["t"], bound, side="right"))
        self._held = pending[cut:].copy() if cut < len(pending) else empty_events()
        return pending[:cut]

    def flush(self) -> np.ndarray:
        """Whatever is still held (the stream ended)."""
        held, self._held = self._held, empty_events()
        return held


def correct_thresholds(events: np.ndarray, width: int, height: int, on, off, valid=None, **options) -> np.ndarray:
    """Re-sample ``events`` of a ``width x height`` sensor at one target threshold (process + flush).

    See :class:`ThresholdCorrector` for the parameters.
    """
    corrector = ThresholdCorrector(width, height, on, off, valid, **options)
    out = corrector.process(np.asarray(events))
    rest = corrector.flush()
    return out if len(rest) == 0 else join([out, rest])
