"""HDF5 event files: DSEC, event_utils (E2VID), v2e, Prophesee's (Metavision) and evtools' own layout.

Layouts read (see FORMATS.md):

- DSEC: ``events/{x,y,t,p}`` with ``t`` in microseconds after the scalar ``t_offset``, ``ms_to_idx``;
- evtools: the DSEC layout plus root attributes ``width``, ``height`` and ``format = "evtools"``;
- event_utils: ``events/{xs,ys,ts,ps}`` with ``ts`` in float seconds (rounded to microseconds; integer ``ts`` are
  taken as microseconds) and ``sensor_resolution = (H, W)``;
- v2e: one dataset ``events`` of shape (N, 4), columns ``t_us, x, y, p``;
- Prophesee (Metavision's HDF5 event files): ``CD/events``, a compound dataset ``x, y`` (uint16), ``p`` (int16),
  ``t`` (int64 us), in chunks of 16,384 events compressed by Prophesee's ECF codec (filter 0x8ECF), which no
  plugin shipped with h5py or hdf5plugin decodes: evtools reads each chunk's stored bytes and decodes them itself
  (:mod:`evtools._kernels.ecf`); the sensor size comes from the root attributes (``format EVT3;width=W;height=H``,
  as a RAW header's).
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections import deque
from typing import BinaryIO, Iterator

import numpy as np

from evtools._kernels.ecf import MAX_BLOCK_EVENTS, decode_ecf
from evtools.events import EVENT_DTYPE, StreamInfo, record_words, second_words
from evtools.frames import Frame, frame_problem
from evtools.formats.errors import FormatError
from evtools.formats.io import Recycled, Source, resolve_sensor_size
from evtools.formats.prophesee import header_size
from evtools.formats.registry import BY_NAME, ReadOptions, WriteOptions

ECF_FILTER_ID = 36559
"""HDF5 filter id of Prophesee's ECF codec (0x8ECF)."""
PROPHESEE_FIELDS = ("x", "y", "p", "t")
"""The fields of Metavision's CD event records (``CD/events``)."""
ECF_MAX_BYTES_PER_EVENT = 32
"""No ECF chunk takes more bytes an event than this (the widest: a 64-bit time step in 4-bit pieces and its run
byte, 19, plus a row run, a column and a polarity run, 5), nor does an unfiltered record (16): a chunk whose stored
size says more is damaged (HDF5 would allocate it before reading: a fuzzed size took 216 MB)."""
ECF_ERRORS = {-1: "ends before its events do", -2: "has a run that overruns its event count",
              -3: "holds more events than the dataset's chunk"}
"""What :func:`evtools._kernels.ecf.decode_ecf`'s error codes say of a chunk."""

WRITE_BLOCK_EVENTS = 1 << 20
"""The writer appends events in blocks of exactly this many (the last one shorter): output bytes never depend
on how the input was chunked."""

HDF5_CHUNK_EVENTS = 1 << 16
"""HDF5 chunk length of the event datasets written (WRITE_BLOCK_EVENTS is a multiple of it)."""

MS_BLOCK = 1 << 16
"""``ms_to_idx`` is appended in blocks of this many entries."""

MAX_MS_CHECKED = 1 << 24
"""A DSEC ``ms_to_idx`` of at most this many entries (4.7 hours, 128 MiB) is read whole and the times checked
against it; a longer one is not checked."""

MAX_MS_TO_IDX = 1 << 28
"""The most ``ms_to_idx`` entries written (74.6 hours of stream at one a millisecond, 2 GiB): a stream spanning
more is refused, naming the span (two events 10^12 us apart, microseconds read as something larger, asked for
13.7 GB)."""

COMPRESSIONS = BY_NAME["hdf5"].compressions
"""The compressions written (the format table's, which ``--compression`` is checked against before writing)."""
DEFAULT_COMPRESSION = COMPRESSIONS[0]
"""No compression: the file opens in any HDF5 reader (plain h5py, MATLAB, evlib, the C library) without a plugin
(issue 39). Measured on 10 million events of the DAVIS346 lab recording, tiled (2 cores, this machine, two runs):
none writes 9-15 million events/s, reads 19-39 million/s, 13.1 bytes/event; zstd (level 1, hdf5plugin's filter
32015 as DSEC publishes: h5py needs ``import hdf5plugin``) 9-12 / 20-23 million/s at 3.3 bytes/event; lzf
(h5py only) 6-8 / 12-13 million/s at 3.6; gzip (any reader) 4-5 / 13-15 million/s at 2.75-2.9 (levels 1 and 4
alike). ``--compression zstd`` for a quarter of the size where the reader has the plugin, gzip for small files any
reader opens. The bytes written do not depend on how the events were chunked, except with lzf: liblzf's encoder
leaves its hash table unset, so its output (not what it decodes to) varies from run to run."""


FRAME_TIMES = ("t_us", "begin_us", "end_us", "exposure_begin_us", "exposure_end_us")
"""The per-frame times of evtools' ``frames/`` group (us, absolute)."""


def _h5py():
    import hdf5plugin  # noqa: F401  (registers Zstd, Blosc, ... with HDF5 before any file is opened)
    import h5py

    return h5py


def _filter_ids(dataset) -> list[int]:
    plist = dataset.id.get_create_plist()
    return [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]


