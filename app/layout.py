"""How the main window fits a screen and keeps its layout: sizes from the screen, side panels in scroll
areas, a timeline that cannot be squeezed to a sliver, and a check of the whole layout (used by the tests).

Rules
-----
- The window never sizes itself beyond the screen's available area: its first size is most of the screen
  (:func:`first_size`), and opening a scene does not resize it (a saved dock layout is restored, a saved
  geometry only at start-up, clamped to the screen).
- Every side dock's content sits in a :func:`scrolled` area (:class:`PanelScroll`), so the window's minimum size does not depend on
  the panels' contents: the whole layout fits a 1280×720 screen, and a text that gets longer (a readout,
  a status line) scrolls or wraps inside its dock instead of moving the frame view.
- On a window lower than :data:`COMPACT_BELOW_H` (a laptop screen) the review marks are a tab beside the space-time
  view instead of under it (:func:`compact`): the space-time view gets the left column's height (its canvas >= 250 px
  at 1366×768), the review list its own tab.
- The timeline keeps its plots at a useful height (:data:`evpose.widgets.timeline.style.MIN_PLOT_H`); its dock has
  no title bar (no close button beside "Fit": it is shown and hidden from View ▸ Panels).
"""
from __future__ import annotations

from PySide6 import QtCore, QtWidgets

#: The smallest first size of the window (clamped to the screen's available area; see :func:`first_size`).
PREFERRED_SIZE = (1500, 950)
#: Saved dock layouts of another version are not restored (their sizes may not fit the current panels).
LAYOUT_VERSION = 3
#: Below this window height (px) the left column tabs the review marks with the space-time view (:func:`compact`).
COMPACT_BELOW_H = 900
#: Smallest useful size of each part of the window, px (the layout check's thresholds).
MIN_FRAME_VIEW = (300, 220)
MIN_DOCK = (200, 80)


class PanelScroll(QtWidgets.QScrollArea):
    """A scroll area that gives its widget the viewport's size, or the widget's minimum size where that is larger
    (then it scrolls). Unlike ``widgetResizable``, which gives a widget holding wrapped text its *preferred* height
    for the width (a GL view in it then takes the height it likes and the panel scrolls with room to spare)."""

    def __init__(self, widget: QtWidgets.QWidget):
        super().__init__()
        self.setWidgetResizable(False)
        self.setFrameShape(QtWidgets.QFrame.NoFrame)
        self.setWidget(widget)
        widget.installEventFilter(self)
        self.viewport().installEventFilter(self)
        self.fit()

    def fit(self) -> None:
        """Size the widget to the viewport, no smaller than its minimum."""
        w = self.widget()
        if w is None:
            return
        vp = self.viewport().size()
        m = w.minimumSizeHint().expandedTo(w.minimumSize())
        size = QtCore.QSize(max(vp.width(), m.width()), max(vp.height(), m.height()))
        if size != w.size():
            w.resize(size)

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt API)
        kind = event.type()
        if (obj is self.viewport() and kind == QtCore.QEvent.Resize) or \
                (obj is self.widget() and kind == QtCore.QEvent.LayoutRequest):
            self.fit()
        return super().eventFilter(obj, event)


def scrolled(widget: QtWidgets.QWidget) -> QtWidgets.QScrollArea:
    """``widget`` in a frameless :class:`PanelScroll`: the area's minimum size is small and does not follow the
    widget's texts, so the dock holding it never pushes the rest of the window; the widget scrolls only where
    the dock is smaller than the widget's minimum size."""
    area = PanelScroll(widget)
    area.setMinimumSize(MIN_DOCK[0], 60)
    return area


def available_rect(window: QtWidgets.QWidget) -> QtCore.QRect:
    """The available area (without panels and task bars) of the screen the window is on."""
    screen = window.screen() or QtWidgets.QApplication.primaryScreen()
    return screen.availableGeometry() if screen is not None else QtCore.QRect(0, 0, *PREFERRED_SIZE)


