"""Byte sources and sinks: paths or stdin/stdout, format sniffing without losing bytes, atomic output files."""

from __future__ import annotations

import array
import contextlib
import fcntl
import io
import logging
import os
import stat
import struct
import sys
import termios
import threading
import time
from collections import deque
from queue import Empty, Full, Queue
from typing import BinaryIO, Iterable, Iterator

import numpy as np

from evtools import interrupt
from evtools.events import EVENT_DTYPE
from evtools.formats.errors import FormatError, OutputCannotTakeFormat
from evtools.inputs import input_named_by, note_input

HEAD_BYTES = 4096
"""How many leading bytes format detection looks at."""
LIVE_HEAD_BYTES = 256
"""What a live input must send before its format is sniffed (every format's signature fits, and AEDAT 4.0's header
is longer: its XML alone exceeds it)."""

STDIO = "-"


MAX_PACKET_BYTES = 1 << 30
"""A packet (AEDAT 4.0, AEDAT 3.1) larger than this (64 M events) is taken for a damaged size field, not allocated
and not taken for a cut (DV and jAER write packets of at most a few megabytes)."""


def is_live(stream) -> bool:
    """True when the file object ``stream`` is not a regular file: a pipe, a socket, a FIFO, a terminal or a device
    (its bytes arrive over time, so a reader passes on what has arrived and a writer flushes what it has); False
    for an in-memory stream."""
    try:
        return not stat.S_ISREG(os.fstat(stream.fileno()).st_mode)
    except (AttributeError, OSError, ValueError):
        return False


class _PrefixedRaw(io.RawIOBase):
    """A raw stream that first replays ``prefix`` and then reads ``raw``: lets us sniff a pipe and still read it whole."""

    def __init__(self, prefix: bytes, raw: BinaryIO) -> None:
        self._prefix = memoryview(prefix)
        self._raw = raw
        self.delivered = 0  # bytes passed on so far (to the buffered stream over this one)

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        if self._prefix.nbytes:
            n = min(len(buffer), self._prefix.nbytes)
            buffer[:n] = self._prefix[:n]
            self._prefix = self._prefix[n:]
            self.delivered += n
            return n
        n = self._raw.readinto(buffer)
        self.delivered += n or 0
        return n


class _NetworkRaw(io.RawIOBase):
    """A connected socket's reads, each waiting at most ``timeout_s``; a silence that long and a connection reset
    mid-stream are errors naming the input (a reset was 'cannot connect')."""

    def __init__(self, name: str, connection, timeout_s: float) -> None:
        self._name, self._raw, self._timeout_s = name, connection.makefile("rb", buffering=0), timeout_s
        self._received = 0  # bytes read: a reset before any is no stream cut (a QA sweep: it said "mid-stream")
        connection.settimeout(timeout_s)

    def readable(self) -> bool:
        return True

    def fileno(self) -> int:
        return self._raw.fileno()

    def readinto(self, buffer) -> int:
        try:
            n = self._raw.readinto(buffer)
        except TimeoutError:
            waited = "sends nothing" if not self._received else "stopped sending"
            raise FormatError(f"{self._name}: no data for {self._timeout_s:g} s; the server is connected but "
                              f"{waited} (--timeout sets how long to wait)") from None
        except ConnectionResetError:
            if not self._received:
                raise FormatError(f"{self._name}: the server reset the connection before sending anything") from None
            raise FormatError(f"{self._name}: the server reset the connection mid-stream (the stream is cut)") from None
        self._received += n or 0
        return n

    def close(self) -> None:
        self._raw.close()
        super().close()


