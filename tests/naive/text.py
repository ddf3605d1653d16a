"""Slow reference of the text readers: line by line with Python's ``str.split``, ``int`` and ``float``, written
from the format descriptions (rpg ``events.txt``: ``t x y p`` with t in seconds; CSV ``t,x,y,p`` with t in
microseconds)."""

from __future__ import annotations


def naive_text_events(lines: list[str], csv: bool) -> list[tuple[int, int, int, int]]:
    """(t_us, x, y, p) of every non-blank line: t in seconds rounded to the nearest microsecond (ties to even, as
    ``round`` does) for whitespace-separated text, whole microseconds for CSV (a CSV time with a fraction is
    refused: the generators write none); p is 1 when positive."""
    rows = []
    for line in lines:
        fields = [field.strip() for field in line.split(",")] if csv else line.split()
        if csv and not line.strip("\r"):
            continue
        if not csv and not fields:
            continue
        rows.append(fields[:4])
    floats = not csv or any("." in field for row in rows for field in row)
    events = []
    for t, x, y, p in rows:
        if floats:
            seconds = float(t)
            t_us = round(seconds * 1e6) if not csv else round(seconds)
            events.append((t_us, int(float(x)), int(float(y)), int(float(p) > 0)))
        else:
            events.append((int(t), int(x), int(y), int(int(p) > 0)))
    return events
