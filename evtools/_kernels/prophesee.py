"""Prophesee EVT 2.0, EVT 2.1 and EVT 3.0 kernels: the decoders, sequential state machines over the words compiled
with numba, write each event's record straight into a chunk (its two 64-bit words, see
:func:`evtools.events.record_words`): no column arrays, no field-by-field copy (measured in docs/performance.md).
The EVT 2.0 encoder writes the words straight from the records.

EVT 3.0 sends a coordinate, polarity or time field only when it changes, and EVT 2.0 and 2.1 a time's upper bits only
when they change, so every word is read against the state left by the words before it; that state lives in one int64
array carried from call to call, so where a stream is cut into calls never changes the events.
``tests/naive/__init__.py`` holds the pure-Python references.

References
----------
Prophesee, "EVT 2.0 Format", "EVT 2.1 Format" and "EVT 3.0 Format",
https://docs.prophesee.ai/stable/data/encoding_formats/
"""

from __future__ import annotations

import numpy as np

from evtools._kernels.jit import kernel

# indices into the state array
TIME_HIGH = 0
"""Last EVT_TIME_HIGH payload (bits 12-23 of the time), -1 before the first one."""
TIME_LOW = 1
"""Last EVT_TIME_LOW payload (bits 0-11 of the time)."""
TIME_LOOPS = 2
"""How many times the 24-bit time base has wrapped."""
ADDR_Y = 3
"""Last EVT_ADDR_Y (row), -1 before the first one."""
BASE_X = 4
"""Column of the next vector element (VECT_BASE_X, advanced by 12 or 8 after each vector)."""
BASE_POLARITY = 5
"""Polarity set by VECT_BASE_X."""
DROPPED_NO_TIME = 6
"""Events seen before the first EVT_TIME_HIGH (time unknown: dropped)."""
DROPPED_NO_Y = 7
"""Events seen before the first EVT_ADDR_Y (row unknown: dropped)."""
TRIGGERS = 8
"""EXT_TRIGGER words (skipped)."""
OTHER_WORDS = 9
"""CONTINUED_4, CONTINUED_12, OTHERS and reserved words (skipped)."""
STATE_SIZE = 10

TIME_HIGH_LOOP_THRESHOLD = 1 << 11
"""A fall of EVT_TIME_HIGH by more than half its 12-bit range is a wrap of the 24-bit time base."""
MAX_EVENTS_PER_WORD = 12

# indices into the EVT 2.0 state array
EVT2_TIME_HIGH = 0
"""Last EVT_TIME_HIGH payload (``t >> 6`` modulo 2^28), -1 before the first one."""
EVT2_LOOPS = 1
"""How many times the 28-bit payload has wrapped."""
EVT2_DROPPED = 2
"""CD events seen before the first EVT_TIME_HIGH (time unknown: dropped)."""
EVT2_TRIGGERS = 3
"""EXT_TRIGGER words (skipped)."""
EVT2_OTHER_WORDS = 4
"""Words of any other type (skipped)."""
EVT2_STATE_SIZE = 5
EVT2_TIME_HIGH_BITS = 28


def new_evt2_state() -> np.ndarray:
    """An EVT 2.0 decoder state for the start of a stream."""
    state = np.zeros(EVT2_STATE_SIZE, dtype=np.int64)
    state[EVT2_TIME_HIGH] = -1
    return state


def new_evt3_state() -> np.ndarray:
    """A decoder state for the start of a stream."""
    state = np.zeros(STATE_SIZE, dtype=np.int64)
    state[TIME_HIGH] = -1
    state[ADDR_Y] = -1
    return state


@kernel(inline=True)
def _evt2_loops(last, value, loops):  # pragma: no cover - compiled
    """The wrap count once an EVT_TIME_HIGH of ``value`` follows one of ``last`` (-1: none yet): a fall by more
    than half the 28-bit range is a wrap of the 2^34 us time base (EVT 2.0 and 2.1)."""
    if last >= 0 and last - value > (1 << (EVT2_TIME_HIGH_BITS - 1)):
        return loops + 1
    return loops


