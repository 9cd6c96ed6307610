"""Shared machinery of the importers: errors, report, validation, event sink and the atomic scene builder.

Every importer turns published data into a scene folder (DESIGN section 4) through the same pieces:

* :class:`ImportFailure` -- the only exception an importer lets out for bad input (besides
  :class:`~evpose.core.data.events.Cancelled` and ``KeyboardInterrupt``). Its message always reads
  ``"{file}: {record}: {field}: {message}"``, e.g. ``"rec.bag: message 12 on /dvs/events: events: ..."``.
* :class:`ImportReport` -- everything that was assumed, repaired, dropped or guessed; written to
  ``import_report.json`` in the scene and echoed on stderr (``log``).
* :class:`EventSink` -- validation of the event stream on its way to :class:`~evpose.core.data.events.EventWriter`:
  out-of-sensor events are dropped and counted, events unsorted inside a chunk are sorted (stable, counted),
  and chunks that overlap in time (e.g. ROS messages) are merged by a **bounded stream merge**: the sink keeps
  the newest ``reorder_window_us`` of events (default 100 ms, at most ``max_pending`` events) in memory and
  writes everything older. An event that arrives later than that (older than the newest event seen so far
  minus the window, or than an event already written) is an error (``--repair``: dropped and counted), whatever
  the buffer holds, so the outcome does not depend on file size. Memory is bounded by the window, never by the
  file.
* :class:`SceneBuilder` -- builds the scene in a hidden sibling folder and renames it into place at the end;
  on any error, cancel or ``KeyboardInterrupt`` the temporary folder is removed, so a partial scene folder
  never exists.
* time units: :func:`guess_time_unit` (seconds / ms / µs / ns from magnitude, event rate or pose period) and
  exact conversions to int64 µs with **round half up** (``floor(x * 10**6 + 1/2)`` for seconds).
* rotations: :func:`check_T` projects onto SO(3), reports the residual and refuses above
  :data:`~evpose.core.data.geometry.ROTATION_TOLERANCE` unless ``repair``.
"""
from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import shutil
import sys
import time
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Callable

import numpy as np

from evpose.core.data.atomic import atomic_write_text
from evpose.core.data.camera import CameraError, CameraModel
from evpose.core.data.events import Cancelled, EventArray, EventWriter
from evpose.core.data.geometry import (
    ROTATION_TOLERANCE,
    make_T,
    orthonormalize,
    rotation_angle,
)
from evpose.core.data.scene import (
    SCENE_FILENAME,
    ObjectSpec,
    SceneError,
    SceneManifest,
    load_manifest,
)
from evpose.core.data.trajectory import Trajectory, TrajectoryError
from evpose.core.errors import InputError

REPORT_FILENAME = "import_report.json"
REPORT_FORMAT = "evpose-import-report/1"
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf")

#: Default reorder window of :class:`EventSink` (µs): events may arrive up to this much out of order.
DEFAULT_REORDER_WINDOW_US = 100_000
#: Longest accepted event stream (s): the ms index costs 8 bytes per ms, and a longer span is nearly always a corrupt
#: time stamp or a wrong time unit.
DEFAULT_MAX_SPAN_S = 4 * 3600.0
#: Events kept back at most by the reorder buffer (bounds memory whatever the window).
DEFAULT_MAX_PENDING = 8_000_000
_FLUSH_EVENTS = 1 << 20


# ---------------------------------------------------------------------------------------------- errors
class ImportFailure(InputError):
    """Bad input to an importer. ``file``, ``record`` (message index / line / row / window) and ``field``
    say where; ``str(exc)`` is ``"{file}: {record}: {field}: {message}"``."""

    def __init__(self, file, record: str, fld: str, message: str):
        self.file, self.record, self.field, self.reason = str(file), str(record), str(fld), str(message)
        super().__init__(f"{self.file}: {self.record}: {self.field}: {self.reason}")


#: errno values that only writing causes (full disk, quota, read-only file system): they pass through
#: :func:`wrap_errors` and end as an error about ``--out``, not about the input being parsed.
_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG})


@contextlib.contextmanager
def wrap_errors(file, record: str = "(file)", fld: str = "-", what: str = ""):
    """Turn any exception raised inside into :class:`ImportFailure` naming ``file``/``record``/``field``.

    :class:`ImportFailure`, :class:`Cancelled`, ``KeyboardInterrupt`` and ``SystemExit`` pass through.
    Parsers of corrupt files fail in many ways (struct errors, assertions, zlib/zstd errors, absurd sizes);
    all of them become one clear error here.
    """
    try:
        yield
    except (ImportFailure, Cancelled):
        raise
    except OSError as exc:
        if exc.errno in _WRITE_ERRNOS:     # the output is full or read-only: not the input's fault
            raise
        msg = str(exc) or type(exc).__name__
        raise ImportFailure(file, record, fld, f"{what + ': ' if what else ''}{msg} ({type(exc).__name__})") from None
    except MemoryError:
        raise ImportFailure(file, record, fld, f"{what or 'data'} claims an impossible size (out of memory)") from None
    except RecursionError:
        raise ImportFailure(file, record, fld, f"{what or 'data'} is nested too deeply") from None
    except Exception as exc:  # noqa: BLE001 - the point is to catch everything a corrupt file can cause
        msg = str(exc) or type(exc).__name__
        if what:
            msg = f"{what}: {msg}"
        raise ImportFailure(file, record, fld, f"{msg} ({type(exc).__name__})") from None


# ---------------------------------------------------------------------------------------------- options
@dataclass
class ImportOptions:
    """All importer options (CLI flags map 1:1; unused ones are ignored by a format).

    Units: µs for times, metres for lengths unless stated.
    """

    repair: bool = False                 # repair what can be repaired (sort, drop, project) instead of refusing
    force: bool = False                  # replace an existing non-empty --out folder
    name: str | None = None              # scene name (default: --out folder name)
    camera: str | None = None            # calibration file: our JSON, OpenCV/YCB-Ev JSON, DSEC/Kalibr YAML, RPG calib.txt
    width: int | None = None             # sensor size override, pixels
    height: int | None = None
    objects: str | None = None           # "name=mesh.obj:T_base_obj.json,..." (T optional for formats that derive it)
    time_unit: str | None = None         # force the unit of guessable times: s, ms, us, ns
    offset_us: int | None = None         # clock prior override (pose minus event time, µs)
    reorder_window_us: int = DEFAULT_REORDER_WINDOW_US
    max_span_s: float = DEFAULT_MAX_SPAN_S  # refuse event times spanning more (a corrupt time stamp, or wrong unit)
    compression: str | None = "blosc-lz4"
    # epose-bag / epose-export
    assets: str | None = None            # folder laid out like shared/assets/epose
    scene: str | None = None             # scenes.json key (aliases and time_shifts.csv names accepted)
    sequence: str | None = None          # time_shifts.csv sequence, e.g. R_05_ml (case-insensitive)
    events_topic: str = "/dvs/events"
    pose_topic: str = "/dvs/pose"
    pose_time: str = "header"            # header | bag: time stamp of PoseStamped samples
    one_based: bool = False              # epose-export: event x/y are 1-based (MATLAB)
    classes: str | None = None           # epose-export: "cls=name,..." mapping of cls_index to object names
    # dsec
    events_mode: str = "copy"            # copy | link | reference
    camera_key: str = "cam0"             # which camera of a DSEC/Kalibr YAML
    # ycbev
    models: str | None = None            # BOP models folder (obj_000001.ply, mm)
    mesh_scale: float | None = None
    frame_us: int = 33333                # frame period of scene_gt.json images, µs (YCB-Ev: 1000000 // 30)
    frame_index_offset: int = 1          # image j is at time_origin + (j + offset) * frame_us
    time_origin_us: int = 0              # added to every YCB-Ev time (the files count from the recording start)
    rgb_to_event: str | None = "auto"    # calib_stereo_c2ev.json: "auto" (found beside the sequence), a path, or "none"

    def check(self) -> None:
        if self.time_unit is not None and self.time_unit not in TIME_UNITS:
            raise ImportFailure("(options)", "--time-unit", "time_unit", f"expected one of {', '.join(TIME_UNITS)}, "
                                f"got {self.time_unit!r}")
        if self.events_mode not in ("copy", "link", "reference"):
            raise ImportFailure("(options)", "--events-mode", "events_mode",
                                f"expected copy, link or reference, got {self.events_mode!r}")
        if self.pose_time not in ("header", "bag"):
            raise ImportFailure("(options)", "--pose-time", "pose_time", f"expected header or bag, got {self.pose_time!r}")
        if not float(self.max_span_s) > 0:
            raise ImportFailure("(options)", "--max-span-s", "max_span_s", "must be positive")
        if int(self.reorder_window_us) < 0:
            raise ImportFailure("(options)", "--reorder-window-ms", "reorder_window_us", "must be >= 0")
        for k in ("width", "height"):
            v = getattr(self, k)
            if v is not None and int(v) <= 0:
                raise ImportFailure("(options)", f"--{k}", k, f"must be positive, got {v}")
        if int(self.frame_us) <= 0:
            raise ImportFailure("(options)", "--frame-us", "frame_us", f"must be positive, got {self.frame_us}")


