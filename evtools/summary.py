"""Summary statistics of a stream, accumulated chunk by chunk (what ``evtools info`` prints)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evtools.events import StreamInfo


@dataclass
class StreamSummary:
    """Event count, time span and ON count of a stream; ``add`` chunks in order, then read the properties."""

    events: int = 0
    on_events: int = 0
    t_first_us: int | None = None
    t_last_us: int | None = None

    def add(self, chunk: np.ndarray) -> None:
        if not len(chunk):
            return
        if self.t_first_us is None:
            self.t_first_us = int(chunk["t"][0])
        self.t_last_us = int(chunk["t"][-1])
        self.events += len(chunk)
        self.on_events += int(np.count_nonzero(chunk["p"]))

    @property
    def duration_s(self) -> float:
        return 0.0 if self.t_first_us is None else (self.t_last_us - self.t_first_us) * 1e-6

    @property
    def rate_hz(self) -> float:
        """Events per second over the span (0 for fewer than two distinct timestamps)."""
        return self.events / self.duration_s if self.duration_s > 0 else 0.0

    @property
    def on_fraction(self) -> float:
        return self.on_events / self.events if self.events else float("nan")

    def as_dict(self, info: StreamInfo) -> dict:
        return {
            "format": info.format,
            "width": info.width,
            "height": info.height,
            "events": self.events,
            "t_first_us": self.t_first_us,
            "t_last_us": self.t_last_us,
            "duration_s": self.duration_s,
            "rate_hz": self.rate_hz,
            "on_fraction": None if not self.events else self.on_fraction,
            "metadata": info.metadata,
        }