@kernel(inline=True)
def _evt2_base(loops, last, t0_us):  # pragma: no cover - compiled
    """The time (us) of a CD word's zero low bits after the time-high ``last`` and ``loops`` wraps, plus ``t0_us``."""
    return (((loops << EVT2_TIME_HIGH_BITS) + last) << 6) + t0_us


@kernel
def decode_evt2(words, state, t0_us, out):  # pragma: no cover - compiled
    """Decode EVT 2.0 words into CD events.

    Parameters
    ----------
    words : ndarray of uint32
        Consecutive words of the stream (little-endian already applied).
    state : ndarray of int64, shape (EVT2_STATE_SIZE,)
        Decoder state from :func:`new_evt2_state` or the previous call; updated in place.
    t0_us : int
        Added to every time (the header's ``% t0``).
    out : ndarray of int64, shape (>= len(words), 2)
        Records (:func:`evtools.events.record_words`); a word is at most one event.

    Returns
    -------
    n_events : int
        Events written to the first ``n_events`` records of ``out``.
    """
    last = state[EVT2_TIME_HIGH]
    loops = state[EVT2_LOOPS]
    base = _evt2_base(loops, last, t0_us)
    n = 0
    for i in range(len(words)):
        word = np.int64(words[i])
        kind = word >> 28
        if kind <= 1:  # CD_OFF / CD_ON: bits 22-27 time's lower 6 bits, 11-21 x, 0-10 y
            if last < 0:
                state[EVT2_DROPPED] += 1
            else:
                out[n, 0] = base + ((word >> 22) & 0x3F)
                out[n, 1] = ((word >> 11) & 0x7FF) | ((word & 0x7FF) << 16) | (kind << 32)
                n += 1
        elif kind == 0x8:  # EVT_TIME_HIGH: bits 0-27 the time's upper bits
            value = word & ((1 << EVT2_TIME_HIGH_BITS) - 1)
            loops = _evt2_loops(last, value, loops)
            last = value
            base = _evt2_base(loops, last, t0_us)
        elif kind == 0xA:  # EXT_TRIGGER
            state[EVT2_TRIGGERS] += 1
        else:
            state[EVT2_OTHER_WORDS] += 1
    state[EVT2_TIME_HIGH] = last
    state[EVT2_LOOPS] = loops
    return n


EVT21_EVENTS_PER_WORD = 32
"""An EVT 2.1 CD word holds up to 32 events (one bit per column of a 32-column group)."""


@kernel(inline=True)
def _bits_below(low):  # pragma: no cover - compiled
    """The index of the one set bit of ``low`` (a power of two below 2^32): the count of the bits below it, added
    up in parallel (a population count without a branch per bit)."""
    v = low - 1
    v = v - ((v >> 1) & 0x55555555)
    v = (v & 0x33333333) + ((v >> 2) & 0x33333333)
    return (((v + (v >> 4)) & 0x0F0F0F0F) * 0x01010101 >> 24) & 0xFF


