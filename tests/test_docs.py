"""The README is part of the product: its commands and shortcut table must match the code."""
import re
from pathlib import Path

from evpose.app.actions import SHORTCUTS

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text()


def test_first_screen_gives_the_two_commands_and_ci_runs_the_test_one():
    first_screen = "\n".join(README.splitlines()[:20])
    assert "./run demo" in first_screen and "./run test" in first_screen
    ci = (REPO / ".ci" / "run").read_text()
    readme_test = [ln for ln in first_screen.splitlines() if re.match(r"^\./run test\b", ln)]
    assert len(readme_test) == 1, "the first screen gives one test command line"
    # CI runs the README's line verbatim (the command and its comment), as its own line
    assert readme_test[0] in ci.splitlines(), "CI must call the README's test command"
    assert re.search(r"^\./run test(\s|$)", ci, re.M)


def test_every_shortcut_is_documented():
    table = README[README.index("### Keyboard shortcuts"):README.index("## Conventions")]
    for sc in SHORTCUTS:
        for key in sc.keys:
            assert f"`{key}`" in table, f"shortcut {key} ({sc.name}) missing from the README table"


def test_screenshot_exists():
    shots = re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", README)
    assert shots
    for s in shots:
        assert (REPO / s).is_file(), s
