"""Importers: published event-camera data -> scene folders (``evpose import FORMAT SRC... --out SCENE``).

Formats (one module each): ``epose-bag`` (E-POSE ROS1 bags), ``epose-export`` (E-POSE ``NNNN_data.mat``
windows), ``dsec`` (DSEC event HDF5 + trajectory + calibration), ``rpg`` (Event Camera Dataset text files),
``ycbev`` (YCB-Ev zstd events + BOP annotations), ``npz`` (NumPy arrays), ``bop`` (a BOP scene of event
frames, e.g. evpose's BOP export), ``aedat4`` (iniVation DV recordings), ``ros-events`` (ROS bags of ``event_camera_msgs/EventPacket``), ``prophesee`` (Metavision EVT 2.0 /
EVT 3.0 ``.raw`` and ``.dat``). ``epose-bag`` also reads ROS2 bags (sqlite3 or MCAP).

Every importer builds the scene atomically (nothing at ``out`` unless it succeeded), streams the events with
bounded memory, never modifies its inputs, and writes ``import_report.json`` listing what was assumed or
repaired. Bad input raises :class:`ImportFailure` (an :class:`~evpose.core.errors.InputError`) whose message
names the file, the record and the field.

Shared pieces, one module each: ``failure`` (the error), ``options``, ``report`` (report and context),
``time_units``/``time_guess`` (exact conversions, unit guessing), ``pose_checks``/``pose_text``/``static_scene``
(poses), ``event_sink`` (event stream validation), ``calibration``/``calibration_formats``, ``object_args``
(``--objects``), ``meshes``, ``input_folders`` (special files in input folders), ``output`` (``--out``/``--force``)
and ``scene_builder`` (the atomic scene folder).

Example
-------
>>> from evpose.core.importers import import_scene, ImportOptions
>>> summary = import_scene("npz", ["rec.npz"], "scenes/rec", ImportOptions(camera="cam.json"))  # doctest: +SKIP
"""
from __future__ import annotations

import importlib
from typing import Callable

from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.input_folders import check_input_folders
from evpose.core.importers.options import ImportOptions
from evpose.core.importers.output import check_out, import_inputs
from evpose.core.importers.report import REPORT_FILENAME, ImportContext, ImportReport, stderr_log

__all__ = ["FORMATS", "import_scene", "ImportFailure", "ImportOptions", "ImportReport", "REPORT_FILENAME"]

#: format name -> (module, function)
FORMATS = {
    "epose-bag": ("epose_bag", "import_epose_bag"),
    "epose-export": ("epose_export", "import_epose_export"),
    "dsec": ("dsec", "import_dsec"),
    "rpg": ("rpg", "import_rpg"),
    "ycbev": ("ycbev", "import_ycbev"),
    "npz": ("npz", "import_npz"),
    "bop": ("bop", "import_bop"),
    "aedat4": ("aedat4", "import_aedat4"),
    "prophesee": ("prophesee", "import_prophesee"),
    "ros-events": ("ros_events", "import_ros_events"),
}


def import_scene(fmt: str, sources, out, options: ImportOptions | None = None, *,
                 progress: Callable[[float, str], None] | None = None, cancel: Callable[[], bool] | None = None,
                 log: Callable[[str], None] | None | str = "stderr", **option_kwargs) -> dict:
    """Import ``sources`` of format ``fmt`` into the scene folder ``out``.

    Parameters
    ----------
    fmt : str
        One of :data:`FORMATS`.
    sources : list of str or Path
        Files and/or folders (see each module for the roles).
    out : str or Path
        Scene folder to create (must be absent or empty unless ``options.force``).
    options : ImportOptions, optional
        Format options; keyword arguments override its fields (``repair=True``, ``camera="cam.json"``...).
    progress : callable, optional
        ``progress(fraction, message)``, fraction in [0, 1].
    cancel : callable, optional
        ``cancel() -> bool``; True aborts with :class:`evpose.core.data.events.Cancelled` and leaves nothing behind.
    log : callable or None, optional
        Receives every assumption/repair/warning line; default ``"stderr"`` prints them there, None is silent.

    Returns
    -------
    dict
        ``scene``, ``format``, ``n_events``, ``n_poses``, ``objects``, ``report`` (path of import_report.json),
        ``assumptions``, ``repairs``, ``warnings``, ``runtime_s``.

    Raises
    ------
    ImportFailure
        Bad input: ``str(exc)`` is ``"{file}: {record}: {field}: {message}"``.
    """
    if fmt not in FORMATS:
        raise ImportFailure("(arguments)", "FORMAT", "format", f"unknown format {fmt!r} (one of {', '.join(FORMATS)})")
    opts = options or ImportOptions()
    for k, v in option_kwargs.items():
        if not hasattr(opts, k):
            raise TypeError(f"import_scene: unknown option {k!r}")
        setattr(opts, k, v)
    if isinstance(log, str):
        log = stderr_log
    ctx = ImportContext(fmt, sources, opts, progress=progress, cancel=cancel, log=log)
    inputs = import_inputs(sources, opts)
    check_input_folders(inputs)                  # FIFOs, devices, sockets in an input folder: before any open
    check_out(out, opts.force, inputs)           # fail fast, before reading anything (checked again when writing)
    mod, fn = FORMATS[fmt]
    func = getattr(importlib.import_module(f".{mod}", __name__), fn)
    return func([str(s) for s in sources], out, ctx)
