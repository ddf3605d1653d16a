"""AEDAT 4.0 event packets, many at a time: DV writes a DAVIS346 recording in packets of a few hundred events, and
parsing each packet's header and flatbuffer in Python cost 17 us a packet (0.55 s of 20M events in 620-event
packets, more than copying them). :func:`copy_event_packets` walks the whole packets of a block of an uncompressed
file; :func:`copy_decoded_packets` the decompressed packets of a compressed one, laid end to end by the decoding
thread. Both copy the events of each event packet and zero their padding, and stop at anything else (a packet of
another stream, a flatbuffer they do not recognise, a packet cut by the block's end, a full chunk), which the
reader's Python path handles.

The layout read (dv-processing's ``EventPacket``, size-prefixed): int32 stream id and uint32 size; then the
flatbuffer: uint32 size prefix, uint32 root offset, ``EVTS``; the table's vtable; field 0, an offset to the vector
of 16-byte events, its uint32 count first, the events last in the packet."""

from __future__ import annotations

import numpy as np

from evtools._kernels.jit import kernel

COPIED = 0
"""Every whole packet of the block was copied (the rest is a part of a packet, or nothing)."""
FULL = 1
"""The next packet's events do not fit in the chunk."""
OTHER = 2
"""The next packet is not an event packet the kernel reads (another stream, another layout, a size too large)."""


PAYLOAD_MASK = np.uint64((1 << 40) - 1)
"""Keeps x, y and on of an event's second 8-byte word and zeroes its padding: the writer's output bytes are
reproducible, and the reader's chunks hold zero padding whatever the file had (the kernels here and the AEDAT 4.0
reader and writer, which import it)."""


@kernel(inline=True)
def _u32(block, at):  # pragma: no cover - compiled
    """The little-endian uint32 at ``block[at]``, as an int64 (numba's arithmetic of uint64 and int64 is float)."""
    return (np.int64(block[at]) | (np.int64(block[at + 1]) << 8) | (np.int64(block[at + 2]) << 16)
            | (np.int64(block[at + 3]) << 24))


@kernel(inline=True)
def _event_vector(block, body, size):  # pragma: no cover - compiled
    """Where the events of the size-prefixed ``EVTS`` flatbuffer ``block[body:body + size]`` start, and how many:
    (byte position from ``body``, count), or (-1, 0) for anything else (another table, no events, a damaged offset,
    bytes after the events), which the reader's Python parser takes (with its error messages)."""
    if size < 16 or block[body + 8] != 69 or block[body + 9] != 86 or block[body + 10] != 84 \
            or block[body + 11] != 83:  # "EVTS"
        return -1, 0
    table = 4 + _u32(block, body + 4)
    if table + 4 > size:
        return -1, 0
    back = _u32(block, body + table)
    if back >= 1 << 31:
        back -= 1 << 32
    vtable = table - back
    if vtable < 0 or vtable + 6 > size:
        return -1, 0
    vtable_size = np.int64(block[body + vtable]) | (np.int64(block[body + vtable + 1]) << 8)
    field = np.int64(0)
    if vtable_size >= 6:
        field = np.int64(block[body + vtable + 4]) | (np.int64(block[body + vtable + 5]) << 8)
    if field == 0:
        return -1, 0  # (no events: the Python path, as an end mark is)
    at = table + field
    if at + 4 > size:
        return -1, 0
    vector = at + _u32(block, body + at)
    if vector + 4 > size:
        return -1, 0
    count = _u32(block, body + vector)
    if vector + 4 + 16 * count != size:
        return -1, 0
    return vector + 4, count


@kernel(inline=True)
def _copy_words(block, source, count, out, filled):  # pragma: no cover - compiled
    """Copy ``count`` events from ``block[source:]`` into ``out`` (8-byte words, two an event) from event
    ``filled`` on, each as its two 8-byte words, the second masked to x, y and the polarity (the file's padding
    zeroed; docs/performance.md). The words are read where the packet puts them, at any byte offset (a file's
    packets are not 8-byte aligned): unaligned 8-byte loads, which x86-64 and AArch64 do in hardware."""
    words = block[source:source + 16 * count].view(np.uint64)
    target = 2 * filled
    for i in range(count):
        out[target + 2 * i] = words[2 * i]
        out[target + 2 * i + 1] = words[2 * i + 1] & PAYLOAD_MASK


@kernel
def copy_event_packets(block, start, end, stream_id, out, filled, max_packet_bytes):  # pragma: no cover - compiled
    """Copy the events of the whole event packets of ``block[start:end]`` (an uncompressed file's bytes) into
    ``out`` (the chunk as 8-byte words, two an event) from event ``filled`` on. Returns (position of the first
    packet not copied, events in ``out``, COPIED / FULL / OTHER, events of the last packet copied or -1)."""
    pos = start
    last = -1
    capacity = out.size // 2
    while True:
        if pos + 8 > end:
            return pos, filled, COPIED, last
        sid = _u32(block, pos)
        if sid >= 1 << 31:
            sid -= 1 << 32
        size = _u32(block, pos + 4)
        if sid != stream_id or size > max_packet_bytes:
            return pos, filled, OTHER, last
        body = pos + 8
        if body + size > end:
            return pos, filled, COPIED, last
        events_at, count = _event_vector(block, body, size)
        if events_at < 0:
            return pos, filled, OTHER, last
        if filled + count > capacity:
            return pos, filled, FULL, last
        _copy_words(block, body + events_at, count, out, filled)
        filled += count
        last = count
        pos = body + size


@kernel
def copy_decoded_packets(data, bounds, first, out, filled):  # pragma: no cover - compiled
    """Copy the events of decompressed event packets laid end to end in ``data`` (packet ``k`` is
    ``data[bounds[k]:bounds[k + 1]]``), from packet ``first`` on, into ``out`` (8-byte words, two an event; room
    for them all) from event ``filled`` on. Returns (the first packet not copied: one the Python parser must read,
    or the number of packets; events in ``out``; events of the last packet copied or -1)."""
    last = -1
    for k in range(first, bounds.size - 1):
        events_at, count = _event_vector(data, bounds[k], bounds[k + 1] - bounds[k])
        if events_at < 0 or 2 * (filled + count) > out.size:
            return k, filled, last
        _copy_words(data, bounds[k] + events_at, count, out, filled)
        filled += count
        last = count
    return bounds.size - 1, filled, last
