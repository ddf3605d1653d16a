"""Options shared by the subcommands."""

from __future__ import annotations

import sys

import click

from evtools.errors import EvtoolsError
from evtools.events import parse_sensor_size
from formats.registry import BY_NAME


def _sensor_size(ctx, param, value):
    if value is None:
        return None
    try:
        return parse_sensor_size(value)
    except EvtoolsError as error:
        raise click.BadParameter(str(error)) from None


input_argument = click.argument("input", default="-", metavar="[IN]", type=click.Path(dir_okay=False, allow_dash=True))
output_option = click.option(
    "-o", "--output", default="-", metavar="OUT", type=click.Path(dir_okay=False, allow_dash=True),
    help="Output file; `-` or absent: stdout (AEDAT 4.0 unless --format says otherwise).",
)
input_format_option = click.option(
    "--input-format", type=click.Choice(sorted(BY_NAME), case_sensitive=False), default=None,
    help="Input format; default: recognised by magic bytes, then by extension.",
)
sensor_size_option = click.option(
    "--sensor-size", callback=_sensor_size, metavar="WxH", default=None,
    help="Sensor size, for files that do not store it (CSV, DSEC without attributes); overrides the file's.",
)
aedat2_layout_option = click.option(
    "--aedat2-layout", type=click.Choice(["dvs128", "davis240", "davis346"]), default=None,
    help="AEDAT 2.0 address layout when the header names no chip (reading) or to force one (writing).",
)
json_option = click.option(
    "--json", "as_json", is_flag=True, help="Print JSON (the default when stdout is not a terminal)."
)


def read_options(function):
    """The options of every command that reads an event stream."""
    for option in (aedat2_layout_option, sensor_size_option, input_format_option, input_argument):
        function = option(function)
    return function


def wants_json(as_json: bool) -> bool:
    return as_json or not sys.stdout.isatty()
