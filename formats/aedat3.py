"""AEDAT 3.1 (iniVation cAER / libcaer): ``#`` header lines, then packets with a 28-byte header.

Layout (FORMATS.md, after libcaer's ``events/common.h`` and ``events/polarity.h``): the header runs from
``#!AER-DAT3.1`` to ``#!END-HEADER``; each packet is ``int16 eventType, int16 eventSource, int32 eventSize,
int32 eventTSOffset, int32 eventTSOverflow, int32 eventCapacity, int32 eventNumber, int32 eventValid``
(little-endian) followed by ``eventCapacity * eventSize`` bytes. Polarity events (type 1) are ``uint32 data,
int32 ts``: bit 0 valid, bit 1 polarity (1 = ON), bits 2-16 y, bits 17-31 x, and the full time is
``(eventTSOverflow << 31) | ts`` microseconds. Frame events (type 2, libcaer's ``frame.h``) are ``uint32 info``
(bit 0 valid, bits 1-3 colour channels: 1 gray, 3 RGB, 4 RGBA), ``int32`` start and end of frame, start and end of
exposure, ``int32 lengthX, lengthY, positionX, positionY``, then ``uint16`` pixels (row-major, channels
interleaved): read as APS frames (:class:`evtools.Frame`, 16-bit gray; colour converted with a warning). Other
packet types (IMU, special) are skipped.

References
----------
iniVation, AEDAT 3.1 file format; libcaer ``include/libcaer/events/common.h``, ``polarity.h``
(https://gitlab.com/inivation/dv/libcaer).
"""

from __future__ import annotations

import os
import re
import struct
from collections import deque
from typing import BinaryIO, Iterator

import numpy as np

from evtools.events import EVENT_DTYPE, StreamInfo
from evtools.frames import Frame, frame_problem, gray
from evtools.formats.errors import FormatError
from evtools.formats.io import MAX_PACKET_BYTES, Source, ends_cut, read_at_most, resolve_sensor_size, size_scan
from evtools.formats.registry import ReadOptions

MAGIC = b"#!AER-DAT3.1\r\n"
END_HEADER = b"#!END-HEADER"
PACKET_HEADER = struct.Struct("<hhiiiiii")
POLARITY_EVENT = 1
FRAME_EVENT = 2
FRAME_HEADER = struct.Struct("<Iiiiiiiii")
"""A frame event's fields before its pixels: info, four times, lengthX, lengthY, positionX, positionY."""

SOURCE_SIZES = (("dvs128", (128, 128)), ("davis240", (240, 180)), ("davis346", (346, 260)))
"""Sensor size by the camera named in ``#Source N: NAME`` (only names whose size is unambiguous)."""
_SIZE_X = re.compile(r"(?:dvs|data)?sizeX\D{0,40}?(\d+)", re.IGNORECASE)
_SIZE_Y = re.compile(r"(?:dvs|data)?sizeY\D{0,40}?(\d+)", re.IGNORECASE)
_SOURCE = re.compile(r"^#Source\s+(\d+):\s*(.*)$")


def _header_size(text: str, sources: dict[int, str]) -> tuple[int, int] | None:
    """Sensor size named by the header: explicit sizeX/sizeY values, else a known camera name."""
    size_x, size_y = _SIZE_X.search(text), _SIZE_Y.search(text)
    if size_x and size_y:
        return int(size_x.group(1)), int(size_y.group(1))
    for description in sources.values():
        simple = description.replace(" ", "").lower()
        for prefix, size in SOURCE_SIZES:
            if simple.startswith(prefix):
                return size
    return None


