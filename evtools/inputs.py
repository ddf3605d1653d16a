"""The files a command reads, so that none of them is ever replaced by one of its outputs.

A command must never overwrite a file the user named as an input, whichever option named it (the events, a
thresholds map, a hot-pixel list, an image or a video to simulate, its timestamps, a weights file). Every reader
calls :func:`note_input` with the path it opens; :func:`evtools.formats.io.atomic_path`, which every file output
goes through, refuses a target that is one of them (the same file by any name: links included), before it writes
and again before it puts the result in place (an input read after the output was opened). Only inside
:func:`guarding_inputs` (the command line wraps every command in it): a Python session that reads a file and later,
in another call, writes it back on purpose is not refused.
"""

from __future__ import annotations

import contextlib
import os
import stat

_READ: dict[tuple[int, int], str] | None = None  # (device, inode) -> the name it was read by


def note_input(path, name: str | None = None) -> None:
    """Record that the current command reads the file ``path`` (or the open descriptor: stdin redirected from a
    file, ``name`` then saying so); nothing outside :func:`guarding_inputs`, or for what is not a regular file (a
    pipe, a FIFO, a folder)."""
    if _READ is None:
        return
    try:
        status = os.stat(path)
    except (OSError, TypeError, ValueError):
        return
    if stat.S_ISREG(status.st_mode):
        _READ.setdefault((status.st_dev, status.st_ino), name or os.fspath(path))


def input_named_by(path) -> str | None:
    """The name an input of the current command was read by, when ``path`` is that same file; else None."""
    if not _READ:
        return None
    try:
        status = os.stat(path)
    except (OSError, TypeError, ValueError):
        return None
    return _READ.get((status.st_dev, status.st_ino))


@contextlib.contextmanager
def guarding_inputs():
    """Within the block, the files read (:func:`note_input`) are never replaced by an output."""
    global _READ
    outer, _READ = _READ, {}
    try:
        yield
    finally:
        _READ = outer
