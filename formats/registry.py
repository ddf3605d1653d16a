"""The one table of formats: detection by magic bytes, then by extension, and dispatch to readers and writers.

A reader class is built as ``Reader(source, options)`` from a :class:`formats.io.Source` and
:class:`ReadOptions`; it sets ``self.info`` (a :class:`evtools.StreamInfo`) in ``__init__`` and yields chunks
of ``EVENT_DTYPE`` from ``__iter__``, about ``options.chunk_events`` at a time, in file order. A writer class is
built as ``Writer(stream, info, options)`` from a binary stream, the stream's info and :class:`WriteOptions`;
``write(chunk)`` takes chunks and ``close()`` finishes the file (without closing ``stream``). The bytes written
never depend on how the events were cut into chunks.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from typing import Callable

from evtools.events import CHUNK_EVENTS

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


@dataclass(frozen=True)
class ReadOptions:
    """How to read an input: built once from the command line's input options (``--input-format``,
    ``--sensor-size``, ``--aedat2-layout``, and the global ``--max-latency`` and ``--timeout``) and passed to
    :func:`evtools.formats.open_events`; the same object from Python (``evtools.open(path, options=...)``, or its
    fields as keywords). Format-specific choices are fields named by their format (``aedat2_layout``)."""

    format: str | None = None
    """The input's format name (``--input-format``); None: recognised by magic bytes, then extension."""
    sensor_size: tuple[int, int] | None = None
    """(width, height) when the file does not say it (``--sensor-size``)."""
    chunk_events: int = CHUNK_EVENTS
    """About how many events a chunk holds."""
    aedat2_layout: str | None = None
    """AEDAT 2.0 address layout when the header has no ``# AEChip:`` line: dvs128, davis240 or davis346."""
    max_latency_s: float = 0.02
    """A live input's events wait at most this long in a reader (``--max-latency``): packets that arrived together
    are passed on as one chunk (a stage that fell behind catches up), but a chunk's first packet is never held
    longer than this for more."""
    connect_timeout_s: float = 10.0
    """How long connecting to a network input (``tcp://``) may take (``--timeout``)."""
    read_timeout_s: float = 60.0
    """A network input that sends nothing for this long is an error naming it (``--timeout``; a server that
    accepts and never sends made evtools wait forever)."""


@dataclass(frozen=True)
class WriteOptions:
    compression: str | None = None
    """Format-specific compression name (aedat4: none, lz4, zstd; hdf5: none, gzip, lzf, zstd); None = default."""
    aedat2_layout: str | None = None
    """AEDAT 2.0 layout to write: dvs128, davis240 or davis346; None = chosen from the sensor size."""


@dataclass(frozen=True)
class Format:
    name: str
    description: str
    extensions: tuple[str, ...]
    sniff: Callable[[bytes], bool]
    reader: str | None  # "module:Class", imported on first use
    writer: str | None
    writer_needs_seek: bool = False
    compressions: tuple[str, ...] = ()
    """The compressions its writer takes (``--compression``), the default first; none: it writes uncompressed."""

    def reader_class(self):
        return _load(self.reader)

    def writer_class(self):
        return _load(self.writer)


def _load(spec: str):
    module, name = spec.split(":")
    return getattr(importlib.import_module(module), name)


def _is_hdf5(head: bytes) -> bool:
    # HDF5 allows a user block of 512, 1024, 2048, ... bytes before the superblock
    return any(head[offset : offset + 8] == HDF5_MAGIC for offset in (0, 512, 1024, 2048))


def _is_prophesee(head: bytes) -> bool:
    return head.startswith(b"% ") and (b"evt" in head[:2048].lower())


def _is_prophesee_dat(head: bytes) -> bool:
    """Prophesee DAT: '%' header lines with a version or size line and no EVT line (that is a RAW file)."""
    return head.startswith(b"% ") and not _is_prophesee(head) and any(
        key in head[:2048] for key in (b"% Version", b"% Height", b"% Width", b"% Date"))


def _is_text(head: bytes, delimiter: bytes) -> bool:
    """Printable ASCII whose first lines (``#`` comments aside) are comma-separated (csv) or numbers and spaces (txt)."""
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError:
        return False
    lines = text.splitlines()[:8]
    if len(lines) > 1 and not head.endswith((b"\n", b"\r")):
        lines = lines[:-1]  # the last line may be cut by the head's end
    lines = [line for line in lines if line.strip() and not line.startswith("#")]
    if not lines or not all(line.isprintable() for line in lines):
        return False
    if delimiter == b",":
        return all("," in line for line in lines)
    return all(set(line) <= set("0123456789.eE+- \t") for line in lines)


