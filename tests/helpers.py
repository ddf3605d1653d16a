"""Small helpers shared by the tests."""

from __future__ import annotations

import numpy as np

from evtools.events import EVENT_DTYPE, concatenate, make_events
import fcntl
import io
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

from evtools.formats import WriteOptions, open_events


def random_events(n: int, width: int = 346, height: int = 260, seed: int = 0, t0_us: int = 0) -> np.ndarray:
    """``n`` random events, sorted by time (with ties), covering the whole sensor."""
    rng = np.random.default_rng(seed)
    t = t0_us + np.sort(rng.integers(0, max(1, 20 * n), n))
    return make_events(t, rng.integers(0, width, n), rng.integers(0, height, n), rng.integers(0, 2, n))


def read_all(path, **options):
    """(info, events) of a whole file."""
    with open_events(path, **options) as stream:
        events = concatenate(stream)
        return stream.info, events


def cut(events: np.ndarray, cuts) -> list[np.ndarray]:
    """``events`` split at the (unsorted, possibly repeated) indices ``cuts``."""
    return np.split(events, sorted(int(c) % (len(events) + 1) for c in cuts))


def assert_same_events(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.dtype == EVENT_DTYPE
    assert len(actual) == len(expected)
    for field in ("t", "x", "y", "p"):
        np.testing.assert_array_equal(actual[field], expected[field], err_msg=f"field {field}")


def write_bytes(writer_class, events: np.ndarray, cuts, info, compression: str | None = None) -> bytes:
    """The bytes a writer produces when given ``events`` cut at ``cuts``."""
    buffer = io.BytesIO()
    writer = writer_class(buffer, info, WriteOptions(compression=compression))
    for part in np.split(events, sorted(cuts)):
        writer.write(part)
    writer.close()
    return buffer.getvalue()


EVTOOLS = str(Path(sys.executable).with_name("evtools"))
"""The console script installed beside the interpreter running the tests."""


def run(*args, input=None, check=True, cwd=None) -> subprocess.CompletedProcess:
    """Run ``evtools ARGS`` as a real process (in ``cwd``); with ``check``, fail the test unless it exits 0."""
    result = subprocess.run([EVTOOLS, *map(str, args)], input=input, capture_output=True, timeout=120, cwd=cwd)
    if check and result.returncode != 0:
        raise AssertionError(f"evtools {args} failed ({result.returncode}): {result.stderr.decode()}")
    return result


def aedat4_packets(data: bytes) -> list[int]:
    """The byte offsets of an AEDAT 4.0 file's packets (after its header), checking that they end with the file."""
    magic = b"#!AER-DAT4.0\r\n"
    position = len(magic) + 4 + struct.unpack_from("<I", data, len(magic))[0]
    packets = []
    while position < len(data):
        packets.append(position)
        position += 8 + struct.unpack_from("<iI", data, position)[1]
    assert position == len(data), "packets do not end with the file"
    return packets


def assert_clean_error(result: subprocess.CompletedProcess, *needles: str) -> None:
    """Exit 1, one line on stderr naming the problem, no traceback, nothing on stdout."""
    stderr = result.stderr.decode()
    assert result.returncode == 1, stderr
    assert "Traceback" not in stderr
    assert stderr.count("\n") == 1 and stderr.startswith("evtools: error: "), stderr
    for needle in needles:
        assert needle in stderr, stderr
    assert result.stdout == b""


def wait_until(condition, what: str, timeout_s: float = 60.0, poll_s: float = 0.02) -> None:
    """Waits for a state, not for a time (a busy machine may take any time to reach it); fails after
    ``timeout_s``, a bound far above any time the state needs."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(poll_s)


def unread_bytes(pipe) -> int:
    """Bytes written into a pipe and not yet read from it (the test keeps its own copy of the read end)."""
    return struct.unpack("i", fcntl.ioctl(pipe.fileno(), termios.FIONREAD, b"\0\0\0\0"))[0]


def _idle(pid: int) -> bool:
    """Every thread of the process sleeps in the kernel (waits for input, a lock or a timer: none is working)."""
    try:
        return all((task / "stat").read_text().rsplit(")", 1)[1].split()[0] == "S"
                   for task in Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return False


def wait_until_waiting_for_input(process: subprocess.Popen, *pipes) -> None:
    """Waits until ``process`` has read everything in ``pipes`` (read ends the test still holds) and waits for more:
    every thread asleep, three polls in a row."""
    settled = [0]

    def waiting() -> bool:
        assert process.poll() is None, f"{process.args} exited early: {process.returncode}"
        if all(unread_bytes(pipe) == 0 for pipe in pipes) and _idle(process.pid):
            settled[0] += 1
        else:
            settled[0] = 0
        return settled[0] >= 3

    wait_until(waiting, f"{process.args[1:4]} to wait for input", poll_s=0.05)
