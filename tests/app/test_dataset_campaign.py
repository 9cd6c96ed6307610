"""Issue 28.3: the dataset view shows the campaign fit recorded in ``campaign_fit.json`` (``evpose dataset refine
--joint --shared hand-eye,placement --apply``), per group: each shared term's change ± 1 sigma, what the group's
scenes stored, the fit's notes; a hint when there is no record and one line naming the file (and the field) when it
cannot be shown -- never a traceback. The lines are composed by core (:mod:`evpose.core.dataset.campaign_view`,
tested here without Qt) and read again with the rows and when the dataset's folder changes."""
from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

from evpose.core.dataset.campaign_view import CAMPAIGN_HINT, campaign_lines, read_record, record_lines

GROUPS = """
[[groups]]
name = "day1"
shared = ["hand-eye", "placement"]
scenes = ["a", "b"]
"""
CYLINDER_REASON = "the campaign's events do not pin its pose (a direction of it is flat); pose kept"
#: what the record of :func:`_record` shows, line by line
EXPECTED = [
    "Campaign fit of 3 scenes: accepted (7 steps, 41.3 s); change ± 1 sigma",
    "day1 (2 scenes): hand-eye 1.15 mm ± 0.80, 0.268° ± 0.167",
    "day1: box 0.86 mm ± 0.58, 0.28° ± 0.17",
    f"day1: cylinder not fitted: {CYLINDER_REASON}",
    "day1: stored in 1 of 2 scenes (a rev 4); b failed: b/corrections.json: changed on disk since the fit",
    "note: a: box's pose in effect differs from group:day1's start by 3.1 mm",
]


def _write_dataset(root, scene_dir=None):
    """Scenes ``a``, ``b`` (group day1) and ``c`` (its own terms) and a dataset.toml listing them."""
    for name in ("a", "b", "c"):
        if scene_dir is not None:
            shutil.copytree(scene_dir, root / name)
        else:
            (root / name).mkdir(parents=True)
            (root / name / "scene.toml").write_text("")
    (root / "dataset.toml").write_text(f'format = "evpose-dataset/1"\nscenes = ["a", "b", "c"]\n{GROUPS}')
    return root


def _record(root):
    """``campaign_fit.json`` of a small fake campaign fit, written by :func:`record_campaign`."""
    from evpose.core.align.campaign_result import CampaignResult, UnitFit
    from evpose.core.align.joint_result import JointParams
    from evpose.core.dataset.batch import BatchResult
    from evpose.core.dataset.campaign import record_campaign
    from evpose.core.dataset.dataset import Dataset

    ds = Dataset.open(root)
    fit = CampaignResult(JointParams(hand_eye=True, skew="fixed"), ["a", "b", "c"], accepted=True, runtime_s=41.34,
                         notes=["a: box's pose in effect differs from group:day1's start by 3.1 mm"], trace=[{}] * 7)
    fit.hand_eye = {"group:day1": UnitFit(["a", "b"], np.eye(4), 1.153, 0.2681, 0.8012, 0.1672, True),
                    "scene:c": UnitFit(["c"], np.eye(4), 9.0, 9.0, 1.0, 1.0, True)}
    fit.placements = {"group:day1": {"box": UnitFit(["a", "b"], np.eye(4), 0.861, 0.2812, 0.58, 0.171, True),
                                     "cylinder": UnitFit(["a", "b"], np.eye(4), reason=CYLINDER_REASON)},
                      "scene:c": {"box": UnitFit(["c"], np.eye(4), 9.0, 9.0, 1.0, 1.0, True)}}
    batch = BatchResult(ds.name, scenes={"a": {"applied": True, "revision": 4, "changes": [{"part": "hand-eye"}]},
                                         "c": {"applied": False}},
                        failed={"b": "b/corrections.json: changed on disk since the fit"})
    return record_campaign(ds, fit, batch)