@kernel
def decode_evt21(words, state, t0_us, legacy, out):  # pragma: no cover - compiled
    """Decode EVT 2.1 words into CD events until the words or the output space run out.

    A word is 64 bits, its type in bits 60-63: EVT_NEG (0) / EVT_POS (1) hold the time's lower 6 bits in 54-59,
    x in 43-53, y in 32-42 and a mask in 0-31 whose bit k is an event at column x + k (in order of k);
    EVT_TIME_HIGH (8) holds ``t >> 6`` in 32-59, as EVT 2.0's (the same wrap rule); EXT_TRIGGER (0xA) and the
    others are counted and skipped. ``legacy``: the word's two 32-bit halves come in the other order (IMX636
    sensors; ``endianness=legacy`` in the header's format).

    Parameters
    ----------
    words : ndarray of int64
        Consecutive words of the stream, each the file's 8 little-endian bytes.
    state : ndarray of int64, shape (EVT2_STATE_SIZE,)
        Decoder state from :func:`new_evt2_state` or the previous call; updated in place.
    t0_us : int
        Added to every time (the header's ``% t0``).
    legacy : bool
        Swap each word's halves first.
    out : ndarray of int64, shape (capacity, 2)
        Records (:func:`evtools.events.record_words`). Decoding stops before a word that might not fit.

    Returns
    -------
    consumed : int
        Words decoded; call again with ``words[consumed:]`` if fewer than ``len(words)``.
    n_events : int
        Events written to the first ``n_events`` records of ``out``.
    """
    last = state[EVT2_TIME_HIGH]
    loops = state[EVT2_LOOPS]
    base = _evt2_base(loops, last, t0_us)
    capacity = out.shape[0]
    n = 0
    i = 0
    while i < len(words):
        if n + EVT21_EVENTS_PER_WORD > capacity:
            break
        word = words[i]
        if legacy:
            word = (word << 32) | ((word >> 32) & 0xFFFFFFFF)
        kind = (word >> 60) & 0xF
        if kind <= 1:  # EVT_NEG / EVT_POS
            mask = word & 0xFFFFFFFF
            if last < 0:
                while mask:
                    state[EVT2_DROPPED] += mask & 1
                    mask >>= 1
            else:
                t_us = base + ((word >> 54) & 0x3F)
                second = (((word >> 43) & 0x7FF) | (((word >> 32) & 0x7FF) << 16) | (kind << 32))
                while mask:  # the set bits, lowest first (x + k is below 2^11 + 32: it stays in its 16 bits)
                    low = mask & -mask
                    out[n, 0] = t_us
                    out[n, 1] = second + _bits_below(low)
                    n += 1
                    mask ^= low
        elif kind == 0x8:  # EVT_TIME_HIGH: bits 32-59 the time's upper bits
            value = (word >> 32) & ((1 << EVT2_TIME_HIGH_BITS) - 1)
            loops = _evt2_loops(last, value, loops)
            last = value
            base = _evt2_base(loops, last, t0_us)
        elif kind == 0xA:  # EXT_TRIGGER
            state[EVT2_TRIGGERS] += 1
        else:
            state[EVT2_OTHER_WORDS] += 1
        i += 1
    state[EVT2_TIME_HIGH] = last
    state[EVT2_LOOPS] = loops
    return i, n


@kernel
def encode_evt2(records, last_high, words):  # pragma: no cover - compiled
    """Encode events as EVT 2.0 words: a CD word each, preceded by an EVT_TIME_HIGH word whenever ``t >> 6``
    changes.

    Parameters
    ----------
    records : ndarray of int64, shape (n, 2)
        The events' records (:func:`evtools.events.record_words`), time-sorted, times not negative.
    last_high : int
        ``t >> 6`` of the last time-high word written before, -1 at the start of a file.
    words : ndarray of uint32, shape (>= 2 n,)
        Room for the words.

    Returns
    -------
    n_words : int
        Words written; -1 (nothing usable written) when two consecutive events lie 2^27 time-high steps (about
        2^33 us) or more apart, which a reader would take for a wrap.
    last_high : int
        ``t >> 6`` of the last time-high word now.
    """
    n = 0
    for k in range(records.shape[0]):
        t = records[k, 0]
        second = records[k, 1]
        high = t >> 6
        if high != last_high:
            if last_high >= 0 and high - last_high >= (1 << (EVT2_TIME_HIGH_BITS - 1)):
                return -1, last_high
            words[n] = (0x8 << 28) | (high & ((1 << EVT2_TIME_HIGH_BITS) - 1))
            n += 1
            last_high = high
        x = second & 0xFFFF
        y = (second >> 16) & 0xFFFF
        on = (second >> 32) & 0xFF
        words[n] = ((1 if on != 0 else 0) << 28) | ((t & 0x3F) << 22) | (x << 11) | y
        n += 1
    return n, last_high


