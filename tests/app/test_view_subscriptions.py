"""Every view of a session disconnects when it is replaced or closed: the old session calls no
deleted view, holds none of them, and one edit reaches exactly once each live view that shows its kind of change,
and no other (issue 25.1: a time step reached 9 subscribers, 6 of which ignored it)."""
import gc
import weakref

import pytest
import shiboken6
from PySide6 import QtCore

VIEWS = ("panel", "objects", "reviews", "timeline", "spacetime", "kymograph", "frame_view")
#: views that subscribe and are not attributes of the window: the frame view's toolbar, the residual view's feed
N_SUBSCRIBERS = len(VIEWS) + 1 + 1 + 1                      # the views, the toolbar, the residual feed and the window


@pytest.fixture
def calls(monkeypatch):
    """``(view class, change)`` of every call of a view's session slot (patched on the classes)."""
    from evpose.app.main_window import MainWindow
    from evpose.widgets.correction_panel import CorrectionPanel
    from evpose.widgets.frame.toolbar import FrameToolbar
    from evpose.widgets.frame.view import FrameView
    from evpose.widgets.kymograph.view import KymographView
    from evpose.widgets.object_list import ObjectList
    from evpose.widgets.review_panel import ReviewPanel
    from evpose.widgets.spacetime.view import SpaceTimeView
    from evpose.widgets.timeline.view import Timeline

    seen = []
    for cls in (CorrectionPanel, ObjectList, ReviewPanel, SpaceTimeView, KymographView, Timeline, FrameView,
                FrameToolbar, MainWindow):
        original = cls._on_session

        def spy(self, change, _original=original, _name=cls.__name__):
            seen.append((_name, change))
            return _original(self, change)

        monkeypatch.setattr(cls, "_on_session", spy)
    return seen


def deleted_and_collected(qtbot) -> None:
    for _ in range(3):
        QtCore.QCoreApplication.sendPostedEvents(None, QtCore.QEvent.DeferredDelete)
        qtbot.wait(20)
    gc.collect()


def test_one_edit_reaches_each_view_once(qtbot, window, scene_copy, calls):
    s = window.controller.open_scene(scene_copy)
    assert len(s.changed) == N_SUBSCRIBERS
    assert len(s.history.changed) == 2                      # the session and the undo bridge
    calls.clear()
    s.set_offset_correction_us(1234)                        # a document change
    assert sorted(name for name, _ in calls) == ["CorrectionPanel", "MainWindow", "ObjectList", "ReviewPanel",
                                                 "Timeline"]
    calls.clear()
    s.set_time(s.time_range[0] + 200_000)                   # a time step: only the views that follow the time
    assert sorted(name for name, _ in calls) == ["CorrectionPanel", "MainWindow", "Timeline"]
    calls.clear()
    s.set_view_option(spacetime_budget=12_345)              # a view option
    assert sorted(name for name, _ in calls) == ["FrameToolbar", "FrameView", "KymographView", "MainWindow",
                                                 "SpaceTimeView", "Timeline"]
    calls.clear()
    s.select(s.object_names[1])                             # objects (selection, visibility)
    assert sorted(name for name, _ in calls) == ["CorrectionPanel", "FrameView", "MainWindow", "ObjectList",
                                                 "SpaceTimeView", "Timeline"]


@pytest.mark.parametrize("how", ["replaced", "closed"])
def test_old_views_are_disconnected_not_called_and_freed(qtbot, window, scene_copy, calls, how):
    old = window.controller.open_scene(scene_copy)
    refs = {name: weakref.ref(getattr(window, name)) for name in VIEWS}
    refs["undo_bridge"] = weakref.ref(window.undo_bridge)
    if how == "replaced":
        new = window.controller.open_scene(scene_copy)
        assert new is not old and len(new.changed) == N_SUBSCRIBERS
    else:
        window.close()
    deleted_and_collected(qtbot)
    assert len(old.changed) == 0                            # nobody listens to the old session
    assert len(old.history.changed) == 1                    # only the old session itself
    alive = [name for name, ref in refs.items() if ref() is not None]
    assert alive == [], f"kept alive after the session was {how}: {alive}"
    calls.clear()
    old.set_view_option(spacetime_budget=12_345)            # the old session changes: no deleted view hears it
    old.select(old.object_names[0])
    old.set_offset_correction_us(999)
    assert calls == []


def test_a_deleted_view_still_held_by_python_is_not_called(qtbot, window, scene_copy, calls):
    """Qt deletes a view's widget before Python frees it (here: a reference held on purpose, as a late
    worker result might): the subscription ends with the widget, not with the Python object."""
    old = window.controller.open_scene(scene_copy)
    held = [getattr(window, name) for name in VIEWS]
    window.controller.open_scene(scene_copy)
    deleted_and_collected(qtbot)
    assert not any(shiboken6.isValid(v) for v in held)    # the widgets are gone, the wrappers are not
    assert len(old.changed) == 0
    calls.clear()
    old.set_view_option(spacetime_budget=12_345)
    old.set_object_visible(old.object_names[0], False)
    old.set_offset_correction_us(999)
    assert calls == []
