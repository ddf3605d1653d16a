"""``evtools convert``: any readable format to any writable one, streaming."""

from __future__ import annotations

import logging

import click

from evtools.cli.batch import Outcome, batch_options, plan, run
from evtools.cli.options import FiniteRange, check_compression, compression_option, slicing_options
from evtools.cli.progress import with_progress
from evtools.formats import create_events, open_events
from evtools.formats.io import paced
from evtools.formats.registry import FORMATS, by_name
from evtools.frames import FrameRelay
from evtools.transform import SlicedStream, transform_of

log = logging.getLogger("evtools")


@click.command()
@batch_options
@click.option(
    "--format", "output_format", default=None,
    type=click.Choice([f.name for f in FORMATS if f.writer], case_sensitive=False),
    help="Output format; default: from OUT's extension, AEDAT 4.0 on stdout and into a folder.",
)
@compression_option
@click.option("--realtime", is_flag=True,
              help="Replay at the recorded speed: events leave when their time has come (5 ms slices), so a "
                   "recording stands in for a camera.")
@click.option("--speed", type=FiniteRange(min=1e-6, max=1e6), default=None, metavar="X",
              help="With --realtime: X times the recorded speed (2: twice as fast; 1e-6 to 1e6).")
@slicing_options
def convert(inputs, reading, output, jobs, scheduler, as_json, output_format,
            compression, realtime, speed, slicing):
    """Convert IN (default stdin) to OUT or -o OUT (default stdout), chunk by chunk in bounded memory.

    Several inputs go to the folder -o FOLDER, each named after its input with --format's extension.

    \b
    evtools convert recording.aedat -o recording.h5
    evtools convert recording.aedat4 - | evtools convert - recording.csv
    evtools convert dataset/*.aedat -o converted/ --format hdf5 --jobs 4
    evtools convert recording.aedat4 - --realtime | evtools bafilter - -o -
    evtools convert recording.aedat4 -o part.aedat4 --start 2s --end 3.5s --crop 100,50,128,128 --flip-y
    """
    if speed is not None and not realtime:
        raise click.UsageError("--speed needs --realtime")
    if output and output.startswith("tcp://") and output_format not in (None, "aedat4"):
        raise click.UsageError(f"-o {output}: a network output carries AEDAT 4.0, not --format {output_format}")
    suffix = by_name(output_format or "aedat4").extensions[0]
    pairs = plan(inputs, output, suffix, check=lambda pairs: check_compression(compression, pairs, output_format))
    options = dict(reading=reading,
                   output_format=output_format, compression=compression, speed=speed or 1.0 if realtime else None,
                   slicing=slicing)
    run(convert_one, pairs, options, jobs, scheduler, as_json)


def convert_one(input, output, *, reading, output_format, compression, speed=None,
                slicing=None) -> Outcome:
    """Convert one file: its :class:`Outcome` (events in and out, whether it was read to its end); ``speed``:
    replayed at that many times the recorded speed; ``slicing``: :class:`evtools.transform.Transform`'s options
    (time slice, polarity, crop, flips, transpose)."""
    events_in = events_out = 0
    stopped = False
    with open_events(input, reading) as stream:
        transform = transform_of(stream, slicing) if slicing else None
        with create_events(
            output, transform.info if transform else stream.info, format=output_format, compression=compression,
            aedat2_layout=reading.aedat2_layout, inputs=(input,),
        ) as writer:
            chunks = stream if speed is None else paced(stream, speed)
            relayed = SlicedStream(stream, transform) if transform else stream  # (its frames, side packets, cut)
            frames = FrameRelay(relayed, writer)
            for chunk in with_progress(chunks, stream, f"converting {stream.name}"):
                events_in += len(chunk)
                last_us = int(chunk["t"][-1])
                if transform:
                    chunk = transform.process(chunk)
                if len(chunk):
                    frames.write(chunk)
                events_out += len(chunk)
                frames.release(last_us)
                # past --end: the rest of the input is not read (but for the side streams' packets stored later)
                if transform and transform.done and not stream.reads_past_the_end:
                    stopped = True
                    break
            frames.release(None)
            if transform and not stopped:
                transform.said_at_end(stream.name)
            writer.cut = relayed.was_cut  # a cut input's output is marked cut too (a slice ended before it: whole)
    read = f"{events_in:,} events read (reading stopped at --end)" if stopped else f"{events_in:,} events in"
    log.info(f"convert: {read}, {events_out:,} out")
    return Outcome(events_in, events_out, {"read_to_the_end": not stopped}, "stopped at --end" if stopped else "",
                   relayed.was_cut)
