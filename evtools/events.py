"""The event model: one dtype, one stream description, one validation.

Every chunk in evtools is a 1-D array of :data:`EVENT_DTYPE`, sorted by ``t`` (ties allowed). The layout is
AEDAT 4.0's ``Event`` struct (t int64 @0, x int16 @8, y int16 @10, on bool @12, itemsize 16), so AEDAT 4.0
packets are read and written without copying field by field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable, Iterator

import numpy as np

from evtools.errors import InvalidEventsError

EVENT_DTYPE = np.dtype(
    {"names": ["t", "x", "y", "p"], "formats": ["<i8", "<i2", "<i2", "?"], "offsets": [0, 8, 10, 12], "itemsize": 16}
)
"""t: microseconds (int64); x: column, y: row (image convention, origin top-left); p: True = ON."""

CHUNK_EVENTS = 1 << 17
"""Events per chunk that readers aim for (131,072: 2 MiB). About seven chunks are in flight at once (the read-ahead
queue, the one being filled, the processor's output, the write-behind queue), so the size sets the memory floor
(the sizes measured: docs/performance.md)."""

MAX_SENSOR_SIDE = 32767
"""x and y are int16."""
MAX_TIME_US = 1 << 62
"""Event times lie in -2^62..2^62 us (146,000 years either way of 0): a kernel adds windows and gaps to a time
without overflow, and 2^63 - 1 stays free to mean "no event yet"."""

MAX_THRESHOLD = 10.0
"""The largest contrast threshold taken (log units: a 22,000-fold change of intensity), as a nominal or a target:
no DVS pixel's is near it, and larger values overflowed float32 maps into inf (a QA sweep: --nominal 1e300)."""

MAX_SENSOR_PIXELS = 1 << 26
"""The largest sensor accepted, in pixels (8192 x 8192; the largest event cameras have about 1.2 million)."""


@dataclass
class StreamInfo:
    """What is known about a stream before its first event.

    Parameters
    ----------
    width, height : int
        Sensor size in pixels; every event has ``0 <= x < width`` and ``0 <= y < height``.
    format : str
        Name of the format the stream was read from (``"aedat4"``, ``"hdf5"``, ...), or ``""``.
    metadata : dict
        Anything else the source said (camera name, time offset, skipped streams, ...).
    """

    width: int
    height: int
    format: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_sensor_size(self.width, self.height)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height)."""
        return (self.width, self.height)


LABEL_NAMES = ("signal", "leak", "shot", "hot")
"""The per-event noise labels by code (``simulate --truth``'s ``label``: 0 signal, 1 leak, 2 shot, 3 hot pixel)."""


def label_problem(labels: np.ndarray) -> str | None:
    """What is wrong with per-event noise labels, or None: the one check of a truth file's labels and of labels given
    in Python. One whole number per event from 0 to 3 (a 7 vanished from every count, -1 scored a held-out AUC of
    1.0; booleans are refused: True would count as leak)."""
    if labels.ndim != 1 or labels.dtype.kind not in "iu":
        return f"labels must be one whole number per event (1-D integers), not {labels.dtype} of shape {labels.shape}"
    if len(labels) and (labels.min() < 0 or labels.max() >= len(LABEL_NAMES)):
        return (f"labels must be 0 (signal), 1 (leak), 2 (shot) or 3 (hot pixel); found {int(labels.min())} to "
                f"{int(labels.max())}")
    return None


def check_sensor_size(width: int, height: int) -> None:
    """Raise :class:`InvalidEventsError` unless ``1 <= width, height <= 32767`` and the sensor has at most
    :data:`MAX_SENSOR_PIXELS` pixels (per-pixel maps of a larger one would take tens of gigabytes)."""
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise InvalidEventsError(f"sensor {name} {value!r} is not a whole number of pixels")
        if not 1 <= int(value) <= MAX_SENSOR_SIDE:
            raise InvalidEventsError(f"sensor {name} {value} is not in 1..{MAX_SENSOR_SIDE}")
    pixels = int(width) * int(height)
    if pixels > MAX_SENSOR_PIXELS:
        raise InvalidEventsError(
            f"sensor {width}x{height} has {pixels:,} pixels, more than {MAX_SENSOR_PIXELS:,} (8192 x 8192, beyond any "
            f"event camera): its per-pixel state would need about {pixels * 32 / 2**30:,.0f} GiB; give the sensor's "
            "real size (--sensor-size / --size)")


def parse_sensor_size(size) -> tuple[int, int]:
    """``(width, height)`` from ``"WxH"`` (e.g. ``"346x260"``, the command line's form) or a pair; a one-line
    :class:`InvalidEventsError` for anything else."""
    if isinstance(size, str):
        parts = size.lower().replace(",", "x").split("x")
        try:
            width, height = (int(part) for part in parts)
        except ValueError:
            raise InvalidEventsError(f"sensor size {size!r} is not of the form WIDTHxHEIGHT, e.g. 346x260") from None
    else:
        try:
            width, height = size
        except (TypeError, ValueError):
            raise InvalidEventsError(f"a sensor size is (width, height) or 'WxH', not {size!r:.40}") from None
    check_sensor_size(width, height)
    return int(width), int(height)


def empty_events(n: int = 0) -> np.ndarray:
    """A zeroed chunk of ``n`` events."""
    return np.zeros(n, dtype=EVENT_DTYPE)


def make_events(t, x, y, p) -> np.ndarray:
    """Build a chunk from four equally long columns (p: bool, or 0/1); the records' padding is zero, as in the
    readers' chunks (``np.empty`` left whatever the memory held there)."""
    t = np.asarray(t)
    out = np.zeros(len(t), dtype=EVENT_DTYPE)
    out["t"] = t
    out["x"] = x
    out["y"] = y
    out["p"] = np.asarray(p) > 0
    return out


def concatenate(chunks: Iterable[np.ndarray], expected: int | None = None) -> np.ndarray:
    """All chunks as one array (memory grows with the stream). Each chunk is released as soon as it is copied into
    the result, whose pages are touched only as they are filled: the peak is the stream plus one chunk, not twice
    the stream.

    ``expected``: about how many events to expect (an overestimate costs nothing: pages not reached are never
    touched). Given, each chunk is copied as it arrives into a result of that size (grown by half when it is
    exceeded), so a reader can reuse the chunk's memory at once; without it the chunks are gathered first and
    copied into a result of their exact size."""
    if expected is not None:
        out, filled = _room(max(int(expected), 1)), 0
        for chunk in chunks:
            chunk = np.asarray(chunk)
            if filled + len(chunk) > len(out):
                grown = np.empty(max(len(out) * 3 // 2, filled + len(chunk)), EVENT_DTYPE)
                grown.view(_RECORD)[:filled] = out.view(_RECORD)[:filled]
                out = grown
            out.view(_RECORD)[filled:filled + len(chunk)] = _records(chunk)
            filled += len(chunk)
            del chunk  # the last reference: the reader may reuse its memory for the next chunk
        return out[:filled]
    parts = [np.asarray(chunk) for chunk in chunks]
    if len(parts) == 1 and parts[0].dtype == EVENT_DTYPE and parts[0].flags.c_contiguous:
        return parts[0]  # the one chunk is the result: no copy
    if len(parts) <= 1:
        return join(parts) if parts else empty_events()
    out = np.empty(sum(len(part) for part in parts), EVENT_DTYPE)
    records, filled = out.view(_RECORD), 0
    parts.reverse()
    while parts:
        part = parts.pop()
        records[filled:filled + len(part)] = _records(part)
        filled += len(part)
        del part  # the last reference: its memory goes back before the next chunk is copied
    return out


def _room(events: int) -> np.ndarray:
    """An uninitialised array of ``events`` events, or of a quarter as many, down to a million, while the system
    refuses to reserve that much (an upper bound taken from a file's size can exceed what the events need; the
    result grows when they do not fit)."""
    while True:
        try:
            return np.empty(events, EVENT_DTYPE)
        except MemoryError:
            if events <= 1 << 20:
                raise
            events = max(events // 4, 1 << 20)


def as_chunk(chunk, name: str = "chunk") -> np.ndarray:
    """``chunk`` as a 1-D array of :data:`EVENT_DTYPE`. An array with its fields in another layout (tonic's x, y, t,
    p int64, faery's t, x, y, on: see :func:`event_fields`) is converted field by field, by name (``p > 0`` is ON),
    other fields ignored, and refused when a value would change
    (a fractional time, a coordinate beyond int16); anything else raises :class:`InvalidEventsError` saying how to
    convert it. A polarity is a bool, 0/1 or -1/+1: another value (0.5, 2, 255, NaN) is refused, not guessed."""
    chunk = np.asarray(chunk)
    if chunk.dtype != EVENT_DTYPE:
        keys = event_fields(chunk.dtype)
        if keys is None:
            raise InvalidEventsError(
                f"{name} has dtype {chunk.dtype}, expected EVENT_DTYPE (fields t, x, y, p: evtools.from_columns, "
                "from_tonic and from_dv convert other layouts)")
        converted = np.zeros(chunk.shape, EVENT_DTYPE)  # (padding zero)
        for column in ("t", "x", "y"):  # by name: numpy's astype between structured types goes by position
            values = chunk[keys[column]]
            converted[column] = values
            if values.dtype != EVENT_DTYPE[column] and np.any(converted[column] != values):
                kind = "a whole number of microseconds in int64" if column == "t" else "an int16 coordinate"
                raise InvalidEventsError(f"{name}: field {column} ({values.dtype}) holds a value that is not {kind}")
        polarity = chunk[keys["p"]]
        if polarity.dtype != bool:
            unknown = ~np.isin(polarity, (0, 1, -1))
            if unknown.any():
                raise InvalidEventsError(f"{name}: field {keys['p']} holds {polarity[unknown][0].item()!r}; "
                                         "a polarity is a bool, 0/1 or -1/+1")
        converted["p"] = polarity > 0
        chunk = converted
    if chunk.ndim != 1:
        raise InvalidEventsError(f"{name}: a chunk is a 1-D array of events, got shape {chunk.shape}")
    return chunk


def event_fields(dtype: np.dtype) -> dict[str, str] | None:
    """The fields of a structured ``dtype`` that hold t, x, y and p, by name or title (faery's, aedat's and tonic's
    ``read_aedat4`` arrays call the polarity ``on``, titled ``p``; ``on`` alone is taken too); None if one lacks.
    Other fields are ignored."""
    fields = dtype.fields or {}
    keys = {column: column for column in ("t", "x", "y", "p") if column in fields}
    if "p" not in keys and "on" in fields:
        keys["p"] = "on"
    return keys if len(keys) == 4 else None


_RECORD = np.dtype((np.void, EVENT_DTYPE.itemsize))
"""An event as 16 raw bytes: copies of these are memory copies (a structured copy goes field by field, ~7x slower)."""


def record_words(chunk: np.ndarray) -> np.ndarray:
    """The records of a contiguous ``EVENT_DTYPE`` chunk as (n, 2) int64 words (a view): the time, then
    ``x | y << 16 | p << 32`` (little-endian: x at byte 8, y at 10, p at 12, the padding bytes 13-15). Writing a
    record's two words at once writes its padding too (zero), and is one pass where the four fields are four."""
    return chunk.view(np.int64).reshape(-1, 2)


def second_words(x: np.ndarray, y: np.ndarray, on: np.ndarray) -> np.ndarray:
    """The second words of :func:`record_words` (int64) for columns x, y (non-negative, below 2^16) and on
    (bool)."""
    return x.astype(np.int64) | (y.astype(np.int64) << 16) | (on.astype(np.int64) << 32)


def select(chunk: np.ndarray, index) -> np.ndarray:
    """``chunk[index]`` (a boolean mask or positions) copied as raw records: numpy's indexing and ``copy()`` of a
    structured array copy its fields and leave the records' padding bytes undefined."""
    return np.ascontiguousarray(chunk).view(_RECORD)[index].view(EVENT_DTYPE)


def join(chunks: list[np.ndarray]) -> np.ndarray:
    """The chunks one after the other, as one :data:`EVENT_DTYPE` array (other layouts of the same fields are
    converted); the records are copied as raw bytes."""
    return np.concatenate([_records(np.asarray(chunk)) for chunk in chunks]).view(EVENT_DTYPE)


def _records(chunk: np.ndarray) -> np.ndarray:
    """``chunk`` as raw 16-byte records (:data:`_RECORD`), converted to :data:`EVENT_DTYPE` first (by
    :func:`as_chunk`) when its fields are laid out otherwise."""
    return (chunk if chunk.dtype == EVENT_DTYPE else as_chunk(chunk)).view(_RECORD)


def rechunk(chunks: Iterable[np.ndarray], size: int) -> Iterator[np.ndarray]:
    """Re-cut a stream into chunks of exactly ``size`` events (the last one shorter), copying as little as possible."""
    pending: list[np.ndarray] = []
    held = 0
    for chunk in chunks:
        while len(chunk):
            take = min(size - held, len(chunk))
            pending.append(chunk[:take])
            held += take
            chunk = chunk[take:]
            if held == size:
                yield pending[0] if len(pending) == 1 else join(pending)
                pending, held = [], 0
    if held:
        yield join(pending)


class StreamChecker:
    """Checks chunk after chunk that events lie on the sensor, that their polarity is 0 or 1 and that time never
    goes backwards (and converts an
    array with EVENT_DTYPE's fields in another layout, see :func:`as_chunk`).

    The first offending event is reported by its index in the whole stream, so the user can find it; ``name``
    starts every message (a reader's: the file) and ``hint`` ends that of an event outside the sensor (a reader's:
    give the right ``--sensor-size``).
    """

    def __init__(self, info: StreamInfo, name: str = "events", hint: str = "") -> None:
        self.info = info
        self.name = name
        self.hint = hint
        self.events_seen = 0
        self.last_t: int | None = None

    def check(self, chunk: np.ndarray) -> np.ndarray:
        chunk = as_chunk(chunk, self.name)
        if len(chunk):
            from evtools._kernels.check import first_faults

            t = chunk["t"]
            outside, polarity, out_of_range, backwards = first_faults(
                t, chunk["x"], chunk["y"], chunk["p"].view(np.uint8), self.info.width, self.info.height,
                self.last_t if self.last_t is not None else 0, self.last_t is not None, MAX_TIME_US)
            if outside >= 0:
                raise InvalidEventsError(
                    f"{self.name}: event {self.events_seen + outside} at (x={chunk['x'][outside]}, "
                    f"y={chunk['y'][outside]}) lies outside the {self.info.width}x{self.info.height} sensor{self.hint}"
                )
            if polarity >= 0:  # a bool byte other than 0 or 1 is damage: it would be read as ON and copied
                raise InvalidEventsError(
                    f"{self.name}: event {self.events_seen + polarity} has a polarity byte of "
                    f"{int(chunk['p'].view(np.uint8)[polarity])}, not 0 (OFF) or 1 (ON): a damaged file?")
            if out_of_range >= 0:
                raise InvalidEventsError(
                    f"{self.name}: event {self.events_seen + out_of_range} has time {int(t[out_of_range])} us, outside "
                    "the +-2^62 us (+-146,000 years) that evtools supports")
            if backwards >= 0:
                self._backwards(backwards, self.last_t if backwards == 0 else t[backwards - 1], t[backwards])
            self.last_t = int(t[-1])
        self.events_seen += len(chunk)
        return chunk

    def _backwards(self, i: int, before_us: int, t_us: int) -> None:
        raise InvalidEventsError(
            f"{self.name}: time goes backwards at event {self.events_seen + i} ({t_us} us after {before_us} us)"
        )
