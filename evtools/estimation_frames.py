"""``estimate --method frames``: each pixel's ON and OFF thresholds on the absolute log scale from its events and
the APS frames of a DAVIS recording (Wang, Ng, van Goor, Mahony, "Event camera calibration of per-pixel biased
contrast threshold", ACRA 2019: offEI offline, onEI online with ``--online``).

The model. A pixel's events move its reference level by its thresholds: after ``A`` ON and ``B`` OFF events the
reference is ``R = c + theta_on A - theta_off B`` (``c`` the pixel's own unknown offset, its gain's log included),
and its log intensity ``L`` lies strictly between ``R - theta_off`` and ``R + theta_on`` (else it would have fired).
A frame measures ``L`` up to noise: ``y = log(DN - black) - log(exposure)``, against ``A`` and ``B`` counted at the
exposure's middle. Facts that shape the fit:

- A frame integrates intensity over its exposure: a pixel's frame is used only when the pixel fired at most
  :data:`MAX_EXPOSURE_EVENTS` times during the exposure (its intensity then moved by about a threshold at most);
  dark values (under :data:`MIN_SIGNAL_DN` above black) and saturated ones (:data:`SATURATED_DN` and up) are not
  used.
- The remainder ``L - R`` lies in one band of the lattice. Its mean given the last event's polarity is not the
  half threshold a ramp would give: on moving textures (an independent generator and evtools' simulator alike)
  the plain least squares of ``y`` on the counts is within 1-2 % with the true log intensity, and adding half a
  threshold after each event's polarity biased it by -17 to -20 %; so the counts enter as they are.
- The black level matters most: 8 DN wrong makes the thresholds 26-30 % wrong on 40 DN signals. It is 0 unless
  given (DV's DAVIS frames are black-subtracted); ``fit`` estimates it, approximately.

Each pixel's least squares (sums accumulated frame by frame: O(pixels) memory) gives the thresholds, the residual
RMS and the standard errors; frames between which the pixel did not fire share one remainder, so the errors are
scaled by ``sqrt(frames / frames with a new count)``, and a pixel's own unknown offset (:data:`OFFSET_FPN_DN`) adds
its bias. The ``fit`` map is the larger relative error of ON and OFF, a standard deviation: it predicts the
estimate's error. A pixel is invalid when it has fewer than :data:`MIN_FRAMES` usable frames, fewer than
``min_events`` events or events of one polarity only, mostly saturated frames, a fit above ``max_fit``, or residuals
more than :data:`MAX_RESIDUAL_RATIO` times what the model allows (its events and frames disagree: a hot pixel, a
frame stream of another time base); the reasons are counted in the attributes, and when the median pixel's residuals
are that large the estimate says the events and frames disagree as a whole.

Also here: :class:`SharedTrend` (onEI's maps freed of their lag behind a drift shared by all pixels) and
:class:`FrameScaledEstimator` (``--nominal frames``: the events-only methods on the frames' absolute scale).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from typing import Any

import numpy as np

from evtools._kernels.estimate import (FRAMES_OFF, FRAMES_ON, FRAMES_ROW, TIME_SUMS, count_times, exposure_counts,
                                       fold_runs, frame_sums, log_levels, polarity_counts)
from evtools.estimation import DEFAULT_MIN_EVENTS, EstimationError, OnlineMaps, ThresholdEstimate
from evtools.events import StreamChecker, StreamInfo, as_chunk, empty_events

MIN_SIGNAL_DN = 8.0
"""A frame's pixel this close to the black level is dark: its log is dominated by read noise."""
SATURATED_DN = 250
"""A frame's pixel at or above this DN is saturated (8-bit frames clip at 255)."""
MAX_EXPOSURE_EVENTS = 1
"""A pixel's frame is used when it fired at most this often during the exposure (its intensity then moved by at most
about a threshold while the frame integrated it)."""
MIN_FRAMES = 12
"""Fewer usable frames than this leave a pixel invalid."""
DEFAULT_MAX_FRAME_FIT = 0.035
"""Pixels whose predicted relative error (a standard deviation: on textures the RMS of error / fit is 0.80-0.98,
slightly pessimistic) is larger are invalid (``--max-fit``): a 10 % error is then 2.86 of them, so a valid pixel at
the limit is more than 10 % off, in the worse of ON and OFF, with a probability under 1 %."""
MAX_RESIDUAL_RATIO = 2.0
"""A pixel whose residual RMS exceeds this many times the model's (the remainder's spread, a band of one threshold:
``theta / sqrt(12)``, and the frames' noise) does not fit the model: invalid. When the median pixel's does, the
estimate says that events and frames disagree (``disagreement``; measured on the independent generator: median
1.5x with the frames on the events' clock, 1.85x 20 ms off, 8-13x 0.1-2 s off)."""
OFFSET_FPN_DN = 1.0
"""A pixel's offset from the black level assumed in its fit (DN, typical): with frames of signal s it biases the
thresholds by about ``OFFSET_FPN_DN`` times the mean of ``1 / s`` over its frames (measured on textures with 1 DN
offsets: most of the error at 40 DN)."""
READ_NOISE_DN = 2.0
"""The frames' noise assumed when judging residuals (DN, standard deviation)."""
DEFAULT_BLACK_LEVEL = 0.0
"""The frames' DN of no light assumed unless given: DV's DAVIS frames are black-subtracted (correlated double
sampling), their darkest pixels read 0."""
BLACK_LEVELS = tuple(float(level) for level in range(0, 44, 4))
"""Black levels tried when fitted (DN)."""
FRAMES_FLOOR_DN = 8.0
"""The black level not said (``--black-level`` not given): a first frame whose darkest 0.1 % of pixels read this
many DN or more may hold the camera's black level (frames not black-subtracted: jAER, libcaer; DV's read 0 in the
dark), so it is fitted. Left at 0, a black level of 16 DN made 99.7 % of the valid pixels more than 10 % off (bias
-17 %) with fits under 3.5 %, silently (evtools' own simulator, a QA sweep); fitted, it is found at 18.3 DN and said
(54 % valid, bias +2.4 %, 4 % of them 10 % off: the fit is approximate, as ``--black-level fit``)."""
AUTO_FIT_MIN_DN = 6.0
"""The black level fitted because it was not said (:data:`FRAMES_FLOOR_DN`) replaces the default 0 only from this
many DN: the fit is approximate (2-5 DN), and a bright scene's frames have a floor with no black level in it."""
BLACK_LEVEL_FIT_ERROR_DN = 3.0
"""A fitted black level's typical error (DN): measured from 9.5 DN low to 2.3 high (the independent generator, 13
draws; evtools' simulator), mostly 0-5. Not in each pixel's fit (widened by it, no pixel stayed valid where the fit
was right: QA8), but in the scale that ``--nominal frames`` takes from the frames (its median over the pixels shares
the level's error: 3.6-4.7 % off with a statistical error of 0.2 %, a QA sweep)."""
BLACK_LEVEL_FIT_SLACK_DN = 3.0
"""A black level given (``--black-level B``) is checked when the first frame never reads below ``B`` plus
:data:`FRAMES_FLOOR_DN` (the level cannot be seen in the frames' dark pixels): the level is fitted over ``B``,
``B + 8``, ... up to the floor; each pixel's fit takes the bias that the fitted level's excess over ``B`` implies,
less this slack for the fit's own error, times the pixel's mean ``1 / signal``, and an excess of
:data:`AUTO_FIT_MIN_DN` or more is said. The fit read 0-2.3 DN high on evtools' simulator (a slack of 1 DN left no
pixel valid with 16 given for 16 over 6 s), 0.5-12 DN low on the independent generator (64 x 48, 5 s, 10-20 ms
exposures, 13 draws): so the check catches a level given 16 DN or more too low, 12 in four draws of five. Unchecked, 0 given for
frames holding a 16 DN black level left 79 % of the pixels valid with 99.8 % of them more than 10 % off, and 8 given
45 % of them (evtools' simulator, a QA sweep), where the brightness slope could not tell (+1.3, +7.1 DN); checked,
both are refused (no pixel valid, the level found named)."""
CHECK_STEP_DN = 8.0
"""The candidates' spacing when a black level given is checked (:data:`BLACK_LEVEL_FIT_SLACK_DN`): twice the fit's,
half the cost (the test's zero crossing is interpolated between them)."""
HOLD_EVENTS = 1 << 22
"""Events held until the frames around them are known (a frame's packet may follow later events in a file); beyond
this many, they are counted and a frame that then arrives too late for them is left out (counted)."""
MIN_SCALE_PIXELS = 10
"""``--nominal frames``: fewer pixels estimated by both the events and the frames give no scale."""
NOT_OBSERVABLE_WITH_FRAMES = ("events give thresholds relative to one another and the frames one scale per "
                              "polarity: not a smooth spatial component of the mismatch (taken for the scene's); "
                              "--method frames gives each pixel's own")
