"""Readers and writers of event files; :func:`open_events` and :func:`create_events` are the two entry points."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import signal
import stat
from typing import Iterator

import numpy as np

from evtools import interrupt
from evtools.events import StreamChecker, StreamInfo, concatenate, parse_sensor_size
from evtools.formats.errors import FormatError, OutputCannotTakeFormat, StreamReadAgain, UnknownOutputFormat
from evtools.formats.io import (
    STDIO,
    STOP_DRAIN_SECONDS,
    TCP_PREFIX,
    Source,
    WriteBehind,
    is_live,
    output_stream,
    read_ahead,
    same_file,
)
from evtools.formats.registry import (FORMATS, NOT_READ, PIPE_FORMAT, TEXT_FORMATS, ReadOptions, WriteOptions, by_name, detect,
                                      from_extension)

COMPRESSED_RATIO_BOUND = 3
"""A whole compressed AEDAT 4.0 file is read into a result sized for this many decoded bytes per file byte (LZ4 on
a DVXplorer recording: 2.0, zstd 2.9); the untouched rest costs nothing, and a denser file grows the result."""

READ_AHEAD = 1
"""Chunks a reader's thread may have ready beyond the one it is making and the one the consumer holds (was 2: 2 MiB
more a stream at the same speed; `correct` on 10M LZ4 events, `bafilter` on 50M, `estimate`, and whole-file reads,
3 alternating runs each)."""

__all__ = ["FORMATS", "EventStream", "FormatError", "ReadOptions", "WriteOptions", "create_events", "open_events"]

CUT_NOTE = "written from a cut input: the events after the cut are missing"
"""What an output of a cut input says of itself (HDF5's ``cut`` attribute, a text file's last comment line)."""
STOPPED_NOTE = "written by a run stopped by {} before its input's end: the events after the stop are missing"
"""What an output of a run stopped early (Ctrl-C, SIGTERM) says of itself: it is a cut stream too."""
FAILED_NOTE = "written by a run that failed before its input's end: the events after the failure are missing"
"""What a CSV or text output that went out (standard output, a pipe) says of itself when its run fails."""
log = logging.getLogger("evtools")


AEDAT3_TYPES = {0: "special", 2: "frames", 3: "IMU6", 4: "IMU9"}
"""AEDAT 3.1's event types that evtools does not read, by number (cAER's), for :meth:`EventStream.not_carried`."""
AEDAT2_WORDS = {"special": "special", "aps_imu": "APS/IMU", "external_input": "external-input"}


class EventStream:
    """An open input stream: ``info`` is known at once, iterating yields checked chunks of ``EVENT_DTYPE``."""

    def __init__(self, source: Source, reader, format_name: str, check: bool = True) -> None:
        self.source = source
        self.name = source.name
        self.reader = reader
        self.info: StreamInfo = reader.info
        self.info.format = format_name
        hint = " (the size the file states: a damaged file, or --sensor-size if it states a wrong one)" \
            if source.size_stated else \
            " (give the right --sensor-size)"
        self.checker = StreamChecker(self.info, self.name, hint) if check else None
        self.cut: FormatError | None = None  # a network stream's error, raised on closing (see _chunks)
        self._said_colour = False  # colour frames converted to gray: said once
        self.closed = False
        self._iterated = False

    @property
    def was_cut(self) -> bool:
        """Whether the stream, read to its end, turned out cut (a file whose writer promised an end mark and that
        ends without it, or cut inside a packet: read with a warning; a network stream cut or garbled: its error
        raised on closing); a command's output of it is then marked cut too (AEDAT 4.0: no end mark)."""
        return bool(getattr(self.reader, "cut_file", False)) or self.cut is not None

    def __iter__(self) -> Iterator[np.ndarray]:
        """The chunks, once: a second pass raises :class:`StreamReadAgain` (it would have read on from where the
        first stopped, a file's middle taken for a damaged record or time going backwards)."""
        if self._iterated:
            raise StreamReadAgain(f"{self.name}: this stream has been read already; a stream is read once, as it "
                                  "comes: open it again, or keep the events of read_all()")
        self._iterated = True
        # a live evtools stream (it promised an end mark) is read on after a stop, for its writer's end: with the
        # mark it was whole, without it cut (the stage upstream was reading a file: the outputs say so); a writer
        # still going after STOP_DRAIN_SECONDS was not stopped, and the stop is the stream's end, as a camera's
        # (not a network input: the stop does not reach its server, which goes on; reading on was a second lost,
        # and a cut warned of that the outputs did not carry, a QA sweep)
        drains = self.source.live and not self.source.network and getattr(self.reader, "expects_end_mark", False)
        return read_ahead(self._chunks(), READ_AHEAD, STOP_DRAIN_SECONDS if drains else 0.0)

    def take_frames(self) -> list:
        """The APS frames (:class:`evtools.frames.Frame`) read since the last call, in the order of the input (the
        reader reads ahead of the chunks given out, so these may lie beyond the last chunk); all of them once the
        stream has been read to its end."""
        taken = _drained(getattr(self.reader, "frames", None))
        colour = next((frame.metadata["converted_from"] for frame in taken if frame.metadata.get("converted_from")),
                      None)
        if colour and not self._said_colour:
            self._said_colour = True
            log.warning(f"{self.name}: its {colour} colour frames are read as gray (OpenCV's weights)")
        return taken

    def carry_side_streams(self) -> None:
        """Ask the reader to keep its side streams' packets (an AEDAT 4.0 input's IMU samples, triggers: each an
        :class:`evtools.formats.aedat4.SidePacket`) for :meth:`take_side_packets`, not skip them: for an output that
        carries them (AEDAT 4.0). Called before the stream is read."""
        if hasattr(self.reader, "carry_side"):
            self.reader.carry_side = True

    @property
    def reads_past_the_end(self) -> bool:
        """Whether a time slice's end should not stop the reading of this stream: a file whose side streams are
        carried (their packets may be stored after the events of their time: dv-processing's writer stores an
        IMU's samples when a packet is full), so that the packets that begin before the end are all met."""
        return bool(getattr(self.reader, "carry_side", False) and getattr(self.reader, "side_ids", None)) and \
            not self.source.live

    def take_side_packets(self) -> list:
        """The side streams' packets read since the last call (after :meth:`carry_side_streams`), in file order."""
        return _drained(getattr(self.reader, "side_packets", None))

    def not_carried(self) -> str | None:
        """What of the input a command that writes events and APS frames leaves out (the streams and words the
        reader skipped: IMU, triggers, jAER's APS samples...), as words, once the stream has been read; None when
        nothing was."""
        metadata = self.info.metadata
        packets = metadata.get("skipped_packets")
        if isinstance(packets, dict):  # AEDAT 3.1: packets by event type
            if not packets:
                return None
            kinds = ", ".join(f"{AEDAT3_TYPES.get(kind, f'type {kind}')}" for kind in sorted(packets))
            return f"{sum(packets.values()):,} packets of other event types ({kinds})"
        if packets:  # AEDAT 4.0: packets of the other streams
            return f"{packets:,} packets of its {', '.join(metadata.get('skipped_streams') or ['other'])} streams"
        words = {name: count for name, count in (metadata.get("skipped_words") or {}).items() if count}
        if words:  # AEDAT 2.0
            return ", ".join(f"{count:,} {AEDAT2_WORDS.get(name, name)} words" for name, count in words.items())
        raw = [f"{metadata[key]:,} {what}" for key, what in (  # Prophesee RAW
            ("triggers", "trigger events"), ("dropped_events", "events before the first time base (as OpenEB drops "
                                             "them)"), ("other_words", "words of other kinds")) if metadata.get(key)]
        return ", ".join(raw) or None

    @property
    def frames_read(self) -> int:
        """APS frames read so far."""
        return getattr(self.reader, "frames_read", 0)

    def _chunks(self) -> Iterator[np.ndarray]:
        try:
            for chunk in self.reader:
                if len(chunk) == 0:
                    continue
                yield self.checker.check(chunk) if self.checker else chunk
        except FormatError as error:
            if not self.source.network:
                raise
            if self.closed:  # our own close ended the connection (a stop): not the server's fault
                return
            # a network stream cut or garbled: what arrived whole is processed and written, and the error is
            # raised when the stream is closed (after the outputs, opened inside its block, are complete)
            self.cut = error

    def read_all(self) -> np.ndarray:
        """Every event, in one array. An uncompressed AEDAT 4.0 file is read straight into it: one chunk sized by
        the file (16 bytes an event: an upper bound; pages not reached cost nothing), each page touched once and no
        copy; a compressed one is copied into a result sized by :data:`COMPRESSED_RATIO_BOUND` chunk by chunk as
        they are decoded, so the reader reuses each chunk's memory (both measured in docs/performance.md); so is a
        stream whose reader tells how many
        events to expect (``expected_events()``: Prophesee RAW and DAT, HDF5); other streams are joined chunk by
        chunk, each chunk released as it is copied."""
        if self.info.format == "aedat4" and self.source.seekable and self.source.path:
            bound = os.path.getsize(self.source.path) // 16 + 1
            if str(self.info.metadata.get("compression")).upper() == "NONE":
                self.reader.options = dataclasses.replace(self.reader.options,
                                                          chunk_events=max(self.reader.options.chunk_events, bound))
            else:
                return concatenate(self, expected=bound * COMPRESSED_RATIO_BOUND)
        expected = getattr(self.reader, "expected_events", None)
        return concatenate(self, expected=expected() if expected else None)

    def close(self) -> None:
        self.closed = True
        close = getattr(self.reader, "close", None)
        if close:
            close()
        self.source.close()

    def __enter__(self) -> "EventStream":
        return self

    def __exit__(self, kind, *exc) -> None:
        self.close()
        if kind is None and self.cut is not None:
            raise self.cut


