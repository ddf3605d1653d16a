"""AEDAT 2.0 (jAER): ``#`` header lines, then big-endian ``int32 address, int32 timestamp`` records.

Layout (FORMATS.md, after jAER's ``DVS128.java`` and ``DavisChip.java``): the header is ASCII lines starting
with ``#`` (CRLF in files jAER writes, LF in some others) and ends at the first byte that is not ``#``; the
``# AEChip:`` line names the sensor's Java class, which fixes the address layout:

- DVS128: ``x = 127 - ((a & 0xFE) >> 1)``, ``y = (a & 0x7F00) >> 8`` counted from the bottom, polarity
  ``1 - (a & 1)``; ``a & 0x8000`` marks special events (skipped).
- DAVIS (240, 346): ``y`` bits 22-30, ``x`` bits 12-21 (both flipped: origin bottom-right in jAER's raw
  numbering), polarity bit 11 (1 = ON); bit 31 marks APS/IMU samples, bit 10 external input (both skipped).

In evtools' image convention both become ``x = W-1-raw_x``, ``y = H-1-raw_y``. Timestamps are 32-bit
microsecond counters that wrap every 2^32 us (71.6 min); the reader unwraps them into int64 (a fall by more than
half the range is a wrap) and the writer stores ``t mod 2^32``, with the multiple of 2^32 us below the first time
in a ``# evtools-t0-us: N`` header line that evtools adds back (jAER ignores it), and refuses a gap between
consecutive events that the reader would unwrap otherwise (any below 2^31 us, 35.8 min, fits).

References
----------
jAER: ``net.sf.jaer.eventio.AEFileInputStream``, ``ch.unizh.ini.jaer.chip.retina.DVS128``,
``eu.seebetter.ini.chips.DavisChip`` (https://github.com/SensorsINI/jaer).
"""

from __future__ import annotations

import logging
import re
from typing import BinaryIO, Iterator

import numpy as np

import evtools
from evtools.events import EVENT_DTYPE, MAX_TIME_US, StreamInfo
from evtools.formats.errors import FormatError
from evtools.formats.io import Source, ends_cut, resolve_sensor_size
from evtools.formats.registry import ReadOptions, WriteOptions

log = logging.getLogger("evtools")

MAGIC = b"#!AER-DAT2.0\r\n"
RECORD_BYTES = 8
WRAP_US = 1 << 32
"""Period of the 32-bit timestamp counter."""
HALF_WRAP_US = 1 << 31
"""A decrease larger than this between consecutive timestamps is a wrap of the counter."""
HASH = 0x23
"""``#``: a body may not start with this byte, or readers take the first record for a header line."""

LAYOUT_SIZES = {"dvs128": (128, 128), "davis240": (240, 180), "davis346": (346, 260)}
"""Sensor size of each address layout."""
CHIP_CLASSES = {
    "dvs128": "ch.unizh.ini.jaer.chip.retina.DVS128",
    "davis240": "eu.seebetter.ini.chips.davis.DAVIS240C",
    "davis346": "eu.seebetter.ini.chips.davis.Davis346red",
}
"""jAER's Java class written in ``# AEChip:`` for each layout."""
SIZE_LINE = "# evtools-sensor-size:"
T0_LINE = "# evtools-t0-us:"
"""Header line of the time (us) added to every timestamp: the 32-bit counter's multiple of 2^32 us that the
writer could not store (jAER ignores the line and reads the times that much earlier)."""
"""Extra header line the writer adds when the stream is smaller than its layout (jAER ignores it)."""

_AECHIP = re.compile(r"^#\s*AEChip:\s*(\S+)")
_SIZE = re.compile(r"^#\s*evtools-sensor-size:\s*(\d+)\s*x\s*(\d+)", re.IGNORECASE)
_T0 = re.compile(r"^#\s*evtools-t0-us:\s*(-?\d+)\s*$", re.IGNORECASE)


def layout_of_chip(chip_class: str) -> str | None:
    """Address layout of a jAER chip class (``...retina.DVS128`` -> ``dvs128``), or None if unknown."""
    simple = chip_class.rsplit(".", 1)[-1].lower()
    for prefix, layout in (("dvs128", "dvs128"), ("davis346", "davis346"), ("davis240", "davis240")):
        if simple.startswith(prefix):
            return layout
    return None


