"""An event-only scene in the app (issue 26.4): it opens for looking (frame, space-time view, kymograph, the
timeline's rate), every pose tool is off and says why, the export offers HDF5 alone, and nothing loads the
rasteriser: the views skip their label stages."""
from __future__ import annotations

import json

import numpy as np
import pytest

from evpose.core.data.scene import Scene
from evpose.core.importers import import_scene

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def eo_scene(tiny_scene_dir, tmp_path_factory):
    """The tiny scene's events alone, imported as an event-only scene."""
    work = tmp_path_factory.mktemp("eo_app")
    scene = Scene.open(tiny_scene_dir, corrections=None)
    try:
        ev = scene.events.window(scene.events.t_first_us, scene.events.t_last_us + 1)
        (work / "camera.json").write_text(json.dumps(scene.camera.to_dict()))
    finally:
        scene.close()
    np.savez(work / "events.npz", x=ev.x, y=ev.y, t=ev.t, p=ev.p, t_unit=np.array("us"))
    res = import_scene("npz", [work / "events.npz"], work / "eo", camera=str(work / "camera.json"), log=None)
    assert res["events_only"]
    return work / "eo"


def test_an_event_only_scene_opens_for_looking_with_the_pose_tools_off(qtbot, window, eo_scene, monkeypatch):
    from evpose.app import events_only
    from evpose.app.export_dialog import ExportDialog
    from evpose.core.label import annotate

    def no_annotator(*a, **k):
        raise AssertionError("an annotator (rasteriser) was made for an event-only scene")

    monkeypatch.setattr(annotate.Annotator, "__init__", no_annotator)
    s = window.controller.open_scene(eo_scene)
    assert s is not None, window.last_error
    s.set_time(s.busiest_time())
    qtbot.waitUntil(window.frame_up_to_date, timeout=30_000)
    assert window.frame_view.events is not None and window.frame_view.events.n_events > 0
    assert not window.frame.labels.valid and window.frame.overlays == []
    # the space-time view and the kymograph draw the events (no silhouettes)
    window.request_spacetime()
    qtbot.waitUntil(window.spacetime_drawn, timeout=30_000)
    assert window.feeds.spacetime.shown > 0
    window.spacetime.kymographRequested.emit()
    qtbot.waitUntil(lambda: window.kymograph.data is not None, timeout=30_000)
    # the timeline shows the rate, no speed
    assert window.timeline.data.rate_hz.sum() > 0 and not window.timeline.data.speed_valid.any()
    # every pose tool is off and says why
    names = events_only.pose_action_names()
    assert {"auto_sync", "score_all", "tx_plus", "offset_plus", "mark_verified"} <= set(names)
    for name in names:
        act = window.actions_by_name[name]
        assert not act.isEnabled() and "set-trajectory" in act.toolTip(), name
    assert not window.panel.isEnabled() and not window.reviews.isEnabled()
    assert "set-trajectory" in window.events_only_banner.text()
    assert not window.timeline.scores_check.isEnabled()
    # what still works: stepping, representations
    assert window.actions_by_name["step_forward"].isEnabled() and window.actions_by_name["rep_counts"].isEnabled()
    dlg = ExportDialog(window, s.scene, window.settings)
    assert [dlg.fmt.itemData(i) for i in range(dlg.fmt.count())] == ["h5"]
    dlg.deleteLater()


def test_the_gui_start_skips_the_raster_warm_up_for_an_event_only_scene(eo_scene, tiny_scene_dir, tmp_path):
    from evpose.app.main import _needs_raster

    assert _needs_raster(str(eo_scene)) is False
    assert _needs_raster(str(tiny_scene_dir)) is True
    assert _needs_raster(None) is True and _needs_raster(str(tmp_path / "missing")) is True