def open_events(path: str | os.PathLike | None = None, options: ReadOptions | None = None, *, check: bool = True,
                **fields) -> EventStream:
    """Open an event file (or ``-``/None for stdin) for streaming, read as ``options`` say (a :class:`ReadOptions`;
    ``fields``: its fields as keywords, replacing those of ``options``).

    The format is recognised by its magic bytes, then by the file's extension; ``format`` overrides both.
    ``check`` (default) raises :class:`evtools.InvalidEventsError` at the first event outside the sensor or
    earlier than the one before it. A live input (pipe, socket, FIFO) of AEDAT 4.0 yields every packet as it
    arrives.
    """
    unknown = sorted(set(fields) - {field.name for field in dataclasses.fields(ReadOptions)})
    if unknown:
        raise TypeError(f"open_events() got unknown reading option(s) {', '.join(unknown)}")
    options = dataclasses.replace(options or ReadOptions(), **fields)
    if options.sensor_size is not None:
        options = dataclasses.replace(options, sensor_size=parse_sensor_size(options.sensor_size))
    folder = None
    if path is not None and os.fspath(path) != STDIO and os.path.isdir(path):  # a dataset folder: RPG, DSEC
        from evtools.formats.rpg import DSEC_SENSOR_SIZE, folder_events, folder_images

        folder = os.fspath(path)
        path, layout = folder_events(folder)
        images = folder_images(folder, layout)  # (checked before the events are read)
        if layout == "dsec" and options.sensor_size is None:
            options = dataclasses.replace(options, sensor_size=DSEC_SENSOR_SIZE)
    source = Source(path, options.connect_timeout_s, options.read_timeout_s)
    try:
        if not source.head:
            raise FormatError(f"{source.name}: empty input, not an event stream")
        if options.format:
            fmt = by_name(options.format)
        else:
            fmt = detect(source.head, source.path)
            unread = next((said for magic, said in NOT_READ.items() if source.head.startswith(magic)), None)
            if fmt is None and unread:
                raise FormatError(f"{source.name}: {unread}: evtools does not read this format")
            if fmt is None:
                raise FormatError(f"{source.name}: unknown format (no known magic bytes or extension); give "
                                  "--input-format")
        if fmt.reader is None:
            raise FormatError(f"{source.name}: {fmt.description} cannot be read")
        reader = fmt.reader_class()(source, options)
        if folder is not None:
            from evtools.formats.rpg import FolderFrames

            reader = FolderFrames(reader, layout, images)
        return EventStream(source, reader, fmt.name, check)
    except BaseException:
        source.close()
        raise


