"""Event Camera Dataset (RPG, Mueggler et al.) text layout (``evpose import rpg``).

Sources: a sequence folder, or the files themselves:

* ``events.txt``: one event per line, ``t x y p`` (t in seconds as a decimal, e.g. ``0.000051000 33 39 1``);
* ``groundtruth.txt``: ``t px py pz qx qy qz qw`` (seconds, metres, quaternion x y z w) = ``T_base_cam`` (without it
  the scene is event-only: no trajectory, no objects);
* ``calib.txt``: ``fx fy cx cy k1 k2 p1 p2 k3`` (sensor size not in the file: DAVIS240C 240x180 assumed unless
  ``--width/--height`` or ``--camera``).

``events.txt`` is parsed exactly in streamed blocks (:mod:`evpose.core.importers.rpg_text`); a block with
exponents, NaN or very long numbers is parsed in float64 instead (reported: exact only to float64 precision), and
NaN/inf there is an error naming the line. Lines starting with ``#`` are comments. The time unit is checked
against the event rate (``--time-unit`` to force it): the format says seconds.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from evpose.core.importers.calibration import load_camera
from evpose.core.importers.event_sink import EventSink
from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.pose_text import read_pose_text
from evpose.core.importers.report import ImportContext, result_summary
from evpose.core.importers.rpg_text import (
    NotPlainDecimal,
    fallback_block,
    iter_text_blocks,
    mantissa_to_us,
    parse_columns,
    strip_comments,
)
from evpose.core.importers.scene_builder import SceneBuilder, events_only
from evpose.core.importers.time_guess import resolve_time_unit
from evpose.core.importers.time_units import float_to_us


def _find(sources, names) -> dict:
    """Role -> path: the files named ``names`` in the source folders, or the source files by their names."""
    found = {}
    for s in map(Path, sources):
        if s.is_dir():
            for role, nm in names.items():
                if (s / nm).is_file() and role not in found:
                    found[role] = s / nm
        elif s.is_file():
            for role, nm in names.items():
                if s.name == nm or (role == "events" and s.name.startswith("events") and s.suffix == ".txt"):
                    found[role] = s
                    break
            else:
                raise ImportFailure(s, "(file)", "SRC", f"unknown role (expected {', '.join(names.values())})")
        else:
            raise ImportFailure(s, "(file)", "SRC", "no such file or folder")
    return found


def import_rpg(sources, out, ctx: ImportContext) -> dict:
    """Import an Event Camera Dataset sequence into a scene folder; returns the summary."""
    opts, rep = ctx.options, ctx.report
    found = _find(sources, {"events": "events.txt", "trajectory": "groundtruth.txt", "camera": "calib.txt"})
    if "events" not in found:
        raise ImportFailure(", ".join(map(str, sources)), "(arguments)", "events", "no events.txt among the sources")
    cam_file = opts.camera or found.get("camera")
    if cam_file is None:
        raise ImportFailure(", ".join(map(str, sources)), "(arguments)", "camera", "no calib.txt and no --camera")
    camera = load_camera(cam_file, ctx, default_size=(240, 180))
    objects = collect_objects(ctx, None)
    ev = found["events"]
    traj = None
    if "trajectory" not in found:         # no groundtruth.txt: an event-only scene
        events_only(ctx, ev, objects)
    else:
        traj = read_pose_text(found["trajectory"], ctx, declared_unit="s", what="groundtruth")
    with SceneBuilder(out, ctx) as sb:
        sink = sb.event_sink(camera.width, camera.height)
        n_fallback = _stream_events(ctx, ev, sink)
        if n_fallback:
            rep.assume(f"{ev.name}: {n_fallback} block(s) with exponents/NaN/long numbers parsed as float64 "
                       "(times exact only to float64 precision there)")
        sb.finish_events(sink, ev)
        if traj is not None:
            sb.set_trajectory(traj, "cam")
            rep.assume("groundtruth.txt is the camera pose in the world/base frame (T_base_cam, metres)")
            sb.add_cli_objects(objects)
        sb.commit(camera)
    ctx.progress(1.0, "done")
    return result_summary(ctx, sb.out)


def _stream_events(ctx: ImportContext, ev: Path, sink: EventSink) -> int:
    """``events.txt`` block by block into ``sink``; returns the number of blocks parsed in float64."""
    size = ev.stat().st_size
    unit = None
    n_fallback = 0
    done = 0
    for line0, block in iter_text_blocks(ev, ctx):
        done += len(block)
        block = strip_comments(block)
        try:
            mant, ndec = parse_columns(block, 4, file=ev, line0=line0, int_cols=(1, 2, 3))
            floats = None
        except NotPlainDecimal:
            floats = fallback_block(block, ev, line0, 4)
            n_fallback += 1
        if floats is None and len(mant) == 0:
            continue
        if floats is not None and len(floats) == 0:
            continue
        if unit is None:
            sample = floats[:, 0] if floats is not None else mant[:, 0] / np.power(10.0, ndec[:, 0])
            unit = resolve_time_unit(ctx, sample, what=f"{ev.name} (events)", kind="events", declared="s")
        rec = f"lines {line0}+"
        if floats is None:
            with wrap_errors(ev, rec, "t"):
                t = mantissa_to_us(mant[:, 0], ndec[:, 0], unit)
            sink.add(mant[:, 1], mant[:, 2], t, mant[:, 3], file=ev, record=rec)
        else:
            _add_float_block(floats, block, line0, unit, ev, sink)
        ctx.progress(0.97 * done / max(size, 1), f"{done / 1e6:.0f}/{size / 1e6:.0f} MB")
    return n_fallback


def _add_float_block(floats: np.ndarray, block: bytes, line0: int, unit: str, ev: Path, sink: EventSink) -> None:
    """A block parsed in float64: NaN/inf refused naming the line, times converted (round half up)."""
    rec = f"lines {line0}+"
    bad = ~np.isfinite(floats)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        # line number of row r: count non-empty lines
        lines = [i for i, ln in enumerate(block.split(b"\n")) if ln.strip()]
        raise ImportFailure(ev, f"line {line0 + lines[r]}", "tpxy"[0] if c == 0 else "xyp"[c - 1],
                            f"not finite ({floats[r, c]})")
    with wrap_errors(ev, rec, "t"):
        tu = float_to_us(floats[:, 0], unit)
    sink.add(floats[:, 1], floats[:, 2], tu, floats[:, 3], file=ev, record=rec)
