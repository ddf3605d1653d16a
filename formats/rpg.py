"""The RPG event-camera dataset layout (Mueggler et al., "The event-camera dataset and simulator", IJRR 2017): a
folder holding ``events.txt`` (``t x y p``, t in seconds), ``images.txt`` (``t path`` per line, t in seconds, the
path relative to the folder) and the images (PNG, 8 or 16 bit gray; colour read as gray with a warning).

Opened as a folder, its events are read by the text reader from ``events.txt`` and its images become APS frames
(:class:`evtools.Frame`, at their timestamp: the layout records no exposure), queued as the events pass their time.
"""

from __future__ import annotations

import os
from collections import deque
from typing import Iterator

import numpy as np

from evtools.formats.errors import FormatError
from evtools.frames import Frame, gray

EVENTS_FILE, IMAGES_FILE = "events.txt", "images.txt"


def rpg_events_path(folder: str) -> str:
    """The folder's ``events.txt``, or a one-line error saying what a folder input must hold."""
    path = os.path.join(folder, EVENTS_FILE)
    if not os.path.isfile(path):
        raise FormatError(f"{folder}: a folder; evtools reads folders in the RPG layout (events.txt, images.txt, "
                          "images/), and this one has no events.txt")
    return path


class RpgFrames:
    """Wraps the reader of a folder's ``events.txt``: its chunks pass unchanged, and the images of ``images.txt``
    are queued as frames (``frames``, taken by :meth:`evtools.formats.EventStream.take_frames`) once the events
    reach their time, the rest at the end."""

    def __init__(self, reader, folder: str) -> None:
        self.reader, self.folder = reader, folder
        self.info = reader.info
        self.frames: deque[Frame] = deque()
        self.frames_read = 0
        self.entries = self._entries()
        self._next = 0
        self._first = self._image(0) if self.entries else None  # read once: it gives the frame size
        if self._first is not None:
            self.info.metadata["frame_size"] = (self._first[0].shape[1], self._first[0].shape[0])
            self.info.metadata["layout"] = "rpg"

    def _entries(self) -> list[tuple[int, str]]:
        path = os.path.join(self.folder, IMAGES_FILE)
        if not os.path.isfile(path):
            return []
        entries = []
        with open(path, encoding="utf-8", errors="replace") as text:
            for number, line in enumerate(text, 1):
                fields = line.split()
                if not fields or fields[0].startswith("#"):
                    continue
                try:
                    t_us = int(round(float(fields[0]) * 1e6))
                    name = fields[1]
                except (ValueError, IndexError):
                    raise FormatError(f"{path}: line {number} is not 'SECONDS IMAGE'") from None
                if entries and t_us < entries[-1][0]:
                    raise FormatError(f"{path}: line {number}: the images' times go backwards")
                entries.append((t_us, name))
        return entries

    def _image(self, k: int) -> tuple[np.ndarray, str | None]:
        import cv2

        t_us, name = self.entries[k]
        path = os.path.join(self.folder, name)
        if not os.path.isfile(path):
            raise FormatError(f"{path}: no such image (listed in {IMAGES_FILE})")
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)  # its own line for a damaged file
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if image is None:
            raise FormatError(f"{path}: not a readable image (listed in {IMAGES_FILE})")
        if image.dtype not in (np.uint8, np.uint16):
            raise FormatError(f"{path}: {image.dtype} pixels; frames are 8 or 16 bit gray")
        return gray(image, "BGR")

    def _queue_until(self, t_us: float) -> None:
        while self._next < len(self.entries) and self.entries[self._next][0] <= t_us:
            t = self.entries[self._next][0]
            image, layout = self._first if self._next == 0 else self._image(self._next)
            if (image.shape[1], image.shape[0]) != self.info.metadata["frame_size"]:
                raise FormatError(f"{os.path.join(self.folder, self.entries[self._next][1])}: an image of "
                                  f"{image.shape[1]} x {image.shape[0]} among images of "
                                  f"{self.info.metadata['frame_size'][0]} x {self.info.metadata['frame_size'][1]}")
            self.frames.append(Frame(image, t, t, t, metadata={"converted_from": layout} if layout else {}))
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
