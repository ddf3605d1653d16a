"""DVS emulation: frames of intensity in, events out, with every noise source of a real sensor and its labels.

The pixel model is v2e's (lin-log photoreceptor, intensity-dependent low-pass, threshold mismatch, leak, shot
noise, hot and dead pixels) with ESIM's per-pixel timing (every crossing at its own interpolated time between two
frames); ``docs/algorithms.md`` section 1 states it. :class:`DvsSimulator` is the stream processor
(``process(t_us, frames)`` frame by frame, in bounded memory), :func:`simulate_frames` the one-shot convenience,
and the ``*_scene`` functions are the built-in stimuli of the report, as frame generators.

References
----------
Y. Hu, S.-C. Liu, T. Delbruck, "v2e: From Video Frames to Realistic DVS Events", CVPR Workshops, 2021.
H. Rebecq, D. Gehrig, D. Scaramuzza, "ESIM: an Open Event Camera Simulator", Conference on Robot Learning, 2018.
"""

from __future__ import annotations

import inspect
import logging
import math
from typing import Any, Callable, Iterable, Iterator

import numpy as np

from evtools._kernels.pixel import (
    LABEL_HOT,
    LABEL_LEAK,
    LABEL_SHOT,
    LABEL_SIGNAL,
    LIN_LOG_KNEE,
    LIN_LOG_SLOPE,
    NEVER_US,
    advance_pixels,
    lin_log_frame,
    sort_events,
)
from evtools.errors import EvtoolsError, UsageMistake
from evtools.events import EVENT_DTYPE, MAX_TIME_US, check_sensor_size, empty_events, join

__all__ = [
    "DEAD_PIXEL_THRESHOLD",
    "DEFAULT_PARAMETERS",
    "DvsSimulator",
    "LABELS",
    "MIN_THRESHOLD",
    "PRESETS",
    "SCENES",
    "SimulationError",
    "lin_log",
    "scene_frames",
    "simulate_frames",
    "run_simulator",
]

LABELS = {LABEL_SIGNAL: "signal", LABEL_LEAK: "leak", LABEL_SHOT: "shot", LABEL_HOT: "hot"}
"""Ground-truth label of each output event: 0 signal, 1 leak, 2 shot noise, 3 hot pixel."""

MIN_THRESHOLD = 0.01
"""Thresholds drawn below this (log units) are clamped to it (v2e)."""
DEAD_PIXEL_THRESHOLD = 100.0
"""Threshold of a dead pixel (log units): far beyond the 0-5.5 range of lin-log intensities, so it never fires."""

MIN_THRESHOLD_FACTOR = 0.05
"""A drift never takes a threshold below 5 % of its first value."""

LOWPASS_MAX_STEP = 0.2
"""The longest frame interval, in low-pass time constants, that is said nothing of: the per-frame update ``eps =
min(1, dt / tau)`` is then within about 10 % of a true single pole's ``1 - exp(-dt / tau)`` (10.3 % at 0.2)."""

DEFAULT_PARAMETERS: dict[str, Any] = {
    "pos_thres": 0.2,
    "neg_thres": 0.2,
    "sigma_thres": 0.03,
    "correlated_sigma_thres": 0.0,
    "correlated_length_px": 10.0,
    "cutoff_hz": 0.0,
    "fixed_cutoff": False,
    "leak_rate_hz": 0.1,
    "leak_spread_decades": 0.1,
    "shot_noise_rate_hz": 0.0,
    "refractory_us": 0,
    "hot_pixel_fraction": 0.0,
    "hot_pixel_rate_hz": 100.0,
    "dead_pixel_fraction": 0.0,
    "thres_drift_per_s": 0.0,
}
"""v2e's ``EventEmulator`` defaults (thresholds 0.2 +- 0.03, no low-pass, leak 0.1 Hz, no shot noise), no hot or
dead pixels, no spatially correlated mismatch."""

PRESETS: dict[str, dict[str, Any]] = {
    "clean": {"pos_thres": 0.2, "neg_thres": 0.2, "sigma_thres": 0.02, "cutoff_hz": 0.0, "leak_rate_hz": 0.0,
              "shot_noise_rate_hz": 0.0, "refractory_us": 0},
    "noisy": {"pos_thres": 0.2, "neg_thres": 0.2, "sigma_thres": 0.05, "cutoff_hz": 30.0, "leak_rate_hz": 0.1,
              "shot_noise_rate_hz": 5.0, "refractory_us": 0},
}
"""v2e's ``--dvs_params clean`` and ``noisy``."""


class SimulationError(EvtoolsError, ValueError):
    """A simulation parameter or input frame that cannot be used."""


class SimulationUsageError(SimulationError, UsageMistake):
    """A built-in scene or scene option that does not exist: a usage mistake (exit 2)."""


def lin_log(intensity) -> np.ndarray:
    """v2e's lin-log photoreceptor: ``I * ln(20) / 20`` for ``I <= 20``, else ``ln(I)`` (intensity 0-255).

    Linear near zero so that dark pixels do not amplify noise without bound, continuous at the knee.
    Negative intensities count as 0.
    """
    intensity = np.maximum(np.asarray(intensity, dtype=np.float64), 0.0)
    with np.errstate(divide="ignore"):
        return np.where(intensity <= LIN_LOG_KNEE, intensity * LIN_LOG_SLOPE, np.log(np.maximum(intensity, 1.0)))


def resolve_seed(seed) -> int:
    """A random generator's seed: a whole number >= 0 (True is refused, not taken as 1), or None for a fresh one."""
    if seed is None:
        return int(np.random.SeedSequence().entropy % (1 << 63))
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(f"seed must be an integer >= 0, got {seed!r}")
    return int(seed)


def _check_nonnegative(name: str, value: float) -> float:
    number = float(value)
    if not number >= 0.0 or math.isinf(number):
        raise SimulationError(f"{name} must be a finite number >= 0, got {value}")
    return number


