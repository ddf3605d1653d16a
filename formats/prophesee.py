"""Prophesee RAW files (Metavision): ``%`` header lines, then an EVT 2.0, EVT 2.1 or EVT 3.0 word stream.

Layout (FORMATS.md, after Prophesee's format pages): the header is ASCII lines ``% key value`` (``% evt 3.0``,
``% format EVT3;width=1280;height=720``, ``% geometry 1280x720``, ``% plugin_name ...``), optionally closed by
``% end``. The body is little-endian words:

- EVT 2.0, 32-bit: type ``w >> 28`` (0 CD OFF, 1 CD ON, 8 EVT_TIME_HIGH, 0xA trigger); a CD word holds
  ``t_low = (w >> 22) & 0x3F``, ``x = (w >> 11) & 0x7FF``, ``y = w & 0x7FF``; EVT_TIME_HIGH holds ``t >> 6``
  in bits 0-27.
- EVT 2.1, 64-bit (GenX320's default, IMX636's alternative): EVT 2.0's upper word with a 32-bit mask below it, an
  event at column ``x + k`` for each bit k; IMX636 sensors store the two 32-bit halves the other way round, said
  by ``endianness=legacy`` in ``% format`` (as OpenEB's decoder reads them).
- EVT 3.0, 16-bit, vectorised and stateful.

All are decoded by numba kernels (:mod:`evtools._kernels.prophesee`) straight into the chunks' records, chunks
whose memory is reused once the consumer lets them go (:class:`evtools.formats.io.Recycled`); EVT 2.0 is written by
one too (docs/performance.md).

Decoding is spec-literal: events before the first time-high word are dropped, and a time-high field that falls
by more than half its range is a wrap of the time base (2^34 us for EVT 2.0 and 2.1, 2^24 us for EVT 3.0). A
``% t0 US`` header line (faery writes one, with the times made relative to it, ``% T0`` in DAT files) is added to
every time: the absolute times come back, as faery reads them (Metavision ignores the line).

References
----------
Prophesee, "EVT 2.0 Format", "EVT 2.1 Format" and "EVT 3.0 Format",
https://docs.prophesee.ai/stable/data/encoding_formats/
"""

from __future__ import annotations

import logging
import os
import re
from typing import BinaryIO, Iterator

import numpy as np

from evtools._kernels.prophesee import (DROPPED_NO_TIME, DROPPED_NO_Y, EVT2_DROPPED, EVT2_OTHER_WORDS, EVT2_TRIGGERS,
                                        EVT21_EVENTS_PER_WORD, MAX_EVENTS_PER_WORD, OTHER_WORDS, TRIGGERS, decode_evt2,
                                        decode_evt3, decode_evt21, encode_evt2, new_evt2_state, new_evt3_state)
from evtools.events import MAX_TIME_US, StreamInfo, record_words, second_words
from evtools.formats.errors import FormatError
from evtools.formats.io import Recycled, Source, ends_cut, resolve_sensor_size, size_scan
from evtools.formats.registry import ReadOptions, WriteOptions

GENERATION_SIZES = (("genx320", (320, 320)), ("imx636", (1280, 720)), ("gen4", (1280, 720)), ("gen3", (640, 480)))
"""Sensor size by camera generation, matched in ``plugin_name`` (``hal_plugin_gen41_evk3``) and the like."""
SENSOR_GENERATION_SIZES = {"3": (640, 480), "3.0": (640, 480), "3.1": (640, 480), "4": (1280, 720),
                           "4.0": (1280, 720), "4.1": (1280, 720), "4.2": (1280, 720), "320": (320, 320)}
"""Sensor size by the ``% sensor_generation`` value."""
WORD_BYTES = {"2.0": 4, "2.1": 8, "3.0": 2}
"""Bytes of a word, by the EVT versions read."""
_GEOMETRY = re.compile(r"^\s*(\d+)\s*x\s*(\d+)\s*$")


def parse_header(lines: list[str]) -> dict[str, str]:
    """``% key value`` lines as a dict (keys lower-cased; the first occurrence wins)."""
    header: dict[str, str] = {}
    for line in lines:
        body = line[1:].strip()
        if not body:
            continue
        key, _, value = body.partition(" ")
        header.setdefault(key.lower(), value.strip())
    return header


