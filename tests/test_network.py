"""Live network streams (issue 16): ``tcp://HOST:PORT`` as input (a DV / dv-processing server) and as output (a
server for DV's GUI and dv-processing's NetworkReader), checked against dv-processing itself on loopback; bad
servers give one-line errors naming the address."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import evtools
from evtools.events import concatenate
from tests.helpers import assert_same_events

dv = pytest.importorskip("dv_processing", reason="dv-processing (the test extra) is the reference peer")

ROOT = Path(__file__).resolve().parents[1]
EVTOOLS = [str(Path(sys.executable).with_name("evtools")), "-q"]
WIDTH, HEIGHT = 64, 48


def _environment():
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _wait_for_server(port: int, process, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert process.poll() is None, process.stderr.read() if process.stderr else process.returncode
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            time.sleep(0.05)
    raise AssertionError(f"nothing listens on {port}")


def _read_all(reader, pieces: list) -> None:
    """Appends every event batch a dv-processing NetworkReader gets, as EVENT_DTYPE, until its server closes."""
    while True:
        running = reader.isRunning()  # read before the batch: once stopped, what it still holds is drained
        batch = reader.getNextEventBatch()
        if batch is not None and len(batch):
            a = batch.numpy()
            pieces.append(evtools.make_events(a["timestamp"], a["x"], a["y"], a["polarity"]))
        elif not running:
            return
        else:
            time.sleep(0.001)


def _joined(pieces: list) -> np.ndarray:
    return np.concatenate(list(pieces)).astype(evtools.EVENT_DTYPE) if pieces else evtools.make_events([], [], [], [])


def _batches(seed: int, count: int = 5, size: int = 2000):
    rng = np.random.default_rng(seed)
    t0 = 1_000_000
    for _ in range(count):
        t = t0 + np.sort(rng.integers(0, 10_000, size))
        t0 = int(t[-1]) + 1
        yield evtools.make_events(t, rng.integers(0, WIDTH, size), rng.integers(0, HEIGHT, size),
                                  rng.integers(0, 2, size))


def _store(events) -> "dv.EventStore":
    store = dv.EventStore()
    for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(), events["p"].tolist()):
        store.push_back(t, x, y, p)
    return store


DV_SERVER = """
import sys, numpy as np, dv_processing as dv
port, width, height, path = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
writer = dv.io.NetworkWriter("127.0.0.1", port, dv.io.Stream.EventStream(0, "events", "test", (width, height)))
print("listening", flush=True)
sys.stdin.readline()  # the test's go: its client is connected to the stage's output
batches = np.load(path)
for k in sorted(batches.files):
    store = dv.EventStore()
    for t, x, y, p in zip(*(batches[k][name].tolist() for name in ("t", "x", "y", "p"))):
        store.push_back(t, x, y, bool(p))
    writer.writeEvents(store)
print("sent", flush=True)
sys.stdin.read()  # until the test says it is done
"""
"""dv-processing's NetworkWriter as DV serves a camera, in a process of its own: its destructor waits for its
clients to leave holding the interpreter's lock, which hung the test process once in a loaded run."""


