"""The README is part of the product: its commands and shortcut table must match the code."""
import ast
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
    assert re.search(r"^\./run test(\s|$)", ci, re.MULTILINE)


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


# ------------------------------------------------------------------ repository paths in the docs
#: First path components that make a backticked span a repository path (other spans with a slash, such
#: as ``OUT/.evpose/journal.jsonl``, are paths of a user's folders); root files are named in full.
TOP_FOLDERS = ("core", "app", "widgets", "resources", "tests", "bench", "docs")
ROOT_FILES = ("setup.py", "pyproject.toml", "README.md")
SPAN = re.compile(r"`([^`\s]+)`")
BARE = re.compile(r"\w+(\.py|/)(::[\w.]+)?")


def is_repo_path(span: str) -> bool:
    path = span.split("::")[0]
    return ("/" in path and path.split("/")[0] in TOP_FOLDERS) or path in ROOT_FILES


def repo_references(text: str) -> list[tuple[int, str]]:
    """``(line, reference)`` of every repository path in backticks: ``core/align/estimate.py``,
    ``app/cli/``, ``path::Name.attr`` (a name defined in that module). In a table row whose first
    cell is a folder (``| `core/data/` | ...``) a bare ``scene.py`` or ``data/`` in the other cells
    is relative to that folder."""
    refs = []
    for n, line in enumerate(text.splitlines(), 1):
        base = None
        if line.startswith("|"):
            first = SPAN.findall(line.split("|")[1])
            if first and is_repo_path(first[0]) and first[0].endswith("/"):
                base = first[0]
        for k, span in enumerate(SPAN.findall(line)):
            if base and k > 0 and BARE.fullmatch(span):
                refs.append((n, base + span))
            elif is_repo_path(span):
                refs.append((n, span))
    return refs


def defined_in(path: Path, qualname: str) -> bool:
    """Whether ``qualname`` (``f``, ``Class.method``) is defined (or imported) at module level of ``path``."""
    scope = ast.parse(path.read_text()).body
    for part in qualname.split("."):
        found = None
        for node in scope:
            names = []
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names = [node.name]
            elif isinstance(node, (ast.Assign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names = [t.id for t in targets if isinstance(t, ast.Name)]
            elif isinstance(node, ast.ImportFrom):
                names = [a.asname or a.name for a in node.names]
            if part in names:
                found = node
        if found is None:
            return False
        scope = found.body if isinstance(found, ast.ClassDef) else []
    return True


def stale(reference: str) -> str | None:
    """Why a reference does not match the tree (None when it does)."""
    path, _, qualname = reference.partition("::")
    target = REPO / path
    if not target.exists() or (path.endswith("/") and not target.is_dir()):
        return f"{path} does not exist"
    if qualname:
        module = target / "__init__.py" if target.is_dir() else target
        if module.suffix != ".py" or not module.is_file() or not defined_in(module, qualname):
            return f"{qualname} is not defined in {path}"
    return None


def layout_section() -> str:
    start = README.index("## Layout\n")
    return README[start:README.index("\n## ", start + 1)]


def test_architecture_and_layout_paths_exist():
    """Every repository path named in docs/ARCHITECTURE.md and in the README's layout section exists (and
    every ``path::Name`` is defined there), so neither can silently describe a tree that is gone."""
    docs = {"docs/ARCHITECTURE.md": (REPO / "docs" / "ARCHITECTURE.md").read_text(),
            "README.md (## Layout)": layout_section()}
    problems = []
    for name, text in docs.items():
        refs = repo_references(text)
        assert len(refs) >= (60 if name.startswith("docs") else 15), f"{name}: only {len(refs)} paths found"
        problems += [f"{name}:{n}: `{ref}`: {why}" for n, ref in refs if (why := stale(ref))]
    assert not problems, "\n".join(problems)


def test_the_path_check_catches_stale_references():
    """The check itself: relative names in a folder's table row, missing files, undefined names."""
    row = "| `core/data/` | x | `scene.py`, `atomic.py::write_atomic`, `gone.py`, `core/label/`, `Scene` |"
    assert [r for _, r in repo_references(row)] == [
        "core/data/", "core/data/scene.py", "core/data/atomic.py::write_atomic", "core/data/gone.py", "core/label/"]
    assert [r for _, r in repo_references("`OUT/.evpose/x`, `scene.toml`, `setup.py`, `app/cli/`")] == [
        "setup.py", "app/cli/"]
    assert stale("core/data/scene.py::Scene.T_cam_obj") is None
    assert stale("core/export/::export_scene") is None
    assert stale("core/data/gone.py") == "core/data/gone.py does not exist"
    assert stale("core/data/scene.py/") is not None
    assert stale("core/data/scene.py::Scene.gone") == "Scene.gone is not defined in core/data/scene.py"
    assert stale("core/data/scene.py::gone") is not None
