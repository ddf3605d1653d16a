"""AEDAT 4.0 (iniVation DV, dv-processing): the streaming format of evtools' pipes.

Layout (FORMATS.md; schemas in neuromorphicsystems/aedat ``flatbuffers/*.fbs``): ``#!AER-DAT4.0\\r\\n``, a
uint32 length and an ``IOHE`` flatbuffer (compression, file_data_position, XML description of the streams),
then packets ``int32 stream_id, int32 byte_size, body``; an event packet body is an (optionally LZ4- or
Zstd-framed) size-prefixed ``EVTS`` flatbuffer whose ``elements`` vector holds 16-byte ``Event`` structs -
exactly :data:`evtools.EVENT_DTYPE`, so packets are decoded with one ``np.frombuffer``.

The reader is evtools' own (one code path for files and pipes: the ``aedat`` package takes only a path, so
it cannot read a pipe whose first bytes were consumed to recognise its format); the tests check it against
``aedat`` and dv-processing. The writer streams: no index table (``file_data_position = -1``), packets of a
fixed number of events so that the bytes written never depend on the input's chunking.
"""

from __future__ import annotations

import logging
import os
import re
import struct
import threading
import time
import xml.etree.ElementTree as ET
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import BinaryIO, Iterator

import numpy as np

from evtools import interrupt

from evtools._kernels.aedat4 import PAYLOAD_MASK  # (a kernel module imports no numba until a kernel compiles)
from evtools.events import EVENT_DTYPE, StreamInfo
from evtools.frames import FORMAT_BGR, FORMAT_BGRA, FORMAT_GRAY, FORMAT_GRAY16, Frame, frame_problem, gray
from evtools.formats import io as formats_io
from evtools.formats.errors import FormatError
from evtools.formats.io import MAX_PACKET_BYTES, Source, ends_cut
from evtools.formats.registry import ReadOptions, WriteOptions

MAGIC = b"#!AER-DAT4.0\r\n"
COMPRESSION_CODES = {"none": 0, "lz4": 1, "lz4-high": 2, "zstd": 3, "zstd-high": 4}
COMPRESSION_XML = {0: "NONE", 1: "LZ4", 2: "LZ4_HIGH", 3: "ZSTD", 4: "ZSTD_HIGH"}
SCAN_PACKETS = True
"""Uncompressed files are read a block of whole packets at a time by a compiled kernel (:meth:`Aedat4Reader.
_scan_uncompressed`; the per-packet path cost 17 us a packet in Python). False: the per-packet path alone (the
tests compare the two)."""
SCAN_BLOCK_BYTES = 1 << 20
"""Bytes read at a time by the scan: whole packets of it are copied, the rest is read again with the next block."""
PACKET_HEAD_BYTES = 256
"""How much of an uncompressed packet is read to find its event vector before reading the events in place."""
PACKET_EVENTS = 1 << 15
"""Events per packet the writer emits (512 KiB): large enough for speed, small enough for pipe latency."""


def _decompressor(code: int, name: str):
    if code == 0:
        return None
    if code in (1, 2):
        import lz4.frame

        local = threading.local()  # a decompression context per thread, reused packet after packet: half the time
        # of lz4.frame.decompress, which makes one a call (docs/performance.md)

        def decompress(data: bytes) -> bytes:
            context = getattr(local, "context", None)
            if context is None:
                context = local.context = lz4.frame.create_decompression_context()
            try:
                out, used, ended = lz4.frame.decompress_chunk(context, data)
            except Exception:
                local.context = None  # (a context that failed is not reused)
                raise
            if not ended or used != len(data):
                local.context = None
                raise ValueError("the LZ4 frame is cut short or followed by other bytes")
            return out

        return decompress
    if code in (3, 4):
        import zstandard

        local = threading.local()  # a ZstdDecompressor is not to be shared by threads

        def decompress(data: bytes) -> bytes:
            if not hasattr(local, "context"):
                local.context = zstandard.ZstdDecompressor()
            return local.context.decompressobj().decompress(data)

        return decompress
    raise FormatError(f"{name}: unknown AEDAT 4.0 compression code {code}")


def _table_fields(buffer: memoryview, table: int) -> tuple[int, ...]:
    """Absolute positions of a flatbuffer table's fields (0 where a field is absent)."""
    (vtable_back,) = struct.unpack_from("<i", buffer, table)
    vtable = table - vtable_back
    vtable_size, _ = struct.unpack_from("<HH", buffer, vtable)
    offsets = struct.unpack_from(f"<{(vtable_size - 4) // 2}H", buffer, vtable + 4)
    return tuple(table + offset if offset else 0 for offset in offsets)


MAX_HEADER_BYTES = 16 << 20
"""The largest AEDAT 4.0 header read (its XML describes a few streams in a few kB)."""


def _parse_ioheader(data: bytes, name: str) -> tuple[int, int, str]:
    buffer = memoryview(data)
    try:
        (root,) = struct.unpack_from("<I", buffer, 0)
        fields = _table_fields(buffer, root) + (0, 0, 0)
        compression = struct.unpack_from("<i", buffer, fields[0])[0] if fields[0] else 0
        data_position = struct.unpack_from("<q", buffer, fields[1])[0] if fields[1] else -1
        description = ""
        if fields[2]:
            string = fields[2] + struct.unpack_from("<I", buffer, fields[2])[0]
            (length,) = struct.unpack_from("<I", buffer, string)
            description = bytes(buffer[string + 4 : string + 4 + length]).decode("utf-8", "replace")
    except struct.error:
        raise FormatError(f"{name}: AEDAT 4.0 header is corrupt") from None
    return compression, data_position, description



END_MARK_KEY = "evtoolsEndMark"
"""An evtools writer says (this attribute, true, in the event stream's info node) that it ends its stream with an
empty event packet, its end mark: DV, dv-processing and ``aedat`` read the packet as no events and the attribute
as nothing. A stream that says so and ends without the mark was cut (its writer killed, a pipe broken at a packet
boundary): on a pipe or socket an error, on a file a warning."""


