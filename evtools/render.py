"""Pictures of event streams, as arrays: no files, only numpy and OpenCV (thresholds maps are figures:
:func:`evtools.plots.map_figure`).

Event frames: :class:`EventFramer` cuts a stream into consecutive time windows of ``window_us`` and, per window,
counts each pixel's ON and OFF events; :func:`event_frame` colours those counts (ON in one colour, OFF in
another, on a dark or white background). Like every stream processor of evtools, the frames never depend on
where the chunks were cut.

Every picture is RGB (``uint8``, height x width x 3); OpenCV's writers want BGR (``image[..., ::-1]``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from evtools.errors import EvtoolsError
from evtools.events import check_sensor_size

__all__ = [
    "BACKGROUNDS",
    "EventFramer",
    "FramePalette",
    "RenderError",
    "accumulate_events",
    "auto_scale",
    "event_frame",
    "event_frames",
    "upscale",
]


class RenderError(EvtoolsError, ValueError):
    """A picture that cannot be made: nothing to draw, bad parameters."""


# -- event frames --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FramePalette:
    """RGB colours of an event frame.

    Attributes
    ----------
    background : tuple of int
        Pixels without events in the window.
    on, off : tuple of int
        Pixels with more ON than OFF events, and more OFF than ON.
    both : tuple of int
        Pixels with as many ON as OFF events (at least one of each).
    """

    background: tuple[int, int, int]
    on: tuple[int, int, int]
    off: tuple[int, int, int]
    both: tuple[int, int, int]

    def table(self) -> np.ndarray:
        """The colours as a (4, 3) ``uint8`` lookup table indexed by :func:`_pixel_codes`: off, none, on, both."""
        return np.array([self.off, self.background, self.on, self.both], dtype=np.uint8)


BACKGROUNDS: dict[str, FramePalette] = {
    # Okabe & Ito's colour-blind-safe colours: ON warm (orange / vermillion), OFF cool (sky blue / blue)
    "dark": FramePalette(background=(24, 24, 24), on=(230, 159, 0), off=(86, 180, 233), both=(220, 220, 220)),
    "white": FramePalette(background=(255, 255, 255), on=(213, 94, 0), off=(0, 114, 178), both=(100, 100, 100)),
}
"""Palettes by background name. ON brightening is warm, OFF darkening cool, in colours that stay distinct for
colour-blind viewers (M. Okabe and K. Ito, "Color Universal Design", 2008)."""

_CODE_OFF, _CODE_NONE, _CODE_ON, _CODE_BOTH = 0, 1, 2, 3


def accumulate_events(events: np.ndarray, on_counts: np.ndarray, off_counts: np.ndarray) -> None:
    """Add each event to its pixel's ON or OFF count, in place.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        Events on the sensor (coordinates already checked).
    on_counts, off_counts : ndarray of uint32, shape (height, width), C-contiguous
        Per-pixel counts, updated in place. The order of the events does not matter.
    """
    if not len(events):
        return
    height, width = on_counts.shape
    index = events["y"].astype(np.intp) * width + events["x"].astype(np.intp)
    on = events["p"]
    for counts, selected in ((on_counts, index[on]), (off_counts, index[~on])):
        if len(selected) > counts.size // 8:  # dense: one pass over the sensor beats scattered adds
            counts += np.bincount(selected, minlength=counts.size).reshape(height, width).astype(counts.dtype)
        elif len(selected):
            np.add.at(counts.reshape(-1), selected, 1)


def _pixel_codes(on_counts: np.ndarray, off_counts: np.ndarray) -> np.ndarray:
    net = on_counts.astype(np.int64) - off_counts.astype(np.int64)
    codes = (np.sign(net) + 1).astype(np.uint8)  # off 0, none or tie 1, on 2
    codes[(net == 0) & (on_counts > 0)] = _CODE_BOTH
    return codes


def event_frame(on_counts: np.ndarray, off_counts: np.ndarray, background: str = "dark") -> np.ndarray:
    """Colour per-pixel event counts: the frame of one time window.

    A pixel takes the ON colour when it saw more ON than OFF events, the OFF colour for more OFF than ON, a
    neutral colour for as many of each, and the background colour without events (see :data:`BACKGROUNDS`).

    Parameters
    ----------
    on_counts, off_counts : ndarray of int, shape (height, width)
        ON and OFF events per pixel in the window.
    background : {"dark", "white"}
        The palette.

    Returns
    -------
    ndarray of uint8, shape (height, width, 3)
        RGB frame.
    """
    palette = _palette(background)
    on_counts, off_counts = np.asarray(on_counts), np.asarray(off_counts)
    if on_counts.shape != off_counts.shape or on_counts.ndim != 2:
        raise RenderError(
            f"ON and OFF counts must be two maps of one shape, got {on_counts.shape} and {off_counts.shape}"
        )
    return palette.table()[_pixel_codes(on_counts, off_counts)]


def _shade_table(palette: FramePalette) -> np.ndarray:
    """(512, 3) ``uint8``: rows 0-255 the background blended toward the OFF colour by k/255, rows 256-511 toward
    the ON colour."""
    steps = np.arange(256, dtype=np.float64)[:, None] / 255.0
    background = np.array(palette.background, np.float64)
    return np.concatenate([np.round(background + (np.array(colour, np.float64) - background) * steps)
                           for colour in (palette.off, palette.on)]).astype(np.uint8)


def colormap_table(name: str) -> np.ndarray:
    """A matplotlib colormap as a (256, 3) ``uint8`` RGB table; an unknown name raises :class:`RenderError`."""
    from matplotlib import colormaps

    if name not in colormaps:
        raise RenderError(f"unknown colormap {name!r}; for example coolwarm, RdBu_r, seismic, viridis, gray "
                          "(any of matplotlib's)")
    return np.round(colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3] * 255.0).astype(np.uint8)


def _palette(background: str) -> FramePalette:
    try:
        return BACKGROUNDS[background]
    except KeyError:
        raise RenderError(f"unknown background {background!r}; choose one of {', '.join(BACKGROUNDS)}") from None


MODES = ("accumulate", "decay", "time-surface")
"""accumulate: each window's events alone (the net polarity of each pixel); decay: every event adds +-1 to its pixel,
and the level decays by e each window (a leaky memory of the recent past); time-surface: each pixel shows its last
event, fading by e each window since (Lagorce et al., HOTS, TPAMI 2017)."""


class EventFramer:
    """Cuts a stream into time windows and makes one RGB event frame per window.

    Window ``k`` holds the events with ``start_us + k * window_us <= t < start_us + (k + 1) * window_us``.
    Every window from the first to the one holding the last event gives a frame, empty windows included (a
    video keeps its clock); events before ``start_us`` are skipped. State is sized from the sensor, so memory
    does not grow with the stream, and the frames do not depend on where the chunks were cut.

    Parameters
    ----------
    width, height : int
        Sensor size in pixels.
    window_us : int
        Length of a window, microseconds (> 0).
    start_us : int or None
        Start of the first window, microseconds; None: the first event's time.
    background : {"dark", "white"}
        Palette of the frames (:data:`BACKGROUNDS`).
    mode : {"accumulate", "decay", "time-surface"}
        How a frame shows the events (:data:`MODES`).
    colormap : str or None
        decay and time-surface: a matplotlib colormap name (``coolwarm``, ``viridis``, ``gray``...) that colours
        each pixel's signed value, -1 (OFF) .. +1 (ON), 0 in its middle; None: the palette's ON and OFF colours
        fading into the background.

    Attributes
    ----------
    events_used : int
        Events counted into frames so far (not those before ``start_us``).
    first_t_us, last_t_us : int or None
        Times of the first and the last event seen, counted or not.
    """

    def __init__(
        self, width: int, height: int, window_us: int, *, start_us: int | None = None, background: str = "dark",
        mode: str = "accumulate", colormap: str | None = None,
    ) -> None:
        check_sensor_size(width, height)
        if int(window_us) != window_us or window_us <= 0:
            raise RenderError(f"window length must be a whole number of microseconds > 0, got {window_us}")
        if mode not in MODES:
            raise RenderError(f"unknown mode {mode!r}; choose one of {', '.join(MODES)}")
        self.mode = mode
        self.width, self.height, self.window_us = int(width), int(height), int(window_us)
        # decay: each event adds +-1 that decays by e every window; time-surface: each pixel's last event fades by e
        # every window (both carried from window to window)
        self._level = np.zeros((self.height, self.width), np.float64)
        self._gain = np.zeros((self.height, self.width), np.float64)
        self._last_us = np.full((self.height, self.width), np.iinfo(np.int64).min // 2, np.int64)
        self._last_on = np.zeros((self.height, self.width), bool)
        self.palette = _palette(background)
        self.background = background
        if colormap is not None and mode == "accumulate":
            raise RenderError("a colormap colours the decay and time-surface modes; accumulate uses the ON/OFF colours")
        self.colormap = colormap
        self._table = self.palette.table()
        self._shades = _shade_table(self.palette) if colormap is None else colormap_table(colormap)
        self._window_start_us = None if start_us is None else int(start_us)
        self._on = np.zeros((self.height, self.width), dtype=np.uint32)
        self._off = np.zeros((self.height, self.width), dtype=np.uint32)
        self.events_used = 0
        self.first_t_us: int | None = None
        self.last_t_us: int | None = None

    def process(self, chunk: np.ndarray) -> Iterator[tuple[int, np.ndarray]]:
        """Count a chunk; yield ``(window_start_us, rgb_frame)`` for every window that it completes.

        This is a generator: the chunk is counted only as the frames are taken, so consume it whole before
        the next call.
        """
        if not len(chunk):
            return
        t = chunk["t"]
        if self.first_t_us is None:
            self.first_t_us = int(t[0])
        self.last_t_us = int(t[-1])
        if self._window_start_us is None:
            self._window_start_us = int(t[0])
        i = int(np.searchsorted(t, self._window_start_us, side="left"))  # before the first window: skipped
        while i < len(chunk):
            end_us = self._window_start_us + self.window_us
            j = int(np.searchsorted(t, end_us, side="left"))
            if self.mode == "accumulate":
                accumulate_events(chunk[i:j], self._on, self._off)
            else:
                self._remember(chunk[i:j])
            self.events_used += j - i
            if j == len(chunk):
                return
            yield self._window_start_us, self._take_frame()
            self._window_start_us = end_us
            empty_windows = (int(t[j]) - self._window_start_us) // self.window_us
            for _ in range(empty_windows):
                yield self._window_start_us, self._blank()
                self._window_start_us += self.window_us
            i = j

    def flush(self) -> Iterator[tuple[int, np.ndarray]]:
        """Yield the frame of the last, unfinished window (nothing if no event reached a window)."""
        if self.events_used:
            yield self._window_start_us, self._take_frame()

    @property
    def background_rgb(self) -> tuple[int, int, int]:
        """The colour of a pixel without events: the palette's background, or the colormap's middle."""
        if self.colormap is None:
            return tuple(self.palette.background)
        return tuple(int(v) for v in self._shades[127])

    def _remember(self, events: np.ndarray) -> None:
        """decay and time-surface: the window's events into the carried state (order within a pixel kept)."""
        if not len(events):
            return
        flat = events["y"].astype(np.int64) * self.width + events["x"]
        if self.mode == "decay":  # +-exp((t - window start) / window): at the window's end, times exp(-1)
            weight = np.exp((events["t"] - self._window_start_us) / self.window_us)
            np.add.at(self._gain.reshape(-1), flat, np.where(events["p"], weight, -weight))
        else:  # the last event of each pixel: events are time-sorted, so the last write of a pixel wins
            order = np.unique(flat[::-1], return_index=True)[1]
            last = len(flat) - 1 - order
            self._last_us.reshape(-1)[flat[last]] = events["t"][last]
            self._last_on.reshape(-1)[flat[last]] = events["p"][last]

    def _take_frame(self) -> np.ndarray:
        if self.mode == "decay":
            self._level = (self._level + self._gain) * math.exp(-1.0)
            self._gain.fill(0.0)
            return self._shade(np.tanh(np.abs(self._level)), self._level > 0)
        if self.mode == "time-surface":
            end_us = self._window_start_us + self.window_us
            return self._shade(np.exp(-(end_us - self._last_us) / self.window_us), self._last_on)
        frame = self._table[_pixel_codes(self._on, self._off)]
        self._on.fill(0)
        self._off.fill(0)
        return frame

    def _shade(self, strength: np.ndarray, on: np.ndarray) -> np.ndarray:
        """The background blended toward the ON or OFF colour by ``strength`` (0..1), or with a colormap the
        colour of the signed value (+-strength), each through a table of 256 steps (within one unit of the exact
        blend)."""
        level = np.rint(np.clip(strength, 0.0, 1.0) * 255.0).astype(np.intp)
        if self.colormap is None:
            return self._shades[level + 256 * on]
        return self._shades[np.where(on, 255 + level, 255 - level) >> 1]

    def _blank(self) -> np.ndarray:
        if self.mode != "accumulate":  # the carried state fades on
            return self._take_frame()
        return np.broadcast_to(np.array(self.palette.background, np.uint8), (self.height, self.width, 3)).copy()