FORMATS: tuple[Format, ...] = (
    Format("aedat4", "AEDAT 4.0 (DV, dv-processing)", (".aedat4",), lambda h: h.startswith(b"#!AER-DAT4.0") or h[8:12] == b"IOHE",
           "evtools.formats.aedat4:Aedat4Reader", "evtools.formats.aedat4:Aedat4Writer",
           compressions=("none", "lz4", "lz4-high", "zstd", "zstd-high")),
    Format("prophesee_dat", "Prophesee DAT (Metavision, version 2)", (), _is_prophesee_dat,
           "evtools.formats.prophesee:PropheseeDatReader", None),
    Format("aedat2", "AEDAT 2.0 (jAER)", (".aedat", ".dat"), lambda h: h.startswith(b"#!AER-DAT2"),
           "evtools.formats.aedat2:Aedat2Reader", "evtools.formats.aedat2:Aedat2Writer"),
    Format("aedat3", "AEDAT 3.1 (cAER, libcaer)", (".aedat3",), lambda h: h.startswith(b"#!AER-DAT3"),
           "evtools.formats.aedat3:Aedat3Reader", None),
    Format("hdf5", "HDF5 (DSEC, event_utils, v2e, Metavision, evtools)", (".h5", ".hdf5", ".hdf"), _is_hdf5,
           "evtools.formats.hdf5:Hdf5Reader", "evtools.formats.hdf5:Hdf5Writer", writer_needs_seek=True,
           compressions=("none", "zstd", "gzip", "lzf")),
    Format("prophesee", "Prophesee EVT 2.0 / 2.1 / 3.0 RAW (written as EVT 2.0)", (".raw",), _is_prophesee,
           "evtools.formats.prophesee:PropheseeRawReader", "evtools.formats.prophesee:Evt2Writer"),
    Format("csv", "CSV (t,x@W,y@H,on header)", (".csv",), lambda h: _is_text(h, b","),
           "evtools.formats.text:CsvReader", "evtools.formats.text:CsvWriter"),
    Format("txt", "text t x y p, t in seconds (rpg events.txt, v2e)", (".txt",), lambda h: _is_text(h, b" "),
           "evtools.formats.text:TxtReader", "evtools.formats.text:TxtWriter"),
)

BY_NAME = {f.name: f for f in FORMATS}
PIPE_FORMAT = "aedat4"
"""The format of streams on pipes: AEDAT 4.0, uncompressed."""


def by_name(name: str) -> Format:
    from evtools.formats.errors import FormatError

    try:
        return BY_NAME[name.lower()]
    except KeyError:
        raise FormatError(f"unknown format {name!r}; known: {', '.join(BY_NAME)}") from None


NOT_READ = {
    b"Event Stream": "Event Stream (.es: faery, neuromorphic_drivers); convert it with faery, e.g. "
                     "'faery input file x.es output file x.aedat4'",
    b"#ROSBAG V2.0": "a ROS 1 bag (rpg_dvs_ros); extract the events with the rosbag tools (e.g. to an rpg events.txt)",
}
"""Magic bytes of formats evtools recognises but does not read, and what to do instead."""

TEXT_FORMATS = ("csv", "txt")
"""Formats recognised by their content's look rather than by magic bytes: the extension comes first for them (a
``.csv`` of space-separated numbers is CSV, with microseconds, not rpg text in seconds)."""


def detect(head: bytes, path: str | None) -> Format | None:
    """The format of a file from its magic bytes; then from its extension; then from the look of its text; None if
    nothing tells."""
    for fmt in FORMATS:
        if fmt.name not in TEXT_FORMATS and fmt.sniff(head):
            return fmt
    return from_extension(path) or next((fmt for fmt in FORMATS if fmt.name in TEXT_FORMATS and fmt.sniff(head)),
                                        None)


def from_extension(path: str | None) -> Format | None:
    if not path:
        return None
    extension = os.path.splitext(path)[1].lower()
    for fmt in FORMATS:
        if extension in fmt.extensions:
            return fmt
    return None
