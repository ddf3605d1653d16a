"""Slow, obviously correct reference versions of evtools' numba kernels (tests compare the kernels to these).

Each reference follows its paper or format specification line by line, in plain Python, one event at a time.
"""

from __future__ import annotations


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