def _parse_streams(description: str, name: str) -> dict[int, dict]:
    """Stream id -> {type, size, source, ...} from the IOHeader's XML description."""
    try:
        root = ET.fromstring(description)
    except ET.ParseError as error:
        raise FormatError(f"{name}: AEDAT 4.0 stream description is not valid XML ({error})") from None
    streams = {}
    out_info = next((node for node in root.iter("node") if node.get("name") == "outInfo"), None)
    for node in out_info if out_info is not None else ():
        if node.tag != "node" or not (node.get("name") or "").isdigit():
            continue
        attrs = {a.get("key"): a.text for a in node.findall("attr")}
        info = node.find("node[@name='info']")
        info_attrs = {a.get("key"): a.text for a in info.findall("attr")} if info is not None else {}
        typed = [[a.get("key"), a.get("type") or "string", a.text or ""] for a in node.findall("attr")]
        typed_info = [[a.get("key"), a.get("type") or "string", a.text or ""]
                      for a in (info.findall("attr") if info is not None else ())]
        streams[int(node.get("name"))] = {
            "attributes": typed,  # (key, type, text): what a side stream is written back with
            "info": typed_info,
            "type": attrs.get("typeIdentifier", ""),
            "name": attrs.get("originalOutputName", ""),
            "width": info_attrs.get("sizeX"),
            "height": info_attrs.get("sizeY"),
            "source": info_attrs.get("source", ""),
            "end_mark": info_attrs.get(END_MARK_KEY, "").strip().lower() == "true",
        }
    return streams


def _packet_layout(body: bytes, name: str, offset: int) -> tuple[int, int]:
    """Byte position and count of the events in a size-prefixed ``EVTS`` flatbuffer whose start is ``body``."""
    buffer = memoryview(body)
    try:
        if bytes(buffer[8:12]) != b"EVTS":
            raise FormatError(f"{name}: event packet at byte {offset} is not an EVTS flatbuffer")
        (root,) = struct.unpack_from("<I", buffer, 4)
        fields = _table_fields(buffer, 4 + root)
        if not fields or not fields[0]:
            return len(body), 0
        vector = fields[0] + struct.unpack_from("<I", buffer, fields[0])[0]
        (count,) = struct.unpack_from("<I", buffer, vector)
    except struct.error:
        raise FormatError(f"{name}: event packet at byte {offset} is corrupt or truncated") from None
    return vector + 4, count


FRAME_DTYPES = {FORMAT_GRAY: (np.uint8, 1), FORMAT_GRAY16: (np.uint16, 1), FORMAT_BGR: (np.uint8, 3),
                FORMAT_BGRA: (np.uint8, 4)}
"""DV's pixel formats read: dtype and channels."""


def _parse_frame(body: bytes, name: str, offset: int) -> Frame:
    """One decompressed, size-prefixed ``FRME`` flatbuffer: ``table Frame { t, begin_t, end_t, exposure_begin_t,
    exposure_end_t: int64; format: int8; width, height, offset_x, offset_y: int16; pixels: [uint8] }``."""
    buffer = memoryview(body)
    where = f"{name}: frame packet at byte {offset}"
    try:
        if bytes(buffer[8:12]) != b"FRME":
            raise FormatError(f"{where} is not a FRME flatbuffer")
        (root,) = struct.unpack_from("<I", buffer, 4)
        fields = _table_fields(buffer, 4 + root) + (0,) * 11

        def number(index: int, code: str) -> int:
            return struct.unpack_from(code, buffer, fields[index])[0] if fields[index] else 0

        times = [number(i, "<q") for i in range(5)]
        pixel_format = number(5, "<b")
        width, height, offset_x, offset_y = (number(i, "<h") for i in range(6, 10))
        if not fields[10]:
            raise FormatError(f"{where} has no pixels")
        vector = fields[10] + struct.unpack_from("<I", buffer, fields[10])[0]
        (count,) = struct.unpack_from("<I", buffer, vector)
    except struct.error:
        raise FormatError(f"{where} is corrupt or truncated") from None
    if pixel_format not in FRAME_DTYPES:
        raise FormatError(f"{where} has pixel format {pixel_format}; evtools reads gray (0), 16-bit gray (2), BGR "
                          "(16) and BGRA (24)")
    dtype, channels = FRAME_DTYPES[pixel_format]
    if width <= 0 or height <= 0 or count != width * height * channels * np.dtype(dtype).itemsize:
        raise FormatError(f"{where} holds {count:,} bytes of pixels for a {width} x {height} image of format "
                          f"{pixel_format} (a damaged packet?)")
    if vector + 4 + count > len(body):
        raise FormatError(f"{where} is truncated")
    pixels = np.frombuffer(body, dtype, width * height * channels, vector + 4).reshape(height, width, channels)
    image, layout = gray(pixels)
    metadata = {"converted_from": layout} if layout else {}
    image = image.copy()
    return Frame(image, times[0], times[3], times[4], times[1], times[2], offset_x, offset_y, metadata)


def _copy_records(target: np.ndarray, events: np.ndarray) -> None:
    """Copy event records as 8-byte words (a structured copy goes field by field: 15x slower), padding zeroed."""
    words = target.view(np.uint64).reshape(-1, 2)
    words[:] = events.view(np.uint64).reshape(-1, 2)
    words[:, 1] &= PAYLOAD_MASK


DECODE_THREADS = max(1, min(4, (os.cpu_count() or 2) - 1))
"""Threads that decompress packets (lz4 and zstandard release the GIL while they work), leaving a core to the
consumer: on 2 cores one, which overlaps decompression with reading (in-process LZ4 read of 10M events: 121 ->
164 Mev/s); two measured the same there, and a `bafilter` pipeline no faster (its kernel needs the other core)."""
ENCODE_THREADS = max(1, min(4, os.cpu_count() or 1))
"""Threads that compress packets when writing LZ4 or zstd (the codecs release the GIL; packets are written in
order). On 2 cores, `convert` of 10M events, 3 alternating runs each: to zstd 1.32-1.35 -> 0.73-0.84 s, to LZ4
0.67-0.81 -> 0.54-0.63 s, for 5 MiB more."""
ENCODE_AHEAD = 4
"""Packets being compressed at most (4 x 512 KiB)."""
DECODE_AHEAD = DECODE_THREADS
"""Groups of compressed packets (:meth:`Aedat4Reader._decode_group`) waiting or being decoded beyond the one being
placed, each about a chunk: one a decoding thread. On 2 cores 1 (was 2): `correct` on 10M LZ4 events peaked 4-6 MiB
lower, `bafilter` on 50M 4 MiB, at the same speed (3 alternating runs each)."""
GUESSED_RATIO = 2.0
"""Decoded bytes per compressed byte assumed for the first group (LZ4 on a DVXplorer recording: 2.0, zstd 2.9);
later groups are sized by the ratio of the group before, kept within 1 (a group of empty packets would otherwise
make the next group the rest of the file) and :data:`MAX_RATIO`."""
MAX_RATIO = 64.0


