"""Thresholds files and ground-truth files (HDF5).

One layout serves ``simulate --truth``, ``estimate -o`` and ``correct --thresholds``: datasets ``on`` and ``off``
(height x width, float32, log intensity), optionally ``valid`` (height x width, bool) and, in a truth file,
``label`` (uint8 per event of the simulated stream, in output order: 0 signal, 1 leak, 2 shot, 3 hot pixel);
the method and its parameters as attributes of the file.
"""

from __future__ import annotations

import logging
import os
import re
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from evtools import interrupt
from evtools.events import label_problem
from evtools.formats.errors import FormatError
from evtools.formats.io import output_stream
from evtools.inputs import note_input
from evtools.formats.hdf5 import attribute, check_global_heaps
from evtools.formats.hdf5 import attributes as hdf5_attributes


_CAMERA = re.compile(r"[A-Za-z][A-Za-z0-9]*_[A-Za-z0-9]+")


def camera_of(source) -> str | None:
    """The camera a stream's ``source`` names, as DV writes it (model and serial: ``DAVIS346_00000104``), or None
    (a simulation, a file without it): a thresholds map keeps it as ``camera``, and ``correct`` compares them."""
    return source if isinstance(source, str) and _CAMERA.fullmatch(source) else None


@dataclass
class ThresholdMap:
    """Per-pixel ON and OFF contrast thresholds (log units), which pixels hold an estimate, and the attributes."""

    on: np.ndarray
    off: np.ndarray
    valid: np.ndarray
    attributes: dict[str, Any] = field(default_factory=dict)
    fit: np.ndarray | None = None
    """Per pixel, how well its events fit the estimation method's model (dataset ``fit``; None when absent)."""
    phase_us: np.ndarray | None = None
    """stimulus with fitted phases: per pixel, a valley time of its stimulus modulo the period, microseconds
    (dataset ``phase_us``, float64; NaN where none was fitted; None when absent)."""
    t_us: np.ndarray | None = None
    """A time series of maps (``estimate --online``): map k holds from ``t_us[k]`` on (int64, increasing), and
    ``on``, ``off``, ``valid``, ``fit`` have a leading time axis; None for a single map."""

    @property
    def width(self) -> int:
        return int(self.on.shape[-1])

    @property
    def height(self) -> int:
        return int(self.on.shape[-2])

    def usable(self) -> np.ndarray:
        """Pixels marked valid whose ON and OFF thresholds are both finite and positive."""
        with np.errstate(invalid="ignore"):
            return self.valid & np.isfinite(self.on) & np.isfinite(self.off) & (self.on > 0) & (self.off > 0)

    def stale(self):
        """A series' pixels whose estimate a map dropped (``fit`` infinite: the threshold stepped away), map by map;
        None for a single map or without ``fit``."""
        return None if self.t_us is None or self.fit is None else per_map(self.fit, np.isinf)

    def check_size(self, width: int, height: int, name: str) -> None:
        """Raise a :class:`FormatError` naming the file ``name`` unless the maps are ``height`` x ``width``."""
        if (self.width, self.height) != (width, height):
            raise FormatError(
                f"{name}: thresholds are {self.width}x{self.height} but the stream is {width}x{height}; "
                "give the thresholds of this sensor"
                + (f" (a stream that stores no size, as CSV or text, is as large as its events: give --sensor-size "
                   f"{self.width}x{self.height} if the thresholds are its sensor's)"
                   if width <= self.width and height <= self.height else "")
            )


def _open_h5(path: str):
    import h5py

    if path == "-":  # (stdin carries the events; HDF5 is read by seeking anyway)
        raise FormatError("-: a thresholds or truth file is HDF5, read from a path, not from stdin: give its path")
    if not os.path.exists(path):
        raise FormatError(f"{path}: no such file")
    if os.path.isdir(path):
        raise FormatError(f"{path}: a folder, not a thresholds file")
    note_input(path)
    source = path
    if not os.path.isfile(path):  # a pipe (a shell's <(...)), a FIFO: HDF5 reads by seeking, so from a copy
        import shutil
        import tempfile

        source = tempfile.TemporaryFile(prefix="evtools-thresholds-")
        with open(path, "rb") as pipe:
            shutil.copyfileobj(pipe, source, 1 << 20)
        source.seek(0)
    check_global_heaps(source, path)  # (its string attributes live there)
    try:
        return h5py.File(source, "r")
    except OSError:
        raise FormatError(f"{path}: cannot read it as HDF5") from None


def _text(value):
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.generic):
        return value.item()
    return value


