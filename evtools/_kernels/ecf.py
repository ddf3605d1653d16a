"""Prophesee's ECF (Event Compression Format) decoder: the HDF5 filter 0x8ECF of Metavision's HDF5 event files.

Metavision stores the CD events of an HDF5 event file in chunks of 16,384 events, each chunk one ECF block, and
nothing but Prophesee's plugin decodes them (hdf5plugin does not ship it). The block layout, as Prophesee's open
codec (github.com/prophesee-ai/hdf5_ecf) writes it, all little-endian:

- a 32-bit header: the event count in bits 2-31, bit 1 "y, x and p packed", bit 0 "x and p packed";
- the times: the first time (64 bits), then bytes ``(dt << 4) | count``: ``count`` events (15: the count is the
  next 16 bits) at the time advanced by ``dt`` (0-14); a byte whose upper half is 15 carries 4 bits of a larger
  advance instead, least significant first, until a byte of the first kind;
- packed y, x, p: 24 bits an event ``(y << 12) | (x << 1) | p``, four events in three 32-bit words; else the rows as
  16-bit runs ``(y << 5) | count`` (31: the count is the next 16 bits), then either packed x, p (12 bits an event,
  four in three 16-bit words) or the columns as 16-bit ``(x << 5) | mask``, an event at x and one at ``x + 1 + j``
  for each set bit ``4 - j`` of the mask, followed by the polarities as byte runs ``(p << 7) | count`` (127: the
  count is the next 16 bits).

The kernel writes each event's record straight into a chunk (:func:`evtools.events.record_words`), checking every
read against the block's end; ``tests/naive/__init__.py`` holds the pure-Python reference.
"""

from __future__ import annotations

import numpy as np

from evtools._kernels.jit import kernel

MAX_BLOCK_EVENTS = 65535
"""The most events an ECF block holds (the codec's limit)."""

TRUNCATED = -1
""":func:`decode_ecf`: the block ends before its events do."""
INCONSISTENT = -2
""":func:`decode_ecf`: a run of times, rows or polarities overruns the block's event count."""
TOO_MANY = -3
""":func:`decode_ecf`: the header's event count exceeds the room given (or the codec's limit)."""


@kernel(inline=True)
def _u16(data, k):  # pragma: no cover - compiled
    return np.int64(data[k]) | (np.int64(data[k + 1]) << 8)


@kernel(inline=True)
def _u32(data, k):  # pragma: no cover - compiled
    return _u16(data, k) | (_u16(data, k + 2) << 16)


@kernel(inline=True)
def _one_of_four(w0, w1, w2, j, spare):  # pragma: no cover - compiled
    """Value ``j`` of four packed in three words whose width exceeds a value's by ``spare`` bits (8: 24-bit values
    in 32-bit words; 4: 12-bit in 16-bit): a word holds the rest of one value above the low ``spare``, ``2 spare``
    or ``3 spare`` bits of the next."""
    if j == 0:
        return w0 >> spare
    if j == 1:
        return (w0 & ((1 << spare) - 1)) | ((w1 >> (2 * spare)) << spare)
    if j == 2:
        return (w1 & ((1 << (2 * spare)) - 1)) | ((w2 >> (3 * spare)) << (2 * spare))
    return w2 & ((1 << (3 * spare)) - 1)


@kernel
def decode_ecf(data, out):  # pragma: no cover - compiled
    """Decode one ECF block into records.

    Parameters
    ----------
    data : ndarray of uint8
        The block's bytes (a chunk as stored in the file).
    out : ndarray of int64, shape (capacity, 2)
        Records (:func:`evtools.events.record_words`).

    Returns
    -------
    n_events : int
        Events written to the first ``n_events`` records of ``out``, in the block's order; or a negative code:
        :data:`TRUNCATED`, :data:`INCONSISTENT`, :data:`TOO_MANY`.
    """
    size = data.shape[0]
    if size < 12:
        return TRUNCATED
    header = _u32(data, 0)
    n = header >> 2
    if n > out.shape[0] or n > MAX_BLOCK_EVENTS:
        return TOO_MANY
    k = 4
    now = _u32(data, k) | (_u32(data, k + 4) << 32)  # the first time (a 64-bit two's complement value)
    k += 8
    i = 0
    while i < n:  # the times
        if k >= size:
            return TRUNCATED
        byte = np.int64(data[k])
        step = byte >> 4
        count = byte & 0xF
        if step == 0xF:  # a larger advance, 4 bits a byte
            advance = 0
            shift = 0
            while step == 0xF:
                if shift < 64:
                    advance |= count << shift
                shift += 4
                k += 1
                if k >= size:
                    return TRUNCATED
                byte = np.int64(data[k])
                step = byte >> 4
                count = byte & 0xF
            now += advance
            continue
        now += step
        if count == 0xF:
            if k + 2 >= size:
                return TRUNCATED
            count = _u16(data, k + 1)
            k += 2
        k += 1
        if i + count > n:
            return INCONSISTENT
        for j in range(i, i + count):
            out[j, 0] = now
            out[j, 1] = 0
        i += count
    if (header >> 1) & 1:  # y, x, p packed: 4 events in 3 words of 32 bits
        for g in range(0, n, 4):
            if k + 12 > size:
                return TRUNCATED
            w0 = _u32(data, k)
            w1 = _u32(data, k + 4)
            w2 = _u32(data, k + 8)
            k += 12
            for j in range(min(4, n - g)):
                v = _one_of_four(w0, w1, w2, j, 8)
                out[g + j, 1] = ((v >> 1) & 0x7FF) | (((v >> 12) & 0x7FF) << 16) | ((v & 1) << 32)
        return n
    i = 0
    while i < n:  # the rows
        if k + 2 > size:
            return TRUNCATED
        value = _u16(data, k)
        k += 2
        count = value & 0x1F
        if count == 0x1F:
            if k + 2 > size:
                return TRUNCATED
            count = _u16(data, k)
            k += 2
        if i + count > n:
            return INCONSISTENT
        for j in range(i, i + count):
            out[j, 1] = (value >> 5) << 16
        i += count
    if header & 1:  # x, p packed: 4 events in 3 words of 16 bits
        for g in range(0, n, 4):
            if k + 6 > size:
                return TRUNCATED
            w0 = _u16(data, k)
            w1 = _u16(data, k + 2)
            w2 = _u16(data, k + 4)
            k += 6
            for j in range(min(4, n - g)):
                v = _one_of_four(w0, w1, w2, j, 4)
                out[g + j, 1] |= (v >> 1) | ((v & 1) << 32)
        return n
    i = 0
    while i < n:  # the columns: x, then x + 1 + j for each set bit 4 - j of the mask
        if k + 2 > size:
            return TRUNCATED
        value = _u16(data, k)
        k += 2
        x = value >> 5
        out[i, 1] |= x
        i += 1
        for j in range(5):
            if (value >> (4 - j)) & 1:
                if i < n:  # (the codec's encoder may mark columns past the block's end: ignored, as it does)
                    out[i, 1] |= x + j + 1
                i += 1
    i = 0
    while i < n:  # the polarities
        if k >= size:
            return TRUNCATED
        byte = np.int64(data[k])
        k += 1
        count = byte & 0x7F
        if count == 0x7F:
            if k + 2 > size:
                return TRUNCATED
            count = _u16(data, k)
            k += 2
        if i + count > n:
            return INCONSISTENT
        if byte >> 7:
            for j in range(i, i + count):
                out[j, 1] |= 1 << 32
        i += count
    return n
