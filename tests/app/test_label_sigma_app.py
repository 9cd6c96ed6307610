"""Issue 28.3 in the app: the label sigma of the current window in the pose readout, and a band of +-1 sigma about
the projected contour -- both from the sigmas the applied estimates stored, both gone once a hand edit drops them."""
from __future__ import annotations

import numpy as np

from evpose.core.label.uncertainty import stored_label_sigmas


def _wait(qtbot, window):
    qtbot.waitUntil(window.frame_up_to_date, timeout=30_000)
    return window.frame


def test_the_label_sigma_shows_in_the_readout_and_as_a_band_about_the_contour(qtbot, window, scene_copy):
    s = window.controller.open_scene(scene_copy)
    name = s.scene.object_names[0]
    s.select(name)
    s.set_time(s.time_range[0] + 300_000)
    _wait(qtbot, window)
    band = window.frame_view._items[name]["band"]
    assert window.panel.label_sigma.text().startswith("label σ: none stored")
    assert len(band.xData if band.xData is not None else []) == 0              # nothing stored: no band
    s.apply_pose_estimate(name, s.scene.corrections.object_delta(name), "estimate", std_mm=2.0, std_deg=1.0)
    f = _wait(qtbot, window)
    want = stored_label_sigmas(s.scene, np.array([f.window.t_label_us]), [name])
    ov = next(o for o in f.overlays if o.name == name)
    assert ov.sigma_px == np.float64(want.sigma_px[0, 0]) and ov.sigma_px > 0.5
    assert band.xData is not None and len(band.xData) > 10
    pen = band.opts["pen"]
    assert not pen.isCosmetic() and abs(pen.widthF() - 2 * ov.sigma_px) < 1e-9     # +-1 sigma in image pixels
    text = window.panel.label_sigma.text()
    assert text.startswith(f"label σ here {want.sigma_t_mm[0, 0]:.2f} mm, {want.sigma_R_deg[0, 0]:.3f}°")
    assert "no σ: clock offset, hand-eye" in text                               # what it does not include
    window.panel.nudge_object("translate", 0, +1)                               # a hand edit drops the sigma
    _wait(qtbot, window)
    assert s.scene.corrections.sigmas == {}
    assert window.panel.label_sigma.text().startswith("label σ: none stored")
    assert band.xData is None or len(band.xData) == 0
    window.actions_by_name["undo"].trigger()                                    # and undo brings it back
    _wait(qtbot, window)
    assert window.panel.label_sigma.text() == text and len(band.xData) > 10