def test_a_dv_server_through_evtools_to_a_dv_client(tmp_path):
    """dv-processing NetworkWriter -> `evtools convert tcp://... -o tcp://...` -> dv-processing NetworkReader: the
    client gets every event the server wrote, in order, with the sensor size; Ctrl-C ends the live stage cleanly."""
    source_port, sink_port = _free_port(), _free_port()
    sent = list(_batches(1))
    np.savez(tmp_path / "batches.npz", **{f"b{k}": batch for k, batch in enumerate(sent)})
    server = subprocess.Popen([sys.executable, "-c", DV_SERVER, str(source_port), str(WIDTH), str(HEIGHT),
                               str(tmp_path / "batches.npz")], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True)
    stage = None
    try:
        assert server.stdout.readline().strip() == "listening"
        stage = subprocess.Popen([*EVTOOLS, "convert", f"tcp://127.0.0.1:{source_port}", "-o",
                                  f"tcp://127.0.0.1:{sink_port}"], stderr=subprocess.PIPE, text=True,
                                 env=_environment(), cwd=ROOT)
        _wait_for_server(sink_port, stage)
        reader = dv.io.NetworkReader("127.0.0.1", sink_port)  # (the stage sends the header as soon as it has it,
        assert reader.getEventResolution() == (WIDTH, HEIGHT)  # so its input is connected: the server has it)
        pieces: list = []
        thread = threading.Thread(target=_read_all, args=(reader, pieces), daemon=True)
        thread.start()
        server.stdin.write("go\n")
        server.stdin.flush()
        assert server.stdout.readline().strip() == "sent"
        total, deadline = sum(len(batch) for batch in sent), time.monotonic() + 120
        while sum(len(piece) for piece in pieces) < total and time.monotonic() < deadline:
            time.sleep(0.05)  # (every event arrived: a state; the deadline only bounds a failure)
        stage.send_signal(signal.SIGINT)
        assert stage.wait(timeout=60) == 130, stage.stderr.read()
        thread.join(timeout=60)
        assert not thread.is_alive(), "the client did not see the server close"
    finally:
        for process in (stage, server):
            if process is not None:
                process.kill()
                process.wait()
    assert_same_events(_joined(pieces), np.concatenate(sent).astype(evtools.EVENT_DTYPE))


def _received_bytes(connection: socket.socket, into: bytearray) -> None:
    while data := connection.recv(1 << 16):
        into += data


def _read_by_dv(path: Path) -> np.ndarray:
    """Every event of an AEDAT 4.0 file, read by dv-processing."""
    recording, batches = dv.io.MonoCameraRecording(str(path)), []
    while recording.isRunning():
        batch = recording.getNextEventBatch()
        if batch is not None and len(batch):
            a = batch.numpy()
            batches.append(evtools.make_events(a["timestamp"], a["x"], a["y"], a["polarity"]))
    return np.concatenate(batches).astype(evtools.EVENT_DTYPE)


def test_a_late_client_gets_the_header_and_then_live_events(tmp_path):
    """A replay served on tcp://: clients that connect a while after the start get the header (sensor size), then
    a contiguous part of the recording from a packet on, up to its end; a client that leaves early does not stop
    the server. (dv-processing's NetworkReader may drop the packets still queued when its server closes, so the
    end of the stream is checked on the bytes a plain socket received, read back by dv-processing.)"""
    events, _ = evtools.simulate("bars", size=(WIDTH, HEIGHT), duration_us=3_000_000, seed=2)
    recording = tmp_path / "bars.aedat4"
    evtools.write(recording, events, evtools.StreamInfo(WIDTH, HEIGHT))
    port = _free_port()
    stage = subprocess.Popen([*EVTOOLS, "convert", str(recording), "-o", f"tcp://127.0.0.1:{port}", "--realtime"],
                             stderr=subprocess.PIPE, text=True, env=_environment(), cwd=ROOT)
    try:
        _wait_for_server(port, stage)
        quitter, received = socket.create_connection(("127.0.0.1", port), timeout=60), 0  # the header (< 1 KiB) and
        while received < 4096:  # some packets, then goes away: the server has sent its first packet (a state, not
            piece = quitter.recv(4096)  # a time, so a busy machine does not matter)
            assert piece, "the server closed before sending a packet"
            received += len(piece)
        quitter.close()
        plain, stream = socket.create_connection(("127.0.0.1", port)), bytearray()
        thread = threading.Thread(target=_received_bytes, args=(plain, stream), daemon=True)
        thread.start()
        reader = dv.io.NetworkReader("127.0.0.1", port)
        assert reader.getEventResolution() == (WIDTH, HEIGHT)
        pieces: list = []
        _read_all(reader, pieces)
        assert stage.wait(timeout=30) == 0, stage.stderr.read()
        thread.join(timeout=30)
    finally:
        stage.kill()
        stage.wait()
    by_reader = _joined(pieces)
    assert len(by_reader) > 0
    first, last = np.searchsorted(events["t"], by_reader["t"][0], side="left"), np.searchsorted(events["t"], by_reader["t"][0], side="right")
    starts = [start for start in range(first, last) if np.array_equal(events[start:start + len(by_reader)], by_reader)]
    assert starts and starts[0] > 0, "the late client's events are not a contiguous part of the recording"
    (tmp_path / "received.aedat4").write_bytes(b"#!AER-DAT4.0\r\n" + bytes(stream))
    tail = _read_by_dv(tmp_path / "received.aedat4")
    assert 0 < len(tail) < len(events)
    assert_same_events(tail, events[len(events) - len(tail):])


