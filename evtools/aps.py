"""A DAVIS camera's APS (active pixel sensor) frames, simulated beside the events (``simulate --aps-rate``).

The model is linear and global-shutter: every pixel integrates the scene's intensity ``I(t)`` (0-255, the same
intensity whose lin-log the DVS pixels see) over one exposure window, and its digital number is

    DN = round(offset_px + gain_px * exposure_ms * mean(I over the exposure) + read noise), clipped to 0..255

with a per-pixel gain ``gain_px = gain * (1 + gain_fpn * N(0, 1))`` (photo-response non-uniformity), a per-pixel
offset ``offset_px = black_level + offset_fpn * N(0, 1)`` (dark signal non-uniformity), read noise
``read_noise * N(0, 1)`` per pixel and frame, 8-bit quantisation and saturation at 255. Between the simulator's
input frames the intensity is linear in time, so the integral over a window is exact for that signal. Frames start
with the first input frame and follow every ``1 / rate``; each is complete at the end of its exposure.

References: the DAVIS pixel (Brandli, Berner, Yang, Liu, Delbruck, "A 240 x 180 130 dB 3 us latency global shutter
spatiotemporal vision sensor", IEEE JSSC 2014); the linear photon-transfer model of EMVA standard 1288.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evtools.errors import EvtoolsError, UsageMistake
from evtools.frames import Frame

APS_DEFAULTS = {
    "aps_exposure_us": 10_000,
    "aps_gain": 0.08,
    "aps_black_level": 0.0,
    "aps_read_noise": 1.5,
    "aps_gain_fpn": 0.01,
    "aps_offset_fpn": 2.0,
}
"""The APS model's defaults: exposure 10 ms; 0.08 DN per intensity level per ms of exposure (the brightest level,
255, gives 204 DN at 10 ms and saturates from 12.5 ms); black level 0 DN (DV's DAVIS frames are black-subtracted by
correlated double sampling: their darkest pixels read 0, as in the DAVIS346 recordings of the tests); read noise
1.5 DN; gain non-uniformity 1 %; offset non-uniformity 2 DN."""
APS_MAX_DN = 255
APS_SEED_KEY = 0x415053  # "APS": the APS's draws come from the simulator's seed, apart from the DVS's
MAX_APS_RATE_HZ = 10_000.0


class ApsError(EvtoolsError, ValueError):
    """An APS parameter that cannot be used."""


class ApsSettingsError(ApsError, UsageMistake):
    """APS settings that do not go together (an exposure as long as the frame interval): a usage error (exit 2)."""


@dataclass
class ApsFrame:
    """A simulated APS frame and its truth: the scene's log intensity (lin-log) at the exposure's middle and its
    mean intensity over the exposure."""

    frame: Frame
    true_log: np.ndarray
    mean_intensity: np.ndarray


class ApsSensor:
    """The APS of a ``width x height`` DAVIS: fed the simulator's input frames (:meth:`add`), it returns the APS
    frames whose exposure has ended. Draws depend only on ``seed`` and the frame's index, never on batching."""

    def __init__(self, width: int, height: int, rate_hz: float, seed: int, *,
                 aps_exposure_us: int = APS_DEFAULTS["aps_exposure_us"], aps_gain: float = APS_DEFAULTS["aps_gain"],
                 aps_black_level: float = APS_DEFAULTS["aps_black_level"],
                 aps_read_noise: float = APS_DEFAULTS["aps_read_noise"],
                 aps_gain_fpn: float = APS_DEFAULTS["aps_gain_fpn"],
                 aps_offset_fpn: float = APS_DEFAULTS["aps_offset_fpn"]) -> None:
        if not 0 < rate_hz <= MAX_APS_RATE_HZ:
            raise ApsError(f"the APS frame rate must be above 0 and at most {MAX_APS_RATE_HZ:g} Hz, not {rate_hz:g}")
        self.period_us = 1e6 / rate_hz
        if not 0 < aps_exposure_us < self.period_us:
            raise ApsSettingsError(f"the APS exposure ({aps_exposure_us} us) must be above 0 and shorter than the frame "
                           f"interval ({self.period_us:g} us at {rate_hz:g} Hz): a global shutter reads a frame "
                           "before the next exposure")
        for name, value in (("gain", aps_gain), ("black level", aps_black_level), ("read noise", aps_read_noise),
                            ("gain non-uniformity", aps_gain_fpn), ("offset non-uniformity", aps_offset_fpn)):
            if not np.isfinite(value) or value < 0:
                raise ApsError(f"the APS {name} must be finite and >= 0, not {value}")
        self.width, self.height, self.seed = width, height, seed
        self.exposure_us = int(aps_exposure_us)
        self.parameters = {"aps_rate_hz": rate_hz, "aps_exposure_us": self.exposure_us, "aps_gain": aps_gain,
                           "aps_black_level": aps_black_level, "aps_read_noise": aps_read_noise,
                           "aps_gain_fpn": aps_gain_fpn, "aps_offset_fpn": aps_offset_fpn}
        rng = np.random.default_rng([seed, APS_SEED_KEY])
        self.gain_map = (aps_gain * (1 + aps_gain_fpn * rng.standard_normal((height, width)))).astype(np.float32)
        self.offset_map = (aps_black_level + aps_offset_fpn * rng.standard_normal((height, width))).astype(np.float32)
        self.read_noise = aps_read_noise
        self.index = 0  # the next frame's
        self.begin_us: float | None = None  # the open exposure's start
        self.integral = np.zeros((height, width), np.float64)  # of I over the open exposure so far (level us)
        self.middle: np.ndarray | None = None
        self.last: tuple[int, np.ndarray] | None = None

    def add(self, t_us: int, frame: np.ndarray) -> list[ApsFrame]:
        """The input frame at ``t_us`` (intensity 0-255); the APS frames completed up to it."""
        frame = np.maximum(np.asarray(frame, np.float64), 0.0)
        done: list[ApsFrame] = []
        if self.last is None:
            self.begin_us, self.last = float(t_us), (t_us, frame)
            return done
        t0, before = self.last
        while True:
            begin, end = self.begin_us, self.begin_us + self.exposure_us
            middle = (begin + end) / 2
            if t0 <= middle <= t_us and self.middle is None:
                self.middle = self._at(t0, before, t_us, frame, middle)
            low, high = max(begin, t0), min(end, t_us)
            if high > low:  # the intensity is linear between two input frames: the trapezoid is exact
                self.integral += (high - low) * (self._at(t0, before, t_us, frame, low)
                                                 + self._at(t0, before, t_us, frame, high)) / 2
            if end > t_us:
                break
            done.append(self._read_out(begin, end))
            self.begin_us = begin + self.period_us
            if self.begin_us > t_us:
                break
        self.last = (t_us, frame)
        return done

    @staticmethod
    def _at(t0: int, before: np.ndarray, t1: int, after: np.ndarray, t: float) -> np.ndarray:
        share = (t - t0) / (t1 - t0)
        return before + (after - before) * share

    def _read_out(self, begin: float, end: float) -> ApsFrame:
        from evtools.simulation import lin_log

        mean = self.integral / self.exposure_us
        noise = np.random.default_rng([self.seed, APS_SEED_KEY, self.index]).standard_normal(mean.shape)
        dn = self.offset_map + self.gain_map * (self.exposure_us / 1000) * mean + self.read_noise * noise
        image = np.clip(np.round(dn), 0, APS_MAX_DN).astype(np.uint8)
        b, e = int(round(begin)), int(round(begin)) + self.exposure_us
        frame = Frame(image, (b + e) // 2, b, e, b, e)
        truth = ApsFrame(frame, lin_log(self.middle).astype(np.float32), mean.astype(np.float32))
        self.index += 1
        self.integral[:] = 0
        self.middle = None
        return truth
