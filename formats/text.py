"""Text event files: CSV with a header, and whitespace-separated rpg ``events.txt`` (also v2e's text output).

Reading parses blocks of whole lines at a time: a numba kernel splits the fields and reads plain decimals
(:mod:`evtools._kernels.text`, exactly as numpy's parser); a block with anything else (exponents, ``true``) is read
by numpy's parser, and only when a block is bad are its lines looked at one by one, to name the offending line.
Writing formats whole chunks with numpy.

- CSV: an optional header naming the columns in any order (``t,x,y,p``; also ``timestamp``, ``polarity``,
  ``on``, ... and faery's ``t,x@W,y@H,on``, whose ``@W``/``@H`` give the sensor size); without a header the
  columns are ``t,x,y,p``. t in integer microseconds; p is 1/0 or +1/-1 (ON if > 0). Fields are separated by
  commas, or, where the first line has none, by semicolons or whitespace (faery writes any separator): a file read
  as CSV (by its ``.csv`` extension or ``--input-format csv``) keeps microseconds whatever its separator.
- txt: ``t x y p`` with t in seconds, optional first line ``width height``, ``#`` comment lines at the top,
  an optional 5th column (v2e's label, ignored). Seconds are rounded to microseconds, exactly for any t below
  2**51 us (the year 2041 as Unix time). A file of another format whose first line has commas is read as CSV.
"""

from __future__ import annotations

import logging
import re
from typing import BinaryIO, Iterator

import numpy as np

from evtools._kernels.text import PARSED, WRONG_COUNT, parse_text
from evtools.events import EVENT_DTYPE, MAX_SENSOR_SIDE, MAX_TIME_US, StreamInfo
from evtools.formats.errors import FormatError
from evtools.formats.io import Source, ends_cut, resolve_sensor_size, size_scan
from evtools.formats.registry import ReadOptions, WriteOptions

_POWERS_OF_TEN_FLOAT = 10.0 ** np.arange(23)
"""10^0..10^22, each an exact double."""

BLOCK_BYTES = 16 << 20
"""Bytes parsed at once (at most)."""

WRITE_ROWS = 1 << 18
"""Rows formatted at once by the writers."""

COLUMN_ALIASES = {
    "t": "t", "ts": "t", "t_us": "t", "time": "t", "timestamp": "t", "timestamps": "t", "timestamp_us": "t",
    "x": "x", "xs": "x", "y": "y", "ys": "y",
    "p": "p", "ps": "p", "pol": "p", "polarity": "p", "polarities": "p", "on": "p",
}
"""Header names (lower case, without ``@size``) and the event field they mean."""

UTF8_BOM = b"\xef\xbb\xbf"
"""The byte-order mark some programs (Excel) put before UTF-8 text."""