def _named(target: str, function, *args):
    """Call ``function`` (a writer's, touching only the output); a :class:`FormatError` it raises gets the output's
    name in front, and an OSError (a full disk, a lost mount) becomes one naming the output, not a temporary."""
    try:
        return function(*args)
    except FormatError as error:
        raise FormatError(f"{target}: {error}") from None
    except BrokenPipeError:  # the reader went away (`| head`): a quiet stop, not an error
        raise
    except OSError as error:
        raise FormatError(f"{target}: cannot write ({error.strerror or error})") from None


class _NamedWriter:
    """A writer whose errors name the output file (writers see only a stream); on a live output (a pipe, a socket,
    a FIFO) what each chunk brought is flushed at once (``flush()`` of the writer, else of the stream)."""

    def __init__(self, target: str, writer, stream, live: bool, description: str) -> None:
        self.target, self.writer, self.description = target, writer, description
        self.live = live  # (a pipe, a socket, stdout: what is written has gone out)
        self.flush = (getattr(writer, "flush", None) or stream.flush) if live else None
        self.frames_left_out = 0

    def write(self, chunk: np.ndarray) -> None:
        _named(self.target, self.writer.write, chunk)
        if self.flush is not None:
            _named(self.target, self.flush)

    def write_frame(self, frame) -> None:
        """An APS frame, where the format stores frames (AEDAT 4.0, HDF5); elsewhere counted and said at the end."""
        if not hasattr(self.writer, "write_frame"):
            self.frames_left_out += 1
            return
        _named(self.target, self.writer.write_frame, frame)
        if self.flush is not None:
            _named(self.target, self.flush)

    @property
    def carries_side_streams(self) -> bool:
        """Whether the output declares side streams (AEDAT 4.0 written with an AEDAT 4.0 input's metadata) and takes
        their packets (:meth:`write_side`)."""
        return bool(getattr(self.writer, "side_streams", 0))

    def write_side(self, packet) -> None:
        """A side stream's packet, where the output carries them (:attr:`carries_side_streams`)."""
        _named(self.target, self.writer.write_side, packet)
        if self.flush is not None:
            _named(self.target, self.flush)

    def close(self) -> None:
        _named(self.target, self.writer.close)
        if self.frames_left_out:
            log.warning(f"{self.target}: {self.description} does not store APS frames: the input's "
                        f"{self.frames_left_out:,} frames are left out (AEDAT 4.0 and HDF5 keep them)")

    def mark_cut(self, note: str, refuse: bool = True) -> None:
        """The output is a cut stream (its input was cut, or a stop ended the run early): the writer marks it so
        (AEDAT 4.0 by ending without the end mark, HDF5 by an attribute ``cut``, CSV and text by a last comment
        line, each holding ``note``) and readers warn; a format with nowhere to say it (AEDAT 2.0, RAW) is refused
        (``refuse``: a cut input, so that no cut stream passes on as whole) or kept with a warning (a stop: the
        user asked for what was processed)."""
        mark = getattr(self.writer, "mark_cut", None)
        if mark is None:
            _named(self.target, self.writer.close)
            if refuse:
                written = ("the events that went out are a cut stream, unmarked" if self.live or
                           self.target == "<stdout>" else "nothing is written")
                raise FormatError(f"{self.target}: the input was cut (events after the cut are missing) and "
                                  f"{self.description} has nowhere to say so: {written}; write AEDAT 4.0, HDF5 or "
                                  "CSV, which carry the cut")
            log.warning(f"{self.target}: {note}, and {self.description} has nowhere to say so: whoever reads it "
                        "next sees a whole stream")
            return
        _named(self.target, mark, note)

    def abort(self) -> None:
        """The run failed: release the writer without marking the stream's end (its ``abort``: AEDAT 4.0 ends
        without its end mark, so what went out reads as cut), or, for a format whose end is no mark, say the cut
        where what went out stays (standard output, a pipe, a FIFO, a socket; a file's temporary is deleted): CSV
        and text by their cut comment (:data:`FAILED_NOTE`; they ended as if whole, and the next stage of a pipe
        took them as whole), AEDAT 2.0 and RAW, which have nowhere to say it, by a warning."""
        if hasattr(self.writer, "abort"):
            _named(self.target, self.writer.abort)
            return
        stays = self.live or self.target == "<stdout>"
        if stays and hasattr(self.writer, "mark_cut"):
            _named(self.target, self.writer.mark_cut, FAILED_NOTE)
            return
        _named(self.target, self.writer.close)
        if stays:
            log.warning(f"{self.target}: the events that went out are a cut stream, unmarked ({self.description} has "
                        "nowhere to say so)")


