"""Progress on stderr, shown only when stderr is a terminal (never in pipes, Makefiles or CI logs)."""

from __future__ import annotations

import os
import sys
from typing import Iterator

import numpy as np


def with_progress(chunks, stream, label: str) -> Iterator[np.ndarray]:
    """Yield ``chunks`` unchanged, showing events done (and bytes read of a file) in a rich progress bar."""
    if not sys.stderr.isatty():
        yield from chunks
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    total = os.path.getsize(stream.source.path) if stream.source.path else None
    columns = [TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[events]:,} events")]
    if total:
        columns.append(TimeRemainingColumn())
    with Progress(*columns, transient=True, console=_stderr_console()) as progress:
        task = progress.add_task(label, total=total, events=0)
        events = 0
        for chunk in chunks:
            events += len(chunk)
            position = stream.source.stream.tell() if total else None
            progress.update(task, completed=position, events=events)
            yield chunk


def _stderr_console():
    from rich.console import Console

    return Console(stderr=True)


def consume(stream, consumer, label: str) -> None:
    """Feed every chunk of ``stream`` to ``consumer.process`` (an estimator, a scorer: nothing is written), with
    progress labelled ``label``; a consumer with ``add_frames`` also gets the stream's APS frames as they are read
    (each after the chunk that reached it) and the rest at the end."""
    add_frames = getattr(consumer, "add_frames", None)
    for chunk in with_progress(stream, stream, label):
        consumer.process(chunk)
        if add_frames is not None:
            add_frames(stream.take_frames())
    if add_frames is not None:
        add_frames(stream.take_frames())


def process_stream(stream, processor, writer, label: str) -> tuple[int, int]:
    """Feed every chunk of ``stream`` through ``processor`` (``process`` then ``flush``) into ``writer``, with
    progress labelled ``label``; empty results are not written. The stream's APS frames are passed on untouched,
    each once the output is final up to its time (``processor.released_us(last input time)``, where the processor
    holds events back). Returns (events in, events out)."""
    from evtools.frames import FrameRelay

    events_in = events_out = 0
    frames = FrameRelay(stream, writer)
    released = getattr(processor, "released_us", lambda last_us: last_us)
    # the output in parts where the processor gives it so (a corrector may release millions of events at once)
    process_parts = getattr(processor, "process_parts", lambda chunk: [processor.process(chunk)])
    flush_parts = getattr(processor, "flush_parts", lambda: [processor.flush()])
    for chunk in with_progress(stream, stream, label):
        events_in += len(chunk)
        for out in process_parts(chunk):
            events_out += len(out)
            if len(out):
                frames.write(out)
        frames.release(released(int(chunk["t"][-1])))
    for rest in flush_parts():
        events_out += len(rest)
        if len(rest):
            frames.write(rest)
    frames.release(None)
    writer.cut = getattr(stream, "was_cut", False)  # a cut input's output ends without the end mark too
    return events_in, events_out
