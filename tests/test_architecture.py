"""Layering rules of DESIGN section 2 and docs/ARCHITECTURE.md, checked on the source (an import
anywhere in a module counts, lazy imports inside functions included).

Packages: ``evpose.core`` (headless engine), ``evpose.widgets`` (Qt views), ``evpose.app`` (wiring,
dialogs, the ``evpose`` CLI in ``evpose.app.cli``), ``evpose.resources``. Rules:

1. nothing under core imports a GUI library, ``evpose.app`` or ``evpose.widgets`` -- no exception;
2. widgets never import app;
3. no module imports another package's private names (``_name``) or private modules;
4. importing core and the CLI loads no GUI library;
5. installed, the project is one import name: ``evpose`` imports from outside the repository and
   the role folders (``core``, ``app``, ``widgets``, ``resources``) do not.
"""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
GUI_LIBS = {"PySide6", "PyQt5", "PyQt6", "pyqtgraph", "vispy", "qtpy", "shiboken6"}
ROLE_FOLDERS = ("core", "app", "widgets", "resources")


def module_name(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(["evpose", *parts])


def package_of(path: Path) -> str:
    """The package a module belongs to (for a package's ``__init__``: the package itself)."""
    name = module_name(path)
    return name if path.name == "__init__.py" else name.rsplit(".", 1)[0]


def imports(path: Path) -> list[tuple[str, list[str], int]]:
    """Every import of a module as ``(absolute module, imported names, line)``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level:
                base = package_of(path).split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([mod] if mod else []))
            out.append((mod, [a.name for a in node.names], node.lineno))
    return out


def sources(*folders):
    return sorted(p for f in folders for p in (REPO / f).rglob("*.py"))


def _id(p):
    return str(p.relative_to(REPO))


@pytest.mark.parametrize("path", sources("core"), ids=_id)
def test_core_imports_no_gui_library_nor_app_nor_widgets(path):
    bad = []
    for mod, names, line in imports(path):
        root = mod.split(".")[0]
        if root in GUI_LIBS:
            bad.append(f"line {line}: {mod}")
        if mod.startswith(("evpose.app", "evpose.widgets")) or root in ("app", "widgets"):
            bad.append(f"line {line}: {mod}")
        if mod == "evpose" and set(names) & {"app", "widgets"}:
            bad.append(f"line {line}: from evpose import {names}")
    assert not bad, f"{_id(path)}: core/ must stay headless and below app/widgets: {bad}"


@pytest.mark.parametrize("path", sources("widgets"), ids=_id)
def test_widgets_do_not_import_app(path):
    bad = [f"line {line}: {mod}" for mod, names, line in imports(path)
           if mod.startswith("evpose.app") or mod.split(".")[0] == "app" or (mod == "evpose" and "app" in names)]
    assert not bad, f"{_id(path)} imports app/: {bad}"


@pytest.mark.parametrize("path", sources(*ROLE_FOLDERS), ids=_id)
def test_no_private_names_across_packages(path):
    """``from evpose.core.x.y import _helper`` is allowed only inside ``evpose.core.x``."""
    own = package_of(path)
    bad = []
    for mod, names, line in imports(path):
        if not mod.startswith("evpose."):
            continue
        target_pkg = mod if (REPO / Path(*mod.split(".")[1:]) / "__init__.py").exists() else mod.rsplit(".", 1)[0]
        if target_pkg == own:
            continue
        private_module = any(part.startswith("_") and not part.startswith("__") for part in mod.split("."))
        private_names = [n for n in names if n.startswith("_") and not n.startswith("__")]
        if private_module or private_names:
            bad.append(f"line {line}: {mod} {private_names}")
    assert not bad, f"{_id(path)} ({own}) imports private names of another package: {bad}"


def test_no_imports_of_the_role_folders_by_their_bare_names():
    """Everything imports ``evpose.<role>``; a bare ``import core`` only works inside the repository."""
    bad = []
    for path in sources(*ROLE_FOLDERS, "tests", "bench"):
        for mod, _names, line in imports(path):
            if mod.split(".")[0] in ROLE_FOLDERS:
                bad.append(f"{_id(path)}:{line}: {mod}")
    assert not bad, bad


def test_importing_core_and_the_cli_loads_no_gui_library(tmp_path):
    code = ("import sys, evpose.core.data.scene, evpose.core.sim.synth, evpose.core.document.history, "
            "evpose.core.data.events, evpose.core.label.raster, evpose.core.export, evpose.core.importers, "
            "evpose.app.cli; from evpose.app.cli.main import build_parser; build_parser(); "
            f"bad = [m for m in sys.modules if m.split('.')[0] in {sorted(GUI_LIBS)!r}]; "
            "print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_one_installed_import_name(tmp_path):
    """From a folder outside the repository: ``evpose`` imports (and ``python -m evpose`` runs), the role
    folders do not, so no other project's ``core`` or ``app`` can collide with ours."""
    code = ("import importlib, sys\n"
            "import evpose, evpose.core, evpose.app, evpose.widgets, evpose.resources\n"
            "leaked = []\n"
            f"for name in {list(ROLE_FOLDERS)!r}:\n"
            "    try:\n"
            "        importlib.import_module(name)\n"
            "        leaked.append(name)\n"
            "    except ImportError:\n"
            "        pass\n"
            "print(leaked); sys.exit(1 if leaked else 0)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run([sys.executable, "-m", "evpose", "--version"], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0 and "evpose" in r.stdout + r.stderr, r.stdout + r.stderr
