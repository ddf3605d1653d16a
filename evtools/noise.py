"""Labelled noise on top of a real event stream: how denoisers are evaluated on recordings (DND21).

The events of a recording pass through unchanged (label 0); leak events (label 1), shot noise (label 2) and hot
pixel events (label 3) are added and merged in time order. :class:`NoiseInjector` is the stream processor
(``process(chunk) -> (events, labels)``, in bounded memory), :func:`inject_noise` the one-shot convenience.
``docs/algorithms.md`` sections 1 and 3 describe the noise.

The noise does not depend on how the input is cut into chunks: the time axis is cut into fixed blocks
(``block_us``, 10 ms, counted from t = 0 us), and the random draws of block ``k`` come from a Philox generator
whose key is derived from the seed and whose counter starts at ``k``, so a block's noise is a function of
``(seed, k)`` alone. Leak is periodic per pixel (v2e's drifting reference in the dark), so it needs no draws
after the per-pixel maps. Noise covers the input's time span, from its first event to its last, both included.
A noise event at the same time as an input event comes after it.

References
----------
S. Guo, T. Delbruck, "Low Cost and Latency Event Camera Background Activity Denoising", IEEE TPAMI 45(1), 2023
(the DND21 benchmark: labelled shot and leak noise injected into recordings).
Y. Hu, S.-C. Liu, T. Delbruck, "v2e: From Video Frames to Realistic DVS Events", CVPR Workshops, 2021.
"""

from __future__ import annotations

from typing import Any, Iterator

import numpy as np

from evtools._kernels.pixel import LABEL_HOT, LABEL_LEAK, LABEL_SHOT, LABEL_SIGNAL
from evtools.events import (CHUNK_EVENTS, EVENT_DTYPE, StreamChecker, StreamInfo, check_sensor_size, empty_events,
                            join, make_events)
from evtools.simulation import (SimulationError, _check_fraction, _check_nonnegative, check_noise_rates, leak_rates,
                                resolve_seed)

__all__ = ["BLOCK_US", "NOISE_DEFAULTS", "NoiseInjector", "inject_noise"]

BLOCK_US = 10_000
"""Length of the time blocks whose noise is drawn together (10 ms)."""

NOISE_DEFAULTS: dict[str, Any] = {
    "shot_noise_rate_hz": 0.0,
    "leak_rate_hz": 0.1,
    "leak_spread_decades": 0.5,
    "hot_pixel_fraction": 0.0,
    "hot_pixel_rate_hz": 100.0,
}
"""The frame simulator's noise defaults (v2e: leak 0.1 Hz, no shot noise, no hot pixels), with the per-pixel leak
rates spread over 0.5 decade, as in DND21 (docs/algorithms.md section 3)."""

_NO_EVENT_US = np.iinfo(np.int64).max
_EMPTY_LABELS = np.empty(0, dtype=np.uint8)