class Aedat3Reader:
    """Read the polarity events of an AEDAT 3.1 file chunk by chunk.

    Parameters
    ----------
    source : evtools.formats.io.Source
        The input, read once from its first byte (pipes work).
    options : evtools.formats.registry.ReadOptions
        ``sensor_size`` is used when the header does not tell it.

    Notes
    -----
    ``info.metadata`` holds ``sources`` (``#Source`` lines by id), ``skipped_packets`` (count by event type)
    and ``invalid_events`` (polarity events with the valid bit clear), complete once the stream is read.
    """

    def __init__(self, source: Source, options: ReadOptions) -> None:
        self.source = source
        self.cut_file = False  # the file ends inside a packet (read up to it: formats.io.ends_cut)
        self.name = source.name
        self.chunk_events = max(1, int(options.chunk_events))
        first = source.stream.readline()
        if not first.startswith(b"#!AER-DAT3"):
            raise FormatError(f"{self.name}: not an AEDAT 3.1 file (starts with {first[:16]!r}, expected {MAGIC!r})")
        lines = [first]
        while not lines[-1].startswith(END_HEADER):
            line = source.stream.readline()
            if not line.startswith(b"#"):
                raise FormatError(f"{self.name}: AEDAT 3.1 header has no {END_HEADER.decode()} line")
            lines.append(line)
        if not lines[-1].endswith(b"\n"):  # (a file cut inside that line read as no events on a 1 x 1 sensor)
            raise FormatError(f"{self.name}: the file ends inside its AEDAT 3.1 header (a cut file?)")
        self.header_bytes = sum(map(len, lines))
        text = [line.decode("latin-1").rstrip("\r\n") for line in lines]
        sources = {int(m.group(1)): m.group(2).strip() for m in map(_SOURCE.match, text) if m}
        width, height = resolve_sensor_size(
            source, _header_size("\n".join(text), sources), options.sensor_size, scan=self._scan
        )
        self.skipped_packets: dict[int, int] = {}
        self.frames: deque[Frame] = deque()  # read, not yet taken (EventStream.take_frames)
        self.frames_read = 0
        self.info = StreamInfo(
            width, height, "aedat3",
            metadata={"version": text[0][2:], "sources": sources, "skipped_packets": self.skipped_packets,
                      "invalid_events": 0},
        )
        first_extent = self._first_frame_size() if source.seekable else None
        if first_extent is not None:  # (the APS covers the sensor: a first frame of a region lies within it)
            self.info.metadata["frame_size"] = (max(first_extent[0], width), max(first_extent[1], height))

    def _packets(self, stream: BinaryIO, offset: int, skipped: dict[int, int], frames=None) -> Iterator[np.ndarray]:
        """(events, invalid count) of each polarity packet from ``offset`` (where ``stream`` is) to the end; the
        frames of frame packets into ``frames`` (None: skipped)."""
        while True:
            head = stream.read(PACKET_HEADER.size)
            if not head:
                return
            if len(head) < PACKET_HEADER.size:
                ends_cut(self, f"truncated AEDAT 3.1 packet header at byte offset {offset:,} ({len(head)} of "
                               f"{PACKET_HEADER.size} bytes)")
                return
            kind, _, size, ts_offset, overflow, capacity, number, _ = PACKET_HEADER.unpack(head)
            if size <= 0 or capacity < 0 or not 0 <= number <= capacity or size * capacity > MAX_PACKET_BYTES:
                raise FormatError(
                    f"{self.name}: corrupt AEDAT 3.1 packet header at byte offset {offset} "
                    f"(eventSize {size}, eventCapacity {capacity}, eventNumber {number}"
                    + (f": {size * capacity:,} bytes, more than a packet holds)" if size > 0 and capacity > 0 else ")")
                )
            body = read_at_most(stream, size * capacity, self.source.seekable)
            if len(body) < size * capacity:
                ends_cut(self, f"truncated AEDAT 3.1 packet at byte offset {offset:,} ({len(body):,} of "
                               f"{size * capacity:,} body bytes)")
                return
            packet_offset, offset = offset, offset + PACKET_HEADER.size + size * capacity
            if kind == FRAME_EVENT and frames is not None:
                frames.extend(self._frames_of(body, size, number, overflow, packet_offset))
                continue
            if kind != POLARITY_EVENT:
                skipped[kind] = skipped.get(kind, 0) + 1
                continue
            if size < 8 or not 4 <= ts_offset <= size - 4:
                raise FormatError(
                    f"{self.name}: polarity packet at byte offset {packet_offset} has eventSize {size}, "
                    f"eventTSOffset {ts_offset} (expected 8 and 4)"
                )
            layout = np.dtype({"names": ["data", "ts"], "formats": ["<u4", "<i4"], "offsets": [0, ts_offset],
                               "itemsize": size})
            raw = np.frombuffer(body, dtype=layout, count=number)
            valid = (raw["data"] & 1) != 0
            invalid = number - int(np.count_nonzero(valid))
            raw = raw[valid] if invalid else raw
            data = raw["data"]
            out = np.empty(len(raw), dtype=EVENT_DTYPE)
            out["t"] = (np.int64(overflow) << 31) | raw["ts"].astype(np.int64)
            out["x"] = data >> 17
            out["y"] = (data >> 2) & 0x7FFF
            out["p"] = (data & 2) != 0
            yield out, invalid

    def _frames_of(self, body: bytes, size: int, number: int, overflow: int, offset: int) -> list[Frame]:
        """The valid frame events of a frame packet's body."""
        where = f"{self.name}: frame packet at byte offset {offset}"
        if number and size < FRAME_HEADER.size:
            raise FormatError(f"{where} has eventSize {size}, less than a frame event's {FRAME_HEADER.size} bytes")
        frames, base = [], np.int64(overflow) << 31
        for k in range(number):
            start = k * size
            info, frame_start, frame_end, exposure_start, exposure_end, width, height, x0, y0 = \
                FRAME_HEADER.unpack_from(body, start)
            if not info & 1:
                continue
            channels = (info >> 1) & 7
            if channels not in (1, 3, 4) or width <= 0 or height <= 0 or x0 < 0 or y0 < 0 or \
                    FRAME_HEADER.size + 2 * width * height * channels > size:
                raise FormatError(f"{where}: a frame of {width} x {height} x {channels} channels at ({x0}, {y0}) "
                                  f"does not fit its {size}-byte event (a damaged packet?)")
            pixels = np.frombuffer(body, "<u2", width * height * channels, start + FRAME_HEADER.size)
            image, layout = gray(pixels.reshape(height, width, channels).astype(np.uint16), "RGB")
            times = [int(base | value) for value in (frame_start, frame_end, exposure_start, exposure_end)]
            frames.append(Frame(image, (times[2] + times[3]) // 2, times[2], times[3], times[0], times[1], x0, y0,
                                {"converted_from": layout} if layout else {}))
        frame_size = self.info.metadata.get("frame_size", (self.info.width, self.info.height))
        for frame in frames:
            problem = frame_problem(frame, frame_size, self._last_frame_us if self.frames_read else None)
            if problem:
                raise FormatError(f"{where}: a frame {problem}")
            self._last_frame_us = frame.order_us
            self.frames_read += 1
        return frames

    def _first_frame_size(self) -> tuple[int, int] | None:
        """The extent (offset + size) of the first frame (a file: its packet headers scanned, the stream put back), or
        None."""
        stream = self.source.stream
        position, offset = stream.tell(), self.header_bytes
        file_bytes = os.fstat(stream.fileno()).st_size if hasattr(stream, "fileno") else float("inf")
        try:
            while True:
                head = stream.read(PACKET_HEADER.size)
                if len(head) < PACKET_HEADER.size:
                    return None
                kind, _, size, _, _, capacity, number, _ = PACKET_HEADER.unpack(head)
                if size <= 0 or capacity < 0 or offset + PACKET_HEADER.size + size * capacity > file_bytes:
                    return None  # damaged or cut: the read proper says so
                if kind == FRAME_EVENT and number > 0 and size >= FRAME_HEADER.size:
                    header = stream.read(FRAME_HEADER.size)
                    if len(header) < FRAME_HEADER.size:
                        return None
                    fields = FRAME_HEADER.unpack(header)
                    return (fields[5] + fields[7], fields[6] + fields[8]) if fields[5] > 0 and fields[6] > 0 \
                        else None
                stream.seek(size * capacity, 1)
                offset += PACKET_HEADER.size + size * capacity
        finally:
            stream.seek(position)

    def _scan(self) -> tuple[int, int]:
        """(max x + 1, max y + 1) over the whole file; leaves the stream where it was."""
        stream = self.source.stream
        position = stream.tell()
        width = height = 0
        with size_scan(self):
            for events, _ in self._packets(stream, self.header_bytes, {}):
                if len(events):
                    width = max(width, int(events["x"].max()) + 1)
                    height = max(height, int(events["y"].max()) + 1)
        stream.seek(position)
        return width, height

    def __iter__(self) -> Iterator[np.ndarray]:
        pending: list[np.ndarray] = []
        held = 0
        for events, invalid in self._packets(self.source.stream, self.header_bytes, self.skipped_packets,
                                             self.frames):
            self.info.metadata["invalid_events"] += invalid
            if len(events):
                pending.append(events)
                held += len(events)
            if held >= self.chunk_events:
                yield np.concatenate(pending)
                pending, held = [], 0
        if pending:
            yield np.concatenate(pending)