def read_thresholds(path: str, series: bool = False) -> ThresholdMap:
    """Read a thresholds file (from ``estimate``) or a truth file (from ``simulate --truth``).

    Without a ``valid`` dataset every pixel is marked valid; :meth:`ThresholdMap.usable` also drops pixels whose
    thresholds are not finite and positive. A time series of maps (``estimate --online``: a ``t_us`` dataset and
    maps with a leading time axis) is returned whole with ``series``, else as its last map (the only one read).
    """
    with open_thresholds(path) as maps:
        if maps.t_us is None:
            return maps
        if not series:  # the latest map
            last = len(maps.t_us) - 1
            return ThresholdMap(maps.on[last], maps.off[last], maps.valid[last], maps.attributes,
                                None if maps.fit is None else maps.fit[last], maps.phase_us)
        return replace(maps, **{name: getattr(maps, name).read_all() for name in ("on", "off", "valid", "fit")
                                if getattr(maps, name) is not None})


class MapsOnDisk:
    """The maps of a series (``estimate --online``) left in its open file: ``[k]`` reads map k (height x width, one
    HDF5 chunk), through ``then`` when given; :meth:`through` adds a step (a crop of the sensor, a test)."""

    def __init__(self, dataset, dtype, path: str, then=None) -> None:
        self.dataset, self.dtype, self.path, self.then = dataset, dtype, path, then
        self.shape = (len(dataset), *self[0].shape)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, k: int) -> np.ndarray:
        try:
            values = np.asarray(self.dataset[k], dtype=self.dtype)
        except OSError as error:
            raise FormatError(f"{self.path}: cannot read map {k} of {self.dataset.name.lstrip('/')} ({error})") \
                from None
        return values if self.then is None else self.then(values)

    def through(self, step) -> "MapsOnDisk":
        """These maps, each through ``step`` (a function of one map) after what they go through now."""
        before = self.then
        return MapsOnDisk(self.dataset, self.dtype, self.path,
                          step if before is None else (lambda values: step(before(values))))

    def read_all(self) -> np.ndarray:
        """Every map, in one array (maps, height', width')."""
        if self.then is not None:
            return np.stack([self[k] for k in range(len(self))])
        try:
            return np.asarray(self.dataset[()], dtype=self.dtype)
        except OSError as error:
            raise FormatError(f"{self.path}: cannot read the maps of {self.dataset.name.lstrip('/')} ({error})") \
                from None


def per_map(maps, step):
    """``step`` (a function of maps with any leading axes: numpy's) applied to ``maps``: an array at once, the maps
    of a :class:`MapsOnDisk` one by one as they are read."""
    return maps.through(step) if isinstance(maps, MapsOnDisk) else step(maps)


@contextmanager
def open_thresholds(path: str):
    """The maps of a thresholds or truth file as a :class:`ThresholdMap` for the block's length; a series' maps
    (``on``, ``off``, ``valid``, ``fit``) stay on disk as :class:`MapsOnDisk`, read one at a time, so ``correct``
    with a series of any length holds a few maps, not the file (:func:`read_thresholds` reads them all)."""
    import h5py

    with _open_h5(path) as h5:
        missing = [name for name in ("on", "off") if not isinstance(h5.get(name), h5py.Dataset)]
        if missing:
            raise FormatError(
                f"{path}: no dataset {' or '.join(missing)} (a thresholds file has datasets on and off, "
                "height x width: write one with `evtools estimate` or `evtools simulate --truth`)"
            )
        try:
            on, off, valid, fit, phase_us, t_us = _maps(h5, path)
        except OSError:  # a compression filter HDF5 lacks (Zstd, Blosc...): hdf5plugin's, loaded only now (6 MiB)
            try:
                import hdf5plugin  # noqa: F401
                on, off, valid, fit, phase_us, t_us = _maps(h5, path)
            except (ImportError, OSError) as error:
                raise FormatError(f"{path}: cannot read the maps ({error})") from None
        attributes = {key: _text(value) for key, value in hdf5_attributes(h5, source=path).items()}
        units = _text(attribute(h5["on"], "units", "", source=path))
        maps = (valid, fit)
        if t_us is not None:
            if (t_us.ndim != 1 or not np.issubdtype(t_us.dtype, np.integer) or len(on.shape) != 3
                    or len(on) != len(t_us)):
                raise FormatError(f"{path}: a series of maps needs t_us (integer microseconds, one per map) and maps "
                                  "of maps x height x width")
            if not len(t_us):
                raise FormatError(f"{path}: a series of maps that holds no map (an online estimate stopped before "
                                  "its first interval ended)")
            if np.any(np.diff(t_us) <= 0):
                k = int(np.argmax(np.diff(t_us) <= 0)) + 1
                raise FormatError(f"{path}: the maps' times are out of order (t_us[{k}] = {int(t_us[k])} is not "
                                  f"after t_us[{k - 1}] = {int(t_us[k - 1])})")
        elif len(on.shape) != 2:
            raise FormatError(f"{path}: datasets on, off must be height x width arrays (or a series with t_us)")
        if on.shape != off.shape or any(m is not None and m.shape != on.shape for m in maps) or (
                phase_us is not None and phase_us.shape != on.shape[-2:]):
            raise FormatError(
                f"{path}: datasets on, off (and valid, fit, phase_us) must be height x width arrays of one shape"
            )
        dead = h5.get("dead_pixels")  # a truth file (simulate --truth): a dead pixel's thresholds (100) are no estimate
        if valid is None and t_us is None and isinstance(dead, h5py.Dataset) and dead.shape == on.shape:
            valid = ~np.asarray(dead[()], dtype=bool)
        if valid is None:
            valid = np.ones(on.shape, dtype=bool) if t_us is None else on.through(_all_valid)
        attributes.setdefault("units", units)
        if attributes.get("partial"):  # (an estimate stopped midway: its maps are of part of the stream)
            stopped = f"{attributes.get('stopped_by', 'stopped')} at {int(attributes.get('stopped_at_us', 0)):,} us"
            logging.getLogger("evtools").warning(f"{path}: estimated from part of its stream ({stopped})")
        if attributes.get("cut"):  # (estimated from a recording whose file was cut: said as a cut stream is)
            logging.getLogger("evtools").warning(f"{path}: {attributes['cut']}")
        yield ThresholdMap(on, off, valid, attributes, fit, phase_us, None if t_us is None else t_us.astype(np.int64))