# ---------------------------------------------------------------------------------------------- report
def _stderr_log(message: str) -> None:
    print(f"evpose import: {message}", file=sys.stderr, flush=True)


class ImportReport:
    """What an import did: sources, assumptions, repairs, warnings and counters (``import_report.json``)."""

    def __init__(self, fmt: str, sources, log: Callable[[str], None] | None = _stderr_log):
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
                 log: Callable[[str], None] | None = _stderr_log):
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


# ---------------------------------------------------------------------------------------------- time
#: Scale of each time unit to µs.
TIME_UNITS = {"s": Fraction(10**6), "ms": Fraction(10**3), "us": Fraction(1), "ns": Fraction(1, 1000)}
_UNIT_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_UNIT_NAMES = {"s": "seconds", "ms": "milliseconds", "us": "microseconds", "ns": "nanoseconds"}


def guess_time_unit(sample, *, kind: str = "events") -> tuple[str, str, dict]:
    """Guess the unit of a column of times from the numbers alone.

    Each unit gets a score (lower is better, ``inf`` = implausible): for events the event rate ``(n-1)/span``
    must lie in 10 .. 2e9 ev/s and the score is its distance (decades) from 1 M ev/s; for poses the median positive
    step must be a sampling period of 10 µs .. 2 s and the score is its distance from 5 ms. Values that read as an
    epoch date (years 1998..2100) in a unit get a bonus of one decade there; fractional values add two decades to
    ms/µs/ns. Units differ by 1000x, so real data is far from ties. With too few values for a rate or a period,
    a unique epoch reading decides, else seconds for fractional and µs for integer values.

    Returns
    -------
    unit : str
        ``"s"``, ``"ms"``, ``"us"`` or ``"ns"``.
    reason : str
        Human-readable justification (goes into the report).
    scores : dict
        Per-unit score.
    """
    v = np.asarray(sample, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return "us", "no finite sample; assumed microseconds", {}
    has_frac = bool(np.any(v != np.round(v)))
    vmin, vmax = float(v.min()), float(v.max())
    epoch = {u for u, f in _UNIT_S.items() if 8.8e8 <= vmin * f and vmax * f <= 4.1e9}
    scores = {}
    if kind == "events":
        span = vmax - vmin
        for u, f in _UNIT_S.items():
            if span <= 0 or len(v) < 2:
                scores[u] = math.inf
                continue
            rate = (len(v) - 1) / (span * f)
            scores[u] = abs(math.log10(rate / 1e6)) if 10 <= rate <= 2e9 else math.inf
        what = "event rate"
    else:
        d = np.diff(v)
        pos = d[d > 0]
        for u, f in _UNIT_S.items():
            if len(pos) == 0:
                scores[u] = math.inf
                continue
            step = float(np.median(pos)) * f
            scores[u] = abs(math.log10(step / 5e-3)) if 1e-5 <= step <= 2.0 else math.inf
        what = "sampling period"
    for u in scores:
        if u in epoch:
            scores[u] -= 1.0
        if has_frac and u != "s":
            scores[u] += 2.0
    finite = {u: sc for u, sc in scores.items() if math.isfinite(sc)}
    if not finite:
        if len(epoch) == 1:
            u = next(iter(epoch))
            return u, f"values look like epoch time in {_UNIT_NAMES[u]} (first {v[0]:.17g})", scores
        u = "s" if has_frac else "us"
        return u, f"too few distinct values to measure the {what}; assumed {_UNIT_NAMES[u]}", scores
    u = min(finite, key=finite.get)
    f = _UNIT_S[u]
    if kind == "events":
        val = f"{(len(v) - 1) / ((vmax - vmin) * f):.3g} ev/s"
    else:
        d = np.diff(v)
        val = f"{float(np.median(d[d > 0])) * f * 1e3:.3g} ms period"
    others = ", ".join(k for k in finite if k != u)
    reason = (f"{what} is plausible in {_UNIT_NAMES[u]} ({val}" + (", epoch-like values" if u in epoch else "") + ")"
              + (f"; also possible: {others}" if others else ""))
    return u, reason, scores


#: A forced unit is questioned when its plausibility score (decades from a typical event rate / pose period, see
#: :func:`guess_time_unit`) is this much worse than the best unit's: 2 decades = a 100x odd rate or period.
FORCED_UNIT_MARGIN_DECADES = 2.0


def _forced_unit_implausible(sample, forced: str, kind: str) -> str | None:
    """Why the numbers do not look like ``forced`` (None when they plausibly do): e.g. ``--time-unit ns`` on
    µs data gives 1834 M events/s."""
    unit, _reason, scores = guess_time_unit(sample, kind=kind)
    sc, best = scores.get(forced, math.inf), scores.get(unit, math.inf)
    if not scores or (math.isfinite(sc) and not (sc - best >= FORCED_UNIT_MARGIN_DECADES)):
        return None
    v = np.asarray(sample, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if len(v) < 2:
        return None
    f = _UNIT_S[forced]
    if kind == "events":
        span = float(v.max() - v.min()) * f
        if span <= 0:
            return None
        val = f"an event rate of {(len(v) - 1) / span / 1e6:.4g} M events/s"
    else:
        d = np.diff(v)
        pos = d[d > 0]
        if len(pos) == 0:
            return None
        val = f"a pose period of {float(np.median(pos)) * f * 1e3:.4g} ms"
    better = f"; the values look like {_UNIT_NAMES[unit]}" if unit != forced else ""
    return f"{_UNIT_NAMES[forced]} give {val}, which is implausible{better} (check --time-unit)"


def resolve_time_unit(ctx: ImportContext, sample, *, what: str, kind: str, declared: str | None = None) -> str:
    """Decide the unit of a time column: ``--time-unit`` wins; else the format's ``declared`` unit if the
    numbers are plausible in it; else the guess. The decision goes into the report (and stderr)."""
    forced = ctx.options.time_unit
    if forced:
        ctx.report.assume(f"{what}: times in {_UNIT_NAMES[forced]} (--time-unit)")
        ctx.report.details.setdefault("time_units", {})[what] = {"unit": forced, "why": "--time-unit"}
        implausible = _forced_unit_implausible(sample, forced, kind)
        if implausible:
            ctx.report.warn(f"{what}: --time-unit {forced}: {implausible}")
        return forced
    unit, reason, scores = guess_time_unit(sample, kind=kind)
    if declared is not None:
        if declared == unit or math.isfinite(scores.get(declared, math.inf)) or not scores:
            ctx.report.details.setdefault("time_units", {})[what] = {"unit": declared, "why": "format specification"}
            return declared
        ctx.report.warn(f"{what}: the format specifies {_UNIT_NAMES[declared]}, but the values are implausible in "
                        f"that unit; {reason}: using {_UNIT_NAMES[unit]} (override with --time-unit)")
    else:
        ctx.report.assume(f"{what}: times in {_UNIT_NAMES[unit]} ({reason}; override with --time-unit)")
    ctx.report.details.setdefault("time_units", {})[what] = {"unit": unit, "why": reason}
    return unit


def float_to_us(t, unit: str) -> np.ndarray:
    """Float times in ``unit`` -> int64 µs, round half up. The integer part is converted exactly and only the
    fraction is scaled in floating point, so float64 seconds that represent whole µs (even epoch seconds) come
    back exactly. Caller checks finiteness first."""
    t = np.asarray(t)
    if t.dtype.kind in "iu":
        return int_to_us(t, unit)
    t = t.astype(np.float64)
    scale = float(TIME_UNITS[unit])
    if t.size and float(np.abs(t).max()) * scale >= 9.2e18:
        raise ValueError(f"time {float(np.abs(t).max())!r} {unit} is outside the int64 µs range")
    whole = np.floor(t)
    frac = t - whole
    whole_i = whole.astype(np.int64)
    if scale >= 1:
        return whole_i * np.int64(int(scale)) + np.floor(frac * scale + 0.5).astype(np.int64)
    return np.floor(t * scale + 0.5).astype(np.int64)


def int_to_us(t, unit: str) -> np.ndarray:
    """Integer times in ``unit`` -> int64 µs (ns: round half up)."""
    t = np.asarray(t)
    if t.dtype == np.uint64 and t.size and int(t.max()) > 2**63 - 1:
        raise ValueError(f"time {int(t.max())} {unit} is outside the int64 range")
    t = t.astype(np.int64)
    s = TIME_UNITS[unit]
    if s.denominator == 1:
        if t.size and s.numerator > 1 and int(np.abs(t).max()) > (2**63 - 1) // s.numerator:
            raise ValueError(f"time {int(np.abs(t).max())} {unit} is outside the int64 µs range")
        return t * np.int64(s.numerator)
    q = np.int64(s.denominator)
    return (t + q // 2) // q


_DECIMAL = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE]([+-]?\d{1,3}))?$")


def decimal_to_us(token: str, unit: str) -> int:
    """One decimal string (``"1468940293.951234"``, ``"1e-3"``) in ``unit`` -> µs, exactly, round half up.

    Raises ``ValueError`` for anything else (and for exponents beyond +-40, which no time stamp needs and which
    would make exact arithmetic slow)."""
    tok = token.strip()
    m = _DECIMAL.match(tok)
    if m is None or len(tok) > 64 or (m.group(3) is not None and abs(int(m.group(3))) > 40):
        raise ValueError(f"not a decimal number: {token!r}")
    v = Fraction(tok) * TIME_UNITS[unit]
    return math.floor(v + Fraction(1, 2))


def ros_time_to_us(sec, nsec) -> np.ndarray:
    """ROS ``time`` (uint32 sec, uint32 nsec) -> int64 µs, nanoseconds rounded half up."""
    return np.asarray(sec, np.int64) * 1_000_000 + (np.asarray(nsec, np.int64) + 500) // 1000


# ---------------------------------------------------------------------------------------------- geometry checks
def check_T(T, ctx: ImportContext, file, record: str, fld: str, *, tolerance: float = ROTATION_TOLERANCE,
            quiet: bool = False) -> tuple[np.ndarray, float]:
    """Validate one 4x4 transform from a file: shape, finiteness, last row, rotation residual.

    Returns the transform with its rotation projected onto SO(3) and the residual ``max|R R^T - I|``.
    Above ``tolerance`` it raises unless ``--repair`` (then the projection is reported).
    """
    try:
        T = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError):
        raise ImportFailure(file, record, fld, "not a numeric 4x4 matrix") from None
    if T.shape == (3, 4):
        T = np.vstack([T, [0.0, 0.0, 0.0, 1.0]])
    if T.shape != (4, 4):
        raise ImportFailure(file, record, fld, f"expected a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ImportFailure(file, record, fld, "contains NaN or inf")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise ImportFailure(file, record, fld, f"last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R, residual = orthonormalize(T[:3, :3])
    if residual > tolerance:
        if not ctx.repair:
            raise ImportFailure(file, record, fld, f"rotation is not orthonormal (max|R R^T - I| = {residual:.4g} > "
                                f"tolerance {tolerance:g}); fix the value or pass --repair to project it onto SO(3)")
        if not quiet:
            ctx.report.repair(f"{file}: {record}: {fld}: rotation projected onto SO(3) (residual {residual:.4g} > "
                              f"tolerance {tolerance:g}, --repair)")
    return make_T(R, T[:3, 3]), residual


def check_finite_rows(arr: np.ndarray, names, file, record_of: Callable[[int], str]) -> None:
    """Raise naming the first row/field that is NaN or inf."""
    arr = np.asarray(arr, dtype=np.float64)
    bad = ~np.isfinite(arr)
    if bad.any():
        r, c = np.argwhere(bad.reshape(len(arr), -1))[0]
        raise ImportFailure(file, record_of(int(r)), names[int(c)], f"not finite ({arr.reshape(len(arr), -1)[r, c]})")


def make_trajectory(ctx: ImportContext, file, t_us, positions_m, quats_xyzw, *, record_of=None,
                    fields=("t", "x", "y", "z", "qx", "qy", "qz", "qw")) -> Trajectory:
    """Validate pose samples and build a :class:`Trajectory` (frame in the base frame, metres, µs).

    NaN/inf and zero quaternions are refused naming the record; non-unit quaternions are normalised and
    reported; decreasing or conflicting duplicate times are refused unless ``--repair`` (then sorted, last
    sample per time kept, reported). Exact duplicates are always dropped and reported.
    """
    record_of = record_of or (lambda i: f"row {i}")
    t_us = np.asarray(t_us, dtype=np.int64)
    pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(quats_xyzw, dtype=np.float64).reshape(-1, 4)
    if len(t_us) == 0:
        raise ImportFailure(file, "(all records)", fields[0], "no pose samples")
    if not (len(t_us) == len(pos) == len(q)):
        raise ImportFailure(file, "(all records)", fields[0], f"{len(t_us)} times for {len(pos)} positions and "
                            f"{len(q)} orientations")
    check_finite_rows(np.hstack([pos, q]), fields[1:], file, record_of)
    norms = np.linalg.norm(q, axis=1)
    if np.any(norms < 1e-9):
        r = int(np.flatnonzero(norms < 1e-9)[0])
        raise ImportFailure(file, record_of(r), "/".join(fields[4:]), "zero quaternion")
    dev = np.abs(norms - 1.0)
    if dev.max() > 1e-6:
        r = int(np.argmax(dev))
        ctx.report.repair(f"{file}: normalised {int(np.count_nonzero(dev > 1e-6))} non-unit quaternion(s) "
                          f"(max |norm - 1| = {dev.max():.3g} at {record_of(r)})")
    d = np.diff(t_us)
    if np.any(d <= 0):
        eq = np.flatnonzero(d == 0)
        same = np.zeros(len(d), bool)
        if len(eq):
            qa, qb = q[eq] / norms[eq, None], q[eq + 1] / norms[eq + 1, None]
            same[eq] = (np.abs(pos[eq] - pos[eq + 1]).max(1) <= 1e-12) & (
                np.minimum(np.abs(qa - qb), np.abs(qa + qb)).max(1) <= 1e-12)
        conflict = (d < 0) | ((d == 0) & ~same)
        if conflict.any() and not ctx.repair:
            r = int(np.flatnonzero(conflict)[0]) + 1
            kind = "decreases" if d[r - 1] < 0 else "repeats with a different pose"
            raise ImportFailure(file, record_of(r), fields[0], f"time {kind} ({t_us[r - 1]} -> {t_us[r]} µs); "
                                "pass --repair to sort the samples and keep the last one per time")
    try:
        traj = Trajectory(t_us, pos, q, source=str(file), repair=ctx.repair)
    except TrajectoryError as exc:
        raise ImportFailure(file, "(trajectory)", fields[0], str(exc).replace(f"{file}: ", "", 1)) from None
    for note in traj.notes:
        if not note.startswith("normalised"):
            ctx.report.repair(f"{file}: trajectory: {note}")
    return traj


def poses_from_matrices(ctx: ImportContext, file, T, record_of) -> tuple[np.ndarray, np.ndarray, float]:
    """(N, 4, 4) transforms -> positions (N, 3), quaternions xyzw (N, 4), max rotation residual.

    Each rotation is validated with :func:`check_T` (refused above tolerance unless ``--repair``).
    """
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, dtype=np.float64)
    out = np.empty_like(T)
    res = np.zeros(len(T))
    n_proj = 0
    for i in range(len(T)):
        out[i], res[i] = check_T(T[i], ctx, file, record_of(i), "T", quiet=True)
        n_proj += res[i] > ROTATION_TOLERANCE
    if len(T) and res.max() > 1e-9:
        msg = (f"{file}: {len(T)} rotation(s) projected onto SO(3) (max residual {res.max():.3g} at "
               f"{record_of(int(np.argmax(res)))})")
        (ctx.report.repair if n_proj else ctx.report.assume)(msg)
    return out[:, :3, 3].copy(), Rotation.from_matrix(out[:, :3, :3]).as_quat(), float(res.max() if len(T) else 0.0)


