"""Dataset folders whose images are APS frames beside an event file, opened as one input (``evtools info folder/``).

- The RPG event-camera dataset (Mueggler et al., "The event-camera dataset and simulator", IJRR 2017):
  ``events.txt`` (``t x y p``, t in seconds, read by the text reader), ``images.txt`` (``t path`` per line, t in
  seconds, the path relative to the folder) and the images; no exposure is recorded (a frame's exposure is its
  timestamp).
- A DSEC sequence (Gehrig et al., "DSEC: A Stereo Event Camera Dataset for Driving Scenarios", RA-L 2021):
  ``events/left/events.h5`` (read by the HDF5 reader, ``t_offset`` added), ``images/left/rectified/*.png`` in name
  order, ``images/timestamps.txt`` (one time a line, microseconds on the events' clock) and, where the release has
  it, ``images/left/exposure_timestamps.txt`` (``start, end`` a line, microseconds; a ``#`` header). The left
  cameras: DSEC's reference pair. Its frame camera is another sensor (1440 x 1080 colour against the events'
  640 x 480): frames keep their own size, and become gray with a warning.

Images are 8 or 16 bit (colour read as gray with a warning) and become :class:`evtools.Frame` s, queued as the
events pass the end of their exposure, the rest at the end of the events.
"""

from __future__ import annotations

import glob
import os
from collections import deque
from typing import Iterator, NamedTuple

import numpy as np

from evtools.formats.errors import FormatError
from evtools.inputs import note_input
from evtools.frames import Frame, gray

EVENTS_FILE, IMAGES_FILE = "events.txt", "images.txt"
"""The RPG layout's files."""
DSEC_EVENTS = os.path.join("events", "left", "events.h5")
DSEC_IMAGES = os.path.join("images", "left", "rectified")
DSEC_TIMESTAMPS = os.path.join("images", "timestamps.txt")
DSEC_EXPOSURES = os.path.join("images", "left", "exposure_timestamps.txt")
"""A DSEC sequence's files, from the sequence's folder."""
DSEC_SENSOR_SIZE = (640, 480)
"""DSEC's event cameras (Prophesee Gen 3.1), whose events.h5 does not store its size: the sensor size of a DSEC
folder unless ``--sensor-size`` says otherwise (inferred from the events, a sequence whose events never reach the
last row or column would get a smaller sensor)."""


class Entry(NamedTuple):
    """One image of a folder: its time, its exposure's begin and end (microseconds) and its file."""

    t_us: int
    begin_us: int
    end_us: int
    path: str


def folder_events(folder: str) -> tuple[str, str]:
    """The event file of a dataset folder and its layout (``"rpg"`` or ``"dsec"``), or a one-line error saying
    what a folder input must hold."""
    for layout, name in (("rpg", EVENTS_FILE), ("dsec", DSEC_EVENTS)):
        if os.path.isfile(os.path.join(folder, name)):
            return os.path.join(folder, name), layout
    raise FormatError(f"{folder}: a folder; evtools reads folders in the RPG layout (events.txt, images.txt, "
                      f"images/) or DSEC's ({DSEC_EVENTS}, {DSEC_IMAGES}/, {DSEC_TIMESTAMPS}), and this one has "
                      f"no events.txt nor {DSEC_EVENTS}")


def folder_images(folder: str, layout: str) -> list[Entry]:
    """The images of a dataset folder (:func:`folder_events`' layout), their times checked, in time order."""
    return _rpg_entries(folder) if layout == "rpg" else _dsec_entries(folder)


def _lines(path: str) -> Iterator[tuple[int, list[str]]]:
    """(line number, fields) of the lines of a text file that are not empty or ``#`` comments (commas or spaces)."""
    note_input(path)
    with open(path, encoding="utf-8", errors="replace") as text:
        for number, line in enumerate(text, 1):
            fields = line.replace(",", " ").split()
            if fields and not fields[0].startswith("#"):
                yield number, fields


def _rpg_entries(folder: str) -> list[Entry]:
    path = os.path.join(folder, IMAGES_FILE)
    if not os.path.isfile(path):
        return []
    entries = []
    for number, fields in _lines(path):
        try:
            t_us = int(round(float(fields[0]) * 1e6))
            name = fields[1]
        except (ValueError, IndexError):
            raise FormatError(f"{path}: line {number} is not 'SECONDS IMAGE'") from None
        if entries and t_us < entries[-1].t_us:
            raise FormatError(f"{path}: line {number}: the images' times go backwards")
        entries.append(Entry(t_us, t_us, t_us, os.path.join(folder, name)))
    return entries


