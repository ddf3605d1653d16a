"""Pictures of event streams and of thresholds maps, as arrays: no files, only numpy and OpenCV.

Event frames: :class:`EventFramer` cuts a stream into consecutive time windows of ``window_us`` and, per window,
counts each pixel's ON and OFF events; :func:`event_frame` colours those counts (ON in one colour, OFF in
another, on a dark or white background). Like every stream processor of evtools, the frames never depend on
where the chunks were cut.

Thresholds maps: :func:`thresholds_picture` draws the ON and OFF maps side by side in a perceptual colormap
(viridis) on one shared scale, with a colour bar, the value range and a line of statistics per map; pixels
without a valid value are grey.

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
    "INVALID_RGB",
    "MapPicture",
    "RenderError",
    "accumulate_events",
    "auto_scale",
    "event_frame",
    "event_frames",
    "thresholds_picture",
    "upscale",
]


class RenderError(EvtoolsError, ValueError):
    """A picture that cannot be made: nothing to draw, maps of the wrong shape, bad parameters."""


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


# -- thresholds maps -----------------------------------------------------------------------------------------------

INVALID_RGB = (128, 128, 128)
"""Colour of map pixels without a valid value."""

_WHITE, _BLACK, _FRAME_RGB = (255, 255, 255), (0, 0, 0), (90, 90, 90)
_FONT_SCALE = 0.45
_MARGIN_PX, _GAP_PX, _BAR_WIDTH_PX, _LINE_PX = 16, 24, 20, 20
_FAR_OUT_IQR = 3.0


@dataclass
class MapPicture:
    """A picture of an ON and an OFF thresholds map.

    Attributes
    ----------
    image : ndarray of uint8, shape (rows, columns, 3)
        The RGB picture.
    on_origin, off_origin : tuple of int
        ``(x, y)`` of each map's top-left pixel in ``image``; map pixel ``(row, col)`` covers
        ``image[y + row * scale : y + (row + 1) * scale, x + col * scale : ...]``.
    scale : int
        Picture pixels per map pixel, in each direction.
    value_range : tuple of float
        Values drawn at the two ends of the colormap (values beyond are drawn as the end colours).
    """

    image: np.ndarray
    on_origin: tuple[int, int]
    off_origin: tuple[int, int]
    scale: int
    value_range: tuple[float, float]


def _valid_masks(on: np.ndarray, off: np.ndarray, valid) -> tuple[np.ndarray, np.ndarray]:
    on_valid, off_valid = np.isfinite(on), np.isfinite(off)
    if valid is not None:
        valid = np.asarray(valid).astype(bool)
        if valid.shape == on.shape:
            on_valid &= valid
            off_valid &= valid
        elif valid.shape == (2, *on.shape):
            on_valid &= valid[0]
            off_valid &= valid[1]
        else:
            raise RenderError(
                f"valid mask of shape {valid.shape} does not match the {on.shape[0]} x {on.shape[1]} maps"
            )
    return on_valid, off_valid


def _display_range(values: np.ndarray) -> tuple[float, float]:
    """min..max of ``values``, narrowed to Tukey's far-out fences (quartile -+ 3 IQR) so that a few wild pixels
    (dead pixels, failed fits) do not squash everyone else's colours into one end of the colormap."""
    low, high = float(values.min()), float(values.max())
    q1, q3 = np.percentile(values, [25.0, 75.0])
    iqr = float(q3 - q1)
    if iqr > 0:
        low, high = max(low, float(q1) - _FAR_OUT_IQR * iqr), min(high, float(q3) + _FAR_OUT_IQR * iqr)
    return low, high


def _colour(values: np.ndarray, value_range: tuple[float, float], colormap: int) -> np.ndarray:
    import cv2

    low, high = value_range
    if high > low:
        unit = np.clip((values.astype(np.float64) - low) / (high - low), 0.0, 1.0)
    else:
        unit = np.full(values.shape, 0.5)
    levels = np.nan_to_num(np.rint(unit * 255.0), nan=0.0).astype(np.uint8)
    return cv2.applyColorMap(levels, colormap)[..., ::-1]  # OpenCV's BGR to RGB


