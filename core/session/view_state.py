"""What the user looks at: the view state of a session (neither saved nor undoable)."""
from __future__ import annotations

from dataclasses import dataclass

from evpose.core.document.review import grid_window
from evpose.core.label.windows import Window, label_time

OVERLAY_KINDS = ("mask", "contour", "box", "axes", "center")
REPRESENTATION_NAMES = ("polarity", "spike", "three_channel", "time_surface", "counts", "voxel")


@dataclass(frozen=True)
class ViewState:
    """What the user looks at (not part of the document)."""

    t_us: int
    window_us: int = 10_000
    representation: str = "polarity"
    overlays: tuple = ("mask", "contour", "box", "center")
    hidden: frozenset = frozenset()
    selected: str | None = None
    mask_alpha: float = 0.35
    spacetime_span_us: int = 100_000
    spacetime_budget: int = 300_000
    spacetime_slices: int = 12
    #: Start of the window grid (the first event): windows are ``[origin + k w, origin + (k+1) w)``.
    grid_origin_us: int = 0

    def window(self, index: int | None = None) -> Window:
        """The grid window holding ``t_us`` (the export's tiling for this window length); ``index``
        defaults to its position in the grid."""
        t0, t1 = grid_window(self.t_us, self.grid_origin_us, self.window_us)
        k = (t0 - int(self.grid_origin_us)) // int(self.window_us) if index is None else index
        return Window(k, t0, t1, label_time(t0, t1))

