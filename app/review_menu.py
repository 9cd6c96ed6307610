"""The Review menu: every review action of the review panel, with the shortcuts of the table in
:mod:`evpose.app.actions` (mark verified / rejected / flagged, next unreviewed / flagged), plus starting a range and
removing the selected mark."""
from __future__ import annotations

from PySide6 import QtGui

#: Action names of the Review menu, in order (None: a separator).
REVIEW_MENU = ("mark_verified", "mark_rejected", "mark_flagged", None, "review_range", "review_remove", None,
               "next_unreviewed", "next_flagged")


def review_actions(window) -> dict[str, QtGui.QAction]:
    """The review actions that have no shortcut: they act on ``window.reviews`` (the review panel) when a scene
    is open."""
    rng = QtGui.QAction("Start a range at this window", window)
    rng.setToolTip("the next mark covers every window from here to the window shown then")
    rng.triggered.connect(lambda: window.reviews is not None and window.reviews.range_button.toggle())
    remove = QtGui.QAction("Remove the selected mark", window)
    remove.setToolTip("remove the mark selected in the review panel's list")
    remove.triggered.connect(lambda: window.reviews is not None and window.reviews.remove_selected())
    return {"review_range": rng, "review_remove": remove}


def fill_review_menu(menu, actions: dict) -> None:
    for name in REVIEW_MENU:
        menu.addSeparator() if name is None else menu.addAction(actions[name])
