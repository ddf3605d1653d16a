"""Summary statistics of a stream, accumulated chunk by chunk (what ``evtools info`` prints)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evtools.events import StreamInfo


@dataclass
class StreamSummary:
    """Event count, time span and ON count of a stream; ``add`` chunks in order, then read the properties."""

    events: int = 0
    on_events: int = 0
    t_first_us: int | None = None
    t_last_us: int | None = None
    frame_times_us: list = field(default_factory=list)  # each APS frame's end of exposure
    frame_exposures_us: list = field(default_factory=list)
    frame_sizes: set = field(default_factory=set)
    frame_dtypes: set = field(default_factory=set)

    def add_frames(self, frames) -> None:
        """APS frames (:class:`evtools.Frame`) of the stream."""
        for frame in frames:
            self.frame_times_us.append(frame.order_us)
            self.frame_exposures_us.append(frame.exposure_us)
            self.frame_sizes.add((frame.width, frame.height))
            self.frame_dtypes.add(str(frame.image.dtype))

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
            "frames": self.frames_dict(),
            # (the side streams' XML attributes, kept for an AEDAT 4.0 output, are not shown: their names are in
            # "skipped_streams")
            "metadata": {key: value for key, value in info.metadata.items() if key != "side_streams"},
        }

    def frames_dict(self) -> dict:
        """APS frames: count, rate (frames per second over their span), exposure (min, median, max us), sizes and
        pixel types."""
        times, exposures = np.asarray(self.frame_times_us), np.asarray(self.frame_exposures_us)
        span_s = (times[-1] - times[0]) * 1e-6 if len(times) > 1 else 0.0
        return {
            "count": len(times),
            "rate_hz": (len(times) - 1) / span_s if span_s > 0 else 0.0,
            "exposure_us": [int(exposures.min()), float(np.median(exposures)), int(exposures.max())]
            if len(exposures) else None,
            "sizes": sorted(f"{w}x{h}" for w, h in self.frame_sizes),
            "pixels": sorted(self.frame_dtypes),
        }
