"""The event words of EVT 3.0 files, decoded here (numba), times as the file holds them.

Why not faery's decoder (which :mod:`evpose.core.importers.prophesee` used for EVT 3.0 before issue 26): on a real
Gen4.1 recording (expelliarmus' ``evt3_sample.raw``) TIME_LOW words step back 3-11 µs within one TIME_HIGH, and faery
0.7 clamps such a time to the previous one, so 0.66 % of the events came out 1-11 µs late against every other
reader; OpenEB's decoder and ``event_camera_codecs`` (the ROS drivers' decoder) take each word as written. Here too.

EVT 3.0 (16-bit little-endian words, type in bits 12-15; Prophesee's format description):

* ``EVT_ADDR_Y`` (0x0): y in bits 0-10 (bit 11: the system type, ignored); it holds for the events that follow;
* ``EVT_ADDR_X`` (0x2): one CD event at x (bits 0-10), polarity bit 11, the current y and time;
* ``VECT_BASE_X`` (0x3): base x (bits 0-10) and polarity (bit 11) of the vector words that follow;
* ``VECT_12`` (0x4) / ``VECT_8`` (0x5): a CD event at base x + i for every bit i set in bits 0-11 / 0-7, then base x
  moves on by 12 / 8;
* ``EVT_TIME_LOW`` (0x6): the low 12 bits of the µs time (bits 0-11), taken as written (it may step back);
* ``EVT_TIME_HIGH`` (0x8): the next 12 bits; a fall by more than half its range (2048 periods of 4096 µs) is a wrap
  of the 24-bit counter, +2**24 µs (the ROS codec counts a fall by more than 10 periods; on real data the two agree:
  a wrap falls from ~4095 to ~0, a glitch by a few);
* ``EXT_TRIGGER`` (0xA) is counted; ``OTHERS`` (0xE), ``CONTINUED_4`` (0x7) and ``CONTINUED_12`` (0xF) are counted and
  skipped; any other type is unknown (counted, reported).

CD events before the stream has had both a TIME_HIGH and a TIME_LOW have no time: they are counted and left out (as
the ROS codec does). Times are µs of the sensor clock plus the header's ``t0``, int64. Backward TIME_LOW steps within
one TIME_HIGH are counted (``n_time_low_back``) for the import report: the event sink then orders the events.
"""
from __future__ import annotations

import numpy as np

try:
    from numba import njit
    HAVE_NUMBA = True
except ImportError:                                  # pragma: no cover - numba is a dependency
    HAVE_NUMBA = False

__all__ = ["Evt3Words", "EVT3_TYPES"]

#: EVT 3.0 word types.
EVT3_TYPES = {"ADDR_Y": 0x0, "ADDR_X": 0x2, "VECT_BASE_X": 0x3, "VECT_12": 0x4, "VECT_8": 0x5, "TIME_LOW": 0x6,
              "CONTINUED_4": 0x7, "TIME_HIGH": 0x8, "EXT_TRIGGER": 0xA, "OTHERS": 0xE, "CONTINUED_12": 0xF}

# decoder state (int64 array): y, base x, vector polarity, time low, last time high (raw), wraps, has high, has low,
# triggers, skipped, unknown, first unknown word index (-1), words so far, CD events without a time, backward steps,
# the TIME_LOW a new one is compared with (-1 after a TIME_HIGH: a new high period starts its lows afresh)
_Y, _BX, _BP, _TL, _TH, _WR, _HH, _HL, _TRIG, _SKIP, _UNK, _FIRST_UNK, _NW, _NO_TIME, _BACK, _CMP = range(16)
_N_STATE = 16


