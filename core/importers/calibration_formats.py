"""The calibration file formats an import reads, each to ``(K, dist, size or None, description)``.

* our JSON (``K``, ``dist``, ``width``, ``height``) and OpenCV/YCB-Ev JSON (``camera_matrix`` 3x3,
  ``distortion_coefficients`` (nested ok), ``img_size`` [w, h]);
* DSEC ``cam_to_cam.yaml`` / Kalibr YAML, read with PyYAML (``yaml.safe_load``): ``intrinsics: {camN:
  {camera_matrix: [fx, fy, cx, cy], distortion_coeffs, resolution}}`` or ``camN: {intrinsics: [fx, fy, cx, cy],
  distortion_coeffs, resolution}``, radtan/plumb_bob only;
* RPG ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``).

A value of the wrong type (a string where numbers belong, a list where a mapping belongs) is refused naming the
file, the entry and the field.
"""
from __future__ import annotations

import json
import re

import numpy as np

from evpose.core.importers.failure import ImportFailure

#: More numbers than any calibration entry holds (3x3 K, 14 distortion coefficients): refused, and never expanded
#: further (a YAML alias bomb stays cheap).
_MAX_NUMBERS = 64


def read_json_calibration(text: str, path, key: str):
    """Our JSON, OpenCV/YCB-Ev JSON, or a JSON with a DSEC-style ``intrinsics`` mapping."""
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ImportFailure(path, f"line {exc.lineno}", "-", f"not valid JSON ({exc.msg})") from None
    if not isinstance(d, dict):
        raise ImportFailure(path, "(file)", "-", "expected a JSON object")
    if "K" in d:
        return d["K"], d.get("dist", []), size_from(d, path, "(file)"), "evpose JSON"
    if "camera_matrix" in d:
        K = numbers(d["camera_matrix"], path, "(file)", "camera_matrix")
        if K.size == 9:
            K = K.reshape(3, 3)
        dkey = "distortion_coefficients" if "distortion_coefficients" in d else "dist_coeffs"
        dist = numbers(d.get(dkey, []), path, "(file)", dkey)
        return K, dist, size_from(d, path, "(file)"), "OpenCV JSON (camera_matrix)"
    if "intrinsics" in d:
        return intrinsics_from_mapping(d, key, path)
    raise ImportFailure(path, "(file)", "K", "no K / camera_matrix / intrinsics entry")


def read_yaml_calibration(text: str, path, key: str):
    """DSEC ``cam_to_cam.yaml`` or a Kalibr camchain (camera ``key``)."""
    return intrinsics_from_mapping(load_yaml_mapping(text, path), key, path)


def read_rpg_calibration(text: str, path):
    """RPG ``calib.txt``: ``fx fy cx cy [k1 k2 p1 p2 [k3]]`` (no sensor size)."""
    try:
        nums = [float(v) for v in text.split()]
    except ValueError:
        raise ImportFailure(path, "line 1", "fx", "expected 'fx fy cx cy [k1 k2 p1 p2 [k3]]' numbers") from None
    if len(nums) not in (4, 8, 9):
        raise ImportFailure(path, "line 1", "fx", f"expected 4, 8 or 9 numbers (fx fy cx cy k1 k2 p1 p2 k3), "
                            f"got {len(nums)}")
    fx, fy, cx, cy = nums[:4]
    return [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], nums[4:], None, "RPG calib.txt"


def load_yaml_mapping(text: str, file) -> dict:
    """Parse a YAML document with ``yaml.safe_load`` and require a mapping at the top level.

    OpenCV's non-standard ``%YAML:1.0`` directive is read as ``%YAML 1.0``. Syntax errors name the line.
    """
    import yaml

    text = re.sub(r"\A%YAML:(\d+\.\d+)", r"%YAML \1", text)
    try:
        d = yaml.safe_load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else "(file)"
        why = exc.problem or exc.context
        if exc.problem and exc.context and exc.context_mark is not None:
            why += f"; {exc.context} that starts at line {exc.context_mark.line + 1}"
        raise ImportFailure(file, where, "-", f"not valid YAML ({why})") from None
    except yaml.YAMLError as exc:
        raise ImportFailure(file, "(file)", "-", f"not valid YAML ({exc})") from None
    except RecursionError:
        raise ImportFailure(file, "(file)", "-", "YAML nested too deeply") from None
    if d is None:
        raise ImportFailure(file, "(file)", "-", "empty YAML document")
    if not isinstance(d, dict):
        raise ImportFailure(file, "(file)", "-", f"expected a mapping at the top level, got {_kind(d)}")
    return d


