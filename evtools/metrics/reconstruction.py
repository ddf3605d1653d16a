"""How well a stream's events reconstruct the true log intensity: the downstream measure of ``correct``.

Each pixel's log intensity is reconstructed with the continuous-time complementary filter of Scheerlinck, Barnes and
Mahony (ACCV 2018) whose low-frequency input is the first true frame: per pixel, ``L(t) = L_F + s(t)`` where each
event adds ``+c_on`` or ``-c_off`` to ``s`` (its contrast: the pixel's thresholds, or one value), and between
events ``s`` decays as ``exp(-alpha dt)`` with ``alpha = 2 pi cutoff`` (``cutoff = 0``: pure integration, no
forgetting). ``L_F`` is the first true frame: the events carry only changes. :class:`HighPassReconstructor` is a
stream processor (the state carries over chunks, so the result does not depend on where the stream is cut);
:func:`reconstruction_errors` compares its snapshots with the true frames: RMSE and SSIM per frame and overall.

References
----------
C. Scheerlinck, N. Barnes, R. Mahony, "Continuous-time Intensity Estimation Using Event Cameras", ACCV 2018.
Z. Wang, A. C. Bovik, H. R. Sheikh, E. P. Simoncelli, "Image quality assessment: from error visibility to
structural similarity", IEEE TIP 13(4), 2004 (SSIM: Gaussian window sigma 1.5, K1 0.01, K2 0.03).
"""

from __future__ import annotations

import math

import numpy as np

from evtools._kernels.reconstruction import integrate_events
from evtools.errors import EvtoolsError
from evtools.events import StreamChecker, StreamInfo

__all__ = ["HighPassReconstructor", "ReconstructionError", "reconstruction_errors", "ssim"]


class ReconstructionError(EvtoolsError, ValueError):
    """Bad frames, contrasts or cut-off for the reconstruction."""


class HighPassReconstructor:
    """Reconstructs every pixel's log intensity at the given frame times, chunk by chunk.

    Parameters
    ----------
    baseline : ndarray, shape (height, width)
        ``L_F``: the log intensity the filter starts from and decays towards (the first true frame).
    frame_times_us : array of int
        When to take the snapshots (increasing); a snapshot at ``t`` includes the events at ``t``.
    contrast_on, contrast_off : float or ndarray (height, width)
        What an ON / OFF event adds / removes (log units, > 0).
    cutoff_hz : float
        The high-pass cut-off ``alpha / 2 pi`` (>= 0; 0: pure integration).
    """

    def __init__(self, baseline, frame_times_us, contrast_on, contrast_off, cutoff_hz: float = 0.0):
        self.baseline = np.asarray(baseline, dtype=np.float64)
        if self.baseline.ndim != 2:
            raise ReconstructionError("the baseline must be one frame (height x width)")
        self.height, self.width = self.baseline.shape
        self.frame_times_us = np.asarray(frame_times_us, dtype=np.int64)
        if self.frame_times_us.ndim != 1 or np.any(np.diff(self.frame_times_us) <= 0):
            raise ReconstructionError("frame times must increase")
        shape = self.baseline.shape
        self.contrast_on = _contrast(contrast_on, shape, "ON")
        self.contrast_off = _contrast(contrast_off, shape, "OFF")
        cutoff_hz = float(cutoff_hz)
        if not math.isfinite(cutoff_hz) or cutoff_hz < 0:
            raise ReconstructionError(f"the cut-off must be a number of Hz >= 0, got {cutoff_hz}")
        self.rate_per_us = 2 * math.pi * cutoff_hz * 1e-6
        self.level = np.zeros(self.width * self.height)  # 0 until a pixel's first event: no decay to start from
        self.last_us = np.zeros(self.width * self.height, dtype=np.int64)
        self.frames: list[np.ndarray] = []
        self._checker = StreamChecker(StreamInfo(self.width, self.height), hint=" (the frames' size)")

    def _snapshot(self, t_us: int) -> None:
        decay = np.exp(-self.rate_per_us * (t_us - self.last_us)) if self.rate_per_us > 0 else 1.0
        self.frames.append(self.baseline + (self.level * decay).reshape(self.height, self.width))

    def process(self, chunk: np.ndarray) -> None:
        """Integrate ``chunk`` (time-sorted, after the previous ones), taking the snapshots it passes."""
        chunk = self._checker.check(chunk)  # on the frames (the kernel indexes by the coordinates), in time order
        if len(chunk) == 0:
            return
        t = chunk["t"]
        start = 0
        while len(self.frames) < len(self.frame_times_us):
            frame_us = int(self.frame_times_us[len(self.frames)])
            stop = int(np.searchsorted(t, frame_us, side="right"))
            if stop >= len(t):
                break
            self._integrate(chunk[start:stop])
            self._snapshot(frame_us)
            start = stop
        self._integrate(chunk[start:])

    def _integrate(self, part: np.ndarray) -> None:
        if len(part):
            integrate_events(part["t"].astype(np.int64), part["x"].astype(np.int64), part["y"].astype(np.int64),
                             part["p"], self.width, self.level, self.last_us, self.contrast_on, self.contrast_off,
                             self.rate_per_us)

    def flush(self) -> np.ndarray:
        """Every snapshot, ``(n_frames, height, width)`` (those after the last event from the state at the end)."""
        while len(self.frames) < len(self.frame_times_us):
            self._snapshot(int(self.frame_times_us[len(self.frames)]))
        return np.stack(self.frames) if self.frames else np.empty((0, self.height, self.width))


def _contrast(value, shape, name) -> np.ndarray:
    array = np.broadcast_to(np.asarray(value, dtype=np.float64), shape) if np.ndim(value) == 0 else \
        np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise ReconstructionError(f"{name} contrasts are {array.shape[1]}x{array.shape[0]} but the frames are "
                                  f"{shape[1]}x{shape[0]}")
    if not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise ReconstructionError(f"{name} contrasts must be finite and positive")
    return np.ascontiguousarray(array).reshape(-1)


def ssim(a: np.ndarray, b: np.ndarray, data_range: float) -> float:
    """Mean structural similarity of two frames (Wang et al. 2004: Gaussian window sigma 1.5, K1 0.01, K2 0.03)."""
    import cv2

    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2

    def blur(image):
        return cv2.GaussianBlur(image, (11, 11), 1.5, borderType=cv2.BORDER_REFLECT)

    a, b = a.astype(np.float64), b.astype(np.float64)
    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a ** 2
    var_b = blur(b * b) - mu_b ** 2
    cov = blur(a * b) - mu_a * mu_b
    index = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))
    return float(index.mean())


def reconstruction_errors(estimated: np.ndarray, truth: np.ndarray) -> dict:
    """RMSE (log units) and SSIM of each estimated frame against the true one, and over all frames (RMSE of every
    pixel of every frame; mean SSIM). The SSIM data range is the true frames' range (at least 1e-6)."""
    if estimated.shape != truth.shape:
        raise ReconstructionError(f"{estimated.shape} estimated frames for {truth.shape} true ones")
    if len(truth) == 0:
        raise ReconstructionError("no frames to compare")
    data_range = max(float(truth.max() - truth.min()), 1e-6)
    error = estimated - truth
    rmse = np.sqrt(np.mean(error ** 2, axis=(1, 2)))
    ssims = np.array([ssim(e, t, data_range) for e, t in zip(estimated, truth)])
    return {"frames": len(truth), "rmse": float(np.sqrt(np.mean(error ** 2))), "ssim": float(ssims.mean()),
            "rmse_per_frame": rmse.tolist(), "ssim_per_frame": ssims.tolist()}
