"""``evtools info``: what is in an event file."""

from __future__ import annotations


import click

from evtools.cli.options import echo_json, input_options, json_option, network_names, wants_json
from evtools.cli.progress import with_progress
from evtools.errors import EvtoolsError
from evtools.summary import StreamSummary
from evtools.formats import open_events


@click.command()
@click.argument("inputs", nargs=-1, metavar="FILE...", type=click.Path(allow_dash=True), callback=network_names)
@input_options
@json_option
def info(inputs, reading, as_json):
    """Format, sensor size, event count, time span, rate and ON fraction of each FILE (`-` = stdin), and its APS
    frames (count, rate, exposure, size) where it has them.

    With several files, one that cannot be read is said on stderr (and in the JSON as ``{"file", "error"}``) and
    the others are shown; the exit code is then 1."""
    paths = inputs or ("-",)
    rows, failed = [], 0
    for path in paths:
        try:
            rows.append(_summary(path, reading))
        except (EvtoolsError, OSError) as error:
            if len(paths) == 1:
                raise
            if isinstance(error, OSError):
                error = f"{error.filename or path}: {error.strerror or error}"
            click.echo(f"evtools: error: {error}", err=True)
            rows.append({"file": path, "error": str(error)})
            failed += 1
    if wants_json(as_json):
        echo_json(rows if len(rows) > 1 else rows[0], indent=2, default=str)
    elif len(rows) > failed:
        _print_table([row for row in rows if "error" not in row])
    if failed:
        raise click.exceptions.Exit(1)


def _summary(path: str, reading) -> dict:
    with open_events(path, reading) as stream:
        summary = StreamSummary()
        for chunk in with_progress(stream, stream, f"reading {stream.name}"):
            summary.add(chunk)
            summary.add_frames(stream.take_frames())
        summary.add_frames(stream.take_frames())
        return {"file": stream.name, **summary.as_dict(stream.info), "cut": bool(stream.was_cut)}


def _print_table(rows: list[dict]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(show_header=True, header_style="bold")
    table.add_column("")
    for row in rows:
        table.add_column(row["file"], overflow="fold")

    def line(label, fmt):
        table.add_row(label, *(fmt(row) for row in rows))

    line("format", lambda r: r["format"])
    line("sensor", lambda r: f"{r['width']} x {r['height']}")
    line("events", lambda r: f"{r['events']:,}")
    line("first t", lambda r: "-" if r["t_first_us"] is None else f"{r['t_first_us']:,} us")
    line("last t", lambda r: "-" if r["t_last_us"] is None else f"{r['t_last_us']:,} us")
    line("span", lambda r: f"{r['duration_s']:.6g} s")
    line("rate", lambda r: f"{r['rate_hz'] / 1e6:.4g} Mev/s")
    line("ON fraction", lambda r: "-" if r["on_fraction"] is None else f"{r['on_fraction']:.3f}")
    line("APS frames", _frames_line)
    line("source", lambda r: str(r["metadata"].get("source") or r["metadata"].get("aechip") or "-"))
    line("skipped", lambda r: ", ".join(r["metadata"].get("skipped_streams", [])) or "-")
    Console().print(table)


def _frames_line(row: dict) -> str:
    frames = row["frames"]
    if not frames["count"]:
        return "-"
    low, median, high = frames["exposure_us"]
    exposure = f"{median:,.0f} us" if low == high else f"{low:,}-{high:,} us (median {median:,.0f})"
    return (f"{frames['count']:,} ({frames['rate_hz']:.4g} /s), exposure {exposure}, "
            f"{', '.join(frames['sizes'])} {', '.join(frames['pixels'])}")
