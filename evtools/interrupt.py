"""Clean stop on SIGINT (Ctrl-C) and SIGTERM for the command line: finish what was read, then exit 130 / 143.

The first signal while a command consumes an event stream asks the stream to end: the reader stops at its next
chunk (at once when it is waiting for input, e.g. on a live pipe), so the processors flush what they hold and the
writers close their outputs as readable files holding every event that was processed (marked as cut when the
inputs were files: see :func:`evtools.formats.create_events`); the command then
exits with ``128 + signal``. A signal before any stream is consumed, or a second one, aborts at once
(``KeyboardInterrupt``: outputs are not committed, as for any failed run).

Only the command line installs the handlers (:func:`install`); the library never sees them.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

_received: int | None = None  # the first stop signal, once one came
_streams = 0  # how many streams are being consumed (a stop then ends them rather than aborting)
_begun = 0  # how many streams began to be consumed
_whole = 0  # how many of them were read to their end before any stop (see read_whole)
_waiting = False  # the main thread waits for input: a stop ends the wait
_deferring = 0  # how many outputs are being committed (a stop then waits until they are)


class StopReading(BaseException):
    """Raised in the main thread, inside :func:`waiting_for_input`, when a stop is requested (a BaseException, so
    that no ``except Exception`` swallows it)."""


def _handle(signum, frame) -> None:
    global _received
    if _deferring:  # an output is being committed: it ends complete, then the command stops (exit 128 + signal)
        if _received is None:
            _received = signum
        return
    if _received is None and _streams:
        _received = signum
        if _waiting:
            raise StopReading
        return
    if _received is None:
        _received = signum
    raise KeyboardInterrupt


def _unraisable(unraisable) -> None:
    """A stop raised where Python cannot pass it on (a weakref callback, a ``__del__`` as objects are freed) is not
    a finding to print with a traceback: the signal is recorded (:func:`received`), so the command ends with
    128 + signal all the same."""
    if isinstance(unraisable.exc_value, (KeyboardInterrupt, StopReading)):
        return
    sys.__unraisablehook__(unraisable)


def install() -> None:
    """Handle SIGINT and SIGTERM as described above (from the main thread)."""
    global _received, _begun, _whole
    _received = None
    _begun = _whole = 0
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _handle)
        signal.signal(signal.SIGTERM, _handle)
        sys.unraisablehook = _unraisable


def install_in_worker() -> None:
    """A batch's worker process (forked from the command): a stop signal is recorded and ends the stream being
    read, as in the command, but never raised while the worker waits for its next file (it would break the pool);
    the worker then starts no new file (:func:`received`). The command forwards its own signal to its workers, so
    a stop sent to it alone (``kill PID``, a supervisor) stops the batch too."""
    global _received, _begun, _whole
    _received = None
    _begun = _whole = 0
    signal.signal(signal.SIGINT, _handle_in_worker)
    signal.signal(signal.SIGTERM, _handle_in_worker)


def _handle_in_worker(signum, frame) -> None:
    global _received
    if _received is None:
        _received = signum
    if _streams and _waiting and not _deferring:
        raise StopReading


def received() -> int | None:
    """The signal that asked to stop (``signal.SIGINT``, ``signal.SIGTERM``) or None."""
    return _received


def exit_code() -> int:
    """``128 + signal`` of the stop (130 for SIGINT, 143 for SIGTERM)."""
    return 128 + (_received or signal.SIGINT)


@contextlib.contextmanager
def consuming():
    """While a stream is consumed, a first stop signal ends it instead of aborting."""
    global _streams, _begun
    _streams += 1
    _begun += 1
    try:
        yield
    finally:
        _streams -= 1


def read_whole() -> None:
    """A stream consumed under :func:`consuming` was read to its end with no stop seen before: a stop that comes
    after it (the work done, the outputs being closed) did not cut it."""
    global _whole
    _whole += 1


def every_stream_whole() -> bool:
    """Whether every stream consumed so far was read to its end before any stop (and there was one): a stop then
    left the outputs complete. A stream that ends on a stop, or whose reader stopped when the signal came, is not
    whole, so an output is never taken as complete when it may not be."""
    return _begun > 0 and _whole == _begun


@contextlib.contextmanager
def deferred():
    """While an output is committed (its last blocks written, its file closed), a stop signal waits until it is: an
    exception raised inside HDF5's writes through a Python file object leaves the library in a state that crashes the
    process (SIGSEGV). The command then stops as after a stream ended early (exit 128 + signal)."""
    global _deferring
    _deferring += 1
    try:
        yield
    finally:
        _deferring -= 1


def work_done() -> None:
    """The command's work is done and its outputs committed: from now on a stop signal is only recorded (raised
    while the interpreter tears objects down, it would print 'Exception ignored' with a traceback)."""
    global _deferring
    _deferring += 1


@contextlib.contextmanager
def waiting_for_input():
    """Wrap a blocking wait of the main thread for input: raises :class:`StopReading` when a stop was or is
    requested (in another thread, only the flag is read)."""
    global _waiting
    if threading.current_thread() is not threading.main_thread():
        if _received is not None:
            raise StopReading
        yield
        return
    _waiting = True
    try:
        if _received is not None:
            raise StopReading
        yield
    finally:
        _waiting = False
