"""Edge uniformity: how alike the pixels respond to one global stimulus edge (the report's Table 2 metric).

For each stimulus edge (a window of time in which the stimulus moves one way) and each pixel, the first and last
event of the edge's polarity; the standard deviation of those times across pixels (the report's section 5.3);
the per-pixel event-count coefficient of variation (about sigma_theta / theta for a global stimulus); and, against
a reference stream from an ideal sensor with one uniform threshold, the per-pixel count error and the timing
error of matched events (the k-th event of a pixel in the edge against the ideal pixel's k-th).

Edges are found automatically (:func:`detect_edges`) or given as start times.

References
----------
The founding report, section 5.3 and Table 2; ``docs/algorithms.md`` section 6.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evtools.errors import EvtoolsError, InvalidEventsError
from evtools.events import as_chunk

__all__ = ["UniformityError", "Edge", "detect_edges", "edges_from_starts", "edge_uniformity", "pixel_levels"]

BIN_US = 1_000
"""Width of the activity bins of the automatic edge detection."""
QUIET_US = 200_000
"""A burst of activity that follows at least this much quiet starts a new edge."""
ACTIVE_FRACTION = 0.02
"""A bin is active when it holds at least this fraction of the responding pixels' count (and at least 2 events)."""
EDGE_PIXEL_FRACTION = 0.5
"""A detected edge is a stimulus edge when at least this fraction of the stream's responding pixels fire in it
with its polarity, and at least :data:`EDGE_PURITY` of its events have its polarity: a step or a flicker reaches
every pixel one way (the simulated step and flicker scenes: 100 % of the pixels, 97-100 % of the events), a
moving scene's bursts few pixels both ways (a moving texture: median 3 % of the pixels, 54 % of the events;
moving bars 6 %, 68 %; the texture's longer bursts reach every pixel but stay near 50 %), and would give
uniformity figures of nothing (count CV 4-6)."""
EDGE_PURITY = 0.8
"""See :data:`EDGE_PIXEL_FRACTION`."""


class UniformityError(EvtoolsError, ValueError):
    """A stream or edge list that the uniformity metric cannot use."""


@dataclass
class Edge:
    """A stimulus edge: events in ``[start_us, end_us)`` of polarity ``polarity`` (True = ON)."""

    start_us: int
    end_us: int
    polarity: bool
    cut: bool = False
    """The stream ends while the edge is still active (:func:`detect_edges`): its counts are partial."""


def _time_ordered(events, name: str = "events") -> np.ndarray:
    """``events`` as EVENT_DTYPE (another layout converted by name, see :func:`evtools.events.as_chunk`), refused when
    time goes backwards (the edges are found by searching the times: unsorted, a count CV of 6.45 for 0.17, a QA
    sweep)."""
    events = as_chunk(events, name)
    backwards = np.flatnonzero(np.diff(events["t"]) < 0)
    if len(backwards):
        raise InvalidEventsError(f"{name}: time goes backwards at event {int(backwards[0]) + 1} "
                                 f"({int(events['t'][backwards[0] + 1])} us after {int(events['t'][backwards[0]])})")
    return events


def _on_width(events: np.ndarray, width: int) -> None:
    """Every x below ``width`` (a pixel is ``y * width + x``: one beyond would count as the next row's)."""
    outside = (events["x"] >= width) | (events["x"] < 0) | (events["y"] < 0)
    if outside.any():
        k = int(np.argmax(outside))
        raise InvalidEventsError(f"events: event {k} at (x={int(events['x'][k])}, y={int(events['y'][k])}) lies "
                                 f"outside a sensor {width} wide")


def _pixel_count(events: np.ndarray) -> int:
    """How many pixels the events come from."""
    return len(np.unique(events["y"].astype(np.int64) * 65536 + events["x"]))


def _net_polarity(events: np.ndarray) -> int:
    return int(np.count_nonzero(events["p"])) * 2 - len(events)


