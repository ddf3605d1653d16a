"""Per-pixel ON and OFF contrast thresholds estimated from events, streaming in O(pixels) memory.

:class:`ThresholdEstimator` is the stream processor (``process(chunk)`` consumes events and returns an empty
chunk; :meth:`ThresholdEstimator.result` gives the maps), :func:`estimate_thresholds` the one-shot convenience.
Methods (``docs/algorithms.md`` section 4):

- ``offe``: Wang et al.'s event-only least squares, as their reference code ``EventOnlyCalib.m`` does it;
  relative thresholds scaled by a nominal value.
- ``stimulus``: the calibration stimulus is known (the flicker or moving-gradient scene); thresholds in absolute
  log units, exact for an ideal pixel.
- ``natural``: an ordinary moving scene; each pixel's ON and OFF event counts against its neighbours' (relative
  thresholds scaled by a nominal value), with a fit map from two interleaved halves of the stream.

References
----------
Z. Wang, Y. Ng, P. van Goor, R. Mahony, "Event Camera Calibration of Per-pixel Biased Contrast Threshold",
Australasian Conference on Robotics and Automation (ACRA), 2019. Code: github.com/ziweiWWANG/Event-Camera-Calibration.
Y. Nozaki, T. Delbruck, "Temperature and Parasitic Photocurrent Effects in Dynamic Vision Sensors",
IEEE Transactions on Electron Devices 64(8), 2017 (thresholds from a known contrast: the stimulus method).
"""

from __future__ import annotations

import math
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from evtools._kernels.estimate import (
    _NEVER,
    NEIGHBOUR_AGE_BINS,
    neighbour_ages,
    OFFE_E,
    OFFE_ROW,
    OFFE_SAMPLES,
    OFFE_SUMS_AT,
    OFFE_STATE_SIZE,
    PROFILE_INTENSITY,
    PROFILE_LOG,
    SEED_PAIRS,
    ST_ALL,
    RING,
    WAVE_CELLS,
    ST_FITTED,
    ST_PHASE,
    ST_EVENTS,
    ST_PAIRS,
    ST_REF,
    ST_SEEN,
    ST_SIZE,
    ST_SQUARES,
    ST_SUM,
    SUM_E,
    SUM_EE,
    SUM_EP,
    SUM_P,
    SUM_PP,
    COUNT_LAST,
    COUNT_SIZE,
    count_accumulate,
    offe_accumulate,
    offe_finish,
    stimulus_accumulate,
    stimulus_fitted_accumulate,
    stimulus_fitted_finish,
    stimulus_table,
    wave_table,
)
from evtools._kernels.pixel import LIN_LOG_KNEE, LIN_LOG_SLOPE
from evtools.errors import EvtoolsError
from evtools.events import MAX_THRESHOLD, MAX_TIME_US, StreamChecker, StreamInfo, check_sensor_size, empty_events

__all__ = [
    "METHODS",
    "EstimationError",
    "Stimulus",
    "ThresholdEstimate",
    "ThresholdSeries",
    "ThresholdEstimator",
    "estimate_thresholds",
]

METHODS = ("offe", "stimulus", "natural")
"""The estimation methods, by name."""

REACQUIRE_SHARE = 0.5
"""stimulus, online: a polarity of a pixel whose accepted changes are fewer than this share of its recent ones (the
decayed counts, or those since the last map alone) has left its acceptance window (a threshold step of more than
-20 % / +25 %) and seeds anew. (The decayed counts alone held a x1.3 step's old values valid a whole interval after
it with the default forget, 3 intervals: 141 of 192 pixels 23.5 % off, a QA sweep.)"""
REACQUIRE_CHANGES = 4.0
"""stimulus, online: ... judged only with at least this many recent changes (decayed count) of that polarity."""

STALE_FIT = math.inf
"""Online: a map's ``fit`` of a pixel whose estimate was dropped (its threshold left the acceptance window) and is
not acquired again yet: ``correct`` does not carry its earlier value past that map."""

SCALES = {"offe": "relative", "natural": "relative", "stimulus": "absolute"}
"""Each method's scale (a map's ``scale`` attribute): ``absolute`` from a known stimulus; ``relative`` from events
alone, set by ``nominal`` (the median pixel's threshold is the nominal value, whatever the camera's is)."""

NOT_OBSERVABLE = ("events alone give thresholds relative to one another: not their absolute scale (set by "
                  "--nominal), not a smooth spatial component of the mismatch (taken for the scene's), not a drift "
                  "shared by all pixels (taken for the scene's), not the balance of ON against OFF where the "
                  "whole scene ends brighter or darker than it began (a net rise reads as smaller ON thresholds); "
                  "a known stimulus or APS frames can")
"""What an events-only estimate cannot observe (a map's ``not_observable`` attribute, shown by ``metrics
thresholds``)."""
POLARITY_BALANCE = 2.0
"""An events-only map whose ON and OFF medians differ by more than this factor says so (``polarity_balance``): the
balance is not observable (:data:`NOT_OBSERVABLE`) and a camera's ON / OFF asymmetry is rarely that large (the
DAVIS346 lab recording with natural: 0.070 against 0.29, a QA sweep; the DVS128 walk 0.18 against 0.20)."""
PHASES = ("fit", "given")
"""stimulus: each pixel's phase fitted to its own events, or given by the stimulus (low end at t = 0)."""

DEFAULT_NOMINAL = 0.2
"""Nominal threshold (log units) that sets the scale of the relative methods (v2e's and the report's 0.2)."""
DEFAULT_SEGMENT_US = 10_000
"""offE segment length: 10 ms (the reference samples at its frames' rate, about 20-25 Hz on a DAVIS240C; shorter
segments give more samples on the report's 0.5 s flicker)."""
DEFAULT_MIN_EVENTS = 10
"""A pixel with fewer events is left invalid."""
RCOND_LIMIT = 1e-14
"""offE: a fit whose normal matrix has a reciprocal condition number below this is singular (the reference's)."""
MAX_SCALE_FACTOR = 10.0
"""offE: ``c > 10 * nominal`` is unrealistic and left invalid (the reference replaces it by the nominal value)."""
DEFAULT_MAX_FIT = 0.5
"""stimulus: a pixel whose fit (RMS deviation of its level changes from its thresholds, in thresholds, a change
that does not fit counting as one) exceeds this is invalid. An ideal pixel under the described stimulus fits to
~1e-4; noise left by a denoiser (one change in 10-20 spoilt, on the report's 2 s calibrations) gives 0.2-0.4; a
period 10-30 % wrong, per-pixel phases or a natural scene give 0.75-0.95 (measured)."""
MIN_FITTING_SHARE = 0.5
"""stimulus: when fewer than half of the pixels with enough events fit, the stream as a whole does not show the
described stimulus (a calibration shows it to the whole view): an error rather than the few chance fits (4 of
2,229 pixels of a street scene fit the default flicker within 0.5)."""
FIT_MIN_CHANGES = 8
"""stimulus: a pixel whose events make fewer level changes than this cannot show that it fits (two or three
changes agree by chance on a natural scene) and is invalid."""
DEFAULT_RADIUS_PX = 1
"""natural: a pixel is compared with its 8 nearest pixels (a 3 x 3 window less itself). Nearer neighbours share
more of the pixel's excursion: on moving natural textures (issue 36's setups, independent generator) the RMS
error over all pixels is 7-15 % at radius 1 against 13-22 % at radius 3."""
MAX_SERIES_BYTES = 1 << 31
"""The most memory an online estimate's maps may take when it holds them (2 GiB at 13 bytes a pixel, as the file
stores them: about 2,150 maps of a 320x240 sensor, 179 of a 1280x720 one): a shorter interval is refused when it
would go past it (:func:`check_series_room`). With a ``map_sink`` (the command line) none is held and no bound
applies."""
DEFAULT_MAX_ERROR = 0.25
"""natural: a pixel whose fit (the largest of its error terms: the halves' disagreement, the counting error
1 / sqrt(N) of its rarer polarity, the excitation gradient across its window, the scene error) exceeds 0.25 is
invalid (offE's fit, its disagreement with natural, the same). On moving natural textures the valid pixels' RMS
error is then 8-9 % on a wobble or a contrast boundary, 15 % on a slow pan (samples/natural.md); 0.15 gives 7 %
on a wobble with 38 % of the pixels valid, not 89 %."""
DEFAULT_FORGET_INTERVALS = 3
"""online: sums forget with a time constant of 3 intervals by default (each map then rests mostly on the last
three intervals' events)."""
BLOCK_US = 100_000
"""natural: the stream is cut into 100 ms blocks, alternately counted in one half or the other (absolute time, so
chunking cannot matter); the halves see nearly the same scene, so their difference measures the estimate's error."""
GRADIENT_RADIUS_PX = 3
"""natural: the excitation gradient is measured across a window of at least this half-width (21 pixels a half:
over a radius-1 window's 3 a half the thresholds' own spread reads as a gradient)."""
SCENE_MAX_LAG_PX = 8
"""natural: the scene error's autocovariance is measured up to this lag (twice the radius, at most this)."""
MIN_NEIGHBOURS = 3
"""natural: a pixel with fewer countable neighbours than this has no reference and is invalid (a corner pixel
has 3 at radius 1)."""
MAX_RELATIVE = 4.0
"""natural: a pixel whose threshold would be more than this factor from its neighbours' (either polarity) is not
valid: thresholds spread by 25 % (more than chips show) are that far only 3 standard deviations below the mean, but
a hot or flickering pixel among quiet neighbours is 10-100 times off (the DVXplorer
recording with --min-events 1: five pixels valid at 1/13 to 1/130 of the nominal, fits 0.17-0.24, a QA sweep)."""
MAX_TABLE_US = 1 << 21
"""stimulus: a flicker whose period is a whole number of microseconds up to this (2.1 s, a 16 MB table) is
tabulated at 1 us over one period; longer periods compute L per event (the same values, slower)."""

