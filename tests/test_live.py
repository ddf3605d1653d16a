"""Live streams (issue 16): a pipe is passed on as it arrives, not when it ends; live outputs flush what each chunk
brought; the events are the same as file to file. Outputs that are not regular files (a FIFO, /dev/null, a
symbolic link) are written through, never replaced (issue 19)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import evtools
from evtools.events import EVENT_DTYPE, join
from tests.helpers import assert_same_events, cut, wait_until, wait_until_waiting_for_input

ROOT = Path(__file__).resolve().parents[1]
EVTOOLS = [str(Path(sys.executable).with_name("evtools")), "-q"]
PARTS, PAUSE_S = 4, 1.0  # a pause 10x the 100 ms latency target: load slows the stages, it cannot break this

FEED = """
import sys, time
data = open(sys.argv[1], "rb").read()
parts, pause = int(sys.argv[2]), float(sys.argv[3])
step = len(data) // parts
for i in range(parts):
    print(time.monotonic(), file=sys.stderr, flush=True)  # before the write: what it sends cannot arrive earlier
    sys.stdout.buffer.write(data[i * step: (i + 1) * step if i < parts - 1 else len(data)])
    sys.stdout.buffer.flush()
    time.sleep(pause)
"""

SINK = """
import sys, time
from evtools.formats import open_events
with open_events("-") as stream:
    for chunk in stream:
        print(time.monotonic(), len(chunk), flush=True)
