"""How well a recording's events predict its own APS frames (``metrics reconstruction`` without ``--truth``): the
evaluation of Wang et al. (ACRA 2019) on real data, with the complementary view of Scheerlinck et al. (ACCV 2018).

Each frame is predicted from the one before it and the events between them: a pixel's log intensity at the
exposure's middle is the previous frame's plus ``theta_on`` per ON event minus ``theta_off`` per OFF event (its
thresholds: one constant, an estimated map, or after ``correct`` the target). The error, over the pixels that are
neither dark nor saturated in both frames, is compared with holding the previous frame (no events): what the events
explain. Frames are the APS's log DN (``log(DN - black) - log(exposure)``), so a pixel's unknown gain cancels in
the difference; thresholds on the absolute scale (``estimate --method frames``, a known stimulus) are what make the
prediction right, and a map that is wrong per pixel shows as a larger error than a good one.
"""

from __future__ import annotations

import math

import numpy as np

import logging

from evtools.estimation_frames import (FRAMES_FLOOR_DN, MIN_SIGNAL_DN, SATURATED_DN, FrameThresholdEstimator,
                                       frames_floor)
from evtools.metrics.reconstruction import ReconstructionError


class FramePrediction(FrameThresholdEstimator):
    """Feeds events and frames as :class:`FrameThresholdEstimator` does (the same order, held events, late frames
    left out), and scores each frame's prediction from the previous frame and the events between them. A black level
    not given (None) is 0, DV's, and a first frame whose floor says the frames may not be black-subtracted
    (:data:`~evtools.estimation_frames.FRAMES_FLOOR_DN`) is warned of: a level left in the frames compresses their
    log changes, so a smaller contrast than the true one predicts them best (a QA sweep: 0.12 for 0.2 at 30 DN)."""

    def __init__(self, width: int, height: int, contrast_on, contrast_off, *, black_level: float | None = None,
                 check: bool = True) -> None:
        if black_level is not None and (isinstance(black_level, (str, bool)) or not np.isfinite(black_level)
                                        or black_level < 0):  # ("fit", the estimator's, scored with 0: a review)
            raise ReconstructionError(f"black level must be a number of DN >= 0 (or None: 0), got {black_level!r}")
        super().__init__(width, height, black_level=black_level, check=check)
        pixels = width * height
        self.theta_on = np.broadcast_to(np.asarray(contrast_on, np.float64), (height, width)).reshape(pixels)
        self.theta_off = np.broadcast_to(np.asarray(contrast_off, np.float64), (height, width)).reshape(pixels)
        if not (np.all(np.isfinite(self.theta_on)) and np.all(self.theta_on > 0) and np.all(np.isfinite(
                self.theta_off)) and np.all(self.theta_off > 0)):
            raise ReconstructionError("every threshold must be a positive number of log units")
        self.black = float(self.candidates[0])
        self.previous: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # log frame, usable, counts
        self.pairs: list[dict] = []

    def _use(self, frame) -> None:
        if not self._fits(frame):
            return
        if self.black_level_auto and self.frames_floor_dn is None:
            self.frames_floor_dn = frames_floor(frame.image)
            if self.frames_floor_dn >= FRAMES_FLOOR_DN:
                logging.getLogger("evtools").warning(
                    f"the first frame never reads below {self.frames_floor_dn:g} DN (frames not black-subtracted, or "
                    "a bright scene) and the black level is taken as 0: a level left in the frames makes a smaller "
                    "contrast predict best; give --black-level (the camera's, or estimate --method frames' "
                    "black_level_used)")
        dn, inside = self._full(frame)
        signal = dn - self.black
        usable = inside & (signal >= MIN_SIGNAL_DN) & (dn < SATURATED_DN)
        log_frame = np.log(np.maximum(signal, 1.0)) - math.log(max(frame.exposure_us, 1) * 1e-6)
        counts = self.counts[:, :2].astype(np.float64)  # at the exposure's middle
        if self.previous is not None:
            previous_log, previous_usable, previous_counts = self.previous
            both = usable & previous_usable
            change = counts - previous_counts
            predicted = previous_log + self.theta_on * change[:, 0] - self.theta_off * change[:, 1]
            if both.any():
                self.pairs.append({
                    "t_us": int(frame.t_us), "pixels": int(both.sum()),
                    "sq_error": float(np.sum((log_frame - predicted)[both] ** 2)),
                    "sq_hold": float(np.sum((log_frame - previous_log)[both] ** 2)),
                    "events": int(change[both].sum()),
                })
        self.previous = (log_frame, usable, counts)
        self.frames_used += 1

    def _full(self, frame) -> tuple[np.ndarray, np.ndarray]:
        """The frame's DN on the whole sensor (flattened, float64) and where it has pixels (it fits the sensor)."""
        height, width = frame.image.shape
        x0, y0 = frame.offset_x, frame.offset_y
        if (x0, y0, width, height) == (0, 0, self.width, self.height):
            return frame.image.astype(np.float64).reshape(-1), np.ones(self.width * self.height, bool)
        dn = np.zeros((self.height, self.width))
        inside = np.zeros((self.height, self.width), bool)
        dn[y0:y0 + height, x0:x0 + width] = frame.image
        inside[y0:y0 + height, x0:x0 + width] = True
        return dn.reshape(-1), inside.reshape(-1)

    def scores(self) -> dict:
        """RMS prediction error (log units) over every compared pixel and pair, the same for holding the previous
        frame, the share of the hold's squared error the events explain, and per pair."""
        self._advance(final=True)
        if self.frames_used == 0:
            raise ReconstructionError("no APS frames: give --truth TRUTH.h5, or a recording with frames (a DAVIS "
                                      "camera's, or simulate --aps-rate)")
        if not self.pairs:
            raise ReconstructionError(f"{self.frames_used} APS frame(s) without two usable in a row: nothing to "
                                      "predict")
        pixels = sum(pair["pixels"] for pair in self.pairs)
        error = sum(pair["sq_error"] for pair in self.pairs)
        hold = sum(pair["sq_hold"] for pair in self.pairs)
        return {
            "frames": self.frames_used, "pairs": len(self.pairs), "pixels_per_pair": pixels / len(self.pairs),
            "rmse": math.sqrt(error / pixels), "rmse_hold": math.sqrt(hold / pixels),
            "explained": 1.0 - error / hold if hold > 0 else float("nan"), "black_level": self.black,
            **({} if self.frames_floor_dn is None else {"frames_floor_dn": self.frames_floor_dn}),
            "rmse_per_pair": [math.sqrt(pair["sq_error"] / pair["pixels"]) for pair in self.pairs],
            "frames_late": self.frames_late,
        }
