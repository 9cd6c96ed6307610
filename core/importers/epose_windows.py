"""The windows of an E-POSE export read in order: events streamed, label times and pose blocks collected.

Windows were cut with closed intervals, so consecutive windows share the events stamped exactly at their
boundary: for windows ``k`` and ``k+1`` (consecutive numbers) the rows of ``k+1`` with ``t`` equal to the last
time of ``k`` that also appear (same ``x, y, t, p``, as a multiset) among those rows of ``k`` are dropped --
exactly those, counted in the report (:class:`BoundaryDedup`).
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from evpose.core.data.geometry import ROTATION_TOLERANCE
from evpose.core.importers.epose_assets import EPOSE_PUBLISHED_TOLERANCE
from evpose.core.importers.epose_mat import K_of, events_of, load_window
from evpose.core.importers.event_sink import EventSink
from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.pose_checks import check_T
from evpose.core.importers.report import ImportContext
from evpose.core.importers.time_guess import resolve_time_unit
from evpose.core.importers.time_units import float_to_us


class BoundaryDedup:
    """Drops the boundary events window ``k+1`` shares with window ``k`` (see the module docstring)."""

    def __init__(self):
        self.prev_k: int | None = None
        self.prev_tail = None          # (t, x, y, p) of the previous window's events at its last time
        self.n_dropped = 0

    def __call__(self, k: int, x, y, t, p):
        """The events of window ``k`` without those shared with window ``k - 1``."""
        if len(t) and self.prev_tail is not None and self.prev_k == k - 1 and len(self.prev_tail[0]):
            drop = self._shared(x, y, t, p)
            if drop:
                keep = np.ones(len(t), bool)
                keep[drop] = False
                x, y, t, p = x[keep], y[keep], t[keep], p[keep]
                self.n_dropped += len(drop)
        if len(t):
            m = t == int(t.max())
            self.prev_tail = (t[m], x[m].astype(float), y[m].astype(float), p[m].astype(float))
        elif self.prev_k != k - 1:
            self.prev_tail = None
        self.prev_k = k
        return x, y, t, p

    def _shared(self, x, y, t, p) -> list[int]:
        """Rows at the previous window's last time that match its rows there, each match used once."""
        tb, px, py, pp = self.prev_tail
        avail = Counter(zip(px.tolist(), py.tolist(), pp.tolist()))
        drop = []
        for j in np.flatnonzero(t == tb[0]):
            key = (float(x[j]), float(y[j]), float(p[j]))
            if avail.get(key, 0) > 0:
                avail[key] -= 1
                drop.append(j)
        return drop