class NoiseInjector:
    """Adds labelled leak, shot and hot-pixel noise to an event stream of a ``width x height`` sensor.

    The per-pixel maps (leak rates and phases, hot pixels) are drawn once from the seed; the shot and hot-pixel
    events of each 10 ms block from a generator keyed by the seed and the block's index, so the output is the
    same bit for bit however the input is chunked. Each noise source has its own random stream, so switching one
    on or off never changes another.

    Parameters
    ----------
    width, height : int
        Sensor size in pixels.
    shot_noise_rate_hz : float
        Poisson shot-noise rate per pixel (ON and OFF together, equally likely), label 2. Unlike the frame
        simulator's it does not fall with intensity: a recording's intensity is unknown.
    leak_rate_hz : float
        Mean leak (background activity) rate per pixel: ON events, label 1, periodic per pixel (a reference
        drifting at a constant rate, as in v2e) with a random phase.
    leak_spread_decades : float
        Standard deviation of the log10 of the per-pixel leak rates (log-normal with mean ``leak_rate_hz``).
    hot_pixel_fraction : float
        Fraction of pixels, chosen at random, that fire at ``hot_pixel_rate_hz`` (Poisson, ON or OFF), label 3.
    hot_pixel_rate_hz : float
        Event rate of each hot pixel.
    seed : int or None
        Seed of every random draw; None draws one (see :attr:`seed`).
    block_us : int
        Length of the time blocks whose noise is drawn together; part of what the seed reproduces.

    Attributes
    ----------
    seed : int
        The seed actually used.
    parameters : dict
        Every parameter, for the ground-truth file.
    hot_pixels : ndarray of bool, shape (height, width)
    leak_rate_map_hz : ndarray of float64, shape (height, width)

    References
    ----------
    S. Guo, T. Delbruck, "Low Cost and Latency Event Camera Background Activity Denoising", IEEE TPAMI, 2023.
    Y. Hu, S.-C. Liu, T. Delbruck, "v2e: From Video Frames to Realistic DVS Events", CVPR Workshops, 2021.
    """

    def __init__(
        self,
        width: int,
        height: int,
        *,
        shot_noise_rate_hz: float = NOISE_DEFAULTS["shot_noise_rate_hz"],
        leak_rate_hz: float = NOISE_DEFAULTS["leak_rate_hz"],
        leak_spread_decades: float = NOISE_DEFAULTS["leak_spread_decades"],
        hot_pixel_fraction: float = NOISE_DEFAULTS["hot_pixel_fraction"],
        hot_pixel_rate_hz: float = NOISE_DEFAULTS["hot_pixel_rate_hz"],
        seed: int | None = None,
        block_us: int = BLOCK_US,
    ) -> None:
        check_sensor_size(width, height)
        self.width, self.height = int(width), int(height)
        if isinstance(block_us, bool) or not isinstance(block_us, (int, np.integer)) or block_us < 1:
            raise SimulationError(f"block_us must be a whole number of microseconds >= 1, got {block_us!r}")
        self.seed = resolve_seed(seed)
        self.block_us = int(block_us)
        self.parameters: dict[str, Any] = {
            "shot_noise_rate_hz": _check_nonnegative("shot_noise_rate_hz", shot_noise_rate_hz),
            "leak_rate_hz": _check_nonnegative("leak_rate_hz", leak_rate_hz),
            "leak_spread_decades": _check_nonnegative("leak_spread_decades", leak_spread_decades),
            "hot_pixel_fraction": _check_fraction("hot_pixel_fraction", hot_pixel_fraction),
            "hot_pixel_rate_hz": _check_nonnegative("hot_pixel_rate_hz", hot_pixel_rate_hz),
            "seed": self.seed,
            "block_us": self.block_us,
        }
        check_noise_rates(self.width, self.height, self.parameters)
        self._draw_maps()
        self._checker = StreamChecker(StreamInfo(self.width, self.height))
        self._t_first: int | None = None  # time of the first input event
        self._t_last: int | None = None  # time of the latest input event
        self._next_block: int | None = None  # first block whose noise is not drawn yet
        self._held = empty_events()  # noise drawn but not emitted yet (time order)
        self._held_labels = _EMPTY_LABELS
        self._flushed = False

    # -- the per-pixel maps, drawn once -------------------------------------------------------------------

    def _draw_maps(self) -> None:
        p = self.parameters
        n = self.width * self.height
        pixel_seq, leak_seq, shot_seq, hot_seq = np.random.SeedSequence(self.seed).spawn(4)
        hot = np.zeros(n, dtype=bool)
        n_hot = int(round(p["hot_pixel_fraction"] * n))
        if n_hot:
            hot[np.random.default_rng(pixel_seq).permutation(n)[:n_hot]] = True
        self.hot_pixels = hot.reshape(self.height, self.width)
        self._hot_index = np.flatnonzero(hot)

        leak_rng = np.random.default_rng(leak_seq)
        rates = leak_rates(p["leak_rate_hz"], p["leak_spread_decades"], leak_rng, n)
        self.leak_rate_map_hz = rates.reshape(self.height, self.width)
        phase = leak_rng.random(n)
        leaking = np.flatnonzero(rates > 0)
        self._leak_pixel = leaking
        self._leak_period_us = 1e6 / rates[leaking]
        self._leak_phase = phase[leaking]
        self._leak_k = np.zeros(len(leaking), dtype=np.int64)  # index of each pixel's next leak event
        self._leak_next_us = np.full(len(leaking), _NO_EVENT_US, dtype=np.int64)

        self._shot_key = shot_seq.generate_state(2, np.uint64)
        self._hot_key = hot_seq.generate_state(2, np.uint64)
        self._shot_per_block = p["shot_noise_rate_hz"] * n * self.block_us * 1e-6
        self._hot_per_block = p["hot_pixel_rate_hz"] * n_hot * self.block_us * 1e-6
        self._silent = not (self._shot_per_block > 0 or self._hot_per_block > 0 or len(leaking))

    # -- processing ---------------------------------------------------------------------------------------

    def process(self, chunk: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The chunk's events with the noise up to its last event merged in; and one label per output event.

        Parameters
        ----------
        chunk : ndarray of EVENT_DTYPE
            The next input events, in time order (ties allowed), not earlier than the previous chunk's.

        Returns
        -------
        events : ndarray of EVENT_DTYPE
            Every input event unchanged and in its order, with the noise events earlier than the chunk's last
            event merged in by time (an input event first when times are equal). Noise at the last event's time
            or later is held for the next call or :meth:`flush`.
        labels : ndarray of uint8
            Per output event: 0 input (signal), 1 leak, 2 shot noise, 3 hot pixel.
        """
        return _join_pieces(list(self.process_pieces(chunk)))

    def process_pieces(self, chunk: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """:meth:`process` as a series of pieces of about a million events at most, so that a long gap in the
        input (hours of noise between two events) never has to be held in memory at once."""
        chunk = self._check(chunk)
        if not len(chunk):
            return
        t = chunk["t"]
        t_max = int(t[-1])
        if self._t_first is None:
            self._t_first = int(t[0])
            self._next_block = self._t_first // self.block_us
        self._t_last = t_max
        last_block = t_max // self.block_us
        start = 0
        while True:
            self._draw_until(last_block, CHUNK_EVENTS)
            if self._next_block > last_block:
                # everything up to t_max is drawn: emit the rest of the input and the noise before t_max
                cut = int(np.searchsorted(self._held["t"], t_max, side="left"))
                yield self._merge(chunk[start:], cut)
                return
            horizon = self._next_block * self.block_us  # all the noise before this time is drawn and held
            end = int(np.searchsorted(t, horizon, side="left"))
            yield self._merge(chunk[start:end], len(self._held))
            start = end

    def flush(self) -> tuple[np.ndarray, np.ndarray]:
        """The noise held back at the time of the last input event (the noise ends there); ends the stream."""
        self._flushed = True
        if self._t_last is None:
            return empty_events(), _EMPTY_LABELS.copy()
        cut = int(np.searchsorted(self._held["t"], self._t_last, side="right"))
        events, labels = join([self._held[:cut]]), self._held_labels[:cut].copy()
        self._held, self._held_labels = empty_events(), _EMPTY_LABELS
        return events, labels

    def _check(self, chunk: np.ndarray) -> np.ndarray:
        if self._flushed:
            raise SimulationError("NoiseInjector: process() after flush(); make a new injector for a new stream")
        return self._checker.check(chunk)

    def _merge(self, events: np.ndarray, n_noise: int) -> tuple[np.ndarray, np.ndarray]:
        """``events`` with the first ``n_noise`` held noise events merged in (input first on equal times)."""
        noise, noise_labels = self._held[:n_noise], self._held_labels[:n_noise]
        self._held, self._held_labels = self._held[n_noise:], self._held_labels[n_noise:]
        total = len(events) + n_noise
        labels = np.full(total, LABEL_SIGNAL, dtype=np.uint8)
        if not n_noise:
            return join([events]), labels  # copied as raw records: numpy copies a record's fields, not its padding
        out = np.zeros(total, dtype=EVENT_DTYPE)  # zero padding: numpy copies structured records field by field
        noise_at = np.searchsorted(events["t"], noise["t"], side="right") + np.arange(n_noise)
        is_noise = np.zeros(total, dtype=bool)
        is_noise[noise_at] = True
        out[noise_at] = noise
        out[~is_noise] = events
        labels[noise_at] = noise_labels
        return out, labels

    # -- drawing the noise, block by block ----------------------------------------------------------------

    def _draw_until(self, last_block: int, limit: int) -> None:
        """Draw the noise of blocks ``_next_block..last_block``, stopping early once ``limit`` events are held."""
        if self._silent:
            self._next_block = max(self._next_block, last_block + 1)
            return
        parts, labels, held = [self._held], [self._held_labels], len(self._held)
        while self._next_block <= last_block and held < limit:
            events, block_labels = self._draw_block(self._next_block)
            self._next_block += 1
            if len(events):
                parts.append(events)
                labels.append(block_labels)
                held += len(events)
        if len(parts) > 1:
            self._held, self._held_labels = join(parts), np.concatenate(labels)

    def _block_rng(self, key: np.ndarray, block: int) -> np.random.Generator:
        # counter = block << 192: the draws of one block (< 2**192 of them) never reach the next block's counter
        return np.random.Generator(np.random.Philox(key=key, counter=(block % (1 << 64)) << 192))

    def _draw_block(self, block: int) -> tuple[np.ndarray, np.ndarray]:
        """The noise events of block ``block``, ``[block * block_us, (block + 1) * block_us)``, in time order."""
        start = block * self.block_us
        end = start + self.block_us
        times, pixels, polarities, labels = [], [], [], []

        if len(self._leak_pixel):
            if block == self._t_first // self.block_us:
                self._start_leak(start)
            firing = np.flatnonzero(self._leak_next_us < end)
            while len(firing):
                times.append(self._leak_next_us[firing])
                pixels.append(self._leak_pixel[firing])
                k = self._leak_k[firing] + 1
                self._leak_k[firing] = k
                self._leak_next_us[firing] = self._leak_time_us(firing, k)
                firing = firing[self._leak_next_us[firing] < end]
            if times:
                n = sum(len(part) for part in times)
                polarities.append(np.ones(n, dtype=bool))
                labels.append(np.full(n, LABEL_LEAK, dtype=np.uint8))

        for mean, key, label, choose in (
            (self._shot_per_block, self._shot_key, LABEL_SHOT, None),
            (self._hot_per_block, self._hot_key, LABEL_HOT, self._hot_index),
        ):
            if not mean > 0:
                continue
            rng = self._block_rng(key, block)
            n = int(rng.poisson(mean))
            if not n:
                continue
            if choose is None:
                pixels.append(rng.integers(0, self.width * self.height, n, dtype=np.int64))
            else:
                pixels.append(choose[rng.integers(0, len(choose), n, dtype=np.int64)])
            times.append(rng.integers(start, end, n, dtype=np.int64))
            polarities.append(rng.integers(0, 2, n, dtype=np.uint8).astype(bool))
            labels.append(np.full(n, label, dtype=np.uint8))

        if not times:
            return empty_events(), _EMPTY_LABELS
        t = np.concatenate(times)
        # ties: leak, shot, hot, each in its draw order; offsets in a block fit 16 bits, which numpy radix-sorts
        offset = t - start
        order = np.argsort(offset.astype(np.uint16) if self.block_us <= 1 << 16 else offset, kind="stable")
        t, pixel = t[order], np.concatenate(pixels)[order]
        polarity, labels = np.concatenate(polarities)[order], np.concatenate(labels)[order]
        if start < self._t_first:  # the first block: the noise starts with the input
            keep = t >= self._t_first
            t, pixel, polarity, labels = t[keep], pixel[keep], polarity[keep], labels[keep]
        return make_events(t, pixel % self.width, pixel // self.width, polarity), labels

    def _leak_time_us(self, index: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Time of leak event ``k`` of leak pixel ``index``: ``floor((k + phase) * period)``, from t = 0."""
        return np.floor((k + self._leak_phase[index]) * self._leak_period_us[index]).astype(np.int64)

    def _start_leak(self, start_us: int) -> None:
        """Point every leaking pixel at its first leak event at or after ``start_us``."""
        every = np.arange(len(self._leak_pixel))
        k = np.ceil(start_us / self._leak_period_us - self._leak_phase).astype(np.int64)
        # the floating-point guess may be one off either way: fix it with the exact event times
        k = np.where(self._leak_time_us(every, k - 1) >= start_us, k - 1, k)
        k = np.where(self._leak_time_us(every, k) < start_us, k + 1, k)
        self._leak_k[:] = k
        self._leak_next_us[:] = self._leak_time_us(every, k)


def _join_pieces(pieces: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    if not pieces:
        return empty_events(), _EMPTY_LABELS.copy()
    if len(pieces) == 1:
        return pieces[0]
    return join([events for events, _ in pieces]), np.concatenate([labels for _, labels in pieces])


def inject_noise(events: np.ndarray, width: int, height: int, **parameters) -> tuple[np.ndarray, np.ndarray]:
    """Add labelled noise to a whole (in-memory) stream: :class:`NoiseInjector` ``process`` then ``flush``.

    Parameters
    ----------
    events : ndarray of EVENT_DTYPE
        The stream, in time order.
    width, height : int
        Sensor size.
    **parameters
        Passed to :class:`NoiseInjector` (rates, ``seed``, ...).

    Returns
    -------
    events : ndarray of EVENT_DTYPE
        The input events unchanged, with the noise merged in by time.
    labels : ndarray of uint8
        0 input, 1 leak, 2 shot noise, 3 hot pixel.
    """
    injector = NoiseInjector(width, height, **parameters)
    return _join_pieces([injector.process(events), injector.flush()])