def _microseconds(path: str, want: int) -> list[list[int]]:
    """The lines of ``path`` as ``want`` whole numbers of microseconds each."""
    rows = []
    for number, fields in _lines(path):
        try:
            values = [int(field) for field in fields]
        except ValueError:
            values = []
        if len(values) != want:
            raise FormatError(f"{path}: line {number} is not {want} whole number(s) of microseconds")
        rows.append(values)
    return rows


def _dsec_entries(folder: str) -> list[Entry]:
    images = os.path.join(folder, DSEC_IMAGES)
    if not os.path.isdir(images):
        return []
    names = sorted(glob.glob(os.path.join(images, "*.png")))
    stamps = os.path.join(folder, DSEC_TIMESTAMPS)
    if not os.path.isfile(stamps):
        raise FormatError(f"{folder}: {len(names)} images in {DSEC_IMAGES} but no {DSEC_TIMESTAMPS}")
    times = [row[0] for row in _microseconds(stamps, 1)]
    if len(times) != len(names):
        raise FormatError(f"{stamps}: {len(times)} times for {len(names)} images in {DSEC_IMAGES}")
    exposures_path = os.path.join(folder, DSEC_EXPOSURES)
    exposures = _microseconds(exposures_path, 2) if os.path.isfile(exposures_path) else [[t, t] for t in times]
    if len(exposures) != len(names):
        raise FormatError(f"{exposures_path}: {len(exposures)} exposures for {len(names)} images")
    for (begin, end), t in zip(exposures, times):
        if not begin <= end:
            raise FormatError(f"{exposures_path}: an exposure ends ({end} us) before it begins ({begin} us)")
    if any(b < a for a, b in zip(times, times[1:])) or any(b[1] < a[1] for a, b in zip(exposures, exposures[1:])):
        raise FormatError(f"{stamps}: the images' times go backwards")
    return [Entry(t, begin, end, name) for t, (begin, end), name in zip(times, exposures, names)]


class FolderFrames:
    """Wraps the reader of a folder's event file: its chunks pass unchanged, and the folder's images are queued as
    frames (``frames``, taken by :meth:`evtools.formats.EventStream.take_frames`) once the events reach the end of
    their exposure, the rest at the end."""

    def __init__(self, reader, layout: str, entries: list[Entry]) -> None:
        self.reader, self.layout, self.entries = reader, layout, entries
        self.info = reader.info
        self.frames: deque[Frame] = deque()
        self.frames_read = 0
        self._next = 0
        self._first = self._image(0) if self.entries else None  # read once: it gives the frame size
        if self._first is not None:
            self.info.metadata["frame_size"] = (self._first[0].shape[1], self._first[0].shape[0])
            self.info.metadata["layout"] = layout

    def _image(self, k: int) -> tuple[np.ndarray, str | None]:
        import cv2

        path = self.entries[k].path
        if not os.path.isfile(path):
            raise FormatError(f"{path}: no such image")
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)  # its own line for a damaged file
        note_input(path)
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise FormatError(f"{path}: not a readable image")
        if image.dtype not in (np.uint8, np.uint16):
            raise FormatError(f"{path}: {image.dtype} pixels; frames are 8 or 16 bit gray")
        return gray(image, "BGR")

    def _queue_until(self, t_us: float) -> None:
        while self._next < len(self.entries) and self.entries[self._next].end_us <= t_us:
            entry = self.entries[self._next]
            image, layout = self._first if self._next == 0 else self._image(self._next)
            if (image.shape[1], image.shape[0]) != self.info.metadata["frame_size"]:
                raise FormatError(f"{entry.path}: an image of {image.shape[1]} x {image.shape[0]} among images of "
                                  f"{self.info.metadata['frame_size'][0]} x {self.info.metadata['frame_size'][1]}")
            self.frames.append(Frame(image, entry.t_us, entry.begin_us, entry.end_us,
                                     metadata={"converted_from": layout} if layout else {}))
            self.frames_read += 1
            self._next += 1

    def __iter__(self) -> Iterator[np.ndarray]:
        for chunk in self.reader:
            if len(chunk):
                self._queue_until(int(chunk["t"][-1]))
            yield chunk
        self._queue_until(np.inf)

    def __getattr__(self, name):
        return getattr(self.reader, name)