# ---------------------------------------------------------------------------------------------- events
def _as_int_column(a, file, record: str, fld: str, ctx: ImportContext) -> tuple[np.ndarray, np.ndarray | None]:
    """Integer view of an event column (integer dtypes kept as they are; floats must be whole numbers and become
    int64). Returns (values, bad-row mask or None)."""
    a = np.asarray(a)
    if a.dtype.kind in "iu":
        return a, None
    if a.dtype.kind == "b":
        return a.view(np.uint8), None
    if a.dtype.kind != "f":
        raise ImportFailure(file, record, fld, f"expected numbers, got dtype {a.dtype}")
    bad = ~np.isfinite(a)
    if bad.any():
        if not ctx.repair:
            i = int(np.flatnonzero(bad)[0])
            raise ImportFailure(file, f"{record}, event {i}", fld, f"not finite ({a[i]}); pass --repair to drop such events")
        a = np.where(bad, 0, a)
    frac = a != np.floor(a)
    if frac.any():
        i = int(np.flatnonzero(frac)[0])
        raise ImportFailure(file, f"{record}, event {i}", fld, f"expected an integer pixel/polarity, got {a[i]}")
    return a.astype(np.int64), (bad if bad.any() else None)


class EventSink:
    """Validates event chunks and streams them, time-sorted, into an :class:`EventWriter`.

    Parameters
    ----------
    writer : EventWriter or None
        None = validate only (reference/link modes).
    width, height : int
        Sensor size; events outside ``[0, width) x [0, height)`` are dropped and counted.
    reorder_window_us : int
        Bounded stream merge: events are held back until they are older than the newest event seen minus
        this window; an event older than one already written is "late" (error, or dropped with ``--repair``).
    """

    def __init__(self, ctx: ImportContext, writer: EventWriter | None, width: int, height: int, *,
                 reorder_window_us: int | None = None, max_pending: int = DEFAULT_MAX_PENDING):
        self.ctx, self.writer, self.width, self.height = ctx, writer, int(width), int(height)
        self.window = int(ctx.options.reorder_window_us if reorder_window_us is None else reorder_window_us)
        self.max_pending = int(max_pending)
        self.pending: list[tuple] = []
        self.n_pending = self._retained = 0
        self.pending_max: int | None = None
        self.need_merge = False
        self.last_written: int | None = None
        self.n_in = self.n_out = 0
        self.n_dropped_sensor = self.n_unsorted_chunks = self.n_inversions = 0
        self.n_overlap_chunks = self.n_late = self.n_nonfinite = 0
        self.t_first = self.t_last = self.t_origin = None
        self.max_span_us = int(float(ctx.options.max_span_s) * 1e6)
        self._where = ("(events)", "-")
        self._first_sensor_drop = None
        self.x_max = self.y_max = -1
        self.x_min = self.y_min = None

    # -------------------------------------------------------------------------------------------
    def add(self, x, y, t_us, p, *, file, record: str) -> None:
        """Add one chunk. ``t_us`` int64 µs (absolute event clock); x/y integer pixels (any int dtype, floats
        must be whole); p in {0, 1}, {-1, 1} or bool."""
        ctx = self.ctx
        ctx.check_cancel()
        t = np.asarray(t_us)
        if t.dtype.kind not in "iu":
            raise ImportFailure(file, record, "t", f"internal: times must be integer µs, got {t.dtype}")
        t = t.astype(np.int64, copy=False)
        n = len(t)
        if not (np.ndim(x) == np.ndim(y) == np.ndim(p) == 1 and len(x) == len(y) == len(p) == n):
            raise ImportFailure(file, record, "x/y/t/p", f"columns have different lengths ({len(x)}, {len(y)}, {n}, "
                                f"{len(p)})")
        if n == 0:
            return
        self.n_in += n
        xi, bx = _as_int_column(x, file, record, "x", ctx)
        yi, by = _as_int_column(y, file, record, "y", ctx)
        pi, bp = _as_int_column(p, file, record, "p", ctx)
        keep = None
        for b in (bx, by, bp):
            if b is not None:
                keep = ~b if keep is None else keep & ~b
        if keep is not None:
            nb = int(n - keep.sum())
            self.n_nonfinite += nb
        # polarity: 0/1, -1/+1 or bool
        if pi.size:
            pmin, pmax = int(pi.min()), int(pi.max())
            if pmin < -1 or pmax > 1:
                i = int(np.flatnonzero((pi < -1) | (pi > 1))[0])
                raise ImportFailure(file, f"{record}, event {i}", "p", f"polarity must be 0/1 or -1/+1, got {int(pi[i])}")
            p8 = (pi > 0).view(np.uint8) if pmin < 0 else pi.astype(np.uint8, copy=False)
        else:
            p8 = pi.astype(np.uint8, copy=False)
        inside = (xi >= 0) & (xi < self.width) & (yi >= 0) & (yi < self.height)
        if keep is not None:
            inside &= keep
            n_sensor = int(np.count_nonzero(~inside & keep))
        else:
            n_sensor = n - int(np.count_nonzero(inside))
        if n_sensor:
            if self._first_sensor_drop is None:
                i = int(np.flatnonzero(~inside if keep is None else (~inside & keep))[0])
                self._first_sensor_drop = f"{record}, event {i}: (x={int(xi[i])}, y={int(yi[i])})"
            self.n_dropped_sensor += n_sensor
        if n_sensor or keep is not None:
            xi, yi, t, p8 = xi[inside], yi[inside], t[inside], p8[inside]
            if len(t) == 0:
                return
        if len(xi):
            self.x_max, self.y_max = max(self.x_max, int(xi.max())), max(self.y_max, int(yi.max()))
            mnx, mny = int(xi.min()), int(yi.min())
            self.x_min = mnx if self.x_min is None else min(self.x_min, mnx)
            self.y_min = mny if self.y_min is None else min(self.y_min, mny)
        # sort inside the chunk (stable: equal times keep their file order)
        if len(t) > 1:
            dec = np.count_nonzero(t[1:] < t[:-1])
            if dec:
                self.n_unsorted_chunks += 1
                self.n_inversions += int(dec)
                o = np.argsort(t, kind="stable")
                xi, yi, t, p8 = xi[o], yi[o], t[o], p8[o]
        # a corrupt time stamp (or a wrong unit) would make the ms index of the event file explode
        if self.t_origin is None:
            self.t_origin = int(t[0])
        if int(t[-1]) - self.t_origin > self.max_span_us or self.t_origin - int(t[0]) > self.max_span_us:
            j = int(np.argmax(np.abs(t - self.t_origin) > self.max_span_us))
            raise ImportFailure(file, f"{record}, event {j}", "t", f"t={int(t[j])} µs is {abs(int(t[j]) - self.t_origin) / 3.6e9:.3g} h "
                                f"from the first event (t={self.t_origin} µs): more than --max-span-s "
                                f"{self.max_span_us / 1e6:g} s (corrupt time stamp or wrong time unit?)")
        # late events: older than the newest event seen minus the window (or than one already written)
        thr = self.last_written
        if self.pending_max is not None:
            thr = max(thr if thr is not None else self.pending_max - self.window, self.pending_max - self.window)
        if thr is not None and t[0] < thr:
            late = t < thr
            nl = int(np.count_nonzero(late))
            if not ctx.repair:
                newest = self.pending_max if self.pending_max is not None else self.last_written
                raise ImportFailure(file, record, "t", f"{nl} event(s) from t={int(t[0])} µs arrive more than the reorder "
                                    f"window ({self.window} µs) after later events (newest so far t={newest} µs); the "
                                    "stream is not sorted. Pass --repair to drop them, or a larger --reorder-window-ms")
            self.n_late += nl
            ok = ~late
            xi, yi, t, p8 = xi[ok], yi[ok], t[ok], p8[ok]
            if len(t) == 0:
                return
        if self.pending_max is not None and t[0] < self.pending_max:
            self.need_merge = True
            self.n_overlap_chunks += 1
        self._where = (file, record)
        self.pending.append((xi.astype(np.uint16, copy=False), yi.astype(np.uint16, copy=False), t, p8))
        self.n_pending += len(t)
        self.pending_max = int(t[-1]) if self.pending_max is None else max(self.pending_max, int(t[-1]))
        if self.n_pending >= _FLUSH_EVENTS + self._retained:       # amortised: each event is copied O(1) times
            self._emit(final=False)

    def _emit(self, final: bool) -> None:
        if not self.pending:
            return
        if len(self.pending) == 1:
            x, y, t, p = self.pending[0]
        else:
            x, y, t, p = (np.concatenate([c[k] for c in self.pending]) for k in range(4))
        if self.need_merge:
            o = np.argsort(t, kind="stable")
            x, y, t, p = x[o], y[o], t[o], p[o]
            self.need_merge = False
        if final:
            cut = len(t)
        else:
            cut = int(np.searchsorted(t, self.pending_max - self.window, side="left"))
            if len(t) - cut > self.max_pending:     # bound memory: the window shrinks at extreme rates
                cut = len(t) - self.max_pending
        if cut > 0:
            self._write(x[:cut], y[:cut], t[:cut], p[:cut])
        self.pending = [(x[cut:], y[cut:], t[cut:], p[cut:])] if cut < len(t) else []
        self.n_pending = self._retained = len(t) - cut

    def _write(self, x, y, t, p) -> None:
        if self.t_first is None:
            self.t_first = int(t[0])
        self.t_last = int(t[-1])
        self.last_written = int(t[-1])
        self.n_out += len(t)
        if self.writer is not None:
            try:
                self.writer.append(EventArray(x, y, t, p))
            except ValueError as exc:       # EventFileError and range errors of the writer: name the input
                raise ImportFailure(self._where[0], self._where[1], "events", f"cannot be written: {exc}") from None

    def close(self) -> None:
        """Write what is held back and put the counters into the report."""
        self._emit(final=True)
        r = self.ctx.report
        r.counts.update(events_in=self.n_in, events_written=self.n_out)
        if self.n_dropped_sensor:
            r.repair(f"dropped {self.n_dropped_sensor} event(s) outside the {self.width}x{self.height} sensor "
                     f"(first: {self._first_sensor_drop})")
            r.counts["events_dropped_outside_sensor"] = self.n_dropped_sensor
        if self.n_nonfinite:
            r.repair(f"dropped {self.n_nonfinite} event(s) with a NaN/inf coordinate or polarity (--repair)")
            r.counts["events_dropped_nonfinite"] = self.n_nonfinite
        if self.n_unsorted_chunks:
            r.repair(f"sorted events inside {self.n_unsorted_chunks} chunk(s)/message(s) with unsorted times "
                     f"({self.n_inversions} decreasing step(s)); stable sort, equal times keep file order")
            r.counts["events_decreasing_steps"] = self.n_inversions
        if self.n_overlap_chunks:
            r.repair(f"merged {self.n_overlap_chunks} chunk(s)/message(s) that overlap earlier ones in time "
                     f"(bounded stream merge, window {self.window} µs)")
            r.counts["chunks_overlapping"] = self.n_overlap_chunks
        if self.n_late:
            r.repair(f"dropped {self.n_late} event(s) arriving later than the reorder window (--repair)")
            r.counts["events_dropped_late"] = self.n_late


