"""Time slicing and geometry of an event stream (``evtools convert --start --end --crop --flip-x --flip-y
--transpose --polarity``), as a stream processor.

The steps, in this order: keep the events in ``[start, end)`` (times relative to the stream's first event unless
absolute), keep one polarity, keep the events inside the crop rectangle ``(x, y, w, h)`` and move them to its
origin (the sensor becomes ``w x h``), mirror x (``x -> W - 1 - x``) and/or y within the sensor so far, then swap
x and y (the sensor becomes ``H x W``). Each step is per event, so the output does not depend on the chunks.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from evtools.errors import EvtoolsError
from evtools.events import StreamInfo, empty_events, join, select


class TransformError(EvtoolsError, ValueError):
    """A slice or a rectangle that does not fit the stream."""


@dataclass(frozen=True)
class Time:
    """A time bound: microseconds from the stream's first event, or an absolute time (``absolute``)."""

    us: int
    absolute: bool = False

    def resolve(self, first_us: int) -> int:
        """This time on the stream's clock, for a stream whose first event is at ``first_us``."""
        return self.us if self.absolute else first_us + self.us


class Transform:
    """Slices and re-maps a ``width x height`` stream; :attr:`info` is the output's stream description.

    Parameters
    ----------
    start, end : Time, optional
        Keep ``start <= t < end``.
    polarity : {"on", "off"}, optional
    crop : (x, y, w, h), optional
        A rectangle inside the sensor.
    flip_x, flip_y, transpose : bool
    """

    def __init__(self, info: StreamInfo, *, start: Time | None = None, end: Time | None = None,
                 polarity: str | None = None, crop: tuple[int, int, int, int] | None = None, flip_x: bool = False,
                 flip_y: bool = False, transpose: bool = False) -> None:
        width, height = info.width, info.height
        if crop is not None:
            x, y, w, h = (int(v) for v in crop)
            if w < 1 or h < 1 or x < 0 or y < 0 or x + w > width or y + h > height:
                raise TransformError(f"crop {x},{y},{w},{h} is not inside the {width}x{height} sensor (X,Y,W,H: "
                                     f"0 <= X, X + W <= {width}, 0 <= Y, Y + H <= {height})")
            crop, width, height = (x, y, w, h), w, h
        if polarity not in (None, "on", "off"):
            raise TransformError(f"polarity must be on or off, not {polarity!r}")
        if start is not None and end is not None and start.absolute == end.absolute and end.us <= start.us:
            raise TransformError(f"the end ({end.us} us) is not after the start ({start.us} us)")
        self.start, self.end, self.polarity, self.crop = start, end, polarity, crop
        self.flip_x, self.flip_y, self.transpose = flip_x, flip_y, transpose
        self.flipped_size = (width, height)  # the sensor the flips act in
        out_width, out_height = (height, width) if transpose else (width, height)
        self.info = replace(info, width=out_width, height=out_height, metadata=dict(info.metadata))
        self.source_size = (info.width, info.height)
        self.moves_pixels = crop is not None or flip_x or flip_y or transpose
        if self.moves_pixels and info.metadata.get("frame_size"):
            self.info.metadata["frame_size"] = (out_width, out_height)
        self.first_us: int | None = None
        self.last_us: int | None = None  # the last event seen
        self.kept = False  # whether any event was kept
        self.done = False  # the end has passed: no later event can be kept

    def said_at_end(self, name: str) -> None:
        """At the stream's end: a warning when the start lies after its last event (nothing kept, and why)."""
        start = self.start
        if self.kept or self.last_us is None or start is None or self._bounds()[0] <= self.last_us:
            return
        logging.getLogger("evtools").warning(
            f"{name}: the start ({'@' if start.absolute else ''}{start.us / 1e6:g} s) lies after the stream's last "
            f"event ({(self.last_us - self.first_us) / 1e6:.6g} s after its first, at {self.last_us:,} us): no event "
            "is kept")

    def end_us(self) -> float:
        """The slice's end as a stream time (inf: none, or no event seen yet to resolve a relative one against)."""
        return np.inf if self.end is None or self.first_us is None else self.end.resolve(self.first_us)

    def _bounds(self) -> tuple[float, float]:
        return (-np.inf if self.start is None else self.start.resolve(self.first_us),
                np.inf if self.end is None else self.end.resolve(self.first_us))

    def process(self, chunk: np.ndarray) -> np.ndarray:
        if not len(chunk) or self.done:
            return chunk[:0]
        if self.first_us is None:
            self.first_us = int(chunk["t"][0])
        start, end = self._bounds()
        t = chunk["t"]
        self.last_us = int(t[-1])
        if t[-1] >= end:
            self.done = True
        chunk = chunk[int(np.searchsorted(t, start, "left")):int(np.searchsorted(t, end, "left"))]
        if self.polarity is not None:
            chunk = select(chunk, chunk["p"] == (self.polarity == "on"))
        if self.crop is not None:
            x0, y0, w, h = self.crop
            x, y = chunk["x"], chunk["y"]
            chunk = select(chunk, (x >= x0) & (x < x0 + w) & (y >= y0) & (y < y0 + h))
            chunk["x"] -= x0
            chunk["y"] -= y0
        elif self.flip_x or self.flip_y or self.transpose:
            chunk = join([chunk])  # never change the caller's events (copied as raw records, padding included)
        width, height = self.flipped_size
        if self.flip_x:
            chunk["x"] = width - 1 - chunk["x"]
        if self.flip_y:
            chunk["y"] = height - 1 - chunk["y"]
        if self.transpose:
            chunk["x"], chunk["y"] = chunk["y"].copy(), chunk["x"].copy()
        self.kept = self.kept or bool(len(chunk))
        return chunk

    def flush(self) -> np.ndarray:
        return empty_events()

    def keeps(self, order_us: int) -> bool:
        """Whether the time slice keeps something (an APS frame, a side stream's packet) at ``order_us``."""
        if self.first_us is None:  # no event yet: times relative to the stream's start count from this one
            start, end = (-np.inf if self.start is None else self.start.resolve(order_us),
                          np.inf if self.end is None else self.end.resolve(order_us))
        else:
            start, end = self._bounds()
        return start <= order_us < end

    def frame(self, frame):
        """An APS frame (:class:`evtools.Frame`) under the same time slice (by the end of its exposure), crop, flips
        and transpose as the events; None outside the slice."""
        if not self.keeps(frame.order_us):
            return None
        if not self.moves_pixels:
            return frame
        if (frame.offset_x, frame.offset_y) != (0, 0) or (frame.width, frame.height) != self.source_size:
            raise TransformError(f"an APS frame of {frame.width} x {frame.height} at ({frame.offset_x}, "
                                 f"{frame.offset_y}) cannot be cropped, flipped or transposed with the "
                                 f"{self.source_size[0]} x {self.source_size[1]} sensor's events (only whole frames)")
        return replace(frame, image=self.pixels(frame.image))

    def pixels(self, values: np.ndarray) -> np.ndarray:
        """A per-pixel array (``(..., height, width)``: a thresholds map, a series of maps) under the same crop,
        flips and transpose as the events, so that map and stream stay pixel for pixel aligned."""
        if self.crop is not None:
            x0, y0, w, h = self.crop
            values = values[..., y0:y0 + h, x0:x0 + w]
        if self.flip_x:
            values = values[..., :, ::-1]
        if self.flip_y:
            values = values[..., ::-1, :]
        if self.transpose:
            values = np.swapaxes(values, -1, -2)
        return np.ascontiguousarray(values)

    def camera_pixels(self, values: np.ndarray, fill) -> np.ndarray:
        """A per-pixel array of the sliced sensor (``(..., height, width)``: an estimated map) on the whole camera
        sensor, ``fill`` outside the crop: the inverse of :meth:`pixels`, so that a map made on a sliced stream is
        the camera's, as every map is (``correct`` cuts and turns it with its own events)."""
        if self.transpose:
            values = np.swapaxes(values, -1, -2)
        if self.flip_y:
            values = values[..., ::-1, :]
        if self.flip_x:
            values = values[..., :, ::-1]
        width, height = self.source_size
        camera = np.full(values.shape[:-2] + (height, width), fill, dtype=values.dtype)
        x0, y0 = self.crop[:2] if self.crop is not None else (0, 0)
        camera[..., y0:y0 + values.shape[-2], x0:x0 + values.shape[-1]] = values
        return camera


