"""Encodings of the files an export writes: PNG images, MATLAB .mat files and JSON text, as bytes.

Deterministic: equal inputs give byte-identical files (no dates, no random padding), so a resumed
export ends identical to an uninterrupted one. The bytes go to disk through
:mod:`evpose.core.data.atomic`.

PNG (issue 22): the scanlines (filter byte 0, "none", then the raw row) are deflated by zlib-ng (``zlib_ng``)
with the run-length strategy ``Z_RLE`` and wrapped in the signature and the IHDR, IDAT and IEND chunks here.
Run-length deflate looks only for repeats of the previous byte: no hash table, no search state, so its output
is a function of the pixels alone, in any process. Before, ISA-L (``isal``, level 1) was used: in a Dask worker
it wrote, for one three-channel image, a match of 171 zeros at distance 6266 where every fresh process writes
distance 6268 (same pixels, same length, one byte of the stream different), in about one dataset export of
eight -- its output depends on state beyond the input. Measured on the images of a 5-object E-POSE export
(real YCB meshes, DAVIS346; CPU per image): 8-bit gray 95 us / 1.03 kB (ISA-L 52 us / 1.49 kB, the standard
library's zlib with ``Z_RLE`` 218 us, libdeflate level 1 466 us), 1-bit masks 25 us / 0.29 kB (ISA-L 16 us),
RGB 0.58 ms / 14.2 kB (ISA-L 0.31 ms / 18.1 kB, zlib ``Z_RLE`` 1.2 ms): +0.7 ms and 25 % smaller files per
5-object window. The decoded pixels are those of the input (tests/core/test_export_encode.py against OpenCV's
and PIL's decoders).

MAT (issue 14: written for every window): :func:`savemat_bytes` writes 2-D float64 / int64 arrays itself, byte
for byte as ``scipy.io.savemat`` (tested), and lets scipy write any other value: 0.2 instead of 2.7 ms for a
3-object window.
"""
from __future__ import annotations

import functools
import io
import json
import struct
import sys
import zlib

import numpy as np
from zlib_ng import zlib_ng

__all__ = ["json_text", "encode_png", "savemat_bytes"]


def json_text(obj, indent=1) -> str:
    """JSON text of the export's files: indented by ``indent``, one trailing newline."""
    return json.dumps(obj, indent=indent) + "\n"


# ------------------------------------------------------------------------------------------- PNG
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)))


def encode_png(img: np.ndarray, *, bilevel: bool = False, compression: int = 1) -> bytes:
    """PNG bytes of a uint8/uint16 image: ``(H, W)`` gray or ``(H, W, 3)`` **RGB**.

    ``bilevel`` writes a 1-bit gray PNG (any non-zero pixel is 1; OpenCV reads it back as 0/255, PIL and
    MATLAB as a logical image). Otherwise 8 or 16 bits per sample as given. No row filter; the scanlines are
    deflated run-length (see the module docstring), or stored uncompressed with ``compression=0``. Sparse event
    images and masks are mostly runs of zeros, which run-length deflate packs well.
    """
    img = np.asarray(img)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3) or img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"encode_png: expected a uint8/uint16 (H, W) or (H, W, 3) image, got {img.dtype} {img.shape}")
    H, W = img.shape[:2]
    if bilevel:
        rows = np.packbits(img.reshape(H, W) != 0, axis=1)
        depth, colour = 1, 0
    else:
        rows = img.reshape(H, -1)
        depth, colour = 8 * img.itemsize, 0 if img.ndim == 2 else 2
        if img.itemsize == 2:
            rows = rows.astype(">u2").view(np.uint8)
    raw = np.empty((H, rows.shape[1] + 1), np.uint8)
    raw[:, 0] = 0                                   # filter type 0 (none) on every scanline
    raw[:, 1:] = rows
    idat = _deflate(raw, int(compression) > 0)
    return (_PNG_SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, depth, colour, 0, 0, 0))
            + _chunk(b"IDAT", idat) + _IEND)


def _deflate(raw: np.ndarray, compress: bool) -> bytes:
    """The zlib stream of ``raw``: run-length deflate (level 1, ``Z_RLE``), or stored blocks (level 0)."""
    c = zlib_ng.compressobj(1 if compress else 0, zlib_ng.DEFLATED, 15, 8, zlib_ng.Z_RLE)
    return c.compress(raw) + c.flush()


