"""``evtools metrics uniformity``: how alike the pixels respond to each stimulus edge (the report's Table 2)."""

from __future__ import annotations

import logging

import click

from evtools.cli.options import TimeBound, echo_json, figure_path, json_option, read_options, wants_json
from evtools.events import concatenate
from evtools.metrics.uniformity import UniformityError, detect_edges, edge_uniformity, edges_from_starts, pixel_levels
from evtools.formats import open_events


def _edges_at(ctx, param, value):
    if value is None:
        return None
    return [TimeBound().convert(part, param, ctx) for part in value.split(",") if part.strip()]


def _read(path, reading, **fields):
    with open_events(path, reading, **fields) as stream:
        return stream.info, stream.name, concatenate(stream)


@click.command()
@read_options
@click.option("--edges-at", callback=_edges_at, metavar="T1,T2,...", default=None,
              help="Edge start times from the stream's first event (100ms,1.1s), or absolute after @ (@2.5s); "
                   "default: detected from bursts of activity across pixels.")
@click.option("--reference", metavar="IDEAL", type=click.Path(dir_okay=False), default=None,
              help="The stream of an ideal sensor with one uniform threshold: adds count and timing errors.")
@click.option("--plot", metavar="FIG.png|svg|pdf", type=click.Path(dir_okay=False), default=None,
              help="Draw the per-pixel reconstructions (cumulative level vs time) of one edge.")
@click.option("--before", metavar="IN2", type=click.Path(dir_okay=False), default=None,
              help="With --plot: the uncorrected stream, drawn beside IN.")
@click.option("--plot-edge", type=click.IntRange(min=0), default=0, show_default=True, help="Edge drawn by --plot.")
@json_option
def uniformity(input, reading, edges_at, reference, plot, before, plot_edge,
               as_json):
    """Per stimulus edge of IN: std across pixels of the first and last event times, count CV, errors vs IDEAL.

    Edges (auto): 1 ms bins, a bin active with >= max(2, 2% of the responding pixels) events; a new edge starts
    at an active bin after 200 ms without one, or whose net polarity turns against the current edge's; an edge
    is a stimulus edge when half the responding pixels fire in it and 80% of its events have its polarity (a
    moving scene has none). Only the events of an edge's polarity count; an edge the stream's end cuts is shown
    but left out of the means.

    \b
    evtools metrics uniformity corrected.aedat4 --reference ideal.aedat4
    evtools metrics uniformity corrected.aedat4 --before raw.aedat4 --plot edges.png
    """
    figure_path(plot, "--plot", (input, reference, before))
    info, name, events = _read(input, reading)
    try:
        first_us = int(events["t"][0]) if len(events) else 0
        edges = (detect_edges(events) if edges_at is None
                 else edges_from_starts(events, [time.resolve(first_us) for time in edges_at]))
        ideal = None
        if reference is not None:
            ref_info, _, ideal = _read(reference, None, sensor_size=reading.sensor_size)
            if ref_info.size != info.size:
                raise UniformityError(f"{reference}: the reference is {ref_info.width}x{ref_info.height} but "
                                      f"{name} is {info.width}x{info.height}")
        result = edge_uniformity(events, info.width, edges, ideal)
    except UniformityError as error:
        raise UniformityError(f"{name}: {error}") from None
    result = {"file": name, **result}
    if not edges:  # (an empty table and exit 0 said nothing)
        logging.getLogger("evtools").warning(
            f"{name}: no stimulus edge found (a step or flicker every pixel sees at once): nothing to measure; give "
            "--edges-at T1,T2,... where the edges are")
    if plot:
        _plot(plot, events, info, edges, plot_edge, before, reading)
    if wants_json(as_json):
        echo_json(result, indent=2)
    else:
        _print_table(result)


def _plot(path, events, info, edges, index, before, reading) -> None:
    from evtools.formats.figures import save_figure
    from evtools.plots import edge_levels_figure

    if index >= len(edges):
        raise UniformityError(f"--plot-edge {index}: the stream has {len(edges)} edges")
    edge, width = edges[index], info.width
    panels = []
    if before is not None:
        before_info, before_name, before_events = _read(before, reading)
        if before_info.size != info.size:  # (its pixels were drawn as the other sensor's, silently)
            raise UniformityError(f"{before_name}: --before is {before_info.width}x{before_info.height} but the "
                                  f"stream is {info.width}x{info.height}")
        panels.append((f"before: {before_name}", list(pixel_levels(before_events, width, edge).values())))
    panels.append(("after" if before is not None else "events", list(pixel_levels(events, width, edge).values())))
    save_figure(edge_levels_figure(panels, edge.start_us, edge.end_us), path)


def _print_table(result: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    keys = [("first_std_ms", "first std ms"), ("last_std_ms", "last std ms"), ("count_mean", "count"),
            ("count_cv", "count CV"), ("count_error", "count err"), ("timing_error_ms", "timing err ms")]
    table = Table(title=result["file"], show_header=True, header_style="bold")
    for title in ("edge", "start ms", "pol", "pixels", *(title for _, title in keys)):
        table.add_column(title, justify="right")

    def cell(value):
        return "-" if value is None else f"{value:.4g}"

    for k, row in enumerate(result["edges"]):
        table.add_row(f"{k} (cut)" if row["cut"] else str(k), f"{row['start_ms']:.1f}", row["polarity"],
                      str(row["pixels"]), *(cell(row.get(key)) for key, _ in keys))
    summary = result["summary"]
    cut = [k for k, row in enumerate(result["edges"]) if row["cut"]]
    table.add_row("mean", "", "", "", *(cell(summary.get(key)) for key, _ in keys))
    console = Console()
    console.print(table)
    if cut and len(cut) < len(result["edges"]):
        console.print(f"edge {cut[0]} (cut) is left out of the means: the stream ends while it is still active")
    console.print(f"polarity balance (ON-OFF)/(ON+OFF) per pixel: mean {result['polarity_balance_mean']:.3f}, "
                  f"std {result['polarity_balance_std']:.3f} over {result['responding_pixels']} pixels")