@kernel(inline=True)
def _emit(state, out, n, time_high, t_us, column, row, polarity):  # pragma: no cover - compiled
    """Write one CD event's record at ``n`` and return the new count; without a time (``time_high`` < 0) or a row
    yet it is dropped and counted in ``state``."""
    if time_high < 0:
        state[DROPPED_NO_TIME] += 1
        return n
    if row < 0:
        state[DROPPED_NO_Y] += 1
        return n
    out[n, 0] = t_us
    # a damaged stream's vectors can run the column past 16 bits: it wraps in its field, as an int16 store would,
    # and never reaches the row's
    out[n, 1] = (column & 0xFFFF) | (row << 16) | (polarity << 32)
    return n + 1


@kernel
def decode_evt3(words, state, t0_us, out):  # pragma: no cover - compiled
    """Decode EVT 3.0 words into CD events until the words or the output space run out.

    Parameters
    ----------
    words : ndarray of uint16
        Consecutive words of the stream (little-endian already applied).
    state : ndarray of int64, shape (STATE_SIZE,)
        Decoder state from :func:`new_evt3_state` or the previous call; updated in place.
    t0_us : int
        Added to every time (the header's ``% t0``).
    out : ndarray of int64, shape (capacity, 2)
        Records (:func:`evtools.events.record_words`). Decoding stops before a word that might not fit (a word
        yields at most 12 events).

    Returns
    -------
    consumed : int
        Words decoded; call again with ``words[consumed:]`` if fewer than ``len(words)``.
    n_events : int
        Events written to the first ``n_events`` records of ``out``.
    """
    time_high = state[TIME_HIGH]
    time_low = state[TIME_LOW]
    loops = state[TIME_LOOPS]
    row = state[ADDR_Y]
    base_x = state[BASE_X]
    base_p = state[BASE_POLARITY]
    now = ((loops << 24) | (time_high << 12) | time_low) + t0_us  # the time of the next event (with a time high)
    capacity = len(out)
    n = 0
    i = 0
    while i < len(words):
        if n + MAX_EVENTS_PER_WORD > capacity:
            break
        word = np.int64(words[i])
        kind = word >> 12
        if kind == 0x0:  # EVT_ADDR_Y: bit 11 system type, bits 0-10 y
            row = word & 0x7FF
        elif kind == 0x2:  # EVT_ADDR_X: bit 11 polarity, bits 0-10 x; one event
            n = _emit(state, out, n, time_high, now, word & 0x7FF, row, (word >> 11) & 1)
        elif kind == 0x3:  # VECT_BASE_X: bit 11 polarity, bits 0-10 x
            base_x = word & 0x7FF
            base_p = (word >> 11) & 1
        elif kind == 0x4 or kind == 0x5:  # VECT_12 (bits 0-11) / VECT_8 (bits 0-7): one bit per column
            width = 12 if kind == 0x4 else 8
            for j in range(width):
                if (word >> j) & 1:
                    n = _emit(state, out, n, time_high, now, base_x + j, row, base_p)
            base_x += width
        elif kind == 0x6:  # EVT_TIME_LOW
            time_low = word & 0xFFF
            now = ((loops << 24) | (time_high << 12) | time_low) + t0_us
        elif kind == 0x8:  # EVT_TIME_HIGH
            value = word & 0xFFF
            if time_high >= 0 and time_high - value > TIME_HIGH_LOOP_THRESHOLD:
                loops += 1
            time_high = value
            now = ((loops << 24) | (time_high << 12) | time_low) + t0_us
        elif kind == 0xA:  # EXT_TRIGGER
            state[TRIGGERS] += 1
        else:
            state[OTHER_WORDS] += 1
        i += 1
    state[TIME_HIGH] = time_high
    state[TIME_LOW] = time_low
    state[TIME_LOOPS] = loops
    state[ADDR_Y] = row
    state[BASE_X] = base_x
    state[BASE_POLARITY] = base_p
    return i, n
