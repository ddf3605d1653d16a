"""Options shared by the subcommands."""

from __future__ import annotations

import functools
import math
import os
import re
import sys

import click

from evtools.errors import EvtoolsError
from evtools.events import MAX_TIME_US, parse_sensor_size
from evtools.formats.registry import BY_NAME


def sensor_size_value(ctx, param, value):
    """A ``WxH`` option's value as ``(width, height)``; a size no sensor has is a usage error (exit 2)."""
    if value is None:
        return None
    try:
        return parse_sensor_size(value)
    except EvtoolsError as error:
        raise click.BadParameter(str(error)) from None


DURATION_UNITS_US = {"us": 1, "ms": 1_000, "s": 1_000_000, "min": 60_000_000}

def _range_text(low, high, low_open: bool, high_open: bool, technical: float) -> str:
    """A range for help texts, without the bounds no user types: none at all, or one at the type's technical
    limit (2^62 us, 2^31 events), which are checked all the same."""
    high = None if high is None or high >= technical else high
    low = None if low is None or low <= -technical else low
    if low is None and high is None:
        return ""
    if high is None:
        return f"x{'>' if low_open else '>='}{low:g}"
    if low is None:
        return f"x{'<' if high_open else '<='}{high}"
    return f"{low}{'<' if low_open else '<='}x{'<' if high_open else '<='}{high}"


class IntRange(click.IntRange):
    """click's IntRange whose help leaves out a bound at the type's technical limit."""

    def _describe_range(self) -> str:
        return _range_text(self.min, self.max, self.min_open, self.max_open, 2**31 - 1)


COUNT = IntRange(1, 2**31 - 1)
"""Options that count (events, neighbours, windows): a positive int32."""


