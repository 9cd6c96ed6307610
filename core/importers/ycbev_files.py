"""The files of a YCB-Ev sequence: where they are, the JSON annotations, and the zstd event stream.

Missing pieces are looked up beside the sequence folder as the published layout has them:
``<parent>/<seq>_events.int32.zst``, ``<parent>/calib_prophesee.json``, ``<parent>/calib_stereo_c2ev.json``,
``<parent>/ycbv_models/models_eval/obj_XXXXXX.ply``.

Event file (as ``ycbev.load_event_data`` of the authors' repository reads it): a zstd stream (one or more
frames) of little-endian int32 pairs ``[t, packed]`` with ``t`` in µs from the recording start and
``packed = x | y << 14 | p << 28`` (x, y: 14 bits each; p: 4 bits, 0/1). It is decompressed as a stream
(bounded memory); a truncated frame is an error.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.report import ImportContext

XMASK, YSHIFT, PSHIFT = 0x3FFF, 14, 28
#: YCB-Video object ids (BOP ycbv) -> names.
YCBV_NAMES = {1: "master_chef_can", 2: "cracker_box", 3: "sugar_box", 4: "tomato_soup_can", 5: "mustard_bottle",
              6: "tuna_fish_can", 7: "pudding_box", 8: "gelatin_box", 9: "potted_meat_can", 10: "banana",
              11: "pitcher_base", 12: "bleach_cleanser", 13: "bowl", 14: "mug", 15: "power_drill", 16: "wood_block",
              17: "scissors", 18: "large_marker", 19: "large_clamp", 20: "extra_large_clamp", 21: "foam_brick"}
_READ = 1 << 20


def pack_events(t_us, x, y, p) -> bytes:
    """Raw (uncompressed) bytes of the YCB-Ev event layout (for tests and converters)."""
    d = np.empty((len(t_us), 2), "<i4")
    d[:, 0] = t_us
    d[:, 1] = (np.asarray(x, np.int32) & XMASK) | ((np.asarray(y, np.int32) & XMASK) << YSHIFT) | (
        (np.asarray(p, np.int32) & 0xF) << PSHIFT)
    return d.tobytes()


def iter_event_file(path: Path, ctx: ImportContext, chunk_events: int = 1 << 20):
    """Yield ``(index of first event, int32 array (n, 2), compressed bytes read)`` from a zstd event file,
    streamed frame by frame."""
    import zstandard

    dctx = zstandard.ZstdDecompressor()
    with wrap_errors(path, "(file)", "-", "cannot open"):
        f = open(path, "rb")
    with f:
        dobj, in_frame = dctx.decompressobj(), False
        pending = bytearray()
        n_done, pos = 0, 0
        rec_bytes = 8 * chunk_events
        while True:
            ctx.check_cancel()
            with wrap_errors(path, f"byte {pos}", "-", "cannot read"):
                data = f.read(_READ)
            if not data:
                break
            pos += len(data)
            while data:
                with wrap_errors(path, f"compressed byte ~{pos}", "zstd", "corrupt zstd stream"):
                    pending += dobj.decompress(data)
                in_frame = True
                data = b""
                if dobj.eof:
                    data = dobj.unused_data
                    dobj, in_frame = dctx.decompressobj(), False
            while len(pending) >= rec_bytes:
                yield n_done, np.frombuffer(bytes(pending[:rec_bytes]), "<i4").reshape(-1, 2), pos
                del pending[:rec_bytes]
                n_done += chunk_events
        if in_frame and not dobj.eof:
            raise ImportFailure(path, f"event {n_done + len(pending) // 8}", "zstd",
                                "the compressed stream ends inside a frame (truncated file)")
        if len(pending) % 8:
            raise ImportFailure(path, f"event {n_done + len(pending) // 8}", "t/packed",
                                f"{len(pending) % 8} trailing byte(s): the data is not int32 pairs")
        if pending:
            yield n_done, np.frombuffer(bytes(pending), "<i4").reshape(-1, 2), pos



def read_json(path: Path):
    """A JSON file; invalid JSON is refused naming the line."""
    with wrap_errors(path, "(file)", "-", "cannot read"):
        text = path.read_bytes().decode("utf-8")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ImportFailure(path, f"line {exc.lineno}", "-", f"not valid JSON ({exc.msg})") from None
    except RecursionError:
        raise ImportFailure(path, "(file)", "-", "JSON nested too deeply") from None



def locate(sources, ctx: ImportContext) -> dict:
    """Role -> path of every file of the sequence: ``gt``, ``events``, ``scene_camera``, ``times``, ``camera``,
    ``c2ev`` (given) or ``c2ev_auto`` (found), ``models`` (a folder)."""
    found: dict[str, Path] = {}
    folders = []
    for s in map(Path, sources):
        if s.is_dir():
            folders.append(s)
            for nm, role in (("scene_gt.json", "gt"), ("scene_camera.json", "scene_camera"),
                             ("scene_times.json", "times")):
                if (s / nm).is_file():
                    found.setdefault(role, s / nm)
        elif s.is_file():
            if _classify_file(s, found):
                folders.append(s.parent)
        else:
            raise ImportFailure(s, "(file)", "SRC", "no such file or folder")
    for d in folders:
        _look_beside(d, found, ctx)
    return found


def _classify_file(s: Path, found: dict) -> bool:
    """Put a source file under its role; True for ``scene_gt.json`` (its folder is the sequence)."""
    nm = s.name
    if nm.endswith(".zst"):
        found["events"] = s
    elif nm == "scene_gt.json":
        found["gt"] = s
        return True
    elif nm == "scene_camera.json":
        found["scene_camera"] = s
    elif nm == "scene_times.json":
        found["times"] = s
    elif nm.endswith(".json"):
        d = read_json(s)
        if isinstance(d, dict) and "R_c2ev" in d:
            found["c2ev"] = s
        elif isinstance(d, dict) and ("camera_matrix" in d or "K" in d):
            found["camera"] = s
        else:
            raise ImportFailure(s, "(file)", "SRC", "unknown JSON (expected scene_gt/scene_camera/"
                                "calibration)")
    else:
        raise ImportFailure(s, "(file)", "SRC", "unknown role (expected a sequence folder, *.zst, *.json)")
    return False


def _look_beside(d: Path, found: dict, ctx: ImportContext) -> None:
    """The pieces the published layout keeps in or beside the sequence folder ``d``, unless given."""
    for nm, role in (("scene_camera.json", "scene_camera"), ("scene_times.json", "times")):
        if (d / nm).is_file():
            found.setdefault(role, d / nm)
    par = d.parent
    if "events" not in found:
        for c in (par / f"{d.name}_events.int32.zst", d / "events.int32.zst"):
            if c.is_file():
                found["events"] = c
                ctx.report.assume(f"event file found beside the sequence: {c}")
                break
    if "camera" not in found and (par / "calib_prophesee.json").is_file():
        found["camera"] = par / "calib_prophesee.json"
    if "c2ev" not in found and (par / "calib_stereo_c2ev.json").is_file():
        found["c2ev_auto"] = par / "calib_stereo_c2ev.json"
    if "models" not in found:
        for c in (par / "ycbv_models" / "models_eval", par / "models_eval", par / "models"):
            if c.is_dir():
                found["models"] = c
                break