def _packet_events(body: bytes, name: str, offset: int) -> np.ndarray:
    """The events of one whole decompressed, size-prefixed ``EVTS`` flatbuffer."""
    events_at, count = _packet_layout(body, name, offset)
    if events_at + 16 * count > len(body):
        raise FormatError(f"{name}: event packet at byte {offset} is truncated")
    return np.frombuffer(body, EVENT_DTYPE, count, events_at)


@dataclass(frozen=True, eq=False)
class SidePacket:
    """A packet of a side stream, one evtools carries from an AEDAT 4.0 input to an AEDAT 4.0 output without reading
    it (DV's IMU samples ``IMUS``, triggers ``TRIG``, any other): its decompressed body (a size-prefixed
    flatbuffer, as it was), the index of its stream in ``info.metadata["side_streams"]``, and the time it belongs at
    (:attr:`order_us`: its first element's timestamp, else the time of the side packet before it)."""

    stream: int
    body: bytes
    order_us: int


def _first_element_us(body: bytes) -> int | None:
    """The timestamp of a DV packet's first element: ``table XPacket { elements: [X] }`` whose element is a table
    starting with ``timestamp: int64`` (DV's IMU ``IMUS``, Trigger ``TRIG``) or a struct that does (an event
    ``EVTS`` of a second event stream); None for an empty packet or another type."""
    buffer = memoryview(body)
    kind = bytes(buffer[8:12])
    if kind not in (b"IMUS", b"TRIG", b"EVTS"):
        return None
    try:
        (root,) = struct.unpack_from("<I", buffer, 4)
        fields = _table_fields(buffer, 4 + root)
        if not fields or not fields[0]:
            return None
        vector = fields[0] + struct.unpack_from("<I", buffer, fields[0])[0]
        if struct.unpack_from("<I", buffer, vector)[0] == 0:
            return None
        if kind == b"EVTS":  # (a vector of structs: the first event's time is its first field)
            return struct.unpack_from("<q", buffer, vector + 4)[0]
        element = vector + 4 + struct.unpack_from("<I", buffer, vector + 4)[0]
        element_fields = _table_fields(buffer, element)
        return struct.unpack_from("<q", buffer, element_fields[0])[0] if element_fields and element_fields[0] else None
    except (struct.error, ValueError):
        return None


