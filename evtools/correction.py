"""Online threshold-mismatch correction: every pixel re-sampled at one target threshold (``evtools correct``).

The founding report's section 4.2: a pixel's events are samples of its log intensity taken at that pixel's own
thresholds; reconstruct the signal (first-order hold between the pixel's events) and sample it again at one target
threshold, so that every pixel behaves as if it had the same threshold. :class:`ThresholdCorrector` is the stream
processor, :func:`correct_thresholds` the one-shot convenience; ``evtools/_kernels/correct.py`` holds the
per-event loop and the modes (``foh``, ``step``, ``turns``, ``highpass``), plus the merge that releases the
created events in time order.

Ordering. A re-sampled event lies between the start of its segment (the pixel's previous original event, never
earlier than ``max_gap_us`` before the current event) and the current event, so the events created for one input
event may precede events already created for others. The corrector keeps the created events in a reorder buffer
and releases, sorted by time (ties in creation order, the even rows' before the odd rows', see :data:`LANES`), those no
later event can precede or tie with: every future event is created at or after ``bound = max(earliest segment start
of any pixel, t_now - latency_us)``, so the events before ``bound`` are released (one at ``bound`` may still get a
tie from the other lane that the order puts first).
``latency_us`` is one window, ``max_gap_us`` (``hold_us`` in all modes but ``foh`` when smaller), or three with
turns: a segment that waits for the pixel's next event starts at most one window before its event and waits at
most two (a pixel that has not fired yet counts as having fired at the stream's start). So the latency and
the buffer are bounded by ``latency_us`` of output, whatever the gaps (a dense stream holds its rate times
``latency_us``: 8.6 M events at 9.5 Mev/s with the defaults). The events a part creates are sorted once, by a
counting sort over their time span (coarser buckets, each put in order by insertion, when the span is large), into
a run laid after the lane's earlier runs in one buffer; a release merges the runs' parts before the bound (a k-way
merge, one numba kernel for all of a lane's runs), so an event is moved a few times however long it is held. When every
pixel's thresholds equal the target, each input event creates exactly itself, and the output is the input, bit
for bit and in its order.

References
----------
The founding report (summarised in ``docs/algorithms.md`` section 5), sections 4.2, 5.2, 5.3.
C. Scheerlinck, N. Barnes, R. Mahony, "Continuous-time Intensity Estimation Using Event Cameras", ACCV 2018.
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from evtools._kernels.correct import (
    MODE_FOH,
    MODE_HIGHPASS,
    MODE_STEP,
    NO_EVENT_US,
    PIXEL_DTYPE,
    compact_runs,
    compact_waiting,
    correct_events,
    finish_runs,
    earliest_start,
    merge_sorted,
    release_runs,
    settle_waiting,
    sort_created,
    split_rows,
)
from evtools.errors import EvtoolsError
from evtools.events import (EVENT_DTYPE, MAX_THRESHOLD, MAX_TIME_US, StreamChecker, StreamInfo, as_chunk,
                            check_sensor_size, empty_events, join, record_words)

MAX_EVENTS_PER_EVENT = 100
"""A target this many times smaller than the largest pixel threshold is refused: each input event would create about
that many events (a target of 1e-9 once grew a 2,560-event run to 24 GB)."""

FEW_EVENTS_RATIO = 5
"""A target this many times larger than the largest pixel threshold is said: every pixel then keeps at most about a
fifth of its events (``--target 2`` on a 0.2 camera, or a map in other units, emptied the stream with one info
line, a QA sweep), a coarser sensor than anyone asks for by design."""

LANES = 2
"""The pixels are re-sampled in two lanes, the even and the odd sensor rows (any scene's events split about
evenly), each with its own queue of waiting pixels and its own reorder buffer (:class:`_Lane`), so that the lanes
of a long part run on two threads. The lanes' outputs are merged, the even rows' first on ties (each lane's ties in
creation order): the output depends on neither the threads nor the chunks."""

PART = 1 << 16
"""Events per part of a long chunk: each part is split into the lanes, re-sampled, sorted into a run, and released.
The lanes' buffers are sized by it; smaller parts cost more per event (each has fixed costs: kernel calls, two
hand-overs to the lane thread, and more runs to merge): on 3 M events of a DVXplorer recording, two threads,
min of 5 runs, 62 ns an event with 2^15, 55 with 2^16, 53 with 2^17. 2^16 (was 2^17): `correct` on 50M LZ4
events peaks 9-11 MiB lower (93 MiB against 102-104), for a time within this machine's noise (10M events, 8
alternating runs: mean 1.08 s against 1.05)."""

QUEUE_ENTRIES = 1 << 16
"""A lane's queue of waiting pixels starts with room for this many entries (it is compacted, then grown)."""

PARALLEL_EVENTS = 1 << 14
"""Parts of at least this many events run their lanes on two threads (smaller ones are not worth a hand-over)."""

__all__ = ["CORRECT_DEFAULTS", "MAX_WINDOW_US", "MODES", "CorrectionError", "ThresholdCorrector", "correct_thresholds"]

MODES = {"highpass": MODE_HIGHPASS, "exponential": MODE_STEP, "turns": MODE_STEP, "step": MODE_STEP,
         "foh": MODE_FOH}