class ExportWindows:
    """State carried across the windows of one export: the time unit, the boundary events, the label times,
    the pose tracks ``{object: {window index: T_cam_obj}}`` and what goes into the report."""

    def __init__(self, ctx: ImportContext, first: dict, K, object_names, cls_map: dict[int, str]):
        self.ctx, self.first, self.K, self.cls_map = ctx, first, K, cls_map
        self.scene_names = list(object_names)
        self.tracks: dict[str, dict[int, np.ndarray]] = {}
        self.t_windows: list[int] = []
        self.n_time_fallback = 0
        self.unit: str | None = None
        self.lags: list[int] = []
        self.state: dict = {}
        self.block_names: list[str] | None = None
        self.res_max, self.res_where, self.n_proj = 0.0, "", 0
        self.dedup = BoundaryDedup()

    def read(self, wi: int, k: int, path: Path, sink: EventSink) -> None:
        """Window number ``k`` (``wi``-th in order): events into ``sink``, its label time and pose blocks kept."""
        self.ctx.check_cancel()
        d = self.first if wi == 0 else load_window(path)
        if wi and "intrinsicMatrix" in d:
            self._check_K(d, path)
        rec = f"window {k}"
        x, y, t, p = self._events(d, path, rec)
        x, y, t, p = self.dedup(k, x, y, t, p)
        sink.add(x, y, t, p, file=path, record=rec)
        tw = self._label_time(d, path, rec, t)
        self._poses(d, path, rec, tw)

    def _check_K(self, d: dict, path: Path) -> None:
        K_first = self.first.get("intrinsicMatrix")
        same = (K_first is not None and K_first.shape == d["intrinsicMatrix"].shape
                and np.allclose(d["intrinsicMatrix"], K_first))
        K2 = self.K if same else K_of(d, path, self.ctx.report)
        if self.K is not None and K2 is not None and not np.allclose(K2, self.K, atol=1e-9):
            self.ctx.report.warn(f"{path.name}: intrinsicMatrix differs from the first window's")

    def _events(self, d: dict, path: Path, rec: str):
        """``x, y`` (0-based), ``t`` (int64 µs), ``p`` of the window; the unit is decided on the first events."""
        e = events_of(d, path, self.ctx.report, self.state)
        if not np.all(np.isfinite(e)):
            r, c = np.argwhere(~np.isfinite(e))[0]
            raise ImportFailure(path, f"{rec}, event row {r}", "events(:, %d) [%s]" % (c + 1, "xytp"[c]),
                                f"not finite ({e[r, c]})")
        if len(e) and self.unit is None:
            self.unit = resolve_time_unit(self.ctx, e[:, 2], what="events t (.mat)", kind="events")
        with wrap_errors(path, rec, "events(:, 3) [t]"):
            t = float_to_us(e[:, 2], self.unit or "s") if len(e) else np.empty(0, np.int64)
        x, y, p = e[:, 0], e[:, 1], e[:, 3]
        if self.ctx.options.one_based:
            x, y = x - 1, y - 1
        return x, y, t, p

    def _label_time(self, d: dict, path: Path, rec: str, t) -> int | None:
        """The window's ``time`` in µs; without one, its last event time (counted); None for an empty window."""
        tm = d.get("time")
        if tm is not None and tm.size >= 1 and np.isfinite(tm.reshape(-1)[0]):
            with wrap_errors(path, rec, "time"):
                tw = int(float_to_us(tm.reshape(-1)[:1], self.unit or "s")[0])
            if len(t):
                self.lags.append(tw - int(t.max()))
            return tw
        if tm is not None and tm.size >= 1:
            raise ImportFailure(path, rec, "time", f"not finite ({tm.reshape(-1)[0]})")
        if len(t):
            self.n_time_fallback += 1
            return int(t.max())
        return None

    def _poses(self, d: dict, path: Path, rec: str, tw: int | None) -> None:
        """The ``pose`` blocks ``T_cam_obj`` at label time ``tw``, checked (published tolerance) and kept as read."""
        P = d.get("pose")
        if P is None or not P.size or tw is None:
            return
        if P.ndim != 2 or P.shape[0] != 4 or P.shape[1] % 4:
            raise ImportFailure(path, rec, "pose", f"expected (4, 4k), got shape {P.shape}")
        names = self._block_names(d, path, rec, P.shape[1] // 4)
        if tw in self.t_windows:
            raise ImportFailure(path, rec, "time", f"label time {tw} µs repeats an earlier window's")
        widx = len(self.t_windows)
        self.t_windows.append(tw)
        for j, nm in enumerate(names):
            B = P[:, 4 * j:4 * j + 4]
            if not np.all(np.isfinite(B)):
                self.ctx.report.count("pose_blocks_not_finite")
                continue
            _, res = check_T(B, self.ctx, path, rec, f"pose(:, {4 * j + 1}:{4 * j + 4}) [{nm}]", quiet=True,
                             tolerance=EPOSE_PUBLISHED_TOLERANCE)
            if res > self.res_max:
                self.res_max, self.res_where = res, f"{path.name} {nm}"
            self.n_proj += res > ROTATION_TOLERANCE
            self.tracks.setdefault(nm, {})[widx] = B

    def _block_names(self, d: dict, path: Path, rec: str, nb: int) -> list[str]:
        """Object name of each pose block: ``--classes``, else the given objects in order, else ``cls_<index>``."""
        cls = d.get("cls_index")
        cls = cls.ravel() if cls is not None else np.arange(1, nb + 1, dtype=float)
        if len(cls) != nb:
            raise ImportFailure(path, rec, "cls_index", f"{len(cls)} classes for {nb} pose blocks")
        if not np.all(np.isfinite(cls)):
            raise ImportFailure(path, rec, "cls_index", f"not finite ({cls.tolist()})")
        by_order = not self.cls_map and nb == len(self.scene_names)
        names = []
        for j, c in enumerate(cls):
            ci = int(c)
            if ci in self.cls_map:
                names.append(self.cls_map[ci])
            elif by_order:
                names.append(self.scene_names[j])
            else:
                names.append(f"cls_{ci}")
        if self.block_names is None:
            self.block_names = names
            if by_order:
                self.ctx.report.assume("pose blocks in the order of the objects (--assets/--scene, --objects): "
                                       + ", ".join(f"block {j} (cls_index {int(c)}) = {n}"
                                                   for j, (c, n) in enumerate(zip(cls, names))))
        if len(set(names)) != len(names):
            raise ImportFailure(path, rec, "cls_index", f"two pose blocks map to the same object: {names}")
        return names

    def report(self) -> None:
        """Counters and summaries of all windows into the import report."""
        rep = self.ctx.report
        if self.dedup.n_dropped:
            rep.repair(f"dropped {self.dedup.n_dropped} boundary event(s) duplicated in consecutive windows")
            rep.counts["events_boundary_duplicates"] = self.dedup.n_dropped
        if self.n_time_fallback:
            rep.assume(f"{self.n_time_fallback} window(s) without 'time': label time = last event time")
        if self.lags:
            lg = np.asarray(self.lags)
            rep.details["label_time_minus_last_event_us"] = {"median": float(np.median(lg)), "min": int(lg.min()),
                                                              "max": int(lg.max())}
        if self.res_max > 1e-9:
            (rep.repair if self.n_proj else rep.assume)(f"pose blocks: rotations not orthonormal up to residual "
                                                        f"{self.res_max:.3g} ({self.res_where})")