def _number(value: float) -> str:
    return f"{value:.4g}"


def _stats(name: str, values: np.ndarray, count: int) -> str:
    if not len(values):
        return f"{name}: no valid pixels"
    text = (f"{name}: mean {_number(values.mean())}, std {_number(values.std())}, "
            f"min {_number(values.min())}, max {_number(values.max())}")
    return text + (f", {count - len(values)} invalid" if len(values) < count else "")


def thresholds_picture(
    on: np.ndarray,
    off: np.ndarray,
    valid: np.ndarray | None = None,
    *,
    value_range: tuple[float, float] | None = None,
    scale: int | None = None,
    colormap: str | None = None,
    units: str = "",
    titles: tuple[str, str] = ("ON threshold", "OFF threshold"),
) -> MapPicture:
    """Draw an ON and an OFF thresholds map side by side, on one colour scale, with a colour bar.

    Parameters
    ----------
    on, off : ndarray, shape (height, width)
        The maps (log units for evtools' thresholds; any real values).
    valid : ndarray of bool, shape (height, width) or (2, height, width), optional
        False where a map has no trustworthy value (one mask for both maps, or ON's then OFF's). Those pixels,
        and non-finite ones, are drawn grey (:data:`INVALID_RGB`) and left out of the scale and statistics.
    value_range : (float, float), optional
        Values at the two ends of the colormap, to compare pictures on one scale. Default: the valid values'
        min to max, narrowed to Tukey's far-out fences (quartiles -+ 3 interquartile ranges) so that a few
        wild pixels do not flatten the rest; a bar end that clips values is labelled with ``<=`` or ``>=``.
    scale : int, optional
        Picture pixels per map pixel (nearest neighbour). Default: enough for maps about 256 pixels wide.
    colormap : str, optional
        A matplotlib colormap name; default viridis, perceptually uniform and colour-blind safe.
    units : str
        Unit of the values, written under the colour bar.
    titles : (str, str)
        Written above the maps.

    Returns
    -------
    MapPicture
        The RGB picture and where each map lies in it.

    Raises
    ------
    RenderError
        When the maps differ in shape or are not 2-D, the mask does not fit, or no pixel has a valid value.
    """
    import cv2

    on, off = np.asarray(on), np.asarray(off)
    if on.ndim != 2 or on.shape != off.shape or 0 in on.shape:
        raise RenderError(
            f"ON and OFF maps must be two non-empty 2-D maps of one shape, got {on.shape} and {off.shape}"
        )
    try:
        on, off = on.astype(np.float64), off.astype(np.float64)
    except (TypeError, ValueError):
        raise RenderError("the maps do not hold numbers") from None
    on_valid, off_valid = _valid_masks(on, off, valid)
    values = np.concatenate([on[on_valid], off[off_valid]])
    if not len(values):
        raise RenderError("no pixel of the maps has a valid (finite, unmasked) value")
    if value_range is None:
        value_range = _display_range(values)
    low, high = (float(v) for v in value_range)
    if not (math.isfinite(low) and math.isfinite(high)) or high < low:
        raise RenderError(f"value range {low} .. {high} is not an increasing pair of finite numbers")
    colormap = cv2.COLORMAP_VIRIDIS if colormap is None else colormap_table(colormap)[:, ::-1].reshape(256, 1, 3).copy()
    height, width = on.shape
    scale = auto_scale(width, height, target_px=256) if scale is None else int(scale)
    if scale < 1:
        raise RenderError(f"scale must be a whole number >= 1, got {scale}")
    check_image_size(width, height, scale)
    map_w, map_h = width * scale, height * scale

    font = cv2.FONT_HERSHEY_SIMPLEX
    (_, text_h), baseline = cv2.getTextSize("Ag", font, _FONT_SCALE, 1)
    title_h = text_h + baseline + 8
    top = _MARGIN_PX + title_h
    on_origin = (_MARGIN_PX, top)
    off_origin = (_MARGIN_PX + map_w + _GAP_PX, top)
    bar_x = off_origin[0] + map_w + _GAP_PX
    clipped_low = bool(values.min() < low)
    clipped_high = bool(values.max() > high)
    ticks = [((">= " if clipped_high else "") + _number(high), top),
             (("<= " if clipped_low else "") + _number(low), top + map_h - 1)]
    if map_h >= 4 * (text_h + baseline):
        ticks.append((_number((low + high) / 2), top + (map_h - 1) // 2))
    label_x = bar_x + _BAR_WIDTH_PX + 6
    labels_w = max(cv2.getTextSize(text, font, _FONT_SCALE, 1)[0][0] for text, _ in ticks + [(units, 0)])
    lines = [_stats(titles[0], on[on_valid], on.size), _stats(titles[1], off[off_valid], off.size)]
    invalid = int((~on_valid).sum() + (~off_valid).sum())
    if invalid:
        lines.append("grey: no valid value")
    lines_w = max(cv2.getTextSize(text, font, _FONT_SCALE, 1)[0][0] for text in lines)
    picture_w = max(label_x + labels_w, _MARGIN_PX + lines_w + (_LINE_PX if invalid else 0)) + _MARGIN_PX
    units_h = _LINE_PX if units else 0
    picture_h = top + map_h + units_h + 10 + _LINE_PX * len(lines) + _MARGIN_PX

    image = np.full((picture_h, picture_w, 3), _WHITE, dtype=np.uint8)
    for (x, y), values_map, valid_map, title in (
        (on_origin, on, on_valid, titles[0]), (off_origin, off, off_valid, titles[1])
    ):
        rgb = _colour(values_map, (low, high), colormap)
        rgb[~valid_map] = INVALID_RGB
        image[y:y + map_h, x:x + map_w] = upscale(rgb, scale)
        cv2.rectangle(image, (x - 1, y - 1), (x + map_w, y + map_h), _FRAME_RGB, 1)
        cv2.putText(image, title, (x, top - baseline - 4), font, _FONT_SCALE, _BLACK, 1, cv2.LINE_AA)

    bar_values = np.linspace(high, low, map_h)[:, None]
    bar = _colour(bar_values, (low, high), colormap)
    image[top:top + map_h, bar_x:bar_x + _BAR_WIDTH_PX] = bar
    cv2.rectangle(image, (bar_x - 1, top - 1), (bar_x + _BAR_WIDTH_PX, top + map_h), _FRAME_RGB, 1)
    for text, y in ticks:
        cv2.line(image, (bar_x + _BAR_WIDTH_PX, y), (bar_x + _BAR_WIDTH_PX + 3, y), _BLACK, 1)
        y_text = min(max(y + text_h // 2, top + text_h), top + map_h)
        cv2.putText(image, text, (label_x, y_text), font, _FONT_SCALE, _BLACK, 1, cv2.LINE_AA)
    if units:
        cv2.putText(image, units, (bar_x, top + map_h + text_h + 8), font, _FONT_SCALE, _BLACK, 1, cv2.LINE_AA)

    y = top + map_h + units_h + 10
    for k, text in enumerate(lines):
        x = _MARGIN_PX
        if k == len(lines) - 1 and invalid:
            cv2.rectangle(image, (x, y + 2), (x + text_h + 1, y + text_h + 3), INVALID_RGB, -1)
            x += _LINE_PX
        cv2.putText(image, text, (x, y + text_h + 2), font, _FONT_SCALE, _BLACK, 1, cv2.LINE_AA)
        y += _LINE_PX
    return MapPicture(image, on_origin, off_origin, scale, (low, high))
