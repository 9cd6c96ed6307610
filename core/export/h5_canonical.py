"""The finished HDF5 export as a canonical file: the same data gives the same bytes.

An HDF5 file's bytes record more than its data: where each chunk landed depends on the order the chunks were
first written, and a chunk rewritten after a resume (or a row block flushed twice) leaves freed space behind. The
``h5`` export writes its rows in whatever order they come back from the workers (``--jobs``, Dask) into a
resumable ``.partial`` file, so two runs of one configuration held equal data in different bytes (a resumed run
501 bytes more). :func:`canonical_copy` therefore writes the finished file once more, in a fixed order: the root
attributes by name, then every group and dataset by name with its creation properties (chunks, filters, fill
value; object times off), each dataset's chunks in the order of their offsets, copied as stored
(``read_direct_chunk`` / ``write_direct_chunk``: no decompression, no recompression). The file format is pinned
(``libver=("earliest", "v110")``), so a newer HDF5 library does not pick newer object formats on its own.

Measured (issue 22): a 400-window DAVIS346 export with the three-channel frames (46 MB) is copied in ~0.25 s.
"""
from __future__ import annotations

from pathlib import Path

#: Oldest and newest HDF5 object formats the export may use (readable by HDF5 1.10 and newer).
LIBVER = ("earliest", "v110")


def canonical_copy(src: Path, dst: Path) -> None:
    """Write the content of the closed HDF5 file ``src`` into the new file ``dst`` in the canonical order (see the
    module docstring). ``dst`` must not be open elsewhere; it is created or truncated."""
    import h5py

    with h5py.File(src, "r") as fin, h5py.File(dst, "w", libver=LIBVER, track_order=False) as fout:
        _copy_attrs(fin, fout)
        names: list[str] = []
        fin.visit(names.append)
        for name in sorted(names):
            obj = fin[name]
            if isinstance(obj, h5py.Group):
                _group(fout, name)
            else:
                _dataset(obj, fout, name)
        fout.flush()


def _copy_attrs(src, dst) -> None:
    for key in sorted(src.attrs):
        dst.attrs.create(key, src.attrs[key], dtype=src.attrs.get_id(key).dtype)


def _group(fout, name: str) -> None:
    """A group without modification times (intermediate groups are created the same way, by name order)."""
    import h5py

    gcpl = h5py.h5p.create(h5py.h5p.GROUP_CREATE)
    gcpl.set_obj_track_times(False)
    h5py.h5g.create(fout.id, name.encode(), gcpl=gcpl)


def _dataset(ds, fout, name: str) -> None:
    import h5py

    dcpl = ds.id.get_create_plist()       # chunks, filters, fill value, no object times: as the export made it
    dcpl.set_obj_track_times(False)
    new = h5py.h5d.create(fout.id, name.encode(), ds.id.get_type(), ds.id.get_space(), dcpl=dcpl)
    out = h5py.Dataset(new)
    if ds.chunks is None:
        if ds.size:
            out[...] = ds[...]
    else:
        n = ds.id.get_num_chunks()
        offsets = sorted(tuple(ds.id.get_chunk_info(i).chunk_offset) for i in range(n))
        for off in offsets:
            mask, data = ds.id.read_direct_chunk(off)
            new.write_direct_chunk(off, data, mask)
    _copy_attrs(ds, out)