def fitted_geometry(available: QtCore.QRect, size=PREFERRED_SIZE, frame_margins=(0, 0)) -> QtCore.QRect:
    """The window's geometry: ``size`` clamped to ``available`` (less the window frame's ``frame_margins``,
    width and height), centred in it."""
    w = min(int(size[0]), available.width() - frame_margins[0])
    h = min(int(size[1]), available.height() - frame_margins[1])
    x = available.x() + max((available.width() - frame_margins[0] - w) // 2, 0)
    y = available.y() + max((available.height() - frame_margins[1] - h) // 2, 0)
    return QtCore.QRect(x, y, w, h)


def frame_margins(window: QtWidgets.QWidget) -> tuple[int, int]:
    """Width and height the window manager's frame adds around the window (0 before it is shown)."""
    fg, g = window.frameGeometry(), window.geometry()
    return max(fg.width() - g.width(), 0), max(fg.height() - g.height(), 0)


def first_size(available: QtCore.QRect) -> tuple[int, int]:
    """The window's first size on a screen: most of it (92 %), at least :data:`PREFERRED_SIZE` where it fits."""
    return (max(int(0.92 * available.width()), PREFERRED_SIZE[0]),
            max(int(0.92 * available.height()), PREFERRED_SIZE[1]))


def fit_to_screen(window: QtWidgets.QWidget, size=None) -> QtCore.QRect:
    """Resize and move ``window`` into its screen's available area (``size``: wanted size, default the
    current one; "first": :func:`first_size`); returns the new geometry."""
    size = (window.width(), window.height()) if size is None else size
    if size == "first":
        size = first_size(available_rect(window))
    rect = fitted_geometry(available_rect(window), size, frame_margins(window))
    if window.isVisible():     # keep the position the user chose when the window still fits there
        cur = window.frameGeometry()
        cur.setSize(rect.size())
        if available_rect(window).contains(cur):
            rect.moveTopLeft(window.geometry().topLeft())
    window.setGeometry(rect)
    return rect


def compact(window: QtWidgets.QWidget) -> bool:
    """Whether the window is too low to stack the space-time view and the review marks (:data:`COMPACT_BELOW_H`)."""
    return window.height() < COMPACT_BELOW_H


#: A saved dock layout is restored when the window is within this share of the size it was saved at.
LAYOUT_SIZE_TOLERANCE = 0.08


def layout_fits(window, width: int, height: int) -> bool:
    """Whether a dock layout saved at ``width`` x ``height`` suits ``window`` now: about the same size and the same
    column arrangement (:func:`compact`). A layout saved on a taller screen stacks the review marks under the
    space-time view; restored on a laptop it left the space-time canvas 33-86 px high."""
    w, h = window.width(), window.height()
    close = abs(w - width) <= LAYOUT_SIZE_TOLERANCE * width and abs(h - height) <= LAYOUT_SIZE_TOLERANCE * height
    return close and (height < COMPACT_BELOW_H) == compact(window)


def default_dock_sizes(window, spacetime, review, corrections, timeline) -> None:
    """Share the window between the frame view and the docks in proportion to its size: the side columns
    take 28 and 30 % (never below what their controls need), the timeline 22 % of the height (140-280 px)."""
    w, h = window.width(), window.height()
    left = int(min(max(0.28 * w, 360, content_width(spacetime), content_width(review)), 560))
    right = int(min(max(0.30 * w, 400, content_width(corrections)), 520))
    window.resizeDocks([spacetime, corrections], [left, right], QtCore.Qt.Horizontal)
    tl = int(min(max(0.22 * h, 140), 280))
    window.resizeDocks([timeline], [tl], QtCore.Qt.Vertical)
    if not window.tabifiedDockWidgets(spacetime):
        column = max(h - tl - 60, 300)
        window.resizeDocks([spacetime, review], [int(column * 0.55), int(column * 0.45)], QtCore.Qt.Vertical)


def content_width(dock: QtWidgets.QDockWidget) -> int:
    """Width ``dock`` needs to show its panel without a horizontal scroll bar (room for a vertical one)."""
    area = dock.widget()
    inner = area.widget() if isinstance(area, QtWidgets.QScrollArea) else area
    if inner is None:
        return 0
    bar = area.verticalScrollBar().sizeHint().width() if isinstance(area, QtWidgets.QScrollArea) else 0
    return inner.minimumSizeHint().width() + bar + 4      # + the dock's border


def bare_title(dock: QtWidgets.QDockWidget) -> None:
    """No title bar (so no close button): the dock is shown and hidden from the View menu only."""
    dock.setTitleBarWidget(QtWidgets.QWidget(dock))
    dock.setFeatures(QtWidgets.QDockWidget.NoDockWidgetFeatures)


def layout_problems(window) -> list[str]:
    """What is wrong with the window's layout now, in words (empty: nothing): a dock hidden, floating, outside
    the window or overlapping another part; a part smaller than useful; the window larger than its screen."""
    out = []
    central = window.centralWidget()
    parts = [("frame view", central)] + [(d.windowTitle(), d) for d in window.findChildren(QtWidgets.QDockWidget)
                                         if d.parent() is window and not d.isHidden() and not _behind_a_tab(window, d)]
    inner = window.rect()
    rects = []
    for name, w in parts:
        r = QtCore.QRect(w.mapTo(window, QtCore.QPoint(0, 0)), w.size())
        rects.append((name, r))
        if not w.isVisible():
            out.append(f"{name}: not visible")
        if getattr(w, "isFloating", lambda: False)():
            out.append(f"{name}: floating")
        elif not inner.contains(r):
            out.append(f"{name}: {_rect(r)} outside the window {_rect(inner)}")
        small = MIN_FRAME_VIEW if w is central else MIN_DOCK
        if r.width() < small[0] or r.height() < small[1]:
            out.append(f"{name}: {r.width()}×{r.height()} px, smaller than {small[0]}×{small[1]}")
    for i, (a, ra) in enumerate(rects):
        for b, rb in rects[i + 1:]:
            if ra.intersects(rb):
                out.append(f"{a} {_rect(ra)} overlaps {b} {_rect(rb)}")
    avail = available_rect(window)
    if window.frameGeometry().width() > avail.width() or window.frameGeometry().height() > avail.height():
        out.append(f"window {_rect(window.frameGeometry())} larger than the screen's {_rect(avail)}")
    return out


def _behind_a_tab(window, dock) -> bool:
    """A dock tabbed with others and not the tab in front (one click brings it)."""
    return bool(window.tabifiedDockWidgets(dock)) and dock.visibleRegion().isEmpty()


def _rect(r: QtCore.QRect) -> str:
    return f"{r.width()}×{r.height()}+{r.x()}+{r.y()}"