STEP_SHARE = 0.05
"""onEI: a shared change of the thresholds by more than this share between the short and the long memory (beyond
what the drift explains) is a step (see ``FrameThresholdEstimator._step``)."""
STEP_SHARE_TWICE = 0.03
"""onEI: so is a change by more than this share, the same way, in two maps in a row (a step that the memories see
slowly: where the counts change little after it, the short memory's thresholds hold 0.6 s back and the shift stayed
at 3.0-4.0 % for three maps, while the shared trend began to read it as a drift). Measured on the independent
generator without a step (15 runs, 0.5 s maps) the shift stayed within 1.4 %, and within 2.4 % under a 2 %/s drift
(one map 3.5 %, seed 10, not twice: 12 runs with 1 s maps)."""
WEIGHTED = ("sums", "runs", "new_counts", "inverse_sums", "time_sums")
"""onEI: each memory's arrays that hold frames times their weight (see ``FrameThresholdEstimator._forget``)."""
MAX_WEIGHT = 1e100
"""onEI: a memory's frame weight (``exp(t / forget)``) past this starts again from 1, its sums divided by it."""
RESTART_WEIGHT = math.exp(-1.0)
"""onEI: after a step the long memory restarts from the short one aged by one interval (its sums times ``exp(-1)``):
the step is seen at the end of the first interval after it (rarely the second), when a third of the short memory's
weight is still the old thresholds' frames. Copied at full weight they held the maps 10-17 % off for the first map after
the step (with 36-203 pixels valid) and 2-4 % off two seconds later; aged, the first map has almost no pixel valid (its
pixels have too few frames' worth) and the later ones come back nearer (0.2-3.3 % two seconds after a x1.3 or /1.3 step
against 0.6-4.4 %, 8 seeds, the independent generator; the README gives the setup)."""
BRIGHTNESS_SLOPE_DN = 4.0
"""Across the pixels, the log of a pixel's thresholds (ON and OFF's geometric mean) regressed on its frames' mean
``1 / signal`` has a slope near 0 when the frames' DN of no light is right (the thresholds do not depend on how
bright a pixel was); a black level ``d`` DN too low makes it about ``-d``, one too high positive, and pixels' own
offsets spread by several DN make it positive too (the brighter-reading pixels' thresholds come out smaller).
Measured on the independent generator (64 x 48, 5 s, 15 ms exposures, signals about 80 DN, 2 seeds): right 2.1 +-
0.7 and 2.6 +- 1.0 DN (1 DN offsets), 8 DN too low -5.1 / -5.4, 20 DN too low -18 / -20, 8 DN too high +6.5 /
+7.6, offsets spread 4 DN +10 / +16, 8 DN +22 / +29; but right on darker scenes too +12 (the tests' 5 ms setup) and
+18 (evtools' simulator): a positive slope is ambiguous (the model's own bias at low signal), kept in the attributes
only. A negative one beyond this (and :data:`BRIGHTNESS_SLOPE_SE` of its standard errors), a black level too low
(frames not black-subtracted, read with the default 0), is said, and each pixel's fit takes the bias it implies
(slope times its mean ``1 / signal``): there 65-100 % of the valid pixels were more than 10 % off, the fit unaware."""
BRIGHTNESS_SLOPE_SE = 3.0
"""How many standard errors the brightness slope must exceed to be more than chance (see :data:`BRIGHTNESS_SLOPE_DN`)."""
BLACK_LEVEL_SAMPLE = 4
"""Every this many pixels take part in the black level's test (its sums, twice per candidate, for a quarter of the
sensor)."""
N_SUMS = 10  # per candidate and pixel: n, x1, x2, y, x1x1, x2x2, x1x2, x1y, x2y, yy
S_N, S_X1, S_X2, S_Y, S_X1X1, S_X2X2, S_X1X2, S_X1Y, S_X2Y, S_YY = range(N_SUMS)


class SharedTrend:
    """onEI's lag behind a drift shared by all pixels, removed. A map from sums forgotten with time constant
    ``forget_us`` is a least-squares slope over the past weighted by ``exp(-age / forget)``: under a drift it holds
    the thresholds of an earlier time, each pixel's own (:func:`_lags`: 1.5-4.2 s behind with a 3 s memory,
    following how the scene moved its counts; uncorrected the maps were 5.4-8.5 % off after 12 s at 2 %/s). Per
    polarity, the shared level ``L`` (the sum of the log of each map's median ratio to the one before, over the
    pixels valid in both: independent of which pixels are valid) against the maps' shared time ``E`` (likewise the
    sum of the median change of the pixels' times, ``T + lag``) gives the drift's rate, the least-squares slope of
    ``L`` on ``E`` over the maps of the last two forgetting times, and each pixel is scaled by ``exp(-rate x lag)``:
    its level at the map's time (Brown's extrapolation of linear exponential smoothing, R. G. Brown, "Smoothing,
    Forecasting and Prediction of Discrete Time Series", 1963, with the lag measured rather than assumed). Only the
    shared rate is fitted, so the pixels' own noise is not amplified; a rate needs three maps after the first
    forgetting time (:attr:`SETTLE_FORGETS`)."""

    MIN_PIXELS = 10
    """Fewer pixels valid in two maps in a row leave the level where it was."""
    SETTLE_FORGETS = 1.0
    """The maps of the first this many forgetting times (their sums still filling, the black level still moving)
    give no rate: with them, on the independent generator with the black level fitted, a x1/1.3 step was 7.2 % off
    two seconds after (0.4 % without) and a x1.3 step was seen twice."""

    def __init__(self, forget_us: float) -> None:
        self.forget_us = float(forget_us)
        self.previous: tuple | None = None  # the last map before scaling: (thresholds, times, valid, candidate)
        self.levels: list[tuple] = []  # (t_us, [log L on, off], [E on, off]) of the maps so far
        self.rates = np.zeros(2)  # the drift's latest rate (log units a second, ON and OFF)

    def factors(self, t_us: int, on: np.ndarray, off: np.ndarray, valid: np.ndarray, lags: np.ndarray,
                candidate: int = 0) -> np.ndarray:
        """Each pixel's factors ((2, pixels): ON, OFF; 1 where its lag is unknown) for the map at ``t_us``; maps come
        in time order. ``on``, ``off``: the thresholds at one black-level ``candidate`` (with the black level fitted,
        a map's own thresholds move with its interpolated black level: 1 DN moves them by several per cent, a false
        drift that then hid a step), ``lags``: theirs (:func:`_lags`, seconds); a map whose candidate differs from
        the map before's carries the level."""
        thresholds = np.stack([on, off])
        times_s = t_us * 1e-6 + lags
        level, shared_s = np.zeros(2), np.zeros(2)
        if self.previous is not None:
            previous, previous_times_s, previous_valid, previous_candidate = self.previous
            _, level, shared_s = self.levels[-1]
            both = valid & previous_valid & np.isfinite(times_s).all(0) & np.isfinite(previous_times_s).all(0)
            if both.sum() >= self.MIN_PIXELS and candidate == previous_candidate:
                level = level + np.log(np.median(thresholds[:, both] / previous[:, both], axis=1))
                shared_s = shared_s + np.median(times_s[:, both] - previous_times_s[:, both], axis=1)
        self.previous = (thresholds, times_s, valid.copy(), candidate)
        self.levels.append((t_us, level, shared_s))
        since_us = max(self.levels[0][0] + self.SETTLE_FORGETS * self.forget_us, t_us - 2 * self.forget_us)
        recent = [(shared, logs) for t, logs, shared in self.levels if t >= since_us]
        self.rates = np.zeros(2)
        if len(recent) >= 3:
            shared, logs = (np.array(column) for column in zip(*recent))
            shared = shared - shared.mean(0)
            spread = (shared * shared).sum(0)
            if (spread > 0).all():
                self.rates = (shared * (logs - logs.mean(0))).sum(0) / spread  # per second
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(lags), np.exp(-self.rates[:, None] * lags), 1.0)