class FiniteRange(click.FloatRange):
    """click's FloatRange without ``nan``, which its comparisons let through (``--fps nan`` reached OpenCV,
    ``simulate --speed nan`` made 2 events), and without ``inf`` unless ``infinite`` (``--max-fit inf``: no
    limit). Without bounds: any finite number (:data:`FINITE`)."""

    def __init__(self, *args, infinite: bool = False, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.infinite = infinite

    def _describe_range(self) -> str:
        return _range_text(self.min, self.max, self.min_open, self.max_open, math.inf)

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if math.isnan(number) or (math.isinf(number) and not self.infinite):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


FINITE = FiniteRange()
"""A finite float option."""
DURATION_FORMS = "2s, 500ms, 250us, 1.5min"


class Duration(click.ParamType):
    """A time with its unit (``us``, ``ms``, ``s``, ``min``), as whole microseconds (int).

    Every time option of the CLI whose name carries no unit takes this; a bare number is refused (is ``0.25``
    seconds or microseconds?) with the accepted forms. Options named with their unit (``--dt-us``) take plain
    numbers in that unit instead. ``minimum_us``, ``maximum_us``: the range accepted (from 1: a positive
    duration; up to evtools' time range, 2^62 us)."""

    name = "duration"

    def __init__(self, minimum_us: int = 1, maximum_us: int = MAX_TIME_US) -> None:
        self.minimum_us, self.maximum_us = minimum_us, maximum_us

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
        if value_us > self.maximum_us:
            self.fail(f"{value!r} is longer than evtools' time range (2^62 us, 146,000 years)"
                      if self.maximum_us == MAX_TIME_US else f"{value!r} must be at most {self.maximum_us:,} us",
                      param, ctx)
        if value_us < self.minimum_us:
            least = "longer than 0 us" if self.minimum_us == 1 else f"at least {self.minimum_us} us"
            self.fail(f"{value!r} must be {least}", param, ctx)
        return int(value_us)


class Microseconds(Duration):
    """Options named with their unit (``--dt-us``): a bare whole number in microseconds, or a duration with its
    unit like every time option (``--dt-us 10ms``); up to evtools' time range, 2^62 us (a larger value reached the
    kernels as more than int64 holds). ``minimum_us``: the smallest accepted (0 where zero means "off")."""

    name = "us"

    def convert(self, value, param, ctx):
        if isinstance(value, str) and re.fullmatch(r"\s*[-+]?[0-9]+\s*", value):
            value = f"{value.strip()}us"
        elif isinstance(value, str) and re.fullmatch(r"\s*[-+]?[0-9]*\.[0-9]*(?:[eE][-+]?[0-9]+)?\s*", value):
            self.fail(f"{value!r} is not a whole number of microseconds; give one, or a time with its unit: "
                      f"{DURATION_FORMS}", param, ctx)
        return super().convert(value, param, ctx)


MICROSECONDS = Microseconds()
"""A positive time in microseconds (see :class:`Microseconds`)."""


class TimeBound(click.ParamType):
    """A time from the stream's first event (``2s``, ``500ms``), or an absolute one after ``@`` (``@136.6s``)."""

    name = "time"

    def convert(self, value, param, ctx):
        from evtools.transform import Time

        if isinstance(value, Time):
            return value
        text = str(value).strip()
        absolute = text.startswith("@")
        return Time(Duration(minimum_us=0).convert(text[1:] if absolute else text, param, ctx), absolute)


def _rectangle(ctx, param, value):
    if value is None:
        return None
    parts = value.split(",")
    if len(parts) != 4 or not all(part.strip().isdigit() for part in parts):
        raise click.BadParameter(f"{value!r}: give X,Y,W,H (whole pixels, e.g. 10,20,64,48)")
    rectangle = tuple(int(part) for part in parts)
    if rectangle[2] < 1 or rectangle[3] < 1:  # (no sensor holds an empty rectangle: it exited 1 as bad data)
        raise click.BadParameter(f"{value!r}: the width W and height H must be at least 1")
    return rectangle


def check_time_span(start, end) -> None:
    """--start and --end (:class:`TimeBound`, either None) as a usage error when the end is not after the start
    (both from the first event, or both absolute: no stream holds events between them)."""
    if start is not None and end is not None and start.absolute == end.absolute and end.us <= start.us:
        raise click.BadParameter(f"the end ({end.us} us) is not after the start ({start.us} us)", param_hint="--end")


SLICING_NAMES = ("start", "end", "polarity", "crop", "flip_x", "flip_y", "transpose")


def slicing_options(command):
    """--start, --end, --polarity, --crop, --flip-x, --flip-y, --transpose (see evtools.transform), given to the
    command as one ``slicing`` dict (None when none is given)."""

    @functools.wraps(command)
    def with_slicing(*args, **kwargs):
        slicing = {name: kwargs.pop(name) for name in SLICING_NAMES}
        check_time_span(slicing["start"], slicing["end"])  # (any stream: it exited 1 as bad data; render's said 2)
        return command(*args, slicing=slicing if any(slicing.values()) else None, **kwargs)

    options = [
        click.option("--start", type=TimeBound(), default=None, metavar="TIME",
                     help="Keep events from this time on: from the stream's first event (2s, 500ms), or absolute "
                          "after @ (@136.6s)."),
        click.option("--end", type=TimeBound(), default=None, metavar="TIME",
                     help="Keep events before this time (as --start)."),
        click.option("--polarity", type=click.Choice(["on", "off"]), default=None, help="Keep one polarity."),
        click.option("--crop", callback=_rectangle, default=None, metavar="X,Y,W,H",
                     help="Keep the events inside this rectangle, moved to its origin: the sensor becomes W x H."),
        click.option("--flip-x", is_flag=True, default=None, help="Mirror left-right (x -> W - 1 - x), after --crop."),
        click.option("--flip-y", is_flag=True, default=None, help="Mirror top-bottom (y -> H - 1 - y), after --crop."),
        click.option("--transpose", is_flag=True, default=None, help="Swap x and y, last: the sensor becomes H x W."),
    ]
    for option in reversed(options):
        with_slicing = option(with_slicing)
    return with_slicing


def merged_alias(name: str, value, alias: str, alias_value):
    """An option given under its name or its older, hidden alias (not both, unless equal)."""
    if alias_value is None:
        return value
    if value is not None and value != alias_value:
        raise click.UsageError(f"{alias} is another name for {name}: give one of them")
    return alias_value


def figure_path(path: str | None, param_hint: str, inputs=()) -> str | None:
    """``path`` when it names a figure evtools can write (.png, .svg, .pdf) and none of the command's ``inputs``
    (the same file through a symbolic or a hard link too), else a usage error: checked before any work is done."""
    if path is None:
        return None
    from evtools.formats.figures import FigureError, figure_format
    from evtools.formats.io import same_file

    for named in inputs:
        if same_file(path, named):
            raise click.BadParameter(f"{path} is an input of this command ({named}): a picture would replace it; "
                                     "choose another file", param_hint=param_hint)
    try:
        figure_format(path)
    except FigureError as error:
        raise click.BadParameter(str(error), param_hint=param_hint) from None
    return path


def network_names(ctx, param, value):
    """Inputs named ``tcp://...`` checked as addresses when the command line is read: a malformed one is a usage
    error (exit 2), as for ``-o``; one that cannot be reached is the environment's (exit 1, when connecting)."""
    from evtools.formats.io import TCP_PREFIX, tcp_address

    for name in (value if isinstance(value, (tuple, list)) else (value,)):
        if isinstance(name, str) and name.startswith(TCP_PREFIX):
            try:
                tcp_address(name)
            except EvtoolsError as error:
                raise click.BadParameter(str(error)) from None
    return value


input_argument = click.argument("input", default="-", metavar="[IN]", callback=network_names,
                                type=click.Path(allow_dash=True))  # (a folder: an RPG or DSEC dataset)


def serve_early(ctx, param, value):
    """``-o tcp://HOST:PORT`` listens from the command's start, before the input is opened, so a client that
    connects meanwhile gets the whole stream (it listened only once the first output was ready)."""
    if isinstance(value, str) and value.startswith("tcp://"):
        from evtools.formats.io import listen_early, tcp_address

        try:
            tcp_address(value)
        except EvtoolsError as error:  # (malformed: usage, exit 2; a port taken: the environment's, exit 1)
            raise click.BadParameter(str(error)) from None
        listen_early(value)
    return value


input_format_option = click.option(
    "--input-format", type=click.Choice(sorted(BY_NAME), case_sensitive=False), default=None,
    help="Input format; default: recognised by magic bytes, then by extension.",
)
sensor_size_option = click.option(
    "--sensor-size", callback=sensor_size_value, metavar="WxH", default=None,
    help="Sensor size, for files that do not store it (CSV, DSEC without attributes); overrides the file's.",
)
aedat2_layout_option = click.option(
    "--aedat2-layout", type=click.Choice(["dvs128", "davis240", "davis346"]), default=None,
    help="AEDAT 2.0 address layout when the header names no chip (reading) or to force one (writing).",
)
json_option = click.option(
    "--json", "as_json", is_flag=True, help="Print JSON (the default when stdout is not a terminal)."
)

LIVE_OPTIONS = "evtools.reading"
"""The key in click's context ``meta`` where the global ``--max-latency`` and ``--timeout`` leave their values
(:class:`evtools.formats.ReadOptions` field -> value), for :func:`input_options` to put into the reading options."""


def reading_options(**fields):
    """The :class:`evtools.formats.ReadOptions` of ``fields`` and of the global ``--max-latency`` and ``--timeout``
    given to the running command."""
    from evtools.formats import ReadOptions

    context = click.get_current_context(silent=True)
    return ReadOptions(**(context.meta.get(LIVE_OPTIONS, {}) if context is not None else {}), **fields)


def input_options(function):
    """``--input-format``, ``--sensor-size`` and ``--aedat2-layout``, given to the command as one ``reading``
    (an :class:`evtools.formats.ReadOptions`, with the global ``--max-latency`` and ``--timeout`` in it): the object
    every ``open_events`` of the command takes."""

    @functools.wraps(function)
    def with_reading(*args, **kwargs):
        reading = reading_options(format=kwargs.pop("input_format"), sensor_size=kwargs.pop("sensor_size"),
                                  aedat2_layout=kwargs.pop("aedat2_layout"))
        return function(*args, reading=reading, **kwargs)

    for option in (aedat2_layout_option, sensor_size_option, input_format_option):
        with_reading = option(with_reading)
    return with_reading


def read_options(function):
    """The options of every command that reads one event stream: ``IN`` and :func:`input_options`."""
    return input_argument(input_options(function))


class FileRead(click.Path):
    """An input a command reads more than once (to count, then to match or sample it): a file, never stdin (`-`
    said "File '-' does not exist", as if the user had mistyped a name: a QA sweep)."""

    def __init__(self) -> None:
        super().__init__(exists=True, dir_okay=False)

    def convert(self, value, param, ctx):
        if value == "-":
            self.fail("- (stdin) cannot be read twice, and this command reads its input twice: give a file",
                      param, ctx)
        return super().convert(value, param, ctx)


def wants_json(as_json: bool) -> bool:
    return as_json or not sys.stdout.isatty()


def echo_json(value, err: bool = False, **dumps) -> None:
    """``value`` as JSON on stdout (stderr with ``err``); a full disk or a failing device is one line naming it
    (it said "No space left on device" alone: a QA sweep). A closed pipe stays the caller's (exit 141)."""
    import io
    import json

    text = json.dumps(value, **dumps) + "\n"
    stream = sys.stderr if err else sys.stdout
    try:
        try:
            fd = stream.fileno()
        except (AttributeError, ValueError, io.UnsupportedOperation):  # (a notebook's or a test's capture)
            click.echo(text, err=err, nl=False)
            return
        stream.flush()
        data = memoryview(text.encode())
        while data:  # (Python's buffered write lost the rest of a large report when the pipe's reader left
            data = data[os.write(fd, data):]  # after a partial write, and exited 0: a QA sweep)
    except BrokenPipeError:
        raise
    except OSError as error:
        raise EvtoolsError(f"<{'stderr' if err else 'stdout'}>: cannot write ({error.strerror or error})") from None


def _compression_help() -> str:
    described = [f"{fmt.name}: {', '.join(fmt.compressions)} (default {fmt.compressions[0]})"
                 for fmt in BY_NAME.values() if fmt.compressions]
    return (f"Compression of the output: {'; '.join(described)}. DV records AEDAT 4.0 with lz4; AEDAT 4.0 packets "
            "are compressed on a pool of threads.")


compression_option = click.option("--compression", default=None, metavar="C", help=_compression_help())
"""``--compression``: of every command that writes an event stream (checked by :func:`check_compression`)."""


def check_compression(compression: str | None, pairs, output_format: str | None = None) -> None:
    """Refuse, as a usage error and before any work, a ``--compression`` that an output's format does not write
    (``pairs``: the (input, output) pairs of :func:`evtools.cli.batch.plan`)."""
    if compression is None:
        return
    from evtools.formats import check_compression as check, output_format as format_of
    from evtools.formats.errors import FormatError

    for _, output in pairs:
        try:
            fmt = format_of(output, output_format)
        except FormatError:
            continue  # no format to check against: the command says why when it opens the output
        try:
            check(fmt, compression, output or "-")
        except FormatError as error:
            raise click.BadParameter(str(error), param_hint="'--compression'") from None
