"""Special files inside input folders, refused by ``stat`` before any reader opens them.

A FIFO blocks whoever opens it until a writer appears (a FIFO named ``rec.db3`` in a ROS2 bag folder hung the
import), a device never ends, a socket cannot be read. Readers of folders (ROS2 bags, DSEC sequences, BOP
scenes, E-POSE exports, RPG and YCB-Ev folders) open files they find by name or by listing, so every input folder
is walked first (:func:`check_input_folders`): anything that is neither a folder nor a regular file (symbolic
links followed; a dangling link is left to the reader) is refused with one line naming it.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from evpose.core.importers.failure import ImportFailure


def check_input_folders(paths) -> None:
    """Walk every folder among ``paths`` (not following links to folders) and refuse the first special file.

    Raises
    ------
    ImportFailure
        ``FILE: in input folder ROOT: file type: a FIFO (named pipe), not a regular file ...``.
    """
    from evpose.core.data.input_files import describe_kind

    for root in paths:
        root = Path(root).expanduser()
        if not root.is_dir():
            continue
        for folder, _dirs, files in os.walk(root):
            for name in files:
                path = os.path.join(folder, name)
                try:
                    mode = os.stat(path).st_mode
                except OSError:                 # dangling link, vanished file: the reader says so if it needs it
                    continue
                if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
                    raise ImportFailure(path, f"in input folder {root}", "file type", f"{describe_kind(mode)}, not a "
                                        "regular file; evpose never opens one (remove it, or import a copy of the "
                                        "folder without it)")
