"""The proposal panel (app/auto_panel.py) shows the clock with its standard error, says when the event rate alone
pins it loosely, lists each object's change with its 1 sigma and the objects held with their reasons, and offers
Accept and the preview only for a usable proposal."""
import math

import numpy as np
import pytest

from evpose.core.align.sync_result import SLOW_STD_NOTE_US, SyncResult


def _rate(std, reliable=True):
    lags = np.linspace(-0.2e6, 0.2e6, 41)
    return SyncResult(None if not reliable else -58_000, None, 0.8 if reliable else 0.0, reliable,
                      "" if reliable else "static camera", lags, np.exp(-((lags + 58_000) / 50_000) ** 2),
                      offset_std_us=std)


def _joint(accepted=True, skew_estimated=False, held=None):
    from evpose.core.align.joint_result import JointParams, JointResult, ObjectFit

    j = JointResult(params=JointParams(), offset_us=-57_640, skew_ppm=12.5 if skew_estimated else 0.0,
                    offset_std_us=85.0, skew_std_ppm=4.0 if skew_estimated else 40.0, skew_estimated=skew_estimated,
                    objective_before=0.031, objective_after=0.034, n_windows=24, runtime_s=6.2, accepted=accepted,
                    reason="" if accepted else "the fit did not improve the objective; start kept")
    if accepted:
        j.objects["box"] = ObjectFit(np.eye(4), 4.96, 3.01, 0.02, 0.01)
    j.held.update(held or {})
    return j


def _auto(rate, joint=None):
    """An Auto proposal as :func:`evpose.app.auto_sync.run_auto` builds it (final clock from sync_run)."""
    from evpose.app.auto_sync import Proposal
    from evpose.core.align.sync_run import final_estimate

    p = Proposal("auto", "Automatic estimate", "auto", (0, 0.0), rate=rate, joint=joint, runtime_s=7.0)
    if not rate.reliable:
        p.reason = f"no reliable clock from the event rate: {rate.reason}; edges not run"
        return p
    f = final_estimate(rate, joint)
    p.offset_us, p.skew_ppm, p.method = f["offset_us"], f["skew_ppm"], f["method"]
    p.offset_std_us, p.skew_std_ppm = f["offset_std_us"], f["skew_std_ppm"]
    if joint is not None and not joint.accepted:
        p.reason = f"edges: {joint.reason}; the event-rate clock is proposed alone"
    return p


@pytest.fixture
def panel(qtbot):
    from evpose.app.auto_panel import ProposalPanel

    w = ProposalPanel()
    qtbot.addWidget(w)
    return w


@pytest.mark.parametrize("std, loose", [(150.0, False), (4200.0, True), (math.inf, True), (None, True)])
def test_rate_only_clock_with_its_standard_error(panel, std, loose):
    """Edges not accepted: the event-rate clock alone, with its 1 sigma; loose timing is said."""
    panel.show_proposal(_auto(_rate(std), _joint(accepted=False)), preview_after=True)
    text = panel.offset_label.text()
    assert text.startswith("+0.000 ms → -58.000 ms")
    if std is not None and math.isfinite(std):
        assert f"± {std / 1000:.3f} ms (1σ)" in text
    verdict = panel.verdict.text()
    assert "Event-rate clock only" in verdict and "did not improve" in verdict
    assert ("loosely" in verdict) == loose == (std is None or not std <= SLOW_STD_NOTE_US)
    assert panel.accept_button.isEnabled() and panel.preview_after()
    assert not panel.table.isVisible() or panel.table.rowCount() == 0


def test_unreliable_rate_cannot_be_accepted(panel):
    panel.show_proposal(_auto(_rate(None, reliable=False)), preview_after=True)
    assert "Nothing to apply" in panel.verdict.text() and "static camera" in panel.verdict.text()
    assert not panel.accept_button.isEnabled()
    assert not panel.after_button.isEnabled() and panel.before_button.isChecked()
    assert "kept" in panel.offset_label.text()


@pytest.mark.parametrize("skew_estimated", [True, False])
def test_joint_proposal_lists_clock_objects_and_held(panel, skew_estimated):
    held = {"flatbox": "too little evidence: 2 of 24 windows hold 30+ events near its edges; pose kept"}
    panel.show_proposal(_auto(_rate(150.0), _joint(skew_estimated=skew_estimated, held=held)), preview_after=True)
    assert "-57.640 ms  ± 0.085 ms (1σ)" in panel.offset_label.text()
    skew = panel.skew_label.text()
    if skew_estimated:
        assert "→ +12.5 ppm ± 4.0 ppm (1σ)" in skew
    else:
        assert "kept" in skew and "± 40.0 ppm" in skew
    rows = {panel.table.item(r, 0).text(): [panel.table.item(r, c).text() for c in range(1, 4)]
            for r in range(panel.table.rowCount())}
    assert rows["box"] == ["4.96 mm", "3.01°", "± 0.02 mm, ± 0.01°"]
    assert rows["flatbox"][0] == "kept" and "flatbox" in panel.held_label.text()
    assert "too little evidence" in panel.held_label.text()
    assert "Clock and poses fitted together" in panel.verdict.text()
    assert "objective 0.0310 → 0.0340" in panel.details.text()


def test_preview_toggle_and_buttons_emit(panel, qtbot):
    panel.show_proposal(_auto(_rate(150.0), _joint()), preview_after=False)
    assert panel.before_button.isChecked()
    with qtbot.waitSignal(panel.previewChanged) as sig:
        panel.after_button.click()
    assert sig.args == [True]
    with qtbot.waitSignal(panel.acceptRequested):
        panel.accept_button.click()
    with qtbot.waitSignal(panel.rejectRequested):
        panel.reject_button.click()
    panel.show_running("Automatic estimate")
    panel.set_progress(0.42, "edges, kernel width 3 of 6")
    assert panel.bar.value() == 420 and "kernel width 3" in panel.message.text()
    with qtbot.waitSignal(panel.cancelRequested):
        panel.cancel_button.click()
    assert not panel.cancel_button.isEnabled() and "cancelling" in panel.message.text()


def test_staged_progress_is_monotonic_and_spans_both_stages():
    from evpose.app.auto_sync import EDGE_SETUP_SHARE, RATE_SHARE, StagedProgress

    seen = []
    bar = StagedProgress(lambda f, m: seen.append((f, m)), n_levels=6, iterations_per_level=4)
    bar.rate(0.3, "coarse correlation")
    bar.rate(1.0, "done")
    bar.edge_setup()
    for level in range(6):
        bar.edges(level / 7, f"sigma {level}")
        for _ in range(5):
            bar.edges(None, "objective")
    bar.edges(1.0, "done")
    f = [x for x, _ in seen]
    assert f == sorted(f) and f[1] == pytest.approx(RATE_SHARE) and f[-1] == 1.0
    assert f[2] == pytest.approx(RATE_SHARE) and f[3] == pytest.approx(RATE_SHARE + EDGE_SETUP_SHARE)
    assert seen[0][1].startswith("event rate") and "kernel width 6 of 6" in seen[-2][1]