# ---------------------------------------------------------------------------------------- core, without Qt
def test_record_lines_per_group_with_sigma(tmp_path):
    root = _write_dataset(tmp_path / "ds")
    assert campaign_lines(root) == ("absent", [CAMPAIGN_HINT])
    path = _record(root)
    state, lines = campaign_lines(root)
    assert (state, lines) == ("ok", EXPECTED)        # scene c's own terms (9 mm) are its row's business, not here
    doc = json.loads(path.read_text())
    # an infinite sigma is null in the record: shown as ∞; a fit not accepted says so first
    doc["fit"]["hand_eye"]["group:day1"]["dR_std_deg"] = None
    doc["fit"].update(accepted=False, reason="the campaign fit did not raise the summed edge objective")
    lines = record_lines(doc, path)
    assert lines[0] == ("Campaign fit of 3 scenes: not accepted: the campaign fit did not raise the summed edge "
                        "objective (every shared term kept its start)")
    assert lines[1] == "day1 (2 scenes): hand-eye 1.15 mm ± 0.80, 0.268° ± ∞"
    # a scene whose share only stored the sigma of values the fit confirmed is not counted as a stored fit
    doc["stored"]["a"]["values"] = False
    assert record_lines(doc, path)[4] == ("day1: stored in 0 of 2 scenes; values confirmed, only their sigma "
                                          "stored: a rev 4; b failed: b/corrections.json: changed on disk since "
                                          "the fit")
    # a kind the group shares in dataset.toml that this fit did not share (--shared placement)
    del doc["fit"]["hand_eye"]["group:day1"]
    assert record_lines(doc, path)[1] == "day1 (2 scenes): hand-eye not shared in this fit (each scene its own)"


def _mutate(doc, where, value):
    *keys, last = where
    for k in keys:
        doc = doc[k]
    if value is KeyError:
        del doc[last]
    else:
        doc[last] = value


@pytest.mark.parametrize("where, value, expected", [
    (("format",), "evpose-campaign-fit/2", "format: expected 'evpose-campaign-fit/1'"),
    (("groups",), KeyError, "groups: expected a list, got nothing"),
    (("groups", 0), "day1", "groups[0]: expected an object"),
    (("groups", 0, "name"), 3, "groups[0].name: expected a string, got 3"),
    (("fit",), [], "fit: expected an object, got []"),
    (("fit", "accepted"), "yes", "fit.accepted: expected true or false"),
    (("fit", "hand_eye", "group:day1", "dt_std_mm"), "0.8", "fit.hand_eye.group:day1.dt_std_mm: expected a number"),
    (("fit", "hand_eye", "group:day1", "dt_mm"), True, "fit.hand_eye.group:day1.dt_mm: expected a number"),
    (("fit", "placements", "group:day1", "box", "fitted"), KeyError,
     "fit.placements.group:day1.box.fitted: expected true or false, got nothing"),
    (("fit", "placements", "group:day1"), [1], "fit.placements.group:day1: expected an object"),
])
def test_a_bad_field_is_one_line_naming_the_file_and_the_field(tmp_path, where, value, expected):
    root = _write_dataset(tmp_path / "ds")
    path = _record(root)
    doc = json.loads(path.read_text())
    _mutate(doc, where, value)
    path.write_text(json.dumps(doc))
    state, lines = campaign_lines(root)
    assert state == "error" and len(lines) == 1 and "\n" not in lines[0], lines
    assert lines[0].startswith(f"{path}: ") and expected in lines[0], lines[0]


def _paths(node, prefix=()):
    """Every field's path in a JSON document."""
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for k, v in items:
        yield prefix + (k,)
        yield from _paths(v, prefix + (k,))


def test_no_field_of_any_shape_is_a_traceback(tmp_path):
    """Every field of the record replaced by a value of every other JSON kind (or removed): an error line or text
    lines, never an exception."""
    path = _record(_write_dataset(tmp_path / "ds"))
    original = json.loads(path.read_text())
    errors = 0
    for where in _paths(original):
        for value in (KeyError, None, True, -1, 2.5, "x", [], [1], {}, {"x": 1}):
            doc = json.loads(json.dumps(original))
            _mutate(doc, where, value)
            try:
                lines = record_lines(doc, path)
            except Exception as exc:                            # noqa: BLE001 -- the one kind allowed: one line
                assert type(exc).__name__ == "CampaignRecordError", (where, value, exc)
                assert str(exc).startswith(f"{path}: ") and "\n" not in str(exc)
                errors += 1
            else:
                assert all(isinstance(line, str) for line in lines)
    assert errors > 50


