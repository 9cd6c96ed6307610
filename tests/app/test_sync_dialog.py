"""The sync proposal shows the estimate with its standard error, and says when it is loose."""
import math

import numpy as np
import pytest

from core.sync import SLOW_STD_NOTE_US, SyncResult


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

    from app.align import SyncDialog

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
    from app.align import SyncDialog

    dlg = SyncDialog(None, _result(None, reliable=False), 0, 0.0)
    qtbot.addWidget(dlg)
    assert "No reliable estimate" in dlg.verdict.text() and not dlg.accept_button.isEnabled()