class Source:
    """An input: a file path or ``-`` for stdin, opened for binary reading, with its first bytes known.

    Attributes
    ----------
    name : str
        What messages call it (the path, or ``<stdin>``).
    path : str or None
        The file path, or None for stdin.
    head : bytes
        The first up to 4096 bytes, for format detection.
    stream : BinaryIO
        Reads the whole input from its first byte.
    seekable : bool
        True for regular files (readers may seek and re-read them).
    live : bool
        True for a pipe, a socket, a FIFO or a terminal: bytes arrive over time (readers pass on what arrived).
    network : bool
        True for ``tcp://HOST:PORT`` (a live network stream; connecting may take ``connect_timeout_s``, then a
        silence of ``read_timeout_s`` is an error).
    """

    def __init__(self, path: str | os.PathLike | None, connect_timeout_s: float = 10.0,
                 read_timeout_s: float = 60.0) -> None:
        path = STDIO if path is None else os.fspath(path)
        self.live = self.network = False
        self.size_stated = False  # the sensor size is the one the file states (resolve_sensor_size)
        self._fileno = None
        if path == STDIO:
            self.name, self.path = "<stdin>", None
            raw = sys.stdin.buffer.raw if hasattr(sys.stdin.buffer, "raw") else sys.stdin.buffer
            if _has_descriptor(raw):  # stdin redirected from a file (`< rec.aedat4`): never an output either
                note_input(raw.fileno(), "<stdin>, redirected from it")
            self._open_stream(raw)
            return
        if path.startswith(TCP_PREFIX):  # a live network stream (AEDAT 4.0 from DV or dv-processing)
            self.name, self.path, self.network = path, None, True
            self.connection = _connect(path, connect_timeout_s)
            self._open_stream(_NetworkRaw(path, self.connection, read_timeout_s))
            return
        self.name, self.path = path, path
        if os.path.isdir(path):
            raise FormatError(f"{path}: is a directory, not an event file")
        try:
            raw = open(path, "rb", buffering=0)
        except FileNotFoundError:
            raise FormatError(f"{path}: no such file") from None
        except OSError as error:
            raise FormatError(f"{path}: cannot open ({error.strerror})") from None
        note_input(path)
        if is_live(raw):  # a FIFO or a device: read as a stream, like stdin
            self._open_stream(raw)
            return
        self.stream = io.BufferedReader(raw, buffer_size=1 << 20)
        self.head = self.stream.read(HEAD_BYTES)
        self.stream.seek(0)
        self.seekable = True

    def _open_stream(self, raw) -> None:
        self.live = is_live(raw)
        self._fileno = raw.fileno() if self.live else None
        # a live source may send its header and then nothing until it has events: take what came, enough to sniff
        self.head = _read_up_to(raw, HEAD_BYTES, LIVE_HEAD_BYTES if self.live else HEAD_BYTES)
        self._prefixed = _PrefixedRaw(self.head, raw)
        self.stream = io.BufferedReader(self._prefixed, buffer_size=1 << 20)
        self.seekable = False

    def arrived(self, consumed: int) -> int:
        """How many bytes of a live input from which ``consumed`` bytes were read have arrived and wait, in the
        stream's buffer and in the pipe or socket (reading that many would not wait); 0 for other inputs."""
        if self._fileno is None:
            return 0
        waiting = array.array("i", [0])
        try:
            fcntl.ioctl(self._fileno, termios.FIONREAD, waiting)
        except (OSError, ValueError):  # closed meanwhile (a stop), or a device that cannot tell
            waiting[0] = 0
        return self._prefixed.delivered - consumed + waiting[0]

    def spooled(self) -> BinaryIO:
        """A seekable stream of the whole input: the file itself, or stdin copied into a temporary file."""
        if self.seekable:
            return self.stream
        import shutil
        import tempfile

        spool = tempfile.TemporaryFile()
        shutil.copyfileobj(self.stream, spool, 1 << 20)
        spool.seek(0)
        self.stream, self.seekable = spool, True
        return spool

    def close(self) -> None:
        if self.network:  # wakes a reading thread blocked in recv (it holds the stream's lock) before closing
            import socket

            try:
                self.connection.shutdown(socket.SHUT_RDWR)
            except OSError:  # the server is gone already
                pass
        elif self.live:  # a FIFO or a device: a reading thread may wait in it, and closing would wait for that
            return
        if self.path is not None or self.seekable or self.network:
            self.stream.close()


TCP_PREFIX = "tcp://"
"""Inputs and outputs named ``tcp://HOST:PORT`` are network streams (AEDAT 4.0 without its first line)."""


def tcp_address(name: str) -> tuple[str, int]:
    """``(host, port)`` of ``tcp://HOST:PORT`` (``tcp://:PORT``: host empty, every interface)."""
    host, colon, port = name[len(TCP_PREFIX):].rpartition(":")
    if not colon or not port.isdigit() or not 0 < int(port) < 65536:
        raise FormatError(f"{name}: not a network address; write tcp://HOST:PORT (port 1-65535)")
    return host.strip("[]"), int(port)


def _connect(name: str, timeout_s: float):
    """A socket connected to the server at ``tcp://HOST:PORT`` within ``timeout_s``; one-line errors name the
    address."""
    import socket

    host, port = tcp_address(name)
    try:
        connection = socket.create_connection((host or "localhost", port), timeout=timeout_s)
    except socket.gaierror as error:
        raise FormatError(f"{name}: unknown host ({error.strerror})") from None
    except TimeoutError:
        raise FormatError(f"{name}: no answer within {timeout_s:g} s (--timeout)") from None
    except OSError as error:
        raise FormatError(f"{name}: cannot connect ({error.strerror or error})") from None
    connection.settimeout(None)
    return connection


