"""Slow, obviously correct reference versions of evtools' numba kernels (tests compare the kernels to these).

Each reference follows its paper or format specification line by line, in plain Python, one event at a time.
"""

from __future__ import annotations

import random

import numpy as np


class NaiveEvt3Decoder:
    """Prophesee EVT 3.0, word by word, as the specification's tables read.

    Call :meth:`feed` with successive pieces of the word stream; ``events`` collects ``(t_us, x, y, p)``
    tuples. Events before the first EVT_TIME_HIGH or EVT_ADDR_Y are dropped (their time or row is unknown);
    EVT_TIME_HIGH falling by more than 2048 (half its 12-bit range) is a wrap of the 24-bit time base.

    References
    ----------
    Prophesee, "EVT 3.0 Format", https://docs.prophesee.ai/stable/data/encoding_formats/evt3.html
    """

    def __init__(self) -> None:
        self.time_high = None
        self.time_low = 0
        self.loops = 0
        self.y = None
        self.base_x = 0
        self.base_polarity = 0
        self.dropped = 0
        self.triggers = 0
        self.others = 0
        self.events: list[tuple[int, int, int, int]] = []

    def _emit(self, x: int, polarity: int) -> None:
        if self.time_high is None or self.y is None:
            self.dropped += 1
            return
        t_us = self.loops * 2**24 + self.time_high * 2**12 + self.time_low
        self.events.append((t_us, x, self.y, polarity))

    def feed(self, words) -> None:
        for word in words:
            word = int(word)
            kind = word // 4096  # the 4 most significant bits
            payload = word % 4096  # the 12 least significant bits
            bit11 = payload // 2048
            low11 = payload % 2048
            if kind == 0b0000:  # EVT_ADDR_Y
                self.y = low11
            elif kind == 0b0010:  # EVT_ADDR_X: a single event
                self._emit(low11, bit11)
            elif kind == 0b0011:  # VECT_BASE_X
                self.base_x = low11
                self.base_polarity = bit11
            elif kind == 0b0100:  # VECT_12
                for j in range(12):
                    if (payload >> j) & 1:
                        self._emit(self.base_x + j, self.base_polarity)
                self.base_x += 12
            elif kind == 0b0101:  # VECT_8
                for j in range(8):
                    if (payload >> j) & 1:
                        self._emit(self.base_x + j, self.base_polarity)
                self.base_x += 8
            elif kind == 0b0110:  # EVT_TIME_LOW
                self.time_low = payload
            elif kind == 0b1000:  # EVT_TIME_HIGH
                if self.time_high is not None and self.time_high - payload > 2048:
                    self.loops += 1
                self.time_high = payload
            elif kind == 0b1010:  # EXT_TRIGGER
                self.triggers += 1
            else:  # CONTINUED_4, CONTINUED_12, OTHERS, reserved
                self.others += 1


def evt3_decode_naive(words) -> list[tuple[int, int, int, int]]:
    """All ``(t_us, x, y, p)`` events of a whole EVT 3.0 word stream."""
    decoder = NaiveEvt3Decoder()
    decoder.feed(words)
    return decoder.events


# -- DVS pixel model (evtools/_kernels/pixel.py) ------------------------------------------------------------------

import math  # noqa: E402

_MASK64 = (1 << 64) - 1


def _splitmix_finalise(z: int) -> int:
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    return z ^ (z >> 31)


def naive_random_bits(key: int, pixel: int, draw: int) -> int:
    """SplitMix64's finaliser applied twice to (key, pixel, draw), in Python integers modulo 2**64."""
    golden = 0x9E3779B97F4A7C15
    return _splitmix_finalise((_splitmix_finalise((key + pixel * golden) & _MASK64) + draw * golden) & _MASK64)


def naive_lin_log(intensity: float) -> float:
    """v2e's lin-log: linear below 20, natural log above."""
    intensity = max(intensity, 0.0)
    return intensity * (math.log(20.0) / 20.0) if intensity <= 20.0 else math.log(intensity)