# ---------------------------------------------------------------------------------------------- scene builder
def import_inputs(sources, options: "ImportOptions") -> list[Path]:
    """Every path an import reads: the sources and the paths its options name (calibration, meshes and
    pose files of ``--objects``, assets, models, the RGB-to-event calibration)."""
    from evpose.core.data.owned_files import input_paths

    rgb = options.rgb_to_event if options.rgb_to_event not in (None, "auto", "none") else None
    return input_paths(list(sources or []), options.camera, options.objects, options.assets, options.models, rgb)


def check_out(out, force: bool, inputs=()) -> Path:
    """The absolute output folder; refuses an existing file or non-empty folder unless ``force``, and with
    ``force`` a folder that holds one of ``inputs`` or anything evpose did not write
    (:func:`evpose.core.data.scene_folder.check_scene_out`)."""
    from evpose.core.data.scene_folder import NotOurs, check_scene_out

    try:
        return check_scene_out(out, inputs, force)
    except NotOurs as exc:
        raise ImportFailure(exc.path, "(output)", "--out", exc.reason) from None


def _output_failure(exc: OSError, out: Path, staging: Path) -> ImportFailure | None:
    """An ``OSError`` of writing the scene (full disk, read-only, permission) as an ImportFailure naming
    ``out`` (the hidden staging folder is gone by then); None for other errors (e.g. reading an input)."""
    from evpose.core.data.os_errors import is_output_error

    if not is_output_error(exc):
        return None
    where = str(exc.filename) if exc.filename is not None else ""
    if where and not (where == str(staging) or where.startswith(str(staging) + os.sep)
                      or where == str(out) or where.startswith(str(out) + os.sep) or where == str(out.parent)):
        return None
    what = exc.strerror or os.strerror(exc.errno)
    if where.startswith(str(staging) + os.sep):
        what += f" while writing {os.path.relpath(where, staging)}"
    return ImportFailure(out, "(output)", "--out", f"{what}; nothing was written")