def _serve_once(payload: bytes) -> int:
    """A one-shot server on loopback that sends ``payload`` to its first client and closes; returns its port."""
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]

    def serve():
        client, _ = listener.accept()
        client.sendall(payload)
        client.close()
        listener.close()

    threading.Thread(target=serve, daemon=True).start()
    return port


def _network_form(path: Path) -> tuple[bytes, list[bytes]]:
    """The header (length + IOHE buffer) and the packets of an AEDAT 4.0 file, as a network stream sends them."""
    data = path.read_bytes()[len(b"#!AER-DAT4.0\r\n"):]
    (length,) = struct.unpack("<I", data[:4])
    header, rest, packets = data[:4 + length], data[4 + length:], []
    while rest:
        size = struct.unpack("<iI", rest[:8])[1]
        packets.append(rest[:8 + size])
        rest = rest[8 + size:]
    return header, packets


def test_bad_servers_give_one_line_errors_naming_the_address(tmp_path):
    events, _ = evtools.simulate("bars", size=(WIDTH, HEIGHT), duration_us=500_000, seed=4)
    recording = tmp_path / "bars.aedat4"
    evtools.write(recording, events, evtools.StreamInfo(WIDTH, HEIGHT))
    header, packets = _network_form(recording)
    assert len(packets) >= 2
    env = _environment()

    def run(*args):
        result = subprocess.run([*EVTOOLS, *args], capture_output=True, text=True, env=env, cwd=ROOT, timeout=60)
        assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
        return result

    refused = run("info", f"tcp://127.0.0.1:{_free_port()}")
    assert refused.returncode == 1 and "cannot connect" in refused.stderr and "tcp://127.0.0.1:" in refused.stderr
    unknown = run("info", "tcp://no-such-host.invalid:7777")
    assert unknown.returncode == 1 and "tcp://no-such-host.invalid:7777: unknown host" in unknown.stderr
    malformed = run("info", "tcp://127.0.0.1")  # (a usage error: the command line is wrong, not the server)
    assert malformed.returncode == 2 and "tcp://HOST:PORT" in malformed.stderr
    garbage_port = _serve_once(os.urandom(5000))
    garbage = run("info", f"tcp://127.0.0.1:{garbage_port}")
    assert garbage.returncode == 1 and f"tcp://127.0.0.1:{garbage_port}" in garbage.stderr
    # closed in the middle of the second packet: exit 1, and the output holds the first packet's events
    cut_port = _serve_once(header + packets[0] + packets[1][: len(packets[1]) // 2])
    out = tmp_path / "out.aedat4"
    cut = run("convert", f"tcp://127.0.0.1:{cut_port}", "-o", str(out))
    assert cut.returncode == 1 and "truncated" in cut.stderr and f"tcp://127.0.0.1:{cut_port}" in cut.stderr
    first_packet = struct.unpack("<I", packets[0][8 + 28:8 + 32])[0]  # the EVTS vector's length
    with evtools.open(out) as written:  # marked cut (it was complete: half a stream passed as whole, a QA sweep)
        assert_same_events(concatenate(written), events[:first_packet])
        assert written.was_cut
    cut_h5 = run("convert", f"tcp://127.0.0.1:{_serve_once(header + packets[0])}", "-o", str(tmp_path / "o.h5"))
    assert cut_h5.returncode == 1 and "without the end mark" in cut_h5.stderr  # (cut at a packet boundary)
    with evtools.open(tmp_path / "o.h5") as written:
        assert written.was_cut
    # a whole stream that ends at a packet boundary is a normal end
    whole_port = _serve_once(header + b"".join(packets))
    whole = subprocess.run([*EVTOOLS, "convert", f"tcp://127.0.0.1:{whole_port}", "-o", str(tmp_path / "whole.aedat4")],
                           capture_output=True, text=True, env=env, cwd=ROOT, timeout=60)
    assert whole.returncode == 0, whole.stderr
    assert_same_events(evtools.read(tmp_path / "whole.aedat4")[0], events)
    busy = subprocess.run([*EVTOOLS, "convert", str(recording), "-o", f"tcp://127.0.0.1:{whole_port}", "--format",
                           "csv"], capture_output=True, text=True, env=env, cwd=ROOT, timeout=60)
    assert busy.returncode == 2 and "carries AEDAT 4.0" in busy.stderr  # a usage error


def test_a_server_that_sends_nothing_or_resets_is_an_error_naming_it():
    """Issue 37 item 10: a server that accepts and never sends made evtools wait forever (the 10 s limit covered
    the connect only); a reset mid-stream was reported as 'cannot connect'. Reads now wait at most the reading
    options' read_timeout_s (lowered here) and a reset says so."""
    import socket
    import struct
    import threading

    from evtools.formats import open_events
    from evtools.formats.errors import FormatError

    for behaviour in ("silent", "reset", "reset at once"):
        finished = threading.Event()
        listener = socket.socket()
        listener.bind(("127.0.0.1", 0))
        listener.listen(1)
        port = listener.getsockname()[1]

        def serve():
            client, _ = listener.accept()
            if behaviour.startswith("reset"):
                if behaviour == "reset":
                    client.send(b"#!AER-DAT4.0\r\n" + bytes(20))  # a header's start, then a reset (RST)
                client.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                client.close()
            else:
                finished.wait(60)  # silent until the reader gave up (however long a busy machine makes that)
                client.close()
            listener.close()

        thread = threading.Thread(target=serve, daemon=True)
        thread.start()
        said = {"silent": "no data for 0.5 s; the server is connected but sends nothing", "reset": "reset|cut|ends",
                "reset at once": "reset the connection before sending anything"}[behaviour]  # (not "mid-stream")
        with pytest.raises(FormatError, match=said):
            with open_events(f"tcp://127.0.0.1:{port}", read_timeout_s=0.5) as stream:
                for _ in stream:
                    pass
        finished.set()
        thread.join(5)


def test_the_timeout_option_bounds_a_silent_server_from_the_command_line(tmp_path):
    """`evtools --timeout 300ms info tcp://...` against a server that accepts and never sends: exit 1, one line
    naming the address and the wait; a bad duration is a usage error (2)."""
    import socket

    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    port = listener.getsockname()[1]
    try:
        done = subprocess.run([*EVTOOLS, "--timeout", "300ms", "info", f"tcp://127.0.0.1:{port}"], capture_output=True,
                              text=True, env=_environment(), cwd=ROOT, timeout=60)
    finally:
        listener.close()
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert f"127.0.0.1:{port}" in done.stderr and "no data for 0.3 s" in done.stderr, done.stderr
    bad = subprocess.run([*EVTOOLS, "--timeout", "soon", "info", f"tcp://127.0.0.1:{port}"], capture_output=True,
                         text=True, env=_environment(), cwd=ROOT)
    assert bad.returncode == 2 and "--timeout" in bad.stderr


def test_a_client_waiting_from_the_start_gets_the_whole_stream_and_no_client_is_said(tmp_path):
    """Issue 39 item 4: ``-o tcp://`` listens from the command's start, before its input is opened, so a client that
    connects while the input is not there yet gets every event (it listened only once the first output was ready:
    a waiting client missed the first packets); at the end the server says whom it served, and a stream served
    to nobody is a warning, not a silent success."""
    events, _ = evtools.simulate("bars", size=(WIDTH, HEIGHT), duration_us=500_000, seed=5)
    recording = tmp_path / "bars.aedat4"
    evtools.write(recording, events, evtools.StreamInfo(WIDTH, HEIGHT))
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    port = _free_port()
    stage = subprocess.Popen([EVTOOLS[0], "bafilter", str(fifo), "-o", f"tcp://127.0.0.1:{port}"],
                             stderr=subprocess.PIPE, text=True, env=_environment(), cwd=ROOT)
    try:
        deadline, client = time.monotonic() + 60, None
        while client is None:  # the stage is waiting for its input: a state, whatever the machine's load
            assert time.monotonic() < deadline and stage.poll() is None
            try:
                client = socket.create_connection(("127.0.0.1", port), timeout=60)
            except OSError:
                time.sleep(0.05)
        stream = bytearray()
        thread = threading.Thread(target=_received_bytes, args=(client, stream), daemon=True)
        thread.start()
        with open(fifo, "wb") as feed:
            feed.write(recording.read_bytes())
        assert stage.wait(timeout=60) == 0
        thread.join(timeout=60)
        stderr = stage.stderr.read()
    finally:
        stage.kill()
        stage.wait()
    (tmp_path / "received.aedat4").write_bytes(b"#!AER-DAT4.0\r\n" + bytes(stream))
    assert_same_events(evtools.read(tmp_path / "received.aedat4")[0],
                       evtools.bafilter(events, (WIDTH, HEIGHT)))
    assert "served 1 client" in stderr and "(the whole stream)" in stderr, stderr
    nobody = subprocess.run([EVTOOLS[0], "convert", str(recording), "-o", f"tcp://127.0.0.1:{_free_port()}"],
                            capture_output=True, text=True, env=_environment(), cwd=ROOT, timeout=60)
    assert nobody.returncode == 0 and "no client connected: the stream went to nobody" in nobody.stderr


def test_a_client_waiting_for_the_header_gets_it_before_any_event(tmp_path):
    """A client that connects to `-o tcp://` before the stage has its input's header gets the header (the sensor
    size) as soon as the stage has it, not with the first events (which may be long in coming): dv-processing's
    NetworkReader waits for the header in its constructor, and under load it waited for events that its own
    process's writer had not sent yet."""
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    port = _free_port()
    stage = subprocess.Popen([EVTOOLS[0], "-q", "convert", str(fifo), "-o", f"tcp://127.0.0.1:{port}"],
                             stderr=subprocess.PIPE, text=True, env=_environment(), cwd=ROOT)
    try:
        deadline, client = time.monotonic() + 60, None
        while client is None:
            assert time.monotonic() < deadline and stage.poll() is None
            try:
                client = socket.create_connection(("127.0.0.1", port), timeout=60)
            except OSError:
                time.sleep(0.05)
        header = (tmp_path / "h.aedat4")
        evtools.write(header, evtools.make_events([], [], [], []), evtools.StreamInfo(WIDTH, HEIGHT))
        with open(fifo, "wb") as feed:
            data = header.read_bytes()
            (length,) = struct.unpack_from("<I", data, 14)
            feed.write(data[:18 + length])  # the header alone: no event yet
            feed.flush()
            received = b""
            while len(received) < 4 + length:  # the header arrives while the input is still open (a state)
                piece = client.recv(1 << 16)
                assert piece, "the server closed"
                received += piece
            assert received[4:4 + length] == data[18:18 + length]
            feed.write(data[18 + length:])  # then the rest (its end mark): the stream ends normally
        assert stage.wait(timeout=60) == 0
    finally:
        stage.kill()
        stage.wait()
        if client is not None:
            client.close()


def test_a_client_that_stops_reading_holds_up_no_one():
    """A QA sweep: the server sent to its clients one after another, blocking, under its lock: a client that never
    reads froze every other client and the stage for 5 s (a 5 s replay took 8.2 s). Each client now has its own
    sender: the reading client gets all of a large flush while the stalled one is still connected."""
    from evtools.formats.io import TcpServer
    from tests.helpers import wait_until

    server = TcpServer(f"tcp://127.0.0.1:{_free_port()}")
    port = server.listener.getsockname()[1]
    stalled = socket.socket()
    stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    stalled.connect(("127.0.0.1", port))
    wait_until(lambda: len(server.served) == 1, "the stalled client to be accepted")
    healthy = socket.create_connection(("127.0.0.1", port))
    wait_until(lambda: len(server.served) == 2, "the reading client to be accepted")
    header, payload = b"H" * 10, b"x" * (16 << 20)  # far beyond what the stalled client's buffers take
    server.write(header)
    received = []

    def read() -> None:
        while sum(map(len, received)) < len(header) + len(payload):
            part = healthy.recv(1 << 20)
            if not part:
                return
            received.append(part)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    server.write(payload)
    server.flush()
    wait_until(lambda: sum(map(len, received)) == len(header) + len(payload), "the reading client's stream")
    assert not any(dropped for _, _, dropped in server.served.values())  # (the stalled one is still there)
    server.close()
    assert b"".join(received) == header + payload
    stalled.close()
    healthy.close()


def test_a_client_that_keeps_sending_does_not_keep_the_server_from_ending():
    """A QA sweep: at its end the server drained each client until it closed, 5 s a client one after another (3
    idle viewers: 17 s to stop), and without end for a client that sent a byte a second. It now ends every
    client's stream at once and waits at most HANG_UP_S in all."""
    from evtools.formats.io import TcpServer
    from tests.helpers import wait_until

    server = TcpServer(f"tcp://127.0.0.1:{_free_port()}")
    port = server.listener.getsockname()[1]
    chatty = socket.create_connection(("127.0.0.1", port))
    idle = [socket.create_connection(("127.0.0.1", port)) for _ in range(3)]
    wait_until(lambda: len(server.served) == 4, "the clients to be accepted")
    server.write(b"H" * 10)
    server.write(b"x" * 1000)
    server.flush()
    talking = threading.Event()

    def talk() -> None:
        with contextlib.suppress(OSError):
            while not talking.is_set():
                chatty.sendall(b".")
                time.sleep(0.05)

    threading.Thread(target=talk, daemon=True).start()
    received = []

    def read() -> None:  # (while the server ends: a close with the client's bytes unread resets the connection)
        with contextlib.suppress(OSError):
            while part := chatty.recv(1 << 16):
                received.append(part)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    wait_until(lambda: sum(map(len, received)) == 1010, "the chatty client's stream")
    closed = threading.Event()
    threading.Thread(target=lambda: (server.close(), closed.set()), daemon=True).start()
    try:
        wait_until(closed.is_set, "the server to end while a client keeps sending")
    finally:
        talking.set()
    reader.join(60)
    assert b"".join(received) == b"H" * 10 + b"x" * 1000  # (its stream whole, then ended)
    for sock in (chatty, *idle):
        sock.close()


def _connections_to(port: int) -> int:
    """How many connections to the local ``port`` are established (Linux's /proc/net/tcp: a state, not a time)."""
    count = 0
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError), open(table) as file:
            for line in file.readlines()[1:]:
                local, state = line.split()[1], line.split()[3]
                count += state == "01" and int(local.split(":")[1], 16) == port
    return count


def _connected_to(port: int) -> bool:
    return _connections_to(port) > 0


DV_CLIENT = """
import sys, time
import numpy as np
import dv_processing as dv
port, out = int(sys.argv[1]), sys.argv[2]
deadline = time.monotonic() + 60
while True:
    try:
        reader = dv.io.NetworkReader("127.0.0.1", port)  # (waits for the header; holds its process's GIL)
        break
    except RuntimeError:
        if time.monotonic() > deadline:
            raise
        time.sleep(0.05)
pieces = []
while True:
    running = reader.isRunning()
    batch = reader.getNextEventBatch()
    if batch is not None and len(batch):
        pieces.append(batch.numpy())
    elif not running:
        break
    else:
        time.sleep(0.001)
a = np.concatenate(pieces)
np.savez(out, t=a["timestamp"], x=a["x"], y=a["y"], p=a["polarity"], size=np.array(reader.getEventResolution()))
"""


def test_a_dv_client_reads_the_served_events_of_a_recording_with_imu_and_triggers(tmp_path):
    """A QA sweep: serving a DV recording with IMU and trigger streams declared them in the network header, and dv's
    NetworkReader, which reads one stream, took the IMU's type and failed on the first event packet. A network
    output serves the events alone, as DV's does, and says what it leaves out: a plain socket gets every event,
    and dv's reader reads them without error (all but what it drops with the connection's end, a dv quirk that
    load makes likelier: the README)."""
    from tests.conftest import data_file
    from tests.helpers import wait_until

    recording = data_file("dvxplorer_sample.aedat4")
    events, info = evtools.read(recording)
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    port = _free_port()
    stage = subprocess.Popen([EVTOOLS[0], "convert", str(fifo), "-o", f"tcp://127.0.0.1:{port}"],
                             stderr=subprocess.PIPE, text=True, env=_environment(), cwd=ROOT)
    client = subprocess.Popen([sys.executable, "-c", DV_CLIENT, str(port), str(tmp_path / "got.npz")],
                              stderr=subprocess.PIPE, text=True)
    raw = bytearray()
    try:
        plain = None
        while plain is None:  # (the stage listens once started: a state, whatever the machine's load)
            assert stage.poll() is None
            try:
                plain = socket.create_connection(("127.0.0.1", port), timeout=60)
            except OSError:
                time.sleep(0.05)
        reader = threading.Thread(target=_received_bytes, args=(plain, raw), daemon=True)
        reader.start()
        wait_until(lambda: _connections_to(port) >= 2, "both clients to connect (they then wait for the header)")
        with open(fifo, "wb") as feed:
            feed.write(recording.read_bytes())
        assert stage.wait(timeout=60) == 0
        assert client.wait(timeout=60) == 0, client.stderr.read()
        reader.join(60)
        stderr = stage.stderr.read()
    finally:
        for process in (stage, client):
            process.kill()
            process.wait()
    (tmp_path / "raw.aedat4").write_bytes(b"#!AER-DAT4.0\r\n" + bytes(raw))
    served, served_info = evtools.read(tmp_path / "raw.aedat4")
    assert_same_events(served, events)
    assert not served_info.metadata.get("side_streams") and not served_info.metadata.get("frame_size")
    got = np.load(tmp_path / "got.npz")
    dv_events = evtools.make_events(got["t"], got["x"], got["y"], got["p"])
    assert tuple(got["size"]) == (info.width, info.height) and 0 < len(dv_events) <= len(events)
    assert_same_events(dv_events, events[:len(dv_events)])
    assert "serves the events alone" in stderr and "IMU and trigger streams are left out" in stderr, stderr


def test_outputs_a_network_cannot_carry_are_usage_errors(tmp_path):
    """A QA sweep: `estimate -o tcp://` and `simulate --truth tcp://` handed h5py the server (a traceback, and
    simulate's -o lost), several inputs with `-o tcp://` made a folder `tcp:/HOST:PORT/` and served nothing (exit
    0), and `--timeout 1e10s` overflowed the socket's timeout (a traceback). Each is now a usage error, nothing
    written."""
    samples = ROOT / "samples"
    port = _free_port()
    cases = [
        (["estimate", samples / "flicker.aedat4", "--method", "stimulus", "-o", f"tcp://127.0.0.1:{port}"],
         "the thresholds map is HDF5"),
        (["simulate", "scene:step", "--duration", "100ms", "--size", "8x8", "-o", tmp_path / "x.aedat4", "--truth",
          f"tcp://127.0.0.1:{port}"], "the truth is HDF5"),
        (["convert", samples / "step.aedat4", samples / "flicker.aedat4", "-o", f"tcp://127.0.0.1:{port}"],
         "a network output serves one stream"),
        (["--timeout", "1e10s", "info", f"tcp://127.0.0.1:{port}"], "must be at most"),
    ]
    for argv, said in cases:
        done = subprocess.run([EVTOOLS[0], *map(str, argv)], capture_output=True, text=True, env=_environment(),
                              cwd=tmp_path, timeout=60)
        assert done.returncode == 2 and said in done.stderr and "Traceback" not in done.stderr, (argv, done.stderr)
    assert list(tmp_path.iterdir()) == []


def _ipv6_loopback() -> bool:
    try:
        with socket.socket(socket.AF_INET6) as probe:
            probe.bind(("::1", 0))
        return True
    except OSError:
        return False


@pytest.mark.skipif(not _ipv6_loopback(), reason="this machine has no IPv6 loopback")
def test_a_network_output_listens_on_ipv6_too():
    """A QA sweep: `-o tcp://[::1]:PORT` could not listen (the address family was not given), and `tcp://:PORT`
    ("every interface") listened on IPv4 alone."""
    from evtools.formats.io import TcpServer
    from tests.helpers import wait_until

    for name, client_host in ((f"tcp://[::1]:{_free_port()}", "::1"), (f"tcp://:{_free_port()}", "::1"),
                              (f"tcp://:{_free_port()}", "127.0.0.1")):
        server = TcpServer(name)
        port = int(name.rsplit(":", 1)[1])
        client = socket.create_connection((client_host, port), timeout=60)
        wait_until(lambda: len(server.served) == 1, f"{client_host} to be accepted by {name}")
        server.write(b"header")
        server.close()
        received = b""
        while part := client.recv(1 << 16):
            received += part
        assert received == b"header", name
        client.close()


def test_a_stop_ends_a_network_input_at_once_and_is_no_cut(tmp_path):
    """A QA sweep: Ctrl-C on a command reading another evtools' `-o tcp://` read on for a second (as for a pipe,
    whose writer the same Ctrl-C stops) although the server goes on, and most runs warned that the stream ended
    without its end mark, "cut", while the output said it was whole. A network input's stop is its end."""
    from tests.helpers import wait_until

    events, _ = evtools.simulate("bars", size=(WIDTH, HEIGHT), duration_us=20_000_000, seed=5)
    recording = tmp_path / "bars.aedat4"
    evtools.write(recording, events, evtools.StreamInfo(WIDTH, HEIGHT))
    port = _free_port()
    server = subprocess.Popen([EVTOOLS[0], "convert", str(recording), "--realtime", "-o", f"tcp://127.0.0.1:{port}"],
                              stderr=subprocess.PIPE, text=True, env=_environment(), cwd=ROOT)
    client = None
    try:
        _wait_for_server(port, server)
        output = tmp_path / "out.aedat4"
        client = subprocess.Popen([EVTOOLS[0], "bafilter", f"tcp://127.0.0.1:{port}", "-o", str(output)],
                                  stderr=subprocess.PIPE, text=True, env=_environment(), cwd=ROOT)
        # its output is made once the input's header came (a stop before any data leaves none, by design)
        wait_until(lambda: any(p.name != "bars.aedat4" for p in tmp_path.iterdir()), "the client's output begun")
        client.send_signal(signal.SIGINT)
        assert client.wait(timeout=60) == 130
        stderr = client.stderr.read()
    finally:
        for process in (client, server):
            if process is not None:
                process.kill()
                process.wait()
    assert "end mark" not in stderr and "Traceback" not in stderr, stderr
    assert not evtools.read(output)[1].metadata.get("cut"), stderr


def test_a_header_of_impossible_length_is_damage_at_once():
    """A QA sweep: an AEDAT 4.0 header whose length field said 1 GiB made a network input wait out --timeout for it,
    then say the server "sends nothing". A length no header has is damage, said at once."""
    from evtools.formats import open_events
    from evtools.formats.errors import FormatError

    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    port = listener.getsockname()[1]
    finished = threading.Event()

    def serve():
        client, _ = listener.accept()
        client.sendall(struct.pack("<I", 1 << 30) + struct.pack("<I", 16) + b"IOHE" + bytes(500))
        finished.wait(60)  # silent after it: the old reader waited for the rest until its timeout
        client.close()
        listener.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        with pytest.raises(FormatError, match="its header says it holds 1,073,741,824 bytes"):
            with open_events(f"tcp://127.0.0.1:{port}", read_timeout_s=60) as stream:
                for _ in stream:
                    pass
    finally:
        finished.set()
        thread.join(5)