class NaiveDvsSensor:
    """The pixel model of docs/algorithms.md section 1, one pixel and one event at a time.

    Built from the per-pixel maps a :class:`evtools.simulation.DvsSimulator` drew (so both see the same sensor).
    For each frame interval, each pixel (raster order) lists its candidate next events - the threshold crossing
    of the straight line between the two filtered log intensities minus the drifting reference (ESIM), the next
    shot-noise event, the next hot-pixel event - takes the earliest, applies it, and repeats until none falls in
    the interval. ``events`` collects ``(t_us, x, y, p, label)``; each interval's events are sorted by
    ``(t, y, x, pixel's own order)``.
    """

    def __init__(self, width, height, on, off, leak_rate_hz, leak_phase, shot_rate_hz, hot_rate_hz,
                 shot_budget, hot_budget, shot_key, hot_key, cutoff_hz, refractory_us,
                 fixed_cutoff=False) -> None:
        self.width, self.height = width, height
        n = width * height
        self.on = [float(v) for v in on.reshape(-1)]
        self.off = [float(v) for v in off.reshape(-1)]
        self.leak = [float(v) for v in leak_rate_hz.reshape(-1)]
        self.phase = [float(v) for v in leak_phase.reshape(-1)]
        self.shot_rate = [float(v) for v in shot_rate_hz.reshape(-1)]
        self.hot_rate = [float(v) for v in hot_rate_hz.reshape(-1)]
        self.shot_budget = [float(v) for v in shot_budget.reshape(-1)]
        self.hot_budget = [float(v) for v in hot_budget.reshape(-1)]
        self.shot_key, self.hot_key = int(shot_key), int(hot_key)
        self.cutoff_hz, self.refractory_us = float(cutoff_hz), int(refractory_us)
        self.fixed_cutoff = bool(fixed_cutoff)
        self.lp = [0.0] * n
        self.ref = [0.0] * n
        self.last = [None] * n
        self.shot_draws = [0] * n
        self.hot_draws = [0] * n
        self.t_us = None
        self.events: list[tuple[int, int, int, bool, int]] = []

    def frame(self, t_us: int, frame) -> None:
        values = [float(v) for v in frame.astype("float32").reshape(-1)]
        if self.t_us is None:
            for i, intensity in enumerate(values):
                self.lp[i] = naive_lin_log(intensity)
                self.ref[i] = self.lp[i] - (self.phase[i] * self.on[i] if self.leak[i] > 0 else 0.0)
            self.t_us = t_us
            return
        interval = []
        for i, intensity in enumerate(values):
            for k, (t, p, label) in enumerate(self._pixel(i, max(intensity, 0.0), self.t_us, t_us)):
                interval.append((t, i // self.width, i % self.width, k, p, label))
        interval.sort(key=lambda e: (e[0], e[1], e[2], e[3]))
        self.events.extend((t, x, y, p, label) for t, y, x, _, p, label in interval)
        self.t_us = t_us

    def _pixel(self, i, intensity, t0_us, t1_us):
        dt_us = float(t1_us - t0_us)
        dt_s = dt_us * 1e-6
        target = naive_lin_log(intensity)
        lp0 = self.lp[i]
        if self.cutoff_hz > 0:
            if self.fixed_cutoff:  # a plain single-pole filter
                eps = min(1.0, dt_s * 2.0 * math.pi * self.cutoff_hz)
            else:  # v2e: the bandwidth falls with intensity
                eps = min(1.0, (intensity + 20.0) / 275.0 * (dt_s * 2.0 * math.pi * self.cutoff_hz))
            lp1 = lp0 + eps * (target - lp0)
        else:
            lp1 = target
        change = lp1 - lp0
        on, off = self.on[i], self.off[i]
        drift = self.leak[i] * on * dt_s  # the reference falls by this much over the interval
        slope = change + drift
        ref = self.ref[i]  # reference at the interval's start
        shot_mass = self.shot_rate[i] * (1.0 - (1.0 - 0.25) / 255.0 * min(intensity, 255.0)) * dt_s
        hot_mass = self.hot_rate[i] * dt_s
        shot_next = self.shot_budget[i] / shot_mass if shot_mass > 0 else math.inf
        hot_next = self.hot_budget[i] / hot_mass if hot_mass > 0 else math.inf
        out = []
        s = 0.0
        while True:
            gap = lp0 - ref  # lp - ref at s = 0 for the current reference
            if slope > 0:
                crossing, kind = (on - gap) / slope, "on"
            elif slope < 0:
                crossing, kind = (-off - gap) / slope, "off"
            else:
                crossing, kind = math.inf, "none"
            crossing = max(crossing, s)
            s = min(crossing, shot_next, hot_next)
            if s > 1.0:
                break
            t = math.floor(t0_us + s * dt_us + 0.5)
            allowed = self.last[i] is None or t - self.last[i] >= self.refractory_us
            if crossing == s:
                if kind == "on":
                    ref += on
                    p, label = True, (1 if change <= 0 else 0)
                else:
                    ref -= off
                    p, label = False, 0
            elif shot_next == s:
                bits = naive_random_bits(self.shot_key, i, self.shot_draws[i])
                self.shot_draws[i] += 1
                p, label = bool(bits & 1), 2
                shot_next = s + -math.log(1.0 - (bits >> 11) / 2.0**53) / shot_mass
                if allowed:
                    ref = lp0 + (change + drift) * s
            else:
                bits = naive_random_bits(self.hot_key, i, self.hot_draws[i])
                self.hot_draws[i] += 1
                p, label = bool(bits & 1), 3
                hot_next = s + -math.log(1.0 - (bits >> 11) / 2.0**53) / hot_mass
            if allowed:
                out.append((t, p, label))
                self.last[i] = t
        self.lp[i] = lp1
        self.ref[i] = ref - drift
        if shot_mass > 0:
            self.shot_budget[i] = (shot_next - 1.0) * shot_mass
        if hot_mass > 0:
            self.hot_budget[i] = (hot_next - 1.0) * hot_mass
        return out


def simulate_naive(simulator, frames) -> list[tuple[int, int, int, bool, int]]:
    """``(t_us, x, y, p, label)`` of every event of ``frames`` (``(t_us, frame)`` pairs) on ``simulator``'s sensor.

    ``simulator`` is a fresh :class:`evtools.simulation.DvsSimulator`; only its drawn maps and keys are used.
    """
    sim = simulator
    sensor = NaiveDvsSensor(
        sim.width, sim.height, sim.on_thres, sim.off_thres, sim._leak_rate_hz, sim._leak_phase, sim._shot_rate_hz,
        sim._hot_rate_hz, sim._shot_budget, sim._hot_budget, sim._shot_key, sim._hot_key,
        sim.parameters["cutoff_hz"], sim.parameters["refractory_us"], sim.parameters["fixed_cutoff"],
    )
    for t_us, frame in frames:
        sensor.frame(int(t_us), frame)
    return sensor.events


def evt2_decode_naive(data: bytes) -> tuple[dict[str, str], list[tuple[int, int, int, int]]]:
    """A Prophesee EVT 2.0 RAW file, line by line and word by word as the specification reads: the ``%`` header
    lines as ``{key: value}``, then ``(t_us, x, y, p)`` of every CD word (type 0 OFF, 1 ON: time low in bits
    22-27, x in 11-21, y in 0-10) after the latest EVT_TIME_HIGH (type 8: t >> 6 in bits 0-27), its 28-bit field
    unwrapped when it falls by more than half its range.

    References
    ----------
    Prophesee, "EVT 2.0 Format", https://docs.prophesee.ai/stable/data/encoding_formats/evt2.html
    """
    header, position = {}, 0
    while data[position:position + 1] == b"%":  # the header ends at "% end" (a first word may start with "%")
        end = data.index(b"\n", position)
        key, _, value = data[position + 1:end].decode("ascii").strip().partition(" ")
        position = end + 1
        if key == "end":
            break
        header[key] = value
    events, time_high, previous, wraps = [], None, None, 0
    for i in range(position, len(data) - 3, 4):
        word = int.from_bytes(data[i:i + 4], "little")
        kind = word >> 28
        if kind == 8:
            field = word & ((1 << 28) - 1)
            if previous is not None and previous - field > 1 << 27:
                wraps += 1
            previous = field
            time_high = field + (wraps << 28)
        elif kind in (0, 1) and time_high is not None:
            t_low, x, y = (word >> 22) & 63, (word >> 11) & 2047, word & 2047
            events.append((time_high * 64 + t_low, x, y, kind))
    return header, events


def evt21_decode_naive(data: bytes) -> tuple[dict[str, str], list[tuple[int, int, int, int]]]:
    """A Prophesee EVT 2.1 RAW file read as the specification and OpenEB's structures lay it out: the ``%`` header
    lines as ``{key: value}``, then ``(t_us, x, y, p)`` of every event. Each 8-byte word is two little-endian
    32-bit halves: the first is the mask and the second the typed half, or the other way round when the header's
    format says ``endianness=legacy`` (IMX636). The typed half is read as an EVT 2.0 word (type in bits 28-31;
    CD: time low 22-27, x 11-21, y 0-10; EVT_TIME_HIGH: t >> 6 in 0-27, unwrapped when it falls by more than half
    its range); mask bit k is an event at column x + k, the bits in increasing order.

    References
    ----------
    Prophesee, "EVT 2.1 Format", https://docs.prophesee.ai/stable/data/encoding_formats/evt21.html; OpenEB,
    hal/cpp/include/metavision/hal/decoders/evt21/evt21_event_types.h (Evt21Raw, Evt21LegacyRaw)
    """
    header, position = {}, 0
    while data[position:position + 1] == b"%":
        end = data.index(b"\n", position)
        key, _, value = data[position + 1:end].decode("ascii").strip().partition(" ")
        header[key] = value
        position = end + 1
        if key == "end":
            break
    legacy = "endianness=legacy" in header.get("format", "").replace(" ", "").lower()
    events, time_high, previous, wraps = [], None, None, 0
    for i in range(position, len(data) - 7, 8):
        first = int.from_bytes(data[i:i + 4], "little")
        second = int.from_bytes(data[i + 4:i + 8], "little")
        typed, mask = (first, second) if legacy else (second, first)
        kind = typed >> 28
        if kind == 8:
            field = typed & ((1 << 28) - 1)
            if previous is not None and previous - field > 1 << 27:
                wraps += 1
            previous = field
            time_high = field + (wraps << 28)
        elif kind in (0, 1) and time_high is not None:
            t_us = time_high * 64 + ((typed >> 22) & 63)
            x, y = (typed >> 11) & 2047, typed & 2047
            events += [(t_us, x + k, y, kind) for k in range(32) if mask >> k & 1]
    return header, events


def evt21_encode_naive(events, width: int, height: int, legacy: bool, seed: int) -> bytes:
    """``events`` (``(t_us, x, y, p)`` in time order, times from 0 and below 2^34, x below 2048 and y below 2048)
    as an EVT 2.1 RAW file a sensor could have sent: a time-high word whenever ``t >> 6`` changes (and now and then
    again for nothing), and consecutive events of one time, row and polarity whose columns rise within 32 of the
    word's first column (or of the 32-column group it lies in, chosen at random) in one word; trigger and OTHERS
    words between them at random."""
    rng = random.Random(seed)
    fmt = f"EVT21;width={width};height={height}" + (";endianness=legacy" if legacy else "")
    out = bytearray(f"% evt 2.1\n% format {fmt}\n% end\n".encode("ascii"))

    def word(typed: int, mask: int) -> None:
        halves = (typed, mask) if legacy else (mask, typed)
        out.extend(halves[0].to_bytes(4, "little") + halves[1].to_bytes(4, "little"))

    high = None
    open_word = None  # [t_us, base_x, y, p, mask, last_x]
    for t_us, x, y, p in list(events) + [(None, None, None, None)]:
        joins = (open_word is not None and t_us is not None and (t_us, y, p) == tuple(open_word[i] for i in (0, 2, 3))
                 and open_word[5] < x < open_word[1] + 32)
        if joins:
            open_word[4] |= 1 << (x - open_word[1])
            open_word[5] = x
            continue
        if open_word is not None:
            t_open, base, row, polarity, mask, _ = open_word
            word((polarity << 28) | ((t_open & 63) << 22) | (base << 11) | row, mask)
            open_word = None
            if rng.random() < 0.05:
                word((0xA << 28) | ((t_open & 63) << 22) | rng.getrandbits(22), rng.getrandbits(32))
            if rng.random() < 0.05:
                word((0xE << 28) | ((t_open & 63) << 22) | rng.getrandbits(22), rng.getrandbits(32))
        if t_us is None:
            break
        if high != t_us >> 6 or rng.random() < 0.02:
            high = t_us >> 6
            word((0x8 << 28) | (high & ((1 << 28) - 1)), rng.getrandbits(32))
        base = x - x % 32 if rng.random() < 0.5 else x
        open_word = [t_us, base, y, p, 1 << (x - base), x]
    return bytes(out)


def ecf_decode_naive(block: bytes) -> list[tuple[int, int, int, int]]:
    """One ECF block (Prophesee's HDF5 codec) as ``(t_us, x, y, p)``, reading the fields as the codec's layout
    describes them: a 32-bit header (count << 2 | yxp-packed << 1 | xp-packed), the times (a 64-bit origin, then
    bytes of a 4-bit step and a 4-bit run length, 15 meaning a 16-bit length follows; bytes whose upper half is 15
    spell a larger step 4 bits at a time, least significant first), then rows, columns and polarities (runs, masks
    or packed groups of four). Raises ValueError where the block is cut short or a run overshoots the count.

    References
    ----------
    Prophesee, hdf5_ecf (github.com/prophesee-ai/hdf5_ecf): the codec this layout is read from.
    """
    position = 0

    def take(n_bytes: int) -> int:
        nonlocal position
        if position + n_bytes > len(block):
            raise ValueError("truncated")
        value = int.from_bytes(block[position:position + n_bytes], "little")
        position += n_bytes
        return value

    header = take(4)
    count = header >> 2
    ts: list[int] = []
    now = take(8)
    now -= (now >> 63) << 64  # two's complement
    while len(ts) < count:
        byte = take(1)
        if byte >> 4 == 15:
            nibbles = []
            while byte >> 4 == 15:
                nibbles.append(byte & 15)
                byte = take(1)
            position -= 1  # the byte that ended the advance starts the next run
            now += sum(nibble << (4 * j) for j, nibble in enumerate(nibbles[:16]))
            continue
        now += byte >> 4
        run = byte & 15
        if run == 15:
            run = take(2)
        ts += [now] * run
    if len(ts) != count:
        raise ValueError("inconsistent")
    xs: list[int] = []
    ys: list[int] = []
    ps: list[int] = []

    def groups_of_four(word_bytes: int, bits: int) -> list[int]:
        """Four values of ``bits`` in three words: each word holds the rest of one value above the low
        ``s``, ``2 s``, ``3 s`` bits of the next (``s`` = word bits - value bits)."""
        s = 8 * word_bytes - bits
        values = []
        while len(values) < count:
            w0, w1, w2 = (take(word_bytes) for _ in range(3))
            values += [w0 >> s, (w0 & ((1 << s) - 1)) | (w1 >> (2 * s)) << s,
                       (w1 & ((1 << 2 * s) - 1)) | (w2 >> (3 * s)) << (2 * s), w2 & ((1 << 3 * s) - 1)]
        return values[:count]

    if header >> 1 & 1:
        for value in groups_of_four(4, 24):
            ys.append(value >> 12 & 2047)
            xs.append(value >> 1 & 2047)
            ps.append(value & 1)
    else:
        while len(ys) < count:
            value = take(2)
            run = value & 31
            if run == 31:
                run = take(2)
            ys += [value >> 5] * run
        if len(ys) != count:
            raise ValueError("inconsistent")
        if header & 1:
            for value in groups_of_four(2, 12):
                xs.append(value >> 1)
                ps.append(value & 1)
        else:
            while len(xs) < count:
                value = take(2)
                xs.append(value >> 5)
                xs += [(value >> 5) + 1 + j for j in range(5) if value >> (4 - j) & 1]
            xs = xs[:count]
            while len(ps) < count:
                value = take(1)
                run = value & 127
                if run == 127:
                    run = take(2)
                ps += [value >> 7] * run
            if len(ps) != count:
                raise ValueError("inconsistent")
    return list(zip(ts, xs, ys, ps))


def ecf_encode_naive(events, mode: int) -> bytes:
    """``events`` (``(t_us, x, y, p)``, times not decreasing, x and y below 2048) as one ECF block, in ``mode`` 0
    (row runs, column masks, polarity runs), 1 (row runs, x and p packed) or 2 (y, x and p packed); times by the
    codec's rule: a step of 15 or more is spelled in 4-bit pieces first."""
    out = bytearray()
    count = len(events)
    out += ((count << 2) | (2 if mode == 2 else 0) | (1 if mode == 1 else 0)).to_bytes(4, "little")
    ts, xs, ys, ps = ([e[k] for e in events] for k in range(4))
    now = ts[0] if events else 0
    out += (now % (1 << 64)).to_bytes(8, "little")

    def runs(values):
        i = 0
        while i < len(values):
            j = i
            while j < len(values) and values[j] == values[i]:
                j += 1
            yield values[i], j - i
            i = j

    for t_us, run in runs(ts):
        step = t_us - now
        if step >= 15:
            while step:
                out.append(0xF0 | (step & 15))
                step >>= 4
            step = 0
        now = t_us
        while run:  # (a run past 65535 is split: the codec's blocks never hold one)
            piece = min(run, 65535)
            out += bytes([step << 4 | 15]) + piece.to_bytes(2, "little") if piece >= 15 else bytes([step << 4 | piece])
            run -= piece
            step = 0
    if mode == 2:
        out += _four_in_three([(y << 12) | (x << 1) | p for x, y, p in zip(xs, ys, ps)], 4, 24)
        return bytes(out)
    for y, run in runs(ys):
        out += ((y << 5) | 31).to_bytes(2, "little") + run.to_bytes(2, "little") if run >= 31 else \
            ((y << 5) | run).to_bytes(2, "little")
    if mode == 1:
        out += _four_in_three([(x << 1) | p for x, p in zip(xs, ps)], 2, 12)
        return bytes(out)
    i = 0
    while i < count:
        x, mask = xs[i], 0
        i += 1
        for j in range(5):
            if i < count and xs[i] == x + j + 1:
                mask |= 1 << (4 - j)
                i += 1
        out += ((x << 5) | mask).to_bytes(2, "little")
    for p, run in runs(ps):
        out += bytes([p << 7 | 127]) + run.to_bytes(2, "little") if run >= 127 else bytes([p << 7 | run])
    return bytes(out)


def _four_in_three(values: list[int], word_bytes: int, bits: int) -> bytes:
    """Values of ``bits`` four to three words (see ``ecf_decode_naive``), the last group padded with zeros."""
    s = 8 * word_bytes - bits
    values = values + [0] * (-len(values) % 4)
    out = b""
    for v0, v1, v2, v3 in zip(*(values[j::4] for j in range(4))):
        words = (v0 << s | (v1 & ((1 << s) - 1)), (v1 >> s) << (2 * s) | (v2 & ((1 << 2 * s) - 1)),
                 (v2 >> (2 * s)) << (3 * s) | v3)
        out += b"".join(word.to_bytes(word_bytes, "little") for word in words)
    return out


METAVISION_CD_DTYPE = {"names": ["x", "y", "p", "t"], "formats": ["<u2", "<u2", "<i2", "<i8"], "offsets": [0, 2, 4, 8],
                       "itemsize": 16}
"""Metavision's CD event record (HDF5 ``CD/events``)."""


def write_metavision_h5(path, events, width: int, height: int, seed: int, chunk: int = 16384,
                        raw_chunks: float = 0.0, pad_last: bool = False) -> None:
    """``events`` (``(t_us, x, y, p)``) as a Metavision HDF5 event file: root attributes ``version`` and ``format``
    (``EVT3;height=H;width=W``), ``CD/events`` records chunked by ``chunk`` with the ECF filter (0x8ECF, optional),
    each chunk one ECF block of :func:`ecf_encode_naive` in a random mode, stored as is; a fraction ``raw_chunks``
    of the chunks stored unfiltered (the records themselves, filter mask 1), as HDF5 does when an optional filter
    fails; ``pad_last``: a partial last chunk encoded whole, padded with zero events (HDF5's own filter path does
    that; Metavision's writer encodes only the events); ``CD/indexes`` and ``EXT_TRIGGER`` as Metavision creates
    them (empty)."""
    import h5py

    rng = random.Random(seed)
    record = np.dtype(METAVISION_CD_DTYPE)
    with h5py.File(path, "w") as f:
        f.attrs["version"] = "1.0"
        f.attrs["format"] = f"EVT3;height={height};width={width}"
        group = f.create_group("CD")
        dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
        dcpl.set_chunk((chunk,))
        dcpl.set_filter(0x8ECF, h5py.h5z.FLAG_OPTIONAL, ())
        space = h5py.h5s.create_simple((len(events),), (h5py.h5s.UNLIMITED,))
        dataset = h5py.Dataset(h5py.h5d.create(group.id, b"events", h5py.h5t.py_create(record), space, dcpl=dcpl))
        for start in range(0, len(events), chunk):
            part = events[start:start + chunk]
            if rng.random() < raw_chunks:
                records = np.zeros(chunk, record)
                for k, name in enumerate(("t", "x", "y", "p")):
                    records[name][:len(part)] = [e[k] for e in part]
                dataset.id.write_direct_chunk((start,), records.tobytes(), 1)
            else:
                if pad_last and len(part) < chunk:
                    part = part + [(part[-1][0], 0, 0, 0)] * (chunk - len(part))
                dataset.id.write_direct_chunk((start,), ecf_encode_naive(part, rng.randrange(3)), 0)
        group.create_dataset("indexes", (0,), [("id", "<u8"), ("ts", "<i8")], maxshape=(None,), chunks=(chunk,))
        triggers = f.create_group("EXT_TRIGGER")
        triggers.create_dataset("events", (0,), {"names": ["p", "t", "id"], "formats": ["<i2", "<i8", "<i2"],
                                                 "offsets": [0, 8, 16], "itemsize": 24}, maxshape=(None,),
                                chunks=(chunk,))


def aedat3_with_frames(events, frames, width: int, height: int) -> bytes:
    """An AEDAT 3.1 file written from libcaer's layout by plain code: a header naming a DAVIS346, then per frame a
    polarity packet (type 1) of the events before its exposure's end and a frame packet (type 2) of one 16-bit gray
    frame event (info: valid, 1 channel; four times; size; position; pixels), times below 2^31 (overflow 0)."""
    import struct

    out = [b"#!AER-DAT3.1\r\n", f"#Source 1: DAVIS346 sizeX {width} sizeY {height}\r\n".encode(),
           b"#!END-HEADER\r\n"]
    start = 0
    for t_start, t_end, image in frames:
        stop = int(np.searchsorted(events["t"], t_end, "right"))
        chunk = events[start:stop]
        if len(chunk):
            out.append(struct.pack("<hhiiiiii", 1, 1, 8, 4, 0, len(chunk), len(chunk), len(chunk)))
            for t, x, y, p in zip(chunk["t"].tolist(), chunk["x"].tolist(), chunk["y"].tolist(), chunk["p"].tolist()):
                out.append(struct.pack("<Ii", 1 | (int(p) << 1) | (y << 2) | (x << 17), t))
        start = stop
        pixels = np.asarray(image, "<u2")
        size = 36 + pixels.nbytes
        out.append(struct.pack("<hhiiiiii", 2, 1, size, 4, 0, 1, 1, 1))
        out.append(struct.pack("<Iiiiiiiii", 1 | (1 << 1), t_start - 100, t_end + 100, t_start, t_end,
                               pixels.shape[1], pixels.shape[0], 0, 0) + pixels.tobytes())
    chunk = events[start:]
    if len(chunk):
        out.append(struct.pack("<hhiiiiii", 1, 1, 8, 4, 0, len(chunk), len(chunk), len(chunk)))
        for t, x, y, p in zip(chunk["t"].tolist(), chunk["x"].tolist(), chunk["y"].tolist(), chunk["p"].tolist()):
            out.append(struct.pack("<Ii", 1 | (int(p) << 1) | (y << 2) | (x << 17), t))
    return b"".join(out)


def naive_spearman(a, b) -> float:
    """Spearman's rank correlation by its textbook definition: each value's rank is 1 + the number of values below
    it + half the number of others equal to it (ties share the mean rank), then Pearson's correlation of the ranks,
    in plain Python."""
    def ranks(values):
        return [1 + sum(w < v for w in values) + (sum(w == v for w in values) - 1) / 2 for v in values]

    ra, rb = ranks(list(a)), ranks(list(b))
    n = len(ra)
    ma, mb = sum(ra) / n, sum(rb) / n
    cov = sum((x - ma) * (y - mb) for x, y in zip(ra, rb))
    va = sum((x - ma) ** 2 for x in ra)
    vb = sum((y - mb) ** 2 for y in rb)
    return cov / (va * vb) ** 0.5
