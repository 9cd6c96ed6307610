"""Arrays inside an ``.npz`` (zip) archive: small ones read whole, event columns streamed in chunks.

A member's ``np.lib.format`` header is read first, then fixed-size reads of the (possibly deflated) member,
so memory does not grow with the archive. Pickled object arrays are refused.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.time_units import TIME_UNITS


class NpyMember:
    """A 1-D array inside an npz, read in chunks."""

    def __init__(self, zf: zipfile.ZipFile, key: str, path: Path):
        self.key, self.path = key, path
        with wrap_errors(path, f"array {key!r}", key, "cannot open the member"):
            self.f = zf.open(f"{key}.npy")
            version = np.lib.format.read_magic(self.f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(self.f)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(self.f)
            else:
                raise ValueError(f"unsupported .npy version {version}")
        if dtype.hasobject:
            raise ImportFailure(path, f"array {key!r}", key, "object arrays (pickles) are refused")
        if len(shape) != 1:
            raise ImportFailure(path, f"array {key!r}", key, f"expected a 1-D array, got shape {shape}")
        if dtype.kind not in "iufb":
            raise ImportFailure(path, f"array {key!r}", key, f"expected numbers, got dtype {dtype}")
        self.n, self.dtype = int(shape[0]), dtype

    def read(self, count: int) -> np.ndarray:
        nbytes = count * self.dtype.itemsize
        with wrap_errors(self.path, f"array {self.key!r}", self.key, "cannot read"):
            buf = self.f.read(nbytes)
        if len(buf) != nbytes:
            raise ImportFailure(self.path, f"array {self.key!r}", self.key, f"truncated: {len(buf)} of {nbytes} bytes")
        return np.frombuffer(buf, self.dtype)

    def close(self):
        try:
            self.f.close()
        except Exception:  # noqa: BLE001
            pass


def open_zip(path: Path) -> zipfile.ZipFile:
    """The archive, opened for reading (not a zip -> :class:`ImportFailure` naming the file)."""
    with wrap_errors(path, "(file)", "-", "not a readable .npz (zip) archive"):
        return zipfile.ZipFile(path, "r")


def small_array(zf: zipfile.ZipFile, path: Path, key: str) -> np.ndarray:
    """A whole member (pose and camera arrays are small), without pickles."""
    with wrap_errors(path, f"array {key!r}", key, "cannot read"):
        with zf.open(f"{key}.npy") as f:
            return np.lib.format.read_array(f, allow_pickle=False)


def stored_unit(zf, path: Path, names: set, key: str) -> str | None:
    """The time unit stored in member ``key`` (``"s"|"ms"|"us"|"ns"``), None when there is none."""
    if key not in names:
        return None
    v = small_array(zf, path, key)
    u = str(v.reshape(-1)[0]) if v.size else ""
    if u not in TIME_UNITS:
        raise ImportFailure(path, f"array {key!r}", key, f"expected one of {', '.join(TIME_UNITS)}, got {u!r}")
    return u