class SceneBuilder:
    """Builds a scene folder atomically: a hidden sibling ``.NAME.import-*`` folder renamed into place at the end.

    Use as a context manager; leaving it with an exception (including ``KeyboardInterrupt`` and
    :class:`Cancelled`) removes the temporary folder, and nothing exists at ``out`` that was not there before.
    """

    def __init__(self, out, ctx: ImportContext):
        from evpose.core.data.scene_folder import StagingFolder

        self.ctx = ctx
        self.inputs = import_inputs(ctx.report.sources, ctx.options)
        self.out = check_out(out, ctx.options.force, self.inputs)
        self.staging = StagingFolder(self.out, "import", f"import {ctx.report.fmt}")
        self.tmp = self.staging.path
        self.writer: EventWriter | None = None
        self.events_ref: str = "events.h5"
        self.objects: list[ObjectSpec] = []
        self.trajectory_frame = "cam"
        self.hand_eye = None
        self._has_traj = False
        self._has_events = False

    def __enter__(self) -> "SceneBuilder":
        try:
            self.staging.create()
            (self.tmp / "models").mkdir()
        except OSError as exc:
            self.staging.abort()
            raise ImportFailure(self.out, "(output)", "--out", f"cannot create the scene folder "
                                f"({exc.strerror or exc})") from None
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()
            if isinstance(exc, OSError):
                failure = _output_failure(exc, self.out, self.tmp)
                if failure is not None:
                    raise failure from None

    def abort(self) -> None:
        if self.writer is not None:
            with contextlib.suppress(Exception):
                self.writer.abort()
            self.writer = None
        self.staging.abort()

    # ------------------------------------------------------------------ events
    def event_sink(self, width: int, height: int, expected_events: int | None = None) -> EventSink:
        """A sink that writes ``events.h5`` (int64 µs, Blosc-LZ4) in the scene."""
        self.writer = EventWriter(self.tmp / "events.h5", time_dtype="int64", compression=self.ctx.options.compression,
                                  cancel=self.ctx.cancelled, expected_events=expected_events)
        self._has_events = True
        return EventSink(self.ctx, self.writer, width, height)

    def finish_events(self, sink: EventSink, file) -> None:
        sink.close()
        if sink.n_out == 0:
            raise ImportFailure(file, "(all records)", "events", "no events (empty topic/file, or every event was "
                                "dropped: see the report)")
        if self.writer is not None:
            self.writer.close()
            self.writer = None
        self.ctx.report.details["events"] = {"n": sink.n_out, "t_first_us": sink.t_first, "t_last_us": sink.t_last,
                                             "x_range": [sink.x_min, sink.x_max], "y_range": [sink.y_min, sink.y_max]}

    def reference_events(self, src: Path, mode: str) -> None:
        """Use an existing event file: ``link`` (symlink ``events.h5`` -> absolute source) or ``reference``
        (absolute path in ``scene.toml``). The source is never modified."""
        src = Path(src).absolute()
        self.inputs.append(src)
        if mode == "link":
            os.symlink(src, self.tmp / "events.h5")
            self.events_ref = "events.h5"
        else:
            self.events_ref = str(src)
        self._has_events = True

    # ------------------------------------------------------------------ trajectory / objects
    def set_trajectory(self, traj: Trajectory, frame: str = "cam", hand_eye=None) -> None:
        traj.save_csv(self.tmp / "trajectory.csv")
        self.trajectory_frame, self.hand_eye = frame, hand_eye
        self._has_traj = True
        self.ctx.report.details["trajectory"] = {"n": len(traj), "frame": frame, "t_first_us": traj.t_first_us,
                                                 "t_last_us": traj.t_last_us}

    def add_cli_objects(self, objects: dict) -> None:
        """Add the ``--objects`` of a command (name -> (mesh, T_base_obj, class id, source)); warn
        when there are none (a scene without objects can be viewed but has nothing to label)."""
        for name, (mesh, T, cid, s) in objects.items():
            self.add_object(name, mesh, T, class_id=cid, source=s)
        if not objects:
            self.ctx.report.warn("no objects (give --objects name=mesh:T_base_obj.json)")

    def add_object(self, name: str, mesh, T_raw, *, residual: float = 0.0, mesh_scale: float = 1.0,
                   class_id: int = 0, symmetric: bool = False, source: str = "") -> None:
        """Add an object. ``mesh`` is a mesh file (copied verbatim, plus a sibling ``.mtl``) or a
        ``(vertices_m, faces)`` pair (written as PLY in metres). ``T_raw`` is ``T_base_obj`` as read; it is
        written unchanged, with ``repair_rotation = true`` when its residual exceeds the tolerance."""
        if any(o.name == name for o in self.objects):
            raise ImportFailure(source or "(objects)", name, "name", f"duplicate object name {name!r}")
        safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "object"
        if isinstance(mesh, tuple):
            import trimesh

            dst = self.tmp / "models" / f"{safe}.ply"
            trimesh.Trimesh(np.asarray(mesh[0]), np.asarray(mesh[1]), process=False).export(dst)
        else:
            src = Path(mesh)
            if not src.is_file():
                raise ImportFailure(src, name, "mesh", "mesh file not found")
            self.inputs.append(src)
            if src.suffix.lower() not in MESH_SUFFIXES:
                self.ctx.report.warn(f"{src}: mesh suffix {src.suffix!r} is not one of {MESH_SUFFIXES}; copied anyway")
            dst = self.tmp / "models" / f"{safe}{src.suffix.lower()}"
            shutil.copyfile(src, dst)
            if src.suffix.lower() == ".obj":
                for mtl in _obj_material_files(src):
                    if mtl.is_file() and not (dst.parent / mtl.name).exists():
                        shutil.copyfile(mtl, dst.parent / mtl.name)
        T_raw = np.asarray(T_raw, dtype=np.float64)
        R, res = orthonormalize(T_raw[:3, :3])
        T = make_T(R, T_raw[:3, 3])
        repair = bool(res > ROTATION_TOLERANCE)
        self.objects.append(ObjectSpec(name, dst, T, float(mesh_scale), int(class_id), bool(symmetric), repair,
                                       float(res), T_raw))
        self.ctx.report.details.setdefault("objects", {})[name] = {
            "mesh": f"models/{dst.name}", "mesh_source": str(mesh) if not isinstance(mesh, tuple) else "(generated)",
            "rotation_residual": float(res), "class_id": int(class_id), "T_base_obj": T_raw.tolist(),
            **({"source": source} if source else {})}

    def save_source_poses(self, t_us, tracks: dict[str, dict[int, np.ndarray]]) -> None:
        """Keep the object poses exactly as the source gave them (``source_poses.npz``: ``t_us`` (F,),
        ``names`` (K,), ``T_cam_obj`` (F, K, 4, 4), NaN where an object has no pose), so that the labels of an
        exported dataset can be compared with the scene's after correction."""
        names = list(tracks)
        T = np.full((len(t_us), len(names), 4, 4), np.nan)
        for j, nm in enumerate(names):
            for k, M in tracks[nm].items():
                T[k, j] = M
        with open(self.tmp / "source_poses.npz", "wb") as f:
            np.savez(f, t_us=np.asarray(t_us, np.int64), names=np.asarray(names), T_cam_obj=T)
        self.ctx.report.details["source_poses"] = "source_poses.npz (T_cam_obj per frame and object, as read)"

    # ------------------------------------------------------------------ commit
    def commit(self, camera: CameraModel, *, clock_offset_us: int = 0, clock_skew_ppm: float = 0.0,
               name: str | None = None) -> Path:
        """Write ``scene.toml`` and ``import_report.json``, check the manifest loads, rename into place."""
        import tomli_w

        if not self._has_events:
            raise ImportFailure(self.out, "(scene)", "events", "internal: no events were written")
        if not self._has_traj:
            raise ImportFailure(self.out, "(scene)", "trajectory", "internal: no trajectory was written")
        if self.ctx.options.offset_us is not None:
            self.ctx.report.assume(f"clock prior offset {int(self.ctx.options.offset_us)} µs (--offset-us)")
            clock_offset_us = int(self.ctx.options.offset_us)
        name = name or self.ctx.options.name or self.out.name
        specs = [ObjectSpec(o.name, o.mesh, o.T_base_obj, o.mesh_scale, o.class_id, o.symmetric, o.repair_rotation,
                            o.rotation_residual, o.T_base_obj_raw) for o in self.objects]
        manifest = SceneManifest(self.tmp / SCENE_FILENAME, name, camera, self.tmp / "events.h5",
                                 self.tmp / "trajectory.csv", self.trajectory_frame, self.hand_eye,
                                 int(clock_offset_us), float(clock_skew_ppm), specs)
        doc = manifest.to_toml_dict()
        doc["events"]["path"] = self.events_ref          # link/reference modes: never resolved through a symlink
        atomic_write_text(self.tmp / SCENE_FILENAME, tomli_w.dumps(doc))
        rep = self.ctx.report
        rep.details["runtime_s"] = time.perf_counter() - self.ctx.t_start
        rep.details["scene"] = {"name": name, "camera": camera.to_dict(), "clock": {
            "offset_us": int(clock_offset_us), "skew_ppm": float(clock_skew_ppm)}, "events_path": self.events_ref}
        atomic_write_text(self.tmp / REPORT_FILENAME, json.dumps(rep.to_dict(), indent=1, default=_json_default) + "\n")
        try:
            load_manifest(self.tmp)
        except SceneError as exc:
            raise ImportFailure(self.out / SCENE_FILENAME, "(manifest)", exc.field or "-",
                                f"the written manifest does not load: {exc}") from None
        self._place()
        return self.out

    def _place(self) -> None:
        from evpose.core.data.scene_folder import NotOurs

        try:
            self.staging.commit(self.inputs, self.ctx.options.force)
        except NotOurs as exc:
            raise ImportFailure(exc.path, "(output)", "--out", exc.reason) from None