def detect_edges(events: np.ndarray, bin_us: int = BIN_US, quiet_us: int = QUIET_US,
                 active_fraction: float = ACTIVE_FRACTION,
                 pixel_fraction: float = EDGE_PIXEL_FRACTION) -> list[Edge]:
    """Edges of a global stimulus, from bursts of activity across pixels.

    The stream is cut into ``bin_us`` bins; a bin is active when it holds at least ``max(2, active_fraction *
    responding pixels)`` events. A new edge starts at an active bin that follows ``quiet_us`` or more without an
    active bin (a step), or whose net polarity is opposite to the current edge's (a ramp turning, as in the
    flicker scene). An edge ends where the next one starts (the last at the end of the stream); its polarity is
    the sign of its first active bins' net polarity; the last is ``cut`` when the stream's last two bins are
    active (it ends with the edge still under way: the README's 3 s step stream ends 1.2 ms after its sixth step).
    A candidate in which fewer than ``pixel_fraction`` of the responding pixels fire with its polarity, or less
    than :data:`EDGE_PURITY` of whose events have it, is no stimulus edge (:data:`EDGE_PIXEL_FRACTION`): its span
    goes to the edge before it (a stray burst of the other polarity inside an edge, the stream's last events), or
    is left out when there is none (a moving scene has no edge at all); so does the candidate after such a stray
    burst when it turns back to that edge's polarity.
    """
    events = _time_ordered(events)
    if len(events) == 0:
        raise UniformityError("the stream has no events: no edge to measure")
    t = events["t"]
    t0 = int(t[0])
    index = (t - t0) // bin_us
    last_bin = int(index[-1])
    # the bins that hold events only (a dense histogram of the span took 1 GB for 4 events 11 days apart, and ran
    # out of memory beyond: a QA sweep)
    bins, where, counts = np.unique(index, return_inverse=True, return_counts=True)
    nets = np.bincount(where, weights=np.where(events["p"], 1.0, -1.0), minlength=len(bins))
    pixels = _pixel_count(events)
    busy = counts >= max(2.0, active_fraction * pixels)
    active_bins, active_nets = bins[busy], nets[busy]
    starts: list[tuple[int, bool, bool]] = []  # (bin, polarity, after a quiet spell)
    last_active = None
    polarity = None
    for b, net_b in zip(active_bins.tolist(), active_nets.tolist()):
        sign = None if net_b == 0 else bool(net_b > 0)
        quiet = last_active is None or (b - last_active) * bin_us > quiet_us
        if quiet or (sign is not None and polarity is not None and sign != polarity and abs(net_b) >= 2):
            starts.append((int(b), sign, quiet))
            polarity = sign
        elif polarity is None:
            polarity = sign
            starts[-1] = (starts[-1][0], sign, starts[-1][2])
        last_active = b
    edges: list[Edge] = []
    ongoing = False  # whether the latest candidate is (part of) the last edge
    for k, (b, sign, quiet) in enumerate(starts):
        end = t0 + starts[k + 1][0] * bin_us if k + 1 < len(starts) else int(t[-1]) + 1
        edge = Edge(t0 + b * bin_us, end, bool(sign) if sign is not None else True)
        span = events[np.searchsorted(t, edge.start_us): np.searchsorted(t, edge.end_us)]
        same = span[span["p"] == edge.polarity]
        stimulus = _pixel_count(same) >= pixel_fraction * pixels and len(same) >= EDGE_PURITY * len(span)
        resumed = bool(not quiet and edges and edges[-1].polarity == edge.polarity)  # (a stray burst went to it)
        if stimulus and not resumed:
            edges.append(edge)
            ongoing = True
        elif edges:  # the edges so far end where this one starts: the last takes its span
            edges[-1].end_us = end
            ongoing = resumed
    if ongoing and len(active_bins) and active_bins[-1] >= last_bin - 1:  # the stream's last 1-2 ms active:
        edges[-1].cut = True  # its last edge goes on past it
    return edges


def edges_from_starts(events: np.ndarray, starts_us, end_us: int | None = None) -> list[Edge]:
    """Edges starting at the given times, each ending where the next starts (the last at ``end_us``, default just
    after the stream's last event)."""
    events = _time_ordered(events)
    starts = [int(s) for s in starts_us]
    if not starts:
        raise UniformityError("give at least one edge time")
    if any(b <= a for a, b in zip(starts, starts[1:])):
        raise UniformityError("edge times must increase")
    if end_us is not None:
        end = int(end_us)
    else:
        end = int(events["t"][-1]) + 1 if len(events) else starts[-1] + 1
    edges = []
    for k, start in enumerate(starts):
        stop = starts[k + 1] if k + 1 < len(starts) else max(end, start + 1)
        window = events[np.searchsorted(events["t"], start): np.searchsorted(events["t"], stop)]
        edges.append(Edge(start, stop, _net_polarity(window) >= 0))
    return edges