@pytest.mark.parametrize("kind, expected", [("text", "not JSON"), ("list", "expected a JSON object"),
                                            ("utf8", "cannot read"), ("folder", "is a folder"),
                                            ("fifo", "is a FIFO"), ("dangling", "file not found")])
def test_an_unreadable_record_is_one_line_naming_the_file(tmp_path, kind, expected):
    root = _write_dataset(tmp_path / "ds")
    path = root / "campaign_fit.json"
    {"text": lambda: path.write_text("format = 'evpose-campaign-fit/1'\n"),
     "list": lambda: path.write_text("[1, 2]"),
     "utf8": lambda: path.write_bytes(b'{"format": "\xff"}'),
     "folder": lambda: path.mkdir(),
     "fifo": lambda: os.mkfifo(path),                      # never blocks the window
     "dangling": lambda: path.symlink_to(tmp_path / "nowhere.json")}[kind]()
    state, lines = campaign_lines(root)
    assert state == "error" and len(lines) == 1 and lines[0].startswith(str(path)) and expected in lines[0], lines
    if kind in ("text", "list"):
        with pytest.raises(Exception, match="campaign_fit.json"):
            read_record(root)


# ---------------------------------------------------------------------------------------- the dataset window
@pytest.fixture
def dataset_dir(tiny_scene_dir, tmp_path):
    return _write_dataset(tmp_path / "ds", tiny_scene_dir)


@pytest.fixture
def open_window(qtbot, window):
    from evpose.app.dataset_window import open_dataset

    def open_(root):
        win = open_dataset(window, root)
        assert win is not None

        def before_close(w):            # pytest-qt closes and deletes it before fixtures' teardown code runs
            w.cancel_batch()
            qtbot.waitUntil(lambda: not w.jobs, timeout=60_000)

        qtbot.addWidget(win, before_close_func=before_close)
        qtbot.waitUntil(win.rows_loaded, timeout=60_000)
        return win

    return open_


def test_the_dataset_window_shows_the_groups_fit(qtbot, open_window, dataset_dir):
    _record(dataset_dir)
    win = open_window(dataset_dir)
    panel = win.campaign
    assert panel.state == "ok" and panel.lines() == EXPECTED
    assert panel.isVisible() and panel.text.width() > 300 and panel.text.height() > 60
    assert win.height() <= 768 and win.width() <= 1366              # a laptop screen
    assert str(dataset_dir / "campaign_fit.json") in panel.text.toolTip()
    assert panel.text.isReadOnly()
    assert win.table.values("a")["status"] == "ok"                  # the rows are read as before


def test_absent_then_recorded_then_broken_no_crash(qtbot, open_window, dataset_dir):
    win = open_window(dataset_dir)
    panel = win.campaign
    assert (panel.state, panel.lines()) == ("absent", [CAMPAIGN_HINT])
    # dataset refine --apply records the fit while the window is open: the folder's watcher reads it
    path = _record(dataset_dir)
    qtbot.waitUntil(lambda: panel.state == "ok", timeout=10_000)
    assert panel.lines() == EXPECTED
    # another program's file: one line naming the file and the field, shown on Reload
    path.write_text('{"format": "someone-else/3"}')
    win.reload_action.trigger()
    assert panel.state == "error" and len(panel.lines()) == 1
    assert panel.lines()[0].startswith(f"{path}: format: expected 'evpose-campaign-fit/1'")
    path.write_text("{not json")
    win.reload_action.trigger()
    assert panel.state == "error" and panel.lines()[0].startswith(f"{path}: not JSON")
    qtbot.waitUntil(win.rows_loaded, timeout=60_000)
    path.unlink()
    qtbot.waitUntil(lambda: panel.state == "absent", timeout=10_000)
    assert panel.lines() == [CAMPAIGN_HINT]
    assert win.isVisible()
