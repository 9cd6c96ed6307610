"""Encodings of the files an export writes: PNG images, MATLAB .mat files and JSON text, as bytes.

Deterministic: equal inputs give byte-identical files (no dates, no random padding), so a resumed
export ends identical to an uninterrupted one. The bytes go to disk through
:mod:`evpose.core.data.atomic`.
"""
from __future__ import annotations

import io
import json

import numpy as np

__all__ = ["json_text", "encode_png", "savemat_bytes"]


def json_text(obj, indent=1) -> str:
    """JSON text of the export's files: indented by ``indent``, one trailing newline."""
    return json.dumps(obj, indent=indent) + "\n"


def encode_png(img: np.ndarray, *, bilevel: bool = False, compression: int = 1) -> bytes:
    """PNG bytes of a uint8/uint16 image (``(H, W)`` gray or ``(H, W, 3)`` **BGR**, OpenCV order).

    ``bilevel`` writes a 1-bit PNG (any non-zero pixel is 1; OpenCV reads it back as 0/255, PIL and
    MATLAB as a logical image). Otherwise zlib level ``compression`` with the run-length strategy and no
    row filter. Measured on DAVIS346 event frames (16 k events, CPU time): RGB 0.8 ms / 18 kB against
    1.6 ms / 32 kB (level 1, "sub" filter) and 2.6 ms / 24 kB (level 1, adaptive filters); gray
    0.3 ms / 5 kB against 0.8 ms / 9 kB (level 1, adaptive). Sparse event images are mostly runs.
    """
    import cv2

    if bilevel:
        params = [cv2.IMWRITE_PNG_BILEVEL, 1]
    else:
        params = [cv2.IMWRITE_PNG_COMPRESSION, int(compression), cv2.IMWRITE_PNG_STRATEGY,
                  cv2.IMWRITE_PNG_STRATEGY_RLE, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]
    ok, buf = cv2.imencode(".png", img, params)
    if not ok:  # pragma: no cover
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


_MAT_DESCRIPTION = "MATLAB 5.0 MAT-file, Platform: evpose export"


def savemat_bytes(fields: dict) -> bytes:
    """``scipy.io.savemat`` (MATLAB 5, uncompressed, 1-D arrays as rows) into bytes, with a fixed
    header text instead of scipy's creation date, so equal inputs give byte-identical files."""
    from scipy.io import savemat

    bio = io.BytesIO()
    savemat(bio, fields, oned_as="row", do_compression=False)
    data = bytearray(bio.getvalue())
    desc = _MAT_DESCRIPTION.encode("latin1")[:116].ljust(116, b" ")
    data[:116] = desc
    return bytes(data)
