"""The ``evpose`` command as one package (issue 12, point 4): one place for exit codes and error lines
(``errors``), for the JSON document (``json_output``) and for progress bars (``progress``); building the
parser and ``--help`` load no engine module; every sub-command returns an exit status."""
from __future__ import annotations

import argparse
import ast
import errno
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from evpose.app.cli.errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_OS_ERROR, CliError, command
from evpose.app.cli.json_output import emit
from evpose.app.cli.main import build_parser
from evpose.app.cli.progress import Progress
from evpose.core.errors import InputError

CLI = Path(__file__).resolve().parents[2] / "app" / "cli"
#: Modules that building the parser and ``--help`` must not load (the engine's heavy dependencies).
HEAVY = ("numpy", "scipy", "h5py", "cv2", "trimesh", "open3d", "tqdm", "hdf5plugin", "PySide6", "vispy")


def run_fake(exc: BaseException | None, capsys, **kw) -> tuple[int, str]:
    @command("fake", **kw)
    def handler(args):
        if exc is not None:
            raise exc

    rc = handler(argparse.Namespace())
    return rc, capsys.readouterr().err


# ------------------------------------------------------------------------------------------ exit codes
@pytest.mark.parametrize("exc, status, line", [
    (InputError("scene.toml: camera.width: must be > 0"), EXIT_BAD_INPUT,
     "evpose fake: error: scene.toml: camera.width: must be > 0"),
    (CliError("--jobs: must be >= 1, got 0"), EXIT_BAD_INPUT, "evpose fake: error: --jobs: must be >= 1, got 0"),
    (FileNotFoundError(errno.ENOENT, "No such file or directory", "/in/events.h5"), EXIT_BAD_INPUT,
     "evpose fake: error: /in/events.h5: No such file or directory"),
    (FileNotFoundError("/meshes: no mesh named teapot"), EXIT_BAD_INPUT,
     "evpose fake: error: /meshes: no mesh named teapot"),
    (NotADirectoryError(errno.ENOTDIR, "Not a directory", "/in/file/x"), EXIT_BAD_INPUT,
     "evpose fake: error: /in/file/x: Not a directory"),
    (OSError(errno.ENOSPC, "No space left on device", "/full/out.h5"), EXIT_OS_ERROR,
     "evpose fake: error: /full/out.h5: No space left on device"),
    (PermissionError(errno.EACCES, "Permission denied", "/ro/out"), EXIT_OS_ERROR,
     "evpose fake: error: /ro/out: Permission denied"),
    (KeyboardInterrupt(), EXIT_INTERRUPTED, "evpose fake: interrupted"),
], ids=lambda v: type(v).__name__ if isinstance(v, BaseException) else None)
def test_each_error_is_one_line_and_its_exit_status(exc, status, line, capsys):
    rc, err = run_fake(exc, capsys)
    assert rc == status
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(line), err


def test_cancelled_and_interrupted_say_what_the_command_wants(capsys):
    from evpose.core.data.events import Cancelled

    assert run_fake(Cancelled("export cancelled"), capsys) == (EXIT_INTERRUPTED, "evpose fake: export cancelled\n")
    assert run_fake(Cancelled("x"), capsys, cancelled="cancelled (nothing written)") == \
        (EXIT_INTERRUPTED, "evpose fake: cancelled (nothing written)\n")
    assert run_fake(KeyboardInterrupt(), capsys, interrupted="interrupted; rerun to resume") == \
        (EXIT_INTERRUPTED, "evpose fake: interrupted; rerun to resume\n")


def test_success_is_zero_and_a_bug_keeps_its_traceback(capsys):
    assert run_fake(None, capsys) == (0, "")
    with pytest.raises(ZeroDivisionError):
        run_fake(ZeroDivisionError("a bug, not bad input"), capsys)


def test_every_command_returns_an_exit_status():
    """Every sub-command's handler goes through ``errors.command`` (so ``args.func(args)`` never lets
    bad input escape as a traceback)."""
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    names = set(sub.choices)
    assert names == {"demo", "synth", "info", "gui", "export", "import", "scene", "sync", "refine", "score",
                     "dataset"}
    parsers = dict(sub.choices)
    nested = next(a for a in parsers.pop("dataset")._actions if isinstance(a, argparse._SubParsersAction))
    assert set(nested.choices) == {"info", "import", "sync", "refine", "score", "report", "export"}
    parsers.update({f"dataset {n}": p for n, p in nested.choices.items()})
    nested = next(a for a in parsers.pop("scene")._actions if isinstance(a, argparse._SubParsersAction))
    assert set(nested.choices) == {"set-trajectory", "add-objects"}
    parsers.update({f"scene {n}": p for n, p in nested.choices.items()})
    for name, parser in parsers.items():
        func = parser.get_default("func")
        assert getattr(func, "__wrapped__", None) is not None, f"evpose {name}: handler not wrapped by command()"


