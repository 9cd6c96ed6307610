"""Events first, overlays when ready (issue 14, point 3): the main window paints a window's event image before its
overlays, marks overlays of another window while they are on screen, and computes only the latest of a flood of
requests on every request path (events, overlays with the scores, space-time)."""
from __future__ import annotations

import threading

import pytest

from evpose.core.views.frame import FrameComputer
from evpose.core.views.spacetime import SpaceTimeComputer
from evpose.widgets.frame.view import STALE_OVERLAY_OPACITY


@pytest.fixture
def gate(monkeypatch):
    """Overlay and space-time computations wait for ``gate`` (set by default); records their requests."""
    gate = threading.Event()
    gate.set()
    gate.overlay_serials, gate.spacetime_serials = [], []
    overlay, spacetime = FrameComputer.overlay_stages, SpaceTimeComputer.spacetime_stages

    def gated_overlays(self, req):
        gate.overlay_serials.append(req.serial)
        assert gate.wait(30)
        return (yield from overlay(self, req))

    def gated_spacetime(self, req):
        gate.spacetime_serials.append(req.serial)
        assert gate.wait(30)
        return (yield from spacetime(self, req))

    monkeypatch.setattr(FrameComputer, "overlay_stages", gated_overlays)
    monkeypatch.setattr(SpaceTimeComputer, "spacetime_stages", gated_spacetime)
    return gate


def overlay_opacities(view) -> set:
    return {round(it.opacity(), 3) for it in view._overlay_items()}


def test_events_are_painted_first_and_overlays_of_another_time_are_marked(qtbot, gate, window, scene_copy):
    gate.clear()
    s = window.controller.open_scene(scene_copy)
    view = window.frame_view
    qtbot.waitUntil(window.events_up_to_date, timeout=30_000)
    assert view.events.window == s.view.window() and window.frame is None     # events on screen, overlays not
    assert "overlays: computing" in view.info.text()
    gate.set()
    qtbot.waitUntil(window.frame_up_to_date, timeout=30_000)
    assert view.frame.window == view.events.window and not view.overlays_stale
    assert overlay_opacities(view) == {1.0} and "on masks" in view.info.text()
    old = view.frame.window
    labelled = next((u, v) for v, row in enumerate(view.frame.labels.label_map) for u, k in enumerate(row) if k >= 0)
    assert view.hover_info(*labelled)["object"] is not None

    gate.clear()                                   # the next overlays take their time
    s.step_windows(3)
    qtbot.waitUntil(window.events_up_to_date, timeout=30_000)
    assert view.events.window == s.view.window() != old
    assert view.frame.window == old                # the old overlays are still drawn ...
    assert view.overlays_stale                     # ... and marked: dimmed, their time named, no hover labels
    assert overlay_opacities(view) == {STALE_OVERLAY_OPACITY}
    assert "updating" in view.info.text()
    assert view.hover_info(*labelled)["object"] is None
    gate.set()
    qtbot.waitUntil(window.frame_up_to_date, timeout=30_000)
    assert view.frame.window == view.events.window == s.view.window() and not view.overlays_stale
    assert overlay_opacities(view) == {1.0}


def test_only_the_latest_of_a_flood_of_scrub_requests_is_computed(qtbot, gate, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    qtbot.waitUntil(lambda: window.frame_up_to_date() and window.spacetime_drawn(), timeout=30_000)
    n_overlays, n_spacetime = len(gate.overlay_serials), len(gate.spacetime_serials)
    gate.clear()
    s.step_windows(1)                               # the overlay worker is now busy with this one
    qtbot.waitUntil(lambda: len(gate.overlay_serials) == n_overlays + 1, timeout=10_000)
    for _ in range(40):                             # a fast scrub: 40 more requests meanwhile
        s.step_windows(1)
    last = window._submitted_serial["frame"]        # the serial of the last scrub request
    qtbot.wait(400)                                 # past the space-time debounce
    gate.set()
    qtbot.waitUntil(lambda: window.frame_up_to_date() and window.spacetime_drawn(), timeout=30_000)
    overlays = gate.overlay_serials[n_overlays:]
    assert len(overlays) == 2 and overlays[-1] == last, overlays        # the busy one, then the latest only
    assert window.frame.window == s.view.window()
    assert len(gate.spacetime_serials) - n_spacetime <= 2              # debounced and coalesced
    assert window.frame_view.events.window == s.view.window()
