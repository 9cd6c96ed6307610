"""The residual view in the app (issue 25.2): closed until asked for, computed on a worker when shown and on every
time step while in sight, not at all while closed; the table has a row per shown object."""
from __future__ import annotations


def test_the_residual_dock_shows_the_window_and_follows_the_time(qtbot, window, scene_copy):
    session = window.controller.open_scene(scene_copy)
    feed = window.residual_feed
    assert feed.dock is not None and feed.dock.isHidden() and feed.view.data is None
    submitted = []
    original = feed.feed.worker.submit
    feed.feed.worker.submit = lambda req: (submitted.append(req), original(req))
    ev = session.scene.events
    session.set_time((ev.t_first_us + ev.t_last_us) // 2)
    qtbot.wait(200)
    assert submitted == []                                   # out of sight: nothing computed
    window.panel.residuals_button.click()
    qtbot.waitUntil(lambda: feed.view.data is not None, timeout=60_000)
    data = feed.view.data
    assert data.t0_us == session.view.window().t0_us and not data.reason
    rows = feed.view.row_texts()
    assert [r[0] for r in rows] == session.object_names and all(int(r[1]) > 0 for r in rows)
    assert feed.view.image_array().shape == (session.scene.camera.height, session.scene.camera.width, 3)
    sweep = feed.view.sweep.data                             # the first shown object swept (none selected)
    assert sweep is not None and sweep.name == session.object_names[0] and not sweep.reason
    assert sweep.top.sum() > 0 and feed.view.sweep.images[0].image is not None
    session.step_windows(1)                                  # in sight: the next window is computed
    qtbot.waitUntil(lambda: feed.view.data is not data and feed.view.data.t0_us != data.t0_us, timeout=60_000)
    shown = feed.view.data
    session.set_object_visible("cylinder", False)            # a hidden object leaves the table
    qtbot.waitUntil(lambda: feed.view.data is not shown, timeout=60_000)
    assert [r[0] for r in feed.view.row_texts()] == [n for n in session.object_names if n != "cylinder"]
    session.select("flatbox")                                # the selected object is swept
    qtbot.waitUntil(lambda: feed.view.sweep.data is not None and feed.view.sweep.data.name == "flatbox",
                    timeout=60_000)