"""Reconstruction modes by name (see :mod:`evtools._kernels.correct`): ``foh`` and ``step`` are the report's;
``turns`` is ``step`` with the reconstruction anchored at the stream's start and the extremum of every reversal
where the lines of the runs on both sides meet;
``highpass`` is ``turns`` plus the decay of the carried level over rests; ``exponential`` (the default) is ``turns``
with the segments of a run that slows down drawn as the exponential approach through its last three events, and
that approach's tail re-sampled when the pixel stops firing (a photoreceptor's first-order low-pass after a
step)."""

CORRECT_DEFAULTS: dict[str, Any] = {
    "target": 0.2,
    "mode": "exponential",
    "hold_us": 300_000,
    "max_gap_us": 1_000_000,
    "tau_us": 100_000.0,
}
"""Defaults: target 0.2 (v2e's nominal threshold), ``exponential`` (it wins on the Table 2 metrics and is exact on
log-linear ramps, see the README), 300 ms hold (above the inter-event times
in the tail of a photoreceptor low-pass of ~20 ms, below the rests between stimulus edges), 100 ms decay time
constant, a 1 s reordering bound."""


class CorrectionError(EvtoolsError, ValueError):
    """Bad parameters or thresholds for the correction."""


CLOCK_GAP_US = 1_000_000
"""A stream that starts more than this (or more than the series' own span) after a thresholds series' last map is
said to be of another clock (a Unix-time stream with a series on a relative clock was corrected silently, and
worse than not at all: a QA sweep)."""

MAX_WINDOW_US = 2**31 - 1
"""The longest hold and gap (35 min): a pixel's pending segment length is stored in 32 bits."""


def _positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= MAX_WINDOW_US:
        raise CorrectionError(f"{name} must be a whole number of microseconds from 1 to {MAX_WINDOW_US}, "
                              f"got {value!r}")
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
    if not 0 < value <= MAX_THRESHOLD or np.float32(value) <= 0:
        raise CorrectionError(f"target threshold must be a positive number of log units up to {MAX_THRESHOLD:g}, got "
                              f"{target!r}")
    value = float(np.float32(value))
    return value, value


MIXED_SCALES = 0.15
"""How far (relative) the estimated pixels' median may be from the target while other pixels pass on as they are
before :func:`_say_mixed_scales` warns (at 10 % an events-only map's own ON / OFF imbalance tripped it: the DVS128
walk's offE map, ON median 0.1795 against 0.2)."""


