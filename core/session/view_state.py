"""What the user looks at: the view state of a session (neither saved nor undoable)."""
from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from evpose.core.document.review import grid_window
from evpose.core.label.windows import DEFAULT_WINDOW_US, Window, label_time

OVERLAY_KINDS = ("mask", "contour", "box", "axes", "center")
REPRESENTATION_NAMES = ("polarity", "spike", "three_channel", "time_surface", "counts", "voxel")


@dataclass(frozen=True)
class CountGrid:
    """Windows of ``n_events`` events each, from the first event: the export's ``--window-events`` tiling
    (:func:`evpose.core.label.windows.count_windows`), looked up one window at a time.

    Two events' times are read per window (cached); the store is shared with the views' worker threads,
    so lookups hold a lock."""

    store: object
    n_events: int
    _cache: dict = field(default_factory=dict, compare=False, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, compare=False, repr=False)

    def __post_init__(self):
        if int(self.n_events) <= 0:
            raise ValueError(f"events per window must be positive, got {self.n_events}")

    @property
    def n_windows(self) -> int:
        return max(-(-int(self.store.n_events) // int(self.n_events)), 1)

    def index_at(self, t_us: int) -> int:
        """Index of the window holding the first event at or after ``t_us`` (the last one past the end)."""
        n = int(self.store.n_events)
        i = min(int(self.store.index_of(int(t_us))), max(n - 1, 0))
        return i // int(self.n_events)

    def window(self, k: int) -> Window:
        """Window ``k`` (clipped to the tiling): ``[t of its first event, t of its last event + 1)``."""
        k = min(max(int(k), 0), self.n_windows - 1)
        with self._lock:
            w = self._cache.get(k)
            if w is None:
                n = int(self.store.n_events)
                i0 = k * int(self.n_events)
                i1 = min(i0 + int(self.n_events), n)
                if i1 <= i0:
                    t0 = t1 = 0
                else:
                    t0 = int(self.store.read(i0, i0 + 1).t[0])
                    t1 = int(self.store.read(i1 - 1, i1).t[0]) + 1
                w = Window(k, t0, t1, label_time(t0, t1), i0, i1)
                if len(self._cache) > 4096:
                    self._cache.clear()
                self._cache[k] = w
        return w

    def window_at(self, t_us: int) -> Window:
        return self.window(self.index_at(t_us))

    def step(self, t_us: int, n: int) -> int:
        """The label time of the window ``n`` windows after the one at ``t_us`` (clipped to the tiling). A view is
        placed by time, so a window whose label time leads back to the window at ``t_us`` or before it (events
        sharing one time across the window border) cannot be shown: such windows are stepped over, so every step
        changes the window shown unless the tiling ends."""
        k0 = self.index_at(t_us)
        k = k0 + int(n)
        w = self.window(k)
        d = 1 if n > 0 else -1
        while n and (self.index_at(w.t_label_us) - k0) * d <= 0 and 0 <= k + d < self.n_windows:
            k += d
            w = self.window(k)
        return w.t_label_us

    def mean_window_us(self) -> int:
        """Average length of a window (µs), for what needs one number (the space-time slab, stepping estimates)."""
        t0, t1 = self.store.t_first_us, self.store.t_last_us
        if t0 is None or not self.store.n_events:
            return 1
        return max(int(np.ceil((t1 - t0 + 1) * int(self.n_events) / int(self.store.n_events))), 1)


@dataclass(frozen=True)
class ViewState:
    """What the user looks at (not part of the document)."""

    t_us: int
    window_us: int = DEFAULT_WINDOW_US
    representation: str = "polarity"
    overlays: tuple = ("mask", "contour", "box", "center")
    hidden: frozenset = frozenset()
    selected: str | None = None
    mask_alpha: float = 0.35
    spacetime_span_us: int = 100_000
    spacetime_budget: int = 300_000
    spacetime_slices: int = 12
    #: Space-time view: events within this many px of a silhouette are drawn in its object's colour (the rest
    #: dimmed) when ``spacetime_by_object``; otherwise every event by polarity.
    spacetime_band_px: float = 3.0
    spacetime_by_object: bool = True
    #: Kymograph: time span around the current time, µs.
    kymograph_span_us: int = 200_000
    #: Start of the window grid (the first event): windows are ``[origin + k w, origin + (k+1) w)``.
    grid_origin_us: int = 0
    #: Windows of a fixed number of events instead of ``window_us`` (None: time windows); ``window_us`` then
    #: holds their average length. Set by :meth:`evpose.core.session.model.Session.set_window_events`.
    count_grid: CountGrid | None = None
    #: Frame view display (no recomputation): opacity of the event image (0..1), contrast of the event
    #: image (1 = as computed; a gamma on the ink, :func:`evpose.core.label.overlay.adjust_contrast`), only the
    #: selected object's overlays, outlines only (no filled masks, boxes, axes, centres).
    event_opacity: float = 1.0
    contrast: float = 1.0
    selected_only: bool = False
    outline_only: bool = False

    @property
    def window_events(self) -> int:
        """Events per window (0: time windows of ``window_us``)."""
        return 0 if self.count_grid is None else int(self.count_grid.n_events)

    def window(self, index: int | None = None) -> Window:
        """The window holding ``t_us``: a cell of the time grid (the export's tiling for this window length),
        or of the event-count tiling when :attr:`count_grid` is set; ``index`` defaults to its position."""
        if self.count_grid is not None:
            w = self.count_grid.window_at(self.t_us)
            return w if index is None else Window(index, w.t0_us, w.t1_us, w.t_label_us, w.i0, w.i1)
        t0, t1 = grid_window(self.t_us, self.grid_origin_us, self.window_us)
        k = (t0 - int(self.grid_origin_us)) // int(self.window_us) if index is None else index
        return Window(k, t0, t1, label_time(t0, t1))
