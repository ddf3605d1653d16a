"""Slow reference of evtools.transform: one event at a time, written from the option descriptions."""

from __future__ import annotations


def naive_transform(events, width, height, start_us=None, end_us=None, polarity=None, crop=None, flip_x=False,
                    flip_y=False, transpose=False):
    """``events``: (t, x, y, p) tuples; start/end relative to the first event. Returns (tuples, (width, height))."""
    kept = []
    first = events[0][0] if events else 0
    if crop:
        cx, cy, cw, ch = crop
        width, height = cw, ch
    for t, x, y, p in events:
        if start_us is not None and t < first + start_us:
            continue
        if end_us is not None and t >= first + end_us:
            continue
        if polarity == "on" and not p or polarity == "off" and p:
            continue
        if crop:
            if not (cx <= x < cx + cw and cy <= y < cy + ch):
                continue
            x, y = x - cx, y - cy
        if flip_x:
            x = width - 1 - x
        if flip_y:
            y = height - 1 - y
        if transpose:
            x, y = y, x
        kept.append((t, x, y, p))
    return kept, ((height, width) if transpose else (width, height))