LEVELS_STEP = 2.0 ** 0.25
"""stimulus (intensity profile): the levels check estimates the stream again with the log ratio of the levels
(high / low) times powers of this, the high level kept, and refuses the levels given when another ratio explains the
events much better (:meth:`ThresholdEstimator._check_description`)."""
DESCRIPTION_CHECK_PIXELS = 2048
"""The description check (levels, period) looks at every s-th row, s chosen to keep at most this many pixels (its
memory and time: 15 estimates of them)."""
LEVELS_STEPS = 4
"""... and this many steps either side (log ratios from 1/2 to 2 times the given's)."""
DESCRIPTION_MIN_DEVIATION = 0.003
"""The description check takes a description whose median deviation is below this (level changes within 0.3 % of
the thresholds). Ideal pixels under the true description deviate by < 1e-4; with a log triangle's period 2-3 %
off by 0.006-0.017 (80 seeds), every threshold then 2-5 % off: a floor of 0.01 took 0.0097 and called such
pixels valid."""
DESCRIPTION_CHECK_PERIODS = 4
"""Online, the description check runs once, at the first map after this many periods of the stream (a wrong
description offline was refused, online it gave every map at half the true thresholds: a QA sweep); a stream
shorter than that is checked at its end, as offline."""
PERIOD_FACTORS = (0.96, 0.98, 0.99, 1.01, 1.02, 1.04)
"""stimulus: the description check estimates the stream again with the period times each of these."""
RISE_SHIFTS = (-0.2, -0.1, -0.05, 0.05, 0.1, 0.2)
"""stimulus: ... and with the rise fraction plus each of these (within 0.02-0.98): a rise of 0.6 for 0.5 called every
pixel valid, ON 10 % low and OFF 15 % high (a QA sweep)."""
DESCRIPTION_BETTER = 1 / math.sqrt(2.0)
"""The description check refuses when another description's median deviation is below this times the given one's (the
simulated 32 x 24 flicker, levels 50,200: ideal pixels 0.001 at the true levels, 0.02-0.1 at low levels 25-100; with
v2e's noisy preset the best over the given is 0.93-1.0 for low levels 45-60 and 0.46-0.67 for 25-40 and 70-100)"""


SCENE_EXPECTED_SHARE = 0.05
"""natural, offE (:meth:`ThresholdEstimator._check_scene`): the lag tested is where independent pixels at the
measured rates would follow a neighbour's event this often."""
SCENE_MIN_DT_US = 1024
"""... and at least this lag (us): shorter ones are shaped by a sensor's readout (Gen4.1's sample: fewer
coincidences within 64 us than independent pixels give, z -10; within 1 ms z 43)."""
SCENE_STRIDE = 1
"""... one event in this many (a power of 2) is looked at, in stream order (1: every one; 4 halved the test's power:
a small flicker fell below :data:`SCENE_Z`)."""
SCENE_EVENTS = 4_000_000
"""... among the stream's first this many events (then the check costs nothing: a long recording estimates at the
speed it did before it)."""
SCENE_Z = 3.0
"""... and the events must follow neighbours' this many standard deviations more often than independent ones."""


class EstimationError(EvtoolsError, ValueError):
    """Threshold estimation cannot run on these parameters or this stream."""


class DescriptionError(EstimationError):
    """The events contradict the stimulus described (its levels or period): every estimate made with it is wrong,
    an online run's earlier maps too."""


def lin_log(intensity: float) -> float:
    """The simulator's log intensity: linear below the knee (20), ``log`` above (``evtools._kernels.pixel``)."""
    return intensity * LIN_LOG_SLOPE if intensity <= LIN_LOG_KNEE else math.log(intensity)


@dataclass(frozen=True)
class Stimulus:
    """A triangle-wave calibration stimulus every pixel sees, possibly shifted in time by its column.

    Parameters
    ----------
    low, high : float
        The stimulus's lowest and highest value: intensities (0-255, the scale of ``evtools simulate``) for the
        ``intensity`` profile, log intensities (any real numbers) for the ``log`` profile.
    period_us : float
        Time of one full rise and fall, microseconds.
    wavelength_px : float
        0: every pixel alike (flicker). Otherwise the moving gradient: the pattern repeats every
        ``wavelength_px`` columns and moves right by one wavelength per period, so column x's stimulus is
        delayed by ``(x + 0.5) / wavelength_px`` periods.
    profile : {"intensity", "log"}
        What the triangle is linear in: intensity (``evtools simulate``'s scenes; L = lin_log(I)) or log
        intensity (L itself goes from ``low`` to ``high``).
    rise : float
        The fraction of a period spent rising, 0 < rise < 1 (0.5: a symmetric triangle; near 1 a sawtooth).

    Notes
    -----
    The stimulus starts at t = 0 at its low level (phase 0), as the simulator's scenes do (the estimator fits
    every pixel's own phase unless told to take this one). For the ``log``
    profile only the amplitude ``high - low`` matters: thresholds are differences of L, so a base level
    ``L0`` cancels (:meth:`log_triangle` takes 0; any other base gives the same thresholds to rounding, ~1e-15).
    """

    low: float = 50.0
    high: float = 200.0
    period_us: float = 500_000.0
    wavelength_px: float = 0.0
    profile: str = "intensity"
    rise: float = 0.5

    def __post_init__(self) -> None:
        if self.profile not in ("intensity", "log"):
            raise EstimationError(f"stimulus profile must be intensity or log, got {self.profile!r}")
        finite = math.isfinite(self.low) and math.isfinite(self.high)
        if not finite or not self.low < self.high or (self.profile == "intensity" and self.low < 0):
            floor = "0 <= " if self.profile == "intensity" else ""
            raise EstimationError(f"stimulus levels must satisfy {floor}low < high, got {self.low}, {self.high}")
        if not self.period_us > 0 or not math.isfinite(self.period_us):
            raise EstimationError(f"stimulus period must be positive, got {self.period_us} us")
        if not self.wavelength_px >= 0 or not math.isfinite(self.wavelength_px):
            raise EstimationError(f"stimulus wavelength must be >= 0 pixels, got {self.wavelength_px}")
        if not 0 < self.rise < 1:
            raise EstimationError(f"stimulus rise fraction must be between 0 and 1 (exclusive), got {self.rise}")

    @classmethod
    def log_triangle(cls, amplitude: float, period_us: float, wavelength_px: float = 0.0,
                     rise: float = 0.5) -> Stimulus:
        """A triangle linear in log intensity with peak-to-peak ``amplitude`` (log units): L from 0 to amplitude."""
        if not amplitude > 0 or not math.isfinite(amplitude):
            raise EstimationError(f"stimulus amplitude must be positive (log units), got {amplitude}")
        return cls(0.0, float(amplitude), period_us, wavelength_px, "log", rise)

    @classmethod
    def moving(cls, low: float, high: float, speed_px_s: float, wavelength_px: float, profile: str = "intensity",
               rise: float = 0.5):
        """The moving gradient of ``wavelength_px`` moving right at ``speed_px_s`` (period = wavelength / speed)."""
        if not speed_px_s > 0 or not wavelength_px > 0:
            raise EstimationError(
                f"a moving stimulus needs a positive speed and wavelength, got {speed_px_s} px/s, {wavelength_px} px"
            )
        return cls(low, high, 1e6 * wavelength_px / speed_px_s, wavelength_px, profile, rise)

    @property
    def log_amplitude(self) -> float:
        """Peak-to-peak amplitude of L (log units)."""
        if self.profile == "log":
            return self.high - self.low
        return lin_log(self.high) - lin_log(self.low)

    def as_dict(self) -> dict[str, Any]:
        return {
            "stimulus_low": self.low, "stimulus_high": self.high, "stimulus_period_us": self.period_us,
            "stimulus_wavelength_px": self.wavelength_px, "stimulus_profile": self.profile,
            "stimulus_rise": self.rise, "stimulus_log_amplitude": self.log_amplitude,
        }


@dataclass
class ThresholdEstimate:
    """The estimated maps (height x width): ``on``, ``off`` (float32, log units), ``valid`` (bool), attributes.

    Invalid pixels hold the median of the valid ones, so a consumer that ignores ``valid`` still gets a sane
    value; :meth:`usable` is the mask to trust.
    """

    on: np.ndarray
    off: np.ndarray
    valid: np.ndarray
    attributes: dict[str, Any] = field(default_factory=dict)
    fit: np.ndarray | None = None
    """Per pixel, how well its events fit the method's model (stimulus: see :data:`DEFAULT_MAX_FIT`; NaN where
    there is nothing to fit); None for methods without a fit measure."""
    phase_us: np.ndarray | None = None
    """stimulus with fitted phases: per pixel, the time of a valley of its stimulus modulo the period
    (microseconds; NaN where no phase was fitted). A moving pattern shows as a ramp across the sensor, a rolling
    display refresh as one along its scan."""

    series: ThresholdSeries | None = None
    """Online estimation: the map at every interval boundary (and the final one, at the last event + 1 us)."""

    def usable(self) -> np.ndarray:
        return self.valid & np.isfinite(self.on) & np.isfinite(self.off) & (self.on > 0) & (self.off > 0)


@dataclass
class ThresholdSeries:
    """Maps over time (online estimation): map k holds from ``t_us[k]`` on. ``on``, ``off``, ``fit``: float32
    (maps, height, width), NaN where not valid; ``valid``: bool (maps, height, width)."""

    t_us: np.ndarray
    on: np.ndarray
    off: np.ndarray
    valid: np.ndarray
    fit: np.ndarray


