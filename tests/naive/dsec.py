"""A DSEC sequence folder (Gehrig et al., RA-L 2021; dsec.ifi.uzh.ch, "data format"), written from its description
with h5py and OpenCV alone: ``events/left/events.h5`` (``events/{p,t,x,y}``, ``ms_to_idx``, ``t_offset``; times
relative to ``t_offset``), ``images/left/rectified/NNNNNN.png`` (8-bit colour) and ``images/timestamps.txt`` (one
image time a line, microseconds, on the events' clock with ``t_offset`` added), optionally
``images/left/exposure_timestamps.txt`` (``# exposure_start_timestamp_us, exposure_end_timestamp_us`` then a
``start, end`` line an image)."""

from __future__ import annotations

import os

import numpy as np


def write_dsec_sequence(folder, events, images, times_us, t_offset_us: int, exposures=None) -> None:
    """``events``: (t_us absolute, x, y, p) tuples in time order; ``images``: H x W x 3 uint8 arrays (BGR as OpenCV
    writes them) at ``times_us``; ``exposures``: (start, end) pairs per image, or None (no exposure file)."""
    import cv2
    import h5py

    os.makedirs(os.path.join(folder, "events", "left"))
    os.makedirs(os.path.join(folder, "images", "left", "rectified"))
    t = np.array([e[0] for e in events], dtype=np.int64) - t_offset_us
    with h5py.File(os.path.join(folder, "events", "left", "events.h5"), "w") as f:
        f.create_dataset("events/t", data=t.astype(np.uint32))
        f.create_dataset("events/x", data=np.array([e[1] for e in events], dtype=np.uint16))
        f.create_dataset("events/y", data=np.array([e[2] for e in events], dtype=np.uint16))
        f.create_dataset("events/p", data=np.array([e[3] for e in events], dtype=np.uint8))
        span_ms = int(t[-1] // 1000) + 1 if len(t) else 0
        f.create_dataset("ms_to_idx", data=np.searchsorted(t, np.arange(span_ms) * 1000).astype(np.uint64))
        f.create_dataset("t_offset", data=np.int64(t_offset_us))
    for k, image in enumerate(images):
        cv2.imwrite(os.path.join(folder, "images", "left", "rectified", f"{k:06d}.png"), image)
    with open(os.path.join(folder, "images", "timestamps.txt"), "w") as text:
        text.writelines(f"{int(t_us)}\n" for t_us in times_us)
    if exposures is not None:
        with open(os.path.join(folder, "images", "left", "exposure_timestamps.txt"), "w") as text:
            text.write("# exposure_start_timestamp_us, exposure_end_timestamp_us\n")
            text.writelines(f"{int(start)}, {int(end)}\n" for start, end in exposures)