def check_compression(fmt, compression: str | None, target: str) -> None:
    """Refuse a ``compression`` that the format ``fmt`` does not write (a CSV file has none to choose: asking for
    one is a mistake to report, not to ignore), before the output is created."""
    if compression is None or compression.lower() in fmt.compressions:
        return
    if not fmt.compressions:
        raise FormatError(f"{target}: {fmt.description} is written uncompressed, compression {compression!r} does "
                          f"not apply (it does to {', '.join(f.name for f in FORMATS if f.compressions)})")
    raise FormatError(f"{target}: unknown {fmt.description.split(' (')[0]} compression {compression!r}; choose one of "
                      f"{', '.join(fmt.compressions)}")


def output_format(path: str | os.PathLike | None, format: str | None):
    """The format to write: ``format`` if given, else by extension, else AEDAT 4.0 for stdout and for a path
    without an extension that is not a regular file (``/dev/null``, a FIFO: streams, like stdout)."""
    if path is not None and os.fspath(path).startswith(TCP_PREFIX):
        if format and by_name(format).name != PIPE_FORMAT:
            raise FormatError(f"{path}: a network output carries AEDAT 4.0, not {by_name(format).description}")
        fmt = by_name(PIPE_FORMAT)
    elif format:
        fmt = by_name(format)
        named = from_extension(os.fspath(path)) if path is not None and os.fspath(path) != STDIO else None
        if named is not None and named.name != fmt.name:  # (evtools itself then refused the file: a QA sweep)
            log.warning(f"{path}: written as {fmt.description} (--format), though its extension says "
                        f"{named.description}: readers go by the extension first; name it "
                        f"*{fmt.extensions[0]} to read it back")
    elif path is None or os.fspath(path) == STDIO:
        fmt = by_name(PIPE_FORMAT)
    else:
        fmt = from_extension(os.fspath(path))
        if fmt is None and os.path.exists(path) and not os.path.isfile(path) and not os.path.isdir(path):
            fmt = by_name(PIPE_FORMAT)
        if fmt is None:
            written = ", ".join(ext for f in FORMATS if f.writer is not None for ext in f.extensions)
            raise UnknownOutputFormat(f"{path}: cannot tell the output format from the extension: end the name "
                                      f"with one of {written} (convert and simulate also take --format)")
    if fmt.writer is None:  # (a choice on the command line: a usage mistake, exit 2, naming the output)
        target = "<stdout>" if path is None or os.fspath(path) == STDIO else os.fspath(path)
        raise OutputCannotTakeFormat(f"{target}: {fmt.description} is read, not written; choose another extension "
                                     "or --format")
    return fmt