def _say_mixed_scales(on, off, usable, target_on: float, target_off: float) -> None:
    """Warn when pixels without an estimate pass on at their own thresholds while the estimated ones, whose median
    is more than :data:`MIXED_SCALES` from the target, are moved to it: the output then mixes two scales and can be
    less uniform than the input (a camera at 0.3 calibrated on half its sensor, corrected to 0.2: count CV
    0.13-0.17 -> 0.23-0.28, a QA sweep)."""
    passed = int(usable.size - usable.sum())
    if not passed:
        return
    median_on, median_off = float(np.median(on[usable])), float(np.median(off[usable]))
    away = max(abs(median_on / target_on - 1.0), abs(median_off / target_off - 1.0))
    if away > MIXED_SCALES:
        logging.getLogger("evtools").warning(
            f"the {passed:,} pixels without an estimate keep their own thresholds while the {int(usable.sum()):,} "
            f"estimated ones (median ON {median_on:.3g}, OFF {median_off:.3g}) go to the target {target_on:.3g} / "
            f"{target_off:.3g}, {100 * away:.0f} % away: the output mixes two scales and may be less uniform than "
            "the input; give the target median (--target median) or a map of every pixel")


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
        Pixels that hold an estimate; pixels not valid (or whose thresholds are not finite and positive) are passed
        on as they are (their thresholds taken as the target): a pixel whose threshold is not known is not made
        worse. (They took the median of the usable pixels', a biased sample: the pixels that fire most, whose
        thresholds are lowest; correct then made sparse scenes worse than doing nothing: a QA sweep.)
    target : float or "median"
        The threshold every pixel is re-sampled at (one value for ON and OFF), or the median of the maps; default
        0.2 (v2e's nominal threshold), the same in the command line and the API.
    mode : {"exponential", "highpass", "turns", "step", "foh"}
        ``foh``: the report's first-order hold; ``step``: stepwise over gaps longer than ``hold_us`` (the report's
        section 5.2); ``turns``: ``step`` anchored at the stream's start, with the extremum of every polarity
        reversal where the lines of the two runs meet (waiting for the second event after the turn), the first
        ramp extended back the same way (exact on piecewise log-linear signals with exact thresholds);
        ``exponential`` (default): ``turns`` with model-based steps (``curves``); ``highpass``: ``turns`` plus an
        exponential decay of the carried level over rests (time constant ``tau_us``): the corrected reference
        relaxes to the pixel's own.
    hold_us : int
        Gaps longer than this are rests (held constant until the next event; all but ``foh``).
    max_gap_us : int
        Interpolation never starts earlier than this before the current event: bounds the reordering window; in
        all modes but ``foh`` a longer gap is a rest (``hold_us`` is at most this).
    tau_us : float
        ``highpass``: time constant of the decay of the carried level towards the pixel's own reference.
    turns : bool or None
        Anchor and reversal extremum on or off regardless of the mode (None: on for ``turns``, ``highpass`` and
        ``exponential``).
    curves : bool or None
        Model-based steps on or off regardless of the mode (None: on for ``exponential``): a segment between two
        events of a run whose interval is more than 1 % longer than the run's previous one is the exponential
        approach ``L_inf - B exp(-t / tau)`` through the run's last three events (one threshold apart: ``tau``
        from the two intervals alone); when the pixel then stops firing for a window, the approach's remaining
        rise towards its asymptote (followed for at most ``3 tau``) is re-sampled too.
    start_us : int or None
        With turns: when every pixel's reconstruction starts at level 0 (the sensor's start); default the first
        event of the stream.
    t_us : array_like of int, optional
        A time series of maps (``estimate --online``): ``on``, ``off``, ``valid`` are (maps, height, width) (or
        anything whose ``[k]`` is map k, such as h5py datasets: read map by map, see :class:`SeriesMaps`) and
        map k is used for the events from ``t_us[k]`` on (the first map before its time too: it is the earliest
        estimate); ``target="median"`` is the median over all maps.
    stale : array_like of bool, optional
        With ``t_us``: (maps, height, width), the pixels whose estimate a map marks as dropped (``fit`` infinite,
        :data:`evtools.estimation.STALE_FIT`): from that map on a pixel does not keep its earlier value but takes
        the map's median until it is valid again.
    check : bool, optional
        Check every chunk as a reader does (default; see :class:`evtools.filters.BAFilter`); the command line
        passes False, its readers having checked.

    References
    ----------
    The founding report, sections 4.2 and 5.2; Scheerlinck, Barnes, Mahony, ACCV 2018 (high-pass decay).
    """

    def __init__(self, width: int, height: int, on, off, valid=None, *, target=CORRECT_DEFAULTS["target"],
                 mode: str = CORRECT_DEFAULTS["mode"], hold_us: int = CORRECT_DEFAULTS["hold_us"],
                 max_gap_us: int = CORRECT_DEFAULTS["max_gap_us"], tau_us: float = CORRECT_DEFAULTS["tau_us"],
                 turns: bool | None = None, curves: bool | None = None, start_us: int | None = None,
                 t_us=None, stale=None, check: bool = True):
        check_sensor_size(width, height)
        self.width, self.height = int(width), int(height)
        self._checker = StreamChecker(StreamInfo(self.width, self.height)) if check else None
        series = t_us is not None
        on, off = (np.asarray(maps, np.float32) if not series or not hasattr(maps, "shape") else maps
                   for maps in (on, off))  # (a series may be datasets on disk: read map by map)
        count = len(np.atleast_1d(t_us)) if series else 1
        shape = (count, self.height, self.width) if series else (self.height, self.width)
        if tuple(on.shape) != shape or tuple(off.shape) != tuple(on.shape):
            size = f"{on.shape[-1]}x{on.shape[-2]}" if len(on.shape) >= 2 else "?"
            raise CorrectionError(
                f"thresholds are {size}{f' ({on.shape[0]} maps)' if len(on.shape) == 3 else ''} but the sensor is "
                f"{self.width}x{self.height}{f' and {count} map times are given' if series else ''}; "
                "give the thresholds of this sensor"
            )
        if mode not in MODES:
            raise CorrectionError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
        if series:
            self._series = SeriesMaps(t_us, on, off, *(maps if maps is None or hasattr(maps, "shape")
                                                       else np.asarray(maps, bool) for maps in (valid, stale)))
            median = isinstance(target, str) and target.strip().lower() == "median"
            values = [np.array([value], np.float32) for value in (self._series.usable_medians() if median else (1, 1))]
            self.target_on, self.target_off = resolve_target(target, *values, np.ones(1, bool))
            self._series.never_usable(self.target_on, self.target_off)
            largest_on, largest_off = self._series.largest_on, self._series.largest_off
        else:
            self._series = None
            valid = np.ones(on.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
            if valid.shape != on.shape:
                raise CorrectionError("the valid map must have the shape of the thresholds")
            with np.errstate(invalid="ignore"):
                usable = valid & np.isfinite(on) & np.isfinite(off) & (on > 0) & (off > 0)
            if not usable.any():
                raise CorrectionError("no pixel has a usable threshold (valid, finite and positive): nothing to "
                                      "correct")
            self.target_on, self.target_off = resolve_target(target, on, off, usable)
            with np.errstate(invalid="ignore"):
                largest_on = float(np.nanmax(np.where(usable, on, 0)))
                largest_off = float(np.nanmax(np.where(usable, off, 0)))
        ratio = max(largest_on / self.target_on, largest_off / self.target_off)
        self._largest = max(largest_on, largest_off)
        if ratio > MAX_EVENTS_PER_EVENT:
            raise CorrectionError(
                f"target {self.target_on:.4g} / {self.target_off:.4g} (ON / OFF) is {ratio:,.0f} times smaller than the "
                f"largest thresholds ({largest_on:.4g} / {largest_off:.4g}): one input event could create about "
                f"{ratio:,.0f} events, more than the {MAX_EVENTS_PER_EVENT} allowed; give a larger target")
        coarser = min(self.target_on / largest_on, self.target_off / largest_off)
        if coarser > FEW_EVENTS_RATIO:
            logging.getLogger("evtools").warning(
                f"target {self.target_on:.4g} / {self.target_off:.4g} (ON / OFF) is {coarser:,.3g} times the largest "
                f"thresholds ({largest_on:.4g} / {largest_off:.4g}): every pixel keeps at most about 1/{coarser:,.3g} "
                "of its events (a map in other units?)")
        self.mode = mode
        self.turns = (mode in ("turns", "highpass", "exponential")) if turns is None else bool(turns)
        self.curves = (mode == "exponential") if curves is None else bool(curves)
        self.max_gap_us = _positive_int("max_gap_us", max_gap_us)
        # a gap longer than max_gap_us is a rest (all but foh): between it and a longer hold a reversal's excursion
        # was cut off by the bound and its events lost (max_gap_us 20 ms: a texture lost 29 % of its events, a QA
        # sweep; the same bound as hold_us loses nothing)
        hold_us = _positive_int("hold_us", hold_us)
        self.hold_us = hold_us if mode == "foh" else min(hold_us, self.max_gap_us)
        tau_us = float(tau_us)
        if not np.isfinite(tau_us) or tau_us <= 0:
            raise CorrectionError(f"tau_us must be a positive number of microseconds, got {tau_us!r}")
        self.tau_us = tau_us
        if start_us is not None and (isinstance(start_us, bool) or not isinstance(start_us, (int, np.integer))
                                     or abs(start_us) > MAX_TIME_US):
            raise CorrectionError(f"start_us must be a whole number of microseconds within +-2^62, got {start_us!r}")
        self.start_us = None if start_us is None else int(start_us)
        if self._series is None:  # (pixels without a usable estimate: at the target, passed on as they are)
            _say_mixed_scales(on, off, usable, self.target_on, self.target_off)
            on = np.where(usable, on, np.float32(self.target_on)).astype(np.float32)
            off = np.where(usable, off, np.float32(self.target_off)).astype(np.float32)
        else:
            self._map = 0
            on, off = self._series.filled(0)
            usable = self._series.ever
        n = self.width * self.height
        # one 32-byte row per pixel, aligned to a cache line (see PIXEL_DTYPE)
        raw = np.zeros(n * PIXEL_DTYPE.itemsize + 64, dtype=np.uint8)
        skip = -raw.ctypes.data % 64
        self._state = raw[skip: skip + n * PIXEL_DTYPE.itemsize].view(PIXEL_DTYPE)
        self._state["on"] = on.reshape(-1)
        self._state["off"] = off.reshape(-1)
        self._state["last_us"] = NO_EVENT_US
        self._status = np.zeros(n, dtype=np.int8)
        # pixels already at the target need no work (and their events stay bit for bit what they were)
        at_target = (on == np.float32(self.target_on)) & (off == np.float32(self.target_off))
        # (a series' pixel usable in some map may change thresholds at any map; one never usable stays at the
        # target in every map: passed on bit for bit, as a single map's, not re-sampled at its own threshold)
        self._use = ~at_target.reshape(-1) if self._series is None else self._series.ever.reshape(-1).copy()
        self._any_use = bool(self._use.any())
        self.usable = usable
        self.window_us = self.max_gap_us if mode == "foh" else min(self.max_gap_us, self.hold_us)
        # with turns a segment starts up to one window before its event and may wait up to two for the next one;
        # a tail starts at its event and waits up to two windows
        self.latency_us = 3 * self.window_us if self.turns else 2 * self.window_us if self.curves else self.window_us
        self._lanes = [_Lane(parity) for parity in range(LANES)]
        self._due_us = -NO_EVENT_US  # when waiting pixels are next checked (see split_rows)
        self._earliest = (NO_EVENT_US, -1)  # the earliest segment start and a pixel where it is (see _bound)
        self._checks_us = np.empty(0, np.int64)
        self._pool = None
        self._started = False
        self._flushed = False  # the stream ended: nothing more comes in or out
        self._last_us = 0  # the latest input event's time
        self.parameters: dict[str, Any] = {
            "target_on": self.target_on, "target_off": self.target_off, "mode": mode, "hold_us": self.hold_us,
            "max_gap_us": self.max_gap_us, "tau_us": self.tau_us, "turns": self.turns, "curves": self.curves,
            "start_us": self.start_us,
        }

    @property
    def held(self) -> int:
        """How many created events wait in the reorder buffers."""
        return sum(lane.n_held for lane in self._lanes)

    def _start(self, t_first: int) -> None:
        """The reconstruction of every pixel starts at level 0 at the stream's start (``turns``: anchored)."""
        self._started = True
        self._first_us = t_first
        if self.start_us is not None and self.start_us > t_first:  # (was taken as the first event's, silently)
            raise CorrectionError(f"the sensor's start ({self.start_us} us: start_us, --start-us) is after the "
                                  f"stream's first event ({t_first} us): the sensor started before it; give an "
                                  "earlier time or none")
        if self.turns:
            origin = t_first if self.start_us is None else self.start_us
            self._state["last_us"][self._use] = origin

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """The corrected events that are final once ``chunk`` (time-sorted, after the previous ones) is seen:
        :meth:`process_parts` joined."""
        parts = list(self.process_parts(chunk))
        return parts[0] if len(parts) == 1 else join([empty_events(), *parts])

    def process_parts(self, chunk: np.ndarray):
        """:meth:`process` as a generator of parts in time order, each of about :data:`PART` events or fewer (a
        stream whose pixels have not all fired is held for up to a hold from its start, then released at once: 7.5
        million events at 25 Mev/s). Consume it whole before the next chunk.

        A chunk is taken in parts of at most :data:`PART` events; each part is split into the lanes (:data:`LANES`),
        which are re-sampled and released side by side. The output is the same whatever the chunks and threads."""
        if self._flushed:
            raise CorrectionError("process() after flush(): the stream has ended; make a new corrector for another "
                                  "stream")
        chunk = self._checker.check(chunk) if self._checker else as_chunk(chunk)
        if len(chunk) == 0:
            return
        if not self._started:
            self._start(int(chunk["t"][0]))
        self._last_us = int(chunk["t"][-1])
        if self._series is not None:
            yield from self._process_series(chunk)
        else:
            yield from self._process(chunk)

    def _process_series(self, chunk: np.ndarray):
        """:meth:`_process` in parts cut at the maps' times, each map taking over before its first event."""
        times = self._series.t_us
        while len(chunk):
            if self._map + 1 < len(times) and chunk["t"][0] >= times[self._map + 1]:
                self._map = int(np.searchsorted(times, chunk["t"][0], side="right")) - 1
                on, off = self._series.filled(self._map)
                self._state["on"], self._state["off"] = on.reshape(-1), off.reshape(-1)
            end = len(chunk)
            if self._map + 1 < len(times):
                end = int(np.searchsorted(chunk["t"], times[self._map + 1], side="left"))
            yield from self._process(chunk[:end])
            chunk = chunk[end:]

    def _process(self, chunk: np.ndarray):
        if not self._any_use:  # every pixel at the target: the input, bit for bit and in its order
            yield join([chunk])  # copied as raw records (chunk.copy() leaves the padding undefined)
            return
        words = record_words(np.ascontiguousarray(chunk))
        for begin in range(0, len(words), PART):
            part = words[begin:begin + PART]
            even, odd = self._lanes[0].input_room(len(part)), self._lanes[1].input_room(len(part))
            checks = min(len(part), int(part[-1, 0] - part[0, 0]) // self.window_us + 1)  # a window apart at least
            if len(self._checks_us) < checks:
                self._checks_us = np.empty(checks, np.int64)
            n_even, n_odd, n_checks, self._due_us = split_rows(part, even, odd, self._due_us, self.window_us,
                                                               self._checks_us)
            checks_us = self._checks_us[:n_checks]
            parallel = len(part) >= PARALLEL_EVENTS
            self._each_lane(lambda lane, lane_words: lane.hold(lane.resample(self, lane_words, checks_us)),
                            [even[:n_even], odd[:n_odd]], parallel)
            bound = self._released_us = self._bound(int(part[-1, 0]))
            yield from self._release(bound, parallel)

    def _release(self, bound: int, parallel: bool):
        """The held events before ``bound`` in time order, in parts of about :data:`PART` events: the bound
        stepped evenly in time through what is held when more than that lies before it, so that the merge buffers
        stay near a part's size."""
        total = sum(lane.count_before(bound) for lane in self._lanes)
        steps = max(1, -(-total // PART))
        if steps > 1:  # the held span, read only to step the bound
            spans = [lane.held_span_us() for lane in self._lanes if lane.runs]
            first_us = min(first for first, _ in spans)
            last_us = min(max(last for _, last in spans) + 1, bound)
        for step in range(1, steps + 1):
            step_us = first_us + (last_us - first_us) * step // steps if step < steps else bound
            released = self._each_lane(lambda lane, _: lane.release(step_us), [None] * LANES, parallel)
            part = np.empty(sum(len(times) for times, _ in released), EVENT_DTYPE)
            self._merged(released, part, 0)
            yield part

    def _each_lane(self, work, arguments: list, parallel: bool) -> list:
        """``work(lane, argument)`` for every lane, the second lane on the pool's thread when ``parallel``."""
        if not parallel:
            return [work(lane, argument) for lane, argument in zip(self._lanes, arguments)]
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="evtools-correct")
        second = self._pool.submit(work, self._lanes[1], arguments[1])
        try:
            first = work(self._lanes[0], arguments[0])
        finally:
            done = second.result()  # never leave the other lane running on the shared state
        return [first, done]

    @staticmethod
    def _merged(released: list[tuple[np.ndarray, np.ndarray]], out: np.ndarray, filled: int) -> int:
        """The lanes' released events (each sorted by time: times, second words) merged into ``out`` from
        ``filled`` on, the first lane's first on ties (every byte of a record written); returns the new end."""
        (first_t, first_w), (second_t, second_w) = released
        end = filled + len(first_t) + len(second_t)
        words = record_words(out)[filled:end]
        merge_sorted(first_t, first_w, second_t, second_w, words[:, 0], words[:, 1])
        return end

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_pool"] = None  # a thread pool does not pickle; a copy makes its own
        return state

    def released_us(self, last_us: int) -> int:
        """The time before which the output is final (the last release's bound; APS frames pass on once the output
        reaches them)."""
        return min(getattr(self, "_released_us", NO_EVENT_US), last_us)

    def _bound(self, t_now: int) -> int:
        """The time before which created events are final once the stream has reached ``t_now``: every later event
        is created at or after the earliest segment start any pixel may still use (its latest event, or the start
        of the segment that waits for its next event; a tail starts at the latest event), and at most
        ``latency_us`` before ``t_now``."""
        if not self._any_use:
            return t_now
        rest_us = NO_EVENT_US if self.mode == "foh" else self.hold_us
        self._earliest = earliest_start(self._state, self._status, *self._earliest, t_now, rest_us)
        return min(max(self._earliest[0], t_now - self.latency_us), t_now)

    def flush(self) -> np.ndarray:
        """The segments still waiting for a next event, re-sampled with what is known, and everything held (the
        stream ended), in time order: :meth:`flush_parts` joined."""
        return join([empty_events(), *self.flush_parts()])

    def flush_parts(self):
        """:meth:`flush` as a generator of parts in time order, of about :data:`PART` events each (a dense
        stream holds millions; one release of them all would need its output and merge buffers at that size)."""
        if self._flushed:  # (a second flush settled the pixels' runs again: new events, out of order)
            return
        self._flushed = True
        if self._series is not None and self._started and self._last_us < self._series.t_us[0]:
            logging.getLogger("evtools").warning(  # (a series estimated on another clock: said, not silent)
                f"the stream ({self._first_us:,} .. {self._last_us:,} us) ends before the thresholds series' first "
                f"map ({int(self._series.t_us[0]):,} us): every event took that map; is the series of another "
                "recording or clock?")
        if self._series is not None and self._started:
            times = self._series.t_us
            after_us = self._first_us - int(times[-1])
            if after_us > max(int(times[-1] - times[0]), CLOCK_GAP_US):  # (the other way round: as silent before)
                logging.getLogger("evtools").warning(
                    f"the stream ({self._first_us:,} .. {self._last_us:,} us) starts {after_us / 1e6:,.6g} s after "
                    f"the thresholds series' last map ({int(times[-1]):,} us), more than the series spans: every "
                    "event took that map; is the series of another recording or clock?")
        for lane in self._lanes:
            lane.hold(lane.settle_all(self))
        yield from (part for part in self._release(NO_EVENT_US, False) if len(part))


NO_ROOM = (np.empty(0, np.int64), np.empty(0, np.int64))
"""Output buffers of no room: :func:`release_runs` then only counts."""


def _buffers(capacity: int) -> tuple[np.ndarray, np.ndarray]:
    """Room for ``capacity`` created events: times (us) and second words (x, y, p as EVENT_DTYPE lays them)."""
    return np.empty(capacity, np.int64), np.empty(capacity, np.int64)


def _grown(buffers, capacity: int, keep: int) -> tuple[np.ndarray, ...]:
    grown = tuple(np.empty(capacity, b.dtype) for b in buffers)
    for old, new in zip(buffers, grown):
        new[:keep] = old[:keep]
    return grown


class _Lane:
    """One lane's pixels (see :data:`LANES`): the queue of pixels that wait for their next event, the events the
    latest part created (creation order), and the reorder buffer: one run of created events per part, sorted by
    time, laid end to end in one buffer (``held``), from which every release takes the events before its bound
    (:func:`release_runs`; a run leaves the table once it is all released), so that an event is sorted once and
    merged once, however long it is held. When a new run does not fit after the last, the runs still held move to
    the front (:func:`compact_runs`), and the buffer is made 1.25 times what they and the new run need when they
    do not fit (or fill less than a quarter of it): a held event is moved about four times at most (a dense stream,
    where what is held dwarfs a part), and the buffer follows what is held (on a DVXplorer recording 148,000 events
    a lane for 83,000 held at most; both lanes' runs and merge buffers 11 MiB at the peak by tracemalloc, where
    runs in buffers of their own, two spare ones and a gathering buffer took 19 MiB). A
    stream whose held events grow to millions (9.5 Mev/s: 4.3 million a lane) pays for the buffer's growth and
    moves: 15-20 % slower than runs of their own, for 4 % more memory at the peak."""

    def __init__(self, parity: int):
        self.parity = parity  # the lane's sensor rows: y % 2
        self.queue_pixel = np.empty(QUEUE_ENTRIES, dtype=np.int64)
        self.queue_us = np.empty(QUEUE_ENTRIES, dtype=np.int64)
        self.head = self.tail = 0
        self.new = _buffers(1 << 16)
        self.counts = np.empty(0, dtype=np.int64)
        self.held = _buffers(0)  # the runs' times and second words (resized in place: never viewed between calls)
        self.filled = 0  # where the last run ends in ``held``
        self.begins = np.empty(16, np.int64)  # run r: held[begins[r]:ends[r]] not yet released, oldest run first
        self.ends = np.empty(16, np.int64)
        self.runs = 0
        self.spare = self.out = _buffers(0)
        self.input = np.empty((0, 2), np.int64)

    def __setstate__(self, state: dict) -> None:
        """An unpickled lane: its held buffers copied, as :meth:`hold` resizes them in place and an unpickled array
        may be a view of the pickle's bytes."""
        self.__dict__.update(state)
        self.held = tuple(np.array(buffer) for buffer in self.held)

    @property
    def n_held(self) -> int:
        """How many created events the runs hold."""
        return int(np.sum(self.ends[:self.runs] - self.begins[:self.runs]))

    def held_span_us(self) -> tuple[int, int]:
        """The earliest and the latest time held (the runs are sorted); only when something is held."""
        times = self.held[0]
        return int(times[self.begins[:self.runs]].min()), int(times[self.ends[:self.runs] - 1].max())

    def count_before(self, bound: int) -> int:
        """How many held events lie before ``bound``."""
        count, _ = release_runs(*self.held, self.begins, self.ends, self.runs, bound, *NO_ROOM, *NO_ROOM)
        return count

    def input_room(self, count: int) -> np.ndarray:
        """Room for ``count`` input events ((count, 2) int64) of a part, reused from part to part."""
        if len(self.input) < count:
            self.input = np.empty((max(count, PART), 2), np.int64)
        return self.input

    def resample(self, corrector: ThresholdCorrector, words: np.ndarray, checks_us: np.ndarray) -> int:
        """Write every event that the input ``words`` ((n, 2) int64, this lane's pixels) and the checks of waiting
        pixels at ``checks_us`` (the part's, see :func:`split_rows`) create into ``self.new``, in creation order;
        returns their number."""
        if len(self.new[0]) < len(words) + len(words) // 4:  # grown below when a part creates more
            self.new = _buffers(len(words) + len(words) // 4)
        self._make_queue_room(len(words), corrector._state)
        c = corrector
        start, n, checked = 0, 0, 0
        while True:
            start, n, self.head, self.tail, checked = correct_events(
                words, start, c.width, c._state, c._status, c._use, c.target_on, c.target_off, MODES[c.mode],
                c.turns, c.curves, c.hold_us, c.max_gap_us, c.tau_us, c.window_us, self.queue_pixel, self.queue_us,
                self.head, self.tail, checks_us, checked, *self.new, n,
            )
            if start >= len(words) and checked >= len(checks_us):
                return n
            self.new = _grown(self.new, 2 * len(self.new[0]), n)

    def settle_all(self, corrector: ThresholdCorrector) -> int:
        """Re-sample every waiting pixel with what is known (the stream ended) into ``self.new``; returns the
        number of events created."""
        c = corrector
        n = 0
        while self.head < self.tail:
            n, self.head = settle_waiting(c.width, c._state, c._status, c.target_on, c.target_off, c.window_us,
                                          self.queue_pixel, self.queue_us, self.head, self.tail, NO_EVENT_US,
                                          *self.new, n)
            if self.head < self.tail:
                self.new = _grown(self.new, 2 * len(self.new[0]), n)
        if c.turns and c._started:
            room = n + int(np.ceil(c.width * ((c.height + 1) // 2) * (c._largest / min(c.target_on, c.target_off)
                                                                         + 2)))
            if len(self.new[0]) < room:
                self.new = _grown(self.new, room, n)
            n = finish_runs(c.width, self.parity, c._state, c._status, c._use, c.curves,
                            c._last_us - c.latency_us, c.target_on, c.target_off, *self.new, n)
        return n

    def _make_queue_room(self, count: int, state: np.ndarray) -> None:
        """Room for ``count`` more waiting pixels (one per input event at most): when the end is reached, the
        entries that can still be settled move to the front (:func:`compact_waiting`), and the queue grows when
        they and ``count`` fill more than half of it, so each entry is moved O(1) times on average."""
        if self.tail + count <= len(self.queue_us):
            return
        live = compact_waiting(state, self.queue_pixel, self.queue_us, self.head, self.tail)
        self.head, self.tail = 0, live
        if 2 * (live + count) > len(self.queue_us):
            self.queue_pixel, self.queue_us = _grown((self.queue_pixel, self.queue_us), 2 * (live + count), live)

    def hold(self, n: int) -> None:
        """Sort the ``n`` events in ``self.new`` (creation order) into a new run after the last."""
        if n == 0:
            return
        if len(self.counts) < 2 * n:  # buckets: two per event (a fixed number would cost a small part as a large)
            self.counts = np.empty(2 * n, dtype=np.int64)
        if self.filled + n > len(self.held[0]):
            self.filled = compact_runs(*self.held, self.begins, self.ends, self.runs)
            need = self.filled + n
            if need > len(self.held[0]) or 4 * need < len(self.held[0]):
                for buffer in self.held:  # in place: a large buffer is remapped, not copied beside itself
                    buffer.resize(need + need // 4, refcheck=False)  # (no view of it outlives a call)
        if self.runs == len(self.begins):
            self.begins, self.ends = _grown((self.begins, self.ends), 2 * self.runs, self.runs)
        end = self.filled + n
        sort_created(*self.new, n, self.counts[:2 * n], self.held[0][self.filled:end], self.held[1][self.filled:end])
        self.begins[self.runs], self.ends[self.runs] = self.filled, end
        self.runs += 1
        self.filled = end

    def release(self, bound: int) -> tuple[np.ndarray, np.ndarray]:
        """The held events before ``bound``, sorted by time, ties in creation order (times, second words; views of
        the lane's output buffer, valid until its next release): the runs' parts before ``bound``, merged in the
        runs' order (:func:`release_runs`)."""
        while True:
            count, runs = release_runs(*self.held, self.begins, self.ends, self.runs, bound, *self.spare, *self.out)
            if runs >= 0:
                break
            self.spare, self.out = _buffers(count + count // 4), _buffers(count + count // 4)
        self.runs = runs
        if runs == 0:
            self.filled = 0
        return self.out[0][:count], self.out[1][:count]


class SeriesMaps:
    """A time series of threshold maps (``estimate --online``), read map by map as the stream reaches them:
    ``on``, ``off`` and optionally ``valid`` and ``stale`` are (maps, height, width) arrays, or anything whose
    ``[k]`` gives map k (h5py datasets: a series on disk is never held whole, only two passes read it).

    Every unusable entry is filled (:meth:`filled`): a pixel keeps its latest usable value, but where a map marks
    it ``stale`` (its estimate was dropped: the threshold stepped away) it takes that map's median of the usable
    pixels (the latest map's that has any); before its first usable value it takes that first one (its earliest
    estimate: early maps rest on the pixels that fire most, whose median is biased low, 0.16 against 0.20 at 1 s
    of a flicker); a pixel never usable takes the values given to :meth:`never_usable` (the corrector's target:
    passed on as it is), until then the median of the last map's usable pixels. The first pass finds those first
    values and the largest thresholds."""

    def __init__(self, t_us, on, off, valid=None, stale=None) -> None:
        self.t_us = np.asarray(t_us)
        if self.t_us.ndim != 1 or not np.issubdtype(self.t_us.dtype, np.integer) or np.any(np.diff(self.t_us) <= 0):
            raise CorrectionError("the maps' times must be increasing whole microseconds")
        self.t_us = self.t_us.astype(np.int64)
        self.on, self.off, self.valid, self.stale = on, off, valid, stale
        self.shape = tuple(on.shape)
        for name, maps in (("off", off), ("valid", valid), ("stale", stale)):
            if maps is not None and tuple(maps.shape) != self.shape:
                raise CorrectionError(f"the {name} maps must have the shape of the thresholds")
        first_on = first_off = None
        self.ever = None  # the pixels usable in some map
        self.largest_on = self.largest_off = 0.0
        last = -1  # the last map with a usable pixel
        for k in range(len(self.t_us)):
            on_k, off_k, usable = self._map(k)
            if first_on is None:
                first_on, first_off, self.ever = np.array(on_k), np.array(off_k), usable.copy()
            new = usable & ~self.ever
            first_on[new], first_off[new] = on_k[new], off_k[new]
            self.ever |= usable
            if usable.any():
                last = k
                last_medians = (np.median(on_k[usable]), np.median(off_k[usable]))  # (the last such map's)
                self.largest_on = max(self.largest_on, float(on_k[usable].max()))
                self.largest_off = max(self.largest_off, float(off_k[usable].max()))
        if last < 0:
            raise CorrectionError("no pixel has a usable threshold (valid, finite and positive): nothing to correct")
        self._start = (np.where(self.ever, first_on, last_medians[0]), np.where(self.ever, first_off, last_medians[1]))
        self._k = -1  # the map :meth:`filled` gave last, and its filled maps and medians
        self._filled = self._medians = None

    def never_usable(self, on: float, off: float) -> None:
        """The thresholds of the pixels never usable in any map (before the first :meth:`filled`)."""
        self._start = tuple(np.where(self.ever, start, np.float32(value)) for start, value in zip(self._start, (on, off)))
        self._k = -1

    def __len__(self) -> int:
        return len(self.t_us)

    def _map(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Map k's thresholds (float32) and its usable pixels (valid, finite and positive)."""
        on, off = np.asarray(self.on[k], np.float32), np.asarray(self.off[k], np.float32)
        with np.errstate(invalid="ignore"):
            usable = np.isfinite(on) & np.isfinite(off) & (on > 0) & (off > 0)
        if self.valid is not None:
            usable &= np.asarray(self.valid[k], bool)
        return on, off, usable

    def filled(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Map k's ON and OFF thresholds (float32) with every unusable entry filled; maps are taken in order
        (a map before the last one asked for reads the series again from its start)."""
        if k < self._k:
            self._k = -1
        while self._k < k:
            self._k += 1
            on, off, usable = self._map(self._k)
            if self._k == 0:
                filled = tuple(np.where(usable, values, start).astype(np.float32)
                               for values, start in zip((on, off), self._start))
                self._medians = tuple(float(np.median(values[usable] if usable.any() else start))
                                      for values, start in zip((on, off), self._start))
            else:
                stale = (np.zeros(usable.shape, bool) if self.stale is None  # (a pixel never usable stays as it is)
                         else np.asarray(self.stale[self._k], bool) & self.ever)
                if usable.any():
                    self._medians = (float(np.median(on[usable])), float(np.median(off[usable])))
                filled = tuple(np.where(usable, values, np.where(stale, median, before)).astype(np.float32)
                               for values, median, before in zip((on, off), self._medians, self._filled))
            self._filled = filled
        return self._filled

    def usable_medians(self) -> tuple[float, float]:
        """The medians of every usable ON and of every usable OFF threshold of the series (``np.median``'s, exactly),
        in two passes that hold a map and a histogram: the first counts the values by the upper 16 bits of their
        float32 patterns (in the order of the values: they are positive), the second sorts the one or two bins where
        the middle ranks fall."""
        histograms = np.zeros((2, 1 << 16), np.int64)
        for k in range(len(self)):
            on, off, usable = self._map(k)
            for histogram, values in zip(histograms, (on, off)):
                histogram += np.bincount(values[usable].view(np.uint32) >> 16, minlength=1 << 16)
        total = int(histograms[0].sum())
        ranks = np.array([(total - 1) // 2, total // 2])  # the middle one, or the middle two
        ends = np.cumsum(histograms, axis=1)  # values before the end of each bin
        bins = [np.searchsorted(end, ranks, side="right") for end in ends]
        kept = [[], []]
        for k in range(len(self)):
            on, off, usable = self._map(k)
            for keep, values, wanted in zip(kept, (on, off), bins):
                values = values[usable]
                keep.append(values[np.isin(values.view(np.uint32) >> 16, wanted)])
        medians = []
        for keep, end, wanted in zip(kept, ends, bins):
            values = np.sort(np.concatenate(keep))
            before = np.where(wanted > 0, end[wanted - 1], 0)[0]  # values in the bins below the first wanted one
            medians.append(float(np.mean(values[ranks - before])))
        return medians[0], medians[1]


def correct_thresholds(events: np.ndarray, width: int, height: int, on, off, valid=None, **options) -> np.ndarray:
    """Re-sample ``events`` of a ``width x height`` sensor at one target threshold (process + flush).

    See :class:`ThresholdCorrector` for the parameters.
    """
    corrector = ThresholdCorrector(width, height, on, off, valid, **options)
    out = corrector.process(np.asarray(events))
    rest = corrector.flush()
    return out if len(rest) == 0 else join([out, rest])