def _all_valid(values: np.ndarray) -> np.ndarray:
    """A series without ``valid``: every pixel of a map valid."""
    return np.ones(values.shape, bool)


def _maps(h5, path: str):
    """on, off, valid, fit, phase_us, t_us of an open thresholds file (None for those it lacks); the maps of a
    series (t_us, and maps x height x width) as :class:`MapsOnDisk` (their first map read: a missing compression
    filter fails here)."""
    import h5py

    t_us = h5.get("t_us")
    t_us = np.asarray(t_us[()]) if isinstance(t_us, h5py.Dataset) else None

    def read(name, dtype=None):
        dataset = h5.get(name)
        if not isinstance(dataset, h5py.Dataset):
            return None
        if t_us is not None and dataset.ndim == 3 and len(dataset) > 0:
            return MapsOnDisk(dataset, dtype, path)
        return np.asarray(dataset[()], dtype=dtype)

    return (read("on", np.float32), read("off", np.float32), read("valid", bool), read("fit", np.float32),
            read("phase_us", np.float64), t_us)


def write_thresholds(path: str, thresholds: ThresholdMap) -> None:
    """Write ``on``, ``off``, ``valid`` (and ``fit`` when known) and the attributes to ``path`` atomically."""
    with _hdf5_output(path) as (h5, _):
        with interrupt.deferred():  # (a stop inside HDF5's writes would crash it: it waits until the file is made)
            _fill(h5, thresholds)


@contextmanager
def _hdf5_output(path: str):
    """An HDF5 file written atomically at ``path`` (:func:`output_stream`), as ``(file, held)``: it takes its name
    when the block ends without an error; when the block or the closing raises, none is left, the file and the
    h5py objects the block put in ``held`` are abandoned (:func:`evtools.formats.hdf5.abandon`), and an OSError
    (a full disk) becomes one line naming ``path``."""
    import h5py

    from evtools.formats.hdf5 import abandon

    with output_stream(path, binary_name="HDF5", needs_seek=True) as stream:
        with interrupt.deferred():
            h5 = h5py.File(stream, "w")
        held: list = []
        try:
            yield h5, held
            with interrupt.deferred():
                h5.close()  # HDF5 writes its last blocks through the stream here: a full disk fails here
        except OSError as error:
            abandon(h5, *held)
            raise FormatError(f"{path}: cannot write ({error.strerror or error})") from None
        except BaseException:
            abandon(h5, *held)
            raise


UNITS = {"on": "log intensity", "off": "log intensity",
         "fit": "thresholds (RMS deviation of the level changes; a change that does not fit: 1)",
         "t_us": "us (map k holds from t_us[k] on)", "phase_us": "us (a valley of the stimulus, modulo its period)"}
"""The ``units`` attribute of each dataset of a thresholds file."""


def _fill(h5, thresholds: ThresholdMap) -> None:
    """The datasets and attributes of a thresholds file."""
    for name in ("on", "off"):
        h5.create_dataset(name, data=np.asarray(getattr(thresholds, name), dtype=np.float32))
    h5.create_dataset("valid", data=np.asarray(thresholds.valid, dtype=bool))
    if thresholds.fit is not None:
        h5.create_dataset("fit", data=np.asarray(thresholds.fit, dtype=np.float32))
    if thresholds.t_us is not None:
        h5.create_dataset("t_us", data=np.asarray(thresholds.t_us, dtype=np.int64))
    _finish(h5, thresholds.attributes, thresholds.phase_us)