def intrinsics_from_mapping(d: dict, key: str, path):
    """DSEC cam_to_cam / Kalibr style -> (K, dist, size, description)."""
    if "intrinsics" in d and isinstance(d["intrinsics"], dict):
        cams = d["intrinsics"]
        if key not in cams:
            raise ImportFailure(path, "intrinsics", key, f"no camera {key!r} (have {', '.join(map(str, cams))}); "
                                "choose one with --camera-key")
        c, fld, mkey = cams[key], f"intrinsics.{key}", "camera_matrix"
        if not isinstance(c, dict):
            raise ImportFailure(path, "intrinsics", key, f"expected a mapping, got {_kind(c)}")
    elif key in d and isinstance(d[key], dict):
        c, fld, mkey = d[key], key, "intrinsics"
    else:
        raise ImportFailure(path, "(file)", "intrinsics", f"no 'intrinsics' mapping and no camera {key!r}")
    if c.get(mkey) is None:
        raise ImportFailure(path, fld, mkey, "missing")
    cm = numbers(c[mkey], path, fld, mkey)
    if cm.size == 4:
        K = [[cm[0], 0, cm[2]], [0, cm[1], cm[3]], [0, 0, 1]]
    elif cm.size == 9:
        K = cm.reshape(3, 3)
    else:
        raise ImportFailure(path, fld, mkey, f"expected [fx, fy, cx, cy], got {cm.size} numbers")
    model = str(c.get("distortion_model", "radtan")).lower()
    if model not in ("radtan", "plumb_bob", "pinhole", "none"):
        raise ImportFailure(path, fld, "distortion_model", f"{_show(model)} is not supported (only radtan/plumb_bob)")
    dist = numbers(c.get("distortion_coeffs") or [], path, fld, "distortion_coeffs")
    return K, dist, size_from(c, path, fld), f"YAML intrinsics ({fld})"


def size_from(d: dict, path, record: str, keys=("resolution", "img_size", "image_size")):
    """``(width, height)`` from ``resolution``/``img_size``/``image_size`` ``[w, h]`` or ``width``/``height``;
    None when the entry has none."""
    for k in keys:
        v = d.get(k)
        if isinstance(v, (list, tuple)) and len(v) == 2:
            return _int(v[0], path, record, k), _int(v[1], path, record, k)
    if "width" in d and "height" in d:
        return _int(d["width"], path, record, "width"), _int(d["height"], path, record, "height")
    return None


def numbers(value, path, record: str, fld: str) -> np.ndarray:
    """A number or a list of numbers (one level of nested lists flattened) as float64 (N,).

    Numeric strings are accepted (YAML 1.1 reads ``1e-05`` as a string); anything else -- text, booleans,
    mappings, deeper nesting, more than 64 numbers -- is refused naming ``path``, ``record`` and ``fld``.
    """
    out: list[float] = []

    def walk(v, depth: int) -> None:
        if isinstance(v, (list, tuple)):
            if depth >= 2:
                raise ImportFailure(path, record, fld, "expected a list of numbers, got lists nested too deeply")
            for u in v:
                walk(u, depth + 1)
            return
        if isinstance(v, bool) or not isinstance(v, (int, float, str)):
            raise ImportFailure(path, record, fld, f"expected numbers, got {_kind(v)}")
        try:
            out.append(float(v))
        except (ValueError, OverflowError):
            raise ImportFailure(path, record, fld, f"expected numbers, got {_show(v)}") from None
        if len(out) > _MAX_NUMBERS:
            raise ImportFailure(path, record, fld, f"more than {_MAX_NUMBERS} numbers")

    walk(value, 0)
    return np.asarray(out, dtype=np.float64)


def _int(v, path, record: str, fld: str) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, float, str)):
        raise ImportFailure(path, record, fld, f"expected an integer number of pixels, got {_kind(v)}")
    try:
        return int(v)
    except (ValueError, OverflowError):
        raise ImportFailure(path, record, fld, f"expected an integer number of pixels, got {_show(v)}") from None


def _kind(v) -> str:
    """How a parsed value reads in a message: ``a mapping``, ``a list``, or its short repr."""
    if isinstance(v, dict):
        return "a mapping"
    if isinstance(v, (list, tuple)):
        return "a list"
    return _show(v)


def _show(v) -> str:
    s = repr(v)
    return s if len(s) <= 40 else s[:37] + "..."