MAX_PIXEL_RATE_HZ = 1e6
"""A noise rate per pixel (leak, shot, hot) above one event a microsecond (evtools' time resolution) is refused."""
def leak_rates(mean_hz: float, spread_decades: float, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` pixels' leak rates: log-normal with mean ``mean_hz`` and ``spread_decades`` the standard deviation of
    their log10, each at most :data:`MAX_PIXEL_RATE_HZ` (the spread took pixels of a 1 MHz mean to 1.43 MHz: two
    events of a pixel in one microsecond, a QA sweep). The pixel model and the noise injector draw them alike."""
    sigma_ln = spread_decades * math.log(10.0)
    spread = np.exp(sigma_ln * rng.standard_normal(n) - sigma_ln**2 / 2)  # log-normal, mean 1
    return np.minimum(mean_hz * spread, MAX_PIXEL_RATE_HZ)


def drift_factor(drift_per_s: float, since_us: float) -> float:
    """How many times its first value a threshold is ``since_us`` after the drift's origin (``thres_drift_per_s``,
    linear), never below :data:`MIN_THRESHOLD_FACTOR`; the simulator and ``metrics thresholds`` (a drifting truth
    taken at an estimate's time) share it."""
    return max(1.0 + drift_per_s * since_us * 1e-6, MIN_THRESHOLD_FACTOR)


MAX_NOISE_RATE_EV_S = 2e9
"""Noise over the whole sensor above 2 Gev/s (twice a Prophesee IMX636's peak event rate) is refused: it would be
made a block at a time in memory (10^12 Hz a pixel grew past 1.8 GiB with no message)."""


def check_noise_rates(width: int, height: int, parameters: dict[str, Any]) -> None:
    """Refuse the per-pixel noise rates of ``parameters`` (leak, shot, hot pixels; already checked >= 0) beyond
    :data:`MAX_PIXEL_RATE_HZ`, or whose sum over the sensor exceeds :data:`MAX_NOISE_RATE_EV_S`, naming the value
    and the limit."""
    rates_hz = {name: parameters[name] for name in ("leak_rate_hz", "shot_noise_rate_hz", "hot_pixel_rate_hz")}
    for name, rate in rates_hz.items():
        if rate > MAX_PIXEL_RATE_HZ:
            raise SimulationError(f"{name} {rate:g} Hz is more than a pixel can fire ({MAX_PIXEL_RATE_HZ:g} Hz: one "
                                  "event a microsecond)")
    total = (rates_hz["leak_rate_hz"] + rates_hz["shot_noise_rate_hz"]
             + rates_hz["hot_pixel_rate_hz"] * parameters["hot_pixel_fraction"]) * width * height
    if total > MAX_NOISE_RATE_EV_S:
        raise SimulationError(f"noise rates of {', '.join(f'{n} {r:g} Hz' for n, r in rates_hz.items() if r)} on "
                              f"{width}x{height} pixels make {total:.3g} events/s, more than the {MAX_NOISE_RATE_EV_S:g} "
                              "allowed (twice the fastest sensor's peak)")


def _check_fraction(name: str, value: float) -> float:
    value = _check_nonnegative(name, value)
    if value > 1.0:
        raise SimulationError(f"{name} must be between 0 and 1, got {value}")
    return value


PARALLEL_PIXELS = 1 << 15
"""Sensors of at least this many pixels are advanced in two lanes of rows (top half, bottom half) on two threads:
the pixels are independent (each its own state and random stream, keyed by its index), and the lanes' events are
joined in row order before the sort by time, so the output is the same bit for bit."""


class _PixelLane:
    """Pixels ``first..end - 1`` (whole rows) and the output columns their events go to (time, x, y, polarity,
    label), grown as needed."""

    def __init__(self, first: int, end: int, capacity: int) -> None:
        self.first, self.end, self.count = first, end, 0
        self.columns = (np.empty(capacity, np.int64), np.empty(capacity, np.int16), np.empty(capacity, np.int16),
                        np.empty(capacity, np.bool_), np.empty(capacity, np.uint8))

    def grow(self) -> None:
        grown = tuple(np.empty(2 * len(column), column.dtype) for column in self.columns)
        for old, new in zip(self.columns, grown):
            new[:self.count] = old[:self.count]
        self.columns = grown

    def taken(self) -> tuple[np.ndarray, ...]:
        """The events so far (views of the columns, valid until the next advance); the lane starts empty again."""
        count, self.count = self.count, 0
        return tuple(column[:count] for column in self.columns)


class DvsSimulator:
    """A DVS sensor of ``width x height`` pixels, turning frames of intensity into events.

    Every random draw is made from the seed: the per-pixel maps (thresholds, leak rates, hot and dead pixels,
    initial leak phases) once at construction from the simulator's own numpy generators, and the per-event draws
    of shot noise and hot pixels from a counter-based generator per pixel, so the output never depends on how
    the frames are batched into :meth:`process` calls.

    Parameters
    ----------
    width, height : int
        Sensor size in pixels.
    pos_thres, neg_thres : float
        Mean ON and OFF contrast thresholds, log units (v2e default 0.2).
    sigma_thres : float
        Standard deviation of the per-pixel thresholds (v2e default 0.03); ``theta_on ~ N(pos_thres, sigma)``,
        ``theta_off ~ N(neg_thres, sigma)``, clamped at >= 0.01.
    correlated_sigma_thres : float
        Standard deviation of a spatially smooth field added to both threshold maps (0: none), the report's
        "gross failing areas".
    correlated_length_px : float
        Correlation length of that field (the sigma of the Gaussian that smooths white noise), pixels.
    cutoff_hz : float
        Photoreceptor bandwidth at full intensity; it falls with intensity as in v2e (0: no low-pass).
    fixed_cutoff : bool
        The bandwidth does not fall with intensity: a plain single-pole low-pass with ``tau = 1/(2 pi
        cutoff_hz)`` (the report's Table 2 setup), instead of v2e's intensity-dependent one.
    leak_rate_hz : float
        Mean leak (background activity) rate: the reference drifts down by ``rate * theta_on`` per second, so a
        static pixel emits ON events at about this rate.
    leak_spread_decades : float
        Per-pixel spread of the leak rate: standard deviation of its log10, log-normal with mean 1 (v2e's
        ``noise_rate_cov_decades``).
    shot_noise_rate_hz : float
        Shot-noise rate per pixel in the dark (ON and OFF together); at intensity I it is
        ``rate * (1 - 0.75 * I / 255)`` (v2e). After a shot event the pixel's reference resets to its signal.
    refractory_us : int
        An event within this time of the pixel's previous event is dropped; a dropped threshold crossing still
        moves the reference (ESIM). 0: none.
    hot_pixel_fraction : float
        Fraction of pixels that fire independently at ``hot_pixel_rate_hz`` (ON or OFF at random), label 3.
    hot_pixel_rate_hz : float
        Event rate of each hot pixel.
    dead_pixel_fraction : float
        Fraction of pixels that never fire: threshold :data:`DEAD_PIXEL_THRESHOLD`, no leak, no shot noise.
    thres_drift_per_s : float
        Every threshold changes by this fraction of its first value per second, linearly from the first frame
        (0.01: +1 %/s, as a warming sensor's): each frame interval uses the thresholds at its middle; the truth
        maps hold those at the first frame.
    seed : int or None
        Seed of every random draw; None draws one (see :attr:`seed`).
    thresholds : (ndarray, ndarray) or None
        Explicit ON and OFF threshold maps (height x width, log units, > 0) instead of drawn ones (tests,
        replaying a measured sensor); dead pixels still get :data:`DEAD_PIXEL_THRESHOLD`.

    Attributes
    ----------
    on_thres, off_thres : ndarray of float32, shape (height, width)
        The thresholds map (the ground truth that ``--truth`` writes).
    hot_pixels, dead_pixels : ndarray of bool, shape (height, width)
    leak_rate_map_hz : ndarray of float64, shape (height, width)
    seed : int
        The seed actually used.

    References
    ----------
    Y. Hu, S.-C. Liu, T. Delbruck, "v2e: From Video Frames to Realistic DVS Events", CVPR Workshops, 2021.
    H. Rebecq, D. Gehrig, D. Scaramuzza, "ESIM: an Open Event Camera Simulator", CoRL, 2018.
    """

    def __init__(
        self,
        width: int,
        height: int,
        *,
        pos_thres: float = DEFAULT_PARAMETERS["pos_thres"],
        neg_thres: float = DEFAULT_PARAMETERS["neg_thres"],
        sigma_thres: float = DEFAULT_PARAMETERS["sigma_thres"],
        correlated_sigma_thres: float = DEFAULT_PARAMETERS["correlated_sigma_thres"],
        correlated_length_px: float = DEFAULT_PARAMETERS["correlated_length_px"],
        cutoff_hz: float = DEFAULT_PARAMETERS["cutoff_hz"],
        fixed_cutoff: bool = DEFAULT_PARAMETERS["fixed_cutoff"],
        leak_rate_hz: float = DEFAULT_PARAMETERS["leak_rate_hz"],
        leak_spread_decades: float = DEFAULT_PARAMETERS["leak_spread_decades"],
        shot_noise_rate_hz: float = DEFAULT_PARAMETERS["shot_noise_rate_hz"],
        refractory_us: int = DEFAULT_PARAMETERS["refractory_us"],
        hot_pixel_fraction: float = DEFAULT_PARAMETERS["hot_pixel_fraction"],
        hot_pixel_rate_hz: float = DEFAULT_PARAMETERS["hot_pixel_rate_hz"],
        dead_pixel_fraction: float = DEFAULT_PARAMETERS["dead_pixel_fraction"],
        thres_drift_per_s: float = DEFAULT_PARAMETERS["thres_drift_per_s"],
        seed: int | None = None,
        thresholds: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        check_sensor_size(width, height)
        self.width, self.height = int(width), int(height)
        for name, value in (("pos_thres", pos_thres), ("neg_thres", neg_thres)):
            if not _check_nonnegative(name, value) >= MIN_THRESHOLD:
                raise SimulationError(f"{name} must be at least {MIN_THRESHOLD} log units, got {value}")
        if hot_pixel_fraction + dead_pixel_fraction > 1.0:
            raise SimulationError("hot_pixel_fraction + dead_pixel_fraction must not exceed 1")
        refractory = _check_nonnegative("refractory_us", refractory_us)
        if refractory != int(refractory) or refractory > MAX_TIME_US:
            raise SimulationError(f"refractory_us must be a whole number of microseconds up to 2^62, got "
                                  f"{refractory_us}")
        self.seed = resolve_seed(seed)
        self.parameters: dict[str, Any] = {
            "pos_thres": float(pos_thres),
            "neg_thres": float(neg_thres),
            "sigma_thres": _check_nonnegative("sigma_thres", sigma_thres),
            "correlated_sigma_thres": _check_nonnegative("correlated_sigma_thres", correlated_sigma_thres),
            "correlated_length_px": _check_nonnegative("correlated_length_px", correlated_length_px),
            "cutoff_hz": _check_nonnegative("cutoff_hz", cutoff_hz),
            "fixed_cutoff": bool(fixed_cutoff),
            "leak_rate_hz": _check_nonnegative("leak_rate_hz", leak_rate_hz),
            "leak_spread_decades": _check_nonnegative("leak_spread_decades", leak_spread_decades),
            "shot_noise_rate_hz": _check_nonnegative("shot_noise_rate_hz", shot_noise_rate_hz),
            "refractory_us": int(refractory),
            "hot_pixel_fraction": _check_fraction("hot_pixel_fraction", hot_pixel_fraction),
            "hot_pixel_rate_hz": _check_nonnegative("hot_pixel_rate_hz", hot_pixel_rate_hz),
            "dead_pixel_fraction": _check_fraction("dead_pixel_fraction", dead_pixel_fraction),
            "thres_drift_per_s": float(thres_drift_per_s),
            "seed": self.seed,
        }
        if not math.isfinite(thres_drift_per_s):
            raise SimulationError(f"thres_drift_per_s must be a finite fraction per second, got {thres_drift_per_s}")
        check_noise_rates(self.width, self.height, self.parameters)
        self._draw_maps(thresholds)
        self._t0_us: int | None = None  # the first frame's time: the drift's origin
        if thres_drift_per_s != 0.0:  # the kernel's maps become copies, rescaled before every frame interval
            self._on, self._off = self._on.copy(), self._off.copy()
        n = self.width * self.height
        self._lp_log = np.zeros(n)
        self._ref_log = np.zeros(n)
        self._last_event_us = np.full(n, NEVER_US, dtype=np.int64)
        self._shot_draws = np.zeros(n, dtype=np.uint64)
        self._hot_draws = np.zeros(n, dtype=np.uint64)
        self._t_us: int | None = None  # time of the last frame seen
        self._said_lowpass = False  # (frames too far apart for the low-pass: said once)
        # the rows in lanes (PARALLEL_PIXELS), each advanced on its own thread into its own output columns
        lanes = 2 if n >= PARALLEL_PIXELS else 1
        rows = [self.height * k // lanes for k in range(lanes + 1)]
        self._lanes = [_PixelLane(rows[k] * self.width, rows[k + 1] * self.width, max(1 << 15, n // lanes))
                       for k in range(lanes)]
        self._pool = None

    # -- the per-pixel maps, drawn once -------------------------------------------------------------------

    def _draw_maps(self, thresholds) -> None:
        p = self.parameters
        shape = (self.height, self.width)
        n = self.width * self.height
        # one independent generator per component, so switching one component on or off never changes another
        streams = np.random.SeedSequence(self.seed).spawn(6)
        thres_rng, field_rng, pixel_rng, leak_rng, noise_rng, key_rng = (np.random.default_rng(s) for s in streams)
        if thresholds is None:
            on = thres_rng.normal(p["pos_thres"], p["sigma_thres"], shape)
            off = thres_rng.normal(p["neg_thres"], p["sigma_thres"], shape)
            if p["correlated_sigma_thres"] > 0:
                field = _smooth_field(field_rng, shape, p["correlated_length_px"])
                on += p["correlated_sigma_thres"] * field
                off += p["correlated_sigma_thres"] * field
            on, off = np.maximum(on, MIN_THRESHOLD), np.maximum(off, MIN_THRESHOLD)
        else:
            on, off = (np.array(m, dtype=np.float64) for m in thresholds)
            if on.shape != shape or off.shape != shape:
                raise SimulationError(f"threshold maps must have shape {shape} (height, width)")
            if not (np.all(on >= MIN_THRESHOLD) and np.all(off >= MIN_THRESHOLD)):
                raise SimulationError(f"threshold maps must be >= {MIN_THRESHOLD} everywhere")
        order = pixel_rng.permutation(n)
        n_hot = int(round(p["hot_pixel_fraction"] * n))
        n_dead = min(int(round(p["dead_pixel_fraction"] * n)), n - n_hot)
        hot = np.zeros(n, dtype=bool)
        hot[order[:n_hot]] = True
        dead = np.zeros(n, dtype=bool)
        dead[order[n_hot:n_hot + n_dead]] = True
        on, off = on.reshape(-1), off.reshape(-1)
        on[dead] = DEAD_PIXEL_THRESHOLD
        off[dead] = DEAD_PIXEL_THRESHOLD
        # the thresholds the kernel uses are exactly the float32 ones that the truth file holds
        self.on_thres = on.astype(np.float32).reshape(shape)
        self.off_thres = off.astype(np.float32).reshape(shape)
        self._on = self.on_thres.reshape(-1)
        self._off = self.off_thres.reshape(-1)
        self.hot_pixels = hot.reshape(shape)
        self.dead_pixels = dead.reshape(shape)

        leak = leak_rates(p["leak_rate_hz"], p["leak_spread_decades"], leak_rng, n)
        leak[dead] = 0.0
        self._leak_rate_hz = leak
        self.leak_rate_map_hz = leak.reshape(shape)
        self._leak_phase = leak_rng.random(n)  # where each pixel starts in its leak cycle

        self._shot_rate_hz = np.where(dead, 0.0, p["shot_noise_rate_hz"])
        self._hot_rate_hz = np.where(hot, p["hot_pixel_rate_hz"], 0.0)
        self._shot_budget = noise_rng.standard_exponential(n)
        self._hot_budget = noise_rng.standard_exponential(n)
        self._shot_key, self._hot_key = (np.uint64(k) for k in key_rng.integers(0, 1 << 64, 2, dtype=np.uint64))
        self._any_leak = bool(np.any(leak > 0))
        self._any_shot = bool(np.any(self._shot_rate_hz > 0))
        self._any_hot = bool(np.any(self._hot_rate_hz > 0))

    # -- processing ---------------------------------------------------------------------------------------

    def process(self, t_us, frames) -> np.ndarray:
        """Events up to the last of ``frames``; see :meth:`process_labelled` (this drops the labels)."""
        return self.process_labelled(t_us, frames)[0]

    def process_labelled(self, t_us, frames) -> tuple[np.ndarray, np.ndarray]:
        """Advance the sensor through one frame or a batch of frames; return their events and labels.

        Parameters
        ----------
        t_us : int or array_like of int
            Time of the frame (or of each frame) in microseconds, strictly increasing over the whole stream.
        frames : ndarray, shape (height, width) or (n, height, width)
            Intensity, 0-255: uint8 (used as it is, lin-log from a table of the 256 levels: the fast path for
            video) or any other number type (converted to float32). The first frame of a stream only sets the
            pixels' state and emits nothing.

        Returns
        -------
        events : ndarray of EVENT_DTYPE
            The events between the previous frame and the last of these, sorted by time; within one time, by
            row, column, then the pixel's own order.
        labels : ndarray of uint8
            Per event: 0 signal, 1 leak, 2 shot noise, 3 hot pixel (:data:`LABELS`). A threshold crossing is
            leak when it is an ON event of a pixel whose (filtered) signal did not rise in that frame interval,
            so that only the drifting reference can have caused it; otherwise it is signal.
        """
        frames = np.asarray(frames)
        times = np.asarray(t_us)
        if frames.ndim == 2:
            frames, times = frames[None], times.reshape(1)
        if (frames.ndim in (3, 4) and frames.shape[-3:-1] == (self.height, self.width) and frames.shape[-1] in (3, 4)
                and frames.shape[1:] != (self.height, self.width)):
            raise SimulationError(
                f"frames of shape {frames.shape} are colour (height x width x {frames.shape[-1]}); the simulator "
                "takes intensities, height x width: convert them to gray first (e.g. cv2.cvtColor, as evtools "
                "simulate does for a colour video)")
        if frames.ndim != 3 or frames.shape[1:] != (self.height, self.width):
            raise SimulationError(
                f"frames of shape {frames.shape[-2:] if frames.ndim >= 2 else frames.shape} do not match the "
                f"{self.width}x{self.height} sensor (expected height x width = {self.height} x {self.width})"
            )
        if times.ndim != 1 or len(times) != len(frames):
            raise SimulationError(f"{len(frames)} frames need as many times, got {times.size}")
        if times.size and times.dtype.kind not in "iuf":  # (a string raised numpy's own TypeError)
            raise SimulationError(f"frame times must be numbers (microseconds), got {times.dtype} values")
        if times.size and not np.issubdtype(times.dtype, np.integer):
            if not np.all(np.isfinite(times)):
                raise SimulationError("frame times must be finite")
            times = np.round(times)
        if times.size and (times.max() > MAX_TIME_US or times.min() < -MAX_TIME_US):  # (2**63 wrapped to -2**63)
            raise SimulationError(f"frame time {times.max() if times.max() > MAX_TIME_US else times.min()} us is "
                                  f"beyond the +-{MAX_TIME_US} us evtools' times hold")
        times = times.astype(np.int64)
        if frames.dtype != np.uint8 and frames.size:  # (one inf pixel made a run grow to 24 GB; NaN a fake burst)
            possible = (np.isfinite(frames) if np.issubdtype(frames.dtype, np.floating) else True) & (frames >= 0)
            if not np.all(possible):
                k, y, x = np.argwhere(~possible)[0]  # (named by its time: its index here is within one batch)
                raise SimulationError(f"the frame at {int(times[k])} us has intensity {frames[k, y, x]} at x={x}, "
                                      f"y={y}: intensities must be finite and not negative")
        # 8-bit frames (video) stay 8-bit: the kernel takes their lin-log from a table of the 256 levels
        dtype = np.uint8 if frames.dtype == np.uint8 else np.float32
        pieces = []  # with lanes: each frame's events, the lanes' rows in order
        for k in range(len(frames)):
            frame = np.ascontiguousarray(frames[k], dtype=dtype).reshape(-1)
            t1 = int(times[k])
            if self._t_us is None:
                self._start(t1, frame)
                continue
            if t1 <= self._t_us:
                raise SimulationError(f"frame times must increase: frame at {t1} us after one at {self._t_us} us")
            self._check_lowpass_step(t1 - self._t_us)
            drift = self.parameters["thres_drift_per_s"]
            if drift != 0.0:  # thresholds at the interval's middle, (1 + drift * t) times those at the start
                factor = drift_factor(drift, (self._t_us + t1) / 2 - self._t0_us)
                np.multiply(self.on_thres.reshape(-1), factor, out=self._on)
                np.multiply(self.off_thres.reshape(-1), factor, out=self._off)
            if len(self._lanes) == 1:
                self._advance(self._lanes[0], frame, t1)
            else:
                if self._pool is None:
                    from concurrent.futures import ThreadPoolExecutor

                    self._pool = ThreadPoolExecutor(1, thread_name_prefix="evtools-pixels")
                second = self._pool.submit(self._advance, self._lanes[1], frame, t1)
                try:
                    self._advance(self._lanes[0], frame, t1)
                finally:
                    second.result()  # never leave the other lane running on the shared state
                # a frame at a time: an event at a frame's time may tie with the next frame's first ones
                pieces.append([np.concatenate(parts) for parts in zip(*(lane.taken() for lane in self._lanes))])
            self._t_us = t1
        if len(self._lanes) == 1:
            return self._sorted(self._lanes[0].taken())
        if len(pieces) == 1:
            return self._sorted(pieces[0])
        return self._sorted([np.concatenate(parts) for parts in zip(*pieces)] if pieces else
                            [column[:0] for column in self._lanes[0].columns])

    def _check_lowpass_step(self, interval_us: int) -> None:
        """Say once when frames come too far apart for the low-pass: it moves by ``eps = min(1, dt / tau)`` a frame
        (v2e's update; at full intensity, and less below), which is a single pole of time constant ``tau`` only for
        ``dt`` well below it; at ``dt >= tau`` it does nothing (an 8 Hz cutoff on 30 fps video: the events came at
        the unfiltered ramp's times, silently, a QA sweep)."""
        cutoff_hz = self.parameters["cutoff_hz"]
        if self._said_lowpass or not cutoff_hz or interval_us * 1e-6 * 2 * math.pi * cutoff_hz <= LOWPASS_MAX_STEP:
            return
        self._said_lowpass = True
        tau_ms = 1e3 / (2 * math.pi * cutoff_hz)
        logging.getLogger("evtools").warning(
            f"frames {interval_us / 1e3:g} ms apart are coarse for the {cutoff_hz:g} Hz low-pass (time constant "
            f"{tau_ms:.3g} ms; it moves min(1, dt / tau) a frame, as v2e's): its time constant is off by more than "
            f"10 % (nothing is filtered from dt >= tau); give frames at most {tau_ms * LOWPASS_MAX_STEP:.3g} ms "
            "apart (a faster --frame-rate, an interpolated video) or a lower --cutoff-hz")

    def _advance(self, lane: "_PixelLane", frame: np.ndarray, t1: int) -> None:
        """Advance ``lane``'s pixels to ``frame`` at ``t1``, appending their events to its columns."""
        pixel = lane.first
        while True:
            lane.count, pixel = advance_pixels(
                frame, self._t_us, t1, self.width, self.parameters["cutoff_hz"], self.parameters["fixed_cutoff"],
                self.parameters["refractory_us"], self._on, self._off, self._leak_rate_hz,
                self._shot_rate_hz, self._hot_rate_hz, self._any_leak, self._any_shot, self._any_hot,
                self._shot_key, self._hot_key,
                self._lp_log, self._ref_log, self._last_event_us, self._shot_budget, self._hot_budget,
                self._shot_draws, self._hot_draws, *lane.columns, lane.count, pixel, lane.end,
            )
            if pixel == lane.end:
                return
            lane.grow()

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_pool"] = None  # a thread pool does not pickle; a copy makes its own
        return state

    def flush(self) -> np.ndarray:
        """Nothing is held back (each frame interval's events leave with it): an empty chunk."""
        return empty_events()

    def flush_labelled(self) -> tuple[np.ndarray, np.ndarray]:
        """``(flush(), no labels)``."""
        return empty_events(), np.empty(0, dtype=np.uint8)

    @property
    def drift_origin_us(self) -> int | None:
        """The first frame's time, where ``thres_drift_per_s`` starts (``on_thres``, ``off_thres`` hold then);
        None before it."""
        return self._t0_us

    def _start(self, t_us: int, frame: np.ndarray) -> None:
        self._t0_us = t_us
        lin_log_frame(frame, self._lp_log)
        # pixels with leak start at a random point of their leak cycle, as a sensor that has been on for a while
        self._ref_log[:] = self._lp_log - np.where(self._leak_rate_hz > 0, self._leak_phase * self._on, 0.0)
        self._t_us = t_us

    def _sorted(self, columns) -> tuple[np.ndarray, np.ndarray]:
        """Events and labels of ``columns`` (time, x, y, polarity, label in frame then raster order), sorted by
        time: ties keep that order, so the result does not depend on the lanes."""
        count = len(columns[0])
        events = np.empty(count, dtype=EVENT_DTYPE)
        labels = np.empty(count, dtype=np.uint8)
        # the kernel writes pixel by pixel; a stable sort by time leaves ties in (frame, row, column, own order).
        # A counting sort on the microsecond, unless the events span much more time than there are of them
        if not sort_events(*columns, max(4 * count, 1 << 16), events["t"], events["x"], events["y"], events["p"],
                           labels):
            order = np.argsort(columns[0], kind="stable")
            for name, column in zip(("t", "x", "y", "p"), columns):
                events[name] = column[order]
            labels = columns[4][order]
        return events, labels


def _smooth_field(rng: np.random.Generator, shape: tuple[int, int], length_px: float) -> np.ndarray:
    """White noise smoothed by a Gaussian of sigma ``length_px``, scaled to unit standard deviation."""
    field = rng.standard_normal(shape)
    if length_px > 0:
        import cv2

        field = cv2.GaussianBlur(field, (0, 0), sigmaX=length_px, sigmaY=length_px, borderType=cv2.BORDER_REFLECT)
    std = field.std()
    return field / std if std > 0 else field


def simulate_frames(
    frames: Iterable[tuple[int, np.ndarray]], width: int, height: int, **parameters
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate a whole (short) sequence at once: :class:`DvsSimulator` ``process`` on every frame, then ``flush``.

    Parameters
    ----------
    frames : iterable of (t_us, frame)
        Frame times (microseconds, increasing) and intensity frames (height x width, 0-255).
    width, height : int
        Sensor size.
    **parameters
        Passed to :class:`DvsSimulator`.

    Returns
    -------
    events : ndarray of EVENT_DTYPE
    labels : ndarray of uint8
    """
    return run_simulator(DvsSimulator(width, height, **parameters), frames)


def run_simulator(simulator: "DvsSimulator", frames: Iterable[tuple[int, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """``simulator.process_labelled`` on every (t_us, frame), then ``flush_labelled``: all events and their labels."""
    pieces = [simulator.process_labelled(t_us, frame) for t_us, frame in frames]
    pieces.append(simulator.flush_labelled())
    return join([p[0] for p in pieces]), np.concatenate([p[1] for p in pieces])


# -- built-in scenes -----------------------------------------------------------------------------------------

DEFAULT_FRAME_RATE_HZ = 1000.0
"""Scenes are sampled at 1 kHz: between two frames the pixel model interpolates linearly in log intensity."""


FRAME_TIMES_BLOCK = 65_536
"""A scene's frame times are made this many at a time (a day at 1 kHz is 86M frames: never all at once)."""


def _frame_times_us(duration_us: int, frame_rate_hz: float) -> Iterator[np.ndarray]:
    """The frame times (microseconds, int64) from 0 at ``frame_rate_hz``, the last one at ``duration_us``, in
    blocks of at most :data:`FRAME_TIMES_BLOCK`; the arguments are checked at the call, the blocks made as read."""
    if not duration_us > 0:
        raise SimulationError(f"duration must be positive, got {duration_us} us")
    if duration_us != int(duration_us):
        raise SimulationError(f"duration must be a whole number of microseconds, got {duration_us} us")
    if not frame_rate_hz > 0 or math.isinf(frame_rate_hz):
        raise SimulationError(f"frame rate must be positive, got {frame_rate_hz} Hz")
    if frame_rate_hz > 1e6:  # (checked before the frame times are made: 10^9 Hz asked for more than 3 GiB)
        raise SimulationError(f"frame rate {frame_rate_hz:g} Hz is more than one frame a microsecond (1e+06 Hz), "
                              "the resolution of event times")
    n = int(math.floor(duration_us * 1e-6 * frame_rate_hz + 1e-9)) + 1
    return _frame_time_blocks(n, 1e6 / frame_rate_hz, int(duration_us))


def _frame_time_blocks(n: int, step_us: float, duration_us: int) -> Iterator[np.ndarray]:
    last = -1
    for start in range(0, n, FRAME_TIMES_BLOCK):
        times = np.round(np.arange(start, min(n, start + FRAME_TIMES_BLOCK)) * step_us).astype(np.int64)
        if start + FRAME_TIMES_BLOCK >= n and times[-1] < duration_us:
            times = np.append(times, duration_us)
        if times[0] <= last or np.any(np.diff(times) <= 0):
            raise SimulationError(f"frame rate {1e6 / step_us} Hz is too high for microsecond frame times")
        last = int(times[-1])
        yield times


def _each_time(blocks: Iterator[np.ndarray]) -> Iterator[int]:
    for block in blocks:
        yield from block.tolist()


def _uniform_frames(blocks: Iterator[np.ndarray], levels: Callable[[np.ndarray], np.ndarray], width: int,
                    height: int) -> Iterator[tuple[int, np.ndarray]]:
    """Frames of one level each, ``levels(block)`` giving a block of frame times' levels."""
    for block in blocks:
        for t, level in zip(block.tolist(), levels(block)):
            yield t, np.full((height, width), level, dtype=np.float32)


def _triangle(phase: np.ndarray | float) -> np.ndarray | float:
    """0 at integer phases, 1 at half-integer ones, linear in between."""
    phase = np.mod(phase, 1.0)
    return 1.0 - np.abs(2.0 * phase - 1.0)


def _check_levels(min_level: float, max_level: float) -> None:
    for name, value in (("min level", min_level), ("max level", max_level)):
        if not 0.0 <= value <= 255.0:
            raise SimulationError(f"{name} must be between 0 and 255, got {value}")


FLICKER_PROFILES = ("intensity", "log")


def flicker_scene(
    width: int, height: int, duration_us: int, *, frame_rate_hz: float = DEFAULT_FRAME_RATE_HZ,
    min_level: float = 50.0, max_level: float = 200.0, period_s: float = 0.5, profile: str = "intensity",
    phase: float = 0.0, phase_spread: float = 0.0,
) -> Iterator[tuple[int, np.ndarray]]:
    """Every pixel alike: a triangle wave from ``min_level`` up to ``max_level`` and back per ``period_s``.

    The report's flicker scene: every pixel sees the same log-intensity excursion, so per-pixel event counts
    reveal the thresholds. ``profile`` ``intensity``: linear in intensity (the report's); ``log``: linear in log
    intensity, so a pixel's log signal is exactly linear between its events (the case where first-order-hold
    re-sampling is exact). ``phase`` (in periods, 0 = the valley) is where the wave is at time 0;
    ``phase_spread`` > 0 delays each pixel by its own fraction of ``phase_spread`` periods (uniform, from a fixed
    seed: the same every run), as a display's latency or an unknown start time per pixel would.
    """
    _check_levels(min_level, max_level)
    _check_positive("period", period_s)
    if profile not in FLICKER_PROFILES:
        raise SimulationError(f"flicker profile must be one of {', '.join(FLICKER_PROFILES)}, got {profile!r}")
    if profile == "log" and min_level <= 0:
        raise SimulationError(f"a log profile needs min level > 0, got {min_level}")
    if not math.isfinite(phase):
        raise SimulationError(f"phase must be a finite number of periods, got {phase}")
    if not 0.0 <= phase_spread < math.inf:
        raise SimulationError(f"phase spread must be a number of periods >= 0, got {phase_spread}")
    times = _frame_times_us(duration_us, frame_rate_hz)
    delays = phase_spread * np.random.default_rng(PHASE_SPREAD_SEED).random((height, width))

    def frame(t_us):
        wave = _triangle(t_us * 1e-6 / period_s + phase - delays)
        if profile == "log":
            return np.exp(math.log(min_level) + (math.log(max_level) - math.log(min_level)) * wave).astype(np.float32)
        return (min_level + (max_level - min_level) * wave).astype(np.float32)

    def levels(block):  # one level per frame
        wave = _triangle(block * 1e-6 / period_s + phase)
        if profile == "log":
            return np.exp(math.log(min_level) + (math.log(max_level) - math.log(min_level)) * wave)
        return min_level + (max_level - min_level) * wave

    if phase_spread == 0.0:
        return _uniform_frames(times, levels, width, height)
    return ((t, frame(t)) for t in _each_time(times))


PHASE_SPREAD_SEED = 0
"""flicker: the seed of the per-pixel delays of ``phase_spread`` (fixed: a scene is the same every run)."""


def gradient_scene(
    width: int, height: int, duration_us: int, *, frame_rate_hz: float = DEFAULT_FRAME_RATE_HZ,
    min_level: float = 50.0, max_level: float = 200.0, speed_px_s: float = 50.0, wavelength_px: float = 64.0,
) -> Iterator[tuple[int, np.ndarray]]:
    """The report's moving gradient: intensity rises linearly in x and falls back over ``wavelength_px`` (a
    triangle profile), the whole pattern moving right at ``speed_px_s``. Every row is alike."""
    _check_levels(min_level, max_level)
    _check_positive("wavelength", wavelength_px)
    times = _frame_times_us(duration_us, frame_rate_hz)
    x = np.arange(width) + 0.5

    def frame(t):
        row = min_level + (max_level - min_level) * _triangle((x - speed_px_s * t * 1e-6) / wavelength_px)
        return _broadcast_rows(row.astype(np.float32), height)

    return ((t, frame(t)) for t in _each_time(times))


def bars_scene(
    width: int, height: int, duration_us: int, *, frame_rate_hz: float = DEFAULT_FRAME_RATE_HZ,
    min_level: float = 50.0, max_level: float = 200.0, speed_px_s: float = 50.0, bar_width_px: float = 8.0,
    orientation: str = "vertical",
) -> Iterator[tuple[int, np.ndarray]]:
    """Bright bars of ``bar_width_px`` on a dark background (period twice the width), moving at ``speed_px_s``.

    ``vertical`` bars move right, ``horizontal`` ones move down. Each pixel's intensity is the fraction of it
    the bar covers (box-filtered edges), so an edge crosses a pixel smoothly rather than in one frame.
    """
    _check_levels(min_level, max_level)
    _check_positive("bar width", bar_width_px)
    if orientation not in ("vertical", "horizontal"):
        raise SimulationError(f"bar orientation must be vertical or horizontal, got {orientation!r}")
    times = _frame_times_us(duration_us, frame_rate_hz)
    length = width if orientation == "vertical" else height
    edges = np.arange(length + 1, dtype=np.float64)
    period = 2.0 * bar_width_px

    def covered(u):  # length of bar within [0, u) of the periodic pattern
        return np.floor(u / period) * bar_width_px + np.minimum(np.mod(u, period), bar_width_px)

    def frame(t):
        shifted = edges - speed_px_s * t * 1e-6
        covered_fraction = np.clip(np.diff(covered(shifted)), 0.0, 1.0)  # (rounding: max level 0 went below 0)
        profile = (min_level + (max_level - min_level) * covered_fraction).astype(np.float32)
        if orientation == "vertical":
            return _broadcast_rows(profile, height)
        return np.ascontiguousarray(np.broadcast_to(profile[:, None], (height, width)))

    return ((t, frame(t)) for t in _each_time(times))


def step_scene(
    width: int, height: int, duration_us: int, *, frame_rate_hz: float = DEFAULT_FRAME_RATE_HZ,
    min_level: float = 50.0, max_level: float = 200.0, period_s: float = 1.0,
) -> Iterator[tuple[int, np.ndarray]]:
    """Every pixel alike: ``min_level`` for the first half of each period, ``max_level`` for the second.

    The report's Table 2 stimulus: a step edge seen through each pixel's low-pass filter (give ``cutoff_hz``);
    without the filter every crossing of the step falls inside one frame interval.
    """
    _check_levels(min_level, max_level)
    _check_positive("period", period_s)
    times = _frame_times_us(duration_us, frame_rate_hz)
    return _uniform_frames(times, lambda block: np.where(np.mod(block * 1e-6 / period_s, 1.0) >= 0.5, max_level,
                                                         min_level), width, height)


def static_scene(
    width: int, height: int, duration_us: int, *, frame_rate_hz: float = DEFAULT_FRAME_RATE_HZ,
    level: float = 128.0,
) -> Iterator[tuple[int, np.ndarray]]:
    """A constant uniform image: every event is noise."""
    _check_levels(level, level)
    times = _frame_times_us(duration_us, frame_rate_hz)
    return _uniform_frames(times, lambda block: np.full(len(block), level), width, height)


def procedural_texture(size_px: int, seed: int = 0) -> np.ndarray:
    """A square grey texture (float32, 0-1) with what natural images have: structure at every scale (smoothed
    noise at 2 to 32 pixels, equal amplitudes) and sharp-edged regions (the sign of a field smoothed at 6 and at
    16 pixels, edges softened to about a pixel), stretched to 0-1 between its 1st and 99th percentiles."""
    import cv2

    rng = np.random.default_rng(seed)
    shape = (size_px, size_px)
    texture = sum(_smooth_field(rng, shape, scale) for scale in (2.0, 4.0, 8.0, 16.0, 32.0))
    for scale in (6.0, 16.0):
        regions = np.sign(_smooth_field(rng, shape, scale))
        texture += 2.0 * cv2.GaussianBlur(regions, (0, 0), sigmaX=0.7, borderType=cv2.BORDER_REFLECT)
    low, high = np.percentile(texture, [1.0, 99.0])
    return np.clip((texture - low) / (high - low), 0.0, 1.0).astype(np.float32)


def texture_scene(
    width: int, height: int, duration_us: int, *, frame_rate_hz: float = DEFAULT_FRAME_RATE_HZ,
    min_level: float = 50.0, max_level: float = 200.0, speed_px_s: float = 50.0, image: np.ndarray | None = None,
    texture_seed: int = 0,
) -> Iterator[tuple[int, np.ndarray]]:
    """A natural-looking scene: a texture moving, turning and zooming under the sensor.

    The texture is ``image`` (a 2-D array, 0-255; its values kept, resized so that its shorter side is twice the
    sensor's longer one) or :func:`procedural_texture` (``texture_seed``) stretched from ``min_level`` to
    ``max_level``. The view's centre follows a Lissajous path (periods in the ratio 1 : 1.37, so it covers the
    texture and every direction of motion) at about ``speed_px_s``, zooms by +-25 % and turns by +-0.3 rad over
    slower periods; each frame is the texture resampled bilinearly (OpenCV's ``warpAffine``, mirrored borders).
    Every pixel sees edges pass in every direction: the stream an ordinary recording gives, with known
    thresholds (the ``estimate --method natural`` test bed).
    """
    import cv2

    _check_levels(min_level, max_level)
    _check_positive("speed", speed_px_s)
    times = _frame_times_us(duration_us, frame_rate_hz)
    size = 2 * max(width, height)
    if image is None:
        texture = min_level + (max_level - min_level) * procedural_texture(size, texture_seed)
    else:
        image = np.asarray(image, dtype=np.float32)
        if image.ndim != 2 or min(image.shape) < 2:
            raise SimulationError(f"a texture image must be a 2-D grey image, got shape {image.shape}")
        scale = size / min(image.shape)
        texture = cv2.resize(image, (max(2, round(image.shape[1] * scale)), max(2, round(image.shape[0] * scale))),
                             interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    centre = np.array([texture.shape[1], texture.shape[0]], dtype=np.float64) / 2
    amplitude = size / 4
    path_s = 2 * math.pi * amplitude / speed_px_s  # the path's period at which its peak speed is speed_px_s

    def frame(t_us):
        t = t_us * 1e-6
        x0 = centre[0] + amplitude * math.sin(2 * math.pi * t / path_s)
        y0 = centre[1] + amplitude * math.sin(2 * math.pi * t / (1.37 * path_s) + 0.5)
        zoom = 1.0 + 0.25 * math.sin(2 * math.pi * t / (2.3 * path_s))
        angle = 0.3 * math.sin(2 * math.pi * t / (3.1 * path_s) + 1.0)
        c, s = zoom * math.cos(angle), zoom * math.sin(angle)
        # sensor (x, y) -> texture (u, v) = centre + zoom * R(angle) (x - W/2, y - H/2), at pixel centres
        dx, dy = -(width / 2 - 0.5), -(height / 2 - 0.5)
        matrix = np.array([[c, -s, x0 + c * dx - s * dy], [s, c, y0 + s * dx + c * dy]])
        return cv2.warpAffine(texture, matrix, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REFLECT)

    return ((t, frame(t)) for t in _each_time(times))


def _broadcast_rows(row: np.ndarray, height: int) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(row, (height, len(row))))


def _check_positive(name: str, value: float) -> None:
    if not value > 0 or math.isinf(value):
        raise SimulationError(f"{name} must be positive, got {value}")


SCENES: dict[str, Callable[..., Iterator[tuple[int, np.ndarray]]]] = {
    "flicker": flicker_scene,
    "gradient": gradient_scene,
    "bars": bars_scene,
    "step": step_scene,
    "static": static_scene,
    "texture": texture_scene,
}
"""The built-in scenes by name; each is ``f(width, height, duration_us, *, frame_rate_hz, ...)``."""


def scene_frames(name: str, width: int, height: int, duration_us: int, **options) -> Iterator[tuple[int, np.ndarray]]:
    """The frames ``(t_us, float32 frame)`` of the built-in scene ``name`` (see :data:`SCENES`); an option the scene
    does not have is refused naming the ones it has (it raised Python's own TypeError)."""
    make = scene_maker(name)
    check_sensor_size(width, height)
    accepted = scene_options(name)
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise SimulationUsageError(f"scene {name} has no option {', '.join(unknown)} (it has {', '.join(accepted)})")
    return make(width, height, duration_us, **options)


def scene_options(name: str) -> dict[str, inspect.Parameter]:
    """The options of the built-in scene ``name`` (its generator's parameters after the size and duration), with
    their defaults."""
    parameters = inspect.signature(scene_maker(name)).parameters
    return {key: value for key, value in parameters.items() if key not in ("width", "height", "duration_us")}


def scene_maker(name: str) -> Callable[..., Iterator[tuple[int, np.ndarray]]]:
    """The frame generator of the built-in scene ``name``; an unknown name is a usage mistake naming the scenes."""
    if name not in SCENES:
        raise SimulationUsageError(f"unknown scene {name!r}; choose one of {', '.join(SCENES)}")
    return SCENES[name]
