"""``--camera`` and the calibration files found beside a recording -> a :class:`CameraModel`.

The format is chosen by the file's suffix (see :mod:`evpose.core.importers.calibration_formats`);
``--width/--height`` override the sensor size, and a file without one takes the format's default sensor
(reported) or is refused.
"""
from __future__ import annotations

from pathlib import Path

from evpose.core.data.camera import CameraError, CameraModel
from evpose.core.importers.calibration_formats import (
    read_json_calibration,
    read_rpg_calibration,
    read_yaml_calibration,
)
from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.report import ImportContext


def load_camera(path, ctx: ImportContext, *, default_size: tuple[int, int] | None = None) -> CameraModel:
    """Read a calibration file (format chosen by its suffix), apply ``--width/--height``.

    Supported: our JSON (``K``, ``dist``, ``width``, ``height``); OpenCV/YCB-Ev JSON (``camera_matrix`` 3x3,
    ``distortion_coefficients`` (nested ok), ``img_size`` [w, h]); DSEC ``cam_to_cam.yaml`` / Kalibr YAML
    (``intrinsics: {camN: {camera_matrix: [fx, fy, cx, cy], distortion_coeffs, resolution}}`` or
    ``camN: {intrinsics: [fx, fy, cx, cy], distortion_coeffs, resolution}``, radtan/plumb_bob only); RPG
    ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``).

    Parameters
    ----------
    default_size : (width, height), optional
        Sensor size in pixels when the file has none (reported); without it such a file is refused.
    """
    path = Path(path)
    opts = ctx.options
    with wrap_errors(path, "(file)", "-", "cannot read the calibration"):
        raw = path.read_bytes()
    text = raw.decode("utf-8", errors="replace")
    suffix = path.suffix.lower()
    try:
        if suffix == ".json":
            K, dist, size, what = read_json_calibration(text, path, opts.camera_key)
        elif suffix in (".yaml", ".yml"):
            K, dist, size, what = read_yaml_calibration(text, path, opts.camera_key)
        else:
            K, dist, size, what = read_rpg_calibration(text, path)
    except ImportFailure:
        raise
    except (TypeError, ValueError, KeyError, OverflowError) as exc:
        raise ImportFailure(path, "(file)", "-", f"malformed calibration ({exc})") from None
    except RecursionError:
        raise ImportFailure(path, "(file)", "-", "malformed calibration (nested too deeply)") from None
    size = _sensor_size(path, size, ctx, default_size)
    try:
        cam = CameraModel(K, dist, int(size[0]), int(size[1]), source=str(path))
    except CameraError as exc:
        raise ImportFailure(path, "(file)", "K/dist", str(exc).replace(f"{path}: ", "", 1)) from None
    ctx.report.details["camera_source"] = {"file": str(path), "format": what}
    return cam


def _sensor_size(path: Path, size, ctx: ImportContext, default_size) -> tuple[int, int]:
    """The file's size, overridden by ``--width/--height``; else ``default_size`` (reported)."""
    opts = ctx.options
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
    return size