def _obj_material_files(obj: Path) -> list[Path]:
    """``mtllib`` files referenced in the first KB of lines of an OBJ (plus ``<stem>.mtl``)."""
    out = [obj.with_suffix(".mtl")]
    try:
        with open(obj, "rb") as f:
            for _ in range(200):
                line = f.readline()
                if not line:
                    break
                if line.startswith(b"mtllib"):
                    for nm in line.split()[1:]:
                        out.append(obj.parent / nm.decode("utf-8", "replace"))
    except OSError:
        pass
    return out


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)


# ---------------------------------------------------------------------------------------------- camera files
def _yaml_scalar(tok: str):
    tok = tok.strip()
    if len(tok) >= 2 and tok[0] == tok[-1] and tok[0] in "'\"":
        return tok[1:-1]
    low = tok.lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("null", "~", ""):
        return None
    try:
        return int(tok)
    except ValueError:
        pass
    try:
        return float(tok)
    except ValueError:
        return tok


def _yaml_flow(text: str, file, lineno: int):
    """Parse a flow value: nested ``[a, b, [c]]`` lists or a scalar."""
    text = text.strip()
    if not text.startswith("["):
        if text.startswith("{"):
            raise ImportFailure(file, f"line {lineno}", "-", "YAML flow mappings ({...}) are not supported")
        return _yaml_scalar(text)
    pos = 0

    def parse():
        nonlocal pos
        assert text[pos] == "["
        pos += 1
        items, buf = [], ""
        while pos < len(text):
            c = text[pos]
            if c == "[":
                items.append(parse())
                buf = None
                continue
            if c in ",]":
                if buf is not None and buf.strip():
                    items.append(_yaml_scalar(buf))
                buf = ""
                pos += 1
                if c == "]":
                    return items
                continue
            if buf is None:
                buf = ""
            buf += c
            pos += 1
        raise ImportFailure(file, f"line {lineno}", "-", "unterminated [ list")

    val = parse()
    if text[pos:].strip():
        raise ImportFailure(file, f"line {lineno}", "-", f"unexpected text after list: {text[pos:]!r}")
    return val


def parse_yaml_subset(text: str, file) -> dict:
    """A small YAML subset, enough for calibration files (DSEC ``cam_to_cam.yaml``, Kalibr camchain):
    block mappings, block sequences (``- item``, also at the parent key's indent), flow lists ``[..]``,
    plain/quoted scalars and comments. Anything else raises :class:`ImportFailure` naming the line."""
    lines = []
    for i, raw in enumerate(text.splitlines(), start=1):
        s = raw.split(" #")[0].rstrip() if "#" in raw else raw.rstrip()
        if not s.strip() or s.lstrip().startswith("#") or s.startswith("%") or s.strip() in ("---", "..."):
            continue
        if "\t" in s[: len(s) - len(s.lstrip())]:
            raise ImportFailure(file, f"line {i}", "-", "tab indentation is not allowed in YAML")
        lines.append((i, len(s) - len(s.lstrip()), s.strip()))

    def block(k: int, indent: int):
        if lines[k][2].startswith("-") and (len(lines[k][2]) == 1 or lines[k][2][1] == " "):
            return seq(k, indent)
        return mapping(k, indent)

    def seq(k: int, indent: int):
        out = []
        while k < len(lines) and lines[k][1] == indent and lines[k][2].startswith("-"):
            ln, _, s = lines[k]
            item = s[1:].strip()
            if item:
                if re.match(r"^[^\[\]'\"]+:\s", item + " ") and not item.startswith("["):
                    raise ImportFailure(file, f"line {ln}", "-", "mappings inside sequences are not supported")
                out.append(_yaml_flow(item, file, ln))
                k += 1
            else:
                if k + 1 >= len(lines) or lines[k + 1][1] <= indent:
                    out.append(None)
                    k += 1
                else:
                    v, k = block(k + 1, lines[k + 1][1])
                    out.append(v)
        return out, k

    def mapping(k: int, indent: int):
        out = {}
        while k < len(lines) and lines[k][1] == indent:
            ln, _, s = lines[k]
            if s.startswith("- "):
                raise ImportFailure(file, f"line {ln}", "-", "sequence item where a mapping key was expected")
            m = re.match(r"""^("[^"]*"|'[^']*'|[^:]+?)\s*:(\s+(.*))?$""", s)
            if not m:
                raise ImportFailure(file, f"line {ln}", "-", f"expected 'key: value', got {s!r}")
            key = _yaml_scalar(m.group(1))
            rest = (m.group(3) or "").strip()
            if rest:
                if rest.startswith(("|", ">", "&", "*", "!")) and not rest.startswith("!!"):
                    raise ImportFailure(file, f"line {ln}", str(key), "block scalars, anchors and tags are not supported")
                out[key] = _yaml_flow(rest, file, ln)
                k += 1
            elif k + 1 < len(lines) and (lines[k + 1][1] > indent or (
                    lines[k + 1][1] == indent and lines[k + 1][2].startswith("-"))):
                out[key], k = block(k + 1, lines[k + 1][1])
            else:
                out[key] = None
                k += 1
        if k < len(lines) and lines[k][1] > indent:
            raise ImportFailure(file, f"line {lines[k][0]}", "-", "unexpected indentation")
        return out, k

    if not lines:
        raise ImportFailure(file, "(file)", "-", "empty YAML document")
    val, k = block(0, lines[0][1])
    if k < len(lines):
        raise ImportFailure(file, f"line {lines[k][0]}", "-", "unexpected indentation")
    if not isinstance(val, dict):
        raise ImportFailure(file, "(file)", "-", "expected a mapping at the top level")
    return val


def _size_from(d: dict, keys=("resolution", "img_size", "image_size")):
    for k in keys:
        if k in d and d[k] is not None:
            v = d[k]
            if isinstance(v, (list, tuple)) and len(v) == 2:
                return int(v[0]), int(v[1])
    if "width" in d and "height" in d:
        return int(d["width"]), int(d["height"])
    return None