def event_frames(
    events: np.ndarray, width: int, height: int, window_us: int, *, start_us: int | None = None,
    background: str = "dark", mode: str = "accumulate", colormap: str | None = None,
) -> list[tuple[int, np.ndarray]]:
    """All frames of one array of events: :class:`EventFramer` ``process`` then ``flush``.

    Returns
    -------
    list of (int, ndarray)
        ``(window_start_us, rgb_frame)`` per window, frames of shape (height, width, 3).
    """
    framer = EventFramer(width, height, window_us, start_us=start_us, background=background, mode=mode,
                         colormap=colormap)
    return [*framer.process(events), *framer.flush()]


MAX_IMAGE_PIXELS = 1 << 28
"""The largest picture drawn (268 M pixels, 0.8 GB as RGB): a Gen4 sensor at --scale 64 would be 3.8 G pixels,
and was killed for memory with no message."""


def check_image_size(width: int, height: int, scale: int) -> None:
    """Refuse a ``width x height`` picture enlarged ``scale`` times beyond :data:`MAX_IMAGE_PIXELS`."""
    pixels = width * scale * height * scale
    if pixels > MAX_IMAGE_PIXELS:
        raise RenderError(f"a {width}x{height} picture at scale {scale} would be {width * scale}x{height * scale} "
                          f"pixels ({pixels * 3 / 2**30:,.1f} GB): give a smaller --scale")


def upscale(image: np.ndarray, factor: int) -> np.ndarray:
    """Enlarge an image ``factor`` times in each direction by repeating pixels (nearest neighbour, exact)."""
    factor = int(factor)
    if factor < 1:
        raise RenderError(f"scale must be a whole number >= 1, got {factor}")
    if factor == 1:
        return image
    check_image_size(image.shape[1], image.shape[0], factor)
    import cv2

    height, width = image.shape[:2]
    return cv2.resize(np.ascontiguousarray(image), (width * factor, height * factor),
                      interpolation=cv2.INTER_NEAREST_EXACT)


def auto_scale(width: int, height: int, target_px: int = 480, max_factor: int = 16) -> int:
    """The smallest whole factor that makes the longer side of a ``width x height`` picture >= ``target_px``."""
    return int(min(max_factor, max(1, math.ceil(target_px / max(width, height)))))


