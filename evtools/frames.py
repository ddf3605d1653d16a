"""APS intensity frames as data beside events (a DAVIS camera's frames; DESIGN.md "Frames").

A :class:`Frame` holds one image and its five times, as DV records them (AEDAT 4.0 ``FRME``): the frame's own time,
the start and end of its readout, and the start and end of its exposure, all in microseconds. Streams carry frames
in the order their file or pipe has them; a command that processes events passes every frame on untouched, once its
output has reached the frame's :attr:`Frame.order_us` (the end of the exposure: when the image was complete), so an
output is in time order whatever the stage holds back.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field

import numpy as np

FORMAT_GRAY, FORMAT_BGR, FORMAT_BGRA = 0, 16, 24
"""DV's pixel formats (OpenCV's CV_8UC1, CV_8UC3, CV_8UC4)."""
FORMAT_GRAY16 = 2
"""OpenCV's CV_16UC1: 16-bit gray, which DV's type allows (its ``format`` is an OpenCV type) though DV writes 8."""


@dataclass(frozen=True, eq=False)
class Frame:
    """One APS frame.

    Parameters
    ----------
    image : ndarray
        Gray levels, 2-D (height x width), uint8 or uint16 (colour images are converted to gray when read, with a
        warning).
    t_us : int
        The frame's time (DV: the middle of the exposure).
    exposure_begin_us, exposure_end_us : int
        Start and end of the exposure (global shutter: every pixel integrates over this interval).
    begin_us, end_us : int
        Start and end of the readout (0 when the writer did not give them, as dv-processing's ``Frame``).
    offset_x, offset_y : int
        Position of the image's top-left pixel on the sensor (a region of interest), usually 0.
    """

    image: np.ndarray
    t_us: int
    exposure_begin_us: int
    exposure_end_us: int
    begin_us: int = 0
    end_us: int = 0
    offset_x: int = 0
    offset_y: int = 0
    metadata: dict = field(default_factory=dict)

    @property
    def exposure_us(self) -> int:
        """Exposure time."""
        return self.exposure_end_us - self.exposure_begin_us

    @property
    def order_us(self) -> int:
        """The time a stream orders the frame by: the end of its exposure (its ``t`` when that is unknown)."""
        return self.exposure_end_us if self.exposure_end_us else self.t_us

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    def same_as(self, other: "Frame") -> bool:
        """Equal in every time, position and pixel."""
        return (self.times() == other.times() and (self.offset_x, self.offset_y) == (other.offset_x, other.offset_y)
                and self.image.dtype == other.image.dtype and np.array_equal(self.image, other.image))

    def times(self) -> tuple[int, int, int, int, int]:
        """(t, begin, end, exposure begin, exposure end) in us."""
        return (self.t_us, self.begin_us, self.end_us, self.exposure_begin_us, self.exposure_end_us)


def frame_problem(frame: Frame, frame_size: tuple[int, int] | None, last_order_us: int | None) -> str | None:
    """What is wrong with ``frame`` as the next frame of a stream, as the end of a sentence that begins with its
    name ("is a float64 array..."), or None: the one set of checks of the writer (``evtools.write``) and of every
    reader, so a file written is one its readers take back and a file read is one the writer takes. A frame is a
    non-empty 2-D gray uint8 or uint16 image within the frame stream of ``frame_size`` (width, height; None:
    unbounded above), its exposure not ending before it begins, its :attr:`Frame.order_us` not before the frame
    before it (``last_order_us``; None: the first)."""
    image = frame.image
    if not isinstance(image, np.ndarray) or image.ndim != 2 or image.dtype not in (np.uint8, np.uint16):
        image = np.asarray(image)
        return (f"is a {image.dtype} array of shape {image.shape}; frames are 2-D gray uint8 or uint16: convert it "
                "first (to gray; one within 0-1 times 255)")
    if image.size == 0:
        return f"has an empty image ({image.shape[1]} x {image.shape[0]})"
    width, height = frame_size if frame_size else (np.inf, np.inf)
    if frame.offset_x < 0 or frame.offset_y < 0 or frame.offset_x + image.shape[1] > width or \
            frame.offset_y + image.shape[0] > height:
        return (f"is {image.shape[1]} x {image.shape[0]} at ({frame.offset_x}, {frame.offset_y}), outside the "
                f"{width} x {height} frame stream")
    if frame.exposure_end_us < frame.exposure_begin_us:
        return f"ends its exposure ({frame.exposure_end_us} us) before it begins ({frame.exposure_begin_us} us)"
    if last_order_us is not None and frame.order_us < last_order_us:
        return (f"ends its exposure at {frame.order_us} us, before the frame before it ({last_order_us} us): frames "
                "go back in time")
    return None


def gray(pixels: np.ndarray, order: str = "BGR") -> tuple[np.ndarray, str | None]:
    """``(image, layout)``: a 2-D gray image from ``pixels`` (height x width, or x channels: 1, 3 or 4 in the
    colour ``order`` of the format, DV's and OpenCV's BGR, libcaer's RGB, alpha last), colour converted by OpenCV's
    weights, as DV's own conversion; ``layout`` names the colour layout converted (``"BGRA"``...) or is None. The
    readers put it in the frame's ``converted_from`` metadata, which the stream says once
    (:meth:`evtools.formats.EventStream.take_frames`)."""
    if pixels.ndim == 2 or pixels.shape[2] == 1:
        return (pixels if pixels.ndim == 2 else pixels[:, :, 0]), None
    import cv2

    layout = order + ("A" if pixels.shape[2] == 4 else "")
    return cv2.cvtColor(np.ascontiguousarray(pixels), getattr(cv2, f"COLOR_{layout}2GRAY")), layout


class FrameRelay:
    """Passes a stream's frames on to a writer (``write_frame``), each once the output has reached its
    :attr:`Frame.order_us`: :meth:`release` with the time before which the processor's output is final, and with
    None when the stream has ended. Where the writer carries them (AEDAT 4.0 to AEDAT 4.0), the stream's side
    streams' packets (IMU samples, triggers: ``write_side``) go on the same way."""

    def __init__(self, stream, writer) -> None:
        self.stream, self.writer = stream, writer
        self.pending: deque[Frame] = deque()
        self.side_pending: deque = deque()
        self.written = 0
        self.carries_side = bool(getattr(writer, "carries_side_streams", False)) and \
            hasattr(stream, "carry_side_streams")
        if self.carries_side:
            stream.carry_side_streams()

    def due(self, released_us: int) -> bool:
        """Whether :meth:`release` with ``released_us`` would write a frame or a side packet (for a writer that
        buffers events: they go out first)."""
        self._take()
        return any(queue and queue[0].order_us < released_us for queue in (self.pending, self.side_pending))

    def _take(self) -> None:
        take = getattr(self.stream, "take_frames", None)
        if take is not None:
            self.pending.extend(take())
        if self.carries_side:
            self.side_pending.extend(self.stream.take_side_packets())

    def write(self, events: np.ndarray) -> None:
        """Write a chunk of the output (time-ordered, as every later one), each frame or side packet waiting for a
        time within it written before the chunk's first event at or after that time, so that a reader (a time
        slice's, a live one) meets it where it belongs, not a whole chunk later."""
        self._take()
        t, start = events["t"], 0
        while len(t):
            heads = [queue for queue in (self.pending, self.side_pending) if queue and queue[0].order_us <= t[-1]]
            if not heads:
                break
            queue = min(heads, key=lambda waiting: waiting[0].order_us)
            item = queue.popleft()
            cut = start + int(np.searchsorted(t[start:], item.order_us, side="left"))
            if cut > start:
                self.writer.write(events[start:cut])
                start = cut
            if queue is self.pending:
                self.writer.write_frame(item)
                self.written += 1
            else:
                self.writer.write_side(item)
        if start < len(events):
            self.writer.write(events[start:] if start else events)

    def release(self, released_us: int | None) -> None:
        self._take()
        while self.pending and (released_us is None or self.pending[0].order_us < released_us):
            self.writer.write_frame(self.pending.popleft())
            self.written += 1
        while self.side_pending and (released_us is None or self.side_pending[0].order_us < released_us):
            self.writer.write_side(self.side_pending.popleft())
        not_carried = getattr(self.stream, "not_carried", None)
        if released_us is None and not_carried is not None and not_carried():
            note = (f"{self.stream.name}: {not_carried()} are not in the output (evtools carries events and APS "
                    "frames only)")
            notes = getattr(self.writer, "notes", None)  # (said once the output is complete: not before an error)
            if notes is None:
                logging.getLogger("evtools").warning(note)
            else:
                notes.append(note)
