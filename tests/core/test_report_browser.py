"""The triage report's HTML (evpose.core.dataset.report_html): self-contained, escaped, and what a real
browser renders. Headless Chromium (Debian's ``chromium``; skipped when absent) prints the DOM and a
screenshot of a report built from a real scene's triage document and variants with injected problems.

``python tests/core/test_report_browser.py docs/dataset_report.png`` rebuilds the README's screenshot from
a realistic dataset (three synthetic scenes of 1.5 s run through ``triage_task``, one broken scene).
"""
from __future__ import annotations

import copy
import json
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest

from evpose.core.dataset.report_html import render_report, write_report
from evpose.core.dataset.triage import triage

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_triage_report import batch, degrade, run_triage_task, shift_prior, true_labels_scene

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
WEIRD = '<b>&"quoted" \'scene\''


def chromium(args: list, profile: Path, timeout_s: float = 90.0) -> subprocess.CompletedProcess:
    """Headless Chromium with no network traffic of its own and a private profile."""
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--hide-scrollbars", f"--user-data-dir={profile}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)


def screenshot(html: Path, png: Path, profile: Path, size=(1280, 2000)) -> None:
    res = chromium([f"--screenshot={png}", f"--window-size={size[0]},{size[1]}", html.resolve().as_uri()], profile)
    if not png.is_file():
        raise RuntimeError(f"chromium wrote no screenshot: {res.stderr[-2000:]}")


class DomSummary(HTMLParser):
    """What the tests read from a DOM: the ranked list's items, the scene sections (id, heading text), every
    src/href, the tags used."""

    def __init__(self):
        super().__init__()
        self.ranked, self.sections, self.refs, self.tags, self.n_svg = [], [], [], set(), 0
        self._stack, self._li, self._h2 = [], None, None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags.add(tag)
        self.n_svg += tag == "svg"
        self.refs += [(tag, k, v) for k, v in attrs if k in ("src", "href", "xlink:href", "action", "poster")]
        if tag == "ol" and "ranked" in (a.get("class") or "").split():
            self._stack.append("ranked")
        elif tag == "li" and self._stack and self._stack[-1] == "ranked":
            self._li = []
        elif tag == "section" and "scene" in (a.get("class") or "").split():
            self.sections.append([a.get("id"), ""])
        elif tag == "h2" and self.sections and self.sections[-1][1] == "":
            self._h2 = []
        if tag == "ol" and "ranked" not in (a.get("class") or "").split():
            self._stack.append("other")

    def handle_endtag(self, tag):
        if tag == "ol" and self._stack:
            self._stack.pop()
        elif tag == "li" and self._li is not None:
            self.ranked.append(" ".join(" ".join(self._li).split()))
            self._li = None
        elif tag == "h2" and self._h2 is not None:
            self.sections[-1][1] = " ".join(" ".join(self._h2).split())
            self._h2 = None

    def handle_data(self, data):
        for buf in (self._li, self._h2):
            if buf is not None:
                buf.append(data)


def report_doc(clean: dict) -> dict:
    """A report document with a clean scene, a shifted clock, a degraded object, a failed scene and a
    scene whose name is markup."""
    b = batch({"seq_clean": clean, "seq_clock": shift_prior(clean, 30_000),    # ~6 sigma of the rate (issue 23.2)
               "seq_object": degrade(clean, "cylinder", 0.3, worst=33), WEIRD: copy.deepcopy(clean)},
              failed={"seq_broken": "seq_broken/events.h5: not an HDF5 file (<truncated>)"})
    return triage(b, order=["seq_clean", "seq_clock", "seq_object", "seq_broken", WEIRD])


@pytest.fixture(scope="module")
def doc(tiny_scene_dir, tmp_path_factory):
    clean = run_triage_task(true_labels_scene(tiny_scene_dir, tmp_path_factory.mktemp("report") / "clean"))
    return report_doc(shift_prior(clean, clean["sync"]["offset_us"] - clean["info"]["clock"]["prior_offset_us"]))