"""


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """An AEDAT 4.0 file of several packets (32,768 events each)."""
    events, _ = evtools.simulate("bars", size=(64, 48), duration_us=1_500_000, seed=3)
    assert len(events) > 4 * 32_768
    path = tmp_path_factory.mktemp("live") / "bars.aedat4"
    evtools.write(path, events, evtools.StreamInfo(64, 48))
    return path


def _environment():
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def test_a_paced_pipe_leaves_the_pipeline_as_it_arrives(recording, tmp_path):
    """Fed in four parts 1 s apart through convert | bafilter: events of each part come out before the next part
    is fed (readers used to wait for a million events, i.e. for the end), and they are the file-to-file events."""
    env = _environment()
    feed = subprocess.Popen([sys.executable, "-c", FEED, str(recording), str(PARTS), str(PAUSE_S)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    convert = subprocess.Popen([*EVTOOLS, "convert", "-", "-o", "-"], stdin=feed.stdout, stdout=subprocess.PIPE,
                               env=env, cwd=ROOT)
    feed.stdout.close()
    bafilter = subprocess.Popen([*EVTOOLS, "bafilter", "-", "-o", "-"], stdin=convert.stdout,
                                stdout=subprocess.PIPE, env=env, cwd=ROOT)
    convert.stdout.close()
    sink = subprocess.run([sys.executable, "-c", SINK], stdin=bafilter.stdout, capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=120)
    bafilter.stdout.close()
    for process in (feed, convert, bafilter):
        assert process.wait(timeout=60) == 0
    fed = [float(line) for line in feed.stderr.read().decode().split()]
    arrivals = [(float(t), int(n)) for t, n in (line.split() for line in sink.stdout.splitlines())]
    assert sink.returncode == 0, sink.stderr
    assert len(fed) == PARTS
    for k in range(PARTS - 1):  # something of part k arrived before part k + 1 was fed
        assert any(fed[k] <= t < fed[k + 1] for t, _ in arrivals), (k, fed, arrivals)
    expected = tmp_path / "expected.aedat4"
    subprocess.run([*EVTOOLS, "bafilter", str(recording), "-o", str(expected)], check=True, env=env, cwd=ROOT)
    assert sum(n for _, n in arrivals) == len(evtools.read(expected)[0])


def _packets_of(events: np.ndarray, sizes: list[int]) -> bytes:
    """An AEDAT 4.0 stream (file form) whose event packets hold ``sizes`` events each."""
    from evtools.formats.aedat4 import Aedat4Writer
    from evtools.formats.registry import WriteOptions

    import io as std_io

    buffer = std_io.BytesIO()
    writer = Aedat4Writer(buffer, evtools.StreamInfo(64, 48), WriteOptions())
    for begin, size in zip(np.cumsum([0, *sizes[:-1]]), sizes):
        writer.write(events[begin:begin + size])
        writer.flush()
    return buffer.getvalue()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("max_latency_s", [0.0, 5.0])
def test_packets_that_arrived_together_go_on_together(recording, tmp_path, max_latency_s):
    """Ten packets written into a FIFO at once, the writer then waiting: with the default bound they come out as
    one chunk, before the input ends (a stage that fell behind catches up in one step); with a bound of 0 each
    packet is its own chunk."""
    from evtools.formats import ReadOptions, open_events

    events = evtools.read(recording)[0][:1000]
    data = _packets_of(events, [100] * 10)
    fifo = tmp_path / "in.fifo"
    os.mkfifo(fifo)
    writer_fd = os.open(fifo, os.O_RDWR)  # holds the FIFO open: the input does not end
    try:
        os.write(writer_fd, data)
        with open_events(str(fifo), ReadOptions(max_latency_s=max_latency_s)) as stream:
            chunks = iter(stream)
            first = next(chunks)
            if max_latency_s:
                assert len(first) == 1000
            else:
                assert len(first) == 100
                assert [len(next(chunks)) for _ in range(9)] == [100] * 9
    finally:
        os.close(writer_fd)


def test_a_csv_pipe_is_passed_on_as_its_lines_arrive(recording, tmp_path):
    """CSV on a pipe, fed in two parts 1 s apart: the first part's events are read before the second is fed,
    and all of them are those of the file."""
    env = _environment()
    text = tmp_path / "bars.csv"
    subprocess.run([*EVTOOLS, "convert", str(recording), "-o", str(text)], check=True, env=env, cwd=ROOT)
    feed = subprocess.Popen([sys.executable, "-c", FEED, str(text), "2", str(PAUSE_S)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env)
    sink = subprocess.run([sys.executable, "-c", SINK], stdin=feed.stdout, capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=120)
    feed.stdout.close()
    assert feed.wait(timeout=60) == 0 and sink.returncode == 0, sink.stderr
    fed = [float(line) for line in feed.stderr.read().decode().split()]
    arrivals = [(float(t), int(n)) for t, n in (line.split() for line in sink.stdout.splitlines())]
    assert any(fed[0] <= t < fed[1] for t, _ in arrivals), (fed, arrivals)
    assert sum(n for _, n in arrivals) == len(evtools.read(recording)[0])


def test_a_live_pipe_gives_the_events_of_the_file(recording, tmp_path):
    """The same events whether the input is a file or a paced pipe, for a processor that holds events (correct)."""
    env = _environment()
    thresholds = tmp_path / "t.h5"
    subprocess.run([*EVTOOLS, "estimate", str(recording), "-o", str(thresholds)], check=True, env=env, cwd=ROOT)
    expected = tmp_path / "file.aedat4"
    subprocess.run([*EVTOOLS, "correct", str(recording), "--thresholds", str(thresholds), "-o", str(expected)],
                   check=True, env=env, cwd=ROOT)
    feed = subprocess.Popen([sys.executable, "-c", FEED, str(recording), "3", "0.2"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, env=env)
    live = tmp_path / "live.aedat4"
    subprocess.run([*EVTOOLS, "correct", "-", "--thresholds", str(thresholds), "-o", str(live)], stdin=feed.stdout,
                   check=True, env=env, cwd=ROOT, timeout=120)
    feed.stdout.close()
    assert feed.wait(timeout=60) == 0
    assert_same_events(evtools.read(live)[0], evtools.read(expected)[0])


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_outputs_that_are_not_regular_files_are_written_through(recording, tmp_path):
    """A FIFO gets the stream (not replaced by a file), /dev/null stays a device, a symbolic link stays a link and
    its target gets the output."""
    env = _environment()
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    reader = subprocess.Popen([sys.executable, "-c", f"import sys; sys.stdout.write(str(len(open({str(fifo)!r}, 'rb').read())))"],
                              stdout=subprocess.PIPE, text=True)
    subprocess.run([*EVTOOLS, "convert", str(recording), "-o", str(fifo), "--format", "aedat4"], check=True,
                   env=env, cwd=ROOT, timeout=120)
    assert int(reader.communicate(timeout=60)[0]) == recording.stat().st_size
    assert fifo.is_fifo()
    subprocess.run([*EVTOOLS, "convert", str(recording), "-o", "/dev/null", "--format", "aedat4"], check=True,
                   env=env, cwd=ROOT)
    assert Path("/dev/null").is_char_device()
    target, link = tmp_path / "target.csv", tmp_path / "link.csv"
    target.write_text("old")
    link.symlink_to(target)
    subprocess.run([*EVTOOLS, "convert", str(recording), "-o", str(link)], check=True, env=env, cwd=ROOT)
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert len(evtools.read(target)[0]) == len(evtools.read(recording)[0])


HOLD = """
import sys, time
data = open(sys.argv[1], "rb").read()
sys.stdout.buffer.write(data[: len(data) // 2])
sys.stdout.buffer.flush()
time.sleep(float(sys.argv[2]))  # the pipe stays open: the reader waits for more
"""


def _prefix_of(events, whole):
    assert 0 < len(events) <= len(whole)
    assert_same_events(events, whole[: len(events)])


@pytest.mark.parametrize("signal_number, code", [(2, 130), (15, 143)])
def test_a_stop_signal_ends_a_waiting_stage_with_its_output_complete(recording, tmp_path, signal_number, code):
    """Ctrl-C (SIGINT) or SIGTERM while bafilter waits on a live pipe that stays open: it stops waiting, writes
    every event it processed into a complete, readable file and exits 130 / 143 with one line, no traceback."""
    env = _environment()
    expected = tmp_path / "expected.aedat4"
    subprocess.run([*EVTOOLS, "bafilter", str(recording), "-o", str(expected)], check=True, env=env, cwd=ROOT)
    whole = evtools.read(expected)[0]
    feed = subprocess.Popen([sys.executable, "-c", HOLD, str(recording), "60"], stdout=subprocess.PIPE, env=env)
    out = tmp_path / "out.aedat4"
    stage = subprocess.Popen([*EVTOOLS, "bafilter", "-", "-o", str(out)], stdin=feed.stdout,
                             stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    try:
        wait_until_waiting_for_input(stage, feed.stdout)  # the first half is read and filtered
        feed.stdout.close()
        stage.send_signal(signal_number)
        assert stage.wait(timeout=20) == code
    finally:
        feed.kill()
        stage.kill()
    stderr = stage.stderr.read()
    assert "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert "stopped by" in stderr
    _prefix_of(evtools.read(out)[0], whole)
    assert not list(tmp_path.glob(".*tmp*")) and not list(tmp_path.glob("*.tmp*"))


def test_ctrl_c_on_a_live_pipeline_leaves_its_file_complete(recording, tmp_path):
    """Ctrl-C reaches every stage of `feed | convert | bafilter -o FILE` (one process group, as a terminal sends
    it): the last stage's file is readable and holds a prefix of the stream, and every evtools stage exits 130.
    The feed, an evtools stream killed inside a packet, was cut: each stage reads on to its writer's end
    (STOP_DRAIN_SECONDS) and passes the cut on (it once took its own stop for the stream's end: marked whole)."""
    env = _environment()
    expected = tmp_path / "expected.aedat4"
    subprocess.run([*EVTOOLS, "bafilter", str(recording), "-o", str(expected)], check=True, env=env, cwd=ROOT)
    out = tmp_path / "out.aedat4"
    feed = subprocess.Popen([sys.executable, "-c", HOLD, str(recording), "60"], stdout=subprocess.PIPE, env=env,
                            process_group=0)
    group = dict(process_group=feed.pid, env=env, cwd=ROOT, stderr=subprocess.PIPE, text=True)
    convert = subprocess.Popen([*EVTOOLS, "convert", "-", "-o", "-"], stdin=feed.stdout, stdout=subprocess.PIPE,
                               **group)
    bafilter = subprocess.Popen([*EVTOOLS, "bafilter", "-", "-o", str(out)], stdin=convert.stdout, **group)
    try:
        wait_until_waiting_for_input(convert, feed.stdout)
        wait_until_waiting_for_input(bafilter, convert.stdout)
        feed.stdout.close()
        convert.stdout.close()
        os.killpg(feed.pid, 2)
        assert bafilter.wait(timeout=20) == 130
        assert convert.wait(timeout=20) in (130, 141)  # 141: bafilter had gone when it flushed
    finally:
        for process in (feed, convert, bafilter):
            process.kill()
    for process in (convert, bafilter):
        assert "Traceback" not in process.stderr.read()
    _prefix_of(evtools.read(out)[0], evtools.read(expected)[0])
    assert json.loads(subprocess.run([*EVTOOLS, "info", str(out), "--json"], capture_output=True, env=env,
                                     cwd=ROOT).stdout)["cut"]


def _written_bytes(folder: Path, out: Path) -> int:
    """The size of the output being written (its temporary beside it), 0 before it exists."""
    sizes = [path.stat().st_size for path in folder.glob(f".{out.name}.*.part")]
    return max(sizes, default=0)


def _empty_file_bytes(folder: Path) -> int:
    """The size of an AEDAT 4.0 file without events: its header and end mark."""
    path = folder / "empty.aedat4"
    if not path.exists():
        evtools.write(path, np.zeros(0, EVENT_DTYPE), evtools.StreamInfo(64, 48))
    return path.stat().st_size


@pytest.mark.parametrize("signal_number, code", [(2, 130), (15, 143)])
def test_a_stop_halfway_through_a_file_to_file_run_leaves_a_whole_file(recording, tmp_path, signal_number, code):
    """A file-to-file run stopped halfway (a replay at recorded speed, so that halfway is a known time): the output
    is a complete AEDAT 4.0 file, read back by evtools and by dv-processing, with the recording's first events."""
    out = tmp_path / "out.aedat4"
    stage = subprocess.Popen([*EVTOOLS, "convert", str(recording), "-o", str(out), "--realtime", "--speed", "0.5"],
                             stderr=subprocess.PIPE, text=True, env=_environment(), cwd=ROOT)
    try:  # the stage is halfway once its output holds events (a replay at half speed lasts 3 s)
        wait_until(lambda: _written_bytes(tmp_path, out) > _empty_file_bytes(tmp_path), "events in the output")
        assert stage.poll() is None
        stage.send_signal(signal_number)
        assert stage.wait(timeout=20) == code
    finally:
        stage.kill()
    assert "Traceback" not in stage.stderr.read()
    whole = evtools.read(recording)[0]
    kept = evtools.read(out)[0]
    _prefix_of(kept, whole)
    assert len(kept) < len(whole)
    dv = pytest.importorskip("dv_processing", reason="dv-processing (the test extra) reads the file back")
    reader, count = dv.io.MonoCameraRecording(str(out)), 0
    while reader.isRunning():
        batch = reader.getNextEventBatch()
        count += len(batch) if batch is not None else 0
    assert count == len(kept)


def test_a_stop_before_any_stream_aborts_without_output(tmp_path):
    """Ctrl-C while a command still waits for its input's first bytes: nothing was processed, so nothing is
    written (no file under the output's name, no temporary left), exit 130."""
    env = _environment()
    feed = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], stdout=subprocess.PIPE, env=env)
    out = tmp_path / "out.aedat4"
    stage = subprocess.Popen([*EVTOOLS, "bafilter", "-", "-o", str(out)], stdin=feed.stdout, stderr=subprocess.PIPE,
                             text=True, env=env, cwd=ROOT)
    try:
        wait_until_waiting_for_input(stage, feed.stdout)
        feed.stdout.close()
        stage.send_signal(2)
        assert stage.wait(timeout=20) == 130
    finally:
        feed.kill()
        stage.kill()
    assert "Traceback" not in stage.stderr.read()
    assert list(tmp_path.iterdir()) == []


@settings(max_examples=30, deadline=None)
@given(times=st.lists(st.integers(0, 60_000), min_size=1, max_size=300), cuts=st.lists(st.integers(0, 300)),
       speed=st.sampled_from([0.5, 1.0, 3.0]))
def test_paced_releases_every_event_once_its_time_has_come(times, cuts, speed):
    """formats.io.paced on a fake clock: the same events in the same order, in slices of at most 5 ms of stream
    time, each released no earlier than its last event's time (from the first event, divided by the speed) and
    without waiting longer than that."""
    from evtools.events import make_events
    from evtools.formats.io import PACE_SLICE_US, paced

    t = np.sort(np.array(times, np.int64)) + 1_000_000
    events = make_events(t, np.zeros_like(t), np.zeros_like(t), np.ones_like(t))
    now, slept = [100.0], [False]

    def sleep(seconds):
        assert seconds > 0
        now[0] += seconds
        slept[0] = True

    released = []
    for piece in paced(cut(events, cuts), speed, clock=lambda: now[0], sleep=sleep):
        assert len(piece) and int(piece["t"][-1]) - int(piece["t"][0]) < PACE_SLICE_US
        due = 100.0 + (int(piece["t"][-1]) - int(t[0])) / 1e6 / speed
        assert now[0] >= due - 1e-9  # not before its time
        if slept[0]:
            assert now[0] == pytest.approx(due)  # and no later than needed
        slept[0] = False
        now[0] += 1e-4  # the consumer's work
        released.append(piece)
    assert_same_events(join(released), events)


def test_convert_realtime_takes_the_recordings_time(recording, tmp_path):
    """`convert --realtime` of a 1.5 s recording takes at least 1.5 s (a bound no load breaks; the pacing itself is
    checked exactly on a fake clock above), and --speed alone is a usage error."""
    env = _environment()
    t = evtools.read(recording)[0]["t"]
    started = time.monotonic()
    subprocess.run([*EVTOOLS, "convert", str(recording), "-o", str(tmp_path / "paced.aedat4"), "--realtime"],
                   check=True, env=env, cwd=ROOT)
    assert time.monotonic() - started >= (int(t[-1]) - int(t[0])) / 1e6
    assert_same_events(evtools.read(tmp_path / "paced.aedat4")[0], evtools.read(recording)[0])
    usage = subprocess.run([*EVTOOLS, "convert", str(recording), "-o", str(tmp_path / "x.aedat4"), "--speed", "2"],
                           capture_output=True, text=True, env=env, cwd=ROOT)
    assert usage.returncode == 2 and "--speed needs --realtime" in usage.stderr
