"""Prophesee EVT 3.0 decoder kernel: a sequential state machine over 16-bit words, compiled with numba.

EVT 3.0 sends a coordinate, polarity or time field only when it changes, so every word is read against the
state left by the words before it; that state lives in one int64 array carried from call to call, so where a
stream is cut into calls never changes the events. ``tests/naive.py`` holds the pure-Python reference.

References
----------
Prophesee, "EVT 3.0 Format", https://docs.prophesee.ai/stable/data/encoding_formats/evt3.html
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


def new_evt3_state() -> np.ndarray:
    """A decoder state for the start of a stream."""
    state = np.zeros(STATE_SIZE, dtype=np.int64)
    state[TIME_HIGH] = -1
    state[ADDR_Y] = -1
    return state


@kernel(inline=True)
def _emit(state, t_us, x, y, p, n, loops, time_high, time_low, column, row, polarity):  # pragma: no cover
    """Write one CD event at ``n`` and return the new count; without a time or a row yet it is dropped and
    counted in ``state``."""
    if time_high < 0:
        state[DROPPED_NO_TIME] += 1
        return n
    if row < 0:
        state[DROPPED_NO_Y] += 1
        return n
    t_us[n] = (loops << 24) | (time_high << 12) | time_low
    x[n] = column
    y[n] = row
    p[n] = polarity
    return n + 1


@kernel
def decode_evt3(words, state, t_us, x, y, p):  # pragma: no cover - compiled
    """Decode EVT 3.0 words into CD events until the words or the output space run out.

    Parameters
    ----------
    words : ndarray of uint16
        Consecutive words of the stream (little-endian already applied).
    state : ndarray of int64, shape (STATE_SIZE,)
        Decoder state from :func:`new_evt3_state` or the previous call; updated in place.
    t_us, x, y : ndarray of int64, int16, int16
        Output columns; ``p`` (uint8, 1 = ON) likewise. Decoding stops before a word that might not fit
        (a word yields at most 12 events).

    Returns
    -------
    consumed : int
        Words decoded; call again with ``words[consumed:]`` if fewer than ``len(words)``.
    n_events : int
        Events written to the first ``n_events`` places of the outputs.
    """
    time_high = state[TIME_HIGH]
    time_low = state[TIME_LOW]
    loops = state[TIME_LOOPS]
    row = state[ADDR_Y]
    base_x = state[BASE_X]
    base_p = state[BASE_POLARITY]
    capacity = len(t_us)
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
            n = _emit(state, t_us, x, y, p, n, loops, time_high, time_low, word & 0x7FF, row, (word >> 11) & 1)
        elif kind == 0x3:  # VECT_BASE_X: bit 11 polarity, bits 0-10 x
            base_x = word & 0x7FF
            base_p = (word >> 11) & 1
        elif kind == 0x4 or kind == 0x5:  # VECT_12 (bits 0-11) / VECT_8 (bits 0-7): one bit per column
            width = 12 if kind == 0x4 else 8
            for j in range(width):
                if (word >> j) & 1:
                    n = _emit(state, t_us, x, y, p, n, loops, time_high, time_low, base_x + j, row, base_p)
            base_x += width
        elif kind == 0x6:  # EVT_TIME_LOW
            time_low = word & 0xFFF
        elif kind == 0x8:  # EVT_TIME_HIGH
            value = word & 0xFFF
            if time_high >= 0 and time_high - value > TIME_HIGH_LOOP_THRESHOLD:
                loops += 1
            time_high = value
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
