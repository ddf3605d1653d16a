"""Options shared by the subcommands."""

from __future__ import annotations

import re
import sys

import click

from evtools.errors import EvtoolsError
from evtools.events import parse_sensor_size
from evtools.formats.registry import BY_NAME


def _sensor_size(ctx, param, value):
    if value is None:
        return None
    try:
        return parse_sensor_size(value)
    except EvtoolsError as error:
        raise click.BadParameter(str(error)) from None


DURATION_UNITS_US = {"us": 1, "ms": 1_000, "s": 1_000_000, "min": 60_000_000}
DURATION_FORMS = "2s, 500ms, 250us, 1.5min"


class Duration(click.ParamType):
    """A time with its unit (``us``, ``ms``, ``s``, ``min``), as whole microseconds (int).

    Every time option of the CLI whose name carries no unit takes this; a bare number is refused (is ``0.25``
    seconds or microseconds?) with the accepted forms. Options named with their unit (``--dt-us``) take plain
    numbers in that unit instead. ``minimum_us``: the smallest value accepted (1: a positive duration)."""

    name = "duration"

    def __init__(self, minimum_us: int = 1) -> None:
        self.minimum_us = minimum_us

    def convert(self, value, param, ctx):
        if isinstance(value, int) and not isinstance(value, bool):
            return value  # already converted (a default given in microseconds)
        text = str(value).strip()
        match = re.fullmatch(r"([-+]?[0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(us|ms|s|min)?", text)
        if not match:
            self.fail(f"{value!r} is not a time; give a number with its unit: {DURATION_FORMS}", param, ctx)
        if match.group(2) is None:
            self.fail(f"{value!r} has no unit; give one: {DURATION_FORMS}", param, ctx)
        value_us = round(float(match.group(1)) * DURATION_UNITS_US[match.group(2)])
        if value_us < self.minimum_us:
            least = "longer than 0 us" if self.minimum_us == 1 else f"at least {self.minimum_us} us"
            self.fail(f"{value!r} must be {least}", param, ctx)
        return int(value_us)


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