def header_t0(header: dict[str, str], name: str) -> int:
    """The ``% t0`` offset (us) of a header parsed by :func:`parse_header`; 0 without one."""
    value = header.get("t0", "0").strip()
    try:
        t0_us = int(value)
    except ValueError:
        raise FormatError(f"{name}: the header's t0 ({value!r}) is not a whole number of microseconds") from None
    if abs(t0_us) > MAX_TIME_US:
        raise FormatError(f"{name}: the header's t0 ({t0_us} us) lies outside the +-2^62 us that evtools supports")
    return t0_us


def evt_version(header: dict[str, str]) -> str | None:
    """``"2.0"``, ``"3.0"`` (or another version string) from ``% evt`` or ``% format``; None if absent."""
    if "evt" in header:
        return header["evt"].strip()
    if "format" in header:
        name = header["format"].split(";")[0].strip().upper()
        return {"EVT2": "2.0", "EVT3": "3.0", "EVT21": "2.1"}.get(name, name)
    return None


def format_fields(header: dict[str, str]) -> dict[str, str]:
    """The ``key=value`` fields of ``% format EVT21;width=W;height=H;endianness=legacy`` (keys lower-cased)."""
    return {key.strip().lower(): value.strip() for key, _, value in
            (part.partition("=") for part in header.get("format", "").split(";") if "=" in part)}


def header_size(header: dict[str, str]) -> tuple[int, int] | None:
    """(width, height) from ``% format ...;width=W;height=H``, ``% geometry WxH`` or the camera generation."""
    fields = format_fields(header)
    if "width" in fields and "height" in fields:
        return int(fields["width"]), int(fields["height"])
    match = _GEOMETRY.match(header.get("geometry", ""))
    if match:
        return int(match.group(1)), int(match.group(2))
    if "width" in header and "height" in header and header["width"].isdigit() and header["height"].isdigit():
        return int(header["width"]), int(header["height"])
    generation = header.get("sensor_generation", "").strip()
    if generation in SENSOR_GENERATION_SIZES:
        return SENSOR_GENERATION_SIZES[generation]
    where = " ".join(header.get(key, "") for key in ("plugin_name", "camera_integrator_name", "system_id")).lower()
    for name, size in GENERATION_SIZES:
        if name in where:
            return size
    return None


