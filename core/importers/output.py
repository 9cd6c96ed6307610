"""Where an import may write: the ``--out`` checks of issue 11 (``--force`` removes only what evpose wrote).

Before anything is read, ``--out`` must be absent or empty, or (with ``--force``) a scene evpose made that
holds none of the inputs; see :mod:`evpose.core.data.scene_folder`. A full disk or read-only output while the
scene is written ends as one error about ``--out``, not about the input being parsed.
"""
from __future__ import annotations

import os
from pathlib import Path

from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.options import ImportOptions


def import_inputs(sources, options: ImportOptions) -> list[Path]:
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


def output_failure(exc: OSError, out: Path, staging: Path) -> ImportFailure | None:
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
