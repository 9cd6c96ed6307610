"""The space-time view's split of the events into those near a silhouette (the band: drawn in their object's
colour, on top) and the rest (dimmed, still by polarity), from the distances core computed
(:class:`evpose.core.views.frame.SpaceTimeData` ``edge_px`` / ``nearest``).

The split is cached by the data's arrays and the settings, so handing the same data again uploads nothing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evpose.widgets.spacetime.cloud import PALETTE_SIZE
from evpose.widgets.spacetime.style import BAND_ALPHA, DIM_OFF_RGBA, DIM_ON_RGBA, OFF_RGBA, ON_RGBA


@dataclass
class Split:
    """The points of one :class:`SpaceTimeData` as the two layers draw them.

    ``rest_points`` / ``rest_colors``: the dimmed events (or all, by polarity, when not coloured by object) and
    their palette indices; ``band_points`` / ``band_colors``: the events within the band and their object's
    palette index (object ``k`` -> ``k % PALETTE_SIZE``); ``in_band``: the mask over the data's points (None when
    not coloured by object); ``by_object``: whether the band is in use."""

    rest_points: np.ndarray
    rest_colors: np.ndarray
    band_points: np.ndarray
    band_colors: np.ndarray
    in_band: np.ndarray | None
    by_object: bool


def band_mask(edge_px: np.ndarray, nearest: np.ndarray, band_px: float, hidden_index) -> np.ndarray:
    """Events within ``band_px`` of a silhouette whose object (index) is not in ``hidden_index``."""
    m = (edge_px <= float(band_px)) & (nearest >= 0)
    if len(hidden_index):
        m &= ~np.isin(nearest, np.asarray(sorted(hidden_index), np.int8))
    return m


def band_palette(object_colors) -> list[tuple[float, float, float, float]]:
    """The band layer's palette: object ``k``'s colour (0-255 RGB) at index ``k % PALETTE_SIZE``."""
    pal = [(0.0, 0.0, 0.0, BAND_ALPHA)] * PALETTE_SIZE
    for k, rgb in enumerate(object_colors):
        pal[k % PALETTE_SIZE] = (*(c / 255.0 for c in rgb), BAND_ALPHA)
    return pal


def rest_palette(by_object: bool) -> tuple:
    """The other layer's palette (OFF, ON): dimmed when the band is in use."""
    return (DIM_OFF_RGBA, DIM_ON_RGBA) if by_object else (OFF_RGBA, ON_RGBA)


class BandSplitter:
    """:meth:`split` with a cache of the last result (same arrays and settings: the same :class:`Split`)."""

    def __init__(self):
        self._src: tuple = ()           # the arrays of the last split (held, so their ids cannot be reused)
        self._key = None
        self._split: Split | None = None

    def split(self, data, band_px: float, by_object: bool, hidden_index) -> Split:
        """The :class:`Split` of ``data`` for a band of ``band_px`` (objects in ``hidden_index`` not coloured);
        everything by polarity when not ``by_object`` or when ``data`` has no distances."""
        use = bool(by_object) and data.edge_px is not None and data.nearest is not None
        src = (data.points, data.polarity, data.edge_px, data.nearest)
        key = (float(band_px), use, frozenset(hidden_index))
        same_src = len(self._src) == 4 and all(a is b for a, b in zip(src, self._src))
        if same_src and key == self._key and self._split is not None:
            return self._split
        if not use:
            empty = np.zeros((0, 3), np.float32)
            sp = Split(data.points, data.polarity, empty, np.zeros(0, np.uint8), None, False)
        else:
            m = band_mask(data.edge_px, data.nearest, band_px, hidden_index)
            band, rest = np.flatnonzero(m), np.flatnonzero(~m)
            colors = (np.take(data.nearest, band).astype(np.uint8) % PALETTE_SIZE).astype(np.uint8)
            sp = Split(np.take(data.points, rest, axis=0), np.take(data.polarity, rest),
                       np.take(data.points, band, axis=0), colors, m, True)
        self._src, self._key, self._split = src, key, sp
        return sp