class ThresholdEstimator:
    """Accumulates a stream's events and estimates every pixel's ON and OFF contrast thresholds.

    Parameters
    ----------
    width, height : int
        Sensor size.
    method : {"offe", "stimulus", "natural"}
        ``offe``: Wang et al.'s offE exactly as ``EventOnlyCalib.m``: the stream is cut into segments of
        ``segment_us``; per pixel, the cumulative polarity sum P_k and event count E_k at each segment end are
        fitted by least squares ``P = m E + d``; r = RMS residual; ``c = nominal * median(r) / r``, ``b = -c m``,
        ``on = c + b``, ``off = c - b``. Invalid: fewer than ``min_events`` events, a singular fit (reciprocal
        condition number of the normal matrix < 1e-14), r = 0, or ``c > 10 * nominal`` (the reference's test),
        and beyond the reference: a fit above ``max_fit``. offE's assumption (every pixel sees the same
        log-intensity variance) cannot be checked from a pixel's own events, so its fit is the relative
        disagreement (RMS over ON and OFF) with the ``natural`` method's estimate from the same events, or
        natural's own fit where that is larger (:func:`_offe_fit`), where natural is valid (NaN elsewhere: not
        checked, so not valid); its rank correlation with offE's true error is 0.6-0.8 on the texture scene,
        -0.1-0.4 on issue 36's moving textures. ``max_fit=inf`` is the reference exactly (every estimate valid).
        ``stimulus``: the known ``stimulus`` waveform L; ``on`` = mean of ``L(t_k) - L(t_{k-1})`` over ON events
        that follow another event of the pixel, ``off`` likewise for OFF; absolute, ``nominal`` unused. Exact
        for an ideal pixel, whose reference is L at its previous event, so turn-arounds need no special case.
        Invalid: fewer than ``min_events`` events or no ON or no OFF pair.
    nominal : float
        offE: the median pixel's threshold c (log units); the scale is not observable from events alone.
    segment_us : int
        offE: segment length, microseconds.
    stimulus : Stimulus
        The stimulus, for ``method="stimulus"``.
    phase : {"fit", "given"}
        stimulus: ``fit`` (default) finds each pixel's phase from its own first events (its turns bracket the
        stimulus's valleys and peaks; the phase that makes its level changes most alike is taken), so a per-pixel
        delay, an unknown start time or a moving pattern need no description; only changes within a ramp (two
        events of one polarity in a row) are counted, so a pixel firing once per ramp is invalid (its phase and
        thresholds are not determined). ``given`` takes the stimulus's own (low end at t = 0, delayed by the
        column for a gradient) and counts every change, turns included.
    min_events : int
        Pixels with fewer events are invalid.
        ``natural``: an ordinary moving scene, nothing known about it. Per pixel its ON and OFF events and its
        polarity reversals are counted; with the turns' share (:func:`_effective_inverse`) they give the
        thresholds up to the pixel's total log-intensity excursion, which its neighbours within ``radius_px``
        share (edges pass over them all), so each pixel is scaled against its neighbours' mean and the whole
        map by ``nominal`` (mean of on and off). The fit is the relative disagreement of the same estimate from
        two halves of the stream (alternate 100 ms blocks), at least ``1 / sqrt(N)`` of its rarer polarity: about
        the estimate's error from counting. Invalid:
        fewer than ``min_events`` of either polarity, fewer than 8 such neighbours, or a fit above ``max_fit``.
    max_fit : float, optional
        Pixels whose fit is worse are invalid. stimulus (default :data:`DEFAULT_MAX_FIT`): the RMS deviation of
        the pixel's level changes from its estimated thresholds, in thresholds, every change that ended in an
        event counted and one outside the acceptance window (or of the wrong sign) counting as a whole threshold:
        so a wrong period, a wrong waveform or a scene that is no stimulus cannot give confident values.
        natural (default :data:`DEFAULT_MAX_ERROR`): the halves' relative disagreement; offe (the same default):
        the disagreement with the natural estimate, or natural's own fit where that is larger (:func:`_offe_fit`).
    radius_px : int
        natural: the neighbourhood's half-width (:data:`DEFAULT_RADIUS_PX`).
    interval_us, forget_us : int and float, optional
        Online (stimulus, natural): a map every ``interval_us`` from the first event, then every sum decays by
        ``exp(-interval / forget)`` (default 3 intervals); the result's ``series`` holds the maps.
    map_sink : callable, optional
        Online: each map is passed to ``map_sink(t_us, on, off, valid, fit)`` as it is made instead of being held
        (:class:`OnlineMaps`; the result's ``series`` is then None): the command line writes them to the file.
    check : bool, optional
        Check every chunk as a reader does (default; see :class:`evtools.filters.BAFilter`); the command line
        passes False, its readers having checked.

    References
    ----------
    Z. Wang, Y. Ng, P. van Goor, R. Mahony, "Event Camera Calibration of Per-pixel Biased Contrast Threshold",
    ACRA 2019 (offE, its equations 8-12).
    Y. Nozaki, T. Delbruck, "Temperature and Parasitic Photocurrent Effects in Dynamic Vision Sensors", IEEE
    Trans. Electron Devices, 2017 (thresholds measured against a known contrast stimulus: stimulus).
    """

    def __init__(
        self,
        width: int,
        height: int,
        method: str = "offe",
        *,
        nominal: float = DEFAULT_NOMINAL,
        segment_us: int = DEFAULT_SEGMENT_US,
        stimulus: Stimulus | None = None,
        phase: str = "fit",
        min_events: int = DEFAULT_MIN_EVENTS,
        max_fit: float | None = None,
        radius_px: int = DEFAULT_RADIUS_PX,
        interval_us: int | None = None,
        forget_us: float | None = None,
        map_sink=None,
        check: bool = True,
    ) -> None:
        check_sensor_size(width, height)
        self._checker = StreamChecker(StreamInfo(int(width), int(height))) if check else None
        if method not in METHODS:
            raise EstimationError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
        if not 0 < nominal <= MAX_THRESHOLD:
            raise EstimationError(f"nominal threshold must be a positive number of log units up to {MAX_THRESHOLD:g}, "
                                  f"got {nominal}")
        if int(segment_us) != segment_us or not 1 <= segment_us <= MAX_TIME_US:
            raise EstimationError(f"segment length must be a whole number of microseconds in 1..{MAX_TIME_US} "
                                  f"(2^62), got {segment_us}")
        if int(min_events) != min_events or min_events < 1:
            raise EstimationError(f"min_events must be a whole number >= 1, got {min_events}")
        if max_fit is None:
            max_fit = DEFAULT_MAX_FIT if method == "stimulus" else DEFAULT_MAX_ERROR
        if not max_fit > 0:
            raise EstimationError(f"max_fit must be positive (inf: no limit), got {max_fit}")
        if int(radius_px) != radius_px or radius_px < 1:
            raise EstimationError(f"radius must be a whole number of pixels >= 1, got {radius_px}")
        radius_px = min(int(radius_px), max(width, height))  # (a wider window holds the same pixels: the sensor)
        if phase not in PHASES:
            raise EstimationError(f"unknown phase {phase!r}; choose one of {', '.join(PHASES)}")
        if interval_us is not None:
            if method == "offe":
                raise EstimationError("online estimation (an interval) works with the stimulus and natural methods; "
                                      "offE fits each pixel's whole history")
            if int(interval_us) != interval_us or interval_us < 1:
                raise EstimationError(f"interval must be a whole number of microseconds >= 1, got {interval_us}")
            forget_us = DEFAULT_FORGET_INTERVALS * interval_us if forget_us is None else forget_us
            if not forget_us > 0:
                raise EstimationError(f"forgetting time must be positive (inf: never forget), got {forget_us} us")
        elif forget_us is not None:
            raise EstimationError("a forgetting time applies to online estimation only: give an interval too")
        if method == "stimulus" and stimulus is None:
            raise EstimationError("method stimulus needs the stimulus (levels, period, and for a gradient its motion)")
        self.width, self.height = int(width), int(height)
        self.method = method
        self.nominal = float(nominal)
        self.segment_us = int(segment_us)
        self.stimulus = stimulus
        self.phase = phase
        self.min_events = int(min_events)
        self.max_fit = float(max_fit)
        self.radius_px = int(radius_px)
        self.interval_us = None if interval_us is None else int(interval_us)
        self.forget_us = None if forget_us is None else float(forget_us)
        self._next_snapshot_us: int | None = None
        self._maps = None if interval_us is None else OnlineMaps(self.width, self.height, self.interval_us, map_sink)
        self.reacquired = 0  # online stimulus: polarities of pixels that stepped out of their window and seeded anew
        self._stale = np.zeros(width * height, dtype=bool)  # dropped estimates not yet acquired again
        self._since_map = None  # stimulus, online: each pixel's (all, accepted) changes of ON, OFF at the last map
        n = self.width * self.height
        self.events = 0
        self.on_events = 0
        self.t_first_us: int | None = None
        self.t_last_us: int | None = None
        self._finished = False
        if method in ("offe", "natural"):  # events alone: whether they show a scene at all (_check_scene)
            self._age_map = np.full((height + 2, width + 2), _NEVER, np.int64)
            self._pixel_events = np.zeros(n, np.int64)
            self._neighbour_ages = np.zeros(NEIGHBOUR_AGE_BINS, np.int64)
        if method == "offe":
            self._pixels = _aligned_zeros(n, OFFE_ROW, np.int64)  # per pixel (E, P), samples included, the sums
            self._clock = np.zeros(OFFE_STATE_SIZE, dtype=np.int64)
            self._counts = _aligned_zeros(n, COUNT_SIZE, np.float32)  # the natural method's, for offE's fit
        elif method == "natural":
            self._counts = _aligned_zeros(n, COUNT_SIZE, np.float32)
        else:
            self._state = _aligned_zeros(n, ST_SIZE, np.float64)
            self._seeds = np.zeros((n, 2, SEED_PAIRS), dtype=np.float64)
            s = stimulus
            profile = PROFILE_LOG if s.profile == "log" else PROFILE_INTENSITY
            self._waveform = (float(s.low), float(s.high), float(s.period_us), float(s.rise))
            self._profile = profile
            if phase == "fit":
                self._wave = np.empty((2, WAVE_CELLS + 2), dtype=np.float64)
                wave_table(float(s.low), float(s.high), float(s.rise), profile, self._wave)
                self._ring = np.zeros((n, RING), dtype=np.int64)
                self._filled = np.zeros(n, dtype=np.int64)
            else:
                self._table = np.zeros(0, dtype=np.float64)
                if s.wavelength_px == 0 and s.period_us == int(s.period_us) and s.period_us <= MAX_TABLE_US:
                    self._table = np.empty(int(s.period_us), dtype=np.float64)
                    stimulus_table(*self._waveform, profile, self._table)
        # the description check: the same estimate on a sample of rows, as described and with other levels and
        # periods (:meth:`_check_description`)
        self._probe_rows = 0
        self._probes: dict[tuple[str, float], ThresholdEstimator] = {}  # ("levels", log ratio scale), ("period", x),
        # or ("rise", shift)
        if method == "stimulus" and math.isfinite(self.max_fit):  # (online: until DESCRIPTION_CHECK_PERIODS)
            self._probe_rows = max(1, math.ceil(width * height / DESCRIPTION_CHECK_PIXELS))
            rows = math.ceil(height / self._probe_rows)

            def probe(description: Stimulus) -> ThresholdEstimator:
                return ThresholdEstimator(width, rows, "stimulus", phase=phase, min_events=min_events,
                                          max_fit=math.inf, check=False, stimulus=description)

            self._probes[("given", 1.0)] = probe(stimulus)
            if stimulus.profile == "intensity" and stimulus.low > 0:  # (the log ratio high / low scaled, high kept)
                log_ratio = math.log(stimulus.high / stimulus.low)
                for k in LEVELS_STEP ** np.arange(-LEVELS_STEPS, LEVELS_STEPS + 1):
                    if k != 1.0:
                        self._probes[("levels", k)] = probe(replace(stimulus, low=stimulus.high / math.exp(log_ratio * k)))
            for factor in PERIOD_FACTORS:
                self._probes[("period", factor)] = probe(replace(stimulus, period_us=stimulus.period_us * factor))
            for shift in RISE_SHIFTS:
                if 0.02 <= stimulus.rise + shift <= 0.98:
                    self._probes[("rise", shift)] = probe(replace(stimulus, rise=stimulus.rise + shift))

    @property
    def parameters(self) -> dict[str, Any]:
        """The method and its parameters (written as attributes of the thresholds file)."""
        parameters: dict[str, Any] = {"method": self.method, "min_events": self.min_events}
        if self.method == "offe":
            parameters["nominal"] = self.nominal
            parameters["segment_us"] = self.segment_us
            parameters["max_fit"] = self.max_fit
        if self.method == "natural":
            parameters.update(nominal=self.nominal, radius_px=self.radius_px, block_us=BLOCK_US, max_fit=self.max_fit)
        if self.interval_us is not None:
            parameters.update(interval_us=self.interval_us, forget_us=self.forget_us)
        if self.method == "stimulus":
            parameters.update(self.stimulus.as_dict())
            parameters["stimulus_phase"] = self.phase
            parameters["max_fit"] = self.max_fit
        return parameters

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """Accumulate ``chunk`` (time-sorted, continuing the stream); the estimator consumes: returns no events."""
        if self._finished:
            raise EstimationError("the estimate is already finished; make a new estimator for another stream")
        if self._checker:
            chunk = self._checker.check(chunk)
        if not len(chunk):
            return empty_events()
        if self.interval_us is not None:  # online: a map at every interval boundary, then the sums forget
            if self._next_snapshot_us is None:
                self._next_snapshot_us = int(chunk["t"][0]) + self.interval_us
            while len(chunk) and chunk["t"][-1] >= self._next_snapshot_us:
                before = int(np.searchsorted(chunk["t"], self._next_snapshot_us, side="left"))
                self._accumulate(chunk[:before])
                self._snapshot(self._next_snapshot_us)
                self._next_snapshot_us += self.interval_us
                chunk = chunk[before:]
        self._accumulate(chunk)
        return empty_events()

    def _accumulate(self, chunk: np.ndarray) -> None:
        if not len(chunk):
            return
        t, x, y, p = chunk["t"], chunk["x"], chunk["y"], chunk["p"]
        if self.t_first_us is None:
            self.t_first_us = int(t[0])
        self.t_last_us = int(t[-1])
        self.events += len(chunk)
        self.on_events += int(np.count_nonzero(p))
        before = self.events - len(chunk)
        scene = None
        if self.method in ("offe", "natural") and before < SCENE_EVENTS:  # (the stream's first SCENE_EVENTS, on a
            end = min(len(chunk), SCENE_EVENTS - before)                 # second thread beside the counting: its
            scene = _scene_thread().submit(                               # own arrays; kernels release the GIL)
                neighbour_ages, t[:end], x[:end], y[:end], before, SCENE_STRIDE, self._age_map, self._pixel_events,
                self._neighbour_ages)
            self._scene_last_us = int(t[end - 1])
        try:
            self._count(t, x, y, p)
        finally:
            if scene is not None:
                scene.result()
        if self._probes:
            sampled = chunk[chunk["y"] % self._probe_rows == 0]
            sampled["y"] //= self._probe_rows
            for probe in self._probes.values():
                probe._accumulate(sampled)

    def _count(self, t, x, y, p) -> None:
        """The method's sums of one chunk's events (its kernel)."""
        if self.method == "offe":
            offe_accumulate(t, x, y, p, self.width, self.segment_us, self._pixels, self._clock, BLOCK_US,
                            self._counts)
        elif self.method == "natural":
            count_accumulate(t, x, y, p, self.width, BLOCK_US, self._counts)
        elif self.phase == "fit":
            stimulus_fitted_accumulate(t, x, y, p, self.width, float(self.stimulus.period_us),
                                       float(self.stimulus.rise), self._wave, self._state, self._seeds, self._ring,
                                       self._filled)
        else:
            stimulus_accumulate(t, x, y, p, self.width, *self._waveform, float(self.stimulus.wavelength_px),
                                self._profile, self._table, self._state, self._seeds)

    def _check_scene(self) -> None:
        """Refuse a stream whose events show no scene: natural and offE read thresholds off what neighbouring pixels
        share, and on pure noise they called a fifth to a third of the pixels valid, at thresholds uncorrelated with
        the true ones (a QA sweep). The test: the events that follow a neighbour's event within ``dt`` (the binary
        order of magnitude where independent pixels at the measured rates would give :data:`SCENE_EXPECTED_SHARE`,
        at least :data:`SCENE_MIN_DT_US`: a sensor's readout shapes shorter lags) must exceed that expectation by
        :data:`SCENE_Z` standard deviations, one event in :data:`SCENE_STRIDE` looked at. Measured z (every
        event): noise -1.1 to 0.9; a 8x8 flicker of 1 s 4.4; every shared recording 26-430 (DAVIS346, DVXplorer,
        DVS128, Gen4.1)."""
        n = int(self._pixel_events.sum())  # (the events looked at: one in SCENE_STRIDE; their rates scaled up)
        span_s = max(self._scene_last_us - self.t_first_us, 1) * 1e-6 / SCENE_STRIDE
        counts = self._pixel_events.reshape(self.height, self.width).astype(np.float64)
        padded = np.pad(counts / span_s, 1)
        neighbours = sum(padded[1 + dy:self.height + 1 + dy, 1 + dx:self.width + 1 + dx]
                         for dy in (-1, 0, 1) for dx in (-1, 0, 1)) - counts / span_s  # rate, events/s
        mean_neighbours = float((neighbours * counts).sum() / max(n, 1))
        if mean_neighbours <= 0:
            return  # (no pixel has a neighbour that fired: the methods' own checks refuse it)
        want_us = -math.log(1 - SCENE_EXPECTED_SHARE) / mean_neighbours * 1e6
        k = int(min(max(round(math.log2(max(want_us, 1.0))), math.log2(SCENE_MIN_DT_US)), NEIGHBOUR_AGE_BINS - 2))
        share = float(((1 - np.exp(-neighbours * (2 ** k) * 1e-6)) * counts).sum()) / n
        observed = int(self._neighbour_ages[:k].sum())
        z = (observed - share * n) / math.sqrt(max(share * (1 - share) * n, 1.0))
        if z < SCENE_Z:
            raise EstimationError(
                f"the events show no scene: {100 * observed / n:.1f} % follow a neighbour's event within "
                f"{2 ** k:,} us, as independent noise at the same rates gives ({100 * share:.1f} %, z {z:.1f}); "
                f"{self.method} reads thresholds off what neighbouring pixels see, and noise alone gives plausible "
                "but meaningless values: record a moving scene, or use --method stimulus with a known stimulus "
                "(--max-fit inf takes the estimates unchecked)")

    def _check_description(self) -> None:
        """Refuse a stimulus description the events contradict: the levels (the ratio high / low) or the period.
        The same estimate on every s-th row as described and with other levels and periods gives the median
        deviation of each one's accepted changes from its thresholds (the misfits, mostly noise, left out); when
        another description's is below :data:`DESCRIPTION_BETTER` times the given one's (and the given one's above
        :data:`DESCRIPTION_MIN_DEVIATION`), the description is refused, naming what fits better.

        Levels: a triangle linear in intensity is curved in log intensity, more so the larger the ratio, so the
        events' timing shows the ratio: an ideal pixel fits the levels given to ~1e-3, levels 20 % off to ~0.04,
        while every threshold comes out 12-14 % off (and 38-49 % with levels 2x off, most pixels still valid: a QA
        sweep). The log ratio is scaled by :data:`LEVELS_STEP` to the power -:data:`LEVELS_STEPS`..; a parabola
        through the lowest and its neighbours' squares puts the best. A triangle in log intensity has no such
        curvature: its amplitude only scales the thresholds, which no event can show. Period: 2 % off (490 ms
        for 500 ms) called every pixel valid at 8.6 % error (a QA sweep); the deviation is sharpest at the true
        period (ideal 0.001 against 0.04 at 1 % off; v2e's noisy preset 0.04 against 0.07)."""
        if not self._probes:
            return
        deviations = {}
        for key, probe in self._probes.items():
            try:
                _, _, valid, fit, extra = probe._stimulus(deviation=True)
            except EstimationError:  # (a longer period than the stream: that description cannot be compared)
                continue
            deviations[key] = np.where(valid & np.isfinite(fit), extra["deviation"], np.nan)
        if ("given", 1.0) not in deviations:
            return
        usable = np.logical_and.reduce([np.isfinite(values) for values in deviations.values()])
        if usable.sum() < MIN_NEIGHBOURS:
            return  # (too few pixels to compare)
        squares = {key: float(np.median(values[usable])) ** 2 for key, values in deviations.items()}
        given_square = squares[("given", 1.0)]
        if given_square <= DESCRIPTION_MIN_DEVIATION**2:
            return
        s = self.stimulus
        problems = []
        levels = sorted(k for kind, k in squares if kind == "levels")
        if levels:
            scales = sorted([1.0, *levels])
            curve = np.array([given_square if k == 1.0 else squares[("levels", k)] for k in scales])
            best, best_square = _lowest(np.log(scales), curve)
            if best_square < DESCRIPTION_BETTER**2 * given_square:
                low = s.high / (s.high / s.low) ** math.exp(best)
                where = "near" if np.log(scales[0]) < best < np.log(scales[-1]) else "beyond"
                problems.append(f"levels {where} {low:.3g}, {s.high:g} fit them better ({math.sqrt(best_square):.3f}; "
                                f"the thresholds scale with the log ratio of the levels: these would make them about "
                                f"{math.exp(best):.2g} times larger)")
        periods = {factor: square for (kind, factor), square in squares.items() if kind == "period"}
        if periods:
            factor = min(periods, key=periods.get)
            if periods[factor] < DESCRIPTION_BETTER**2 * given_square:
                speed = (f" (a speed near {s.wavelength_px / (s.period_us * factor) * 1e6:.4g} px/s)"
                         if s.wavelength_px else "")
                problems.append(f"a period near {s.period_us * factor / 1e3:.4g} ms{speed} fits them better "
                                f"({math.sqrt(periods[factor]):.3f})")
        rises = {shift: square for (kind, shift), square in squares.items() if kind == "rise"}
        if rises:
            shift = min(rises, key=rises.get)
            if rises[shift] < DESCRIPTION_BETTER**2 * given_square:
                problems.append(f"a rise near {s.rise + shift:.3g} of the period fits them better "
                                f"({math.sqrt(rises[shift]):.3f}; a wrong rise moves ON and OFF apart)")
        if problems:
            timing = ("--stimulus-speed, --stimulus-wavelength (the period: wavelength / speed)" if s.wavelength_px
                      else "--stimulus-period")
            raise DescriptionError(
                f"the events do not fit the described stimulus (levels {s.low:g}, {s.high:g}, period "
                f"{s.period_us / 1e3:.4g} ms, rise {s.rise:g}: median deviation {math.sqrt(given_square):.3f}); "
                f"{'; '.join(problems)}: check --stimulus-levels, {timing}, --stimulus-rise, or give --max-fit inf "
                "to take the estimates as they are")

    def _snapshot(self, t_us: int) -> None:
        """Online: the maps as they stand at ``t_us`` (invalid where nothing is known yet), then every sum decays
        by ``exp(-interval / forget)`` and the stimulus's acceptance windows re-centre on the current means (so
        a threshold may drift beyond the window of its first changes). Before the maps, a stimulus pixel whose
        threshold stepped out of its window is dropped and acquired anew (:meth:`_reacquire`): stale in this map."""
        if self._probes and self.events and (t_us - self.t_first_us
                                             >= DESCRIPTION_CHECK_PERIODS * self.stimulus.period_us):
            self._check_description()  # (online: once, on the stream's first periods; an error stops the series)
            self._probes = {}
        if self.events and self.method == "stimulus":
            self._reacquire()
        if self.events:
            on, off, valid, fit, _ = self._natural() if self.method == "natural" else self._stimulus(final=False)
            valid = valid & (fit <= self.max_fit)
            self._stale &= ~valid
            fit = np.where(self._stale, STALE_FIT, fit)
        else:
            on = off = fit = np.full(self.width * self.height, np.nan)
            valid = np.zeros(self.width * self.height, dtype=bool)
        self._maps.add(t_us, on, off, valid, fit)
        keep = math.exp(-self.interval_us / self.forget_us)
        if self.method == "natural":
            self._counts[:, :COUNT_LAST] *= keep
            return
        state = self._state
        for column in (ST_SUM, ST_PAIRS, ST_SQUARES, ST_ALL):
            state[:, column:column + 2] *= keep
        self._since_map = np.concatenate([state[:, ST_ALL:ST_ALL + 2], state[:, ST_PAIRS:ST_PAIRS + 2]], axis=1)
        seeded = state[:, ST_REF:ST_REF + 2] > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = state[:, ST_SUM:ST_SUM + 2] / state[:, ST_PAIRS:ST_PAIRS + 2]
        state[:, ST_REF:ST_REF + 2] = np.where(seeded & np.isfinite(mean) & (mean > 0), mean,
                                               state[:, ST_REF:ST_REF + 2])

    def _reacquire(self) -> None:
        """A threshold that stepped out of its acceptance window (most of a polarity's recent changes rejected:
        :data:`REACQUIRE_SHARE`) is acquired again: that polarity seeds anew from its next changes, and with fitted
        phases the pixel fits its phase anew too (it was fitted with the old thresholds); the pixel is stale until
        valid again."""
        state = self._state
        changes, accepted = state[:, ST_ALL:ST_ALL + 2], state[:, ST_PAIRS:ST_PAIRS + 2]
        lost = (changes >= REACQUIRE_CHANGES) & (accepted < REACQUIRE_SHARE * changes)
        if self._since_map is not None:  # (the last interval alone: the decayed counts held a step's old values
            recent, recent_accepted = changes - self._since_map[:, :2], accepted - self._since_map[:, 2:]  # valid)
            lost |= (recent >= REACQUIRE_CHANGES) & (recent_accepted < REACQUIRE_SHARE * recent)
        if not lost.any():
            return
        for column in (ST_REF, ST_SUM, ST_PAIRS, ST_SQUARES, ST_ALL):
            state[:, column:column + 2][lost] = 0.0
        pixels = lost.any(axis=1)
        self.reacquired += int(lost.sum())
        self._stale |= pixels
        if self.phase == "fit":
            state[pixels, ST_FITTED] = 0.0
            state[pixels, ST_EVENTS] = 0.0
            self._filled[pixels] = 0

    def flush(self) -> np.ndarray:
        """No events to give back (the estimator consumes the stream); call :meth:`result` for the maps."""
        return empty_events()

    def result(self) -> ThresholdEstimate:
        """The thresholds of every pixel, after the whole stream went through :meth:`process`.

        Raises
        ------
        EstimationError
            On an empty stream, an offE segment longer than the stream, fewer than 3 segments, or when no
            pixel could be estimated.
        """
        if not self.events:
            raise EstimationError("the stream has no events: nothing to estimate thresholds from")
        fit = None
        if self.method == "offe":
            on, off, valid, fit, extra = self._offe(self._pixels[:, OFFE_E] >= self.min_events)
        elif self.method == "natural":
            on, off, valid, fit, extra = self._natural()
        else:
            on, off, valid, fit, extra = self._stimulus()
            fitting = valid & (fit <= self.max_fit)
            if valid.any() and fitting.sum() < MIN_FITTING_SHARE * valid.sum():
                raise EstimationError(
                    f"the events do not fit the described stimulus: {int(fitting.sum())} of {int(valid.sum())} "
                    f"pixels fit within {self.max_fit:g} thresholds (median fit {np.median(fit[valid]):.2f}); check "
                    "the period and the waveform, or the stream shows no calibration stimulus"
                )
            extra["rejected_by_fit"] = int((valid & ~fitting).sum())
            valid = fitting
            self._check_description()
        if not valid.any() and self.on_events in (0, self.events):  # (every method reads both polarities)
            raise EstimationError(
                f"the stream's {self.events:,} events are all {'OFF' if self.on_events == 0 else 'ON'}: the "
                "thresholds are estimated from both polarities (was --polarity given?)")
        if not valid.any() and self.method == "natural":
            per_pixel = self.events / (self.width * self.height)
            span_us = max(self.t_last_us - self.t_first_us, 1)
            if self.interval_us is not None and self.forget_us < span_us:  # online: what the sums remember
                remembered = per_pixel * self.forget_us / span_us
                advice = (f"online, the sums forget over {self.forget_us / 1e6:.3g} s, which holds about "
                          f"{remembered:.1f} of them: give a longer --forget (or --interval: it is 3 intervals by "
                          "default)")
            else:
                advice = (f"give a longer recording (hundreds of events per pixel)"
                          f"{' or lower --min-events' if self.min_events > 1 else ''}")
            raise EstimationError(
                f"no pixel could be estimated by natural: none has {self.min_events} "
                f"event{'s' if self.min_events != 1 else ''} of each polarity, "
                f"{MIN_NEIGHBOURS} or more neighbours that do, a threshold within {MAX_RELATIVE:g} times theirs and "
                f"a fit within {self.max_fit:g} ({per_pixel:.1f} events per pixel on average); {advice}"
            )
        if not valid.any() and self.method == "offe" and extra.get("rejected_by_fit"):
            raise EstimationError(
                f"no offe estimate fits within {self.max_fit:g}: {extra['rejected_by_fit']:,} pixels' fits are above "
                f"it (offE's line through {extra['segments']} segments alone leaves a median error of "
                f"{extra['sampling_error_median']:.2f}); give a shorter --segment-us (the reference samples at "
                "20-25 Hz), a longer stream, or --max-fit inf to take the estimates unchecked")
        if not valid.any() and extra.get("unchecked"):
            raise EstimationError(
                f"none of offe's {extra['unchecked']:,} estimates could be checked: its fit compares each pixel with "
                "the natural method's estimate, which found no pixel whose neighbours share its excursion (a scene "
                "not every pixel sees alike, or too few events); give --max-fit inf to take them unchecked, or use "
                "--method stimulus with a known stimulus")
        if not valid.any():
            raise EstimationError(
                f"no pixel could be estimated by {self.method} (fewer than {self.min_events} events or no usable "
                "pair of events everywhere): give a longer calibration stream"
                f"{' or lower --min-events' if self.min_events > 1 else ''}"
            )
        if self.method in ("offe", "natural") and math.isfinite(self.max_fit):  # (max_fit inf: unchecked)
            self._check_scene()  # (after the methods' own refusals: too few events is said as such)
        on_median = float(np.median(on[valid]))
        off_median = float(np.median(off[valid]))
        on = np.where(valid, on, on_median).astype(np.float32).reshape(self.height, self.width)
        off = np.where(valid, off, off_median).astype(np.float32).reshape(self.height, self.width)
        attributes = {
            **self.parameters, **extra,
            "events": int(self.events), "width": self.width, "height": self.height,
            "t_first_us": int(self.t_first_us), "t_last_us": int(self.t_last_us),
            "valid_pixels": int(valid.sum()), "on_median": on_median, "off_median": off_median,
            "scale": SCALES[self.method],
        }
        if self.method != "stimulus":
            attributes["not_observable"] = NOT_OBSERVABLE
            balance = on_median / off_median
            if not 1 / POLARITY_BALANCE <= balance <= POLARITY_BALANCE:
                attributes["polarity_balance"] = (
                    f"the ON thresholds come out {balance:.2g} times the OFF ones (medians {on_median:.3g} and "
                    f"{off_median:.3g}): events alone cannot tell the pixels' ON / OFF balance from a scene that "
                    f"ends {'brighter' if balance < 1 else 'darker'} than it began, which reads so; a corrected "
                    "stream's ON / OFF ratio follows this map (give a stimulus or frames for the balance)")
        if fit is not None:
            fit = fit.astype(np.float32).reshape(self.height, self.width)
            compared = fit[valid.reshape(fit.shape) & np.isfinite(fit)]
            if compared.size:
                attributes["fit_median"] = float(np.median(compared))
        phase_us = None
        if self.method == "stimulus" and self.phase == "fit":
            fitted = self._state[:, ST_FITTED] > 0
            phase_us = np.where(fitted, self._state[:, ST_PHASE], np.nan)
            phase_us = phase_us.reshape(self.height, self.width)
        series = None
        if self.interval_us is not None:
            self._maps.add_final(self.t_last_us + 1, on, off, valid, np.full(on.shape, np.nan) if fit is None else fit)
            series = self._maps.series()
            attributes["maps"] = self._maps.count
            if self.method == "stimulus":
                attributes["reacquired"] = self.reacquired
        return ThresholdEstimate(on, off, valid.reshape(self.height, self.width), attributes, fit, phase_us, series)

    def maps_so_far(self) -> ThresholdSeries | None:
        """Online: the maps held so far (each complete at its time), or None before the first or when they went to
        a ``map_sink``; what is left of a run that stops midway (an error in the stream)."""
        return None if self._maps is None else self._maps.series()

    def finish(self) -> ThresholdEstimate:
        """Alias of :meth:`result`."""
        return self.result()

    # -- the methods' final step: sums to thresholds ---------------------------------------------------------

    def _offe(self, enough):
        span_us = self.t_last_us - self.t_first_us
        if span_us < self.segment_us:
            raise EstimationError(
                f"the segment ({self.segment_us} us) is longer than the stream ({span_us} us): give a shorter "
                "--segment-us"
            )
        if not self._finished:
            offe_finish(self._pixels, self._clock)
            self._finished = True
        k = float(self._clock[OFFE_SAMPLES])
        if k < 3:
            raise EstimationError(
                f"only {int(k)} segments: offE fits a line through each pixel's samples and needs at least 3; give "
                "a shorter --segment-us or a longer stream"
            )
        m, r, fitted = offe_fit(self._pixels[:, OFFE_SUMS_AT:OFFE_SUMS_AT + 5].T, k)
        valid = enough & fitted & (r > 0)
        extra = {"segments": int(k)}
        if not valid.any():
            return m, m, valid, np.full(m.shape, np.nan), extra
        with np.errstate(divide="ignore", invalid="ignore"):
            c = np.median(self.nominal * r[valid]) / r
        valid &= np.isfinite(c) & (c <= MAX_SCALE_FACTOR * self.nominal)
        c = np.where(valid, c, 0.0)
        b = -c * m
        on, off = c + b, c - b
        # the fit: offE's assumption (every pixel sees the same log-intensity variance) cannot be checked from a
        # pixel's own events, so it is checked against the natural method's estimate from the same events, where
        # that one is valid (:func:`_offe_fit`)
        natural_on, natural_off, natural_valid, natural_fit, _ = self._natural(DEFAULT_MAX_ERROR)
        sampling = _offe_sampling_error(self._pixels[:, OFFE_SUMS_AT:OFFE_SUMS_AT + 5].T, k, m, r)
        with np.errstate(divide="ignore", invalid="ignore"):
            disagreement = np.stack([2 * (on - natural_on) / (on + natural_on),
                                     2 * (off - natural_off) / (off + natural_off)])
            fit = np.where(valid & natural_valid,
                           _offe_fit(np.sqrt(np.mean(disagreement**2, axis=0)), np.fmax(natural_fit, sampling)),
                           np.nan)
        extra["sampling_error_median"] = float(np.median(sampling[valid])) if valid.any() else float("nan")
        # NaN (no natural estimate to compare with): not checked, not valid, unless no check is asked (max_fit inf)
        fitting = valid if np.isinf(self.max_fit) else valid & (fit <= self.max_fit)
        extra["rejected_by_fit"] = int((valid & np.isfinite(fit) & ~fitting).sum())
        extra["unchecked"] = int((valid & ~np.isfinite(fit)).sum())
        extra["fit_compared"] = int(np.isfinite(fit).sum())
        return on, off, fitting, fit, extra

    def _natural(self, max_fit: float | None = None):
        """The natural method's maps from the counts so far (docs/algorithms.md section 4): (on, off, valid, fit,
        extra), pixels flattened; ``max_fit`` defaults to the estimator's (offE's fit asks with natural's own)."""
        max_fit = self.max_fit if max_fit is None else max_fit
        # (the sums, minima and means over the two halves and two polarities are written out: numpy's reductions
        # over an axis of 2 cost 10x an addition, 0.2 s on a Gen4 sensor's 921,600 pixels; same floats)
        # (float64 one half at a time: the counts are float32, exact; a Gen4 sensor's both halves are 44 MB)
        counts = self._counts[:, :6].reshape(self.height, self.width, 2, 3)  # [y, x, half, k]
        whole = counts[:, :, 0].astype(np.float64) + counts[:, :, 1]
        enough = (whole[..., 0] >= self.min_events) & (whole[..., 1] >= self.min_events)
        inverse = _effective_inverse(whole)
        relative, neighbours = _relative_to_neighbours(inverse, enough, self.radius_px)
        halves = []
        for h in (0, 1):
            half = counts[:, :, h].astype(np.float64)
            usable = enough & (half[..., 0] > 0) & (half[..., 1] > 0)
            halves.append(_relative_to_neighbours(_effective_inverse(half), usable, self.radius_px)[0])
            del half
        with np.errstate(divide="ignore", invalid="ignore"):
            squares = ((halves[0] - halves[1]) / (halves[0] + halves[1]))**2
            halves_error = np.sqrt((squares[..., 0] + squares[..., 1]) / 2)
            counting = 1.0 / np.sqrt(np.minimum(whole[..., 0], whole[..., 1]))
            gradient = _excitation_gradient(inverse, enough, max(self.radius_px, GRADIENT_RADIUS_PX))
            scene = _scene_error(inverse, enough, self.radius_px)
            # the counting error of the rarer polarity (a floor: halves of a pixel with few events agree by
            # chance); neighbours that do not share the excursion: a contrast edge or a region's border (the
            # window's opposite halves disagree), and a texture each neighbour sees its own patch of (the scene
            # error, from the map's spatial autocovariance). Each is about the relative error it gives; the
            # largest stands for them (measured the most predictive of the true error, issue 36)
            fit = np.maximum(np.maximum(halves_error, counting), scene)
            fit = np.where(np.isnan(gradient), fit, np.maximum(fit, gradient))  # (a NaN fit stays NaN)
        fit = np.where(enough & (neighbours >= MIN_NEIGHBOURS), fit, np.nan)
        with np.errstate(invalid="ignore"):  # (a pixel its neighbours fire a tenth as often as: a hot or flickering
            plausible = np.all((relative >= 1 / MAX_RELATIVE) & (relative <= MAX_RELATIVE), axis=-1)  # pixel)
        valid = np.isfinite(fit) & (fit <= max_fit) & plausible
        extra = {"scene_error": scene, "rejected_by_neighbours": int((enough & (neighbours < MIN_NEIGHBOURS)).sum()),
                 "rejected_by_fit": int((np.isfinite(fit) & (fit > max_fit)).sum()),
                 "rejected_as_implausible": int((np.isfinite(fit) & (fit <= max_fit) & ~plausible).sum())}
        on = np.where(valid, self.nominal * relative[..., 0], 0.0)
        off = np.where(valid, self.nominal * relative[..., 1], 0.0)
        return on.ravel(), off.ravel(), valid.ravel(), fit.ravel(), extra

    def _stimulus(self, final: bool = True, deviation: bool = False):
        span_us = self.t_last_us - self.t_first_us
        if final and span_us < self.stimulus.period_us:  # (44 % of the pixels were "estimated" from 1 s of a 1.28 s
            raise EstimationError(  # stimulus: from a part of one rise or fall, levels the stimulus never repeats)
                f"the stream ({span_us / 1e6:.3g} s) is shorter than one stimulus period "
                f"({self.stimulus.period_us / 1e6:.3g} s): every pixel must see the whole stimulus at least once; "
                "give the period the recording shows (--stimulus-period) or a longer recording")
        if final and self.phase == "fit" and not self._finished:
            stimulus_fitted_finish(float(self.stimulus.period_us), float(self.stimulus.rise), self._wave,
                                   self._state, self._seeds, self._ring, self._filled)
            self._ring = self._filled = None  # the rings are replayed: free their memory
        if final:
            self._finished = True
        enough = self._state[:, ST_SEEN if self.phase == "fit" else ST_EVENTS] >= self.min_events
        references = self._state[:, ST_REF:ST_REF + 2].T
        level_sums = self._state[:, ST_SUM:ST_SUM + 2].T.copy()
        squares = self._state[:, ST_SQUARES:ST_SQUARES + 2].T.copy()
        pairs = self._state[:, ST_PAIRS:ST_PAIRS + 2].T.copy()
        changes = self._state[:, ST_ALL:ST_ALL + 2].T
        # a polarity with fewer than SEED_PAIRS changes (reference still -count): the median of those it has
        few = references <= 0
        medians = None
        if few.any():
            counts = -references[few]
            seeds = self._seeds.transpose(1, 0, 2)[few]
            seeds = np.where(np.arange(SEED_PAIRS) < counts[:, None], seeds, np.nan)
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                medians = np.nanmedian(seeds, axis=-1)
            level_sums[few] = np.nansum(seeds, axis=-1)
            squares[few] = np.nansum(seeds * seeds, axis=-1)
            pairs[few] = counts
        valid = enough & (pairs[0] > 0) & (pairs[1] > 0)
        extra = {}
        with np.errstate(divide="ignore", invalid="ignore"):
            thresholds = level_sums / pairs
            if medians is not None:
                thresholds[few] = np.nan_to_num(medians)
            # squared deviations of the accepted changes from the threshold, in thresholds, plus one per change
            # that did not fit (outside the window or the wrong sign)
            deviations = (squares - 2 * thresholds * level_sums + pairs * thresholds**2) / thresholds**2
            accepted = np.where(pairs > 0, np.maximum(deviations, 0.0), 0.0)
            fit = np.sqrt((accepted + (changes - pairs)).sum(axis=0) / changes.sum(axis=0))
            if deviation:  # the accepted changes' part alone (the description check: misfits are mostly noise)
                extra["deviation"] = np.sqrt(accepted.sum(axis=0) / pairs.sum(axis=0))
        fit[changes.sum(axis=0) < FIT_MIN_CHANGES] = np.inf  # too few changes to show a fit
        return thresholds[0], thresholds[1], valid, fit, extra