MAX_ATTRIBUTE_BYTES = 1 << 16
"""An attribute is read only when it stores at most this many bytes (64 KiB: every attribute a camera's software
writes is a few words)."""
READABLE_ATTRIBUTE_CLASSES = (0, 1, 3, 8)
"""HDF5 type classes of the attributes read: integer, float, string (fixed or variable length), enum (h5py's
booleans), and arrays of them. Others are
refused before HDF5 reads them: a damaged string attribute can look like a variable-length sequence (class 9), and
reading that crashes the HDF5 library (SIGSEGV, found by mutating a Metavision file's attribute headers)."""


HEAP_SCAN_BYTES = 1 << 20
"""Global heap collections are looked for in a file's first and last MiB (where HDF5 puts those it makes as a file's
attributes are written: at its start, or at its end when they are written on closing)."""


def check_global_heaps(file, name: str) -> None:
    """Refuse a file (a path or a binary file, read from its start) whose HDF5 global heap collections (where
    variable-length strings live: the attributes of Metavision's files, h5py's string attributes) are
    inconsistent: HDF5 loops forever reading one whose objects do not fill it exactly (found by mutating a
    Metavision file: a damaged collection or object size hung the read, deaf to signals). Layout (HDF5 file format spec, III.E): ``GCOL``, version 1, 3 reserved bytes, the collection
    size (8 bytes, at least 4096), then objects of a 16-byte header (index 2, reference count 2, reserved 4, size
    8) and their data padded to 8 bytes; object 0 is the free space, last, its size counting its header."""
    if isinstance(file, (str, os.PathLike)):
        with open(file, "rb") as opened:
            return check_global_heaps(opened, name)
    size = file.seek(0, os.SEEK_END)
    file.seek(0)
    head = file.read(min(size, HEAP_SCAN_BYTES))
    tail_start = max(len(head), size - HEAP_SCAN_BYTES)
    file.seek(tail_start)
    parts = ((0, head), (tail_start, file.read()))
    file.seek(0)
    for base, data in parts:
        at = data.find(b"GCOL\x01")
        while at >= 0:
            problem = _heap_problem(data, at, size - base)
            if problem:
                raise FormatError(f"{name}: HDF5's global heap at byte {base + at:,} is damaged ({problem}; its "
                                  "variable-length strings cannot be read)")
            at = data.find(b"GCOL\x01", at + 1)


def _heap_problem(data: bytes, at: int, room: int) -> str | None:
    """What is wrong with the global heap collection at ``data[at:]`` (``room``: bytes from ``data[0]`` to the
    file's end), or None."""
    if at + 16 > len(data):
        return None  # (its header crosses the end of what was read: a later scan reads it)
    size = int.from_bytes(data[at + 8:at + 16], "little")
    if size < 4096 or at + size > room:
        return f"a collection of {size:,} bytes, {'less than 4,096' if size < 4096 else 'beyond the end of the file'}"
    end = min(at + size, len(data))
    position = at + 16
    while position + 16 <= end:
        index = int.from_bytes(data[position:position + 2], "little")
        length = int.from_bytes(data[position + 8:position + 16], "little")
        if index == 0:  # the free space: the rest of the collection, header included
            return None if position + length == at + size else "its free space does not end the collection"
        position += 16 + (length + 7) // 8 * 8
        if position > at + size:
            return f"object {index} of {length:,} bytes runs past the collection"
    if at + size <= len(data) and at + size - position >= 16:
        return "its objects do not fill the collection"
    return None


def attribute(node, name: str, default=None, *, source: str = ""):
    """``node``'s attribute ``name`` (``default`` when it has none), its type and size checked before HDF5 reads
    the value (:data:`READABLE_ATTRIBUTE_CLASSES`, :data:`MAX_ATTRIBUTE_BYTES`); a damaged one raises
    :class:`FormatError` naming ``source``."""
    import h5py  # (not _h5py: a thresholds map needs no plugin to be read)
    if name not in node.attrs:
        return default
    try:
        raw = h5py.h5a.open(node.id, name.encode())
        dtype = raw.get_type()
        kind = dtype.get_super() if dtype.get_class() == h5py.h5t.ARRAY else dtype
        size = raw.get_storage_size()
    except (KeyError, OSError, RuntimeError, ValueError) as error:
        raise FormatError(f"{source}: attribute {name!r} of {node.name} cannot be read ({error}; a damaged "
                          "file?)") from None
    if kind.get_class() not in READABLE_ATTRIBUTE_CLASSES or size > MAX_ATTRIBUTE_BYTES:
        raise FormatError(f"{source}: attribute {name!r} of {node.name} is not a number or text of at most "
                          f"{MAX_ATTRIBUTE_BYTES:,} bytes (HDF5 type class {dtype.get_class()}, {size:,} bytes; "
                          "a damaged file?)")
    try:
        return node.attrs[name]
    except (OSError, RuntimeError, TypeError, ValueError) as error:
        raise FormatError(f"{source}: attribute {name!r} of {node.name} cannot be read ({error}; a damaged "
                          "file?)") from None


def attributes(node, *, source: str = "") -> dict:
    """All of ``node``'s attributes, each read by :func:`attribute`."""
    return {str(name): attribute(node, name, source=source) for name in node.attrs}


