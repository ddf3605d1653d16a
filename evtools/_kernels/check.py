"""The stream check (:class:`evtools.events.StreamChecker`) in one pass: every chunk a reader gives is checked
(on the sensor, polarity 0 or 1, time in range and never going backwards), and numpy's six strided passes over the
16-byte events cost 10 ns an event (0.2 s of 20M events, as much as reading them).

The kernel finds the first event of each kind of fault; the checker raises them in its order, so the messages are
those of the passes it replaces."""

from __future__ import annotations

from evtools._kernels.jit import kernel


@kernel
def first_faults(t, x, y, p, width, height, last_t, has_last, max_time):  # pragma: no cover - compiled
    """Indices (-1: none) of the first event off the ``width x height`` sensor, with a polarity byte above 1, with
    a time beyond ``+-max_time``, and earlier than the event before it (the one before the chunk: ``last_t``, when
    ``has_last``)."""
    outside = polarity = out_of_range = backwards = -1
    previous = last_t
    check_order = has_last
    for i in range(t.size):
        xi, yi, ti = x[i], y[i], t[i]
        if outside < 0 and (xi < 0 or xi >= width or yi < 0 or yi >= height):
            outside = i
        if polarity < 0 and p[i] > 1:
            polarity = i
        if out_of_range < 0 and (ti < -max_time or ti > max_time):
            out_of_range = i
        if backwards < 0 and check_order and ti < previous:
            backwards = i
        previous = ti
        check_order = True
    return outside, polarity, out_of_range, backwards