_SCENE_THREAD: ThreadPoolExecutor | None = None


def _scene_thread() -> ThreadPoolExecutor:
    """The one worker thread the scene check runs on beside the methods' counting (made on first use)."""
    global _SCENE_THREAD
    if _SCENE_THREAD is None:
        _SCENE_THREAD = ThreadPoolExecutor(1, thread_name_prefix="evtools-scene")
    return _SCENE_THREAD


def _lowest(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Where the sampled curve ``y(x)`` (x increasing, evenly spaced) is lowest: the parabola through its lowest
    sample and their neighbours, its vertex kept within a step (the lowest sample itself at either end)."""
    lowest = int(np.argmin(y))
    if not 0 < lowest < len(y) - 1:
        return float(x[lowest]), float(y[lowest])
    step = float(x[lowest + 1] - x[lowest])
    below, at, above = y[lowest - 1:lowest + 2]
    curvature = (below + above - 2 * at) / (2 * step**2)
    slope = (above - below) / (2 * step)
    if curvature <= 0:
        return float(x[lowest]), float(at)
    offset = min(max(-slope / (2 * curvature), -step), step)
    return float(x[lowest] + offset), max(float(at + slope * offset + curvature * offset**2), 0.0)


def _effective_inverse(counts: np.ndarray) -> np.ndarray:
    """Per pixel, (u_on, u_off) with ``theta = D * u``: the thresholds up to the pixel's total log-intensity
    excursion D, from its (ON events, OFF events, reversals) in ``counts[..., 0:3]``.

    A pixel's rises sum to ``D = theta_on N_on + b (theta_on + theta_off)`` and its falls likewise with N_off
    (the log intensity ends about where it began): at each turn the signal goes on past the last event by half a
    threshold on average, and the first event after the turn needs a whole threshold from that last event, so
    each rising run loses (theta_on + theta_off) / 2 of its rise to no event, and the runs of each kind are half
    the reversals: ``b = reversals / 4``. Solving the two equations gives u. Without the turns' share, a
    pixel's counts fall faster than 1 / theta (as theta^-1.28 on the texture scene) and the thresholds' spread
    comes out too wide."""
    n_on, n_off, b = counts[..., 0], counts[..., 1], counts[..., 2] / 4.0
    with np.errstate(divide="ignore", invalid="ignore"):
        det = (n_on + b) * (n_off + b) - b * b
        return np.stack([n_off / det, n_on / det], axis=-1)


def _relative_to_neighbours(inverse: np.ndarray, usable: np.ndarray, radius_px: int):
    """Per pixel (``inverse``: height x width x 2, the (u_on, u_off) of :func:`_effective_inverse`), its
    thresholds relative to its usable neighbours': ``2 u / mean(u_on + u_off over the neighbours)`` (mean
    threshold 1), and the number of those neighbours (the window of ``radius_px`` around it, itself left out).

    Neighbours see nearly the same log-intensity history as edges pass over them, so they share the excursion D
    of ``theta = D u``, and the mean threshold over the window sets D. The window leaves the pixel out, so its
    own counts do not pull its reference."""
    neighbours = _around(usable.astype(np.float64), radius_px)
    total = np.where(usable, inverse[..., 0] + inverse[..., 1], 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = _around(total, radius_px) / neighbours
        relative = np.where(usable[..., None], 2.0 * inverse / mean[..., None], np.nan)
    return relative, np.round(neighbours)


def _offe_sampling_error(sums: np.ndarray, k: float, m: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Per pixel, the relative error that offE's line through only ``k`` samples leaves: the larger of the RMS
    residual's (``r`` sets the threshold scale; its sampling error with k - 2 degrees of freedom is
    ``1 / sqrt(2 (k - 2))``) and the slope's standard error ``se(m)`` (``m`` splits the scale into ON and OFF:
    ``on = c (1 - m)``, ``off = c (1 + m)``), relative to the smaller of ``1 -+ m``. Three to five segments of a
    flicker called 84-95 % of the pixels valid with 97-100 % of them more than 10 % off (ON +16 %, OFF -14 %: a
    QA sweep); the default 10 ms segments of a 2 s stream leave 0.05."""
    s_e, s_ee = (sums[j].astype(np.float64) for j in (SUM_E, SUM_EE))
    spread = k * s_ee - s_e * s_e  # k * sum (E - mean E)^2
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.sqrt(r * r * k / (k - 2) * k / spread) / np.maximum(1 - np.abs(m), 1e-3)
    return np.fmax(np.sqrt(1 / (2 * (k - 2))), np.where(np.isfinite(slope), slope, np.inf))