def _check_thumbnail(uri: str, doc: dict) -> None:
    """A thumbnail is the scene's event frame with a label contour in an object's colour on it."""
    import base64

    import cv2
    import numpy as np

    from evpose.core.label.overlay import PALETTE

    img = cv2.imdecode(np.frombuffer(base64.b64decode(uri.split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
    rec = next(r for r in doc["scenes"] if r.get("thumbnails"))
    assert img.shape == (130, 173, 3)                                    # the scene's camera, half DAVIS346
    colours = {tuple(c) for c in img.reshape(-1, 3)}
    assert colours & set(PALETTE), rec["name"]                             # a contour
    assert colours & {(255, 0, 0), (0, 0, 255), (255, 0, 255)}, rec["name"]   # events


def test_report_is_self_contained_and_escaped(doc, tmp_path):
    out = write_report(doc, tmp_path / "report.html")
    assert out == tmp_path / "report.html" and sorted(p.name for p in tmp_path.iterdir()) == ["report.html"]
    text = out.read_text("utf-8")
    assert text == render_report(doc)
    assert "http://" not in text and "https://" not in text and "url(" not in text and "@import" not in text
    assert "<b>&" not in text and "&lt;b&gt;&amp;&quot;quoted&quot;" in text
    assert "(&lt;truncated&gt;)" in text
    dom = DomSummary()
    dom.feed(text)
    assert not ({"link", "iframe", "object", "embed"} & dom.tags)
    images = [v for tag, k, v in dom.refs if tag == "img"]
    assert all(v.startswith("#") for tag, _, v in dom.refs if tag != "img")
    assert images and all(v.startswith("data:image/png;base64,") for v in images)     # inline, nothing fetched
    _check_thumbnail(images[0], doc)
    assert len(dom.ranked) == len(doc["ranked"]) == 3
    assert [s[1].rsplit(" ", 2)[0] if not s[1].endswith("failed") else s[1].rsplit(" ", 1)[0]
            for s in dom.sections] == [r["name"] for r in doc["scenes"]]


def test_box_plot_axis_holds_every_score(doc):
    d = copy.deepcopy(doc)
    for r in d["scenes"]:
        for s in r["scores"].values():
            s["quantiles"].update(min=max(s["quantiles"]["min"], -0.2), max=min(s["quantiles"]["max"], 0.6))
    html = render_report(d)                                 # scores within the histogram's range: axis -0.2 to 0.6
    assert ">0.6</text>" in html and ">0.7</text>" not in html and ">-0.3</text>" not in html
    q = d["scenes"][0]["scores"]["box"]["quantiles"]
    q["max"], q["min"] = 0.87, -0.55
    html = render_report(d)
    assert ">0.8</text>" in html and ">1</text>" in html and ">-0.6</text>" in html
    assert html.count(">0.8</text>") == 1                  # only that scene's box plot reaches it


def test_report_rewrite_replaces_the_file(doc, tmp_path):
    path = tmp_path / "r.html"
    path.write_text("old")
    write_report(doc, path)
    assert path.read_text("utf-8").startswith("<!DOCTYPE html>")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.html"]


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed")
def test_the_scene_table_filters_in_chromium(doc, tmp_path):
    """The overview table's filter (plain JS, no network): a word of a flag's text or a scene name, and "flagged
    only"; a link can carry both (report.html#filter=clock&flagged)."""
    import re

    html = write_report(doc, tmp_path / "report.html")

    def shown(fragment: str) -> list:
        res = chromium(["--dump-dom", html.as_uri() + fragment], tmp_path / "profile")
        assert res.returncode == 0, res.stderr[-2000:]
        body = res.stdout.split('class="scenes sortable filterable"', 1)[1].split("<tbody>", 1)[1].split("</tbody>")[0]
        rows = re.findall(r"<tr([^>]*)>.*?<a href=\"#[^\"]+\">(.*?)</a>", body, flags=re.S)
        return [name for attrs, name in rows if " hidden" not in attrs]

    names = [r["name"] for r in doc["scenes"]]
    assert len(shown("")) == len(names)
    with_clock = [r["name"] for r in doc["scenes"] if any("clock" in f["kind"] + f["reason"] for f in r["flags"])]
    assert shown("#filter=clock") == with_clock and "seq_clock" in with_clock
    flagged = [r["name"] for r in doc["scenes"] if r["flags"]]
    assert len(shown("#filter=&flagged")) == len(flagged) < len(names)
    assert shown("#filter=seq_object") == ["seq_object"]
    # each next command became a copy button (the script ran in the browser)
    dom = chromium(["--dump-dom", html.as_uri()], tmp_path / "profile").stdout
    nexts = re.findall(r'<code class="next"([^>]*)>(.*?)</code>', dom)
    assert nexts and all(f'title="click to copy: {text}"' in attrs and 'role="button"' in attrs
                         for attrs, text in nexts), nexts


def test_report_renders_in_chromium(doc, tmp_path):
    html = write_report(doc, tmp_path / "report.html")
    res = chromium(["--dump-dom", html.as_uri()], tmp_path / "profile")
    assert res.returncode == 0, res.stderr[-2000:]
    dom = DomSummary()
    dom.feed(res.stdout)
    # the ranked list, in rank order, each with its scene and reason
    assert len(dom.ranked) == len(doc["ranked"]) == 3
    for text, e in zip(dom.ranked, doc["ranked"]):
        assert text.startswith(f"{e['severity']:.1f} {e['scene']}") and text.endswith(e["reason"])
    assert [e["scene"] for e in doc["ranked"]] == ["seq_broken", "seq_clock", "seq_object"]
    # every scene has its section, the markup-named one as text
    ids = {r["name"]: f"scene-{k}" for k, r in enumerate(doc["scenes"])}
    assert [s[0] for s in dom.sections] == list(ids.values())
    for (sid, heading), rec in zip(dom.sections, doc["scenes"]):
        assert heading.startswith(rec["name"] + " "), heading
    assert dom.sections[-1][1].startswith(WEIRD)
    # the plots: clock and unlabeled share, then per scene that ran one box plot and a histogram per object
    ok = [r for r in doc["scenes"] if r["status"] == "ok"]
    assert dom.n_svg == 2 + sum(1 + len(r["objects"]) for r in ok) == 2 + 4 * 4
    assert '<ul class="facts" id="summary"><li>5 scenes</li><li class="bad">1 failed</li><li>3 flagged</li>' in res.stdout
    # nothing external is referenced: links are in-page anchors to sections that exist
    assert not [r for r in dom.refs if "http:" in r[2] or "https:" in r[2] or r[2].startswith("//")]
    assert {v for _, k, v in dom.refs if k == "href"} <= {f"#{i}" for i in ids.values()}
    # the screenshot: the page was drawn (not blank), at the window's size
    from PIL import Image

    png = tmp_path / "report.png"
    screenshot(html, png, tmp_path / "profile")
    img = Image.open(png).convert("RGB")
    assert img.size == (1280, 2000)
    colors = img.getcolors(maxcolors=1 << 20)
    assert len(colors) > 50
    assert any(c[1] == (0x7F, 0x1D, 0x1D) for c in colors)        # the failed scene's severity badge


# ------------------------------------------------------------------------------- the README's screenshot
def build_demo_dataset(root: Path) -> dict:
    """Three synthetic scenes of 1.5 s and a broken one, each run through triage_task as the dataset
    report does: a clean scene with part of it verified, one whose prior is 20 ms off, one with a 250 ms
    trajectory hole and a bad correction of one object; the fourth's event file is truncated."""
    import numpy as np
    from evpose_testing import TINY_SCENE, half_davis_camera
    from test_triage_report import cut_trajectory

    from evpose.core.data.scene import Scene
    from evpose.core.dataset.batch import failure_text
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    base = dict(TINY_SCENE, duration_s=1.5, pose_error_mm=0.0, pose_error_deg=0.0, offset_us=0)
    specs = {"seq_001": dict(seed=11, trajectory="A"), "seq_002": dict(seed=12, offset_us=20_000),
             "seq_003": dict(seed=13, trajectory="A")}
    for name, spec in specs.items():
        generate(root / name, SynthConfig(**dict(base, **spec), camera=half_davis_camera()))
    scene = Scene.open(root / "seq_001")
    t0 = scene.events.t_first_us
    scene.close()
    marks = [{"t0_us": t0, "t1_us": t0 + 900_000, "status": "verified"},
             {"t0_us": t0 + 900_000, "t1_us": t0 + 1_000_000, "status": "rejected", "object": "box"}]
    (root / "seq_001" / "corrections.json").write_text(json.dumps(
        {"format": "evpose-corrections/1", "revision": 1, "reviews": marks}))
    cut_trajectory(root / "seq_003", (600.0, 850.0), 1e9)
    dT = np.eye(4)
    dT[:3, 3] = [0.012, -0.006, 0.0]
    (root / "seq_003" / "corrections.json").write_text(json.dumps(
        {"format": "evpose-corrections/1", "revision": 1, "objects": {"cylinder": {"dT_base": dT.tolist()}}}))
    shutil.copytree(root / "seq_001", root / "seq_004")
    ev = root / "seq_004" / "events.h5"
    ev.write_bytes(ev.read_bytes()[:4096])
    scenes, failed = {}, {}
    for name in sorted(p.name for p in root.iterdir()):
        try:
            scenes[name] = run_triage_task(root / name)
        except Exception as exc:            # as map_scenes reports a failed scene
            failed[name] = failure_text(exc)
    return {"dataset": "demo", "scenes": scenes, "failed": failed, "runtime_s": 41.7}


def main(argv) -> None:
    import tempfile

    out = Path(argv[0]) if argv else Path("docs/dataset_report.png")
    with tempfile.TemporaryDirectory(prefix="evpose-report-") as tmp:
        tmp = Path(tmp)
        b = build_demo_dataset(tmp / "demo")
        t = triage(b, order=sorted([*b["scenes"], *b["failed"]]))
        html = write_report(t, tmp / "report.html")
        screenshot(html, tmp / "shot.png", tmp / "profile", size=(1280, 2000))
        shutil.copyfile(tmp / "shot.png", out)
        (out.with_suffix(".json")).write_text(json.dumps(t, indent=1, ensure_ascii=False)) if "--json" in argv else None
    print(out)


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    main(sys.argv[1:])


def test_a_thumbnail_that_cannot_be_drawn_is_named_not_fatal(doc):
    """A scene whose worst window cannot be drawn keeps its triage; the report says which picture is missing and
    why."""
    bad = copy.deepcopy(doc)
    rec = next(r for r in bad["scenes"] if r.get("thumbnails"))
    name = next(iter(rec["thumbnails"]))
    rec["thumbnails"][name] = {"window": 3, "t_label_us": rec["t0_us"], "error": "ValueError: <no poses>"}
    html = render_report(bad)
    assert f"{name}: no picture of window 3 (ValueError: &lt;no poses&gt;)" in html
