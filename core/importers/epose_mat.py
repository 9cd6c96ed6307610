"""The files of an E-POSE export: ``NNNN_data.mat`` windows listed in numeric order and read field by field.

MATLAB ``save`` files are read with ``scipy.io.loadmat``; MATLAB v7.3 files are HDF5 and are read with h5py and
transposed back (MATLAB is column-major). See :mod:`evpose.core.importers.epose_export` for the fields.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.report import ImportReport

_NAME = re.compile(r"^(\d+)_data\.mat$")
_FIELDS = ("events", "pose", "time", "intrinsicMatrix", "cls_index", "cameraPose")


def list_windows(sources) -> list[tuple[int, Path]]:
    """``(window number, path)`` of every ``NNNN_data.mat`` among the sources (folders are listed), sorted."""
    files: dict[int, Path] = {}
    for s in map(Path, sources):
        cands = sorted(s.iterdir()) if s.is_dir() else [s] if s.is_file() else None
        if cands is None:
            raise ImportFailure(s, "(file)", "SRC", "no such file or folder")
        for p in cands:
            m = _NAME.match(p.name)
            if m:
                k = int(m.group(1))
                if k in files and files[k] != p:
                    raise ImportFailure(p, "(arguments)", "SRC", f"window {k} given twice ({files[k]})")
                files[k] = p
            elif not s.is_dir():
                raise ImportFailure(p, "(file)", "SRC", "expected NNNN_data.mat")
    return sorted(files.items())


def load_window(path: Path) -> dict:
    """The fields of one ``NNNN_data.mat`` as float64 arrays (MATLAB shapes kept)."""
    import h5py
    import scipy.io

    try:
        with wrap_errors(path, "(file)", "-", "not a readable MATLAB file"):
            raw = scipy.io.loadmat(str(path), squeeze_me=False, struct_as_record=True,
                                   variable_names=list(_FIELDS))
    except ImportFailure:
        try:
            is_h5 = h5py.is_hdf5(str(path))
        except Exception:  # noqa: BLE001
            is_h5 = False
        if not is_h5:
            raise
        raw = _load_v73(path)            # MATLAB -v7.3 files are HDF5
    out = {}
    for k in _FIELDS:
        if k in raw:
            v = raw[k]
            if not isinstance(v, np.ndarray) or v.dtype.kind not in "iufb":
                raise ImportFailure(path, "(file)", k, f"expected a numeric array, got {getattr(v, 'dtype', type(v))}")
            out[k] = v.astype(np.float64)
    return out


def _load_v73(path: Path) -> dict:
    """The fields of a MATLAB -v7.3 (HDF5) file, transposed back to MATLAB's shapes."""
    import h5py

    out = {}
    with wrap_errors(path, "(file)", "-", "not a readable MATLAB v7.3 (HDF5) file"):
        with h5py.File(path, "r") as f:
            for k in _FIELDS:
                if k in f and isinstance(f[k], h5py.Dataset):
                    out[k] = np.asarray(f[k][()]).T     # MATLAB is column-major
    return out


def events_of(d: dict, path: Path, rep: ImportReport, state: dict) -> np.ndarray:
    """The window's ``events`` as (N, 4) ``[x y t p]`` ((4, N) is transposed back, reported once)."""
    e = d.get("events")
    if e is None or e.size == 0:
        return np.empty((0, 4))
    if e.ndim != 2 or 4 not in e.shape:
        raise ImportFailure(path, "(file)", "events", f"expected (N, 4) [x y t p], got shape {e.shape}")
    if e.shape[1] != 4:
        if not state.get("transposed_events"):
            rep.assume(f"{path.name}: events stored as (4, N); read as its transpose")
            state["transposed_events"] = True
        e = e.T
    return e


def K_of(d: dict, path: Path, rep: ImportReport) -> np.ndarray | None:
    """The window's ``intrinsicMatrix`` as K (MATLAB's transposed convention detected and undone)."""
    K = d.get("intrinsicMatrix")
    if K is None:
        return None
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ImportFailure(path, "(file)", "intrinsicMatrix", f"expected a finite 3x3 matrix, got shape {K.shape}")
    if np.allclose(K[2], [0, 0, 1]):
        return K
    if np.allclose(K[:, 2], [0, 0, 1]):
        rep.assume(f"{path.name}: intrinsicMatrix is in MATLAB's transposed convention ([fx 0 0; s fy 0; cx cy 1]);"
                   " transposed")
        return K.T.copy()
    raise ImportFailure(path, "(file)", "intrinsicMatrix", f"neither its third row nor its third column is [0 0 1]: "
                        f"{K.tolist()}")


