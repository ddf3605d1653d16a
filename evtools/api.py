"""The Python API: read and write event files, and run the command line's processors on arrays.

Every function here is a thin door onto the objects the command line uses (no second implementation): files
through :mod:`evtools.formats`, the processors through :mod:`evtools.filters`, :mod:`evtools.estimation`,
:mod:`evtools.correction`, :mod:`evtools.simulation` and :mod:`evtools.noise`. Events are numpy structured arrays
of :data:`evtools.EVENT_DTYPE` (``t`` int64 microseconds, ``x``, ``y`` int16, ``p`` bool ON; 16 bytes, the AEDAT
4.0 event), in time order; :class:`evtools.StreamInfo` carries the sensor size.

Heavy modules (h5py, OpenCV, numba) are imported inside the functions, so ``import evtools`` stays fast.

Examples
--------
>>> import evtools
>>> events, truth = evtools.simulate("flicker", size=(16, 12), duration_us=1_000_000, seed=1)
>>> info = evtools.StreamInfo(16, 12)
>>> kept = evtools.bafilter(events, info, method="baf", dt_us=100_000)
>>> thresholds = evtools.estimate(kept, info, method="stimulus")
>>> bool(abs(float(thresholds.on.mean()) / float(truth["on"].mean()) - 1) < 0.02)
True
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import logging
import os
import tempfile
from typing import Any, Iterable, Iterator

import numpy as np

from evtools.errors import EvtoolsError, InvalidEventsError
from evtools.events import (EVENT_DTYPE, StreamChecker, StreamInfo, as_chunk, empty_events, event_fields,
                            parse_sensor_size)

__all__ = [
    "bafilter", "correct", "estimate", "from_columns", "from_dv", "from_tonic", "inject_noise", "open", "read",
    "simulate", "to_columns", "to_dv", "to_tonic", "write", "writer",
]

def read(path: str | os.PathLike, *, frames: bool = False, **options) -> tuple:
    """Read a whole event file into memory.

    Parameters
    ----------
    path : str or path-like
        An event file (AEDAT 2.0/3.1/4.0, HDF5, Prophesee RAW/DAT, CSV, text), recognised by its magic bytes then
        its extension; ``"-"`` reads standard input.
    **options
        ``options``: a :class:`evtools.ReadOptions` (how the command line reads: ``format`` as
        ``--input-format``, ``sensor_size`` ((width, height) or "WxH": ``--sensor-size``), ``aedat2_layout``,
        ``chunk_events``, ``max_latency_s`` (``--max-latency``), ``connect_timeout_s`` and ``read_timeout_s``
        (``--timeout``)), and/or any of its fields as keywords; ``check`` (default True: raise at the first event
        outside the sensor or earlier than the one before it).

    Returns
    -------
    events : ndarray of EVENT_DTYPE
    info : StreamInfo, (width, height) or "WxH"
        Sensor size, format and what the file said about itself (``metadata``; ``frame_size`` when it has APS
        frames; ``cut``: True when the file turned out cut, then :func:`write` marks its output cut too).
    frames : list of evtools.Frame
        Only with ``frames=True``: the APS frames (a DAVIS camera's intensity images) in the file's order, each
        with its image and five times (:class:`evtools.Frame`); empty where the file has none.

    Examples
    --------
    >>> import evtools, tempfile, os
    >>> events = evtools.from_columns([0, 5, 5], [1, 2, 3], [0, 0, 1], [True, False, True])
    >>> path = os.path.join(tempfile.mkdtemp(), "three.aedat4")
    >>> evtools.write(path, events, evtools.StreamInfo(4, 2))
    >>> back, info = evtools.read(path)
    >>> (info.width, info.height, back["t"].tolist(), back["x"].tolist())
    (4, 2, [0, 5, 5], [1, 2, 3])
    """
    with open(path, **options) as stream:
        events = stream.read_all()
        if stream.was_cut:  # (said in a warning; evtools.write of this info marks its output cut in turn)
            stream.info.metadata["cut"] = True
        if frames:
            return events, stream.info, stream.take_frames()
        return events, stream.info


def open(path: str | os.PathLike | None = None, **options):  # noqa: A001 - the name users expect (evtools.open)
    """Open an event file for streaming: a context manager whose ``info`` is known at once and which yields
    chunks (arrays of EVENT_DTYPE, about a million events each) in time order.

    Parameters are those of :func:`read`; ``None`` or ``"-"`` reads standard input.

    Examples
    --------
    >>> import evtools, tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "e.csv")
    >>> evtools.write(path, evtools.from_columns([1, 2], [0, 1], [0, 0], [1, 0]), evtools.StreamInfo(2, 1))
    >>> with evtools.open(path, sensor_size=(2, 1)) as stream:
    ...     sum(len(chunk) for chunk in stream)
    2
    """
    from evtools.formats import open_events

    return open_events(path, **options)


def write(path: str | os.PathLike, events: np.ndarray, info: StreamInfo, frames=(), **options) -> None:
    """Write ``events`` to ``path`` (atomically: the file appears complete or not at all).

    Parameters
    ----------
    path : str or path-like
        The output; its extension chooses the format unless ``format`` is given (``"-"``: standard output, AEDAT
        4.0).
    events : ndarray of EVENT_DTYPE
    info : StreamInfo, (width, height) or "WxH"
    frames : sequence of evtools.Frame
        APS frames to write among the events, each after the events before the end of its exposure (AEDAT 4.0 and
        HDF5; other formats store none and say so). ``info.metadata["frame_size"]`` gives the frame stream's size;
        without it, the sensor's.
    **options
        ``format`` (aedat4, aedat2, hdf5, csv, txt), ``compression`` (AEDAT 4.0: lz4, zstd, none; HDF5: the
        filter), ``aedat2_layout`` - the command line's output options.
    """
    info = _stream_info(info)
    frames = list(frames)
    if frames and not info.metadata.get("frame_size"):
        info = dataclasses.replace(info, metadata={**info.metadata, "frame_size": (info.width, info.height)})
    with writer(path, info, **options) as sink:
        start = 0
        for frame in frames:
            end = int(np.searchsorted(events["t"], frame.order_us, "right"))
            sink.write(events[start:end])
            sink.write_frame(frame)
            start = max(start, end)
        sink.write(events[start:])


@contextlib.contextmanager
def writer(path: str | os.PathLike | None, info: StreamInfo, **options) -> Iterator[Any]:
    """A streaming writer: ``with evtools.writer(path, info) as sink: sink.write(chunk)`` for each chunk, in time
    order. Options as for :func:`write`. The file takes its name only when the block ends without an error.

    Examples
    --------
    >>> import evtools, tempfile, os
    >>> path = os.path.join(tempfile.mkdtemp(), "two.h5")
    >>> with evtools.writer(path, evtools.StreamInfo(8, 8)) as sink:
    ...     sink.write(evtools.from_columns([0], [1], [2], [1]))
    ...     sink.write(evtools.from_columns([9], [3], [4], [0]))
    >>> len(evtools.read(path)[0])
    2
    """
    from evtools.formats import create_events

    info = _stream_info(info)
    if "side_streams" in info.metadata:  # (a recording's IMU and trigger streams: their packets go by the command
        # line's pipeline only, so a file written here does not declare them empty)
        info = dataclasses.replace(info, metadata={k: v for k, v in info.metadata.items() if k != "side_streams"})
    with create_events(path, info, **options) as sink:
        yield _CheckedSink(sink, info)
        sink.cut = bool(info.metadata.get("cut"))  # (a cut input's events: the output says so, or is refused)


def _stream_info(info) -> StreamInfo:
    """``info`` as a :class:`StreamInfo`: one, or a sensor size, ``(width, height)`` or ``"WxH"``."""
    if isinstance(info, StreamInfo):
        return info
    try:
        return StreamInfo(*parse_sensor_size(info))
    except InvalidEventsError as error:
        raise EvtoolsError(f"info must be an evtools.StreamInfo or a sensor size, (width, height) or 'WxH': "
                           f"{error}") from None


class _CheckedSink:
    """A writer's sink whose chunks are checked first (on the sensor, in time order; :class:`StreamChecker`), so
    that no file is written with events its readers would refuse."""

    def __init__(self, sink, info: StreamInfo) -> None:
        self.sink, self.checker = sink, StreamChecker(info)
        self.frame_size = info.metadata.get("frame_size") or (info.width, info.height)
        self.frames = 0
        self.last_frame_us: int | None = None

    def write(self, chunk) -> None:
        if len(chunk):
            self.sink.write(self.checker.check(chunk))

    def write_frame(self, frame) -> None:
        """The frame, once it is one the readers take back (:func:`evtools.frames.frame_problem`; unchecked, AEDAT 4.0
        stored a colour image as a damaged packet, floats cut to 0 or 1 and large integers wrapped, silently)."""
        from evtools.frames import frame_problem

        problem = frame_problem(frame, self.frame_size, self.last_frame_us)
        if problem:
            raise InvalidEventsError(f"frame {self.frames} (t {frame.t_us} us) {problem}")
        self.last_frame_us = frame.order_us
        self.frames += 1
        self.sink.write_frame(frame)


def bafilter(events: np.ndarray, info: StreamInfo, method: str = "baf", **params) -> np.ndarray:
    """Remove background-activity noise: the events the filter keeps (``evtools bafilter``).

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
    info : StreamInfo, (width, height) or "WxH"
    method : str
        METHODS_TEXT
    preset : {"evtools", "dv", "jaer"}
        Semantics and defaults (README, section Bafilter).
    **params
        The filters' parameters, named as on the command line (listed below, from the filters' declarations;
        None or absent: the preset's default). One that no method of the chain has is refused.

    Examples
    --------
    >>> import evtools
    >>> lone = evtools.from_columns([0, 1_000_000], [3, 9], [3, 9], [1, 1])   # two events far apart
    >>> len(evtools.bafilter(lone, evtools.StreamInfo(16, 16), dt_us=10_000))
    0
    """
    from evtools.filters import ba_filter

    info = _stream_info(info)
    return ba_filter(events, info.width, info.height, method, **params)


def estimate(events: np.ndarray, info: StreamInfo, method: str = "offe", **params):
    """Every pixel's ON and OFF contrast thresholds (``evtools estimate``): a :class:`ThresholdEstimate` with
    ``on``, ``off`` (height x width, log units), ``valid``, ``fit`` and the attributes.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
    info : StreamInfo, (width, height) or "WxH"
    method : {"offe", "stimulus", "natural"}
        offE (Wang et al., ACRA 2019), a known calibration stimulus (absolute; Nozaki & Delbruck 2017), or an
        ordinary moving scene (counts against the neighbours').
    **params
        :class:`evtools.estimation.ThresholdEstimator`'s parameters: ``stimulus`` (a
        :class:`evtools.estimation.Stimulus`; default for ``method="stimulus"``: ``simulate``'s flicker),
        ``phase``, ``nominal``, ``segment_us``, ``min_events``, ``max_fit``, ``radius_px``, ``interval_us`` and
        ``forget_us`` (online: the result's ``series``).

    Examples
    --------
    >>> import evtools
    >>> events, truth = evtools.simulate("flicker", size=(8, 6), duration_us=2_000_000, seed=3)
    >>> result = evtools.estimate(events, evtools.StreamInfo(8, 6), method="stimulus")
    >>> bool(result.valid.all()), bool(abs(result.on / truth["on"] - 1).max() < 0.01)
    (True, True)
    """
    from evtools.estimation import Stimulus, estimate_thresholds

    if method == "stimulus":
        params.setdefault("stimulus", Stimulus())
    info = _stream_info(info)
    return estimate_thresholds(events, info.width, info.height, method, **params)


def correct(events: np.ndarray, info: StreamInfo, thresholds, **params) -> np.ndarray:
    """Re-sample every pixel's events at one target threshold (``evtools correct``; the founding report's
    section 4.2).

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
    info : StreamInfo, (width, height) or "WxH"
    thresholds : ThresholdEstimate, ThresholdMap, str or path-like
        An estimate (:func:`estimate`), a thresholds map, or a thresholds or truth file (HDF5); an online
        estimate's series is used map by map.
    **params
        :class:`evtools.correction.ThresholdCorrector`'s parameters: ``target`` (a number or ``"median"``;
        default 0.2, the command line's),
        ``mode`` (exponential, highpass, turns, step, foh), ``hold_us``, ``max_gap_us``, ``tau_us``.

    Examples
    --------
    >>> import evtools
    >>> events, truth = evtools.simulate("flicker", size=(4, 3), duration_us=1_000_000, seed=2,
    ...                                  sigma_thres=0.05, leak_rate_hz=0)
    >>> corrected = evtools.correct(events, evtools.StreamInfo(4, 3), truth, target=0.2)
    >>> counts = evtools.to_columns(corrected)[1].size
    >>> bool(counts > 0)
    True
    """
    from evtools.formats.thresholds import open_thresholds, per_map

    if isinstance(thresholds, (str, os.PathLike)):
        with open_thresholds(os.fspath(thresholds)) as maps:  # (a series' maps are read as the events reach them)
            return correct(events, info, maps, **params)
    from evtools.correction import correct_thresholds

    if isinstance(thresholds, dict):  # simulate()'s truth
        on, off, valid = thresholds["on"], thresholds["off"], None
    elif getattr(thresholds, "series", None) is not None:  # an online ThresholdEstimate
        series = thresholds.series
        on, off, valid, params["t_us"] = series.on, series.off, series.valid, series.t_us
        params.setdefault("stale", np.isinf(series.fit))
    elif all(hasattr(thresholds, name) for name in ("on", "off", "valid")):
        on, off, valid = thresholds.on, thresholds.off, thresholds.valid
        if getattr(thresholds, "t_us", None) is not None:
            params["t_us"] = thresholds.t_us
            if getattr(thresholds, "fit", None) is not None:
                params.setdefault("stale", per_map(thresholds.fit, np.isinf))
    else:
        raise EvtoolsError(f"thresholds must be an estimate (evtools.estimate), a thresholds map, a thresholds or "
                           f"truth file's path, or simulate()'s truth; got {type(thresholds).__name__} "
                           f"(a target threshold is the target= parameter)")
    info = _stream_info(info)
    return correct_thresholds(events, info.width, info.height, on, off, valid, **params)


def simulate(source: str | os.PathLike | Iterable[tuple[int, np.ndarray]] = "flicker", *, size=None,
             duration_us: int = 1_000_000, frame_rate: float | None = None, scene: dict | None = None,
             **parameters) -> tuple[np.ndarray, dict]:
    """Simulate a DVS (``evtools simulate``): v2e's pixel model (Hu, Liu, Delbruck 2021) with ESIM's per-pixel
    crossing times (Rebecq et al. 2018).

    Parameters
    ----------
    source : str, path or iterable of (t_us, frame)
        A built-in scene's name (flicker, gradient, bars, step, static, texture), a video file or a folder of
        images (with its ``timestamps.txt``, else ``frame_rate``), as ``evtools simulate`` reads them, or frames:
        times in microseconds, increasing (a fractional time is rounded to the microsecond), and gray intensity
        images (height x width, 0-255 with white 255, brighter allowed; frames within 0-1 are warned of).
    size : (width, height) or "WxH", optional
        The scene's size (default 346 x 260), or the size a video's or folder's frames are resized to.
    duration_us : int
        The scene's length (a built-in scene only).
    frame_rate : float, optional
        Frames per second of a video that does not say it, or of a folder without timestamps.
    scene : dict, optional
        The scene's options (``period_s``, ``speed_px_s``, ``profile``, ``phase_spread``, ``image``, ...).
    **parameters
        :class:`evtools.simulation.DvsSimulator`'s: ``seed``, ``pos_thres``, ``sigma_thres``, ``cutoff_hz``,
        ``leak_rate_hz``, ``shot_noise_rate_hz``, ``thres_drift_per_s``, ...

    Returns
    -------
    events : ndarray of EVENT_DTYPE
    truth : dict
        ``label`` (uint8 per event: 0 signal, 1 leak, 2 shot, 3 hot pixel), ``on``, ``off`` (the thresholds,
        height x width), ``parameters`` (every model parameter, the seed included).

    Examples
    --------
    >>> import evtools
    >>> events, truth = evtools.simulate("bars", size=(32, 24), duration_us=200_000, seed=0)
    >>> truth["on"].shape, bool(len(events) > 100), truth["parameters"]["seed"]
    ((24, 32), True, 0)
    """
    from evtools.simulation import DvsSimulator, run_simulator, scene_frames

    if isinstance(source, os.PathLike) or (isinstance(source, str) and os.path.exists(source)):  # a video, images
        from evtools.formats.video import open_frames

        if scene:
            raise EvtoolsError("scene options apply to a built-in scene, not to a video or images")
        frames = open_frames(os.fspath(source), frame_rate, size).frames
    elif isinstance(source, str):
        frames = scene_frames(source, *parse_sensor_size(size or (346, 260)), duration_us, **(scene or {}))
    elif scene:
        raise EvtoolsError("scene options apply to a built-in scene, not to frames")
    else:
        frames = iter(source)
    first = next(iter(frames), None)
    if first is None:
        raise EvtoolsError("no frames to simulate")
    first_frame = np.asarray(first[1])
    if not isinstance(source, (str, os.PathLike)) and first_frame.dtype != np.uint8 and 0 < first_frame.max() <= 1:
        logging.getLogger("evtools").warning(
            "the first frame's intensities lie within 0-1, but simulate takes 0-255 (white 255): normalised frames "
            "are simulated as a very dark scene; multiply them by 255")
    if first_frame.ndim not in (2, 3):  # (unpacking its shape raised Python's own ValueError)
        raise EvtoolsError(f"a frame is an image, height x width: the first is of shape {first_frame.shape}")
    frame_height, frame_width = first_frame.shape[:2]
    simulator = DvsSimulator(frame_width, frame_height, **parameters)
    events, labels = run_simulator(simulator, itertools.chain([first], frames))
    truth = {"label": labels, "on": simulator.on_thres, "off": simulator.off_thres,
             "parameters": dict(simulator.parameters)}
    return events, truth


def inject_noise(events: np.ndarray, info: StreamInfo, **parameters) -> tuple[np.ndarray, np.ndarray]:
    """Add labelled noise to a stream (``evtools simulate`` on an event stream): leak, shot noise, hot pixels.

    Returns the events with the noise merged in by time, and the label of each (0 the input's own events,
    1 leak, 2 shot, 3 hot pixel). Parameters: :class:`evtools.noise.NoiseInjector`'s (``leak_rate_hz``,
    ``shot_noise_rate_hz``, ``hot_pixel_fraction``, ``seed``, ...).

    Examples
    --------
    >>> import evtools
    >>> clean = evtools.from_columns([0, 1_000_000], [0, 1], [0, 1], [1, 0])
    >>> noisy, labels = evtools.inject_noise(clean, evtools.StreamInfo(32, 32), shot_noise_rate_hz=5, seed=1)
    >>> int((labels == 0).sum()), bool(len(noisy) > 2)
    (2, True)
    """
    from evtools.noise import inject_noise as inject

    info = _stream_info(info)
    return inject(events, info.width, info.height, **parameters)


def _keywords_of(function, target, leave_out=()) -> None:
    """Give ``function``, which passes its ``**params`` on to ``target`` (a processor's constructor), the
    target's keyword-only parameters in its signature: ``help()`` and tab completion list them, with their
    defaults, from the one place they are declared."""
    import inspect

    own = inspect.signature(function)
    kept = [p for p in own.parameters.values() if p.kind is not inspect.Parameter.VAR_KEYWORD]
    names = {p.name for p in kept}
    kept += [p for p in inspect.signature(target).parameters.values()
             if p.kind is inspect.Parameter.KEYWORD_ONLY and p.name not in names | set(leave_out)]
    function.__signature__ = own.replace(parameters=kept)


PROCESSORS = ("bafilter", "estimate", "correct", "simulate", "inject_noise")
"""The functions whose keywords are their processor's (:func:`document_processors`)."""
_DOCUMENTED = False


def document_processors() -> None:
    """Give :data:`PROCESSORS` their processors' keywords in their signatures and docstrings (once). The package
    calls it when one of them is first taken from it (``evtools.correct``), not at this module's import: the
    processors' modules (correction, estimation, filters, noise, simulation: ~30 ms) are not loaded by a script
    that only reads or writes files."""
    global _DOCUMENTED
    if _DOCUMENTED:
        return
    _DOCUMENTED = True
    from evtools.correction import ThresholdCorrector
    from evtools.estimation import ThresholdEstimator
    from evtools.noise import NoiseInjector
    from evtools.simulation import DvsSimulator

    from evtools.filters.registry import document

    document(bafilter, "events", "info", methods="method")
    _keywords_of(estimate, ThresholdEstimator, leave_out=("check",))
    _keywords_of(correct, ThresholdCorrector, leave_out=("check", "t_us", "stale", "start_us"))
    _keywords_of(simulate, DvsSimulator)
    _keywords_of(inject_noise, NoiseInjector)


# -- conversions ---------------------------------------------------------------------------------------------------


def to_columns(events: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(t, x, y, p)``: int64 microseconds, int16, int16, bool (ON), each a contiguous copy.

    Examples
    --------
    >>> import evtools
    >>> t, x, y, p = evtools.to_columns(evtools.from_columns([3], [1], [2], [0]))
    >>> t.tolist(), x.tolist(), y.tolist(), p.tolist()
    ([3], [1], [2], [False])
    """
    return tuple(np.ascontiguousarray(events[name]) for name in ("t", "x", "y", "p"))


def from_columns(t, x, y, p) -> np.ndarray:
    """Events from four columns (``p``: ON where true or > 0), order kept as given.

    Examples
    --------
    >>> import evtools
    >>> evtools.from_columns([0, 2], [5, 6], [1, 1], [1, -1])["p"].tolist()
    [True, False]

    A value the events cannot hold as given is refused (:class:`InvalidEventsError`), never rounded or wrapped: a
    fractional time or coordinate, a time beyond int64, a coordinate beyond int16, a polarity other than a bool,
    0/1 or -1/+1, columns of different lengths.
    """
    columns = {name: np.asarray(values) for name, values in (("t", t), ("x", x), ("y", y), ("p", p))}
    lengths = {name: column.shape for name, column in columns.items()}
    if any(len(shape) != 1 for shape in lengths.values()) or len(set(lengths.values())) != 1:
        said = ", ".join(f"{name} {shape}" for name, shape in lengths.items())
        raise InvalidEventsError(f"columns: four 1-D columns of one length are needed, got shapes {said}")
    for name, column in columns.items():
        if column.dtype.kind not in "biuf":
            raise InvalidEventsError(f"columns: {name} holds {column.dtype} values, not numbers")
    array = np.empty(len(columns["p"]), [(name, column.dtype) for name, column in columns.items()])
    for name, column in columns.items():
        array[name] = column
    return as_chunk(array, "columns")


TONIC_DTYPE = np.dtype([("x", "<i8"), ("y", "<i8"), ("t", "<i8"), ("p", "<i8")])
"""tonic's default event layout (``tonic.io.make_structured_array``): x, y, t (us), p (1 ON, 0 OFF)."""


def to_tonic(events: np.ndarray) -> np.ndarray:
    """A structured array as tonic's transforms take it (fields x, y, t, p; :data:`TONIC_DTYPE`), same order.

    Examples
    --------
    >>> import evtools
    >>> events = evtools.from_columns([7, 7], [1, 2], [0, 0], [1, 0])
    >>> back = evtools.from_tonic(evtools.to_tonic(events))
    >>> bool((back == events).all())
    True
    """
    out = np.empty(len(events), dtype=TONIC_DTYPE)
    for name in ("x", "y", "t"):
        out[name] = events[name]
    out["p"] = events["p"]
    return out


def from_tonic(array: np.ndarray) -> np.ndarray:
    """Events from a tonic structured array (fields x, y, t and p, any integer or bool types; p > 0 is ON; the
    polarity may be named ``on``, as tonic's ``read_aedat4``, faery and aedat name it).

    tonic's times are microseconds for its event-camera datasets; the order of the array is kept (equal times
    included) and must be by time.

    Examples
    --------
    >>> import numpy as np, evtools
    >>> array = np.zeros(2, dtype=[("x", int), ("y", int), ("t", int), ("p", int)])
    >>> array["t"] = [4, 4]; array["p"] = [1, 0]
    >>> evtools.from_tonic(array)["p"].tolist()
    [True, False]
    """
    keys = event_fields(array.dtype)
    if keys is None:
        fields = array.dtype.fields or {}
        missing = [name for name in ("x", "y", "t", "p") if name not in fields and not (name == "p" and "on" in fields)]
        raise EvtoolsError(f"a tonic event array has fields x, y, t, p; this one lacks {', '.join(missing)}")
    return from_columns(array[keys["t"]], array[keys["x"]], array[keys["y"]], array[keys["p"]])


def to_dv(events: np.ndarray, info: StreamInfo):
    """A dv-processing ``EventStore`` (needs ``dv-processing``): the events written as an AEDAT 4.0 file and read
    back by dv-processing's own reader, so no Python loop runs per event; order kept, equal times included.

    Examples
    --------
    >>> import evtools
    >>> events = evtools.from_columns([5, 5, 9], [1, 2, 3], [0, 0, 1], [1, 0, 1])
    >>> store = evtools.to_dv(events, evtools.StreamInfo(4, 2))
    >>> bool((evtools.from_dv(store) == events).all())
    True
    """
    import dv_processing as dv

    if not len(events):
        return dv.EventStore()
    store = None
    with tempfile.TemporaryDirectory(prefix="evtools-dv-") as folder:
        path = os.path.join(folder, "events.aedat4")
        write(path, events, info, compression="none")
        recording = dv.io.MonoCameraRecording(path)
        while (batch := recording.getNextEventBatch()) is not None:
            if store is None:  # the first batch is the store: an empty EventStore refuses a time before 0
                store = batch
            else:
                store.add(batch)
    return store


def from_dv(store) -> np.ndarray:
    """Events from a dv-processing ``EventStore`` (or anything with its ``numpy()``: fields timestamp, x, y,
    polarity), field by field (the layouts are alike, 16 bytes, but a store's polarity is int8).

    Examples
    --------
    >>> import dv_processing as dv, evtools
    >>> store = dv.EventStore()
    >>> _ = store.push_back(10, 3, 4, True)
    >>> evtools.from_dv(store)["t"].tolist()
    [10]
    """
    numpy = getattr(store, "numpy", None)
    array = numpy() if callable(numpy) else None
    if not (isinstance(array, np.ndarray) and {"timestamp", "x", "y", "polarity"} <= set(array.dtype.names or ())):
        raise EvtoolsError(f"from_dv takes a dv-processing EventStore (or anything whose numpy() gives the fields "
                           f"timestamp, x, y, polarity), got {type(store).__name__}")
    if not len(array):
        return empty_events()
    events = np.zeros(len(array), dtype=EVENT_DTYPE)  # (padding zero)
    events["t"] = array["timestamp"]
    events["x"] = array["x"]
    events["y"] = array["y"]
    events["p"] = array["polarity"] != 0
    return events