def _finish(h5, attributes: dict, phase_us: np.ndarray | None) -> None:
    """``phase_us`` (when known), the datasets' units and the file's attributes."""
    if phase_us is not None:
        h5.create_dataset("phase_us", data=np.asarray(phase_us, dtype=np.float64))
    for name, units in UNITS.items():
        if name in h5:
            h5[name].attrs["units"] = units
    for key, value in attributes.items():
        if key == "units":
            continue
        h5.attrs[key] = value if not isinstance(value, (dict, list, tuple)) else str(value)


class SeriesFile:
    """A time series of maps (``estimate --online``) written map by map as an online estimate makes them
    (:func:`series_file`): the file's layout is :func:`write_thresholds`' for a series, its datasets chunked one map
    a chunk and grown along the time axis, so the run's length is bounded by the disk, not by memory."""

    def __init__(self, h5, path: str, width: int, height: int) -> None:
        self.h5, self.path, self.count, self.failed = h5, path, 0, False
        self.last_t_us: int | None = None
        self.any_valid = False  # whether any map has a valid pixel
        # (held for the file's life: an h5py object freed after a failed write writes again as it goes, and prints
        # the failure as an ignored exception; on failure :func:`series_file` abandons them with the file)
        self.datasets = {name: h5.create_dataset(name, shape=(0, height, width), maxshape=(None, height, width),
                                                 dtype=dtype, chunks=(1, height, width))
                         for name, dtype in (("on", np.float32), ("off", np.float32), ("valid", bool),
                                             ("fit", np.float32))}
        self.datasets["t_us"] = h5.create_dataset("t_us", shape=(0,), maxshape=(None,), dtype=np.int64,
                                                  chunks=(4096,))

    def append(self, t_us: int, on, off, valid, fit) -> None:
        """Map ``t_us`` (after the previous one): ``on``, ``off``, ``fit`` height x width, NaN where not valid."""
        with interrupt.deferred():  # (a stop inside HDF5's writes would crash it)
            try:
                for name, value in (("on", on), ("off", off), ("valid", valid), ("fit", fit), ("t_us", t_us)):
                    self.datasets[name].resize(self.count + 1, axis=0)
                    self.datasets[name][self.count] = value
            except OSError as error:
                self.failed = True
                raise FormatError(f"{self.path}: cannot write ({error.strerror or error})") from None
        self.count += 1
        self.last_t_us = int(t_us)
        self.any_valid = self.any_valid or bool(np.any(valid))

    def finish(self, attributes: dict, phase_us: np.ndarray | None = None) -> None:
        """The file's attributes (and the stimulus phases), once every map is in."""
        with interrupt.deferred():
            _finish(self.h5, attributes, phase_us)


@contextmanager
def series_file(path: str, width: int, height: int):
    """A :class:`SeriesFile` at ``path``, written atomically: the file takes its name when the block ends without
    an error (call :meth:`SeriesFile.finish` first), and none is left when it raises."""
    with _hdf5_output(path) as (h5, held):
        maps = SeriesFile(h5, path, width, height)
        held.append(maps)
        yield maps


def read_labels(path: str) -> tuple[np.ndarray, str | None]:
    """The per-event ``label`` dataset of a truth file (uint8: 0 signal, 1 leak, 2 shot, 3 hot pixel) and the
    fingerprint of the events they label (``events_fingerprint``, see :class:`evtools.formats.truth.Fingerprint`;
    None in files written before it). Labels that are not one whole number from 0 to 3 per event are an error (a
    label of 7 vanished from every count, -1 scored a held-out AUC of 1.0: a QA sweep)."""
    import h5py

    with _open_h5(path) as h5:
        dataset = h5.get("label")
        if not isinstance(dataset, h5py.Dataset):
            raise FormatError(
                f"{path}: no dataset label (per-event labels are written by `evtools simulate ... --truth FILE`)"
            )
        if dataset.ndim != 1 or dataset.dtype.kind not in "iu":  # (before the read: its values are checked below)
            raise FormatError(f"{path}: labels must be one whole number per event (1-D integers), not "
                              f"{dataset.dtype} of shape {dataset.shape}")
        try:
            labels = dataset[()]
        except OSError as error:
            raise FormatError(f"{path}: cannot read the labels ({error})") from None
        problem = label_problem(labels)
        if problem:
            raise FormatError(f"{path}: {problem}")
        fingerprint = h5.attrs.get("events_fingerprint")
        return labels.astype(np.uint8), None if fingerprint is None else _text(fingerprint)