def _offe_fit(disagreement: np.ndarray, natural_fit: np.ndarray) -> np.ndarray:
    """offE's fit where the natural estimate of the same events is valid: the larger of their relative disagreement
    and natural's own fit. The disagreement alone was optimistic: both methods count the same events, so they err
    together and agree where both are off (on issue 36's moving textures, independent generator, the RMS of offE's
    largest relative error over the disagreement was 1.1-2.7 over fitted pixels, 2.3-3.9 over valid ones; between two
    halves of the real DVS128 walk, the halves' difference over the disagreements 1.16-1.19, 8 % past two). Natural's
    fit (at least its counting error) is the floor of that shared error: with it 0.8-1.25 over valid pixels
    (samples/natural.md) and 0.67-0.69 on the walk, at most 7 % past two fits; the valid pixels are the same at the
    default ``max_fit`` (natural's fit is within it where natural is valid). On a flicker, where offE's assumption
    holds and its error is 2 %, the floor is conservative (0.12: natural's counting error takes a flicker's regular
    events for random ones)."""
    return np.fmax(disagreement, natural_fit)


def check_series_room(maps: int, width: int, height: int, interval_us: int, t_us: int) -> None:
    """An error when ``maps`` online maps of ``width x height`` (on, off, fit as float32, valid: 13 bytes a pixel, as
    they are held and written) would pass :data:`MAX_SERIES_BYTES` (a run was once killed for memory, with no
    message)."""
    if maps * 13 * width * height > MAX_SERIES_BYTES:
        raise EstimationError(
            f"online maps every {interval_us:,} us: {maps:,} maps of {width}x{height} would take more than "
            f"{MAX_SERIES_BYTES / 2**30:.0f} GiB by {t_us:,} us; give a longer interval, or a map_sink to take them "
            "as they come")


