"""An ideal DVS pixel driven by an analytic log-intensity waveform: exact crossing times, no frames.

Independent of ``evtools.simulation`` (which samples frames and interpolates): here the waveform is known in closed
form and every crossing time is solved for directly. A pixel starts with its reference at the signal's first
value; it fires ON when the signal reaches reference + theta_on (the reference moves up by theta_on), OFF when it
reaches reference - theta_off.
"""

from __future__ import annotations

import math

import numpy as np


def triangle_corners(start_us, end_us, base, amplitude, rise_us, fall_us, phase):
    """Corners (t_us, level) of a triangle wave from ``base`` up to ``base + amplitude`` in ``rise_us`` and back
    in ``fall_us``, covering [start_us, end_us]; ``phase`` in [0, 1) is where in its period the wave is at
    ``start_us`` (0: at the valley)."""
    period = rise_us + fall_us

    def level(u):  # u: time since a valley, within one period
        return base + amplitude * (u / rise_us if u <= rise_us else (period - u) / fall_us)

    u0 = phase * period
    corners = [(float(start_us), level(u0))]
    valley = start_us - u0  # the valley at or before start_us
    while True:
        for offset, value in ((rise_us, base + amplitude), (period, base)):
            t = valley + offset
            if t <= start_us:
                continue
            if t >= end_us:
                corners.append((float(end_us), level((end_us - valley) % period)))
                return corners
            corners.append((t, value))
        valley += period


def exponential_corners(start_us, end_us, edges, tau_us, level0, samples_per_tau=400):
    """A signal that, from ``level0``, approaches each edge's target ``(t_us, target)`` exponentially with time
    constant ``tau_us``, as a dense polyline (the crossing times below are then exact to ~1e-6 of tau)."""
    corners = [(float(start_us), float(level0))]
    value = float(level0)
    bounds = [t for t, _ in edges[1:]] + [end_us]
    for (t_edge, target), t_next in zip(edges, bounds):
        steps = max(1, int(math.ceil((t_next - t_edge) / tau_us * samples_per_tau)))
        if t_edge > corners[-1][0]:
            corners.append((float(t_edge), value))
        for k in range(1, steps + 1):
            t = t_edge + (t_next - t_edge) * k / steps
            corners.append((t, target + (value - target) * math.exp(-(t - t_edge) / tau_us)))
        value = corners[-1][1]
    return corners


def ideal_events(corners, theta_on, theta_off):
    """[(t_us float, polarity)] of an ideal pixel watching the piecewise-linear signal through ``corners``."""
    reference = corners[0][1]
    events = []
    for (t0, l0), (t1, l1) in zip(corners, corners[1:]):
        if l1 > l0:
            while reference + theta_on <= l1:
                reference += theta_on
                events.append((t0 + (reference - l0) / (l1 - l0) * (t1 - t0), True))
        elif l1 < l0:
            while reference - theta_off >= l1:
                reference -= theta_off
                events.append((t0 + (reference - l0) / (l1 - l0) * (t1 - t0), False))
    return events


def step_response_events(edges, end_us, tau_us, level0, theta_on, theta_off):
    """[(t_us float, polarity)] of an ideal pixel behind a first-order low-pass (time constant ``tau_us``) watching
    log-intensity steps: from ``level0``, at each edge ``(t_us, target)`` the signal starts to approach ``target``
    as ``target + (v - target) exp(-(t - t_edge) / tau)`` (``v`` its value at the edge), until the next edge or
    ``end_us``. Each crossing time is solved in closed form (the signal is monotone between edges)."""
    reference = value = float(level0)
    events = []
    bounds = [t for t, _ in edges[1:]] + [end_us]
    for (t_edge, target), t_next in zip(edges, bounds):
        def crossing(level):  # when the approach from value to target passes level (inf: never)
            remaining = (target - level) / (target - value)
            return t_edge - tau_us * math.log(remaining) if remaining > 0 else math.inf

        if target > value:
            while reference + theta_on < target and crossing(reference + theta_on) < t_next:
                reference += theta_on
                events.append((crossing(reference), True))
        elif target < value:
            while reference - theta_off > target and crossing(reference - theta_off) < t_next:
                reference -= theta_off
                events.append((crossing(reference), False))
        value = target + (value - target) * math.exp(-(t_next - t_edge) / tau_us)
    return events


def ideal_columns(waves, thresholds, width):
    """(t, x, y, p) arrays of ideal pixels watching ``waves`` (corner lists) with ``thresholds`` ((on, off) per pixel),
    pixel i at x = i % width, y = i // width, times rounded to whole microseconds, in time order (stable)."""
    t, x, y, p = [], [], [], []
    for i, (corners, (on, off)) in enumerate(zip(waves, thresholds)):
        for when, polarity in ideal_events(corners, on, off):
            t.append(int(np.floor(when + 0.5)))
            x.append(i % width)
            y.append(i // width)
            p.append(polarity)
    order = np.argsort(t, kind="stable")
    return np.array(t, np.int64)[order], np.array(x, int)[order], np.array(y, int)[order], np.array(p, bool)[order]
