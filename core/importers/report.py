"""What an import did, said once: the report (``import_report.json`` + stderr lines) and the import context.

Every assumption (a guessed unit, a default sensor size), repair (sorted events, projected rotations) and
warning goes through :class:`ImportReport`, which echoes it on stderr and keeps it for the scene's
``import_report.json``. :class:`ImportContext` carries the options, the report and the progress/cancel
callbacks through one import.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Callable

from evpose.core.data.events import Cancelled
from evpose.core.importers.options import ImportOptions

REPORT_FILENAME = "import_report.json"
REPORT_FORMAT = "evpose-import-report/1"


def stderr_log(message: str) -> None:
    """Print one report line on stderr (the default ``log`` of an import)."""
    print(f"evpose import: {message}", file=sys.stderr, flush=True)


class ImportReport:
    """What an import did: sources, assumptions, repairs, warnings and counters (``import_report.json``)."""

    def __init__(self, fmt: str, sources, log: Callable[[str], None] | None = stderr_log):
        self.fmt = fmt
        self.sources = [str(Path(s)) for s in sources]
        self.assumptions: list[str] = []
        self.repairs: list[str] = []
        self.warnings: list[str] = []
        self.counts: dict[str, int] = {}
        self.details: dict = {}
        self._log = log

    def _emit(self, kind: str, msg: str) -> None:
        if self._log is not None:
            self._log(f"{kind}: {msg}")

    def assume(self, msg: str) -> None:
        self.assumptions.append(msg)
        self._emit("assumed", msg)

    def repair(self, msg: str) -> None:
        self.repairs.append(msg)
        self._emit("repaired", msg)

    def warn(self, msg: str) -> None:
        self.warnings.append(msg)
        self._emit("warning", msg)

    def count(self, key: str, n: int = 1) -> None:
        self.counts[key] = self.counts.get(key, 0) + int(n)

    def to_dict(self) -> dict:
        srcs = []
        for s in self.sources:
            p = Path(s)
            try:
                st = p.stat()
                srcs.append({"path": str(p.resolve()), "bytes": st.st_size if p.is_file() else None,
                             "mtime_ns": st.st_mtime_ns})
            except OSError:
                srcs.append({"path": s})
        return {"format": REPORT_FORMAT, "importer": self.fmt, "sources": srcs, "assumptions": self.assumptions,
                "repairs": self.repairs, "warnings": self.warnings, "counts": self.counts, **self.details}


class ImportContext:
    """Options, report and the ``progress(fraction, message)`` / ``cancel() -> bool`` callbacks of one import."""

    def __init__(self, fmt: str, sources, options: ImportOptions | None = None, *, progress=None, cancel=None,
                 log: Callable[[str], None] | None = stderr_log):
        self.options = options or ImportOptions()
        self.options.check()
        self.report = ImportReport(fmt, sources, log)
        self._progress, self._cancel = progress, cancel
        self._last = (-1.0, 0.0)
        self.t_start = time.perf_counter()

    @property
    def repair(self) -> bool:
        return bool(self.options.repair)

    def progress(self, fraction: float, message: str = "") -> None:
        if self._progress is None:
            return
        now = time.perf_counter()
        f = min(max(float(fraction), 0.0), 1.0)
        if f >= 1.0 or f - self._last[0] >= 0.002 or now - self._last[1] > 0.25:
            self._last = (f, now)
            self._progress(f, message)

    def cancelled(self) -> bool:
        return bool(self._cancel is not None and self._cancel())

    def check_cancel(self) -> None:
        if self.cancelled():
            raise Cancelled("import cancelled")


def result_summary(ctx: ImportContext, out: Path) -> dict:
    """The JSON summary printed by ``evpose import --json`` and returned by the API."""
    r = ctx.report
    return {"scene": str(out), "format": r.fmt, "n_events": r.counts.get("events_written"),
            "n_poses": r.details.get("trajectory", {}).get("n", 0), "events_only": bool(r.details.get("events_only")),
            "objects": list(r.details.get("objects", {})), "report": str(Path(out) / REPORT_FILENAME),
            "assumptions": r.assumptions, "repairs": r.repairs, "warnings": r.warnings,
            "runtime_s": time.perf_counter() - ctx.t_start}