def _series_of(maps: list) -> ThresholdSeries:
    """The online maps (time, on, off, valid, fit each) as one :class:`ThresholdSeries`."""
    return ThresholdSeries(np.array([m[0] for m in maps], dtype=np.int64),
                           *(np.stack([m[k] for m in maps]).astype(np.float32) for k in (1, 2)),
                           np.stack([m[3] for m in maps]), np.stack([m[4] for m in maps]).astype(np.float32))


class OnlineMaps:
    """An online estimator's maps as they are made: held (for :meth:`series`; at most :data:`MAX_SERIES_BYTES`,
    :func:`check_series_room`) or, with ``sink``, passed on at once as ``sink(t_us, on, off, valid, fit)`` (height
    x width each: float32 with NaN where not valid, bool) and not kept, so a run's length is bounded by where they
    go, not by memory (the command line writes them to the file as they come). The final map (the estimate at the
    stream's end) is added once, however often the estimate is asked for."""

    def __init__(self, width: int, height: int, interval_us: int, sink=None) -> None:
        self.width, self.height, self.interval_us, self.sink = width, height, interval_us, sink
        self.held: list[tuple] = []
        self.count = 0  # maps made, held or passed on
        self.finished = False  # the final map is in

    def add(self, t_us: int, on, off, valid, fit) -> None:
        """Map ``t_us`` (each array height x width or flattened; ``on`` and ``off`` become NaN where not
        ``valid``)."""
        shape = (self.height, self.width)
        valid = np.asarray(valid, dtype=bool).reshape(shape)
        entry = (int(t_us), np.where(valid, np.reshape(on, shape), np.nan).astype(np.float32),
                 np.where(valid, np.reshape(off, shape), np.nan).astype(np.float32), valid,
                 np.asarray(fit, dtype=np.float32).reshape(shape))
        if self.sink is not None:
            self.sink(*entry)
        else:
            check_series_room(len(self.held) + 1, self.width, self.height, self.interval_us, t_us)
            self.held.append(entry)
        self.count += 1

    def add_final(self, t_us: int, on, off, valid, fit) -> None:
        """The map at the stream's end, added the first time only."""
        if not self.finished:
            self.add(t_us, on, off, valid, fit)
            self.finished = True

    def series(self) -> ThresholdSeries | None:
        """The maps held (None with a sink, or before the first)."""
        return _series_of(self.held) if self.held else None


