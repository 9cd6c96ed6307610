"""Issue 24 ("Must show"): on a test dataset of five scenes with the same events -- right labels, the clock 20 ms
off, one object 5 mm / 3 deg off, the camera mounting (hand-eye) 2 mm / 0.5 deg off, a broken events file --
``dataset report --edges`` ranks every wrong scene above the right one with the right cause (the right scene has no
flag), and after ``dataset refine --apply`` the flags of the fixed scenes are gone while the right scene's files
are unchanged byte for byte."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from evpose_testing import build_triage_dataset

pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def triage_dataset(tmp_path_factory) -> Path:
    """Five scenes from one generated recording (3 objects, 2.5 s at 0.5 m/s, half resolution; its labels right)."""
    base = tmp_path_factory.mktemp("triage") / "base"
    root = base.parent / "ds"
    build_triage_dataset(base, root)
    return root


def _evpose(*args, timeout=1200):
    r = subprocess.run([sys.executable, "-m", "evpose", *map(str, args)], capture_output=True, text=True,
                       timeout=timeout)
    return r


def _report(root: Path, out: Path) -> dict:
    r = _evpose("dataset", "report", root, "--edges", "--windows", "16", "--out", out, "--workers", "2", "--json",
                "-q")
    assert r.returncode == 3, r.stderr                               # the broken scene: a partial run
    return json.loads(r.stdout)


def _files(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_the_report_ranks_wrong_scenes_by_cause_and_refine_apply_clears_them(triage_dataset, tmp_path):
    root = triage_dataset
    right_before = _files(root / "a_right")
    doc = _report(root, tmp_path / "report.html")
    assert doc["since_last"] is None
    rows = (tmp_path / "report.csv").read_text().splitlines()
    assert rows[0] == "rank,scene,severity,cause,reasons,next" and len(rows) == 1 + len(doc["scenes_ranked"])
    assert rows[1].startswith("1,e_broken,100.000,failed,")
    ranked = {e["scene"]: e for e in doc["scenes_ranked"]}
    print(json.dumps(doc["scenes_ranked"], indent=1))
    assert "a_right" not in ranked and not doc["scenes"]["a_right"]["flags"]
    assert set(ranked) == {"b_clock", "c_pose", "d_mounting", "e_broken"}
    assert ranked["e_broken"]["rank"] == 1 and ranked["e_broken"]["cause"] == "failed"
    assert ranked["e_broken"]["next"] == f"evpose info {root / 'e_broken'}"
    assert ranked["b_clock"]["cause"] == "clock" and "sync" in ranked["b_clock"]["next"]
    # the edges confirm the rate's clock with their own precision (not the rate's 4.75 ms)
    assert doc["scenes"]["b_clock"]["clock"]["offset_std_us"] < 1000 and ranked["b_clock"]["severity"] >= 20
    assert ranked["c_pose"]["cause"] == "pose" and "box" in doc["scenes"]["c_pose"]["verdicts"]
    assert set(doc["scenes"]["c_pose"]["verdicts"]) == {"box"}          # the right objects get no verdict
    assert "refine" in ranked["c_pose"]["next"] and "--joint" in ranked["c_pose"]["next"]
    assert ranked["d_mounting"]["cause"] == "mounting" and "--hand-eye" in ranked["d_mounting"]["next"]
    # a low score explained by the pose verdict is not a second flag of the same object
    assert sum(1 for f in doc["scenes"]["c_pose"]["flags"] if f["object"] == "box") == 1

    # only what the report flags for a cause refine deals with: not the broken scene, not the right one
    r = _evpose("dataset", "refine", root, "--apply", "--only-flagged", tmp_path / "report.json", "--windows", "16",
                "--workers", "2", "--json", "-q")
    assert r.returncode == 0, r.stderr
    refined = json.loads(r.stdout)["scenes"]
    assert set(refined) == {"b_clock", "c_pose", "d_mounting"}
    # the mounting scene: the hand-eye is stored, not a clock and object poses bent to absorb it
    values = [c["part"] for c in refined["d_mounting"]["changes"] if c["part"] != "sigma"]   # + confirmed parts' sigma
    assert values == ["hand-eye"], refined["d_mounting"]["changes"]
    assert all(c["part"] != "hand-eye" for n in ("b_clock", "c_pose") for c in refined[n]["changes"])
    after = _report(root, tmp_path / "report.html")                # the same --out: compared with the last one
    left = {e["scene"] for e in after["scenes_ranked"]}
    assert {"b_clock", "c_pose", "d_mounting"} <= set(after["since_last"]["resolved"])
    assert after["since_last"]["new"] == []
    assert json.loads((tmp_path / "report.json").read_text())["since_last"] == after["since_last"]
    assert not left & {"b_clock", "c_pose", "d_mounting"}, after["scenes_ranked"]
    assert "e_broken" in left and "a_right" not in left
    assert _files(root / "a_right") == right_before                  # nothing written into the right scene