def _drained(queue) -> list:
    """What a reader's queue (a deque, or None) holds, taken from it in order (popleft: the reader's thread may
    append meanwhile)."""
    taken = []
    while queue:
        taken.append(queue.popleft())
    return taken


def stop_cut(inputs: tuple[str, ...]) -> str | None:
    """The name of the stop signal (``SIGINT``) when one ended the reading of ``inputs`` early, so that the
    outputs made from them are cut; else None. A live input's stop is its end, and a stop after every input was
    read to its end cut nothing."""
    stop = interrupt.received()
    if stop is None or _any_live(inputs) or interrupt.every_stream_whole():
        return None
    return signal.Signals(stop).name


def _any_live(inputs: tuple[str, ...]) -> bool:
    """Whether one of ``inputs`` (paths, ``-``, ``tcp://``) is live: a network stream, a pipe, a FIFO, a device.
    A stop (Ctrl-C) ends a live stream where it is, as a camera's recording ends; a file's reading stopped early
    leaves its output cut."""
    for path in inputs:
        path = os.fspath(path) if path is not None else STDIO
        if path.startswith(TCP_PREFIX):
            return True
        try:
            mode = os.fstat(0).st_mode if path == STDIO else os.stat(path).st_mode
        except OSError:
            continue
        if not stat.S_ISREG(mode):
            return True
    return False