def _excitation_gradient(inverse: np.ndarray, usable: np.ndarray, radius_px: int) -> np.ndarray:
    """Per pixel, how much the excitation differs across its window: the larger of ``|a - b| / (a + b)`` for the
    means ``a``, ``b`` of the usable neighbours' ``u_on + u_off`` (:func:`_effective_inverse`) in the window's
    left and right halves, and in its top and bottom halves (NaN where a half has none). Where neighbours share
    the excursion (the natural method's assumption) only the thresholds' own spread shows, a few per cent over
    21 pixels a half; at a contrast edge a pixel on one side is off from the window's mean by about this much."""
    total = np.where(usable, inverse[..., 0] + inverse[..., 1], 0.0)
    weight = usable.astype(np.float64)
    r = radius_px
    sums = [_integral(total), _integral(weight)]

    def mean(x0, x1, y0, y1):
        values, counts = (_rectangle_sum(table, x0, x1, y0, y1) for table in sums)
        return values / counts

    with np.errstate(divide="ignore", invalid="ignore"):
        left, right = mean(-r, -1, -r, r), mean(1, r, -r, r)
        top, bottom = mean(-r, r, -r, -1), mean(-r, r, 1, r)
        return np.fmax(np.abs(left - right) / (left + right), np.abs(top - bottom) / (top + bottom))