def _per_pixel(window: np.ndarray, width: int) -> dict[int, np.ndarray]:
    """Times of the window's events per pixel index (events already of one polarity, time order)."""
    pixel = window["y"].astype(np.int64) * width + window["x"]
    order = np.argsort(pixel, kind="stable")
    pixel, times = pixel[order], window["t"][order]
    cuts = np.flatnonzero(np.diff(pixel)) + 1
    return {int(group[0]): times_ for group, times_ in zip(np.split(pixel, cuts), np.split(times, cuts)) if len(group)}


def edge_uniformity(events: np.ndarray, width: int, edges: list[Edge], reference: np.ndarray | None = None) -> dict:
    """Per-edge uniformity statistics of ``events`` (and their distance to ``reference``); see the module doc.

    Returns a dict with ``edges`` (one dict per edge: times in ms; ``cut`` for an edge the stream's end cuts),
    ``summary`` (means over the edges, those cut left out unless every edge is) and the stream's per-pixel
    polarity balance ``(ON - OFF) / (ON + OFF)`` (mean and std over responding pixels).
    """
    if reference is not None:
        reference = _time_ordered(reference, "reference")
    events = _time_ordered(events)
    _on_width(events, width)
    responding = np.unique(events["y"].astype(np.int64) * width + events["x"]) if len(events) else np.empty(0, int)
    if len(responding) == 0:
        raise UniformityError("the stream has no events: nothing to measure")
    rows = []
    for edge in edges:
        row = {"start_ms": edge.start_us / 1e3, "end_ms": edge.end_us / 1e3,
               "polarity": "ON" if edge.polarity else "OFF", "cut": edge.cut}
        window = _window(events, edge)
        groups = _per_pixel(window, width)
        counts = np.array([len(groups.get(int(i), ())) for i in responding], dtype=float)
        firsts = np.array([g[0] for g in groups.values()], dtype=float)
        lasts = np.array([g[-1] for g in groups.values()], dtype=float)
        row.update({
            "pixels": len(groups),
            "first_std_ms": float(np.std(firsts) / 1e3) if len(groups) else None,
            "last_std_ms": float(np.std(lasts) / 1e3) if len(groups) else None,
            "count_mean": float(counts.mean()),
            "count_cv": float(counts.std() / counts.mean()) if counts.mean() > 0 else None,
        })
        if reference is not None:
            ideal = _per_pixel(_window(reference, edge), width)
            pixels = set(groups) | set(ideal)
            count_errors, timing = [], []
            for i in pixels:
                mine, theirs = groups.get(i, np.empty(0)), ideal.get(i, np.empty(0))
                count_errors.append(abs(len(mine) - len(theirs)))
                k = min(len(mine), len(theirs))
                timing.extend(np.abs(mine[:k] - theirs[:k]).tolist())
            row["count_error"] = float(np.mean(count_errors)) if count_errors else None
            row["timing_error_ms"] = float(np.mean(timing) / 1e3) if timing else None
        rows.append(row)
    summary = {}
    whole = [r for r in rows if not r["cut"]] or rows
    for key in ("first_std_ms", "last_std_ms", "count_cv", "count_error", "timing_error_ms"):
        values = [r[key] for r in whole if r.get(key) is not None]
        if values:
            summary[key] = float(np.mean(values))
    pixel = events["y"].astype(np.int64) * width + events["x"]
    n_on = np.bincount(pixel, weights=events["p"].astype(float))[responding]
    n_all = np.bincount(pixel)[responding]
    balance = (2 * n_on - n_all) / n_all
    return {
        "edges": rows,
        "summary": summary,
        "polarity_balance_mean": float(balance.mean()),
        "polarity_balance_std": float(balance.std()),
        "responding_pixels": int(len(responding)),
    }


def _window(events: np.ndarray, edge: Edge) -> np.ndarray:
    window = events[np.searchsorted(events["t"], edge.start_us): np.searchsorted(events["t"], edge.end_us)]
    return window[window["p"] == edge.polarity]


def pixel_levels(events: np.ndarray, width: int, edge: Edge, step: float = 1.0) -> dict[int, tuple[np.ndarray,
                                                                                                   np.ndarray]]:
    """Per pixel, the cumulative level (``step`` per event, signed) against time over ``edge``: (t_us, level)."""
    events = _time_ordered(events)
    _on_width(events, width)
    window = events[np.searchsorted(events["t"], edge.start_us): np.searchsorted(events["t"], edge.end_us)]
    pixel = window["y"].astype(np.int64) * width + window["x"]
    out = {}
    for i in np.unique(pixel):
        mine = window[pixel == i]
        out[int(i)] = (mine["t"], np.cumsum(np.where(mine["p"], step, -step)))
    return out
