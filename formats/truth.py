"""The truth file of ``evtools simulate --truth`` (HDF5): what the simulation knows and the events cannot say.

Datasets: the per-pixel maps (``on``, ``off`` in log units, ``hot_pixels``, ``dead_pixels``, ``leak_rate_hz``),
``label`` (one uint8 per output event, in output order: see ``evtools.noise.LABELS``), optionally ``log_frames``
(float32, frames x height x width) with ``log_frame_t_us``, and an ``aps/`` group (the APS frames' times, the
scene's log intensity at each exposure's middle, the mean intensity over the exposure, the gain and offset maps).
Attributes: every parameter of the simulation. :func:`evtools.formats.thresholds.read_thresholds` and
``read_labels`` read it back.
"""

from __future__ import annotations

import contextlib
from typing import Any, Iterator

import numpy as np

from evtools import interrupt
from evtools.formats.errors import FormatError
from evtools.formats.io import output_stream

LOG_UNITS = "log intensity"


def _attribute(value):
    """An attribute value HDF5 stores (None as the empty text; a whole number beyond 64 bits, a seed of 2^64 or
    more, as its digits: HDF5 has no type for it, and it was a traceback)."""
    if isinstance(value, int) and not isinstance(value, bool) and not -2**63 <= value < 2**64:
        return str(value)
    return "" if value is None else value


class TruthWriter:
    """Writes one truth file as the simulation runs (:func:`create_truth`); every append goes to disk at once, so
    memory does not grow with the stream."""

    def __init__(self, h5) -> None:
        self._h5 = h5
        self._labels = self._log_frames = self._aps = None
        self._fingerprint = Fingerprint()

    def write_maps(self, maps: dict[str, np.ndarray]) -> None:
        """Per-pixel maps (height x width) as datasets (``on`` and ``off`` with their units), then the labels'."""
        for name, values in maps.items():
            self._h5.create_dataset(name, data=values)
            if name in ("on", "off"):
                self._h5[name].attrs["units"] = LOG_UNITS
        self._labels = self._h5.create_dataset("label", shape=(0,), maxshape=(None,), dtype=np.uint8,
                                               chunks=(1 << 16,), compression="gzip")

    def write_attributes(self, attributes: dict[str, Any]) -> None:
        for key, value in attributes.items():
            self._h5.attrs[key] = _attribute(value)

    def append_labels(self, labels: np.ndarray, events: np.ndarray) -> None:
        """The labels of the next output ``events``, in output order; the events go into the file's
        fingerprint (attribute ``events_fingerprint``: the labels are of these events, see :class:`Fingerprint`)."""
        start = self._labels.shape[0]
        self._labels.resize((start + len(labels),))
        self._labels[start:] = labels
        self._fingerprint.add(events)
        self._h5.attrs["events_fingerprint"] = self._fingerprint.value()

    def start_log_frames(self, width: int, height: int, rate_hz: float) -> None:
        """``log_frames`` and ``log_frame_t_us``, appended by :meth:`append_log_frame`."""
        shape = (0, height, width)
        frames = self._h5.create_dataset("log_frames", shape=shape, maxshape=(None, *shape[1:]), dtype=np.float32,
                                         chunks=(1, *shape[1:]), compression="gzip")
        times = self._h5.create_dataset("log_frame_t_us", shape=(0,), maxshape=(None,), dtype=np.int64,
                                        chunks=(1024,))
        frames.attrs["units"] = "log intensity (lin-log of the 0-255 frame)"
        self._h5.attrs["truth_frame_rate_hz"] = rate_hz
        self._log_frames = (frames, times)

    def append_log_frame(self, t_us: int, log_frame: np.ndarray) -> None:
        frames, times = self._log_frames
        n = frames.shape[0]
        frames.resize(n + 1, axis=0)
        frames[n] = log_frame.astype(np.float32)
        times.resize((n + 1,))
        times[n] = t_us

    def start_aps(self, gain: np.ndarray, offset: np.ndarray, parameters: dict[str, Any]) -> None:
        """The ``aps/`` group: the sensor's gain and offset maps and parameters; frames by :meth:`append_aps`."""
        group = self._h5.create_group("aps")
        shape = gain.shape
        group.create_dataset("gain", data=gain).attrs["units"] = "DN per intensity level per ms"
        group.create_dataset("offset", data=offset).attrs["units"] = "DN"
        for key, value in parameters.items():
            group.attrs[key] = value
        self._aps = {name: group.create_dataset(name, shape=(0,), maxshape=(None,), dtype=np.int64, chunks=(256,))
                     for name in ("t_us", "exposure_begin_us", "exposure_end_us")}
        for name in ("log_intensity", "mean_intensity"):
            self._aps[name] = group.create_dataset(name, shape=(0, *shape), maxshape=(None, *shape),
                                                   dtype=np.float32, chunks=(1, *shape), compression="gzip")

    def append_aps(self, values: dict[str, Any]) -> None:
        """One APS frame's truth: ``t_us``, ``exposure_begin_us``, ``exposure_end_us``, ``log_intensity``,
        ``mean_intensity``."""
        n = len(self._aps["t_us"])
        for name, dataset in self._aps.items():
            dataset.resize((n + 1, *dataset.shape[1:]))
            dataset[n] = values[name]


class Fingerprint:
    """A fingerprint of an event stream, whatever its chunks: the count and the sums (modulo 2^64) of t, x, y
    and p. A truth file keeps its events' (``events_fingerprint``), so that labels are never read against another
    stream of the same length: another seed's noise over the same recording has the same count (3 of 30 seeds on
    a small clip, a QA sweep) and scored TPR 0.68 / FPR 0.63 for 0.86 / 0.27, silently."""

    def __init__(self) -> None:
        self.sums = [0] * 5  # (Python integers, taken modulo 2^64)

    def add(self, events: np.ndarray) -> None:
        self.sums[0] += len(events)
        for k, name in enumerate(("t", "x", "y", "p"), start=1):  # (numpy's reduction wraps modulo 2^64)
            self.sums[k] = (self.sums[k] + int(np.sum(events[name].astype(np.uint64), dtype=np.uint64))) % 2**64

    def value(self) -> str:
        return ":".join(map(str, self.sums))


def check_labelled(truth_path: str, fingerprint: str | None, stream: Fingerprint, name: str) -> None:
    """An error when the truth file's events (``fingerprint``, its ``events_fingerprint``; None in older files:
    not checked) are not the stream ``name`` read (``stream``)."""
    if fingerprint is not None and fingerprint != stream.value():
        same_count = fingerprint.split(":")[0] == str(stream.sums[0])
        raise FormatError(f"{truth_path}: its labels are of another stream than {name} (the events differ"
                          f"{', though their count is the same' if same_count else ''}): give the truth file written "
                          "with that stream")


@contextlib.contextmanager
def create_truth(path: str) -> Iterator[TruthWriter]:
    """A :class:`TruthWriter` on ``path``, written under a temporary name and moved there when the block ends
    without error; a failed write (a full disk) is an error naming ``path``. A stop (Ctrl-C, SIGTERM) waits for
    the file's writes to end (inside them it would crash HDF5): the caller's loop sees it and stops."""
    import h5py

    try:
        with output_stream(path, binary_name="HDF5", needs_seek=True, option="--truth") as stream, \
                interrupt.deferred(), h5py.File(stream, "w") as h5:
            yield TruthWriter(h5)
    except (FormatError, BrokenPipeError):
        raise
    except OSError as error:
        raise FormatError(f"{path}: cannot write the truth ({error.strerror or error})") from None