def _scene_error(inverse: np.ndarray, usable: np.ndarray, radius_px: int) -> float:
    """The relative error that the neighbours' differing excursions give a pixel's estimate: the RMS of
    ``log D_i - mean_j log D_j`` over the window, predicted from the spatial autocovariance of the map's
    ``z = -log(u_on + u_off)`` (:func:`_effective_inverse`).

    ``z`` is the log excursion ``s`` less the log threshold plus counting noise; the thresholds and the counting
    are independent from pixel to pixel, so beyond lag 0 the autocovariance ``C(d)`` is the excursion's alone.
    Its value at 0 is extrapolated from the lags within 2 pixels (``C(d) = c0 - a d^2``, a smooth field), the
    rest of ``C(0)`` is the pixels' own (thresholds and counting, ``w``). Then for the mean over the window's
    ``N`` pixels: ``E[(s_i - mean s_j)^2] = c0 - 2 mean C(d_ij) + mean C(d_jk)``, and their own parts add
    ``w / N``. Lags beyond :data:`SCENE_MAX_LAG_PX` count as uncorrelated. 0 where fewer than 16 pixels are
    usable."""
    if usable.sum() < 16:
        return 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        z = -np.log(inverse[..., 0] + inverse[..., 1])
    z = np.where(usable, z - z[usable].mean(), 0.0)
    weight = usable.astype(np.float64)
    height, width = z.shape
    reach = min(2 * radius_px, SCENE_MAX_LAG_PX)
    covariance = np.zeros((2 * reach + 1, 2 * reach + 1))  # [dy + reach, dx + reach]
    for dy in range(0, min(reach, height - 1) + 1):
        for dx in range(-min(reach, width - 1), min(reach, width - 1) + 1):
            if dy == 0 and dx < 0:
                continue
            x0, x1 = max(0, -dx), width - max(0, dx)
            pairs = (weight[:height - dy, x0:x1] * weight[dy:, x0 + dx:x1 + dx]).sum()
            if pairs > 0:
                value = (z[:height - dy, x0:x1] * z[dy:, x0 + dx:x1 + dx]).sum() / pairs
                covariance[reach + dy, reach + dx] = covariance[reach - dy, reach - dx] = value
    lags_y, lags_x = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    squared = lags_x**2 + lags_y**2
    near = (squared > 0) & (squared <= 4)
    _, c0 = np.polyfit(squared[near], covariance[near], 1)  # (the slope: how fast the scene decorrelates)
    whole = covariance[reach, reach]
    c0 = min(max(c0, covariance[reach, reach + 1]), whole)
    own = whole - c0
    covariance[reach, reach] = c0
    side = 2 * radius_px + 1
    n = side * side - 1
    in_window = (np.abs(lags_x) <= radius_px) & (np.abs(lags_y) <= radius_px) & (squared > 0)
    to_pixel = covariance[in_window].sum() / n
    # pairs of window pixels (the centre left out) at each lag: the full square's less those with the centre
    pairs_at = np.clip(side - np.abs(lags_x), 0, None) * np.clip(side - np.abs(lags_y), 0, None) - 2.0 * in_window
    pairs_at[reach, reach] = 0
    among = ((covariance * pairs_at).sum() + n * c0) / n**2
    return float(np.sqrt(max(c0 - 2 * to_pixel + among, 0.0) + own / n))


def _integral(values: np.ndarray) -> np.ndarray:
    """The summed-area table of ``values`` (2-D): ``table[i, j]`` is the sum of ``values[:i, :j]``."""
    table = np.zeros((values.shape[0] + 1, values.shape[1] + 1))
    np.cumsum(np.cumsum(values, axis=0), axis=1, out=table[1:, 1:])
    return table


def _rectangle_sum(table: np.ndarray, x0: int, x1: int, y0: int, y1: int) -> np.ndarray:
    """Per pixel (x, y), the sum of the values at ``[x + x0, x + x1] x [y + y0, y + y1]`` inside the sensor, from
    the summed-area ``table`` (:func:`_integral`): four lookups a pixel whatever the rectangle's size."""
    height, width = table.shape[0] - 1, table.shape[1] - 1
    columns, rows = np.arange(width), np.arange(height)
    c, d = np.clip(columns + x0, 0, width), np.clip(columns + x1 + 1, 0, width)
    a, b = np.clip(rows + y0, 0, height)[:, None], np.clip(rows + y1 + 1, 0, height)[:, None]
    return table[b, d] - table[a, d] - table[b, c] + table[a, c]


def _around(values: np.ndarray, radius_px: int) -> np.ndarray:
    """The sum of ``values`` (2-D) over the square window of ``radius_px`` around each pixel, the pixel itself
    left out and nothing counted outside the sensor: a box sum, row by row then column by column."""
    height, width = values.shape
    padded = np.zeros((height + 2 * radius_px, width + 2 * radius_px))
    padded[radius_px:radius_px + height, radius_px:radius_px + width] = values
    rows = padded[:, :width].copy()
    for dx in range(1, 2 * radius_px + 1):  # in place: one array, not one per term (Gen4: 7 MB each)
        rows += padded[:, dx:dx + width]
    window = rows[:height].copy()
    for dy in range(1, 2 * radius_px + 1):
        window += rows[dy:dy + height]
    window -= values
    return window


def _aligned_zeros(rows: int, columns: int, dtype) -> np.ndarray:
    """A zeroed (rows, columns) array whose rows start on 64-byte boundaries when a row is 16 or 64 bytes, so
    that a pixel's state never straddles two cache lines."""
    itemsize = np.dtype(dtype).itemsize
    spare = 64 // itemsize
    buffer = np.zeros(rows * columns + spare, dtype=dtype)
    start = (-buffer.ctypes.data % 64) // itemsize
    return buffer[start:start + rows * columns].reshape(rows, columns)


def offe_fit(sums: np.ndarray, k: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slope m, RMS residual r and fit success of ``P = m E + d`` per pixel, from the sums over k samples.

    The normal matrix is ``[[sum E^2, sum E], [sum E, k]]``; its 1-norm reciprocal condition number is
    ``det / norm1^2`` (2 x 2 symmetric: the adjugate has the same 1-norm), as MATLAB's ``rcond`` in the reference.
    The arithmetic is exact on integers (the residual is a difference of near-equal products), floats at the end:
    in int64 for the pixels whose every intermediate stays below 2^53 (so each conversion to float is exact and
    each quotient correctly rounded, as Python's integer division is), in Python integers for the others (the
    products overflow int64 on long streams). The int64 path made the fit of a Gen4 sensor's 921,600 pixels 0.62 s
    -> 0.08 s alone, 0.13-0.16 s inside `estimate` (Python integers for all of them before).
    """
    k = int(k)
    columns = [sums[j] for j in (SUM_E, SUM_P, SUM_EE, SUM_EP, SUM_PP)]
    s_e, s_p, s_ee, s_ep, s_pp = (np.abs(column.astype(np.float64)) for column in columns)
    det_bound, cov_bound, var_bound = k * s_ee + s_e * s_e, k * s_ep + s_e * s_p, k * s_pp + s_p * s_p
    bound = np.maximum(np.maximum(var_bound * det_bound + cov_bound * cov_bound, det_bound * k * k), s_ee + k)
    small = bound < 2.0**52  # the bounds are floats: a factor 2 to spare for their rounding
    m, r, fitted = np.zeros(len(s_e)), np.zeros(len(s_e)), np.zeros(len(s_e), dtype=bool)
    for rows, kind in ((small, np.int64), (~small, object)):
        if rows.any():
            m[rows], r[rows], fitted[rows] = _offe_fit_exact([column[rows].astype(kind) for column in columns], k)
    return m, r, fitted


def _offe_fit_exact(columns: list[np.ndarray], k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`offe_fit` on the sums (E, P, EE, EP, PP) as integers that do not overflow (int64 below 2^53, or
    Python integers)."""
    s_e, s_p, s_ee, s_ep, s_pp = columns
    det = k * s_ee - s_e * s_e  # k^2 var(E)
    cov = k * s_ep - s_e * s_p  # k^2 cov(E, P)
    var_p = k * s_pp - s_p * s_p  # k^2 var(P)
    det_f = det.astype(np.float64)
    norm1 = np.maximum(s_ee + np.abs(s_e), k + np.abs(s_e)).astype(np.float64)
    fitted = det_f > RCOND_LIMIT * norm1 * norm1
    safe = np.where(fitted, det, 1)
    m = np.where(fitted, (cov / safe).astype(np.float64), 0.0)
    # mean squared residual of the best line: var(P) - cov(E, P)^2 / var(E)
    mse = ((var_p * safe - cov * cov) / (safe * k * k)).astype(np.float64)
    r = np.sqrt(np.maximum(np.where(fitted, mse, 0.0), 0.0))
    return m, r, fitted


def estimate_thresholds(events: np.ndarray, width: int, height: int, method: str = "offe", **parameters):
    """Estimate the thresholds of one whole (short) stream: :class:`ThresholdEstimator` ``process`` then ``result``.

    Parameters are those of :class:`ThresholdEstimator`; returns a :class:`ThresholdEstimate`.
    """
    estimator = ThresholdEstimator(width, height, method, **parameters)
    estimator.process(events)
    return estimator.result()