@contextlib.contextmanager
def create_events(
    path: str | os.PathLike | None,
    info: StreamInfo,
    *,
    format: str | None = None,
    compression: str | None = None,
    aedat2_layout: str | None = None,
    inputs: tuple[str, ...] = (),
):
    """Write an event stream to ``path`` (``-``/None: stdout), atomically; yields a writer with ``write(chunk)``.

    ``inputs`` are the paths being read, which the output may not overwrite. When the input turned out cut (the
    caller sets ``writer.cut``) or a stop (Ctrl-C) ended the reading of files (not of a live input: its end), the
    output is marked cut (:meth:`_NamedWriter.mark_cut`) instead of closed whole.
    """
    fmt = output_format(path, format)
    if path is not None and os.fspath(path) != STDIO:
        for input_path in inputs:
            if input_path and same_file(path, input_path):
                raise FormatError(f"{path}: output would overwrite the input; choose another -o")
    target = "<stdout>" if path is None or os.fspath(path) == STDIO else os.fspath(path)
    check_compression(fmt, compression, target)
    options = WriteOptions(compression=compression, aedat2_layout=aedat2_layout)
    writer_class = fmt.writer_class()
    with output_stream(path, binary_name=fmt.description, needs_seek=fmt.writer_needs_seek,
                       text=fmt.name in TEXT_FORMATS) as stream:
        live = getattr(stream, "network", False) or is_live(stream)
        with interrupt.deferred():  # a writer half made (HDF5's file, its datasets) cannot be released cleanly
            writer = WriteBehind(_NamedWriter(target, _named(target, writer_class, stream, info, options), stream,
                                              live, fmt.description))
        try:
            yield writer
            stop = stop_cut(inputs)
            writer.stopped = stop is not None
            if writer.cut or writer.stopped:  # the input turned out cut, or a stop (Ctrl-C) ended a file's reading
                with interrupt.deferred():    # early: the output says so (or is refused where it cannot say a cut)
                    writer.mark_cut(CUT_NOTE if writer.cut else STOPPED_NOTE.format(stop), refuse=writer.cut)
        except BaseException:
            # release the writer's hold on the stream (h5py crashes if its file object closes first) without
            # marking the stream's end: what went out to a pipe, a FIFO or a socket reads as cut, not as whole; a
            # half-written temporary file is then deleted by output_stream
            with contextlib.suppress(Exception), interrupt.deferred():
                writer.abort()
            raise
        if not writer.cut and not writer.stopped:
            with interrupt.deferred():
                writer.close()
    for note in writer.notes:  # (the output complete: not said before an error)
        log.warning(note)