# ------------------------------------------------------------------------------------------ JSON
def test_json_is_the_only_thing_on_stdout(capsys):
    @command("fake")
    def handler(args):
        print("a stray message")                     # e.g. a library printing: must not spoil the document
        emit(args, {"n": np.int64(3), "x": np.float32(0.5), "bad": np.float32("nan"), "v": np.arange(2),
                    "ok": np.bool_(True)}, "text")

    assert handler(argparse.Namespace(json=True)) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out) == {"n": 3, "x": 0.5, "bad": None, "v": [0, 1], "ok": True}
    assert "a stray message" in cap.err
    assert handler(argparse.Namespace(json=False)) == 0
    assert capsys.readouterr().out == "a stray message\ntext\n"


def test_json_of_an_unknown_type_is_a_bug(capsys):
    with pytest.raises(TypeError, match="not JSON serialisable: object"):
        emit(argparse.Namespace(json=True), {"x": object()}, "")


# ------------------------------------------------------------------------------------------ progress
def test_progress_bar_on_stderr_only_once_work_starts(capsys):
    with Progress("export epose", enabled=True) as progress:
        assert capsys.readouterr().err == ""           # nothing before the first callback
        progress.write("evpose import: assumed: times in us")
        for f in np.linspace(0, 1, 5):
            progress(f, "window 3")
    cap = capsys.readouterr()
    assert cap.out == ""
    assert "evpose import: assumed: times in us" in cap.err
    assert "export epose: 100%|" in cap.err.replace("\r", "\n")
    with Progress("quiet", enabled=False) as progress:
        progress(0.5, "x")
    assert capsys.readouterr().err == ""


def test_one_place_for_json_progress_and_exit_codes():
    """No command module writes JSON, draws a bar, handles Ctrl-C or defines an exit code on its own."""
    owner = {"json": "json_output.py", "tqdm": "progress.py", "KeyboardInterrupt": "errors.py",
             "sys.exit": "main.py", "EXIT_": "errors.py"}
    bad = []
    for path in sorted(CLI.glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name.split(".")[0] for a in node.names] + [(getattr(node, "module", None) or "")]
            elif isinstance(node, ast.Name):
                names = [node.id]
            elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
                names = [f"{node.value.id}.{node.attr}"]
            elif isinstance(node, ast.Assign):
                names = ["EXIT_" for t in node.targets if isinstance(t, ast.Name) and t.id.startswith("EXIT_")]
            for n in names:
                if n in owner and path.name != owner[n]:
                    bad.append(f"{path.name}:{node.lineno}: {n}")
    assert not bad, bad


# ------------------------------------------------------------------------------------------ start-up
def test_parser_and_help_load_no_engine_module(tmp_path):
    code = (
        "import contextlib, io, sys\n"
        "from evpose.app.cli.main import build_parser\n"
        "p = build_parser()\n"
        "for cmd in ([], ['demo'], ['synth'], ['info'], ['gui'], ['export'], ['import'], ['sync'], ['refine'], ['dataset'], ['dataset', 'export'],"
        " ['score'], ['scene'], ['scene', 'set-trajectory'], ['scene', 'add-objects']):\n"
        "    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "        p.parse_args([*cmd, '--help'])\n"
        f"heavy = sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r})\n"
        "engine = sorted(m for m in sys.modules if m.startswith('evpose.core.') and m != 'evpose.core.errors')\n"
        "print(heavy, engine)\n"
        "sys.exit(1 if heavy or engine else 0)\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_import_format_names_are_the_engines():
    from evpose.app.cli.importers import FORMAT_NAMES
    from evpose.core.importers import FORMATS

    assert FORMAT_NAMES == tuple(FORMATS)
    from evpose.app.cli.scene import TRAJECTORY_FORMATS
    from evpose.core.importers import scene_edit

    assert TRAJECTORY_FORMATS == scene_edit.TRAJECTORY_FORMATS


@pytest.mark.parametrize("at", ["-1", "nan", "inf"])
def test_gui_at_refuses_a_time_before_the_recording_in_one_line(at, capsys, tmp_path):
    """``evpose gui SCENE --at SECONDS`` (the triage report's "open it here" command) checks its value before any
    window opens."""
    from evpose.app.cli.main import main

    assert main(["gui", str(tmp_path), "--at", at]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--at" in err[0], err
