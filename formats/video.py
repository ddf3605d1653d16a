"""Frame sources for the simulator: a video file (OpenCV) or a folder of images timed by a timestamps file or a
frame rate, read as luma frames ``(t_us, height x width)`` on the 0-255 scale (``evtools simulate clip.mp4``,
``evtools.simulate("clip.mp4")``)."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import sys
import threading
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from evtools.errors import UsageMistake
from evtools.events import parse_sensor_size
from evtools.formats.errors import FormatError
from evtools.inputs import note_input

log = logging.getLogger("evtools")

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".pbm", ".webp", ".exr")
TIMESTAMPS_FILE = "timestamps.txt"
"""Looked for inside an image folder when no timestamps file is given."""


class VideoError(FormatError):
    """A video or an image folder that cannot be read as frames."""


class VideoTimingError(VideoError, UsageMistake):
    """Two timings given for one image folder: a usage error (exit 2)."""


@dataclass
class FrameSource:
    """Frames ``(t_us, height x width luma 0-255)`` with what is known about them beforehand.

    Frames are uint8 when the images are 8-bit and not resized (the simulator then reads lin-log from a table of
    the 256 levels), float32 otherwise.
    """

    name: str
    width: int
    height: int
    frames: Iterator[tuple[int, np.ndarray]]
    count: int | None = None
    attributes: dict[str, Any] = field(default_factory=dict)
    was_cut: bool = False  # set once read: the source ended before the frames it declares (a video broken off)


def read_image(path: str) -> np.ndarray:
    """An image file as luma, 0-255 (``--image``)."""
    import cv2

    if not os.path.isfile(path):
        raise VideoError(f"{path}: no such image file")
    note_input(path)
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise VideoError(f"{path}: cannot read this image (not a format OpenCV reads)")
    return _luma(image, path)


def _luma(frame: np.ndarray, name: str) -> np.ndarray:
    """8-bit (or 16-bit) grey or BGR(A) image as luma on the 0-255 scale (Rec. 601 weights, OpenCV's): uint8 for an
    8-bit image, float32 otherwise."""
    import cv2

    if frame.ndim == 3 and frame.shape[2] == 4:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY)
    elif frame.ndim == 3 and frame.shape[2] == 3:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    elif frame.ndim == 3 and frame.shape[2] == 1:
        frame = frame[:, :, 0]
    if frame.ndim != 2:
        raise VideoError(f"{name}: unsupported image layout {frame.shape}")
    if frame.dtype == np.uint8:
        return frame
    if frame.dtype == np.uint16:
        return frame.astype(np.float32) * np.float32(255.0 / 65535.0)
    # float images: 1.0 is the 8-bit image's white, and brighter (an HDR highlight) is kept, not clipped: the
    # simulator works in log intensity, and a clip at 1.0 made a highlight brightening 4x fire nothing
    return np.maximum(frame.astype(np.float32) * np.float32(255.0), np.float32(0.0))


def _resize(frame: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    if size is None or (frame.shape[1], frame.shape[0]) == size:
        return frame
    import cv2

    # in float32, so that the averaged intensities are not rounded to whole levels
    return cv2.resize(frame.astype(np.float32, copy=False), size, interpolation=cv2.INTER_AREA)


_QUIET = threading.Lock()


@contextlib.contextmanager
def quiet_stderr():
    """File descriptor 2 sent to /dev/null for the block, then restored: FFmpeg's and OpenCV's own lines (codec
    probes, broken files) are not ours to print; evtools reports its errors in one line. One block at a time across
    threads (two overlapping would restore each other's /dev/null)."""
    with _QUIET:
        if sys.stderr is not None:
            sys.stderr.flush()
        try:
            saved = os.dup(2)
        except OSError:
            yield
            return
        try:
            with open(os.devnull, "wb") as null:
                os.dup2(null.fileno(), 2)
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def video_source(path: str, fps: float | None, size: str | None) -> FrameSource:
    """A video file read with OpenCV; frame times from the container's (each frame's presentation time, relative to
    the first: variable frame rates, dropped frames), or from ``fps`` when given. Where the container's times do
    not increase, the frame rate takes over from there (said once). A video that ends before the frames it
    declares is said and marked cut (``was_cut``): a copy broken off read as a shorter, whole one."""
    # FFmpeg prints its complaints about broken files on stderr (its level read when OpenCV first uses it), and
    # OpenCV's own AVI parser with a plain fprintf: errors are ours to report, in one line
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    import cv2

    note_input(path)
    with quiet_stderr():
        capture = cv2.VideoCapture(path)
    if not capture.isOpened():
        raise VideoError(f"{path}: cannot read it as a video (OpenCV could not open it)")
    with quiet_stderr():
        ok, first = capture.read()
    if not ok or first is None:
        capture.release()
        raise VideoError(f"{path}: cannot read a frame from this video")
    rate = float(fps) if fps else float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
    if not rate > 0 or math.isinf(rate):
        capture.release()
        raise VideoError(f"{path}: the video does not say its frame rate; give --frame-rate")
    target = parse_sensor_size(size) if size else None
    first = _resize(_luma(first, path), target)
    height, width = first.shape
    parse_sensor_size(f"{width}x{height}")
    count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0) or None
    start_ms = float(capture.get(cv2.CAP_PROP_POS_MSEC) or 0.0)

    def frames():
        t_us, by_rate = 0, bool(fps)  # (--frame-rate overrides the container's times)
        try:
            yield 0, first
            index = 1
            while True:
                with quiet_stderr():
                    ok, frame = capture.read()
                if not ok or frame is None:
                    break
                if not by_rate:
                    stamp_us = round((float(capture.get(cv2.CAP_PROP_POS_MSEC)) - start_ms) * 1000)
                    if stamp_us > t_us:
                        t_us = stamp_us
                    else:
                        by_rate = True
                        log.warning(f"{path}: the container's frame times stop increasing at frame {index}: "
                                    f"timed by the frame rate ({rate:g} fps) from there")
                if by_rate:
                    t_us = round(index * 1e6 / rate) if fps else t_us + round(1e6 / rate)
                yield t_us, _resize(_luma(frame, path), target)
                index += 1
            if count is not None and index < count - max(1, count // 50):  # (a declared count may be an estimate:
                # some containers' is their duration times their frame rate; 2 % is slack)
                source.was_cut = True
                log.warning(f"{path}: the video ends after {index:,} of the {count:,} frames it declares (a copy "
                            "broken off?): the events are marked cut")
        finally:
            capture.release()

    source = FrameSource(path, width, height, frames(), count, {"video": os.path.basename(path), "fps": rate})
    return source


def _natural_key(name: str):
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_timestamps_us(path: str) -> np.ndarray:
    """One time per line in seconds (blank lines and ``#`` comments skipped), as microseconds: the line's first
    field (rpg's ``t image``); a first column counting 0, 1, 2... beside more fields is frame numbers, refused."""
    times, more_fields = [], True
    note_input(path)
    try:
        with open(path, encoding="utf-8") as file:
            for number, line in enumerate(file, 1):
                text = line.split("#", 1)[0].strip()
                if not text:
                    continue
                fields = text.replace(",", " ").split()  # (a number after the first: "index seconds"; rpg's
                more_fields &= len(fields) > 1 and _is_number(fields[1])  # "t image" is fine)
                try:
                    value = float(text.split()[0].rstrip(","))
                except ValueError:
                    raise VideoError(f"{path}: line {number} is not a time in seconds: {text!r}") from None
                if not math.isfinite(value):
                    raise VideoError(f"{path}: line {number} is not a finite time: {text!r}")
                times.append(value)
    except OSError as error:
        raise VideoError(f"{path}: cannot read timestamps ({error.strerror})") from None
    except UnicodeDecodeError:
        raise VideoError(f"{path}: not a text file of timestamps") from None
    counting = len(times) > 2 and times[0] in (0, 1) and np.array_equal(np.diff(times), np.ones(len(times) - 1))
    if counting and more_fields:
        raise VideoError(f"{path}: its first column counts {times[0]:g}, {times[1]:g}, {times[2]:g}... (frame numbers, "
                         "read as seconds): give one time in seconds per line, or the time first (t image)")
    if len(times) > 1 and np.median(np.diff(times)) > 60:  # (microseconds read as seconds: days of leak noise)
        log.warning(
            f"{path}: the frames are {np.median(np.diff(times)):,.0f} s apart (median): timestamps are read as "
            "seconds; if these are microseconds, divide them by 1e6")
    return np.round(np.asarray(times, dtype=np.float64) * 1e6).astype(np.int64)


def folder_source(folder: str, timestamps: str | None, fps: float | None, size: str | None) -> FrameSource:
    """The images of ``folder`` in natural name order, timed by a timestamps file or ``fps``."""
    import cv2

    names = sorted((n for n in os.listdir(folder) if n.lower().endswith(IMAGE_EXTENSIONS)), key=_natural_key)
    if not names:
        raise VideoError(f"{folder}: no images in this folder ({', '.join(IMAGE_EXTENSIONS[:5])}, ...)")
    if timestamps is None and os.path.isfile(os.path.join(folder, TIMESTAMPS_FILE)):
        timestamps = os.path.join(folder, TIMESTAMPS_FILE)
    if timestamps is not None and fps:  # (one was ignored without a word: a QA sweep)
        raise VideoTimingError(f"{folder}: a frame rate and the images' timestamps ({timestamps}) both time the "
                               "images: give one")
    if timestamps is not None:
        times = read_timestamps_us(timestamps)
        if len(times) != len(names):
            raise VideoError(f"{timestamps}: {len(times)} timestamps for {len(names)} images in {folder}")
        if np.any(np.diff(times) <= 0):
            i = int(np.argmax(np.diff(times) <= 0)) + 1
            raise VideoError(f"{timestamps}: times must increase (line {i + 1} is not after line {i})")
        offset_us = int(times[0])
        times = times - offset_us  # events start at 0; the truth file keeps the offset
    elif fps:
        if not fps > 0 or math.isinf(fps):
            raise VideoError(f"the frame rate must be positive, got {fps}")
        times = np.round(np.arange(len(names)) * (1e6 / fps)).astype(np.int64)
        offset_us = 0
    else:
        raise VideoError(f"{folder}: no {TIMESTAMPS_FILE}; give --timestamps FILE or --frame-rate")
    target = parse_sensor_size(size) if size else None

    def read(name: str) -> np.ndarray:
        path = os.path.join(folder, name)
        note_input(path)
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise VideoError(f"{path}: cannot read this image")
        return _resize(_luma(image, path), target)

    first = read(names[0])
    height, width = first.shape
    parse_sensor_size(f"{width}x{height}")

    def frames():
        yield int(times[0]), first
        for t_us, name in zip(times[1:], names[1:]):
            frame = read(name)
            if frame.shape != first.shape:
                raise VideoError(
                    f"{os.path.join(folder, name)}: {frame.shape[1]}x{frame.shape[0]} image among "
                    f"{width}x{height} ones (give --size to resize them all)"
                )
            yield int(t_us), frame

    attributes = {
        "folder": os.path.basename(os.path.normpath(folder)), "images": len(names), "time_offset_us": offset_us,
    }
    return FrameSource(folder, width, height, frames(), len(names), attributes)


def open_frames(path: str, fps: float | None = None, size=None, timestamps: str | None = None) -> FrameSource:
    """The frames of a video file or of a folder of images (``timestamps``: its times file; default its
    ``timestamps.txt``, else ``fps``); ``size``: ``"WxH"`` or (W, H) to resize them to."""
    size = None if size is None else "x".join(map(str, parse_sensor_size(size)))
    if os.path.isdir(path):
        return folder_source(path, timestamps, fps, size)
    if not os.path.exists(path):
        raise VideoError(f"{path}: no such file or folder")
    if timestamps is not None:
        raise VideoError(f"{path}: a timestamps file applies to image folders only")
    return video_source(path, fps, size)
