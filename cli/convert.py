"""``evtools convert``: any readable format to any writable one, streaming."""

from __future__ import annotations

import click

from evtools.cli.options import output_option, read_options
from evtools.cli.progress import with_progress
from evtools.formats import create_events, open_events
from evtools.formats.registry import FORMATS


@click.command()
@read_options
@click.argument("output_path", required=False, metavar="[OUT]", type=click.Path(dir_okay=False, allow_dash=True))
@output_option
@click.option(
    "--format", "output_format", default=None,
    type=click.Choice([f.name for f in FORMATS if f.writer], case_sensitive=False),
    help="Output format; default: from OUT's extension, AEDAT 4.0 on stdout.",
)
@click.option(
    "--compression", default=None, metavar="C",
    help="aedat4: none (default), lz4, zstd; hdf5: none, gzip, lzf, zstd.",
)
def convert(input, input_format, sensor_size, aedat2_layout, output_path, output, output_format, compression):
    """Convert IN (default stdin) to OUT or -o OUT (default stdout), chunk by chunk in bounded memory.

    \b
    evtools convert recording.aedat -o recording.h5
    evtools convert recording.aedat4 - | evtools convert - recording.csv
    """
    if output_path is not None:
        if output != "-":
            raise click.UsageError("give the output either as OUT or as -o OUT, not both")
        output = output_path
    with open_events(input, format=input_format, sensor_size=sensor_size, aedat2_layout=aedat2_layout) as stream:
        with create_events(
            output, stream.info, format=output_format, compression=compression,
            aedat2_layout=aedat2_layout, inputs=(input,),
        ) as writer:
            for chunk in with_progress(stream, stream, f"converting {stream.name}"):
                writer.write(chunk)