_NUMBER = re.compile(rb"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


WHOLE_SECONDS_LINES = 10
"""rpg text whose first this many lines or more (the first block) all have whole-number times is refused as
microseconds taken for seconds (:meth:`TextReader._refuse_whole_seconds`)."""


CUT_COMMENT = b"# evtools: "
"""The start of the last line of a CSV or text file written from a cut input (then :data:`CUT_NOTE`)."""


def _microseconds(mantissas: np.ndarray, decimals: np.ndarray) -> np.ndarray:
    """Seconds written as ``mantissa / 10**decimals`` in whole microseconds, in integers: exact with up to 6
    decimals, rounded half to even beyond (``1.0000005`` -> 1,000,000 us, ``1.0000015`` -> 1,000,002 us)."""
    scale = 10 ** np.maximum(6 - decimals, 0)
    divisor = 10 ** np.maximum(decimals - 6, 0)
    magnitude = np.abs(mantissas)
    whole, rest = np.divmod(magnitude, divisor)
    up = (2 * rest > divisor) | ((2 * rest == divisor) & (whole % 2 == 1))
    return np.sign(mantissas) * (whole + up) * scale


LONE_SIGN = re.compile(rb"(?:^|[\s,;])[-+](?=[\s,;]|$)")
"""A field that is a sign alone: not a number."""


class TextReader:
    """Reads CSV or rpg text, block by block: CSV (t in microseconds) when the file was opened as CSV or its first
    data line has commas, else text (t in seconds); see the module's notes for the separators.

    Parameters
    ----------
    source : evtools.formats.io.Source
        The input (a file or stdin).
    options : evtools.formats.registry.ReadOptions
        ``sensor_size`` when the file does not give it; otherwise a seekable file is scanned once for it.
    """

    def __init__(self, source: Source, options: ReadOptions) -> None:
        self.source = source
        self.name = source.name
        self.stream = source.stream
        self.chunk_events = max(1, int(options.chunk_events))
        self.off_seen: int | None = None  # how the file writes OFF (0 or -1), once seen
        self.cut_file = False  # the file says it was written from a cut input (its comment: :meth:`_comment`)
        self.block_bytes = int(min(BLOCK_BYTES, max(1 << 16, self.chunk_events * 32)))
        if source.head.startswith(UTF8_BOM):  # (Excel's CSV): not part of the first field
            self.stream.read(len(UTF8_BOM))
        size_from_file = self._read_header()
        width, height = resolve_sensor_size(source, size_from_file, options.sensor_size, self._scan_size)
        self.info = StreamInfo(width, height, "txt" if self.seconds else "csv", {"columns": ",".join(self.names)})

    DECLARED: str | None = None
    """The format the file was opened as (``csv``, ``txt``; None: by its content alone)."""

    # -- header ---------------------------------------------------------------------------------------------
    def _read_header(self) -> tuple[int, int] | None:
        """Consume comments and header lines; leave the first data line in ``self.pending``."""
        self.line_no = 1  # of the next line to read
        self.pending = b""
        self.csv = self.semicolons = False  # fields separated by commas (semicolons: made commas block by block)
        self.seconds = self.DECLARED != "csv"
        line = self._next_content_line()
        if not line:
            self._set_columns(["t", "x", "y", "p"])  # an empty stream
            return None
        text = line.strip()
        self.semicolons = b"," not in text and self.DECLARED == "csv" and b";" in text
        self.csv = b"," in text or self.semicolons
        if self.csv or self.DECLARED == "csv":
            self.seconds = False
            if re.search(rb"[A-Za-z_@]", text):
                size = self._parse_csv_header(text.decode("utf-8", "replace"))
                self._consumed()
                return size
            self._set_columns(["t", "x", "y", "p"])
            self.pending = line
            return None
        size = None
        tokens = text.split()
        if len(tokens) == 2 and all(token.isdigit() for token in tokens):
            if not line.endswith(b"\n"):  # ("346 26" of "346 260"): a size cut short, not a size
                raise FormatError(f"{self.name}: the file ends inside its first line, the sensor size (a cut file?)")
            size = int(tokens[0]), int(tokens[1])
            self._consumed()
            line = self._next_content_line()
            tokens = line.split()
        if line and len(tokens) not in (4, 5) and line.endswith(b"\n"):  # (not: the last line, cut: see _parsed)
            raise FormatError(
                f"{self.name}: line {self.line_no}: {len(tokens)} columns, expected 't x y p' "
                "(t in seconds, optional 5th label column)"
            )
        self._set_columns(["t", "x", "y", "p", "label"][: max(4, len(tokens))])
        self.pending = line
        return size

    def _next_content_line(self) -> bytes:
        """The next line that is neither blank nor a ``#`` comment (b"" at the end)."""
        self.data_pos = self.stream.tell() if self.source.seekable else None
        while True:
            line = self.stream.readline()
            stripped = line.strip()
            if not line or (stripped and not stripped.startswith(b"#")):
                return line
            self._comment(line)
            self._consumed()

    def _comment(self, line: bytes) -> None:
        """A ``#`` comment line; the one evtools writes after the events of a cut input (:data:`CUT_COMMENT`) is
        said, and the stream counts as cut (a command's output of it is marked cut too)."""
        if line.lstrip().startswith(CUT_COMMENT) and not self.cut_file:
            self.cut_file = True
            logging.getLogger("evtools").warning(f"{self.name}: {line.strip()[len(CUT_COMMENT):].decode('utf-8', 'replace')}")

    def _consumed(self) -> None:
        self.line_no += 1
        self.data_pos = self.stream.tell() if self.source.seekable else None

    def _parse_csv_header(self, text: str) -> tuple[int, int] | None:
        names, sizes = [], {}
        for raw in text.split(";" if self.semicolons else "," if self.csv else None):
            base, _, size = raw.strip().strip('"').lower().partition("@")
            field = COLUMN_ALIASES.get(base.strip(), base.strip() or "?")
            if field in names and field in ("t", "x", "y", "p"):
                raise FormatError(f"{self.name}: line {self.line_no}: header names {field!r} twice: {text!r}")
            if size:
                if not size.strip().isdigit():
                    raise FormatError(f"{self.name}: line {self.line_no}: bad size in header column {raw!r}")
                sizes[field] = int(size)
            names.append(field)
        missing = [field for field in ("t", "x", "y", "p") if field not in names]
        if missing:
            raise FormatError(
                f"{self.name}: line {self.line_no}: header {text.strip()!r} lacks column(s) {', '.join(missing)} "
                "(expected t,x,y,p in any order)"
            )
        self._set_columns(names)
        if "x" in sizes and "y" in sizes:
            return sizes["x"], sizes["y"]
        return None

    def _set_columns(self, names: list[str]) -> None:
        self.names = names
        self.ncols = len(names)
        self.index = {field: names.index(field) for field in ("t", "x", "y", "p") if field in names}

    # -- blocks ---------------------------------------------------------------------------------------------
    def _blocks(self) -> Iterator[tuple[bytes, int]]:
        """Blocks of whole lines with the number of their first line."""
        if self.source.seekable:
            self.stream.seek(self.data_pos)
            carry = b""
        else:
            carry, self.pending = self.pending, b""
        line_no = self.line_no
        # a live input (pipe, socket): the lines that have arrived, not a full block
        read = self.stream.read1 if self.source.live else self.stream.read
        while True:
            data = read(self.block_bytes)
            if not data:
                if carry.strip():
                    self._last_line = line_no  # (without its newline: cut short, if it does not parse)
                    yield carry + b"\n", line_no
                return
            buffer = carry + data if carry else data
            cut = buffer.rfind(b"\n")
            if cut < 0:
                carry = buffer
                continue
            block, carry = buffer[: cut + 1], buffer[cut + 1 :]
            yield block, line_no
            line_no += block.count(b"\n")

    def _parse(self, block: bytes, line_no: int) -> np.ndarray:
        """Events of one block of whole lines (the first numbered ``line_no``): read by the kernel
        (:func:`evtools._kernels.text.parse_text`), or by numpy when a field is more than a plain decimal; a ``#``
        comment line among them is left out (:meth:`_comment`)."""
        hash_at = block.find(b"#")
        if hash_at >= 0:
            start = block.rfind(b"\n", 0, hash_at) + 1
            if not block[start:hash_at].strip():  # a comment line: the lines before it and after it
                end = block.find(b"\n", hash_at) + 1 or len(block)
                self._comment(block[start:end])
                parts = [self._parse(block[:start], line_no)] if start else []
                if end < len(block):
                    parts.append(self._parse(block[end:], line_no + block.count(b"\n", 0, end)))
                return np.concatenate(parts) if parts else np.empty(0, EVENT_DTYPE)
        if self.semicolons:
            block = block.replace(b",", b" ").replace(b";", b",")  # (a comma inside a field is no separator)
        lines = block.count(b"\n") + 1  # (+ 1: room for a last line without its newline, were there one)
        mantissas, decimals = np.empty((lines, self.ncols), np.int64), np.empty((lines, self.ncols), np.int64)
        rows = np.empty(lines, np.int64)
        status, n, line, fields, point = parse_text(np.frombuffer(block, np.uint8), self.ncols, self.csv,
                                                    mantissas, decimals, rows,
                                                    self.index["t"] if self.seconds else -1)
        if status == WRONG_COUNT:
            self._wrong_count(line_no + line, fields)
        if status == PARSED:
            if self.seconds and not point and line_no == self.line_no and n >= WHOLE_SECONDS_LINES:
                self._refuse_whole_seconds(mantissas[:n, self.index["t"]], line_no)
            if not self.seconds and not point:  # numpy's integer parser reads such a block: the exact integers
                values = mantissas[:n]
            else:
                values = mantissas[:n].astype(np.float64) / _POWERS_OF_TEN_FLOAT[decimals[:n]]
            events = self._events(values, rows[:n], line_no)
            if self.seconds:  # microseconds from the decimal digits in integers (through float64 seconds they lost
                column = self.index["t"]  # 1 us near 2^53 us, Unix times in us): exact to 6 decimals, rounded half
                events["t"] = _microseconds(mantissas[:n, column], decimals[:n, column])  # to even beyond
            return events
        return self._parse_numpy(block, line_no)

    def _refuse_whole_seconds(self, t: np.ndarray, line_no: int) -> None:
        """Times in seconds of which the first block's every one is a whole number (no decimal point in it) are
        microseconds written as rpg text (a QA sweep: a 1 s recording read as 11.6 days, and bafilter then removed
        every event): refused, never guessed."""
        if np.ptp(t) > 0:
            raise FormatError(
                f"{self.name}: lines {line_no}-{line_no + len(t) - 1}: every time is a whole number, read as seconds "
                f"as rpg text's are ({int(np.ptp(t)):,} s from the first to the last): microseconds? read the file "
                "as CSV, whose times are microseconds whatever its separator (--input-format csv)")

    def _wrong_count(self, line_no: int, fields: int) -> None:
        raise FormatError(
            f"{self.name}: line {line_no}: {fields} columns, expected {self.ncols} "
            f"({self._separated()}{','.join(self.names)})"
        )

    def _separated(self) -> str:
        return "semicolon-separated " if self.semicolons else "" if self.csv else "whitespace-separated "

    def _parse_numpy(self, block: bytes, line_no: int) -> np.ndarray:
        """:meth:`_parse` by numpy's parser (exponents, ``true``/``false``, long mantissas), and the errors."""
        raw = np.frombuffer(block, np.uint8)
        ends = np.flatnonzero(raw == 10)
        starts = np.concatenate(([0], ends[:-1] + 1))
        if self.csv:
            separators = np.flatnonzero(raw == 44)
            fields = np.diff(np.searchsorted(separators, ends), prepend=0) + 1
            length = ends - starts
            blank = (length == 0) | ((length == 1) & (raw[np.maximum(ends - 1, 0)] == 13))
            fields[blank] = 0
        else:
            space = raw <= 32
            token_starts = np.flatnonzero(space[:-1] & ~space[1:]) + 1
            if len(raw) and not space[0]:
                token_starts = np.concatenate(([0], token_starts))
            fields = np.diff(np.searchsorted(token_starts, ends), prepend=0)
            blank = fields == 0
        wrong = (fields != self.ncols) & ~blank
        if wrong.any():
            i = int(np.argmax(wrong))
            self._wrong_count(line_no + i, int(fields[i]))
        rows = np.flatnonzero(~blank)  # line index (in the block) of each row
        values = self._numbers(block, len(rows) * self.ncols, line_no)
        if values is None:
            self._raise_bad_line(block, line_no)
        values = values.reshape(len(rows), self.ncols)
        return self._events(values, rows, line_no)

    def _numbers(self, block: bytes, expected: int, line_no: int) -> np.ndarray | None:
        if LONE_SIGN.search(block):  # (numpy reads a lone "-" or "+" as 0: "-1" cut to "-" passed as OFF)
            return None
        text = block.replace(b",", b" ") if self.csv else block
        attempts = (np.float64,) if self.seconds else (np.int64, np.float64)
        for dtype in attempts:
            try:
                values = np.fromstring(text, dtype=dtype, sep=" ")
            except ValueError:
                if dtype is np.int64 and re.search(rb"(?i)true|false", text):
                    text = re.sub(rb"(?i)true", b"1", re.sub(rb"(?i)false", b"0", text))
                    try:
                        values = np.fromstring(text, dtype=dtype, sep=" ")
                    except ValueError:
                        continue
                else:
                    continue
            if values.size == expected:
                return values
        return None

    def _raise_bad_line(self, block: bytes, line_no: int) -> None:
        for i, line in enumerate(block.split(b"\n")):
            fields = line.split(b",") if self.csv else line.split()
            if not line.strip():
                continue
            for field in fields:
                field = field.strip()
                if not _NUMBER.match(field) and not (not self.seconds and field.lower() in (b"true", b"false")):
                    shown = field.decode("utf-8", "replace")[:40]
                    raise FormatError(f"{self.name}: line {line_no + i}: {shown!r} is not a number")
        last = line_no + block.count(b"\n") - 1
        raise FormatError(f"{self.name}: lines {line_no}-{last}: cannot parse as numbers")

    def _events(self, values: np.ndarray, rows: np.ndarray, line_no: int) -> np.ndarray:
        t, x, y, p = (values[:, self.index[field]] for field in ("t", "x", "y", "p"))
        if values.dtype.kind == "f":
            self._check(~np.isfinite(t), rows, line_no, "t is not a finite number")
            if not self.seconds:  # (rounding a fraction away would move the event: refused, never guessed)
                self._check(t != np.floor(t), rows, line_no,
                            "t is not a whole number of microseconds (comma-separated, it reads as CSV, whose times "
                            "are integer microseconds; times in seconds are rpg text: 't x y p' separated by spaces)")
            t = np.rint(t * 1e6 if self.seconds else t)
            self._check((x != np.floor(x)) | (y != np.floor(y)) | ~np.isfinite(p), rows, line_no,
                        "x and y must be integers, p a number")
        # the integer parser saturates at +-(2^63 - 1): such a value, and any beyond the supported range, is refused
        self._check((t > MAX_TIME_US) | (t < -MAX_TIME_US), rows, line_no,
                    "t is outside the +-2^62 us (+-146,000 years) that evtools supports")
        self._check((x < 0) | (x > MAX_SENSOR_SIDE) | (y < 0) | (y > MAX_SENSOR_SIDE), rows, line_no,
                    f"x or y outside 0..{MAX_SENSOR_SIDE}")
        self._check((p != 0) & (p != 1) & (p != -1), rows, line_no, "p must be 0 or 1 (or -1 and +1)")
        off = p <= 0  # one file, one convention for OFF: 0 with 1, or -1 with +1 (mixed: a file joined wrong)
        if off.any():
            if self.off_seen is None:
                self.off_seen = int(p[int(np.argmax(off))])
            other = -1 - self.off_seen  # (0 <-> -1)
            self._check(p == other, rows, line_no, f"p is {other} where earlier lines wrote OFF as {self.off_seen}: "
                                                   "one file takes one convention (0 and 1, or -1 and +1)")
        out = np.empty(len(values), dtype=EVENT_DTYPE)
        out["t"] = t
        out["x"] = x
        out["y"] = y
        out["p"] = p > 0
        return out

    def _check(self, bad: np.ndarray, rows: np.ndarray, line_no: int, problem: str) -> None:
        if bad.any():
            raise FormatError(f"{self.name}: line {line_no + int(rows[int(np.argmax(bad))])}: {problem}")

    # -- size and iteration ---------------------------------------------------------------------------------
    def _scan_size(self) -> tuple[int, int]:
        position = self.stream.tell()
        width = height = 0
        with size_scan(self):
            for events in self._parsed():
                if len(events):
                    width = max(width, int(events["x"].max()) + 1)
                    height = max(height, int(events["y"].max()) + 1)
        self.stream.seek(position)
        return width, height

    def _parsed(self) -> Iterator[np.ndarray]:
        """The events of each block. A last line without its newline that does not read as an event is left out:
        the file was cut inside it (a writer stopped mid-line: :func:`ends_cut`)."""
        self._last_line = None
        for block, line_no in self._blocks():
            try:
                events = self._parse(block, line_no)
            except FormatError as error:
                if line_no != self._last_line:
                    raise
                ends_cut(self, f"line {line_no}, the last, ends without its newline and does not read as an "
                               f"event ({str(error).removeprefix(f'{self.name}: line {line_no}: ')})")
                return
            yield events

    def __iter__(self) -> Iterator[np.ndarray]:
        for events in self._parsed():
            for start in range(0, len(events), self.chunk_events):
                yield events[start : start + self.chunk_events]


class CsvReader(TextReader):
    """:class:`TextReader` of a file opened as CSV (by extension or ``--input-format csv``): t in microseconds."""

    DECLARED = "csv"


class TxtReader(TextReader):
    """:class:`TextReader` of a file opened as text: t in seconds unless the first line has commas."""

    DECLARED = "txt"


# -- writing ------------------------------------------------------------------------------------------------
_POWERS_OF_TEN = np.array([10**k for k in range(1, 20)], dtype=np.uint64)


_DIGIT_PAIRS = np.array([[48 + i // 10, 48 + i % 10] for i in range(100)], dtype=np.uint8).view(np.uint16).ravel()
"""ASCII of 00..99, two bytes each, as uint16 (so one indexing writes two digits)."""


def _ascii_digits(magnitude: np.ndarray, width: int) -> np.ndarray:
    """(n, width) uint8 ASCII of zero-padded decimals, two digits at a time (8-digit groups in uint32)."""
    n_pairs = (width + 1) // 2
    pairs = np.empty((len(magnitude), n_pairs), dtype=np.uint16)
    rest = magnitude.astype(np.uint64)
    column = n_pairs - 1
    while column >= 0:
        group = (rest % np.uint64(10**8)).astype(np.uint32)
        rest //= np.uint64(10**8)
        for _ in range(4):
            if column < 0:
                break
            pairs[:, column] = _DIGIT_PAIRS[group % 100]
            group //= 100
            column -= 1
    return pairs.view(np.uint8).reshape(len(magnitude), 2 * n_pairs)[:, 2 * n_pairs - width :]


def _digits_field(magnitude: np.ndarray, negative: np.ndarray | None, min_digits: int = 1):
    """ASCII matrix (n, width) of right-aligned decimal numbers and the mask of the bytes to keep."""
    n_digits = np.maximum(1 + np.searchsorted(_POWERS_OF_TEN, magnitude, side="right"), min_digits)
    signed = negative is not None and bool(negative.any())
    most = int(n_digits.max()) if len(magnitude) else min_digits
    width = most + signed
    matrix = np.empty((len(magnitude), width), dtype=np.uint8)
    matrix[:, signed:] = _ascii_digits(magnitude, most)
    used = n_digits + (negative if signed else 0)
    if signed:
        rows = np.flatnonzero(negative)
        matrix[rows, width - used[rows]] = ord("-")
    keep = np.arange(width) >= (width - used)[:, None]
    return matrix, keep


def _signed(values: np.ndarray):
    values = values.astype(np.int64)
    negative = values < 0
    return np.abs(values).view(np.uint64), negative  # abs(int64 min) wraps to 2**63, right as uint64


def _render(parts: list, n: int) -> bytes:
    """Rows of text from fields (``(matrix, keep)``) and constant separators (``bytes``)."""
    matrices, keeps = [], []
    for part in parts:
        if isinstance(part, bytes):
            matrices.append(np.broadcast_to(np.frombuffer(part, np.uint8), (n, len(part))))
            keeps.append(np.ones((n, len(part)), dtype=bool))
        else:
            matrices.append(part[0])
            keeps.append(part[1])
    matrix = np.concatenate(matrices, axis=1)
    keep = np.concatenate(keeps, axis=1)
    return matrix[keep].tobytes()


def _polarity_field(p: np.ndarray):
    matrix = (p.astype(np.uint8) + 48)[:, None]
    return matrix, np.ones(matrix.shape, dtype=bool)


class _TextWriter:
    def __init__(self, stream: BinaryIO, info: StreamInfo, options: WriteOptions) -> None:
        self.stream = stream
        self.info = info
        stream.write(self._header())

    def _header(self) -> bytes:
        return b""

    def write(self, chunk: np.ndarray) -> None:
        """Append a chunk of ``EVENT_DTYPE``."""
        for start in range(0, len(chunk), WRITE_ROWS):
            part = chunk[start : start + WRITE_ROWS]
            self.stream.write(self._rows(part))

    def _rows(self, events: np.ndarray) -> bytes:
        raise NotImplementedError

    def close(self) -> None:
        """Flush (the stream stays open)."""
        self.stream.flush()

    def mark_cut(self, note: str) -> None:
        """The input was cut: a last comment line says so (:data:`CUT_COMMENT`; evtools warns reading it)."""
        self.stream.write(CUT_COMMENT + note.encode() + b"\n")
        self.close()


class CsvWriter(_TextWriter):
    """CSV: faery's header ``t,x@W,y@H,on``, then one ``t,x,y,on`` row per event (t absolute microseconds, 1 = ON).

    The ``@W``/``@H`` suffixes carry the sensor size (faery's convention), so a CSV round trip keeps it;
    readers that ignore them still see the columns t, x, y and on.
    """

    def _header(self) -> bytes:
        return f"t,x@{self.info.width},y@{self.info.height},on\n".encode()

    def _rows(self, events: np.ndarray) -> bytes:
        n = len(events)
        return _render(
            [_digits_field(*_signed(events["t"])), b",", _digits_field(*_signed(events["x"])), b",",
             _digits_field(*_signed(events["y"])), b",", _polarity_field(events["p"]), b"\n"],
            n,
        )


class TxtWriter(_TextWriter):
    """rpg ``events.txt``: first line ``width height``, then ``t x y p`` with t in seconds as ``%.6f`` (exact)."""

    def _header(self) -> bytes:
        return f"{self.info.width} {self.info.height}\n".encode()

    def _rows(self, events: np.ndarray) -> bytes:
        magnitude, negative = _signed(events["t"])
        seconds, micro = np.divmod(magnitude, np.uint64(1_000_000))
        return _render(
            [_digits_field(seconds, negative), b".", _digits_field(micro, None, 6), b" ",
             _digits_field(*_signed(events["x"])), b" ", _digits_field(*_signed(events["y"])), b" ",
             _polarity_field(events["p"]), b"\n"],
            len(events),
        )