def _decode_py(words, state, t0, x_out, y_out, t_out, p_out):
    """The decoder loop (compiled by numba below; this plain function is its reference and fallback)."""
    n = 0
    for i in range(words.shape[0]):
        w = int(words[i])
        kind = w >> 12
        if kind == 0x2 or kind == 0x4 or kind == 0x5:
            has_time = state[_HH] == 1 and state[_HL] == 1
            t = t0 + (state[_WR] << 24) + (state[_TH] << 12) + state[_TL]
            if kind == 0x2:
                if has_time:
                    x_out[n] = w & 0x7FF
                    y_out[n] = state[_Y]
                    t_out[n] = t
                    p_out[n] = (w >> 11) & 1
                    n += 1
                else:
                    state[_NO_TIME] += 1
            else:
                width = 12 if kind == 0x4 else 8
                for b in range(width):
                    if (w >> b) & 1:
                        if has_time:
                            x_out[n] = state[_BX] + b
                            y_out[n] = state[_Y]
                            t_out[n] = t
                            p_out[n] = state[_BP]
                            n += 1
                        else:
                            state[_NO_TIME] += 1
                state[_BX] += width
        elif kind == 0x0:
            state[_Y] = w & 0x7FF
        elif kind == 0x3:
            state[_BX] = w & 0x7FF
            state[_BP] = (w >> 11) & 1
        elif kind == 0x6:
            low = w & 0xFFF
            if low < state[_CMP]:
                state[_BACK] += 1
            state[_TL] = low
            state[_CMP] = low
            state[_HL] = 1
        elif kind == 0x8:
            high = w & 0xFFF
            if state[_HH] == 1 and high < state[_TH] - 2048:
                state[_WR] += 1
            state[_TH] = high
            state[_HH] = 1
            state[_CMP] = -1
        elif kind == 0xA:
            state[_TRIG] += 1
        elif kind == 0xE or kind == 0x7 or kind == 0xF:
            state[_SKIP] += 1
        else:
            if state[_UNK] == 0:
                state[_FIRST_UNK] = state[_NW] + i
            state[_UNK] += 1
    state[_NW] += words.shape[0]
    return n


_decode = njit(cache=True, nogil=True)(_decode_py) if HAVE_NUMBA else _decode_py


class Evt3Words:
    """Stateful decoder of EVT 3.0 words, chunk by chunk (the state -- y, vector base, times -- carries over).

    Parameters
    ----------
    t0_us : int
        Added to every time (the header's ``t0``; 0 when absent).

    Attributes (counts so far)
    ----------
    n_triggers, n_skipped, n_unknown, first_unknown : as :class:`~evpose.core.importers.prophesee_words.Evt2Words`
    n_no_time : CD events before the first TIME_HIGH and TIME_LOW (left out)
    n_time_low_back : TIME_LOW words smaller than the one before (backward steps, kept as written)
    n_wraps : 24-bit wraps of the TIME_HIGH counter
    """

    def __init__(self, t0_us: int = 0):
        self.t0 = int(t0_us)
        self._state = np.zeros(_N_STATE, np.int64)
        self._state[_FIRST_UNK] = -1
        self._state[_CMP] = -1

    def decode(self, words: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(x uint16, y uint16, t_us int64, p uint8)`` of the CD events in ``words`` (uint16)."""
        words = np.ascontiguousarray(words, dtype=np.uint16)
        kind = words >> 12
        bound = int(np.count_nonzero(kind == 0x2)) + 12 * int(np.count_nonzero(kind == 0x4)) + \
            8 * int(np.count_nonzero(kind == 0x5))
        x, y = np.empty(bound, np.uint16), np.empty(bound, np.uint16)
        t, p = np.empty(bound, np.int64), np.empty(bound, np.uint8)
        n = _decode(words, self._state, self.t0, x, y, t, p)
        return x[:n], y[:n], t[:n], p[:n]

    def _get(self, k: int) -> int:
        return int(self._state[k])

    n_triggers = property(lambda self: self._get(_TRIG))
    n_skipped = property(lambda self: self._get(_SKIP))
    n_unknown = property(lambda self: self._get(_UNK))
    n_no_time = property(lambda self: self._get(_NO_TIME))
    n_time_low_back = property(lambda self: self._get(_BACK))
    n_wraps = property(lambda self: self._get(_WR))
    n_words = property(lambda self: self._get(_NW))

    @property
    def first_unknown(self) -> int | None:
        v = self._get(_FIRST_UNK)
        return None if v < 0 else v