def _unacknowledged_bytes(sock) -> int:
    """Bytes sent on ``sock`` that its peer's system has not acknowledged yet (Linux: the send queue)."""
    return struct.unpack("i", fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0"))[0]


class _Client:
    """One connection of a :class:`TcpServer`: its own thread sends what is queued, in order, so that a client that
    stops reading holds up no one else (a blocking send under the server's lock froze every client, and the
    stage, for 5 s: a QA sweep). A client whose send stalls :attr:`TcpServer.SEND_TIMEOUT_S`, or that falls
    :attr:`TcpServer.MAX_BEHIND_BYTES` behind, is dropped; at the end its stream is ended, ours first."""

    def __init__(self, sock, served: list) -> None:
        self.sock, self.served = sock, served  # served: [bytes received, whole stream so far, dropped]
        self.queue: deque = deque()
        self.behind = 0  # bytes queued, not sent yet
        self.ending = False
        self.sent = threading.Event()  # everything queued was sent (or the client dropped): its hang-up begins
        self.changed = threading.Condition()
        self.thread = threading.Thread(target=self._send_all, name="evtools-tcp-client", daemon=True)
        self.thread.start()

    def put(self, data: bytes) -> bool:
        """Queue ``data``; False when the client is (now) dropped."""
        with self.changed:
            if self.served[2]:
                return False
            if self.behind + len(data) > TcpServer.MAX_BEHIND_BYTES:
                self._drop()
                return False
            self.queue.append(data)
            self.behind += len(data)
            self.changed.notify()
        return True

    def end(self) -> None:
        """Send what is queued, then end the stream (:meth:`_hang_up`)."""
        with self.changed:
            self.ending = True
            self.changed.notify()

    def _drop(self) -> None:
        self.served[2] = True
        self.queue.clear()
        self.sent.set()
        with contextlib.suppress(OSError):
            self.sock.close()

    def _send_all(self) -> None:
        while True:
            with self.changed:
                while not self.queue and not self.ending and not self.served[2]:
                    self.changed.wait()
                if self.served[2]:
                    return
                if not self.queue:  # ending, everything sent
                    self.sent.set()
                    break
                data = self.queue.popleft()
            try:
                self.sock.sendall(data)
            except OSError:  # gone, or stalled: dropped
                with self.changed:
                    self._drop()
                return
            with self.changed:
                self.behind -= len(data)
                self.served[0] += len(data)
        self._hang_up()

    def _hang_up(self) -> None:
        """Ends the client's stream so that it gets every byte sent: our end first, then its end (a close with
        unread bytes from the client would reset the connection and could drop the last packets in flight); the
        server closes the socket of a client that has not closed by its deadline."""
        import socket

        try:  # (dv-processing's NetworkReader drops the bytes that arrive with the stream's end: the end waits
            while _unacknowledged_bytes(self.sock):  # until the client's system has them all, within HANG_UP_S)
                time.sleep(0.005)
            self.sock.shutdown(socket.SHUT_WR)
            while self.sock.recv(1 << 16):
                pass
        except OSError:
            pass
        self.sock.close()


class TcpServer:
    """A binary output that serves ``tcp://HOST:PORT`` (``tcp://:PORT``: every interface) the way dv-processing's
    ``NetworkWriter`` does: every client that connects gets the stream's header (the first write) as soon as there
    is one and then what is written from the next ``flush()`` on, whole packets only; each client is sent to by its
    own thread (:class:`_Client`), and one that goes away, stalls for :data:`SEND_TIMEOUT_S` or falls
    :data:`MAX_BEHIND_BYTES` behind is dropped while the server goes on. ``network`` tells the AEDAT 4.0 writer to
    leave out the file's first line, as network streams do. At the end every client gets the rest of its stream
    (as long as it reads) and then its end, the server waiting at most :data:`HANG_UP_S` in all for the clients to
    close; it says how many clients got how much, and warns when none connected (the stream went to nobody)."""

    network = True
    SEND_TIMEOUT_S = 5.0
    MAX_BEHIND_BYTES = 64 << 20
    HANG_UP_S = 2.0  # (was 5 s a client, one after another, and without end for a client that kept sending)

    def __init__(self, name: str) -> None:
        import socket

        self.name = name
        host, port = tcp_address(name)
        try:  # (an IPv6 address, and every interface of both families for tcp://:PORT: a QA sweep)
            if ":" in host:
                self.listener = socket.create_server((host, port), family=socket.AF_INET6)
            elif not host and socket.has_dualstack_ipv6():
                self.listener = socket.create_server(("", port), family=socket.AF_INET6, dualstack_ipv6=True)
            else:
                self.listener = socket.create_server((host, port))
        except OSError as error:
            raise FormatError(f"{name}: cannot listen ({error.strerror or error})") from None
        self.header: bytes | None = None
        self.pending = bytearray()
        self.clients: list[_Client] = []
        self.arrived: list = []  # accepted before the header was written: they get it when it is
        self.packets_sent = 0  # flushes that sent data: a client joined at 0 gets the whole stream
        self.served: dict = {}  # socket -> [bytes received, whole stream so far, dropped]
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, name="evtools-tcp-accept", daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self.listener.accept()
            except OSError:  # the listener was closed
                return
            sock.settimeout(self.SEND_TIMEOUT_S)
            with self.lock:  # the header now (clients wait for it), packets from the next flush on
                self.served[sock] = [0, self.packets_sent == 0, False]
                if self.header is None:
                    self.arrived.append(sock)
                else:
                    self._join(sock)

    def _join(self, sock) -> None:
        client = _Client(sock, self.served[sock])
        if client.put(self.header):
            self.clients.append(client)

    def write(self, data) -> int:
        data = memoryview(data).cast("B")  # bytes or an array's buffer
        if self.header is None:  # the header goes at once to the clients that wait for it (a reader learns the
            with self.lock:  # sensor size before the first events, which may be long in coming)
                self.header = bytes(data)
                arrived, self.arrived = self.arrived, []
                for sock in arrived:
                    self._join(sock)
        else:
            self.pending += data
        return len(data)

    def flush(self) -> None:
        data, self.pending = bytes(self.pending), bytearray()
        with self.lock:
            if data:
                self.clients = [client for client in self.clients if client.put(data)]
                self.packets_sent += 1

    def isatty(self) -> bool:
        return False

    def close(self) -> None:
        import socket

        self.flush()
        self.listener.close()
        with self.lock:
            clients, arrived = self.clients, self.arrived
            self.clients, self.arrived = [], []
        for sock in arrived:  # (no header came: nothing to send)
            sock.close()
        for client in clients:
            client.end()
        for client in clients:  # (a client that reads gets its stream whole however slowly; one that stalls for
            client.sent.wait()  # SEND_TIMEOUT_S is dropped by its own send)
        deadline = time.monotonic() + self.HANG_UP_S
        for client in clients:
            client.thread.join(max(0.0, deadline - time.monotonic()))
            if client.thread.is_alive():  # still sending, or the client has not closed: cut off now (a shutdown
                with contextlib.suppress(OSError):  # wakes the thread's blocked send or receive; a close would not)
                    client.sock.shutdown(socket.SHUT_RDWR)
                client.sock.close()
        self._report()

    def _report(self) -> None:
        log = logging.getLogger("evtools")
        if not self.served:
            log.warning(f"{self.name}: no client connected: the stream went to nobody")
            return
        parts = [f"{sent / 1e6:.2f} MB ({'left early' if dropped else 'the whole stream' if whole else 'joined late'})"
                 for sent, whole, dropped in self.served.values()]
        count = len(self.served)
        log.info(f"{self.name}: served {count} client{'s' if count > 1 else ''}: {', '.join(parts)}")


LISTENING: dict[str, TcpServer] = {}
"""Network outputs opened ahead of their writer (:func:`listen_early`), by name."""


def listen_early(name: str) -> None:
    """Serve the network output ``tcp://HOST:PORT`` from now on (a command's start, before it reads its input), so
    that a client that connects while the input is opened gets the stream from its first packet; the output's
    writer (:func:`output_stream`) takes this server over."""
    if name.startswith(TCP_PREFIX) and name not in LISTENING:
        LISTENING[name] = TcpServer(name)


def _read_up_to(raw, n: int, enough: int) -> bytes:
    """Up to ``n`` bytes of ``raw``, reading until at least ``enough`` came or the input ended."""
    parts, got = [], 0
    while got < enough:
        part = raw.read(n - got)
        if not part:
            break
        parts.append(part)
        got += len(part)
    return b"".join(parts)


def read_at_most(stream: BinaryIO, n: int, seekable: bool) -> bytes:
    """``n`` bytes of ``stream`` or, when it ends first, what there is; never allocates more than the input holds
    (a damaged length field may ask for gigabytes): a file's remaining length is checked first, a pipe is read in
    pieces of at most 16 MiB."""
    if seekable:
        here = stream.tell()
        try:  # the file's size, without a seek (which would drop the reader's buffer: 47 us a packet of DV's)
            end = os.fstat(stream.fileno()).st_size
        except (AttributeError, OSError, io.UnsupportedOperation):
            end = stream.seek(0, 2)
            stream.seek(here)
        return stream.read(min(n, max(end - here, 0)))
    pieces, got = [], 0
    while got < n:
        piece = stream.read(min(n - got, 1 << 24))
        if not piece:
            break
        pieces.append(piece)
        got += len(piece)
    return b"".join(pieces)


def ends_cut(reader, problem: str) -> None:
    """A file that ends inside a record or packet (``problem`` says where) was cut: a recording stopped by a crash,
    a copy broken off. The whole records before it have been read and go on; a warning says what was lost and the
    stream is marked cut (``reader.cut_file``: its outputs say so, DESIGN.md), so no input is lost and no cut stream
    passes as whole. A live input cut so (its writer stopped mid-write) is an error, as a live input ending without
    its end mark is, unless this command was stopped too (a pipeline's Ctrl-C: the stream is read on to its
    writer's end, :data:`STOP_DRAIN_SECONDS`): then it is marked cut as a file is."""
    if getattr(reader, "scanning", False):  # (a scan for the sensor size, :func:`size_scan`: the read says it)
        return
    if reader.source.live and interrupt.received() is None:
        raise FormatError(f"{reader.name}: {problem}")
    logging.getLogger("evtools").warning(f"{reader.name}: {problem}: the {'stream' if reader.source.live else 'file'} "
                                         "was cut (or damaged there); the events before it are read, the rest is "
                                         "lost, and the stream is marked cut")
    reader.cut_file = True


@contextlib.contextmanager
def size_scan(reader) -> Iterator[None]:
    """A reader's scan of its whole file for the sensor size: a cut it meets is left to the read proper
    (:func:`ends_cut`), which says it once."""
    reader.scanning = True
    try:
        yield
    finally:
        reader.scanning = False


def same_file(a, b) -> bool:
    """True if paths ``a`` and ``b`` name the same existing file (standard input or output, ``-``, is none)."""
    if a is None or b is None or STDIO in (os.fspath(a), os.fspath(b)):
        return False
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def same_target(a, b) -> bool:
    """True if two outputs ``a`` and ``b`` would be one file: :func:`same_file`, or one path where none exists yet
    (symbolic links followed: a link to a file not made yet and that file's name are one output, a QA sweep)."""
    if a is None or b is None or STDIO in (os.fspath(a), os.fspath(b)):
        return False
    return os.path.realpath(a) == os.path.realpath(b) or same_file(a, b)


@contextlib.contextmanager
def output_stream(path: str | os.PathLike | None, *, binary_name: str, needs_seek: bool = False,
                  text: bool = False, option: str = "-o") -> Iterator[BinaryIO]:
    """Open an output for binary writing: a file written atomically, or stdout for ``-``/None.

    A file is written to a temporary name beside the target and renamed only when the block ends without an
    error, so an interrupted run never leaves a half-written file under the real name; a symbolic link keeps
    pointing where it did (its target is replaced). A FIFO, a socket or a device (``/dev/null``, a terminal) is
    written directly, never renamed over. A binary stream is never written to a terminal (``text``: CSV and text
    may be, to look at). ``needs_seek`` formats (HDF5) cannot go to stdout or to a FIFO. ``option`` names the
    command-line option the path came from, in messages (``--truth``).
    """
    path = STDIO if path is None else os.fspath(path)
    if path.startswith(TCP_PREFIX):
        if needs_seek:  # (h5py was handed the server: a traceback, a QA sweep)
            raise OutputCannotTakeFormat(f"{binary_name} cannot be served on a network output ({path}): it needs a "
                                         f"seekable file; give {option} FILE")
        server = LISTENING.pop(path, None) or TcpServer(path)
        try:
            yield server
        finally:
            server.close()
        return
    if path == STDIO:
        _check_stream_target(None, "stdout", binary_name, needs_seek, text, option)
        sys.stdout.flush()
        if isinstance(sys.stdout.buffer, io.BufferedWriter) or not _has_descriptor(sys.stdout):
            yield sys.stdout.buffer  # (or a test runner's or notebook's stdout: no descriptor to write whole)
            sys.stdout.buffer.flush()
            return
        # python -u / PYTHONUNBUFFERED=1: stdout's binary layer is raw, and a raw write may write part of its bytes
        # (a pipe whose reader went, a signal) and say so only in its count: a buffered writer of the same
        # descriptor writes all or raises (the rest of a CSV went missing and the exit code was 0)
        stream = open(sys.stdout.fileno(), "wb", buffering=1 << 20, closefd=False)
        try:
            yield stream
        except BaseException:
            with contextlib.suppress(OSError):  # (the body's error is the one to report)
                stream.close()
            raise
        stream.close()
        return
    try:  # (followed through links: /dev/stdout names a pipe by a /proc path that is no file name)
        mode = os.stat(path).st_mode
    except OSError:
        mode = None
    if mode is not None and not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
        try:
            stream = open(path, "wb", buffering=1 << 20)
        except OSError as error:
            raise FormatError(f"{path}: cannot open for writing ({error.strerror})") from None
        try:
            _check_stream_target(stream, path, binary_name, needs_seek, text, option)
            yield stream
        except BaseException:
            with contextlib.suppress(OSError):  # (the body's error is the one to report)
                stream.close()
            raise
        try:
            stream.close()  # the last flush (/dev/full: "No space left on device" named, not alone)
        except OSError as error:
            raise FormatError(f"{path}: cannot write ({error.strerror or error})") from None
        return
    with atomic_path(path) as temporary:
        try:
            stream = open(temporary, "w+b", buffering=1 << 20)
        except OSError as error:  # name the user's path, not the temporary
            raise FormatError(f"{path}: cannot write ({error.strerror or error})") from None
        try:
            yield stream
        except BaseException:
            with contextlib.suppress(OSError):  # the body's error is the one to report (a full disk: both)
                stream.close()
            raise
        try:
            stream.close()  # the last flush
        except OSError as error:
            raise FormatError(f"{path}: cannot write ({error.strerror or error})") from None


def _has_descriptor(stream) -> bool:
    try:
        stream.fileno()
    except (AttributeError, OSError, ValueError):  # (io.UnsupportedOperation is both an OSError and a ValueError)
        return False
    return True


def _check_stream_target(stream, name: str, binary_name: str, needs_seek: bool, text: bool = False,
                         option: str = "-o") -> None:
    """Refuse binary on a terminal, and a format that seeks on stdout (``stream`` None) or on anything live: choices
    of the command line (exit 2)."""
    if not text and (sys.stdout if stream is None else stream).isatty():
        raise OutputCannotTakeFormat(f"refusing to write binary {binary_name} to a terminal"
                                     f"{'' if stream is None else f' ({name})'}: give {option} FILE or pipe into "
                                     "another command")
    if needs_seek and (stream is None or is_live(stream)):
        raise OutputCannotTakeFormat(f"{binary_name} cannot be written to {name} (it needs a seekable file): give "
                                     f"{option} FILE")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[str]:
    """A temporary path beside ``path``, renamed to ``path`` when the block ends without an error, else removed.

    For writers that need a path of their own (OpenCV); ``suffix`` keeps an extension they dispatch on.
    The file gets the permissions of any new file (``mkstemp`` alone would make it private), or those of the file it
    replaces; a read-only file is not replaced (an error naming it). A symbolic link keeps
    pointing where it did (its target is replaced); a FIFO, a socket or a device is refused (a writer that wants a
    path cannot write into it, and renaming over it would destroy it).
    """
    named = os.fspath(path)
    path = os.path.realpath(named)
    if os.path.exists(path) and not os.path.isfile(path):
        kind = "a folder" if os.path.isdir(path) else "not a regular file (a FIFO, a device)"
        raise OutputCannotTakeFormat(f"{named}: is {kind}; this output is written as a file: give -o FILE")
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise FormatError(f"{named}: directory {directory} does not exist")
    _refuse_an_input(named, path)
    replaced_mode = stat.S_IMODE(os.stat(path).st_mode) if os.path.exists(path) else None
    if replaced_mode is not None and not replaced_mode & 0o222:
        raise FormatError(f"{named}: exists and is read-only (mode {replaced_mode:o}): remove it or make it writable "
                          "first, or choose another -o")
    try:
        temporary = _new_file(directory, "." + os.path.basename(path) + ".", ".part" + suffix)
    except OSError as error:  # (a folder one cannot write in, /proc: the user's path named, not the temporary's)
        raise FormatError(f"{named}: cannot write there ({error.strerror or error})") from None
    try:
        if replaced_mode is None:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(temporary, 0o666 & ~umask)
        else:  # a replaced file keeps its permissions (a private 0600 output stays private)
            os.chmod(temporary, replaced_mode)
        yield temporary
        _refuse_an_input(named, path)  # (an input read after the output was opened)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


def _refuse_an_input(named: str, path: str) -> None:
    """An error when the output ``path`` is a file the command reads (:mod:`evtools.inputs`)."""
    read_as = input_named_by(path)
    if read_as is not None:
        also = "" if os.path.abspath(read_as) == os.path.abspath(named) else f" ({read_as})"
        raise FormatError(f"{named}: is an input of this command{also}: an output would replace it; choose another "
                          "file")


def _new_file(directory: str, prefix: str, suffix: str) -> str:
    """A new empty file (mode 0600) in ``directory`` named ``prefix``, the process id, a number and ``suffix``: as
    ``tempfile.mkstemp`` makes one (``O_EXCL``: never a file that exists), without importing tempfile (shutil and
    random with it: 6 ms of the start-up of every command that writes a file)."""
    for attempt in range(10_000):
        name = os.path.join(directory, f"{prefix}{os.getpid()}-{attempt}{suffix}")
        try:
            os.close(os.open(name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
            return name
        except FileExistsError:
            continue
    raise FileExistsError(f"{directory}: no free temporary name {prefix}{os.getpid()}-N{suffix}")


MAX_INFERRED_SIDE = 2048
"""A sensor size inferred from the events (the file does not store it) is refused beyond this many pixels a side
(the largest event cameras have 1280 x 960; Prophesee's 11-bit addresses reach 2048): a stray coordinate would
otherwise size every per-pixel map by it (a 3-line CSV reaching 8191 took 2-3 GiB in estimate, bafilter, render).
``--sensor-size`` sets any size."""


def resolve_sensor_size(source: Source, from_file, sensor_size, scan=None) -> tuple[int, int]:
    """The sensor size of a stream: what the file says, else ``--sensor-size``, else inferred by ``scan()``.

    ``from_file`` is (width, height) or None; ``sensor_size`` the user's (width, height) or None; ``scan`` a
    callable returning (max x + 1, max y + 1) by reading a seekable file once (it must leave the stream where it
    found it). Without any of them the stream cannot be read: the message asks for ``--sensor-size``.
    """
    from evtools.errors import EvtoolsError
    from evtools.events import check_sensor_size

    def checked(size, said: str) -> tuple[int, int]:
        try:
            check_sensor_size(*size)
        except EvtoolsError as error:
            raise FormatError(f"{source.name}: {said} {size[0]}x{size[1]}: {error}") from None
        return tuple(size)

    if from_file is not None:
        if sensor_size is not None and tuple(sensor_size) != tuple(from_file):
            logging.getLogger("evtools").warning(
                "%s: file says %dx%d, using --sensor-size %dx%d", source.name, *from_file, *sensor_size
            )
            return tuple(sensor_size)
        source.size_stated = True  # (an event outside it is then damage, not a size to give)
        return checked(from_file, "the file says the sensor is")
    if sensor_size is not None:
        return tuple(sensor_size)
    if scan is not None and source.seekable:
        width, height = scan()
        if max(width, height) > MAX_INFERRED_SIDE:
            raise FormatError(f"{source.name}: the file does not store the sensor size and its events reach "
                              f"{width}x{height}, larger than any camera ({MAX_INFERRED_SIDE} a side): a damaged "
                              "file? If the size is right, give --sensor-size WxH")
        if width == 0 and height == 0:  # (no event to infer it from: the 1x1 of an empty stream)
            logging.getLogger("evtools").warning(
                "%s: the file holds no events and does not store the sensor size: taken as 1x1 (give --sensor-size "
                "to set it)", source.name)
        else:
            logging.getLogger("evtools").warning(
                "%s: sensor size not stored in the file; inferred %dx%d from the events (give --sensor-size to set "
                "it)", source.name, max(width, 1), max(height, 1))
        return checked((max(width, 1), max(height, 1)), "inferred from the events, the sensor is")
    raise FormatError(f"{source.name}: the file does not store the sensor size; give --sensor-size WxH")


_DONE = object()


def _nothing_but_the_end(queue: Queue) -> bool:
    """Whether ``queue`` (of :func:`read_ahead`) holds no item the consumer has not had: empty, or the end next."""
    try:
        item, _ = queue.get_nowait()
    except Empty:
        return True
    return item is _DONE


STOP_DRAIN_SECONDS = 1.0
"""After a stop, how long a live evtools stream (one that promised an end mark) is read on for its writer's end:
a terminal's Ctrl-C stops every stage of a pipeline, and the stage upstream ends its output at once, with the end
mark when what it read was whole (a live input's stop is its end), without it when it was reading a file: the
outputs are then marked cut. Taking the stop as the end at once had marked an output whole that held 14 M of a
file's 35 M events (a QA sweep). A writer still sending after this was not stopped: the stop is the end."""


def read_ahead(items: Iterable, depth: int = 2, drain_s: float = 0.0) -> Iterator:
    """The items of ``items``, produced by a background thread up to ``depth`` ahead of the consumer.

    Reading and decoding then overlap the consumer's work on a second core (file reads, decompression and the
    numba kernels release the GIL). An exception of the producer is raised in the consumer at its place in the
    sequence; when the consumer stops early, the producer stops at its next item. A stop requested on the command
    line (:mod:`evtools.interrupt`: Ctrl-C, SIGTERM) ends the sequence, at once when the consumer waits; with
    ``drain_s`` the items go on for up to that long after it, until their end (:data:`STOP_DRAIN_SECONDS`).
    """
    queue: Queue = Queue(maxsize=depth)
    stop = threading.Event()

    def put(entry) -> bool:
        while not stop.is_set():
            try:
                queue.put(entry, timeout=0.05)
                return True
            except Full:
                continue
        return False

    whole = threading.Event()  # the items ended with no stop seen before (a reader may end early on one)

    def produce() -> None:
        try:
            for item in items:
                if not put((item, None)):
                    return
            if interrupt.received() is None:
                whole.set()
            put((_DONE, None))
        except BaseException as error:  # handed to the consumer, raised there
            put((_DONE, error))

    thread = threading.Thread(target=produce, name="evtools-read-ahead", daemon=True)
    thread.start()
    try:
        with interrupt.consuming():
            ended = False
            while interrupt.received() is None:  # a stop (Ctrl-C) ends the stream like its end
                try:
                    with interrupt.waiting_for_input():
                        item, error = queue.get()
                except interrupt.StopReading:
                    break
                if error is not None:
                    raise error
                if item is _DONE:
                    thread.join()
                    ended = True
                    break
                yield item
            if not ended and drain_s and interrupt.received() is not None:  # on to the writer's own end
                deadline = time.monotonic() + drain_s
                while True:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    try:
                        item, error = queue.get(timeout=min(left, 0.05))
                    except Empty:
                        continue
                    if error is not None:
                        raise error
                    if item is _DONE:
                        thread.join()
                        break
                    yield item
            if whole.is_set() and _nothing_but_the_end(queue):  # read to its end before any stop: a stop after
                interrupt.read_whole()  # the last event leaves the outputs whole (they were marked cut: a QA sweep)
    finally:
        stop.set()


class Recycled:
    """Event arrays handed out as chunks and taken back for new chunks once nothing refers to them any more.

    A reader allocates a chunk's memory every chunk; fresh memory is paged in (zeroed by the kernel) on its first
    write, which on a virtual machine costs as much as decoding it (a whole-file LZ4 read spent 20 % of its time
    in the kernel's page clearing). A chunk given out is a view of an array kept here; the array is free again
    when its reference count says no chunk, view or copy-in-progress holds it (views keep their base alive), so
    reuse never touches memory a consumer still sees. Thread-safe: a count read while another thread drops a
    reference can only be too high (the array is skipped). Where reference counts are not exact (a
    free-threaded interpreter, PyPy) nothing is reused."""

    def __init__(self, keep: int = 6) -> None:
        self.arrays: list[np.ndarray] = []
        self.keep = keep
        self.exact = hasattr(sys, "getrefcount") and getattr(sys, "_is_gil_enabled", lambda: True)()
        self.lock = threading.Lock()

    def take(self, n: int) -> np.ndarray:
        """An array of ``n`` events (EVENT_DTYPE; contents undefined)."""
        with self.lock:
            if self.exact:
                for kept in self.arrays:
                    # held by the list, this loop and getrefcount's argument: nothing else
                    if len(kept) >= n and sys.getrefcount(kept) == 3:
                        return kept[:n]
            fresh = np.empty(n + n // 8, EVENT_DTYPE)  # room for the next, slightly larger request
            if self.exact:
                in_use = [kept for kept in self.arrays if sys.getrefcount(kept) > 3]
                self.arrays = in_use[max(len(in_use) - (self.keep - 1), 0):] + [fresh]
            return fresh[:n]


class WriteBehind:
    """A writer wrapper whose ``write`` hands chunks to a background thread (at most ``depth`` waiting), so that
    encoding and writing overlap the producer's work; the thread's errors are raised by the next ``write`` or by
    ``close``, which writes what is queued and then closes the writer."""

    def __init__(self, writer, depth: int = 2) -> None:
        self.writer = writer
        self.cut = False  # set when the input turned out cut: create_events then ends the output without its mark
        self.stopped = False  # set when a stop (Ctrl-C) ended the reading of a file early: the output is cut too
        self.notes: list[str] = []  # warnings about the output, given once it is complete (create_events)
        self.queue: Queue = Queue(maxsize=depth)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._consume, name="evtools-write-behind", daemon=True)
        self.thread.start()

    def _consume(self) -> None:
        while True:
            chunk = self.queue.get()
            if chunk is _DONE:
                return
            if self.error is None:
                try:
                    if isinstance(chunk, np.ndarray):
                        self.writer.write(chunk)
                    elif isinstance(chunk, tuple):  # a side stream's packet, in its place among the chunks
                        self.writer.write_side(chunk[1])
                    else:  # an APS frame, in its place among the chunks
                        self.writer.write_frame(chunk)
                except BaseException as error:  # raised in the producer's thread
                    self.error = error

    def _raise(self) -> None:
        if self.error is not None:
            error, self.error = self.error, None
            raise error

    def write(self, chunk) -> None:
        self._raise()
        self.queue.put(chunk)

    def write_frame(self, frame) -> None:
        """An APS frame (:class:`evtools.frames.Frame`), written after the chunks given before it."""
        self._raise()
        self.queue.put(frame)

    @property
    def carries_side_streams(self) -> bool:
        return bool(getattr(self.writer, "carries_side_streams", False))

    def write_side(self, packet) -> None:
        """A side stream's packet (IMU samples, triggers), written after the chunks given before it."""
        self._raise()
        self.queue.put(("side", packet))

    def close(self) -> None:
        if self.thread.is_alive():
            self.queue.put(_DONE)
            self.thread.join()
        self._raise()
        self.writer.close()

    def mark_cut(self, note: str, refuse: bool = True) -> None:
        """The output is a cut stream: what is queued is written, then the writer marks it (``note``)."""
        if self.thread.is_alive():
            self.queue.put(_DONE)
            self.thread.join()
        self._raise()
        self.writer.mark_cut(note, refuse)

    def abort(self) -> None:
        """The producer stopped with an error: what is queued is written, then the writer is released without
        marking the stream's end (``abort`` where the writer has one, else ``close``)."""
        if self.thread.is_alive():
            self.queue.put(_DONE)
            self.thread.join()
        getattr(self.writer, "abort", self.writer.close)()


PACE_SLICE_US = 5_000
""":func:`paced` releases events in slices of at most this much stream time (5 ms)."""


def paced(chunks: Iterable, speed: float = 1.0, clock=time.monotonic, sleep=time.sleep) -> Iterator:
    """The chunks of a stream, cut into slices of at most :data:`PACE_SLICE_US` of stream time, each released when
    the wall clock has advanced ``(last event time - first event time) / speed`` since the first: a recording
    replayed at its recorded speed (``speed`` 2: twice as fast) stands in for a camera. Late slices (a slow
    consumer) are released at once; the pace then catches up rather than shifting."""
    start_wall = start_us = None
    for chunk in chunks:
        if not len(chunk):
            continue
        t = chunk["t"]
        if start_us is None:
            start_us, start_wall = int(t[0]), clock()
        edges = np.arange(int(t[0]) - (int(t[0]) - start_us) % PACE_SLICE_US + PACE_SLICE_US, int(t[-1]) + 1,
                          PACE_SLICE_US)
        cuts = [0, *np.searchsorted(t, edges, side="left").tolist(), len(chunk)]
        for begin, end in zip(cuts, cuts[1:]):
            if end > begin:
                wait = start_wall + (int(t[end - 1]) - start_us) / 1e6 / speed - clock()
                if wait > 0:
                    try:
                        with interrupt.waiting_for_input():  # Ctrl-C ends a long wait (a gap in the recording)
                            sleep(wait)
                    except interrupt.StopReading:
                        return
                if interrupt.received() is not None:
                    return
                yield chunk[begin:end]
