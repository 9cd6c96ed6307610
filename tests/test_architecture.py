"""Layering rules of DESIGN section 2, checked on the source (imports anywhere in a module count)."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
GUI_LIBS = {"PySide6", "PyQt5", "PyQt6", "pyqtgraph", "vispy", "qtpy", "shiboken6"}


def imported_roots(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            roots.add(node.module.split(".")[0])
    return roots


def sources(pkg: str):
    return sorted((REPO / pkg).rglob("*.py"))


@pytest.mark.parametrize("path", sources("core"), ids=lambda p: str(p.relative_to(REPO)))
def test_core_imports_no_gui_library(path):
    bad = imported_roots(path) & GUI_LIBS
    assert not bad, f"{path.relative_to(REPO)} imports {bad}: core/ must stay headless"


@pytest.mark.parametrize("path", sources("core"), ids=lambda p: str(p.relative_to(REPO)))
def test_core_does_not_import_app_or_widgets(path):
    bad = imported_roots(path) & {"app", "widgets"}
    # the CLI starts the GUI through a lazy import inside one function; nothing else may
    if path.name == "cli.py":
        bad -= {"app"}
    assert not bad, f"{path.relative_to(REPO)} imports {bad}"


@pytest.mark.parametrize("path", sources("widgets"), ids=lambda p: str(p.relative_to(REPO)))
def test_widgets_do_not_import_app(path):
    assert "app" not in imported_roots(path), f"{path.relative_to(REPO)} imports app/"


def test_importing_core_loads_no_gui_library():
    code = ("import sys, core.scene, core.synth, core.cli, core.history, core.events, core.raster; "
            f"bad = [m for m in sys.modules if m.split('.')[0] in {sorted(GUI_LIBS)!r}]; "
            "print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
