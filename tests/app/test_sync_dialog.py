"""The sync proposal shows the estimate with its standard error, and says when it is loose."""
import math

import numpy as np
import pytest

from evpose.core.align.sync_result import SLOW_STD_NOTE_US, SyncResult


def _result(std, reliable=True):
    lags = np.linspace(-0.2e6, 0.2e6, 41)
    return SyncResult(None if not reliable else -58_000, None, 0.8 if reliable else 0.0, reliable,
                      "" if reliable else "static camera", lags, np.exp(-((lags + 58_000) / 50_000) ** 2),
                      offset_std_us=std)


@pytest.mark.parametrize("std, band, verdict", [
    (150.0, True, "Reliable estimate."),
    (4200.0, True, "only to ±4.2 ms"),
    (math.inf, False, "nothing within its likelihood scan"),
    (None, False, "Reliable estimate."),
])
def test_sync_dialog_standard_error(qtbot, std, band, verdict):
    from PySide6 import QtWidgets

    from evpose.app.align import SyncDialog

    dlg = SyncDialog(None, _result(std), 0, 0.0)
    qtbot.addWidget(dlg)
    assert verdict in dlg.verdict.text()
    assert hasattr(dlg, "std_band") == band
    if band:
        lo, hi = dlg.std_band.getRegion()
        assert (hi - lo) * 1e6 == pytest.approx(2 * std)
    labels = [w.text() for w in dlg.findChildren(QtWidgets.QLabel)]
    estimate = next(t for t in labels if t.startswith("-58.000 ms"))
    if std is not None and math.isfinite(std):
        assert f"± {std / 1000:.3f} ms" in estimate
    assert dlg.accept_button.isEnabled()
    assert (std is not None and not std <= SLOW_STD_NOTE_US) == ("loose timing" in dlg.verdict.text())


def test_unreliable_result_cannot_be_accepted(qtbot):
    from evpose.app.align import SyncDialog

    dlg = SyncDialog(None, _result(None, reliable=False), 0, 0.0)
    qtbot.addWidget(dlg)
    assert "No reliable estimate" in dlg.verdict.text() and not dlg.accept_button.isEnabled()


def test_then_edges_choice(qtbot):
    from evpose.app.align import SyncDialog

    dlg = SyncDialog(None, _result(150.0), 0, 0.0, has_objects=True)
    qtbot.addWidget(dlg)
    assert dlg.then_edges.isEnabled() and dlg.then_edges.isChecked()
    for res, objects in ((_result(150.0), False), (_result(None, reliable=False), True)):
        d = SyncDialog(None, res, 0, 0.0, has_objects=objects)
        qtbot.addWidget(d)
        assert not d.then_edges.isEnabled() and not d.then_edges.isChecked()


def _offset_result(accepted, skew_estimated=False):
    from evpose.core.align.refine_result import RefineResult

    return RefineResult("offset", None, offset_us=-57_640 if accepted else -58_000,
                        offset_std_us=85.0 if accepted else None, skew_ppm=12.5 if accepted else None,
                        skew_std_ppm=4.0 if accepted else None, skew_estimated=skew_estimated,
                        objective_before=0.031, objective_after=0.034, n_windows=24, runtime_s=6.2,
                        accepted=accepted, reason="" if accepted else "no window with camera motion")


@pytest.mark.parametrize("accepted, fitted", [(True, True), (True, False), (False, False)])
def test_clock_refine_dialog(qtbot, accepted, fitted):
    from PySide6 import QtWidgets

    from evpose.app.align import ClockRefineDialog

    dlg = ClockRefineDialog(None, _offset_result(accepted, fitted), -58_000, 0.0)
    qtbot.addWidget(dlg)
    labels = " | ".join(w.text() for w in dlg.findChildren(QtWidgets.QLabel))
    assert dlg.accept_button.isEnabled() == accepted
    if accepted:
        assert "-57.640 ms  ± 0.085 ms (1σ)" in labels and "object poses are right" in dlg.verdict.text()
        assert ("fitted from the windows" in labels) == fitted and ("kept" in labels) == (not fitted)
    else:
        assert "Clock kept" in dlg.verdict.text() and "no window" in dlg.verdict.text()