def _attr_size(source: str, *nodes) -> tuple[int, int] | None:
    """(width, height) from ``width``/``height`` or ``sensor_resolution = (H, W)`` attributes, if any."""
    for node in nodes:
        if node is None:
            continue
        if "width" in node.attrs and "height" in node.attrs:
            return (int(np.asarray(attribute(node, "width", source=source)).item()),
                    int(np.asarray(attribute(node, "height", source=source)).item()))
    for node in nodes:
        if node is not None and "sensor_resolution" in node.attrs:
            resolution = np.asarray(attribute(node, "sensor_resolution", source=source)).ravel()
            if resolution.size >= 2:
                return int(resolution[1]), int(resolution[0])
    return None


class Hdf5Reader:
    """Reads the HDF5 layouts above in slices of ``options.chunk_events``; ``t`` comes out absolute (int64 us).

    Parameters
    ----------
    source : evtools.formats.io.Source
        The input; stdin is spooled to a temporary file (HDF5 needs random access).
    options : evtools.formats.registry.ReadOptions
        ``sensor_size`` is used when the file does not store it (else it is inferred by a scan, with a warning).
    """

    def __init__(self, source: Source, options: ReadOptions) -> None:
        h5py = _h5py()
        self.source = source
        self.name = source.name
        self.chunk_events = max(1, int(options.chunk_events))
        self._recycled = Recycled()
        self.frames: deque[Frame] = deque()  # APS frames read, not yet taken (EventStream.take_frames)
        self.frames_read, self._frame_times, self._next_frame = 0, None, 0
        check_global_heaps(source.spooled(), self.name)
        try:
            self.file = h5py.File(source.spooled(), "r")
        except (OSError, ValueError, RuntimeError, KeyError, TypeError, OverflowError) as error:  # h5py's, damaged
            raise FormatError(f"{self.name}: not a readable HDF5 file ({error})") from None
        try:
            with self._corruption():
                self._open_layout(options)
        except BaseException:
            self.file.close()
            raise

    @contextlib.contextmanager
    def _corruption(self):
        """h5py's own exceptions on a damaged file (RuntimeError, KeyError, ...) as one FormatError naming it."""
        try:
            yield
        except FormatError:
            raise
        except (OSError, RuntimeError, ValueError, KeyError, TypeError, AttributeError, IndexError,
                OverflowError, UnicodeDecodeError) as error:
            raise FormatError(f"{self.name}: damaged or unreadable HDF5 ({type(error).__name__}: {error})") from None

    def _open_layout(self, options: ReadOptions) -> None:
        h5py = _h5py()
        f = self.file
        group = f.get("events")
        self.t_offset_us = 0
        self.ms_to_idx: np.ndarray | None = None  # DSEC's index, to check the times read against (see _check_times)
        cd = f.get("CD")
        if isinstance(cd, h5py.Group) and isinstance(cd.get("events"), h5py.Dataset):
            self._open_prophesee(cd["events"], options)
            return
        self._refuse_ecf()
        if isinstance(group, h5py.Group) and all(k in group for k in ("x", "y", "t", "p")):
            self.layout = "evtools" if _text(attribute(f, "format", source=self.name)) == "evtools" else "dsec"
            if self.layout == "evtools" and "cut" in f.attrs:  # (written from a cut input: said, and passed on)
                self.cut_file = True
                logging.getLogger("evtools").warning(f"{self.name}: {_text(attribute(f, 'cut', source=self.name))}")
            self.columns = [group[k] for k in ("t", "x", "y", "p")]
            index = f.get("ms_to_idx")
            if isinstance(index, h5py.Dataset) and index.ndim == 1 and index.dtype.kind in "iu" and (
                    0 < len(index) <= MAX_MS_CHECKED):
                self.ms_to_idx = np.asarray(index[()], dtype=np.int64)
            if "t_offset" in f:
                self.t_offset_us = int(np.asarray(f["t_offset"][()]).item())
            elif "t_offset" in f.attrs:
                self.t_offset_us = int(np.asarray(attribute(f, "t_offset", source=self.name)).item())
        elif isinstance(group, h5py.Group) and all(k in group for k in ("xs", "ys", "ts", "ps")):
            self.layout = "event_utils"
            self.columns = [group[k] for k in ("ts", "xs", "ys", "ps")]
        elif isinstance(group, h5py.Dataset) and group.ndim == 2 and group.shape[1] == 4:
            self.layout = "v2e"
            self.columns = [group]
        else:
            raise FormatError(
                f"{self.name}: no events dataset recognised (expected events/{{x,y,t,p}}, events/{{xs,ys,ts,ps}} "
                f"or an N x 4 'events'); found: {self._listing()}"
            )
        for column in self.columns:
            if column.ndim != (2 if self.layout == "v2e" else 1):
                raise FormatError(f"{self.name}: dataset {column.name} has shape {column.shape}, expected 1-D")
        lengths = {len(column) for column in self.columns}
        if len(lengths) != 1:
            raise FormatError(f"{self.name}: the event datasets have different lengths {sorted(lengths)}")
        self.n_events = lengths.pop()
        self._open_frames()
        events_group = group if isinstance(group, h5py.Group) else None
        width, height = resolve_sensor_size(
            self.source, _attr_size(self.name, f, events_group), options.sensor_size, self._scan_size
        )
        metadata = {"layout": self.layout, "events": self.n_events}
        if getattr(self, "info_frame_size", None):
            metadata["frame_size"] = self.info_frame_size
        if self.layout in ("dsec", "evtools"):
            metadata["t_offset_us"] = self.t_offset_us
        self.info = StreamInfo(width, height, "hdf5", metadata)

    def _open_frames(self) -> None:
        """APS frames: evtools' ``frames/`` (``images`` N x H x W, and the five times and offsets per frame, us;
        attributes ``width`` and ``height``: the frame stream's size, else the frames' extent) or
        event_utils' ``images/image*`` datasets (attribute ``timestamp`` in seconds; no exposure stored). Their times
        are read now, their images as the events pass them."""
        h5py = _h5py()
        group = self.file.get("frames")
        if isinstance(group, h5py.Group) and isinstance(group.get("images"), h5py.Dataset):
            images = group["images"]
            columns = {name: np.asarray(group[name][()], np.int64) for name in FRAME_TIMES + ("offset_x", "offset_y")
                       if isinstance(group.get(name), h5py.Dataset)}
            if images.ndim != 3 or any(len(column) != len(images) for column in columns.values()) or \
                    "exposure_end_us" not in columns:
                raise FormatError(f"{self.name}: frames/ holds images of shape {images.shape} and times of other "
                                  "lengths (a damaged file?)")
            self._frame_images, self._frame_columns = (lambda k: images[k]), columns
        elif self.layout == "event_utils" and isinstance(self.file.get("images"), h5py.Group):
            names = sorted(name for name, node in self.file["images"].items() if isinstance(node, h5py.Dataset))
            datasets = [self.file["images"][name] for name in names]
            try:
                seconds = np.array([float(np.asarray(attribute(d, "timestamp", source=self.name)).item())
                                    for d in datasets])
            except (KeyError, TypeError, ValueError):
                raise FormatError(f"{self.name}: an image in images/ has no numeric 'timestamp' attribute") from None
            t_us = np.round(seconds * 1e6).astype(np.int64)
            self._frame_images = lambda k: datasets[k][()]
            self._frame_columns = {"t_us": t_us, "exposure_begin_us": t_us, "exposure_end_us": t_us}
        else:
            return
        end_us = self._frame_columns["exposure_end_us"]
        self._frame_times = np.where(end_us != 0, end_us, self._frame_columns.get("t_us", end_us))  # Frame.order_us
        if (np.diff(self._frame_times) < 0).any():
            raise FormatError(f"{self.name}: the frames' times go backwards")
        if not len(end_us):
            return
        stated = [attribute(group, key, source=self.name) for key in ("width", "height")] \
            if isinstance(group, h5py.Group) and "width" in group.attrs and "height" in group.attrs else None
        if stated is not None:
            try:
                self.info_frame_size = (int(stated[0]), int(stated[1]))
            except (TypeError, ValueError):
                raise FormatError(f"{self.name}: frames/ states a frame size of {stated[0]} x {stated[1]}, not "
                                  "two whole numbers (a damaged file?)") from None
        else:  # (files before the size was stored: the frames' extent)
            shape = self._frame_images(0).shape
            self.info_frame_size = (int(np.max(self._frame_columns.get("offset_x", 0))) + shape[1],
                                    int(np.max(self._frame_columns.get("offset_y", 0))) + shape[0])

    def _frames_until(self, t_us: float) -> None:
        """Queue the frames whose exposure ended at or before ``t_us`` (all of them: ``inf``)."""
        if self._frame_times is None:
            return
        stop = int(np.searchsorted(self._frame_times, t_us, "right"))
        for k in range(self._next_frame, stop):
            column = {name: int(values[k]) for name, values in self._frame_columns.items()}
            frame = Frame(np.asarray(self._frame_images(k)), column.get("t_us", column["exposure_end_us"]),
                          column.get("exposure_begin_us", column["exposure_end_us"]), column["exposure_end_us"],
                          column.get("begin_us", 0), column.get("end_us", 0), column.get("offset_x", 0),
                          column.get("offset_y", 0))
            problem = frame_problem(frame, self.info_frame_size, int(self._frame_times[k - 1]) if k else None)
            if problem:
                raise FormatError(f"{self.name}: frame {k} {problem}")
            self.frames.append(frame)
            self.frames_read += 1
        self._next_frame = max(self._next_frame, stop)

    def _open_prophesee(self, dataset, options: ReadOptions) -> None:
        """Metavision's layout: ``CD/events`` records, ECF chunks decoded here (see the module's notes)."""
        names = dataset.dtype.names or ()
        if dataset.ndim != 1 or not all(name in names for name in PROPHESEE_FIELDS):
            raise FormatError(f"{self.name}: CD/events has shape {dataset.shape} and fields {names}; expected the "
                              f"1-D records {', '.join(PROPHESEE_FIELDS)} of a Prophesee HDF5 event file")
        filters = _filter_ids(dataset)
        self.ecf = ECF_FILTER_ID in filters
        if self.ecf and filters != [ECF_FILTER_ID]:
            raise FormatError(f"{self.name}: CD/events is filtered by {filters}: evtools decodes the ECF codec "
                              f"({ECF_FILTER_ID}) alone, not combined with other filters")
        if self.ecf and not 0 < dataset.chunks[0] <= MAX_BLOCK_EVENTS:
            raise FormatError(f"{self.name}: CD/events is stored in chunks of {dataset.chunks[0]:,} events; an ECF "
                              f"chunk holds at most {MAX_BLOCK_EVENTS:,} (a damaged file?)")
        self.layout, self.dataset, self.n_events = "prophesee", dataset, len(dataset)
        self.columns = [dataset]
        header = {key.lower(): _text(value) for key, value in attributes(self.file, source=self.name).items()}
        try:
            stated = header_size(header)
        except ValueError:
            raise FormatError(f"{self.name}: the sensor size in the file's attributes is not a number "
                              f"(format {header.get('format', '')})") from None
        width, height = resolve_sensor_size(self.source, stated, options.sensor_size, self._scan_size)
        self.info = StreamInfo(width, height, "hdf5", {"layout": self.layout, "events": self.n_events,
                                                       "ecf": self.ecf, "header": header})

    def _refuse_ecf(self) -> None:
        """An ECF-compressed dataset anywhere but in Metavision's CD/events cannot be read: say so."""
        h5py = _h5py()

        def visit(name, node):
            return name if isinstance(node, h5py.Dataset) and ECF_FILTER_ID in _filter_ids(node) else None

        found = self.file.visititems(visit)
        if found:
            raise FormatError(f"{self.name}: dataset {found} is compressed by Prophesee's ECF codec (id "
                              f"{ECF_FILTER_ID}), which evtools decodes only in a Prophesee event file's CD/events")

    def _listing(self, limit: int = 20) -> str:
        names: list[str] = []

        def visit(name, node):
            shape = getattr(node, "shape", None)
            names.append(f"{name} {shape} {node.dtype}" if shape is not None else f"{name}/")
            return True if len(names) >= limit else None

        self.file.visititems(visit)
        return ", ".join(names) if names else "nothing (an empty file)"

    def _read(self, start: int, stop: int) -> np.ndarray:
        if self.layout == "prophesee":
            return self._read_prophesee(start, stop)
        if self.layout == "v2e":
            rows = self.columns[0][start:stop]
            t, x, y, p = rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]
            on = p == 1  # v2e writes OFF as 0 (older versions -1)
        else:
            t, x, y, p = (column[start:stop] for column in self.columns)
            on = p > 0
        if t.dtype.kind == "f" and not np.isfinite(t).all():
            raise FormatError(f"{self.name}: event times that are not numbers between events {start} and {stop} "
                              "(a damaged file?)")
        _check_polarity(self.name, p, start, stop)
        if self.ms_to_idx is not None:
            self._check_times(t, start, stop)
        for field, values in (("x", x), ("y", y)):
            if len(values) and (np.min(values) < 0 or np.max(values) > 32767 or
                                (values.dtype.kind == "f" and not np.isfinite(values).all())):
                raise FormatError(f"{self.name}: event {field} coordinates outside 0..32767 between events {start} "
                                  f"and {stop} (a damaged file?)")
            fractional = np.flatnonzero(values != np.floor(values)) if values.dtype.kind == "f" else ()
            if len(fractional):  # (a pixel's coordinate is whole: refused, not cut)
                k = int(fractional[0])
                raise FormatError(f"{self.name}: event {field} coordinate {values[k].item()!r} (event {start + k}) "
                                  "is not a whole pixel")
        out = self._recycled.take(stop - start)
        words = record_words(out)  # each record's two words at once: the padding of a reused chunk zeroed
        if self.layout == "event_utils" or t.dtype.kind == "f":
            scale = 1e6 if self.layout == "event_utils" and t.dtype.kind == "f" else 1.0
            words[:, 0] = np.rint(t * scale)
            if scale == 1.0 and t.dtype.kind == "f" and np.any(words[:, 0] != t):  # (1000.7 us, or 1.25 s: taken as 1)
                k = int(np.argmax(words[:, 0] != t))
                raise FormatError(f"{self.name}: event time {t[k].item()!r} (event {start + k}) is not a whole "
                                  "number of microseconds, the unit of this layout's times (seconds? give them in us)")
        else:
            words[:, 0] = t
        if self.t_offset_us:
            words[:, 0] += self.t_offset_us
        words[:, 1] = second_words(x, y, on)
        return out

    def _check_times(self, t: np.ndarray, start: int, stop: int) -> None:
        """DSEC's ``ms_to_idx`` says where each millisecond starts (``t[ms_to_idx[ms]] >= 1000 ms >
        t[ms_to_idx[ms] - 1]``, times after ``t_offset``): the times read (``t``, events ``start:stop``) must agree
        wherever an entry points into them, else a damaged chunk of ``t`` (decoded as zeros, say) would be read as
        other events. One comparison an entry: the index has one a millisecond."""
        index = self.ms_to_idx
        first, last = np.searchsorted(index, [start, stop], side="left")
        ms = np.arange(first, min(last + 1, len(index)), dtype=np.int64)
        at = index[ms]
        t = np.asarray(t, dtype=np.int64)
        inside = (at >= start) & (at < stop)
        before = (at > start) & (at <= stop)
        wrong = np.zeros(len(ms), dtype=bool)
        wrong[inside] |= t[at[inside] - start] < 1000 * ms[inside]
        wrong[before] |= t[at[before] - 1 - start] >= 1000 * ms[before]
        if wrong.any():
            k = int(np.argmax(wrong))
            raise FormatError(f"{self.name}: the event times near event {int(at[k])} disagree with ms_to_idx (ms "
                              f"{int(ms[k])}): a damaged file?")

    def _read_prophesee(self, start: int, stop: int) -> np.ndarray:
        """Events ``start:stop`` of ``CD/events``; with ECF, ``start`` on a chunk boundary: whole chunks are
        decoded, each straight into its part of the result."""
        out = self._recycled.take(stop - start)
        if not self.ecf:
            self._put_records(self.dataset[start:stop], out, start)
            return out
        length = self.dataset.chunks[0]
        for offset in range(start, stop, length):
            target = out[offset - start:min(offset + length, stop) - start]
            stored_bytes = self.dataset.id.get_chunk_info_by_coord((offset,)).size
            if stored_bytes is None or stored_bytes > ECF_MAX_BYTES_PER_EVENT * length + 64:
                raise FormatError(f"{self.name}: the chunk of CD/events at event {offset} is stored in "
                                  f"{stored_bytes} bytes, more than any {length:,} events take (a damaged file?)")
            mask, stored = self.dataset.id.read_direct_chunk((offset,))
            if mask & 1:  # the optional filter was skipped when this chunk was written: the records as they are
                records = np.frombuffer(stored, self.dataset.dtype, count=min(len(target), len(stored) //
                                                                             self.dataset.dtype.itemsize))
                if len(records) < len(target):
                    raise FormatError(f"{self.name}: the chunk of CD/events at event {offset} holds "
                                      f"{len(records)} of its {len(target)} events")
                self._put_records(records, target, offset)
                continue
            # (the last chunk, when HDF5's filter wrote it, holds a whole chunk: the dataset's end pads it)
            decoded = target if len(target) == length else np.empty(length, EVENT_DTYPE)
            n = decode_ecf(np.frombuffer(stored, np.uint8), record_words(decoded))
            if n < 0:
                raise FormatError(f"{self.name}: the ECF chunk of CD/events at event {offset} {ECF_ERRORS[n]} "
                                  "(a damaged file?)")
            if n < len(target):
                raise FormatError(f"{self.name}: the ECF chunk of CD/events at event {offset} holds {n} events, "
                                  f"the dataset {len(target)}")
            if decoded is not target:
                target[:] = decoded[:len(target)]
        return out

    def _put_records(self, records: np.ndarray, out: np.ndarray, start: int) -> None:
        """Metavision's records (x, y, p, t) as evtools' events in ``out``."""
        x, y = records["x"], records["y"]
        if len(records) and (max(int(x.max()), int(y.max())) > 32767):
            raise FormatError(f"{self.name}: event coordinates beyond 32767 from event {start} (a damaged file?)")
        _check_polarity(self.name, records["p"], start, start + len(records))
        words = record_words(out)
        words[:, 0] = records["t"]
        words[:, 1] = second_words(x, y, records["p"] > 0)

    def _step(self) -> int:
        """Events read at a time: ``chunk_events``, or whole ECF chunks (at least one)."""
        if self.layout == "prophesee" and self.ecf:
            length = self.dataset.chunks[0]
            return max(1, self.chunk_events // length) * length
        return self.chunk_events

    def _scan_size(self) -> tuple[int, int]:
        width = height = 0
        step = self._step()
        for start in range(0, self.n_events, step):
            chunk = self._read(start, min(start + step, self.n_events))
            width = max(width, int(chunk["x"].max()) + 1)
            height = max(height, int(chunk["y"].max()) + 1)
        return width, height

    def expected_events(self) -> int:
        """How many events the file holds (a whole-file read's result is made that size at once)."""
        return self.n_events

    def __iter__(self) -> Iterator[np.ndarray]:
        step = self._step()
        for start in range(0, self.n_events, step):
            with self._corruption():
                chunk = self._read(start, min(start + step, self.n_events))
                if len(chunk):
                    self._frames_until(int(chunk["t"][-1]))
            for piece in range(0, len(chunk), self.chunk_events):
                yield chunk[piece:piece + self.chunk_events]
        with self._corruption():
            self._frames_until(np.inf)

    def close(self) -> None:
        self.file.close()


def _text(value) -> str:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return "" if value is None else str(value)


CHECKSUMS = True
"""Every dataset evtools writes carries HDF5's Fletcher-32 checksum per chunk (a filter built into the HDF5 library,
so any reader checks it): a damaged chunk is an error instead of other events. Cost: see the README (Robustness)."""


def _compression_args(name: str | None) -> dict:
    import hdf5plugin

    name = (name or DEFAULT_COMPRESSION).lower()
    if name == "none":
        return {}
    if name == "gzip":
        return {"compression": "gzip", "compression_opts": 4, "shuffle": True}
    if name == "lzf":
        return {"compression": "lzf", "shuffle": True}
    if name == "zstd":
        return dict(hdf5plugin.Zstd(clevel=1))
    raise FormatError(f"unknown HDF5 compression {name!r}; choose one of {', '.join(COMPRESSIONS)}")


_ABANDONED: list = []
"""h5py objects of files whose write failed, never freed (see :func:`abandon`)."""


def _check_polarity(name: str, p: np.ndarray, start: int, stop: int) -> None:
    """Polarities must be 1 (ON) or 0 / -1 (OFF, as the layouts write it): a 2 or a 0.5 is damage (it was read as
    ON, or as ON in one layout and OFF in another), refused naming the events' range."""
    if len(p) == 0:
        return
    wrong = (p.min() < -1 or p.max() > 1) if p.dtype.kind in "iub" else not np.isin(p, (-1.0, 0.0, 1.0)).all()
    if wrong:
        raise FormatError(f"{name}: polarities other than 1 (ON) and 0 or -1 (OFF) between events {start} and {stop} "
                          "(a damaged file?)")


def abandon(*objects) -> None:
    """Keep the h5py objects of a file whose write failed (a full disk) until the process ends: h5py crashes
    (SIGSEGV) when they are freed, even once closed (reproduced with h5py alone). The command line ends a failed run
    without the interpreter's finalisation (:func:`evtools.cli.main.main`), so they are never freed; a library
    user's process keeps them."""
    _ABANDONED.append(objects)


class Hdf5Writer:
    """Writes evtools' HDF5 layout: DSEC's datasets plus the sensor size as root attributes.

    ``events/x`` u2, ``events/y`` u2, ``events/t`` u8 (microseconds after ``t_offset``; always u8, since a
    streaming writer cannot know the span beforehand and the bytes must not depend on it), ``events/p`` u1,
    ``t_offset`` i8 (the first event's t, or 0), ``ms_to_idx`` u8 with
    ``t[ms_to_idx[ms]] >= 1000*ms > t[ms_to_idx[ms]-1]``; root attributes ``width``, ``height``,
    ``format = "evtools"``. Datasets are chunked and resizable and grow in blocks of exactly
    ``WRITE_BLOCK_EVENTS`` events, and no times are recorded, so the bytes depend only on the events.

    Parameters
    ----------
    stream : BinaryIO
        A seekable binary stream opened for reading and writing.
    info : evtools.StreamInfo
        Sensor size of the stream.
    options : evtools.formats.registry.WriteOptions
        ``compression``: none, gzip, lzf or zstd; default none (any HDF5 reader opens it:
        :data:`DEFAULT_COMPRESSION` has the measured sizes and speeds).
    """

    def __init__(self, stream: BinaryIO, info: StreamInfo, options: WriteOptions) -> None:
        h5py = _h5py()
        self.compression = (options.compression or DEFAULT_COMPRESSION).lower()
        filters = {**_compression_args(self.compression), "fletcher32": CHECKSUMS}
        self.stream = stream
        self.file = h5py.File(stream, "w", libver="earliest", track_order=False)
        self.file.attrs["width"] = np.int64(info.width)
        self.file.attrs["height"] = np.int64(info.height)
        self.file.attrs["format"] = "evtools"
        group = self.file.create_group("events")
        self.datasets = {}
        for key, dtype in (("x", "<u2"), ("y", "<u2"), ("t", "<u8"), ("p", "u1")):
            self.datasets[key] = group.create_dataset(
                key, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(HDF5_CHUNK_EVENTS,), track_times=False,
                **filters,
            )
        self.ms_dataset = self.file.create_dataset(
            "ms_to_idx", shape=(0,), maxshape=(None,), dtype="<u8", chunks=(MS_BLOCK,), track_times=False,
            **filters,
        )
        self.buffer = np.empty(WRITE_BLOCK_EVENTS, dtype=EVENT_DTYPE)
        self.pending_events = 0
        self.events_written = 0
        self.t_offset_us: int | None = None
        self.next_ms = 0
        self.ms_pending: list[np.ndarray] = []
        self.ms_pending_count = 0
        self.ms_written = 0
        self.filters = filters
        self.frame_datasets: dict | None = None  # frames/, made at the first frame
        self.frame_size = info.metadata.get("frame_size") or (info.width, info.height)

    def write_frame(self, frame: Frame) -> None:
        """An APS frame into ``frames/``: ``images`` (N x H x W, one HDF5 chunk a frame) and per frame its five times
        (us, absolute) and offset, the frame stream's size as the group's ``width`` and ``height``; every frame of a
        file has one size and pixel type."""
        try:
            if self.frame_datasets is None:
                group = self.file.create_group("frames")
                group.attrs["width"], group.attrs["height"] = (np.int64(side) for side in self.frame_size)
                image = frame.image
                self.frame_datasets = {"images": group.create_dataset(
                    "images", shape=(0, *image.shape), maxshape=(None, *image.shape), dtype=image.dtype,
                    chunks=(1, *image.shape), track_times=False, **self.filters)}
                for name in FRAME_TIMES + ("offset_x", "offset_y"):
                    self.frame_datasets[name] = group.create_dataset(
                        name, shape=(0,), maxshape=(None,), dtype="<i8", chunks=(256,),
                        track_times=False, fletcher32=CHECKSUMS)
            images = self.frame_datasets["images"]
            if frame.image.shape != images.shape[1:] or frame.image.dtype != images.dtype:
                raise FormatError(f"HDF5 stores frames of one size and type: a {frame.image.dtype} frame of "
                                  f"{frame.width} x {frame.height} after {images.dtype} frames of "
                                  f"{images.shape[2]} x {images.shape[1]}")
            n = len(images)
            values = dict(zip(FRAME_TIMES, (frame.t_us, frame.begin_us, frame.end_us, frame.exposure_begin_us,
                                            frame.exposure_end_us)), offset_x=frame.offset_x, offset_y=frame.offset_y)
            for name, dataset in self.frame_datasets.items():
                dataset.resize((n + 1, *dataset.shape[1:]))
                dataset[n] = frame.image if name == "images" else values[name]
        except BaseException as error:
            self._give_up(error)
            raise

    def write(self, chunk: np.ndarray) -> None:
        """Append a chunk of ``EVENT_DTYPE`` (sorted by t)."""
        if len(chunk) == 0:
            return
        try:
            self._write(chunk)
        except BaseException as error:
            self._give_up(error)
            raise

    def _write(self, chunk: np.ndarray) -> None:
        if self.t_offset_us is None:
            self.t_offset_us = int(chunk["t"][0])
        while len(chunk):
            take = min(WRITE_BLOCK_EVENTS - self.pending_events, len(chunk))
            if take == WRITE_BLOCK_EVENTS:
                self._append(chunk[:take])  # a whole block straight from the input
            else:
                self.buffer[self.pending_events : self.pending_events + take] = chunk[:take]
                self.pending_events += take
                if self.pending_events == WRITE_BLOCK_EVENTS:
                    self._append(self.buffer)
                    self.pending_events = 0
            chunk = chunk[take:]

    def _append(self, events: np.ndarray) -> None:
        t_us = events["t"] - self.t_offset_us
        if t_us[0] < 0 or (len(t_us) > 1 and (np.diff(t_us) < 0).any()):
            raise FormatError("events must be sorted by time to be written as HDF5")
        x, y = events["x"], events["y"]
        if x.min() < 0 or y.min() < 0:
            raise FormatError("negative coordinates cannot be written as HDF5 (u2)")
        start, stop = self.events_written, self.events_written + len(events)
        for key, values in (("x", x), ("y", y), ("t", t_us), ("p", events["p"])):
            dataset = self.datasets[key]
            dataset.resize((stop,))
            dataset[start:stop] = values.astype(dataset.dtype)
        last_ms = int(t_us[-1]) // 1000
        if last_ms >= MAX_MS_TO_IDX:
            raise FormatError(
                f"the events span {last_ms + 1:,} ms: the DSEC layout's ms_to_idx would hold an entry per ms, more "
                f"than the {MAX_MS_TO_IDX:,} allowed ({MAX_MS_TO_IDX * 8 / 2**30:.0f} GiB, {MAX_MS_TO_IDX / 3.6e6:.0f} "
                "hours); check the times' unit, or write another format")
        while last_ms >= self.next_ms:  # in blocks: a long gap costs no more memory than a block
            upto = min(last_ms, self.next_ms + MS_BLOCK * 16 - 1)
            ms = np.arange(self.next_ms, upto + 1, dtype=np.int64)
            self._append_ms(start + np.searchsorted(t_us, ms * 1000, side="left").astype(np.uint64))
            self.next_ms = upto + 1
        self.events_written = stop

    def _append_ms(self, indices: np.ndarray | None, final: bool = False) -> None:
        if indices is not None and len(indices):
            self.ms_pending.append(indices)
            self.ms_pending_count += len(indices)
        while self.ms_pending_count >= MS_BLOCK or (final and self.ms_pending_count):
            values = np.concatenate(self.ms_pending)
            block, rest = values[:MS_BLOCK], values[MS_BLOCK:]
            stop = self.ms_written + len(block)
            self.ms_dataset.resize((stop,))
            self.ms_dataset[self.ms_written : stop] = block
            self.ms_written = stop
            self.ms_pending = [rest] if len(rest) else []
            self.ms_pending_count = len(rest)

    def mark_cut(self, note: str) -> None:
        """The input was cut: the root attribute ``cut`` says so (evtools warns reading it), then :meth:`close`."""
        if self.file is not None:
            self.file.attrs["cut"] = note
        self.close()

    def close(self) -> None:
        """Write the last events, ``t_offset`` and ``ms_to_idx``, and close the HDF5 file (not ``stream``)."""
        if self.file is None:
            return
        try:
            if self.pending_events:
                self._append(self.buffer[: self.pending_events])
                self.pending_events = 0
            self._append_ms(None, final=True)
            self.file.create_dataset("t_offset", data=np.int64(self.t_offset_us or 0), track_times=False)
            self.file.close()  # HDF5 writes its last blocks through the stream here: a full disk fails here
        except BaseException as error:
            self._give_up(error)
            raise
        self.file = None
        self.stream.flush()

    def _give_up(self, error: BaseException) -> None:
        """After ``error``: the file is closed when HDF5 itself did not fail (events refused, a stop); after a
        failed write (an OSError: a full disk) its h5py objects are kept, never freed (see :func:`abandon`)."""
        if self.file is None:
            return
        if not isinstance(error, OSError):
            try:
                self.file.close()
                self.file = None
                return
            except BaseException:
                pass
        abandon(self.file, self.datasets, self.ms_dataset, self.frame_datasets)
        self.file, self.datasets, self.ms_dataset, self.frame_datasets = None, {}, None, None
