"""Fault and bad-input tests (issue 11): shared harness (a uniquely named module: every test
folder has its own ``conftest``, so tests import the harness from here).

Every case runs the real ``evpose`` command in a subprocess with a bounded timeout and ends in
either a non-zero exit with one line naming the file and the field, or a documented warning --
never a traceback, a signal or a hang. Inputs are snapshotted before and compared after.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import uuid
from dataclasses import dataclass
from pathlib import Path

import pytest

#: The installed console script beside the interpreter running the tests.
EVPOSE = str(Path(sys.executable).with_name("evpose"))


@dataclass
class Run:
    args: tuple
    returncode: int
    stdout: str
    stderr: str

    @property
    def error_lines(self) -> list[str]:
        """stderr lines that are not progress-bar redraws or warnings."""
        out = []
        for line in self.stderr.replace("\r", "\n").splitlines():
            s = line.strip()
            if not s or "%|" in s or s.startswith("warning") or "warning:" in s.lower():
                continue
            out.append(s)
        return out


def run_cli(*args, timeout: float = 120, cwd=None, env=None) -> Run:
    """Run ``evpose ARGS`` with a hard timeout (a hang fails the test instead of blocking the suite)."""
    full_env = dict(os.environ, PYTHONUNBUFFERED="1", **(env or {}))
    full_env.pop("DISPLAY", None) if args and args[0] != "gui" else None
    try:
        p = subprocess.run([EVPOSE, *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=cwd,
                           env=full_env, errors="replace")
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"evpose {' '.join(map(str, args))}: no answer after {timeout} s (hang)\n"
                    f"stderr: {exc.stderr!r}")
    return Run(args, p.returncode, p.stdout, p.stderr)


def assert_clean_error(run: Run, *must_name: str) -> str:
    """A non-zero exit by status (not a signal), no traceback, and exactly one error line that names
    each of ``must_name`` (the file and the field). Returns that line."""
    assert run.returncode > 0, (f"expected a clean failure, got exit {run.returncode} "
                                f"(negative = killed by a signal)\nstderr:\n{run.stderr}")
    assert "Traceback" not in run.stderr, f"traceback on stderr:\n{run.stderr}"
    lines = run.error_lines
    assert len(lines) == 1, f"expected one error line, got {len(lines)}:\n" + "\n".join(lines)
    for name in must_name:
        assert str(name) in lines[0], f"error line does not name {name!r}: {lines[0]}"
    return lines[0]


def assert_ok(run: Run) -> None:
    assert run.returncode == 0, f"exit {run.returncode}\nstdout:\n{run.stdout}\nstderr:\n{run.stderr}"
    assert "Traceback" not in run.stderr, run.stderr


def snapshot(root) -> dict[str, str]:
    """relative path -> sha256 of every regular file under ``root`` (symlinks by their target)."""
    root = Path(root)
    out = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        if p.is_symlink():
            out[rel] = "link:" + os.readlink(p)
        elif p.is_file():
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture
def small_tmpfs(tmp_path):
    """A factory for small tmpfs mounts (a full disk on demand); skipped unless running as root."""
    if os.geteuid() != 0 or not shutil.which("mount"):
        pytest.skip("full-disk tests mount a tmpfs: needs root")
    mounts = []

    def make(size: str = "2m") -> Path:
        d = tmp_path / f"tmpfs-{uuid.uuid4().hex[:6]}"
        d.mkdir()
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(d)], capture_output=True)
        if r.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode(errors='replace').strip()}")
        mounts.append(d)
        return d

    yield make
    for d in mounts:
        subprocess.run(["umount", "-l", str(d)], capture_output=True)