def read_hash_header(stream: BinaryIO, marker: bytes = b"#") -> tuple[list[bytes], int, bytes]:
    """Read the lines starting with ``marker`` at the head of ``stream``.

    Returns
    -------
    lines : list of bytes
        The header lines, line endings included.
    header_bytes : int
        Their total length: the offset of the first body byte.
    first : bytes
        The first body byte already consumed (``b""`` at end of file).
    """
    lines: list[bytes] = []
    header_bytes = 0
    while True:
        first = stream.read(1)
        if first != marker:
            return lines, header_bytes, first
        line = first + stream.readline()
        lines.append(line)
        header_bytes += len(line)


def _check_layout(name: str, where: str) -> str:
    layout = name.lower()
    if layout not in LAYOUT_SIZES:
        raise FormatError(f"{where}: unknown AEDAT 2.0 layout {name!r}; known: {', '.join(LAYOUT_SIZES)}")
    return layout


class Aedat2Reader:
    """Read a jAER AEDAT 2.0 file chunk by chunk.

    Parameters
    ----------
    source : evtools.formats.io.Source
        The input, read once from its first byte (pipes work).
    options : evtools.formats.registry.ReadOptions
        ``aedat2_layout`` and ``sensor_size`` are used when the header has no known ``# AEChip:`` line.

    Notes
    -----
    ``info.metadata`` holds ``aechip`` (the Java class, or None), ``aedat2_layout`` and ``skipped_words``
    (counts of special, APS/IMU and external-input words, complete once the stream is read).
    """

    def __init__(self, source: Source, options: ReadOptions) -> None:
        self.source = source
        self.cut_file = False  # the file ends inside a record (read up to it: formats.io.ends_cut)
        self.name = source.name
        self.chunk_records = max(1, int(options.chunk_events))
        lines, self.header_bytes, self._first = read_hash_header(source.stream)
        if not lines or not lines[0].startswith(b"#!AER-DAT2"):
            found = lines[0][:16] if lines else self._first
            raise FormatError(f"{self.name}: not an AEDAT 2.0 file (starts with {found!r}, expected {MAGIC!r})")
        if not lines[-1].endswith(b"\n"):  # the file ends inside a header line: cut, not an empty recording
            raise FormatError(f"{self.name}: truncated AEDAT 2.0 header (the file ends inside a header line, at "
                              f"byte {self.header_bytes})")
        text = [line.decode("latin-1").rstrip("\r\n") for line in lines]
        chip = next((m.group(1) for m in map(_AECHIP.match, text) if m), None)
        stored = next(((int(m.group(1)), int(m.group(2))) for m in map(_SIZE.match, text) if m), None)
        self.t0_us = next((int(m.group(1)) for m in map(_T0.match, text) if m), 0)
        if abs(self.t0_us) > MAX_TIME_US:
            raise FormatError(f"{self.name}: the header's t0 ({self.t0_us} us) lies outside the +-2^62 us that "
                              "evtools supports")

        layout = layout_of_chip(chip) if chip else None
        if layout is not None:
            if options.aedat2_layout and _check_layout(options.aedat2_layout, self.name) != layout:
                log.warning("%s: header names chip %s (%s layout); ignoring --aedat2-layout %s",
                            self.name, chip, layout, options.aedat2_layout)
            self.decode_size = LAYOUT_SIZES[layout]
        elif options.aedat2_layout:
            layout = _check_layout(options.aedat2_layout, self.name)
            self.decode_size = tuple(options.sensor_size) if options.sensor_size else LAYOUT_SIZES[layout]
        elif options.sensor_size:
            self.decode_size = tuple(options.sensor_size)
            layout = "dvs128" if self.decode_size == (128, 128) else "davis"
        else:
            said = f"chip class {chip} is unknown" if chip else "the header has no '# AEChip:' line"
            raise FormatError(
                f"{self.name}: cannot tell the AEDAT 2.0 address layout ({said}); "
                "give --aedat2-layout dvs128|davis240|davis346 or --sensor-size WxH"
            )
        self.layout = layout
        width, height = resolve_sensor_size(source, stored or self.decode_size, options.sensor_size)
        self.skipped = {"special": 0, "aps_imu": 0, "external_input": 0}
        self.info = StreamInfo(
            width, height, "aedat2",
            metadata={"aechip": chip, "aedat2_layout": layout, "skipped_words": self.skipped, "t0_us": self.t0_us},
        )
        self._last_raw_t: int | None = None
        self._wraps = 0

    def __iter__(self) -> Iterator[np.ndarray]:
        stream = self.source.stream
        pending = self._first
        records_read = 0
        block_bytes = self.chunk_records * RECORD_BYTES
        while True:
            data = stream.read(block_bytes - len(pending))
            buffer = pending + data if pending else data
            whole = len(buffer) // RECORD_BYTES * RECORD_BYTES
            if whole:
                yield self._decode(np.frombuffer(buffer, dtype=">u4", count=whole // 4))
                records_read += whole // RECORD_BYTES
            pending = buffer[whole:]
            if not data:
                break
        if pending:
            offset = self.header_bytes + records_read * RECORD_BYTES
            ends_cut(self, f"truncated AEDAT 2.0 record at byte offset {offset:,} ({len(pending)} of "
                           f"{RECORD_BYTES} bytes)")

    def _decode(self, words: np.ndarray) -> np.ndarray:
        """Events of a block of big-endian (address, timestamp) words, special/APS/IMU words dropped."""
        address = words[0::2]
        if self.layout == "dvs128":
            special = (address & 0x8000) != 0
            self.skipped["special"] += int(np.count_nonzero(special))
            keep = ~special
            address = address[keep]
            raw_x = (address & 0xFE) >> 1
            raw_y = (address & 0x7F00) >> 8
            on = (address & 1) == 0
        else:
            aps_imu = (address & 0x80000000) != 0
            external = ~aps_imu & ((address & 0x400) != 0)
            self.skipped["aps_imu"] += int(np.count_nonzero(aps_imu))
            self.skipped["external_input"] += int(np.count_nonzero(external))
            keep = ~(aps_imu | external)
            address = address[keep]
            raw_y = (address >> 22) & 0x1FF
            raw_x = (address >> 12) & 0x3FF
            on = (address & 0x800) != 0
        out = np.empty(len(address), dtype=EVENT_DTYPE)
        if len(out) == 0:
            return out
        width, height = self.decode_size
        out["x"] = (width - 1) - raw_x.astype(np.int64)
        out["y"] = (height - 1) - raw_y.astype(np.int64)
        out["p"] = on
        out["t"] = self._unwrap(words[1::2][keep].astype(np.int64))
        return out

    def _unwrap(self, raw_t: np.ndarray) -> np.ndarray:
        """int64 microseconds from wrapping 32-bit counts; the wrap count is carried from block to block."""
        previous = np.empty_like(raw_t)
        previous[0] = raw_t[0] if self._last_raw_t is None else self._last_raw_t
        previous[1:] = raw_t[:-1]
        wraps = np.cumsum((raw_t - previous) < -HALF_WRAP_US) + self._wraps
        self._last_raw_t = int(raw_t[-1])
        self._wraps = int(wraps[-1])
        return raw_t + wraps * WRAP_US + self.t0_us


class Aedat2Writer:
    """Write events as a jAER AEDAT 2.0 file (DVS128, DAVIS240 or DAVIS346 address layout).

    Parameters
    ----------
    stream : BinaryIO
        Where the bytes go (not closed by :meth:`close`).
    info : evtools.StreamInfo
        The stream's sensor size chooses the layout unless ``options.aedat2_layout`` names one.
    options : evtools.formats.registry.WriteOptions
        ``aedat2_layout``: dvs128, davis240 or davis346.

    Notes
    -----
    Timestamps are stored modulo 2^32 (jAER's 32-bit counter; the reader unwraps); a stream that starts later (DV's
    times are Unix times) gets a ``# evtools-t0-us:`` line, the multiple of 2^32 us below its first time, with a
    warning (jAER reads the times that much earlier); a gap the reader would unwrap otherwise is refused (one of
    2^31 us or more across a wrap, of 2^32 us or more anywhere).
    Times must not be negative. Leading events whose first byte would be ``#`` (DAVIS raw y 140..143) are dropped
    with a warning: they would read as header. The header is written with the first events (or at the end).
    """

    def __init__(self, stream: BinaryIO, info: StreamInfo, options: WriteOptions) -> None:
        self.stream = stream
        width, height = info.width, info.height
        if options.aedat2_layout:
            layout = _check_layout(options.aedat2_layout, "AEDAT 2.0 writer")
        elif (width, height) == (128, 128):
            layout = "dvs128"
        elif width <= 240 and height <= 180:
            layout = "davis240"
        elif width <= 346 and height <= 260:
            layout = "davis346"
        else:
            raise FormatError(
                f"AEDAT 2.0 cannot hold a {width}x{height} sensor (jAER layouts: DVS128 128x128, "
                "DAVIS240 240x180, DAVIS346 346x260); write another format"
            )
        self.layout = layout
        self.width, self.height = LAYOUT_SIZES[layout]
        if width > self.width or height > self.height:
            raise FormatError(
                f"AEDAT 2.0 layout {layout} ({self.width}x{self.height}) cannot hold a {width}x{height} sensor"
            )
        self.lines = [
            "#!AER-DAT2.0",
            f"# This is a raw AE data file created by evtools {evtools.__version__} - do not edit",
            "# Data format is int32 address, int32 timestamp (8 bytes total), repeated for each event",
            "# Timestamps tick is 1 us",
            f"# AEChip: {CHIP_CLASSES[layout]}",
        ]
        if (width, height) != (self.width, self.height):
            self.lines.append(f"{SIZE_LINE} {width}x{height}")
        self._headed = False
        self._last_t: int | None = None
        self._started = False
        self.dropped = 0

    def _write_header(self, t0_us: int) -> None:
        lines = self.lines + ([f"{T0_LINE} {t0_us}"] if t0_us else [])
        self.stream.write("".join(line + "\r\n" for line in lines).encode("ascii"))
        self._headed = True

    def write(self, chunk: np.ndarray) -> None:
        """Append a chunk of ``EVENT_DTYPE`` events."""
        if len(chunk) == 0:
            return
        t, x, y = chunk["t"], chunk["x"].astype(np.int64), chunk["y"].astype(np.int64)
        if t.min() < 0:
            raise FormatError(f"AEDAT 2.0 cannot store negative timestamps ({int(t.min())} us)")
        gaps = np.diff(t, prepend=t[0] if self._last_t is None else self._last_t)
        stored = np.diff(t & (WRAP_US - 1), prepend=(t[0] if self._last_t is None else self._last_t) & (WRAP_US - 1))
        read_back = np.where(stored < -HALF_WRAP_US, stored + WRAP_US, stored)  # as the reader unwraps them
        if np.any(read_back != gaps):
            gap = int(gaps[np.argmax(read_back != gaps)])
            raise FormatError(f"AEDAT 2.0 cannot store two consecutive events {gap:,} us apart here: its 32-bit "
                              "timestamps wrap every 2^32 us and a reader could not tell how many wraps lie between "
                              "them (gaps below 2^31 us, 35.8 minutes, always fit)")
        self._last_t = int(t[-1])
        if not self._headed:
            t0_us = int(t[0]) >> 32 << 32
            if t0_us:
                log.warning(f"AEDAT 2.0 keeps times modulo 2^32 us (71.6 minutes): the file's '{T0_LINE} {t0_us}' "
                            f"line holds the rest (evtools adds it back; jAER reads the times {t0_us:,} us earlier)")
            self._write_header(t0_us)
        if x.min() < 0 or y.min() < 0 or x.max() >= self.width or y.max() >= self.height:
            raise FormatError(f"AEDAT 2.0 layout {self.layout}: event outside {self.width}x{self.height}")
        raw_x = (self.width - 1) - x
        raw_y = (self.height - 1) - y
        if self.layout == "dvs128":
            address = (raw_y << 8) | (raw_x << 1) | (~chunk["p"]).astype(np.int64)
        else:
            address = (raw_y << 22) | (raw_x << 12) | (chunk["p"].astype(np.int64) << 11)
        if not self._started:
            hashes = (address >> 24) == HASH
            first = int(np.argmin(hashes)) if not hashes.all() else len(address)
            self.dropped += first
            if first == len(address):
                return
            self._started = True
            if self.dropped:
                self._warn()
            address, t = address[first:], t[first:]
        records = np.empty((len(address), 2), dtype=">u4")
        records[:, 0] = address
        records[:, 1] = t & (WRAP_US - 1)
        self.stream.write(records.tobytes())

    def _warn(self) -> None:
        log.warning(
            "AEDAT 2.0: dropped %d leading event(s) whose first byte 0x23 ('#') would be read as header", self.dropped
        )

    def close(self) -> None:
        """Finish the file (AEDAT 2.0 has no trailer; the header of a stream without events); does not close the
        stream."""
        if not self._headed:
            self._write_header(0)
        if self.dropped and not self._started:
            self._warn()