class SlicedStream:
    """An open stream seen through a :class:`Transform`: ``info`` is the transformed stream's, iteration yields
    the transformed chunks (none empty) and stops reading once the end has passed; everything else is the
    stream's."""

    def __init__(self, stream, transform: Transform) -> None:
        self._stream = stream
        self.transform = transform
        self.info = transform.info

    def __getattr__(self, name):
        return getattr(self._stream, name)

    def take_frames(self) -> list:
        """The stream's APS frames read since the last call, sliced and re-mapped as the events."""
        frames = (self.transform.frame(frame) for frame in self._stream.take_frames())
        return [frame for frame in frames if frame is not None]

    @property
    def was_cut(self) -> bool:
        """Whether the stream turned out cut within what the slice keeps: a cut after the slice's end leaves the
        slice whole."""
        return bool(getattr(self._stream, "was_cut", False)) and not self.transform.done

    def take_side_packets(self) -> list:
        """The stream's side packets (IMU samples, triggers) read since the last call, within the time slice (they
        are the camera's: crops, flips and transposes leave them as they are)."""
        return [packet for packet in self._stream.take_side_packets() if self.transform.keeps(packet.order_us)]

    def __iter__(self):
        for chunk in self._stream:
            chunk = self.transform.process(chunk)
            if len(chunk):
                yield chunk
            if self.transform.done and not getattr(self._stream, "reads_past_the_end", False):
                return
        self.transform.said_at_end(self._stream.name)


def sliced(stream, slicing: dict | None):
    """``stream`` itself when ``slicing`` (:class:`Transform`'s options, as the commands' shared options give
    them) asks for nothing, else a :class:`SlicedStream`."""
    if not slicing or not any(slicing.values()):
        return stream
    return SlicedStream(stream, transform_of(stream, slicing))


def transform_of(stream, slicing: dict) -> Transform:
    """The :class:`Transform` of ``slicing`` on ``stream``'s sensor; an error names the stream (a crop outside its
    sensor: which input, with several)."""
    try:
        return Transform(stream.info, **slicing)
    except TransformError as error:
        raise TransformError(f"{stream.name}: {error}") from None


def on_sliced_sensor(stream, values: np.ndarray) -> np.ndarray:
    """A per-pixel array of ``stream``'s file (a thresholds map, a hot-pixel map) on the sensor that ``stream``
    shows (cropped, flipped, transposed by :func:`sliced`, or as it is)."""
    return stream.transform.pixels(values) if isinstance(stream, SlicedStream) else values