def load_camera(path, ctx: ImportContext, *, default_size: tuple[int, int] | None = None) -> CameraModel:
    """Read a calibration file (format chosen by content), apply ``--width/--height``.

    Supported: our JSON (``K``, ``dist``, ``width``, ``height``); OpenCV/YCB-Ev JSON (``camera_matrix`` 3x3,
    ``distortion_coefficients`` (nested ok), ``img_size`` [w, h]); DSEC ``cam_to_cam.yaml`` / Kalibr YAML
    (``intrinsics: {camN: {camera_matrix: [fx, fy, cx, cy], distortion_coeffs, resolution}}`` or
    ``camN: {intrinsics: [fx, fy, cx, cy], distortion_coeffs, resolution}``, radtan/plumb_bob only); RPG
    ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``).
    """
    path = Path(path)
    opts = ctx.options
    with wrap_errors(path, "(file)", "-", "cannot read the calibration"):
        raw = path.read_bytes()
    text = raw.decode("utf-8", errors="replace")
    key = opts.camera_key
    size = None
    suffix = path.suffix.lower()
    try:
        if suffix == ".json":
            try:
                d = json.loads(text)
            except json.JSONDecodeError as exc:
                raise ImportFailure(path, f"line {exc.lineno}", "-", f"not valid JSON ({exc.msg})") from None
            if not isinstance(d, dict):
                raise ImportFailure(path, "(file)", "-", "expected a JSON object")
            if "K" in d:
                K, dist, size = d["K"], d.get("dist", []), _size_from(d)
                what = "evpose JSON"
            elif "camera_matrix" in d:
                K = np.asarray(d["camera_matrix"], dtype=np.float64)
                if K.size == 9:
                    K = K.reshape(3, 3)
                dist = np.asarray(d.get("distortion_coefficients", d.get("dist_coeffs", [])), dtype=np.float64).ravel()
                size = _size_from(d)
                what = "OpenCV JSON (camera_matrix)"
            elif "intrinsics" in d:
                K, dist, size, what = _dsec_intrinsics(d, key, path)
            else:
                raise ImportFailure(path, "(file)", "K", "no K / camera_matrix / intrinsics entry")
        elif suffix in (".yaml", ".yml"):
            d = parse_yaml_subset(text, path)
            K, dist, size, what = _dsec_intrinsics(d, key, path)
        else:
            vals = text.split()
            try:
                nums = [float(v) for v in vals]
            except ValueError:
                raise ImportFailure(path, "line 1", "fx", "expected 'fx fy cx cy [k1 k2 p1 p2 [k3]]' numbers") from None
            if len(nums) not in (4, 8, 9):
                raise ImportFailure(path, "line 1", "fx", f"expected 4, 8 or 9 numbers (fx fy cx cy k1 k2 p1 p2 k3), "
                                    f"got {len(nums)}")
            fx, fy, cx, cy = nums[:4]
            K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
            dist = nums[4:]
            what = "RPG calib.txt"
    except ImportFailure:
        raise
    except (TypeError, ValueError, KeyError) as exc:
        raise ImportFailure(path, "(file)", "-", f"malformed calibration ({exc})") from None
    if opts.width and opts.height:
        if size and tuple(size) != (opts.width, opts.height):
            ctx.report.warn(f"{path}: sensor size {size[0]}x{size[1]} overridden by --width/--height "
                            f"{opts.width}x{opts.height}")
        size = (int(opts.width), int(opts.height))
    if size is None:
        if default_size is None:
            raise ImportFailure(path, "(file)", "resolution", "no sensor size in the file; pass --width and --height")
        size = default_size
        ctx.report.assume(f"{path}: no sensor size in the calibration; assumed {size[0]}x{size[1]} "
                          "(override with --width/--height)")
    try:
        cam = CameraModel(K, dist, int(size[0]), int(size[1]), source=str(path))
    except CameraError as exc:
        raise ImportFailure(path, "(file)", "K/dist", str(exc).replace(f"{path}: ", "", 1)) from None
    ctx.report.details["camera_source"] = {"file": str(path), "format": what}
    return cam


def _dsec_intrinsics(d: dict, key: str, path):
    """DSEC cam_to_cam / Kalibr style -> (K, dist, size, description)."""
    if "intrinsics" in d and isinstance(d["intrinsics"], dict):
        cams = d["intrinsics"]
        if key not in cams:
            raise ImportFailure(path, "intrinsics", key, f"no camera {key!r} (have {', '.join(map(str, cams))}); "
                                "choose one with --camera-key")
        c = cams[key]
        fld = f"intrinsics.{key}"
        cm = c.get("camera_matrix") if isinstance(c, dict) else None
    elif key in d and isinstance(d[key], dict):
        c = d[key]
        fld = key
        cm = c.get("intrinsics")
    else:
        raise ImportFailure(path, "(file)", "intrinsics", f"no 'intrinsics' mapping and no camera {key!r}")
    if not isinstance(c, dict) or cm is None:
        raise ImportFailure(path, fld, "camera_matrix", "missing")
    cm = np.asarray(cm, dtype=np.float64).ravel()
    if cm.size == 4:
        K = [[cm[0], 0, cm[2]], [0, cm[1], cm[3]], [0, 0, 1]]
    elif cm.size == 9:
        K = cm.reshape(3, 3)
    else:
        raise ImportFailure(path, fld, "camera_matrix", f"expected [fx, fy, cx, cy], got {cm.size} numbers")
    model = str(c.get("distortion_model", "radtan")).lower()
    if model not in ("radtan", "plumb_bob", "pinhole", "none"):
        raise ImportFailure(path, fld, "distortion_model", f"{model!r} is not supported (only radtan/plumb_bob)")
    dist = np.asarray(c.get("distortion_coeffs") or [], dtype=np.float64).ravel()
    return K, dist, _size_from(c), f"YAML intrinsics ({fld})"


# ---------------------------------------------------------------------------------------------- objects
@dataclass
class ObjectArg:
    """One ``name=mesh[:T.json]`` entry of ``--objects``."""

    name: str
    mesh: Path | None
    T_raw: np.ndarray | None
    T_file: Path | None = None


def parse_objects_arg(spec, ctx: ImportContext) -> list[ObjectArg]:
    """``"name=mesh.obj:T.json,name2=mesh2.ply"`` (the T file: a 4x4 JSON list or ``{"T_base_obj": ...}``,
    or a 16-number text file). ``spec`` may also be a list of such strings."""
    if not spec:
        return []
    items = spec if isinstance(spec, (list, tuple)) else [s for s in str(spec).split(",")]
    out = []
    for item in (s.strip() for s in items):
        if not item:
            continue
        if "=" not in item:
            raise ImportFailure("--objects", item, "name", "expected name=mesh[:T_base_obj.json]")
        name, rest = item.split("=", 1)
        mesh_s, T_s = rest, None
        if ":" in rest:
            mesh_s, T_s = rest.rsplit(":", 1)
        mesh = Path(mesh_s).expanduser() if mesh_s else None
        T_raw = None
        T_file = None
        if T_s:
            T_file = Path(T_s).expanduser()
            with wrap_errors(T_file, "(file)", "T_base_obj", "cannot read"):
                text = T_file.read_text()
            try:
                d = json.loads(text)
                if isinstance(d, dict):
                    d = d.get("T_base_obj", d.get("T"))
            except json.JSONDecodeError:
                try:
                    d = [float(v) for v in text.replace(",", " ").split()]
                except ValueError:
                    raise ImportFailure(T_file, "(file)", "T_base_obj", "expected a 4x4 JSON list or 16 numbers") from None
            try:
                T_raw = np.asarray(d, dtype=np.float64)
            except (TypeError, ValueError):
                raise ImportFailure(T_file, "(file)", "T_base_obj", "not a numeric 4x4 matrix") from None
            if T_raw.size == 16:
                T_raw = T_raw.reshape(4, 4)
            check_T(T_raw, ctx, T_file, "(file)", "T_base_obj")
        out.append(ObjectArg(name.strip(), mesh, T_raw, T_file))
    return out


# ---------------------------------------------------------------------------------------------- pose text
_POSE_COLS = ("t", "x", "y", "z", "qx", "qy", "qz", "qw")
_HEADER_ALIASES = {
    "t": ("t_us", "t", "time", "timestamp", "ts", "t_s", "t_ns", "#timestamp", "# timestamp", "#time"),
    "x": ("x", "px", "tx", "p_x", "pos_x"), "y": ("y", "py", "ty", "p_y", "pos_y"),
    "z": ("z", "pz", "tz", "p_z", "pos_z"),
    "qx": ("qx", "q_x", "rx"), "qy": ("qy", "q_y", "ry"), "qz": ("qz", "q_z", "rz"), "qw": ("qw", "q_w", "rw"),
}
_UNIT_FROM_TIME_HEADER = {"t_us": "us", "t_s": "s", "t_ns": "ns", "t_ms": "ms"}


