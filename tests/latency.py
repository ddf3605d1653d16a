"""Latency through a pipeline of evtools commands (issue 16), shared by the test and the benchmark.

The caller is the camera: it writes an AEDAT 4.0 stream into the first stage's stdin one packet per
``packet_us`` of event time, each packet when its time has come on the wall clock. The last stage writes CSV
into a FIFO that a thread reads, noting when each byte arrived. An output event at time t "entered" when the
first input packet reaching t was written; its latency is its arrival minus that moment.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from evtools.formats.aedat4 import Aedat4Writer
from evtools.formats.registry import WriteOptions
from tests.helpers import wait_until_waiting_for_input

EVTOOLS = str(Path(sys.executable).with_name("evtools"))


class _NetworkBuffer(io.BytesIO):
    network = True  # the AEDAT 4.0 writer leaves out the file's first line: a stream as a camera serves it


def paced_packets(events: np.ndarray, info, packet_us: int) -> tuple[bytes, list[bytes], np.ndarray, bytes]:
    """The stream's header, its packets (one per ``packet_us`` of event time), each packet's last event time, and
    the writer's end mark (sent after the last packet)."""
    buffer = _NetworkBuffer()
    writer = Aedat4Writer(buffer, info, WriteOptions())
    header = buffer.getvalue()
    edges = np.searchsorted(events["t"], np.arange(events["t"][0], events["t"][-1] + packet_us, packet_us), "right")
    packets, last_t_us, start = [], [], 0
    for end in edges:
        if end > start:
            before = buffer.tell()
            writer.write(events[start:end])
            writer.flush()
            packets.append(buffer.getvalue()[before:])
            last_t_us.append(int(events["t"][end - 1]))
            start = end
    before = buffer.tell()
    writer.close()
    return header, packets, np.array(last_t_us), buffer.getvalue()[before:]


def _read_fifo(path: str, arrivals: list) -> None:
    with open(path, "rb", buffering=0) as fifo:
        while data := fifo.read(1 << 20):
            arrivals.append((time.monotonic(), data))


def pipeline_latency_ms(stages: list[list[str]], header: bytes, packets: list[bytes], last_t_us: np.ndarray,
                        end_mark: bytes, folder: Path, env=None) -> np.ndarray:
    """Runs ``evtools STAGE[0] - | evtools STAGE[1] - | ... -o FIFO.csv`` fed at the events' own pace; the
    latency of every output event in ms (raises if a stage fails)."""
    fifo = str(folder / "latency-out.csv")
    os.mkfifo(fifo)
    arrivals: list = []
    reader = threading.Thread(target=_read_fifo, args=(fifo, arrivals), daemon=True)
    reader.start()
    processes, upstream = [], subprocess.PIPE
    for index, stage in enumerate(stages):
        last = index == len(stages) - 1
        process = subprocess.Popen([EVTOOLS, "-q", *stage, "-", "-o", fifo if last else "-"], stdin=upstream,
                                   stdout=None if last else subprocess.PIPE, stderr=subprocess.PIPE, env=env)
        if processes:
            processes[-1].stdout.close()  # the next stage holds it now
        processes.append(process)
        upstream = process.stdout
    source = processes[0].stdin
    source.write(header)
    source.flush()
    for process in processes:  # every stage started (imports done, the header read) before the clock starts
        wait_until_waiting_for_input(process)
    start = time.monotonic()
    sent_s = np.empty(len(packets))
    for index, packet in enumerate(packets):
        due = start + (last_t_us[index] - last_t_us[0]) / 1e6
        if (wait := due - time.monotonic()) > 0:
            time.sleep(wait)
        source.write(packet)
        source.flush()
        sent_s[index] = time.monotonic()
    source.write(end_mark)  # the stream ends whole (a stream cut short is an error downstream)
    source.close()
    for process in processes:
        errors = process.stderr.read()
        if process.wait(timeout=60):
            raise AssertionError(f"{process.args}: exit {process.returncode}: {errors.decode()}")
    reader.join(timeout=60)
    return _latencies_ms(arrivals, sent_s, last_t_us)


def _latencies_ms(arrivals: list, sent_s: np.ndarray, last_t_us: np.ndarray) -> np.ndarray:
    times_us, arrived_s, carry = [], [], b""
    for moment, data in arrivals:
        lines = (carry + data).split(b"\n")
        carry = lines.pop()
        for line in lines:
            field = line.split(b",", 1)[0]
            if field.isdigit():  # skips the header line
                times_us.append(int(field))
                arrived_s.append(moment)
    packet = np.minimum(np.searchsorted(last_t_us, np.array(times_us, dtype=np.int64), "left"), len(sent_s) - 1)
    return (np.array(arrived_s) - sent_s[packet]) * 1e3