class Aedat4Reader:
    """Reads the event stream of an AEDAT 4.0 file or pipe, its APS frames (:meth:`EventStream.take_frames`) and,
    when asked (:meth:`EventStream.carry_side_streams`), its other streams' packets (IMU samples, triggers:
    :class:`SidePacket`); else those are skipped and counted."""

    def __init__(self, source: Source, options: ReadOptions) -> None:
        self.source, self.options, self.name = source, options, source.name
        stream = source.stream
        # a network stream (dv-processing's NetworkWriter, DV's outputs) starts at the header's length: no magic
        magic = b"" if source.head[8:12] == b"IOHE" else stream.read(len(MAGIC))
        if magic not in (MAGIC, b""):
            raise FormatError(f"{self.name}: not an AEDAT 4.0 file (magic {magic[:14]!r})")
        header_size = self._read_exact(4, "header length")
        (length,) = struct.unpack("<I", header_size)
        if length > MAX_HEADER_BYTES:  # (a network input waited out --timeout for it, then said "sends nothing")
            raise FormatError(f"{self.name}: its header says it holds {length:,} bytes, more than any AEDAT 4.0 "
                              f"header's ({MAX_HEADER_BYTES:,}: a few kB of XML): not an AEDAT 4.0 stream, or damaged")
        code, self.data_position, description = _parse_ioheader(self._read_exact(length, "header"), self.name)
        self.position = len(magic) + 4 + length
        self.decompress = _decompressor(code, self.name)
        streams = _parse_streams(description, self.name)
        event_ids = sorted(i for i, s in streams.items() if s["type"] == "EVTS")
        if not event_ids:
            raise FormatError(f"{self.name}: AEDAT 4.0 file has no event stream")
        self.stream_id = event_ids[0]
        events = streams[self.stream_id]
        frame_ids = sorted(i for i, s in streams.items() if s["type"] == "FRME")
        self.frame_stream_id = frame_ids[0] if frame_ids else None
        self.frames: deque[Frame] = deque()  # read, not yet taken (EventStream.take_frames): file order
        self.frames_read = 0
        self.cut_file = False  # the file turned out cut (no end mark where one was promised, or cut inside a packet)
        self.expects_end_mark = events["end_mark"]
        self._last_count: int | None = None  # events in the last event packet read (0: the end mark)
        try:
            from_file = (int(events["width"]), int(events["height"])) if events["width"] else None
        except (ValueError, TypeError):
            from_file = None
        if from_file is None and options.sensor_size is None:
            raise FormatError(f"{self.name}: the event stream does not state its size; give --sensor-size WxH")
        width, height = formats_io.resolve_sensor_size(source, from_file, options.sensor_size)
        side_ids = sorted(i for i in streams if i not in (self.stream_id, self.frame_stream_id))
        self.side_ids = {stream_id: index for index, stream_id in enumerate(side_ids)}
        self.carry_side = False  # set by carry_side_streams(): the side streams' packets are queued, not skipped
        self.side_packets: deque[SidePacket] = deque()  # read, not yet taken (EventStream.take_side_packets)
        self._side_us = 0  # the time of the last side packet that had one
        self.info = StreamInfo(
            width, height, "aedat4",
            {"source": events["source"], "compression": COMPRESSION_XML.get(code, str(code)),
             "skipped_streams": sorted(streams[i]["name"] or streams[i]["type"] for i in side_ids)},
        )
        if side_ids:  # (an AEDAT 4.0 output declares them and carries their packets: DV's IMU samples, triggers)
            self.info.metadata["side_streams"] = [
                {key: streams[i][key] for key in ("type", "name", "attributes", "info")} for i in side_ids]
        if self.frame_stream_id is not None:
            frames = streams[self.frame_stream_id]
            try:
                self.info.metadata["frame_size"] = (int(frames["width"] or width), int(frames["height"] or height))
            except ValueError:
                raise FormatError(f"{self.name}: the frame stream's size is not a number") from None

    def _read_exact(self, n: int, what: str) -> bytes:
        data = formats_io.read_at_most(self.source.stream, n, self.source.seekable)
        if len(data) != n:
            raise FormatError(f"{self.name}: truncated AEDAT 4.0 {what} (wanted {n} bytes, got {len(data)})")
        return data

    def __iter__(self) -> Iterator[np.ndarray]:
        """Chunks of about ``chunk_events`` events (whole packets); uncompressed packets are read straight into them,
        compressed ones are decompressed by :data:`DECODE_THREADS` threads (the codecs release the GIL) in groups of
        about a chunk (:meth:`_decode_group`), up to :data:`DECODE_AHEAD` groups ahead, and placed in file order."""
        stream, self._skipped_packets = self.source.stream, 0
        self._recycled = formats_io.Recycled()
        self._staging = threading.local()  # each decoding thread's buffer of decompressed packets
        self._chunk, self._filled = self._recycled.take(self.options.chunk_events), 0
        pending: deque = deque()  # futures of decoded groups, in file order
        group: list[tuple[bytes, int]] = []  # compressed packets (body, file offset) not yet handed to the pool
        group_bytes, ratio = 0, GUESSED_RATIO
        pool = ThreadPoolExecutor(DECODE_THREADS, thread_name_prefix="evtools-decode") if self.decompress else None
        live, first_arrival_s = self.source.live, 0.0
        file_bytes = self._file_bytes = os.fstat(stream.fileno()).st_size \
            if self.source.seekable and hasattr(stream, "fileno") else float("inf")
        scan = SCAN_PACKETS and pool is None and not live and file_bytes < float("inf") and hasattr(stream, "readinto")
        try:
            while self.data_position < 0 or self.position < self.data_position:
                if scan:  # many whole event packets at once; the per-packet path below takes the one it leaves
                    yield from self._scan_uncompressed()
                    if self.position >= (self.data_position if self.data_position >= 0 else file_bytes):
                        break
                # a live input: what has arrived is passed on, unless the next packet has arrived whole and the
                # chunk is younger than options.max_latency_s (packets that arrived together go on together)
                if live and (self._filled or pending or group) and not (
                        time.monotonic() - first_arrival_s < self.options.max_latency_s and self._packet_waits()):
                    if group:
                        pending.append(pool.submit(self._decode_group, group))
                        group, group_bytes = [], 0
                    while pending:
                        yield from self._place_group(*pending.popleft().result())
                    yield self._chunk[:self._filled]
                    self._chunk, self._filled = self._recycled.take(self.options.chunk_events), 0
                head = stream.read(8)
                if not head:
                    if self.data_position >= 0:  # (a cut at a packet's end, in a file DV wrote with its data table)
                        ends_cut(self, f"the file ends at byte {self.position:,}, before the data table its header "
                                       f"places at byte {self.data_position:,}")
                    break
                if live and not (self._filled or pending or group):
                    first_arrival_s = time.monotonic()
                if len(head) != 8:
                    ends_cut(self, f"truncated AEDAT 4.0 packet header at byte {self.position:,}")
                    break
                stream_id, size = struct.unpack("<iI", head)
                offset = self.position
                if size > MAX_PACKET_BYTES:
                    if head.startswith(b"#!AER-DA"):  # (`cat a.aedat4 b.aedat4 |`: said as damage, a QA sweep)
                        raise FormatError(f"{self.name}: a second AEDAT file begins at byte {offset:,}, after the "
                                          "first's packets (files joined end to end?): evtools reads one stream; "
                                          "give the files as separate inputs")
                    raise FormatError(f"{self.name}: damaged AEDAT 4.0 packet header at byte {offset:,} (its size "
                                      f"field says {size:,} bytes, more than a packet holds)")
                if 0 <= self.data_position <= file_bytes and offset + 8 + size > self.data_position:
                    raise FormatError(f"{self.name}: damaged AEDAT 4.0 packet header at byte {offset:,} (its size "
                                      f"field says {size:,} bytes, past the data table the file reaches at byte "
                                      f"{self.data_position:,})")
                if offset + 8 + size > file_bytes:
                    ends_cut(self, f"truncated AEDAT 4.0 packet at byte {offset:,} (its size field says {size:,} "
                                   f"bytes, {file_bytes - offset - 8:,} follow)")
                    break
                self.position += 8 + size
                if stream_id != self.stream_id:
                    if stream_id == self.frame_stream_id and self.frame_stream_id is not None:
                        self._take_frame(self._read_packet(size, size, offset), offset)
                        continue
                    if self.carry_side and stream_id in self.side_ids:
                        self._take_side(stream_id, self._read_packet(size, size, offset), offset)
                        continue
                    if stream_id not in self.side_ids:  # (a stream id the header never declared: damage)
                        raise FormatError(f"{self.name}: damaged AEDAT 4.0 packet header at byte {offset:,} (stream "
                                          f"id {stream_id}, which the header does not declare)")
                    self._skipped_packets += 1
                    self._skip(size, offset)
                    continue
                if pool is not None:
                    group.append((self._read_packet(size, size, offset), offset))
                    group_bytes += size
                    # a live input's group takes the packets that have arrived (a pipe from a file: many)
                    if group_bytes * ratio >= 16 * self.options.chunk_events or (live and not self._packet_waits()):
                        pending.append(pool.submit(self._decode_group, group))
                        group, group_bytes = [], 0
                        if len(pending) > DECODE_AHEAD:
                            ratio = yield from self._place_group(*pending.popleft().result())
                    continue
                # the flatbuffer's tables come first, the event vector last: parse the start, then read the events
                start = self._read_packet(min(size, PACKET_HEAD_BYTES), size, offset)
                events_at, count = _packet_layout(start, self.name, offset)
                if events_at + 16 * count != size or events_at > len(start):
                    yield from self._place(_packet_events(start + self._read_packet(size - len(start), size, offset),
                                                          self.name, offset))
                    continue
                yield from self._make_room(count)
                self._last_count = count
                target = self._chunk[self._filled: self._filled + count]  # straight from the file into the chunk
                target_bytes = target.view(np.uint8)
                have = len(start) - events_at
                target_bytes[:have] = np.frombuffer(start, np.uint8, have, events_at)
                if stream.readinto(memoryview(target_bytes)[have:]) != 16 * count - have:  # (a stream of unknown size)
                    ends_cut(self, f"truncated AEDAT 4.0 packet at byte {offset:,}")
                    break
                target.view(np.uint64).reshape(-1, 2)[:, 1] &= PAYLOAD_MASK  # the file's padding: zeroed
                self._filled += count
            if group:
                pending.append(pool.submit(self._decode_group, group))
            while pending:
                yield from self._place_group(*pending.popleft().result())
        finally:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)
            self._recycled.arrays.clear()  # the chunks given out stay valid; nothing more is recycled
        if self._filled:
            yield self._chunk[:self._filled]
        self.info.metadata["skipped_packets"] = self._skipped_packets
        if self.expects_end_mark and self._last_count != 0 and not self.cut_file:
            self._cut()

    def _scan_uncompressed(self) -> Iterator[np.ndarray]:
        """Whole packets of a seekable uncompressed file, a block at a time: event packets copied into the chunk by
        a compiled kernel (:func:`evtools._kernels.aedat4.copy_event_packets`), frame packets and other streams'
        taken from the block too. Returns with the stream at :attr:`position`, at the first packet it leaves to the
        per-packet path (a layout the kernel does not read, a packet larger than a block or cut by the file's end,
        more events than a chunk holds) or at the end."""
        from evtools._kernels.aedat4 import COPIED, FULL, OTHER, copy_event_packets

        stream = self.source.stream
        limit = self.data_position if self.data_position >= 0 else self._file_bytes
        if getattr(self, "_scan_block", None) is None:
            self._scan_block = np.empty(SCAN_BLOCK_BYTES, np.uint8)
        block = self._scan_block
        while self.position < limit:
            got = stream.readinto(memoryview(block)[:min(len(block), limit - self.position)])
            start = status = 0
            while True:
                end, self._filled, status, last = copy_event_packets(block, start, got, self.stream_id,
                                                                     self._chunk.view(np.uint64), self._filled,
                                                                     MAX_PACKET_BYTES)
                self.position += end - start
                start = end
                if last >= 0:
                    self._last_count = last
                if status == FULL and self._filled:
                    yield self._chunk[:self._filled]
                    self._chunk, self._filled = self._recycled.take(self.options.chunk_events), 0
                    continue
                if status == OTHER and start + 8 <= got:  # another stream's packet, whole in the block: here too
                    stream_id, size = struct.unpack_from("<iI", block, start)
                    whole = start + 8 + size <= got
                    if whole and stream_id == self.frame_stream_id and self.frame_stream_id is not None:
                        self._take_frame(block[start + 8:start + 8 + size].tobytes(), self.position)
                    elif whole and self.carry_side and stream_id in self.side_ids:
                        self._take_side(stream_id, block[start + 8:start + 8 + size].tobytes(), self.position)
                    elif whole and stream_id in self.side_ids:
                        self._skipped_packets += 1
                    else:
                        break
                    self.position += 8 + size
                    start += 8 + size
                    continue
                break
            stream.seek(self.position)  # (the block read past it)
            if status != COPIED or start == 0:  # a packet for the per-packet path (or one larger than a block)
                return

    def _decompressed(self, body: bytes, offset: int) -> bytes:
        """A packet's body as written (decompressed where the file is compressed), or an error naming its offset."""
        if self.decompress is None:
            return body
        try:
            return self.decompress(body)
        except Exception as error:  # lz4 and zstandard raise their own types
            raise FormatError(f"{self.name}: cannot decompress packet at byte {offset} ({error})") from None

    def _take_frame(self, body: bytes, offset: int) -> None:
        """A frame packet: decoded (at once: frames are few) and queued for :meth:`EventStream.take_frames`."""
        frame = _parse_frame(self._decompressed(body, offset), self.name, offset)
        last_us = self._last_frame_us if self.frames_read else None
        problem = frame_problem(frame, self.info.metadata["frame_size"], last_us)
        if problem:
            raise FormatError(f"{self.name}: frame packet at byte {offset} {problem}")
        self._last_frame_us = frame.order_us
        self.frames.append(frame)
        self.frames_read += 1

    def _take_side(self, stream_id: int, body: bytes, offset: int) -> None:
        """A side stream's packet (IMU samples, triggers...), decompressed and queued whole for
        :meth:`EventStream.take_side_packets`, at the time of its first element (else of the packet before it)."""
        body = self._decompressed(body, offset)
        first_us = _first_element_us(body)
        if first_us is not None:
            self._side_us = first_us
        self.side_packets.append(SidePacket(self.side_ids[stream_id], body, self._side_us))

    def _cut(self) -> None:
        """A stream whose writer promised an end mark ended without it: an error on a pipe or socket (the writer
        was stopped), a warning on a file, or on a pipe when this command was stopped too (a pipeline's Ctrl-C: its
        outputs are then marked cut)."""
        message = (f"{self.name}: the stream ends without the end mark its writer (evtools) puts after the last "
                   "packet: it was cut (the writer killed or the copy broken off), events may be missing")
        if self.source.live and interrupt.received() is None:  # (stopped too: the outputs are marked cut instead)
            raise FormatError(message)
        if self.source.network and interrupt.received() is not None:  # (its end came from this command's stop: a
            return  # network input's server is not stopped with it, and its stop is its end, as a camera's)
        logging.getLogger("evtools").warning(message)
        self.cut_file = True  # (a stage's output then ends without the end mark too: see EventStream.was_cut)

    def _packet_waits(self) -> bool:
        """True when the next packet of a live input has arrived whole (reading it would not wait)."""
        if self.source.arrived(self.position) < 8:
            return False
        head = self.source.stream.peek(8)  # from the buffer, or one read of bytes that are there
        if len(head) < 8:
            return False
        return self.source.arrived(self.position) >= 8 + struct.unpack_from("<iI", head)[1]

    def _decode_group(self, group: list[tuple[bytes, int]]) -> tuple[np.ndarray, int, float]:
        """Decode consecutive compressed event packets (in a decoding thread) into one array, padding zeroed.

        DV records packets of a few thousand events (1,900 on average in the DVXplorer sample: 10 ms each; 620 for
        a DAVIS346), so packets are handed to the pool in groups of about a chunk: one hand-over per group, not per
        packet (docs/performance.md). Each packet is decompressed and put at the end of the thread's staging
        buffer, reused group after group, so one packet's bytes object is alive at a time (holding a whole
        group's and freeing them together made the thread's malloc arena give its pages back and fault them in
        again for every group: 190,000 page faults reading 50M events); then one kernel copies the events of every
        packet into the group's array (:func:`evtools._kernels.aedat4.copy_decoded_packets`: parsing and copying
        each packet in Python held the GIL ~11 us a packet), and a packet it does not read goes through
        :func:`_packet_events` (its errors, empty packets). Returns (events, events in the group's last packet,
        the group's own ratio of decoded to compressed bytes, for the size of the next groups)."""
        from evtools._kernels.aedat4 import copy_decoded_packets

        staging = getattr(self._staging, "buffer", None)
        bounds = np.empty(len(group) + 1, np.int64)  # packet k: staging[bounds[k]:bounds[k + 1]]
        at = 0
        for k, (body, offset) in enumerate(group):
            packet = self._decompressed(body, offset)
            end = at + len(packet)
            if staging is None or end > len(staging):
                grown = np.empty(max(2 * (0 if staging is None else len(staging)), end, 1 << 20), np.uint8)
                if at:
                    grown[:at] = staging[:at]
                staging = self._staging.buffer = grown
            memoryview(staging)[at:end] = packet
            bounds[k], at = at, end
            del packet  # before the next is decompressed (see above)
        bounds[-1] = at
        events = self._recycled.take(max(1, at // 16))  # (a packet's events take 16 of its bytes each)
        words = events.view(np.uint64)
        done, filled, last = copy_decoded_packets(staging, bounds, 0, words, 0)
        while done < len(group):
            packet = _packet_events(staging[bounds[done]:bounds[done + 1]].tobytes(), self.name, group[done][1])
            _copy_records(events[filled:filled + len(packet)], packet)
            filled, last = filled + len(packet), len(packet)
            done, filled, copied_last = copy_decoded_packets(staging, bounds, done + 1, words, filled)
            last = copied_last if copied_last >= 0 else last
        compressed = sum(len(body) for body, _ in group)
        return events[:filled], last, min(max(at / max(1, compressed), 1.0), MAX_RATIO)

    def _place_group(self, events: np.ndarray, last_count: int, ratio: float) -> Iterator[np.ndarray]:
        """Pass on a decoded group: as chunks of its own when no chunk is being filled (no copy), else appended to
        the chunk. Returns ``ratio`` (for the size of the next groups)."""
        if self._filled and self._filled + len(events) > len(self._chunk):
            yield self._chunk[:self._filled]
            self._chunk, self._filled = self._recycled.take(self.options.chunk_events), 0
        if self._filled == 0 and len(events) >= self.options.chunk_events // 2:
            for begin in range(0, len(events), self.options.chunk_events):
                yield events[begin: begin + self.options.chunk_events]
        elif len(events):
            _copy_records(self._chunk[self._filled: self._filled + len(events)], events)
            self._filled += len(events)
        self._last_count = last_count
        return ratio

    def _make_room(self, count: int) -> Iterator[np.ndarray]:
        """Yield the chunk so far (and start a new one) when ``count`` more events do not fit in it."""
        if self._filled + count > len(self._chunk):
            if self._filled:
                yield self._chunk[:self._filled]
            self._chunk, self._filled = self._recycled.take(max(self.options.chunk_events, count)), 0

    def _place(self, events: np.ndarray) -> Iterator[np.ndarray]:
        """Append one packet's events to the chunk (yielding the chunk first if they do not fit)."""
        yield from self._make_room(len(events))
        self._last_count = len(events)
        _copy_records(self._chunk[self._filled: self._filled + len(events)], events)
        self._filled += len(events)

    def _read_packet(self, n: int, size: int, offset: int) -> bytes:
        # a file's packet was checked to end within it (its size field): read as it is, no length check a packet
        data = self.source.stream.read(n) if self._file_bytes < float("inf") else \
            formats_io.read_at_most(self.source.stream, n, self.source.seekable)
        if len(data) != n:
            raise FormatError(f"{self.name}: truncated AEDAT 4.0 packet at byte {offset} (its size is {size} bytes)")
        return data

    def _skip(self, n: int, offset: int) -> None:
        stream = self.source.stream
        if self.source.seekable:
            end = stream.seek(n, 1)
            if end > os.fstat(stream.fileno()).st_size:
                raise FormatError(f"{self.name}: truncated AEDAT 4.0 packet at byte {offset}")
        else:
            while n:
                part = stream.read(min(n, 1 << 20))
                if not part:
                    raise FormatError(f"{self.name}: truncated AEDAT 4.0 packet at byte {offset}")
                n -= len(part)


def _ioheader(compression: int, description: str) -> bytes:
    """An ``IOHE`` flatbuffer: root offset, identifier, vtable, table (int32, int64, string offset), string."""
    text = description.encode("utf-8")
    vtable = struct.pack("<5H", 10, 20, 4, 8, 16)
    table = struct.pack("<iiqI", 24 - 8, compression, -1, 4)
    string = struct.pack("<I", len(text)) + text + b"\0"
    buffer = struct.pack("<I", 24) + b"IOHE" + vtable + b"\0" * 6 + table + string
    return buffer + b"\0" * (-len(buffer) % 4)


_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")
"""Characters XML 1.0 forbids in a document even when escaped (C0 controls but tab and line ends, surrogates,
U+FFFE and U+FFFF): a source name holding one is written with U+FFFD in its place, else no reader (evtools, DV,
aedat, faery) would parse the stream description."""


def _description(info: StreamInfo, compression: int) -> str:
    """The streams' XML: events (id 0), when ``info.metadata["frame_size"]`` says the stream has APS frames, frames
    (id :data:`FRAME_STREAM_ID`), and the side streams ``info.metadata["side_streams"]`` lists (from
    :data:`SIDE_STREAM_FIRST_ID` on)."""
    source = _xml_text(info.metadata.get("source") or "evtools")
    frame_size = info.metadata.get("frame_size")
    frames = "" if not frame_size else (
        f'        <node name="{FRAME_STREAM_ID}" path="/mainloop/Recorder/outInfo/{FRAME_STREAM_ID}/">\n'
        f'            <attr key="compression" type="string">{COMPRESSION_XML[compression]}</attr>\n'
        '            <attr key="originalModuleName" type="string">evtools</attr>\n'
        '            <attr key="originalOutputName" type="string">frames</attr>\n'
        '            <attr key="typeDescription" type="string">Standard frame (8-bit image).</attr>\n'
        '            <attr key="typeIdentifier" type="string">FRME</attr>\n'
        f'            <node name="info" path="/mainloop/Recorder/outInfo/{FRAME_STREAM_ID}/info/">\n'
        f'                <attr key="sizeX" type="int">{int(frame_size[0])}</attr>\n'
        f'                <attr key="sizeY" type="int">{int(frame_size[1])}</attr>\n'
        f'                <attr key="source" type="string">{source}</attr>\n'
        '            </node>\n'
        '        </node>\n'
    )
    sides = "".join(_side_node(SIDE_STREAM_FIRST_ID + index, side, compression)
                    for index, side in enumerate(info.metadata.get("side_streams") or ()))
    return (
        '<dv version="2.0">\n'
        '    <node name="outInfo" path="/mainloop/Recorder/outInfo/">\n'
        '        <node name="0" path="/mainloop/Recorder/outInfo/0/">\n'
        f'            <attr key="compression" type="string">{COMPRESSION_XML[compression]}</attr>\n'
        '            <attr key="originalModuleName" type="string">evtools</attr>\n'
        '            <attr key="originalOutputName" type="string">events</attr>\n'
        '            <attr key="typeDescription" type="string">Array of events (polarity ON/OFF).</attr>\n'
        '            <attr key="typeIdentifier" type="string">EVTS</attr>\n'
        '            <node name="info" path="/mainloop/Recorder/outInfo/0/info/">\n'
        f'                <attr key="sizeX" type="int">{info.width}</attr>\n'
        f'                <attr key="sizeY" type="int">{info.height}</attr>\n'
        f'                <attr key="source" type="string">{source}</attr>\n'
        f'                <attr key="{END_MARK_KEY}" type="string">true</attr>\n'
        '            </node>\n'
        '        </node>\n'
        f'{frames}{sides}'
        '    </node>\n'
        '</dv>\n'
    )


def _xml_text(text) -> str:
    """``text`` safe inside an XML attribute or element (characters XML forbids replaced, markup escaped: not by
    html.escape, whose import costs 3 ms)."""
    text = _NOT_XML.sub("\ufffd", str(text))
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")


def _side_node(stream_id: int, side: dict, compression: int) -> str:
    """A side stream's node (``info.metadata["side_streams"]``: its attributes as the input stated them) under the
    id it has in this file, with this file's compression."""
    path = f"/mainloop/Recorder/outInfo/{stream_id}/"

    def attrs(items, indent: str) -> str:
        return "".join(f'{indent}<attr key="{_xml_text(key)}" type="{_xml_text(kind)}">{_xml_text(text)}</attr>\n'
                       for key, kind, text in items)

    own = [item for item in side["attributes"] if item[0] != "compression"]
    return (f'        <node name="{stream_id}" path="{path}">\n'
            f'            <attr key="compression" type="string">{COMPRESSION_XML[compression]}</attr>\n'
            f'{attrs(own, "            ")}'
            f'            <node name="info" path="{path}info/">\n'
            f'{attrs(side["info"], "                ")}'
            '            </node>\n'
            '        </node>\n')


FRAME_STREAM_ID = 1
SIDE_STREAM_FIRST_ID = 2
"""The id of the first side stream an evtools file carries (IMU samples, triggers: :class:`SidePacket`), the others
following in the input's order."""
"""The stream id of the frames the writer declares (DV's recordings number them 1 too)."""


def _frame_body(frame: Frame) -> bytes:
    """A size-prefixed ``FRME`` flatbuffer (see :func:`_parse_frame`), aligned as DV's: root table at byte 44 (its
    int64 times 8-aligned from the body's start), the pixels' vector after the table."""
    image = np.ascontiguousarray(frame.image)
    pixel_format = FORMAT_GRAY16 if image.dtype == np.uint16 else FORMAT_GRAY
    pixels = image.astype("<u2" if pixel_format == FORMAT_GRAY16 else np.uint8, copy=False).tobytes()
    table, vector = 44, 104
    vtable = struct.pack("<13H", 26, 60, 4, 12, 20, 28, 36, 56, 48, 50, 52, 54, 44)
    fields = struct.pack("<i5qI4hb3x", table - 12, frame.t_us, frame.begin_us, frame.end_us, frame.exposure_begin_us,
                         frame.exposure_end_us, vector - (table + 44), image.shape[1], image.shape[0], frame.offset_x,
                         frame.offset_y, pixel_format)
    body = struct.pack("<I4s", table - 4, b"FRME") + vtable + bytes(table - 12 - len(vtable)) + fields
    body += struct.pack("<I", len(pixels)) + pixels
    body += bytes(-len(body) % 4)
    return struct.pack("<I", len(body)) + body


def _packet_prefix(count: int) -> bytes:
    """Size prefix, root offset, identifier, vtable and table of an ``EVTS`` buffer whose vector data starts at 32."""
    return struct.pack("<II4s3HxxiII", 28 + 16 * count, 16, b"EVTS", 6, 8, 4, 8, 4, count)


CHECKSUMS = True
"""Compressed AEDAT 4.0 packets written with their codec's checksum, 4 bytes a packet (its cost and what it
catches: the README, after the ``make fuzz`` table)."""


class Aedat4Writer:
    """Writes an AEDAT 4.0 event stream (compression none, lz4 or zstd) that DV, dv-processing and ``aedat`` read.

    Compressed packets carry their codec's own checksum of the content (LZ4 frame: xxHash32, flag 0x04; zstd:
    XXH64, 4 bytes), which every LZ4 and zstd decoder checks, DV's and dv-processing's included: damage to a
    packet's bytes is an error at the packet instead of other events (:data:`CHECKSUMS`)."""

    def __init__(self, stream: BinaryIO, info: StreamInfo, options: WriteOptions) -> None:
        name = (options.compression or "none").lower()
        if name not in COMPRESSION_CODES:
            raise FormatError(f"unknown AEDAT 4.0 compression {name!r}; choose one of {', '.join(COMPRESSION_CODES)}")
        self.stream, self.code = stream, COMPRESSION_CODES[name]
        self.compress = None
        if self.code in (1, 2):
            import lz4.frame

            level = lz4.frame.COMPRESSIONLEVEL_MINHC if self.code == 2 else 0
            self.compress = lambda data: lz4.frame.compress(data, compression_level=level, content_checksum=CHECKSUMS)
        elif self.code in (3, 4):
            import zstandard

            level, local = (10 if self.code == 4 else 3), threading.local()

            def compress(data: bytes) -> bytes:  # a compressor per thread: one is not safe to share
                if not hasattr(local, "compressor"):
                    local.compressor = zstandard.ZstdCompressor(level=level, write_checksum=CHECKSUMS)
                return local.compressor.compress(data)

            self.compress = compress
        network = getattr(stream, "network", False)
        if network and (info.metadata.get("frame_size") or info.metadata.get("side_streams")):
            # DV's NetworkWriter serves one stream, and dv's NetworkReader takes one from the header: with IMU or
            # triggers declared beside the events it took theirs and failed on the events (a QA sweep)
            left = [what for key, what in (("frame_size", "APS frames"), ("side_streams", "IMU and trigger streams"))
                    if info.metadata.get(key)]
            logging.getLogger("evtools").warning(
                f"a network output serves the events alone, as DV's does (dv's NetworkReader reads one stream): the "
                f"input's {' and '.join(left)} are left out; write a file to keep them")
            info = StreamInfo(info.width, info.height, info.format, {
                key: value for key, value in info.metadata.items() if key not in ("frame_size", "side_streams")})
        self.network = network
        header = _ioheader(self.code, _description(info, self.code))
        first_line = b"" if network else MAGIC  # a network stream has none
        stream.write(first_line + struct.pack("<I", len(header)) + header)
        self.pending: list[np.ndarray] = []
        self.held = 0
        self.encoding: deque = deque()  # packets being compressed ((stream id, future of the body)), in file order
        self.pool: ThreadPoolExecutor | None = None
        self.frames = bool(info.metadata.get("frame_size"))  # the header declares a frame stream
        self.frames_left_out = 0
        self.side_streams = len(info.metadata.get("side_streams") or ())  # the side streams the header declares

    def write(self, chunk: np.ndarray) -> None:
        while len(chunk):
            take = min(PACKET_EVENTS - self.held, len(chunk))
            self.pending.append(chunk[:take])
            self.held += take
            chunk = chunk[take:]
            if self.held == PACKET_EVENTS:
                self._flush()

    def _flush(self) -> None:
        """The events held as one packet: its body (prefix, then the events, padding zeroed) built in one array, the
        events copied into it once, then written or handed to the compressing pool (the codecs take the array as
        it is: joining the pieces, copying to mask, ``tobytes`` and prepending the prefix were four copies)."""
        if not self.held:
            return
        prefix = np.frombuffer(_packet_prefix(self.held), np.uint64)
        body = np.empty(len(prefix) + 2 * self.held, np.uint64)
        body[:len(prefix)] = prefix
        events, at = body[len(prefix):].view(EVENT_DTYPE), 0
        for piece in self.pending:
            _copy_records(events[at:at + len(piece)], np.ascontiguousarray(piece, EVENT_DTYPE))
            at += len(piece)
        self._packet(0, body)
        self.pending, self.held = [], 0

    def _packet(self, stream_id: int, body) -> None:
        """Write a packet's body, or hand it to the compressing pool (packets leave in the order given)."""
        if self.compress is None:
            self._write_body(body, stream_id)
            return
        if self.pool is None:
            self.pool = ThreadPoolExecutor(ENCODE_THREADS, thread_name_prefix="evtools-encode")
        self.encoding.append((stream_id, self.pool.submit(self.compress, body)))
        while len(self.encoding) > ENCODE_AHEAD:
            stream_id, future = self.encoding.popleft()
            self._write_body(future.result(), stream_id)

    def write_frame(self, frame: Frame) -> None:
        """An APS frame, as one ``FRME`` packet (after the events written before it; the events held for the
        current packet stay held, so that packets hold a fixed number of events whatever the frames)."""
        if not self.frames:  # the header went out before the input's frames were known (an AEDAT 3.1 pipe), or a
            self.frames_left_out += not self.network  # network output, which serves the events alone (said)
            return
        self._packet(FRAME_STREAM_ID, _frame_body(frame))

    def write_side(self, packet: SidePacket) -> None:
        """A side stream's packet (:class:`SidePacket`), as it came, after the events written before it."""
        self._packet(SIDE_STREAM_FIRST_ID + packet.stream, packet.body)

    def _write_body(self, body, stream_id: int = 0) -> None:
        self.stream.write(struct.pack("<iI", stream_id, memoryview(body).nbytes))
        self.stream.write(body)

    def _drain(self) -> None:
        """Write every packet still being compressed, in order."""
        while self.encoding:
            stream_id, future = self.encoding.popleft()
            self._write_body(future.result(), stream_id)

    def flush(self) -> None:
        """Write the events held as a (short) packet and flush the stream: a live output's reader gets them now."""
        self._flush()
        self._drain()
        self.stream.flush()

    def abort(self) -> None:
        """The input stopped with an error: write what is held but no end mark, so that a reader of this output
        (a pipe's next stage) sees a cut stream, not a whole one."""
        try:
            self._flush()
            self._drain()
            self.stream.flush()
        finally:
            if self.pool is not None:
                self.pool.shutdown()

    def mark_cut(self, note: str) -> None:
        """The input was cut: the output ends without the end mark (:meth:`abort`), which says so to its reader."""
        self.abort()

    def close(self) -> None:
        """Write what is held, then the end mark (an empty event packet, see :data:`END_MARK_KEY`)."""
        if self.frames_left_out:
            logging.getLogger("evtools").warning(
                f"{self.frames_left_out:,} APS frames left out: the input's frames became known after the output's "
                "header was written (a pipe of a format that does not state them upfront); write to a file first")
        self._flush()
        self._drain()
        if self.pool is not None:
            self.pool.shutdown()
        prefix = _packet_prefix(0)
        self._write_body(prefix if self.compress is None else self.compress(prefix))
        self.stream.flush()