class FrameThresholdEstimator:
    """Accumulates a stream's events (:meth:`process`) and APS frames (:meth:`add_frames`, in the stream's order)
    and estimates every pixel's thresholds on the absolute scale (see the module docstring).

    Parameters
    ----------
    width, height : int
        Sensor size; frames may be smaller (a region of interest at their offset).
    black_level : float or "fit"
        The frames' DN of no light (default 0: DV's DAVIS frames are black-subtracted); ``"fit"``: fitted
        (:data:`BLACK_LEVELS`), which is approximate (measured: within 2-5 DN on textures, a 5-25 % error of the
        thresholds on signals of 40 DN): give it when it is known.
    min_events : int
        Pixels with fewer events are invalid.
    max_fit : float or None
        Pixels whose predicted relative error (the fit map) is larger are invalid (default
        :data:`DEFAULT_MAX_FRAME_FIT`; inf: none).
    interval_us, forget_us : int or None
        onEI: a map every ``interval_us`` from the frames so far, older ones forgotten with time constant
        ``forget_us`` (default 3 intervals).
    map_sink : callable, optional
        onEI: each map passed to ``map_sink(t_us, on, off, valid, fit)`` as it is made instead of being held (see
        :class:`evtools.estimation.ThresholdEstimator`).
    """

    def __init__(self, width: int, height: int, *, black_level: float | str | None = DEFAULT_BLACK_LEVEL,
                 min_events: int = DEFAULT_MIN_EVENTS, max_fit: float | None = None, interval_us: int | None = None,
                 forget_us: int | None = None, map_sink=None, check: bool = True, **unused) -> None:
        unknown = sorted(name for name, value in unused.items() if value is not None and name not in (
            "method", "nominal", "segment_us", "stimulus", "phase", "radius_px"))
        if unknown:
            raise EstimationError(f"the frames method takes no {', '.join(unknown)}")
        self.black_level_auto = black_level is None  # not said: the default unless the frames' floor says otherwise
        if black_level is None:
            black_level = DEFAULT_BLACK_LEVEL
        fitted = isinstance(black_level, str) and black_level == "fit"
        if not fitted and not (isinstance(black_level, (int, float)) and math.isfinite(black_level)
                               and 0 <= black_level < 65535):
            raise EstimationError(f"the black level must be a DN from 0, or 'fit', not {black_level!r}")
        # a level given as a number: the maps' level, checked against the frames when their floor is far above it
        self.black_level_said = None if fitted or self.black_level_auto else float(black_level)
        self.black_level_checked = False
        if interval_us is not None and interval_us <= 0:
            raise EstimationError("the interval must be positive")
        self.width, self.height = width, height
        self.min_events = int(min_events)
        self.max_fit = DEFAULT_MAX_FRAME_FIT if max_fit is None else float(max_fit)
        self.black_level_unsure = False  # the black level's test never crossed zero (fit: the closest candidate)
        self.frames_floor_dn: float | None = None  # (not said: the first frame's floor, see FRAMES_FLOOR_DN)
        self.interval_us = interval_us
        self.forget_us = forget_us if forget_us is not None else (3 * interval_us if interval_us else None)
        pixels = width * height
        self.counts = np.zeros((pixels, FRAMES_ROW), np.int64)
        self._set_candidates(BLACK_LEVELS if fitted else (black_level,))
        self.frames_seen = np.zeros(pixels, np.int64)  # frames covering the pixel (those covering all: full_frames)
        self.full_frames = 0
        self.saturated = np.zeros(pixels, np.int64)  # frames in which the pixel is saturated
        self.marks = np.zeros((pixels, 2), np.int32)  # the latest exposure with events, and how many in it
        self.marks[:, 0] = -1
        self.exposures = 0  # exposures opened so far (the stamp of the latest)
        self._checker = StreamChecker(StreamInfo(width, height)) if check else None
        self.pending: deque = deque()  # frames whose exposure the counts have not passed yet
        self.held: deque = deque()  # event chunks not counted yet
        self.held_events = 0
        self.counted_before_us = -math.inf  # every event earlier than this is counted (and no later one)
        self.last_t_us: int | None = None
        self.events = 0
        # frames beyond the events' span (events cut at the start or the end while the APS ran on): the counts
        # there are not known, so only the frame next to the span on each side is used (its interval to the
        # events holds none: a stream that starts or ends without events between it and the frame)
        self.frames_used = self.frames_late = self.frames_outside = self.frames_beyond_events = 0
        self.frames_after_events = False
        self.t_frame_us: int | None = None  # the last frame used (online forgetting)
        self.weight = 1.0  # onEI: the weight of a frame added now (see _forget)
        self.next_map_us: int | None = None
        self.maps = None if interval_us is None else OnlineMaps(width, height, interval_us, map_sink)
        self.trend: SharedTrend | None = None  # onEI: the shared drift's level, for the maps' lag
        # onEI: each pixel's sums of its counted events' times (see _lags); offline empty, and the kernels skip them
        online = interval_us is not None
        self.event_times = np.zeros((pixels if online else 0, FRAMES_ROW))
        self._set_online_candidates()
        self.origin_us: int | None = None
        self.steps_us: list[int] = []  # onEI: when a step was seen (and the memory restarted)
        self.suspected = np.zeros(2)  # onEI: the sign of the last map's shift beyond STEP_SHARE_TWICE (ON, OFF)
        self.black_level_before = None  # onEI: the black level's test before the last step (slopes, frames)
        self.frames_at_step = 0

    def _set_candidates(self, levels) -> None:
        """The black levels whose sums the frames fill (one: given; :data:`BLACK_LEVELS`: fitted), their sums empty;
        the black level's test (a sample of pixels, each fitted on its frames below and above its mean level) only
        when fitted."""
        self.candidates = np.array(levels, np.float64)
        fitted = len(self.candidates) > 1
        self.black_level_given = not fitted
        pixels, candidates = self.width * self.height, len(self.candidates)
        self.sums = np.zeros((candidates, N_SUMS, pixels), np.float64)
        self.new_counts = np.zeros((candidates, pixels), np.float64)  # frames with a count not seen before
        self.inverse_sums = np.zeros((candidates, pixels), np.float64)  # 1 / (DN - black), frames used
        # each pixel's open run: frames since its counts last changed (number, sum y, sum y^2) and those counts
        self.runs = np.zeros((candidates, 3, pixels), np.float64)
        self.run_counts = np.full((candidates, 2, pixels), -1, np.int64)
        self.sample_step = BLACK_LEVEL_SAMPLE if fitted else 0
        self.sample = np.arange(0, pixels, BLACK_LEVEL_SAMPLE) if fitted else np.zeros(0, np.int64)
        self.half_sums = np.zeros((candidates, 2, N_SUMS, len(self.sample)), np.float64)
        self.log_tables: dict = {}  # (candidate, DN levels): log(DN - black) per DN, NaN where dark or saturated
        self.black_level_index = candidates // 2  # the candidate nearest the black level last used

    def _set_online_candidates(self) -> None:
        """onEI's arrays per black level (see :meth:`_set_candidates`): a second memory of one interval, to see a
        threshold step (see _step), and the frames' sums of the events' times (see _lags)."""
        online, pixels, candidates = self.interval_us is not None, self.width * self.height, len(self.candidates)
        self.short = None
        if online:
            self.short = {"sums": np.zeros((candidates, N_SUMS, pixels)), "runs": np.zeros((candidates, 3, pixels)),
                          "run_counts": np.full((candidates, 2, pixels), -1, np.int64),
                          "new_counts": np.zeros((candidates, pixels)), "inverse_sums": np.zeros((candidates, pixels)),
                          "half": np.zeros((2, N_SUMS, 0)), "time_sums": np.zeros((candidates, TIME_SUMS, pixels)),
                          "run_times": np.zeros((candidates, FRAMES_ROW, pixels)), "weight": 1.0}
        self.time_sums = np.zeros((candidates, TIME_SUMS if online else 0, pixels if online else 0))
        self.run_times = np.zeros((candidates, FRAMES_ROW if online else 0, pixels if online else 0))

    def _check_floor(self, image: np.ndarray) -> None:
        """The black level not said: the first frame's floor (its darkest 0.1 % of pixels) at or above
        :data:`FRAMES_FLOOR_DN` looks like frames not black-subtracted, so the black level is fitted (every
        candidate's sums from this first frame on) and the default kept unless the fit finds it away from 0
        (:meth:`_solve`)."""
        self.frames_floor_dn = frames_floor(image)
        if self.frames_floor_dn >= FRAMES_FLOOR_DN:
            logging.getLogger("evtools").info(
                f"the first frame never reads below {self.frames_floor_dn:g} DN (frames not black-subtracted, or a "
                f"bright scene): the black level is fitted over {len(BLACK_LEVELS)} candidates, which costs the "
                "frame pass several times; --black-level DN (the camera's, 0 for DV's frames) skips it")
            self._set_candidates(BLACK_LEVELS)
            self._set_online_candidates()

    def _check_given(self, image: np.ndarray) -> None:
        """A black level given: the first frame's floor at or above it plus :data:`FRAMES_FLOOR_DN` has the level
        fitted from it upwards too, as a check (:data:`BLACK_LEVEL_FIT_SLACK_DN`)."""
        given = self.black_level_said
        self.frames_floor_dn = frames_floor(image)
        levels = [given + CHECK_STEP_DN * k for k in range(len(BLACK_LEVELS))
                  if given + CHECK_STEP_DN * k <= self.frames_floor_dn]
        if self.frames_floor_dn >= given + FRAMES_FLOOR_DN and len(levels) > 1:
            logging.getLogger("evtools").info(
                f"the first frame never reads below {self.frames_floor_dn:g} DN, {self.frames_floor_dn - given:g} "
                f"above the black level given: the level is checked by fitting it over {len(levels)} candidates, "
                "which costs the frame pass several times")
            self.black_level_checked = True
            self._set_candidates(levels)
            self._set_online_candidates()

    @property
    def parameters(self) -> dict[str, Any]:
        if self.black_level_said is not None:
            black_level = self.black_level_said
        else:
            black_level = float(self.candidates[0]) if self.black_level_given else "fitted"
        return {"method": "frames", "black_level": black_level, "black_level_given": not self.black_level_auto,
                "min_events": self.min_events, "max_fit": self.max_fit,
                **({"interval_us": self.interval_us, "forget_us": self.forget_us} if self.interval_us else {})}

    def add_frames(self, frames) -> None:
        """APS frames of the stream, in its order (a frame whose exposure lies before events already counted, when
        more than :data:`HOLD_EVENTS` were waiting for it, is left out and counted)."""
        for frame in frames:
            if frame.exposure_begin_us < self.counted_before_us:
                self.frames_late += 1
                continue
            self.pending.append(frame)
        self._advance(final=False)

    def process(self, chunk: np.ndarray) -> np.ndarray:
        """Hold a chunk of events until the frames around it are known; returns nothing (an estimator)."""
        chunk = self._checker.check(chunk) if self._checker else as_chunk(chunk)
        if len(chunk):
            self.held.append(chunk)
            self.held_events += len(chunk)
            self.events += len(chunk)
            self.last_t_us = int(chunk["t"][-1])
            if self.origin_us is None:
                self.origin_us = int(chunk["t"][0])
        self._advance(final=False)
        if self.held_events > HOLD_EVENTS:  # no frame for a long stretch: count what waits (not a pending exposure)
            self._count_before(min(self.last_t_us, self.pending[0].exposure_begin_us) if self.pending
                               else self.last_t_us)
        return chunk[:0]

    def flush(self) -> np.ndarray:
        """Use every frame still waiting (the stream ended); returns nothing (an estimator)."""
        self._advance(final=True)
        return empty_events()

    # -- events and frames in time order --------------------------------------------------------------------

    def _count_before(self, t_us: float, exposure: int | None = None) -> None:
        """Count every held event earlier than ``t_us`` (with ``exposure``: also into that exposure's events)."""
        while self.held:
            chunk = self.held[0]
            split = len(chunk) if chunk["t"][-1] < t_us else int(np.searchsorted(chunk["t"], t_us, "left"))
            if split:
                part = chunk[:split]
                if exposure is None:
                    polarity_counts(part["x"], part["y"], part["p"], self.width, self.counts)
                else:
                    exposure_counts(part["x"], part["y"], part["p"], self.width, self.counts, self.marks,
                                    exposure, True)
                if len(self.event_times):
                    count_times(part["t"], part["x"], part["y"], part["p"], self.width, self.origin_us,
                                self.event_times)
                self.held_events -= split
            if split < len(chunk):
                self.held[0] = chunk[split:]
                break
            self.held.popleft()
        self.counted_before_us = max(self.counted_before_us, t_us)

    def _mark_before(self, t_us: float, exposure: int) -> None:
        """Count every held event earlier than ``t_us`` into ``exposure``'s events only (they stay held)."""
        for chunk in self.held:
            split = len(chunk) if chunk["t"][-1] < t_us else int(np.searchsorted(chunk["t"], t_us, "left"))
            exposure_counts(chunk["x"][:split], chunk["y"][:split], chunk["p"][:split], self.width, self.counts,
                            self.marks, exposure, False)
            if split < len(chunk):
                break

    def _advance(self, final: bool) -> None:
        """Use every pending frame whose exposure the events have passed (all of them at the stream's end): its
        pixels' counts at the exposure's middle, and their events during it."""
        known_us = math.inf if final else (self.last_t_us if self.last_t_us is not None else -math.inf)
        while self.pending:
            frame = self.pending[0]
            if known_us <= frame.exposure_end_us:  # a later event may still belong to its exposure
                return
            if self.last_t_us is None:  # (no event at all)
                self.frames_beyond_events += 1
                self.pending.popleft()
                continue
            if frame.exposure_end_us < self.origin_us:  # before the events: only the last such frame is used
                if len(self.pending) == 1 and not final:  # (whether another follows is not known yet; past
                    if self.held_events <= HOLD_EVENTS:  # HOLD_EVENTS waiting it is used now: held in bounded memory)
                        return
                elif len(self.pending) > 1 and self.pending[1].exposure_end_us < self.origin_us:
                    self.frames_beyond_events += 1
                    self.pending.popleft()
                    continue
            elif frame.exposure_begin_us > self.last_t_us:  # after them (known at the end): only the first
                if self.frames_after_events:
                    self.frames_beyond_events += 1
                    self.pending.popleft()
                    continue
                self.frames_after_events = True
            self._count_before(frame.exposure_begin_us)
            if self.exposures == np.iinfo(np.int32).max:  # the marks start again (after 2^31 frames)
                self.marks[:, 0] = -1
                self.exposures = 0
            self.exposures += 1
            middle_us = -(-(frame.exposure_begin_us + frame.exposure_end_us) // 2)  # events before it (an integer:
            self._count_before(middle_us, self.exposures)                          # numpy searches ints fast)
            self._mark_before(frame.exposure_end_us + 1, self.exposures)
            self._use(frame)
            self.pending.popleft()
        if final:
            self._count_before(math.inf)

    # -- the fit ------------------------------------------------------------------------------------------------

    def _fits(self, frame) -> bool:
        """Whether the frame lies on the sensor (else it is counted in ``frames_outside``)."""
        height, width = frame.image.shape
        x0, y0 = frame.offset_x, frame.offset_y
        if x0 < 0 or y0 < 0 or x0 + width > self.width or y0 + height > self.height:
            self.frames_outside += 1
            return False
        return True

    def _log_table(self, index: int, levels: int) -> np.ndarray:
        """log(DN - black) for black-level candidate ``index`` and every DN of ``levels`` (NaN: dark or saturated)."""
        table = self.log_tables.get((index, levels))
        if table is None:
            table = self.log_tables[index, levels] = np.empty(levels)
            log_levels(table, float(self.candidates[index]), MIN_SIGNAL_DN, float(SATURATED_DN))
        return table

    def _use(self, frame) -> None:
        """One frame into the sums: each pixel's counts at the exposure's middle against its log DN, where the
        pixel fired at most :data:`MAX_EXPOSURE_EVENTS` times during the exposure."""
        if not self._fits(frame):
            return
        self._forget(frame.exposure_end_us)
        image = np.ascontiguousarray(frame.image)
        if self.frames_floor_dn is None:
            if self.black_level_auto:
                self._check_floor(image)
            elif self.black_level_said is not None:
                self._check_given(image)
        height, width = image.shape
        x0, y0 = frame.offset_x, frame.offset_y
        if (x0, y0, width, height) == (0, 0, self.width, self.height):
            self.full_frames += 1
        else:
            self.frames_seen.reshape(self.height, self.width)[y0:y0 + height, x0:x0 + width] += 1
        levels = np.iinfo(image.dtype).max + 1
        log_exposure = math.log(max(frame.exposure_us, 1) * 1e-6)
        for index, black in enumerate(self.candidates):
            checking = self.black_level_checked and index > 0  # (a check's candidate: its test's pixels alone)
            frame_sums(image, x0, y0, self.width, self.counts, self.marks, self.exposures,
                       self._log_table(index, levels), float(black), log_exposure, MAX_EXPOSURE_EVENTS,
                       float(SATURATED_DN), self.sums[index], self.runs[index], self.run_counts[index],
                       self.half_sums[index], self.sample_step, self.inverse_sums[index], self.new_counts[index],
                       self.saturated if index == 0 else self.saturated[:0], self.weight, self.event_times,
                       self.time_sums[index], self.run_times[index], checking)
            if self.short is not None and not checking:
                short = self.short
                frame_sums(image, x0, y0, self.width, self.counts, self.marks, self.exposures,
                           self._log_table(index, levels), float(black), log_exposure, MAX_EXPOSURE_EVENTS,
                           float(SATURATED_DN), short["sums"][index], short["runs"][index], short["run_counts"][index],
                           short["half"], 0, short["inverse_sums"][index], short["new_counts"][index],
                           self.saturated[:0], short["weight"], self.event_times, short["time_sums"][index],
                           short["run_times"][index], False)
        self.frames_used += 1
        if self.interval_us is not None:
            self._snapshot_maps(frame.exposure_end_us)

    def _forget(self, t_us: int) -> None:
        """onEI: older frames weigh ``exp(-age / forget_us)`` (the short memory's ``exp(-age / interval_us)``), kept
        lazily: each new frame is added with a weight that grows as ``exp(t / forget_us)`` (``self.weight``, the short
        memory's ``short["weight"]``) and the sums are read divided by it (:meth:`_fit`), so no sum is touched at a
        frame (multiplying every sum at every frame took a third of an online run with the black level fitted: 11
        candidates, two memories); the weights start again from 1 before they pass :data:`MAX_WEIGHT`."""
        if self.interval_us is None:
            return
        if self.t_frame_us is not None and t_us > self.t_frame_us:
            self.weight *= math.exp((t_us - self.t_frame_us) / self.forget_us)
            self.short["weight"] *= math.exp((t_us - self.t_frame_us) / self.interval_us)
            if max(self.weight, self.short["weight"]) > MAX_WEIGHT:
                for name in WEIGHTED:
                    getattr(self, name)[...] /= self.weight
                    self.short[name][...] /= self.short["weight"]
                self.weight = self.short["weight"] = 1.0
        self.t_frame_us = t_us

    def _snapshot_maps(self, t_us: int) -> None:
        if self.last_t_us is not None and t_us > self.last_t_us:  # (the frame after the events: the final map's)
            return
        if self.next_map_us is None:
            self.next_map_us = t_us + self.interval_us
        while t_us >= self.next_map_us:
            fits = self._fit_all()
            if self._step(self.next_map_us, fits):
                fits = self._fit_all()  # (the long memory restarted)
            self._add_map(self.next_map_us, self._without_lag(self.next_map_us, self._solve(fits), fits))
            self.next_map_us += self.interval_us

    def _step(self, t_us: int, fits: list[dict]) -> bool:
        """onEI: a threshold step shared by the pixels, seen and followed. The short memory (one interval) against the
        long one (``forget_us``): under a drift at rate r their shared ratio is about ``exp(r d)``, d the median of
        how much later the short memory's thresholds hold (:func:`_lags` of both); when the median over the pixels
        both fit differs from that by more than :data:`STEP_SHARE` for ON or OFF (or by more than
        :data:`STEP_SHARE_TWICE` the same way in this map and the one before), the thresholds stepped, and the long
        memory restarts from the short one aged by one interval (:data:`RESTART_WEIGHT`; its older frames belong to
        the thresholds before; the shared trend restarts too, and the black level's test, see :meth:`_black_level`).
        Measured on the independent generator (0.25 s maps): the ratio stays within 1.4 % without a step and passes
        5 % 0.3-0.5 s after a x1.3 or /1.3 step. With the black level fitted, both memories are compared at the
        candidate nearest the black level last used (a wrong black level biases both alike) and every candidate's
        long memory restarts. ``fits``: the long memory's, one per candidate; returns whether it restarted."""
        if self.short is None:
            return False
        short = self.short
        index = self.black_level_index
        whole = fits[index]
        recent = self._fit_of(short, index)
        both = recent["solved"] & whole["solved"] & (recent["n"] >= MIN_FRAMES / 2) & (whole["n"] >= MIN_FRAMES)
        with np.errstate(divide="ignore", invalid="ignore"):
            both &= (recent["on"] > 0) & (recent["off"] > 0) & (whole["on"] > 0) & (whole["off"] > 0)
        if both.sum() < MIN_SCALE_PIXELS:
            return False
        expected = np.zeros(2)  # the drift's share: rate times how much later the short memory's thresholds hold
        if self.trend is not None:
            later_s = self._lags_of(short, index, recent, t_us) - self._lags_of(vars(self), index, whole, t_us)
            expected = self.trend.rates * np.nan_to_num(np.median(later_s[:, both], axis=1))
        shift = np.array([math.log(np.median(recent[key][both] / whole[key][both])) for key in ("on", "off")])
        deviation = shift - expected
        beyond = np.where(np.abs(deviation) > math.log1p(STEP_SHARE_TWICE), np.sign(deviation), 0.0)
        twice = bool(np.any((beyond != 0) & (beyond == self.suspected)))
        self.suspected = beyond
        if np.abs(deviation).max() <= math.log1p(STEP_SHARE) and not twice:
            return False
        self.suspected = np.zeros(2)
        for candidate in range(len(self.candidates)):  # (the open runs into the sums: the runs restart empty)
            fold_runs(*self._runs_of(short, candidate))
        for name in WEIGHTED:  # (each memory's sums times its weight)
            getattr(self, name)[...] = short[name] * (RESTART_WEIGHT * self.weight / short["weight"])
        self.run_counts[...] = short["run_counts"]  # (the open runs' counts and times: which run, not a weight)
        self.run_times[...] = short["run_times"]
        if len(self.sample):  # the black level's test restarts too, its curve so far kept for pooling
            self.black_level_before = self._black_level_curve()
            self.frames_at_step = self.frames_used
            self.half_sums[...] = 0
        self.trend = None
        self.steps_us.append(int(t_us))
        return True

    def _black_level(self, fits: list[dict]) -> tuple[dict, float]:
        """The fit at the black level where a pixel's thresholds do not depend on its brightness. A black level
        too low compresses the logs of a pixel's darker frames more than those of its brighter ones (their
        thresholds come out smaller), one too high stretches them: the median over a sample of pixels of
        ``log(theta below / theta above)`` (each pixel fitted apart on its frames below and above its mean count
        level) falls through zero at the true level, found between two candidates and interpolated (the maps
        too). The test's sums are never forgotten (the black level is the camera's, not the thresholds'); after an
        onEI step they restart, as a regression across the step mixes two thresholds, and the curve from before
        is pooled with the new one, each weighted by its frames (measured on the independent generator, a x1.3
        step at 7 s: without the restart the fitted level went from 15-16 to 18-19 DN after the step, the maps
        7-8 % off two seconds later; pooled, 14.9-17.0 DN over 12 runs, seeds 1-6, x1.3 and /1.3)."""
        if len(fits) == 1:
            return fits[0], float(self.candidates[0])
        slopes, _ = self._black_level_curve()
        for k in range(len(slopes) - 1):
            a, b = slopes[k], slopes[k + 1]
            if np.isfinite(a) and np.isfinite(b) and a > 0 >= b:
                share = a / (a - b)
                mixed = {key: (1 - share) * fits[k][key] + share * fits[k + 1][key]
                         for key in ("on", "off", "rms", "expected_rms", "fit", "n", "mean_inverse")}
                mixed["solved"] = fits[k]["solved"] & fits[k + 1]["solved"]
                return mixed, float((1 - share) * self.candidates[k] + share * self.candidates[k + 1])
        finite = np.where(np.isfinite(slopes), np.abs(slopes), np.inf)
        best = int(np.argmin(finite))
        self.black_level_unsure = True
        return fits[best], float(self.candidates[best])

    def _black_level_curve(self) -> tuple[np.ndarray, int]:
        """The black level's test (:meth:`_black_level_slopes`) on the sums since the last step, pooled with the
        curve from before it (each weighted by its frames; where the new sums give none, the old curve), and the
        frames behind it."""
        slopes, frames = self._black_level_slopes(), self.frames_used - self.frames_at_step
        if self.black_level_before is not None:
            before, frames_before = self.black_level_before
            with np.errstate(invalid="ignore"):
                pooled = (frames_before * before + frames * slopes) / max(frames_before + frames, 1)
            slopes, frames = np.where(np.isfinite(slopes), pooled, before), frames + frames_before
        return slopes, frames

    def _black_level_slopes(self) -> np.ndarray:
        """Per black-level candidate, the median over the sampled pixels of ``-log(theta below / theta above)``
        (see :meth:`_black_level`); NaN where fewer than 10 pixels fit both halves."""
        slopes = []
        ones = np.ones(len(self.sample))
        for index in range(len(self.candidates)):
            low, high = (_least_squares(self.half_sums[index, half], ones, ones) for half in (0, 1))
            use = low["solved"] & high["solved"] & (np.minimum(low["n"], high["n"]) >= MIN_FRAMES)
            for fit in (low, high):
                use &= (fit["on"] > 0) & (fit["off"] > 0)
            if use.sum() < 10:
                slopes.append(np.nan)
                continue
            ratio = np.log(low["on"][use] * low["off"][use] / (high["on"][use] * high["off"][use])) / 2
            slopes.append(-float(np.median(ratio)))
        return np.array(slopes)

    def _solve(self, fits: list[dict]) -> ThresholdEstimate:
        """The maps from the sums so far (``fits``: :meth:`_fit_all`)."""
        fit, black_level = self._black_level(fits)
        said = {}
        if self.black_level_checked:  # (given, and the frames' floor far above it: fitted as a check)
            fitted, fit, black_level = black_level, fits[0], self.black_level_said
            said["black_level_fitted_dn"] = fitted
            excess = fitted - black_level - BLACK_LEVEL_FIT_SLACK_DN
            if excess > 0:  # (else the map is the unchecked one, bit for bit)
                fit = {**fit, "fit": np.sqrt(fit["fit"] ** 2 + (excess * fit["mean_inverse"]) ** 2)}
            if fitted - black_level >= AUTO_FIT_MIN_DN:
                at_least = "at least " if self.black_level_unsure else ""
                said["black_level_disagrees"] = (
                    f"the frames' black level looks about {fitted:.0f} DN ({at_least}"
                    f"{fitted - black_level:.0f} DN above the {black_level:g} given: frames not black-subtracted, as "
                    "jAER and libcaer give them?); each pixel's fit includes the bias it implies; give the camera's "
                    "level, or --black-level fit")
            self.black_level_unsure = False
        elif self.black_level_auto and len(fits) > 1:  # (not said, and the frames' floor was high: fitted)
            said["black_level_fitted_dn"] = black_level
            if black_level < AUTO_FIT_MIN_DN:
                fit, black_level, self.black_level_unsure = fits[0], 0.0, False
            else:
                said["black_level_fitted"] = (
                    f"the frames never read below {self.frames_floor_dn:g} DN and their black level is fitted at "
                    f"{black_level:.1f} DN (frames not black-subtracted, as jAER and libcaer give them): used in "
                    "place of 0, as --black-level fit would (approximate: within a few DN); give --black-level B "
                    "when the camera's is known")
        slope = _brightness_slope(fit)
        depends = slope is not None and -slope[0] > max(BRIGHTNESS_SLOPE_DN, BRIGHTNESS_SLOPE_SE * slope[1])
        if depends:  # each pixel's fit takes the bias the measured dependence implies for it
            fit = {**fit, "fit": np.sqrt(fit["fit"] ** 2 + (slope[0] * fit["mean_inverse"]) ** 2)}
        self.black_level_index = int(np.argmin(np.abs(self.candidates - black_level)))
        on, off = fit["on"], fit["off"]
        n_events = self.counts[:, FRAMES_ON] + self.counts[:, FRAMES_OFF]
        frames_seen = self.frames_seen + self.full_frames
        with np.errstate(invalid="ignore"):  # (NaN where not solved: that pixel has its reason first)
            failing = {  # in this order: each invalid pixel is counted under its first reason
                "no_frames": frames_seen == 0,
                # (before few_frames: a saturated frame is not used, so those pixels have few frames too, and a
                # longer recording would not help them)
                "saturated": (self.saturated * 2 > frames_seen) & (frames_seen > 0),
                "few_frames": fit["n"] < MIN_FRAMES,
                "few_events": n_events < self.min_events,
                "one_polarity": (self.counts[:, FRAMES_ON] < 2) | (self.counts[:, FRAMES_OFF] < 2),
                "singular": ~fit["solved"],
                "out_of_range": ~((on > 0.01) & (off > 0.01) & (on < 5) & (off < 5)),
                "does_not_fit": fit["rms"] > MAX_RESIDUAL_RATIO * fit["expected_rms"],
                "poor_fit": ~(fit["fit"] <= self.max_fit),
            }
        valid = np.ones(len(on), bool)
        reasons = {}
        for name, mask in failing.items():
            reasons[name] = valid & mask
            valid &= ~mask
        shape = (self.height, self.width)
        on_map, off_map = on.astype(np.float32), off.astype(np.float32)
        if valid.any():
            on_map[~valid], off_map[~valid] = np.median(on[valid]), np.median(off[valid])
        attributes = {
            **self.parameters, "black_level_used": black_level, "scale": "absolute",
            "black_level_unsure": bool(self.black_level_unsure),
            "events": self.events, "frames": self.frames_used, "frames_late": self.frames_late,
            "frames_outside": self.frames_outside, "frames_beyond_events": self.frames_beyond_events,
            "valid_fraction": float(valid.mean()),
            **({"steps_seen": len(self.steps_us)} if self.short is not None else {}),
            **({"steps_us": np.array(self.steps_us, np.int64)} if self.steps_us else {}),
            **{f"invalid_{name}": int(mask.sum()) for name, mask in reasons.items()},
            **({} if slope is None else {"brightness_slope_dn": slope[0], "brightness_slope_se_dn": slope[1]}),
            **({} if self.frames_floor_dn is None else {"frames_floor_dn": self.frames_floor_dn}), **said,
        }
        if depends:
            attributes["brightness_dependence"] = (
                f"the thresholds come out smaller the darker a pixel's frames (a slope of {slope[0]:+.1f} DN: the "
                f"frames' DN of no light looks about {-slope[0]:.0f} DN above the {black_level:g} used); the fits "
                f"include it (valid: {valid.mean():.0%} of the pixels); give --black-level B or fit")
        solved = fit["solved"] & (fit["expected_rms"] > 0) & (fit["n"] >= MIN_FRAMES)
        if solved.sum() >= MIN_SCALE_PIXELS:
            ratio = float(np.median(fit["rms"][solved] / fit["expected_rms"][solved]))
            attributes["residual_ratio_median"] = ratio
            if ratio > MAX_RESIDUAL_RATIO:
                attributes["disagreement"] = (
                    f"the events and the frames disagree at most pixels (their residuals are a median {ratio:.1f}x "
                    "what the model allows): are the frames on the events' clock (0.1 s off makes it 8x), "
                    "the black level right, the frames of this sensor?")
        return ThresholdEstimate(on_map.reshape(shape), off_map.reshape(shape), valid.reshape(shape), attributes,
                                 fit["fit"].astype(np.float32).reshape(shape))

    def result(self) -> ThresholdEstimate:
        """The maps from everything so far (the stream's end: its held events and frames used); raises
        :class:`EstimationError` when the stream had no frames."""
        self._advance(final=True)
        if self.frames_used == 0 and self.frames_beyond_events:
            raise EstimationError(f"{self.frames_beyond_events:,} APS frames but no event during them: nothing to "
                                  "estimate from")
        if self.frames_used == 0:
            raise EstimationError("no APS frames: --method frames needs a recording with frames (a DAVIS camera's, "
                                  "or simulate --aps-rate); --method natural estimates from events alone")
        fits = self._fit_all()
        estimate = self._solve(fits)
        if self.interval_us is not None:
            estimate = self._without_lag((self.last_t_us or 0) + 1, estimate, fits)
            self._add_map((self.last_t_us or 0) + 1, estimate, final=True)
            estimate.series = self.maps.series()
            estimate.attributes["maps"] = self.maps.count
        return estimate

    def why_none_valid(self, attributes: dict) -> str:
        """Why no pixel of an estimate (its ``attributes``) is valid, in one line: the events and the frames
        disagreeing when they do, else the reason most pixels have (the command line's error when no map has a valid
        pixel, as every method's; the estimate itself keeps every reason in its ``invalid_*`` attributes)."""
        for said in ("disagreement", "brightness_dependence", "black_level_disagrees"):
            if said in attributes:
                return f"no pixel could be estimated by frames: {attributes[said]}"
        reasons = {
            "no_frames": "saw no frame", "saturated": "are saturated in most frames",
            "few_frames": f"have fewer than {MIN_FRAMES} frames to fit",
            "few_events": f"have fewer than {self.min_events} events",
            "one_polarity": "have fewer than 2 events of a polarity",
            "singular": "have frames and events that do not determine the thresholds",
            "out_of_range": "come out beyond 0.01-5 log units", "does_not_fit": "do not fit the model",
            "poor_fit": f"fit worse than --max-fit {self.max_fit:g}"}
        name = max(reasons, key=lambda key: attributes.get(f"invalid_{key}", 0))
        hint = ("give a longer recording with frames" if name in ("no_frames", "few_frames", "few_events",
                                                                   "one_polarity") else
                "a larger --max-fit takes less certain pixels" if name == "poor_fit" else
                "the frames are too bright: a shorter exposure or a darker scene" if name == "saturated" else
                "check the black level (--black-level) and that the frames are this sensor's")
        return (f"no pixel could be estimated by frames ({self.frames_used} frames used): "
                f"{attributes.get(f'invalid_{name}', 0):,} of {self.width * self.height:,} pixels {reasons[name]}; "
                f"{hint}")

    def maps_so_far(self):
        """onEI: the maps held so far (a run stopped midway keeps them), or None (before the first, or when they
        went to a ``map_sink``)."""
        return None if self.maps is None else self.maps.series()

    @property
    def t_last_us(self) -> int:
        """The latest event's time (0 before any)."""
        return self.last_t_us or 0

    def _without_lag(self, t_us: int, estimate: ThresholdEstimate, fits: list[dict]) -> ThresholdEstimate:
        """onEI: the map scaled by :class:`SharedTrend`'s factors (the lag behind a drift shared by all pixels),
        the drift read on ``fits`` (each candidate's) at the candidate nearest the black level used."""
        if self.trend is None:
            self.trend = SharedTrend(self.forget_us)
        index = self.black_level_index
        fit = fits[index]
        with np.errstate(invalid="ignore"):
            valid = estimate.valid.ravel() & fit["solved"] & (fit["on"] > 0) & (fit["off"] > 0)
        lags = self._lags_of(vars(self), index, fit, t_us)
        factors = self.trend.factors(t_us, fit["on"], fit["off"], valid, lags, index)
        shape = estimate.on.shape
        estimate.on = (estimate.on * factors[0].reshape(shape)).astype(np.float32)
        estimate.off = (estimate.off * factors[1].reshape(shape)).astype(np.float32)
        estimate.attributes.update({f"lag_factor_{key}": float(np.median(factors[k][valid])) if valid.any() else 1.0
                                    for k, key in enumerate(("on", "off"))})
        return estimate

    def _lags_of(self, memory: dict, index: int, fit: dict, t_us: int) -> np.ndarray:
        """:func:`_lags` of a memory (``vars(self)`` or ``self.short``, its runs folded: :meth:`_fit_of`) for
        black-level candidate ``index`` and its ``fit``, for its map at ``t_us``."""
        to_true = 1.0 / memory["weight"]  # (onEI's lazy forgetting, see _forget)
        return _lags(memory["sums"][index] * to_true, memory["time_sums"][index] * to_true, fit["on"], fit["off"],
                     (t_us - (self.origin_us or 0)) * 1e-6)

    def _add_map(self, t_us: int, estimate: ThresholdEstimate, final: bool = False) -> None:
        """One map of the online series (:class:`evtools.estimation.OnlineMaps`)."""
        fit = np.full(estimate.on.shape, np.nan) if estimate.fit is None else estimate.fit
        add = self.maps.add_final if final else self.maps.add
        add(t_us, estimate.on, estimate.off, estimate.valid, fit)

    def _fit_all(self) -> list[dict]:
        """:meth:`_fit` of every black-level candidate."""
        return [self._fit(index) for index in range(len(self.candidates))]

    @staticmethod
    def _runs_of(memory: dict, index: int) -> tuple:
        """A memory's (``vars(self)`` or ``self.short``) arrays for :func:`fold_runs`, for candidate ``index``."""
        return tuple(memory[name][index] for name in ("sums", "runs", "run_counts", "time_sums", "run_times"))

    def _fit(self, index: int) -> dict:
        """Each pixel's least squares for black-level candidate ``index``: thresholds, residual RMS, the RMS the
        model allows, and the fit (the larger relative standard error)."""
        return self._fit_of(vars(self), index)

    def _fit_of(self, memory: dict, index: int) -> dict:
        """:meth:`_fit` of a memory (``vars(self)``, the long one, or ``self.short``): its open runs folded, its sums
        read at their true scale (divided by its frame weight: onEI's lazy forgetting, see :meth:`_forget`)."""
        fold_runs(*self._runs_of(memory, index))
        to_true = 1.0 / memory["weight"]
        return _least_squares(memory["sums"][index] * to_true, memory["new_counts"][index] * to_true,
                              memory["inverse_sums"][index] * to_true)


def frames_floor(image: np.ndarray) -> float:
    """A frame's floor (DN): its darkest 0.1 % of pixels' value (see :data:`FRAMES_FLOOR_DN`)."""
    flat = image.ravel()
    k = min(flat.size // 1000, flat.size - 1)
    return float(np.partition(flat, k)[k])


def _brightness_slope(fit: dict) -> tuple[float, float] | None:
    """Across the pixels the fit solved, the slope (DN) of the log of their thresholds' geometric mean against their
    frames' mean ``1 / signal``, and its standard error (least squares, once more without the pixels beyond 4
    robust deviations); None with fewer than 50 such pixels (see :data:`BRIGHTNESS_SLOPE_DN`)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        use = fit["solved"] & (fit["n"] >= MIN_FRAMES) & (fit["on"] > 0) & (fit["off"] > 0) & \
            (fit["mean_inverse"] > 0) & np.isfinite(fit["on"]) & np.isfinite(fit["off"])
    if use.sum() < 50:
        return None
    g, m = np.log(fit["on"][use] * fit["off"][use]) / 2, fit["mean_inverse"][use]
    for _ in range(2):
        design = np.stack([np.ones(len(m)), m], axis=1)
        coefficients, *_ = np.linalg.lstsq(design, g, rcond=None)
        residuals = g - design @ coefficients
        spread = 1.4826 * np.median(np.abs(residuals - np.median(residuals)))
        keep = np.abs(residuals) <= 4 * spread if spread > 0 else np.ones(len(m), bool)
        if keep.all() or keep.sum() < 50:
            break
        g, m = g[keep], m[keep]
    covariance = residuals.var() * np.linalg.pinv(design.T @ design)
    return float(coefficients[1]), float(np.sqrt(max(covariance[1, 1], 0.0)))


def _cofactors(s: np.ndarray) -> tuple:
    """The normal equations' symmetric 3 x 3 matrix [[a, b, c], [b, d, e], [c, e, f]] of the sums ``s``
    (:data:`N_SUMS` rows), per pixel at once: its cofactors (c11, c12, c13, c22, c23, c33), whether it is solvable,
    and 1 / its determinant (0 where not). Solved by cofactors: numpy's batched inv and det took 35 + 8 ms a call on
    90k pixels (22 s of an online run with the black level fitted, 11 candidates a map)."""
    n = s[S_N]
    a, b, c, d, e, f = n, s[S_X1], s[S_X2], s[S_X1X1], s[S_X1X2], s[S_X2X2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        c11, c12, c13 = d * f - e * e, c * e - b * f, b * e - c * d
        c22, c23, c33 = a * f - c * c, b * c - a * e, a * d - b * b
        determinant = a * c11 + b * c12 + c * c13
        scale = np.maximum(n, 1) * np.maximum(d, 1) * np.maximum(f, 1)
        solved = (n >= 3) & (np.abs(determinant) > 1e-9 * scale)
        inverse_determinant = np.where(solved, 1.0 / np.where(solved, determinant, 1.0), 0.0)
    return (c11, c12, c13, c22, c23, c33), solved, inverse_determinant


def _lags(s: np.ndarray, time_sums: np.ndarray, on: np.ndarray, off: np.ndarray, t_s: float) -> np.ndarray:
    """onEI: per pixel and polarity ((2, pixels), seconds, negative: behind), where before ``t_s`` (seconds after
    the origin of the event times) the thresholds fitted from the sums ``s`` hold under a drift shared by all
    pixels. With ``theta(t) = theta(T) (1 + r (t - T))`` a pixel's log DN is ``theta_on(T) (A (1 - r T) + r z_on)
    - theta_off(T) (B (1 - r T) + r z_off)`` (z: the sums of its events' times, :func:`count_times`), so the fitted
    ``theta_on`` is ``theta_on(T) (1 + r lag_on)`` with ``lag_on = a_on(z_on) - T - (theta_off / theta_on)
    a_on(z_off)``, ``a_on(z)`` the x1 coefficient of z regressed on the same design (``time_sums``), and
    ``lag_off = -a_off(z_off) - T + (theta_on / theta_off) a_off(z_on)``. Exact to first order in r: it follows
    the scene (measured on the independent generator, 1 s maps, 3 s memory: 1.5-4.2 s behind, where a fixed
    1.3 memories assumed 3.9 s)."""
    (_, c12, c13, c22, c23, c33), solved, inverse_determinant = _cofactors(s)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        z_on, z_off = time_sums[:3], time_sums[3:]
        on_of = [(c12 * z0 + c22 * z1 + c23 * z2) * inverse_determinant for z0, z1, z2 in (z_on, z_off)]
        off_of = [(c13 * z0 + c23 * z1 + c33 * z2) * inverse_determinant for z0, z1, z2 in (z_on, z_off)]
        ratio = off / on
        lags = np.stack([on_of[0] - t_s - ratio * on_of[1], -off_of[1] - t_s + off_of[0] / ratio])
    return np.where(solved, lags, np.nan)


def _least_squares(s: np.ndarray, new_counts: np.ndarray, inverse_sums: np.ndarray) -> dict:
    """Per pixel, ``y = c + theta_on x1 + theta_off x2`` from the sums ``s`` (:data:`N_SUMS` rows)."""
    n = s[S_N]
    (c11, c12, c13, c22, c23, c33), solved, inverse_determinant = _cofactors(s)
    v0, v1, v2 = s[S_Y], s[S_X1Y], s[S_X2Y]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        beta0 = (c11 * v0 + c12 * v1 + c13 * v2) * inverse_determinant
        on = (c12 * v0 + c22 * v1 + c23 * v2) * inverse_determinant
        off = (c13 * v0 + c23 * v1 + c33 * v2) * inverse_determinant
        residual_ss = np.maximum(s[S_YY] - (beta0 * v0 + on * v1 + off * v2), 0.0)
        dof = np.maximum(n - 3, 1)
        variance = residual_ss / dof
        inflation = n / np.maximum(new_counts, 1)
        se_on = np.sqrt(variance * c22 * inverse_determinant * inflation)
        se_off = np.sqrt(variance * c33 * inverse_determinant * inflation)
        band = (np.abs(on) + np.abs(off)) / 2
        # a DN error e moves a frame's log by about e / signal: its frames' mean of 1 / signal scales both the read
        # noise and the bias a pixel's own offset (unknown, OFFSET_FPN_DN typical) gives the slope of its logs
        # (d log(s + e) / d log s = 1 - e / s: the darker frames weigh most, so not e over the mean signal)
        mean_inverse = np.minimum(inverse_sums / np.maximum(n, 1), 1.0)
        offset_share = OFFSET_FPN_DN * mean_inverse
        fit = np.sqrt(np.maximum(se_on / np.abs(on), se_off / np.abs(off)) ** 2 + offset_share**2)
        expected_rms = np.sqrt(band**2 / 12 + (READ_NOISE_DN * mean_inverse) ** 2)
    fit = np.where(solved, fit, np.nan)
    return {"on": np.where(solved, on, np.nan), "off": np.where(solved, off, np.nan), "n": n.copy(), "solved": solved,
            "rms": np.sqrt(variance), "expected_rms": expected_rms, "fit": fit, "mean_inverse": mean_inverse}


class FrameScaledEstimator:
    """An events-only estimate (``natural`` or ``offe``) on the absolute scale of a DAVIS recording's APS frames
    (``estimate --nominal frames``): the events give each pixel's thresholds relative to the others', the frames
    (:class:`FrameThresholdEstimator`, every pixel its least squares can solve, valid or not) their scale, one
    factor for the sensor and polarity: the median over the pixels both estimate (the frames' valid ones before
    their ``--max-fit``) of the frames' threshold over the events'. The factors' relative error (the medians'
    standard error, ``1.2533 sd / sqrt(n)``) is added to every pixel's fit. A scale per polarity also gives the
    balance of ON against OFF that events alone cannot (a scene ending brighter than it began). Measured on the
    independent DAVIS generator (``samples/frames.py``'s setups): the factors within 0.2-0.9 % of the true mean
    thresholds, even where no pixel's frames estimate is valid (5 ms exposures), and ``natural`` as accurate as
    when given the true mean as ``--nominal`` (RMS 6.2-13.4 %, within 0.1 points)."""

    def __init__(self, width: int, height: int, method: str = "natural", *, black_level=DEFAULT_BLACK_LEVEL,
                 interval_us: int | None = None, check: bool = True, **parameters) -> None:
        from evtools.estimation import ThresholdEstimator

        if interval_us is not None:
            raise EstimationError("--nominal frames works offline: an online map takes --nominal as a number")
        if method not in ("natural", "offe"):
            raise EstimationError(f"--nominal frames scales the natural and offe methods, not {method}")
        parameters.pop("nominal", None)
        self._checker = StreamChecker(StreamInfo(width, height)) if check else None
        self.events_only = ThresholdEstimator(width, height, method, nominal=1.0, check=False, **{
            name: value for name, value in parameters.items() if value is not None})
        self.frames = FrameThresholdEstimator(width, height, black_level=black_level, max_fit=math.inf, check=False)
        self.interval_us = None
        self.width, self.height = width, height

    @property
    def parameters(self) -> dict[str, Any]:
        return {**self.events_only.parameters, "nominal": "frames",
                "black_level": self.frames.parameters["black_level"]}

    def process(self, chunk: np.ndarray) -> np.ndarray:
        chunk = self._checker.check(chunk) if self._checker else as_chunk(chunk)
        self.events_only.process(chunk)
        self.frames.process(chunk)
        return chunk[:0]

    def add_frames(self, frames) -> None:
        self.frames.add_frames(frames)

    def flush(self) -> np.ndarray:
        return empty_events()

    def maps_so_far(self):
        return None

    @property
    def t_last_us(self) -> int:
        return self.frames.t_last_us

    def result(self) -> ThresholdEstimate:
        """The events-only estimate times the frames' scales (see the class); raises :class:`EstimationError` when
        the stream has no frames or too few pixels are estimated by both."""
        relative = self.events_only.result()
        try:
            by_frames = self.frames.result()
        except EstimationError:
            if self.frames.frames_used:
                raise
            raise EstimationError("no APS frames: --nominal frames takes the scale from a DAVIS recording's frames; "
                                  "give --nominal as a number (log units) for a recording without them") from None
        if "black_level_disagrees" in by_frames.attributes:  # (the frames' scale is as wrong as their thresholds)
            raise EstimationError(f"the frames give no scale: {by_frames.attributes['black_level_disagrees']}")
        both = relative.usable() & by_frames.valid
        if both.sum() < MIN_SCALE_PIXELS:
            raise EstimationError(f"the frames give no scale: {int(both.sum())} pixels are estimated by both the "
                                  f"events and the frames (need {MIN_SCALE_PIXELS}); give --nominal as a number")
        scales, errors = [], []
        for absolute, relative_map in ((by_frames.on, relative.on), (by_frames.off, relative.off)):
            ratios = (absolute / relative_map)[both]
            scales.append(float(np.median(ratios)))
            errors.append(float(1.2533 * np.std(ratios) / math.sqrt(len(ratios)) / scales[-1]))
        scale_error = max(errors)
        if "black_level_fitted_dn" in by_frames.attributes and not self.frames.black_level_checked:
            # a fitted black level shifts every pixel's frames alike: the scale by its error over their signals
            mean_inverse = self.frames._fit_all()[self.frames.black_level_index]["mean_inverse"][both.ravel()]
            scale_error = math.hypot(scale_error, BLACK_LEVEL_FIT_ERROR_DN * float(np.median(mean_inverse)))
        fit = relative.fit
        if fit is not None:
            fit = np.sqrt(fit.astype(np.float64) ** 2 + scale_error**2).astype(np.float32)
        attributes = {**relative.attributes, "nominal": "frames", "scale": "absolute", "scale_on": scales[0],
                      "scale_off": scales[1], "scale_error": scale_error, "scale_pixels": int(both.sum()),
                      "black_level": self.frames.parameters["black_level"], "frames": self.frames.frames_used,
                      **{key: by_frames.attributes[key] for key in ("black_level_used", "frames_floor_dn",
                                                                    "black_level_fitted", "black_level_disagrees")
                         if key in by_frames.attributes},
                      "on_median": relative.attributes["on_median"] * scales[0],
                      "off_median": relative.attributes["off_median"] * scales[1],
                      "not_observable": NOT_OBSERVABLE_WITH_FRAMES}
        return ThresholdEstimate(relative.on * np.float32(scales[0]), relative.off * np.float32(scales[1]),
                                 relative.valid, attributes, fit, relative.phase_us)
