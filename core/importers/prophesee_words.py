"""The event words of EVT 2.0 and DAT files, decoded with NumPy, times as the file holds them.

Why not faery's decoders for these two formats (:mod:`evpose.core.importers.prophesee` reads the headers and EVT
3.0 with faery): faery 0.7 clamps every time that steps back to the previous one (a DAT file whose time steps
back once put 100,001 events on one microsecond), reads any fall of an EVT 2.0 TIME_HIGH as a 2**34 µs wrap, and
skips unknown EVT 2.0 words without a count; it has no option to do otherwise. Both formats are fixed-size
words, so decoding them is a few vectorised bit operations. Here a time is never changed: the words' times go
to :class:`~evpose.core.importers.event_sink.EventSink`, which puts events out of order within the reorder
window in place (counted) and refuses the others (``--repair``: drops them, counted).

EVT 2.0 (32-bit little-endian words, type in bits 28-31): CD_OFF (0) / CD_ON (1) events carry x (bits 11-21),
y (bits 0-10) and the low 6 bits of the time (bits 22-27); EVT_TIME_HIGH (8) carries the upper 28 bits of the
34-bit µs counter; EXT_TRIGGER (10) is counted, OTHERS (14) and CONTINUED (15) are counted and skipped; any other
type is unknown (counted, reported). A TIME_HIGH that falls by more than half its range is a wrap (+2**34 µs).

DAT (64-bit words after the header's 2-byte event type and size): the low 32 bits are the time (a fall by more
than 2**31 µs is a wrap, +2**32 µs); DAT 2: x bits 32-45, y bits 46-59, polarity bits 60-63; DAT 1: x bits
32-40, y bits 41-48, polarity bits 49-52.

Times are µs of the sensor clock plus the header's ``t0``, int64.
"""
from __future__ import annotations

import numpy as np

#: EVT 2.0 word types.
EVT2_CD_OFF, EVT2_CD_ON, EVT2_TIME_HIGH, EVT2_TRIGGER, EVT2_OTHERS, EVT2_CONTINUED = 0, 1, 8, 10, 14, 15
_EVT2_KNOWN = (EVT2_CD_OFF, EVT2_CD_ON, EVT2_TIME_HIGH, EVT2_TRIGGER, EVT2_OTHERS, EVT2_CONTINUED)
#: DAT 1 / DAT 2 bit fields: (x shift, x mask, y shift, y mask, polarity shift, polarity mask).
_DAT_FIELDS = {"dat1": (32, 0x1FF, 41, 0xFF, 49, 0xF), "dat2": (32, 0x3FFF, 46, 0x3FFF, 60, 0xF)}


def _unwrap(raw: np.ndarray, last: int, n_wraps: int, period_bits: int) -> tuple[np.ndarray, int, int]:
    """``raw`` (int64, a counter of ``period_bits`` bits) unwrapped: a fall by more than half the period
    after ``last`` (the previous raw value) is one wrap. Returns (unwrapped, last raw value, wraps so far)."""
    steps = np.diff(raw, prepend=last)
    wraps = n_wraps + np.cumsum(steps < -(1 << (period_bits - 1)))
    if len(raw):
        last, n_wraps = int(raw[-1]), int(wraps[-1])
    return raw + (wraps << period_bits), last, n_wraps


class Evt2Words:
    """Stateful decoder of EVT 2.0 words, chunk by chunk.

    Parameters
    ----------
    t0_us : int
        Added to every time (the header's ``t0``; 0 when absent).

    Attributes
    ----------
    n_triggers, n_skipped, n_unknown : int
        EXT_TRIGGER words, OTHERS/CONTINUED words and words of unknown type so far.
    first_unknown : int or None
        Word index (from the start of the payload) of the first unknown word.
    """

    def __init__(self, t0_us: int = 0):
        self.t0 = int(t0_us)
        self.high_raw, self.n_wraps, self.high_us = 0, 0, 0
        self.n_words = self.n_triggers = self.n_skipped = self.n_unknown = 0
        self.first_unknown: int | None = None

    def decode(self, words: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(x uint16, y uint16, t_us int64, p uint8)`` of the CD events in ``words`` (uint32)."""
        kind = words >> 28
        is_high = kind == EVT2_TIME_HIGH
        raw = (words[is_high] & 0x0FFFFFFF).astype(np.int64)
        high, self.high_raw, self.n_wraps = _unwrap(raw, self.high_raw, self.n_wraps, 28)
        highs = np.concatenate([[self.high_us], high << 6])       # µs; [0] = the TIME_HIGH before this chunk
        if len(high):
            self.high_us = int(highs[-1])
        self._count(kind)
        cd = kind <= EVT2_CD_ON
        w = words[cd]
        t = highs[np.cumsum(is_high)[cd]] + ((w >> 22) & 0x3F).astype(np.int64) + self.t0
        self.n_words += len(words)
        return (((w >> 11) & 0x7FF).astype(np.uint16), (w & 0x7FF).astype(np.uint16), t,
                kind[cd].astype(np.uint8))

    def _count(self, kind: np.ndarray) -> None:
        self.n_triggers += int(np.count_nonzero(kind == EVT2_TRIGGER))
        self.n_skipped += int(np.count_nonzero((kind == EVT2_OTHERS) | (kind == EVT2_CONTINUED)))
        unknown = ~np.isin(kind, _EVT2_KNOWN)
        if unknown.any():
            if self.first_unknown is None:
                self.first_unknown = self.n_words + int(np.flatnonzero(unknown)[0])
            self.n_unknown += int(np.count_nonzero(unknown))


class DatWords:
    """Stateful decoder of DAT 1 / DAT 2 CD words (uint64), chunk by chunk; ``t0_us`` as for :class:`Evt2Words`."""

    def __init__(self, version: str, t0_us: int = 0):
        self.fields = _DAT_FIELDS[version]
        self.t0 = int(t0_us)
        self.last_raw, self.n_wraps = 0, 0

    def decode(self, words: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(x uint16, y uint16, t_us int64, p uint8)``: one event per word."""
        xs, xm, ys, ym, ps, pm = self.fields
        raw = (words & np.uint64(0xFFFFFFFF)).astype(np.int64)
        t, self.last_raw, self.n_wraps = _unwrap(raw, self.last_raw, self.n_wraps, 32)
        field = lambda shift, mask: ((words >> np.uint64(shift)) & np.uint64(mask))  # noqa: E731
        return (field(xs, xm).astype(np.uint16), field(ys, ym).astype(np.uint16), t + self.t0,
                field(ps, pm).astype(np.uint8))
