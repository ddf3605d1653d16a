"""Hot-pixel lists (``bafilter --hot-pixels`` / ``--save-hot-pixels``): a CSV file, header ``x,y``, one pixel a
line (``#`` comments and blank lines skipped), in the sensor's coordinates."""

from __future__ import annotations

import sys

import numpy as np

from evtools.formats.errors import FormatError
from evtools.formats.io import STDIO, atomic_path
from evtools.inputs import note_input


class HotPixelsError(FormatError):
    """A hot-pixel list that cannot be read or does not fit the sensor."""


def read_hot_pixels(path: str, width: int, height: int) -> np.ndarray:
    """A hot-pixel CSV file (header ``x,y``, one pixel a line) as a (height, width) boolean map."""
    hot = np.zeros((height, width), dtype=bool)
    note_input(path)
    try:
        with open(path, encoding="utf-8") as file:
            lines = file.read().splitlines()
    except OSError as error:
        raise HotPixelsError(f"{path}: {error.strerror}") from None
    except UnicodeDecodeError:  # (an event file given by mistake)
        raise HotPixelsError(f"{path}: not a hot-pixel list (not text: a CSV with the header `x,y`)") from None
    if not lines or lines[0].strip().lower() != "x,y":
        raise HotPixelsError(f"{path}: not a hot-pixel list (first line must be `x,y`)")
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip() or line.startswith("#"):
            continue
        try:
            x, y = (int(v) for v in line.split(","))
        except ValueError:
            raise HotPixelsError(f"{path}: line {number}: expected `x,y` integers, got {line!r}") from None
        if not (0 <= x < width and 0 <= y < height):
            raise HotPixelsError(f"{path}: line {number}: pixel ({x}, {y}) is outside the {width}x{height} sensor")
        hot[y, x] = True
    return hot


def write_hot_pixels(path: str, hot: np.ndarray) -> None:
    """Write the hot pixels of ``hot`` as CSV (``x,y`` header, row-major order), atomically (``-``: stdout)."""
    ys, xs = np.nonzero(hot)
    text = "x,y\n" + "".join(f"{x},{y}\n" for x, y in zip(xs.tolist(), ys.tolist()))
    if path == STDIO:
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    try:
        with atomic_path(path) as temporary, open(temporary, "w", encoding="utf-8") as file:
            file.write(text)
    except OSError as error:
        raise HotPixelsError(f"{path}: cannot write the hot-pixel list ({error.strerror})") from None