def read_pose_text(path, ctx: ImportContext, *, declared_unit: str | None = None, what: str = "trajectory"):
    """Read a pose file: ``t x y z qx qy qz qw`` per line (whitespace or comma separated; TUM / RPG
    ``groundtruth.txt``), optionally with a header line naming the columns (any order; our
    ``t_us,x,y,z,qx,qy,qz,qw`` CSV). Lines starting with ``#`` or ``//`` are comments (a comment line that names
    the columns counts as the header).

    Times are converted exactly from their decimal text (round half up); the unit comes from the header
    (``t_us``/``t_s``/``t_ns``), ``--time-unit``, the format's ``declared_unit`` when plausible, or a guess from
    the sampling period (all reported).

    Returns a :class:`Trajectory` (validated by :func:`make_trajectory`).
    """
    path = Path(path)
    with wrap_errors(path, "(file)", "-", "cannot read"):
        text = path.read_bytes().decode("utf-8")
    cols = None
    rows: list[list[str]] = []
    line_nos: list[int] = []
    unit_hdr = None
    for ln, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s:
            continue
        is_comment = s.startswith(("#", "//"))
        toks = [t for t in re.split(r"[,\s]+", s.lstrip("#/").strip()) if t]
        if cols is None and not rows and toks and any(re.search(r"[a-df-zA-DF-Z_]", t) for t in toks) and not all(
                _is_number(t) for t in toks):
            names = [t.strip().lower() for t in toks]
            mapping = {}
            for key, aliases in _HEADER_ALIASES.items():
                for j, nm in enumerate(names):
                    if nm in aliases:
                        mapping[key] = j
                        break
            if len(mapping) == 8:
                cols = [mapping[k] for k in _POSE_COLS]
                unit_hdr = _UNIT_FROM_TIME_HEADER.get(names[mapping["t"]])
                continue
            if not is_comment:
                raise ImportFailure(path, f"line {ln}", "header", f"cannot map columns {toks} to "
                                    f"{','.join(_POSE_COLS)}")
            continue
        if is_comment:
            continue
        rows.append(toks)
        line_nos.append(ln)
    if not rows:
        raise ImportFailure(path, "(file)", "t", f"no pose samples in the {what} file")
    cols = cols or list(range(8))
    need = max(cols) + 1
    vals = np.empty((len(rows), 7))
    t_tok = []
    for i, toks in enumerate(rows):
        if len(toks) < need:
            raise ImportFailure(path, f"line {line_nos[i]}", "-", f"expected {need} columns, got {len(toks)}")
        t_tok.append(toks[cols[0]])
        for j, c in enumerate(cols[1:]):
            try:
                vals[i, j] = float(toks[c])
            except ValueError:
                raise ImportFailure(path, f"line {line_nos[i]}", _POSE_COLS[j + 1],
                                    f"not a number ({toks[c]!r})") from None
    t_float = np.empty(len(t_tok))
    for i, tok in enumerate(t_tok):
        try:
            t_float[i] = float(tok)
        except ValueError:
            raise ImportFailure(path, f"line {line_nos[i]}", "t", f"not a number ({tok!r})") from None
        if not math.isfinite(t_float[i]):
            raise ImportFailure(path, f"line {line_nos[i]}", "t", f"not finite ({tok!r})")
    if unit_hdr is not None and ctx.options.time_unit is None:
        unit = unit_hdr
        ctx.report.details.setdefault("time_units", {})[f"{path.name}"] = {"unit": unit, "why": "column header"}
    else:
        unit = resolve_time_unit(ctx, t_float, what=f"{path.name} (poses)", kind="poses", declared=declared_unit)
    t_us = np.empty(len(t_tok), np.int64)
    for i, tok in enumerate(t_tok):
        try:
            t_us[i] = decimal_to_us(tok, unit)
        except (ValueError, ZeroDivisionError, OverflowError):
            raise ImportFailure(path, f"line {line_nos[i]}", "t", f"not a decimal number ({tok!r})") from None
    return make_trajectory(ctx, path, t_us, vals[:, :3], vals[:, 3:], record_of=lambda i: f"line {line_nos[i]}")


def _is_number(tok: str) -> bool:
    try:
        float(tok)
        return True
    except ValueError:
        return False


# ---------------------------------------------------------------------------------------------- pose tracks
def chordal_mean(Ts: np.ndarray) -> np.ndarray:
    """Mean of rigid transforms: translations averaged, rotations by the chordal L2 mean (SVD projection)."""
    Ts = np.asarray(Ts, dtype=np.float64)
    if len(Ts) == 1:
        R, _ = orthonormalize(Ts[0, :3, :3])
        return make_T(R, Ts[0, :3, 3])
    R, _ = orthonormalize(Ts[:, :3, :3].mean(0))
    return make_T(R, Ts[:, :3, 3].mean(0))


def derive_camera_trajectory(ctx: ImportContext, file, t_us: np.ndarray, tracks: dict[str, dict[int, np.ndarray]],
                             known: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Camera poses from per-frame object poses in the camera, for a static scene.

    Parameters
    ----------
    t_us : (F,) int64
        Frame times.
    tracks : {object: {frame index: T_cam_obj (4, 4)}}
        As read (may be slightly non-orthonormal; inverted as general matrices so that labels made from a
        non-orthonormal ``T_base_obj`` give back the camera pose exactly).
    known : {object: T_base_obj (4, 4)}
        Object poses in the base frame, as given (raw). Without any, the base frame is the frame of the object
        seen in most frames (reported).

    Returns
    -------
    t_us : (M,) int64, T_base_cam : (M, 4, 4), T_base_obj : {object: (4, 4)} (known ones unchanged)
    """
    known = dict(known)
    if not known:
        anchor = max(tracks, key=lambda k: (len(tracks[k]), -list(tracks).index(k)))
        known[anchor] = np.eye(4)
        ctx.report.assume(f"no T_base_obj given: the base frame is the frame of object {anchor!r} "
                          f"(seen in {len(tracks[anchor])} of {len(t_us)} frames)")
    given = set(known)
    estimated: dict[str, np.ndarray] = {}

    def cam_at(k: int, objs) -> np.ndarray | None:
        ests = [known[o] @ np.linalg.inv(tracks[o][k]) for o in objs if k in tracks[o]]
        return chordal_mean(np.stack(ests)) if ests else None

    # camera poses from the given objects, then estimate the others from those frames, repeat until stable
    cams: dict[int, np.ndarray] = {}
    for _ in range(len(tracks) + 1):
        for k in range(len(t_us)):
            if k not in cams:
                c = cam_at(k, [o for o in known if o in tracks])
                if c is not None:
                    cams[k] = c
        progress = False
        for o, tr in tracks.items():
            if o in known:
                continue
            ks = [k for k in tr if k in cams]
            if ks:
                estimated[o] = chordal_mean(np.stack([cams[k] @ tr[k] for k in ks]))
                known[o] = estimated[o]
                progress = True
        if not progress:
            break
    # consistency of the static-scene assumption: spread of the per-object camera estimates
    spread_t, spread_r = [], []
    for k, c in cams.items():
        for o in tracks:
            if k in tracks[o] and o in known:
                e = known[o] @ np.linalg.inv(tracks[o][k])
                spread_t.append(float(np.linalg.norm(e[:3, 3] - c[:3, 3])))
                Re, _ = orthonormalize(e[:3, :3])
                spread_r.append(float(rotation_angle(c[:3, :3].T @ Re)))
    missing = [k for k in range(len(t_us)) if k not in cams]
    if missing:
        ctx.report.warn(f"{file}: {len(missing)} frame(s) without any object pose give no camera pose "
                        f"(first: frame {missing[0]})")
    for o in estimated:
        ctx.report.assume(f"T_base_obj of {o!r} estimated as the mean over {len(tracks[o])} frame(s) (static scene)")
    if spread_t:
        ctx.report.details["camera_from_objects"] = {
            "max_disagreement_mm": 1e3 * max(spread_t), "max_disagreement_deg": math.degrees(max(spread_r)),
            "median_disagreement_mm": 1e3 * float(np.median(spread_t)), "objects_given": sorted(given)}
        if max(spread_t) > 2e-3 or math.degrees(max(spread_r)) > 0.5:
            ctx.report.warn(f"{file}: object poses disagree about the camera pose by up to {1e3 * max(spread_t):.2f} mm "
                            f"/ {math.degrees(max(spread_r)):.3f} deg (the scene is not static, or T_base_obj is off)")
    ks = sorted(cams)
    T = np.stack([cams[k] for k in ks]) if ks else np.zeros((0, 4, 4))
    return np.asarray(t_us, np.int64)[ks], T, known


def result_summary(ctx: ImportContext, out: Path) -> dict:
    """The JSON summary printed by ``evpose import --json`` and returned by the API."""
    r = ctx.report
    return {"scene": str(out), "format": r.fmt, "n_events": r.counts.get("events_written"),
            "n_poses": r.details.get("trajectory", {}).get("n"),
            "objects": list(r.details.get("objects", {})), "report": str(Path(out) / REPORT_FILENAME),
            "assumptions": r.assumptions, "repairs": r.repairs, "warnings": r.warnings,
            "runtime_s": time.perf_counter() - ctx.t_start}


__all__ = ["ImportFailure", "ImportOptions", "ImportContext", "ImportReport", "EventSink", "SceneBuilder",
           "wrap_errors", "guess_time_unit", "resolve_time_unit", "float_to_us", "int_to_us", "decimal_to_us",
           "ros_time_to_us", "check_T", "make_trajectory", "read_pose_text", "poses_from_matrices", "load_camera", "parse_yaml_subset",
           "parse_objects_arg", "derive_camera_trajectory", "chordal_mean", "REPORT_FILENAME"]