# ------------------------------------------------------------------------------------------- MAT
_MAT_DESCRIPTION = "MATLAB 5.0 MAT-file, Platform: evpose export"
_MI_INT8, _MI_INT32, _MI_UINT32, _MI_MATRIX = 1, 5, 6, 14
#: dtype -> (MAT data type, MAT array class) of the arrays written here (scipy's NP_TO_MTYPES / NP_TO_MXTYPES)
_NUMERIC = {np.dtype("<f8"): (9, 6), np.dtype("<i8"): (12, 14)}


def _padded(n: int) -> bytes:
    return b"\x00" * (-n % 8)


def _numeric_parts(name: bytes, arr: np.ndarray) -> list:
    """One top-level MAT 5 variable of a 2-D float64/int64 array, exactly as ``scipy.io.savemat`` writes it
    (uncompressed), as a list of byte strings: matrix tag, array flags, dimensions, name (small-data
    element up to 4 bytes), data in column-major order (small-data element when empty), each element
    padded to 8 bytes. A Fortran-ordered array is copied once, straight into the bytes."""
    mtype, mclass = _NUMERIC[arr.dtype]
    if len(name) <= 4:
        name_el = struct.pack("<I", (len(name) << 16) + _MI_INT8) + name.ljust(4, b"\x00")
    else:
        name_el = struct.pack("<II", _MI_INT8, len(name)) + name + _padded(len(name))
    nbytes = arr.size * arr.itemsize
    pad = _padded(nbytes)
    size = 16 + 16 + len(name_el) + 8 + nbytes + len(pad)
    head = (struct.pack("<IIIIIIIIii", _MI_MATRIX, size, _MI_UINT32, 8, mclass, 0, _MI_INT32, 8, *arr.shape)
            + name_el + struct.pack("<II", mtype, nbytes))
    if nbytes == 0:
        return [head]
    return [head, arr.tobytes(order="F"), pad]


def _scipy_file_bytes(fields: dict) -> bytes:
    """``scipy.io.savemat`` of ``fields`` (uncompressed, 1-D arrays as rows) into bytes."""
    from scipy.io import savemat

    bio = io.BytesIO()
    savemat(bio, fields, oned_as="row", do_compression=False)
    return bio.getvalue()


def _scipy_variable_bytes(name: str, value) -> bytes:
    """One top-level variable as ``scipy.io.savemat`` writes it (its output without the 128-byte header).
    An array of strings (the cell ``object_names``, the same in every window) is encoded once and cached:
    scipy takes ~1 ms for it."""
    if type(value) is np.ndarray and value.dtype == object and all(type(v) is str for v in value.flat):
        return _cached_strings_bytes(name, value.shape, tuple(value.flat))
    return _scipy_file_bytes({name: value})[128:]


@functools.lru_cache(maxsize=64)
def _cached_strings_bytes(name: str, shape: tuple, items: tuple) -> bytes:
    value = np.empty(shape, dtype=object)
    value.flat[:] = items
    return _scipy_file_bytes({name: value})[128:]


def savemat_bytes(fields: dict) -> bytes:
    """The bytes of ``scipy.io.savemat(f, fields, oned_as="row", do_compression=False)`` (MATLAB 5,
    uncompressed, 1-D arrays as rows) with a fixed header text instead of scipy's creation date, so equal
    inputs give byte-identical files. 2-D float64 / int64 arrays are written here (the bulk of an
    export's .mat), any other value by scipy; the result is the same bytes either way (tested)."""
    desc = _MAT_DESCRIPTION.encode("latin1")[:116].ljust(116, b" ")
    if sys.byteorder != "little":                  # scipy writes native byte order: let it write everything
        return desc + _scipy_file_bytes(fields)[116:]
    parts = [desc, b"\x00" * 8, struct.pack("<H", 0x0100), b"IM"]
    for name, value in fields.items():
        if (type(value) is np.ndarray and value.ndim == 2 and value.dtype in _NUMERIC
                and not name.startswith("_")):
            parts += _numeric_parts(name.encode("latin1"), value)
        else:
            parts.append(_scipy_variable_bytes(name, value))
    return b"".join(parts)