class PropheseeRawReader:
    """Read the CD events of a Prophesee EVT 2.0, 2.1 or 3.0 RAW file chunk by chunk.

    Parameters
    ----------
    source : evtools.formats.io.Source
        The input, read once from its first byte (pipes work).
    options : evtools.formats.registry.ReadOptions
        ``sensor_size`` is used when the header does not tell it.

    Notes
    -----
    ``info.metadata`` holds ``evt`` (the version), ``endianness`` (``"legacy"``: an IMX636's EVT 2.1, the words'
    halves swapped), ``header`` (the ``%`` lines as a dict), ``t0_us`` (the header's
    ``% t0``, added to every time; 0 without one) and, complete once the stream is read, ``dropped_events``
    (before the first time base), ``triggers`` and ``other_words``.
    """

    def __init__(self, source: Source, options: ReadOptions) -> None:
        self.source = source
        self.cut_file = False  # the file ends inside a word (read up to it: formats.io.ends_cut)
        self.name = source.name
        self.chunk_events = max(1, int(options.chunk_events))
        lines, self.header_bytes, self._first = self._read_header()
        if not lines:
            raise FormatError(f"{self.name}: not a Prophesee RAW file (no '%' header lines)")
        header = parse_header(lines)
        version = evt_version(header)
        if version not in WORD_BYTES:
            said = f"EVT {version}" if version else "an unstated EVT version (no '% evt' or '% format' line)"
            raise FormatError(f"{self.name}: Prophesee RAW with {said}; evtools reads EVT 2.0, 2.1 and 3.0")
        self.version = version
        self.word_bytes = WORD_BYTES[version]
        self.legacy = version == "2.1" and format_fields(header).get("endianness", "").lower() == "legacy"
        try:
            stated = header_size(header)
        except ValueError:
            raise FormatError(f"{self.name}: the header's sensor size is not a number "
                              f"(% format {header.get('format', '')})") from None
        if stated and max(stated) > 2048:
            logging.getLogger("evtools").warning(
                f"{self.name}: the header's sensor size {stated[0]}x{stated[1]} exceeds the 2048 x 2048 that EVT "
                f"{version} addresses (11-bit x and y): columns and rows beyond 2047 cannot be told apart in this "
                "file (its writer wrapped them?)")
        self.t0_us = header_t0(header, self.name)
        width, height = resolve_sensor_size(source, stated, options.sensor_size, scan=self._scan)
        self.info = StreamInfo(
            width, height, "prophesee",
            metadata={"evt": version, "header": header, "t0_us": self.t0_us, "dropped_events": 0, "triggers": 0,
                      "other_words": 0, **({"endianness": "legacy"} if self.legacy else {})},
        )

    def _read_header(self) -> tuple[list[str], int, bytes]:
        stream = self.source.stream
        lines: list[str] = []
        consumed = 0
        while True:
            first = stream.read(1)
            if first != b"%":
                return lines, consumed, first
            line = first + stream.readline()
            if not line.endswith(b"\n"):  # the file ends inside a header line: cut, not an empty recording
                raise FormatError(f"{self.name}: truncated Prophesee RAW header (the file ends inside a header line, "
                                  f"at byte {consumed + len(line)})")
            consumed += len(line)
            text = line.decode("latin-1").rstrip("\r\n")
            lines.append(text)
            if text.strip().lower() == "% end":
                return lines, consumed, b""

    def _words(self) -> Iterator[np.ndarray]:
        """The body as blocks of little-endian words, from where the header ended."""
        stream = self.source.stream
        pending = self._first
        words_read = 0
        block_bytes = self.chunk_events * self.word_bytes
        dtype = {2: "<u2", 4: "<u4", 8: "<i8"}[self.word_bytes]
        while True:
            data = stream.read(block_bytes - len(pending))
            buffer = pending + data if pending else data
            whole = len(buffer) // self.word_bytes * self.word_bytes
            if whole:
                yield np.frombuffer(buffer, dtype=dtype, count=whole // self.word_bytes)
                words_read += whole // self.word_bytes
            pending = buffer[whole:]
            if not data:
                break
        if pending:
            offset = self.header_bytes + words_read * self.word_bytes
            ends_cut(self, f"truncated EVT {self.version} word at byte offset {offset:,} ({len(pending)} of "
                           f"{self.word_bytes} bytes)")

    def _events(self, counts: dict[str, int]) -> Iterator[np.ndarray]:
        if self.version == "3.0":
            return self._events_evt3(counts)
        if self.version == "2.1":
            return self._events_evt21(counts)
        return self._events_evt2(counts)

    def _events_evt3(self, counts: dict[str, int]) -> Iterator[np.ndarray]:
        state, recycled = new_evt3_state(), Recycled()
        capacity = self.chunk_events + MAX_EVENTS_PER_WORD
        for words in self._words():
            start = 0
            while start < len(words):
                chunk = recycled.take(capacity)
                consumed, n = decode_evt3(words[start:], state, self.t0_us, record_words(chunk))
                start += consumed
                if n:
                    yield chunk[:n]
            counts["dropped_events"] = int(state[DROPPED_NO_TIME] + state[DROPPED_NO_Y])
            counts["triggers"] = int(state[TRIGGERS])
            counts["other_words"] = int(state[OTHER_WORDS])

    def _events_evt21(self, counts: dict[str, int]) -> Iterator[np.ndarray]:
        state, recycled = new_evt2_state(), Recycled()
        capacity = self.chunk_events + EVT21_EVENTS_PER_WORD
        for words in self._words():
            start = 0
            while start < len(words):
                chunk = recycled.take(capacity)
                consumed, n = decode_evt21(words[start:], state, self.t0_us, self.legacy, record_words(chunk))
                start += consumed
                if n:
                    yield chunk[:n]
            counts["dropped_events"] = int(state[EVT2_DROPPED])
            counts["triggers"] = int(state[EVT2_TRIGGERS])
            counts["other_words"] = int(state[EVT2_OTHER_WORDS])

    def _events_evt2(self, counts: dict[str, int]) -> Iterator[np.ndarray]:
        state, recycled = new_evt2_state(), Recycled()
        for words in self._words():
            chunk = recycled.take(len(words))
            n = decode_evt2(words, state, self.t0_us, record_words(chunk))
            counts["dropped_events"] = int(state[EVT2_DROPPED])
            counts["triggers"] = int(state[EVT2_TRIGGERS])
            counts["other_words"] = int(state[EVT2_OTHER_WORDS])
            yield chunk[:n]

    def expected_events(self) -> int | None:
        """About how many events the file holds at most, for a whole-file read's result (see
        :func:`evtools.events.concatenate`: pages of an overestimate never reached cost nothing, a result grown
        costs a copy); None for a pipe. One a word, two for EVT 2.1, whose 8-byte words are vectors of up to 32
        (a Gen4 recording's 50M events in 47.5M words grew the result once: 1,490 MiB against 802 for EVT 3.0)."""
        if not (self.source.seekable and self.source.path):
            return None
        words = max(0, os.path.getsize(self.source.path) - self.header_bytes) // self.word_bytes
        return words * (2 if self.version == "2.1" else 1) + 1

    def _scan(self) -> tuple[int, int]:
        """(max x + 1, max y + 1) over the whole file; leaves the stream where it was."""
        stream = self.source.stream
        position = stream.tell()
        width = height = 0
        with size_scan(self):
            for events in self._events({"dropped_events": 0, "triggers": 0, "other_words": 0}):
                if len(events):
                    width = max(width, int(events["x"].max()) + 1)
                    height = max(height, int(events["y"].max()) + 1)
        stream.seek(position)
        return width, height

    def __iter__(self) -> Iterator[np.ndarray]:
        for events in self._events(self.info.metadata):
            if len(events):
                yield events


class Evt2Writer:
    """Write events as a Prophesee RAW file in EVT 2.0 (what Metavision's tools read): the header ``% evt 2.0``,
    ``% format EVT2;height=H;width=W``, ``% geometry WxH``, ``% end``, then for each event a CD word, preceded by
    an EVT_TIME_HIGH word whenever ``t >> 6`` changes. Times are stored modulo 2^34 us (4.8 hours) as the format
    does; a stream that starts later (DV's times are Unix times) gets a ``% t0`` line, the multiple of 2^34 us
    below its first time, which evtools and faery add back (exact), and Metavision, which ignores it, does not (a
    warning says so). Readers unwrap a fall by more than half the range, so consecutive events must lie less than
    about 2^33 us (2.4 hours) apart. Times must not be negative and the sensor must fit the 11-bit coordinates
    (2048 x 2048). The header is written with the first events (or at the end, for a stream without any)."""

    def __init__(self, stream: BinaryIO, info: StreamInfo, options: WriteOptions) -> None:
        if info.width > 2048 or info.height > 2048:
            raise FormatError(f"EVT 2.0 cannot hold a {info.width}x{info.height} sensor (11-bit x and y: 2048 at "
                              "most); write another format")
        self.stream, self.info = stream, info
        self._headed = False  # the header is written
        self._last_high = -1  # t >> 6 of the last time-high word written

    def _write_header(self, t0_us: int) -> None:
        lines = f"% evt 2.0\n% format EVT2;height={self.info.height};width={self.info.width}\n" \
                f"% geometry {self.info.width}x{self.info.height}\n"
        if t0_us:
            lines += f"% t0 {t0_us}\n"
        self.stream.write(f"{lines}% end\n".encode("ascii"))
        self._headed = True

    def write(self, chunk: np.ndarray) -> None:
        """Append a chunk of ``EVENT_DTYPE`` events."""
        if len(chunk) == 0:
            return
        t = chunk["t"]
        if t[0] < 0:
            raise FormatError(f"EVT 2.0 cannot store negative timestamps ({int(t[0])} us)")
        if not self._headed:
            t0_us = int(t[0]) >> 34 << 34
            if t0_us:
                logging.getLogger("evtools").warning(
                    f"EVT 2.0 keeps times modulo 2^34 us (4.8 hours): the file's '% t0 {t0_us}' line holds the rest "
                    f"(evtools and faery add it back; Metavision reads the times {t0_us:,} us earlier)")
            self._write_header(t0_us)
        words = np.empty(2 * len(chunk), dtype="<u4")
        count, last_high = encode_evt2(record_words(np.ascontiguousarray(chunk)), self._last_high, words)
        if count < 0:
            raise FormatError("EVT 2.0 cannot store two consecutive events about 2^33 us (2.4 hours) or more apart")
        self.stream.write(memoryview(words[:count]).cast("B"))
        self._last_high = last_high

    def close(self) -> None:
        """Finish the file (EVT 2.0 has no trailer; the header of a stream without events); does not close the
        stream."""
        if not self._headed:
            self._write_header(0)


DAT_RECORD = np.dtype([("t", "<u4"), ("w", "<u4")])
"""A Prophesee DAT record: time (us, 32 bits, wrapping) and x (bits 0-13), y (14-27), polarity (28-31)."""


class PropheseeDatReader:
    """Read a Prophesee DAT file (Metavision's older recording format): ``%`` header lines (``% Version 2``,
    ``% Width W``, ``% Height H``, ``% Date ...``), one byte of event type and one of event size (8), then 8-byte
    records (:data:`DAT_RECORD`). The 32-bit times are unwrapped (a fall of more than half the range is a wrap) and
    offset by a ``% T0`` line's time (faery's).
    Only the version-2 layout is read; another version is refused, not guessed."""

    def __init__(self, source: Source, options: ReadOptions) -> None:
        self.source, self.name = source, source.name
        self.cut_file = False  # the file ends inside a record (read up to it: formats.io.ends_cut)
        self.chunk_events = max(1, int(options.chunk_events))
        stream = source.stream
        lines: list[str] = []
        first = stream.read(1)
        while first == b"%":
            lines.append(("%" + stream.readline().decode("latin-1")).rstrip("\r\n"))
            first = stream.read(1)
        header = parse_header(lines)
        kind_and_size = first  # the byte after the header: the event type
        if not lines:
            raise FormatError(f"{self.name}: not a Prophesee DAT file (no '%' header lines)")
        version = header.get("version", "").strip()
        if version not in ("2", "2.0"):
            raise FormatError(f"{self.name}: Prophesee DAT version {version or '(not stated)'}; evtools reads version 2")
        size = stream.read(1)
        if len(kind_and_size) != 1 or len(size) != 1:
            raise FormatError(f"{self.name}: truncated Prophesee DAT header (no event type and size bytes)")
        if size[0] != DAT_RECORD.itemsize:
            raise FormatError(f"{self.name}: Prophesee DAT events of {size[0]} bytes; evtools reads 8-byte events")
        self.event_type = kind_and_size[0]
        self.body_start = stream.tell() if source.seekable else 0  # bytes before the first record
        self.t0_us = header_t0(header, self.name)  # faery writes "% T0" with the times relative to it
        stated = None
        if header.get("width", "").isdigit() and header.get("height", "").isdigit():
            stated = int(header["width"]), int(header["height"])
        width, height = resolve_sensor_size(source, stated, options.sensor_size, scan=self._scan)
        self.info = StreamInfo(width, height, "prophesee_dat", metadata={"header": header, "t0_us": self.t0_us,
                                                                         "event_type": self.event_type})

    def _records(self) -> Iterator[np.ndarray]:
        stream = self.source.stream
        pending = b""
        while True:
            data = stream.read(self.chunk_events * DAT_RECORD.itemsize - len(pending))
            buffer = pending + data if pending else data
            whole = len(buffer) // DAT_RECORD.itemsize * DAT_RECORD.itemsize
            if whole:
                yield np.frombuffer(buffer, DAT_RECORD, whole // DAT_RECORD.itemsize)
            pending = buffer[whole:]
            if not data:
                break
        if pending:
            ends_cut(self, f"truncated Prophesee DAT event at the end ({len(pending)} of 8 bytes)")

    def _events(self) -> Iterator[np.ndarray]:
        last, loops, recycled, index = -1, 0, Recycled(), 0
        for records in self._records():
            polarity = records["w"] >> 28
            if np.any(polarity > 1):  # (the 4-bit field holds 0 or 1: another value is damage, not ON)
                k = int(np.argmax(polarity > 1))
                raise FormatError(f"{self.name}: DAT event {index + k:,} has polarity {int(polarity[k])}, not 0 (OFF) "
                                  "or 1 (ON) (a damaged file?)")
            index += len(records)
            t = records["t"].astype(np.int64)
            previous = np.concatenate(([t[0] if last < 0 else last], t[:-1]))
            wraps = loops + np.cumsum(previous - t > (1 << 31))
            last, loops = int(t[-1]), int(wraps[-1])
            chunk = recycled.take(len(records))
            out = record_words(chunk)  # each record's two words at once (the padding zero)
            out[:, 0] = t + (wraps << 32) + self.t0_us
            w = records["w"]
            out[:, 1] = second_words(w & 0x3FFF, (w >> 14) & 0x3FFF, polarity == 1)
            yield chunk

    def expected_events(self) -> int | None:
        """How many events the file holds (8 bytes each), for a whole-file read; None for a pipe."""
        if not (self.source.seekable and self.source.path):
            return None
        return max(0, os.path.getsize(self.source.path) - self.body_start) // DAT_RECORD.itemsize + 1

    def _scan(self) -> tuple[int, int]:
        stream = self.source.stream
        position = stream.tell()
        width = height = 0
        with size_scan(self):
            for events in self._events():
                width = max(width, int(events["x"].max()) + 1)
                height = max(height, int(events["y"].max()) + 1)
        stream.seek(position)
        return width, height

    def __iter__(self) -> Iterator[np.ndarray]:
        yield from self._events()
