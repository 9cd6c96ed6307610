"""The main window on an event-only scene (no ``[trajectory]``, no objects; issue 26.4): the events can be looked at
(frame, space-time view, kymograph, timeline's rate), every tool that needs poses is switched off and says why, and
the export offers HDF5 (events and event frames) alone. Nothing loads meshes or the rasteriser: the views skip
their label stages for such a scene (``core/views/``)."""
from __future__ import annotations

from PySide6 import QtWidgets

from evpose.app import actions as A
from evpose.core.data.manifest import ADD_TRAJECTORY_HINT, EVENTS_ONLY

__all__ = ["apply", "POSE_SECTIONS", "POSE_TOOLS", "REASON"]

#: the shortcut sections that act on poses, the clock or labels
POSE_SECTIONS = ("Clock", "Object pose", "Review")
#: the other actions that need poses: overlays of labels, the estimation tools, review marks
POSE_TOOLS = ("toggle_mask", "toggle_contour", "toggle_box", "toggle_axes", "selected_only", "outline_only",
              "auto_sync", "edge_sync", "refine_selected", "score_all", "review_range", "review_remove")
#: what a switched-off tool says (tooltip, status bar, the panel's banner)
REASON = f"{EVENTS_ONLY}: labels, the clock and pose tools need a trajectory; {ADD_TRAJECTORY_HINT}"


def pose_action_names() -> list[str]:
    return [s.name for s in A.SHORTCUTS if s.section in POSE_SECTIONS] + list(POSE_TOOLS)


def apply(window) -> None:
    """Switch ``window``'s pose tools off for its event-only session, each saying why."""
    for name in pose_action_names():
        act = window.actions_by_name.get(name)
        if act is not None:
            act.setEnabled(False)
            act.setToolTip(REASON)
            act.setStatusTip(REASON)
    banner = QtWidgets.QLabel(f"<b>Events only</b> — no trajectory, no objects. Labels, the clock and the pose "
                              f"tools need a trajectory:<br><code>evpose scene set-trajectory SCENE TRAJECTORY"
                              f"</code><br>(README, “Event-only scenes”).")
    banner.setWordWrap(True)
    banner.setObjectName("events_only_banner")
    banner.setStyleSheet("QLabel { background: #fff4d6; border: 1px solid #e0b84c; padding: 6px; }")
    for w in (window.panel, window.reviews, window.objects):
        if w is not None:
            w.setEnabled(False)
            w.setToolTip(REASON)
    right = window.panel.parentWidget() if window.panel is not None else None
    if right is not None and right.layout() is not None:
        right.layout().insertWidget(0, banner)
    window.events_only_banner = banner
    if window.timeline is not None:                 # the score row: scores need labels; no speed without poses
        for w in (window.timeline.scores_check, window.timeline.worst_button):
            w.setEnabled(False)
            w.setToolTip(REASON)
        window.timeline.show_pose_curves(False)
    if window.spacetime is not None:                # no silhouettes: no band
        window.spacetime.show_band_controls(False)
    window.statusBar().showMessage(EVENTS_ONLY, 10_000)
