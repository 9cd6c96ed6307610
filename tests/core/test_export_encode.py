"""The export's encoders (evpose.core.export.encode) against the straightforward encodings.

PNG: our bytes (ISA-L deflate, chunks written by evpose) decode, with OpenCV and with PIL, to exactly the
pixels given, with the bit depth and colour type of the straightforward ``cv2.imencode`` encoding, for
every image kind an export writes (8-bit gray, 16-bit label maps, 1-bit masks, RGB) and every level.
MAT: :func:`savemat_bytes` is byte for byte ``scipy.io.savemat`` (with the fixed header text), including
empty arrays, short and long names, Fortran-ordered and strided arrays and the cell of object names;
``scipy.io.loadmat`` reads back the values.
"""
from __future__ import annotations

import io
import struct
import zlib

import cv2
import numpy as np
import pytest
from PIL import Image
from scipy.io import loadmat, savemat

from evpose.core.export.encode import encode_png, savemat_bytes

H, W = 26, 35


def _images():
    rng = np.random.default_rng(7)
    sparse = np.zeros((H, W), np.uint8)
    sparse[rng.integers(0, H, 60), rng.integers(0, W, 60)] = 255
    labels = np.zeros((H, W), np.uint8)
    labels[3:12, 4:20] = 1
    labels[8:20, 15:30] = 3
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[sparse > 0] = rng.integers(0, 256, (int((sparse > 0).sum()), 3))
    return {
        "gray_sparse": (sparse, {}),
        "gray_random": (rng.integers(0, 256, (H, W), dtype=np.uint8), {}),
        "labels": (labels, {}),
        "labels16": (rng.integers(0, 65536, (H, W), dtype=np.uint16), {}),
        "rgb_sparse": (rgb, {}),
        "rgb_random": (rng.integers(0, 256, (H, W, 3), dtype=np.uint8), {}),
        "mask": ((labels == 3).view(np.uint8), {"bilevel": True}),
        "mask_0_255": ((labels == 1).view(np.uint8) * np.uint8(255), {"bilevel": True}),
        "mask_empty": (np.zeros((H, W), np.uint8), {"bilevel": True}),
        "mask_odd_width": (rng.integers(0, 2, (5, 13), dtype=np.uint8), {"bilevel": True}),
        "strided": (rng.integers(0, 256, (2 * H, 2 * W), dtype=np.uint8)[::2, 1::2], {}),
    }


def _expected(img, kw):
    """The pixels OpenCV decodes from the straightforward ``cv2.imencode`` PNG of the image (RGB given,
    BGR to OpenCV): 1-bit masks come back as 0/255."""
    if kw.get("bilevel"):
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_BILEVEL, 1])
    else:
        ok, buf = cv2.imencode(".png", img[..., ::-1] if img.ndim == 3 else img)
    assert ok
    ref = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    return ref[..., ::-1] if ref.ndim == 3 else ref


def _ihdr(png: bytes) -> tuple:
    """``(width, height, bit depth, colour type)`` of a PNG's IHDR (checked to be the first chunk)."""
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and png[12:16] == b"IHDR"
    return struct.unpack(">IIBB", png[16:26])


def _chunks_ok(png: bytes) -> list:
    """Walk the chunks and check every CRC; returns the chunk types in order."""
    pos, kinds = 8, []
    while pos < len(png):
        n, = struct.unpack(">I", png[pos:pos + 4])
        kind, data = png[pos + 4:pos + 8], png[pos + 8:pos + 8 + n]
        crc, = struct.unpack(">I", png[pos + 8 + n:pos + 12 + n])
        assert crc == zlib.crc32(kind + data), kind
        kinds.append(kind)
        pos += 12 + n
    return kinds


@pytest.mark.parametrize("level", [0, 1, 2, 3, 9])
@pytest.mark.parametrize("name", list(_images()))
def test_png_decodes_to_the_input_pixels(name, level):
    img, kw = _images()[name]
    png = encode_png(img, compression=level, **kw)
    assert _chunks_ok(png) == [b"IHDR", b"IDAT", b"IEND"]
    # OpenCV: exactly the pixels of the straightforward encoding
    dec = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    dec = dec[..., ::-1] if dec.ndim == 3 else dec
    ref = _expected(img, kw)
    assert dec.dtype == ref.dtype and dec.shape == ref.shape and np.array_equal(dec, ref)
    # PIL: the same header fields as OpenCV's own encoding, and the pixels
    ok, buf = cv2.imencode(".png", img[..., ::-1] if img.ndim == 3 else img,
                           [cv2.IMWRITE_PNG_BILEVEL, 1] if kw.get("bilevel") else [])
    assert _ihdr(png) == _ihdr(buf.tobytes())
    pil = np.array(Image.open(io.BytesIO(png)))
    want = (img != 0) if kw.get("bilevel") else img
    assert pil.shape == want.shape and np.array_equal(pil.astype(np.int64), want.astype(np.int64))


def test_png_is_deterministic_and_refuses_other_arrays():
    img, _ = _images()["rgb_sparse"]
    assert encode_png(img) == encode_png(img.copy())
    for bad in (np.zeros((4, 4), np.float32), np.zeros((4, 4, 4), np.uint8), np.zeros(5, np.uint8)):
        with pytest.raises(ValueError, match="encode_png"):
            encode_png(bad)


# ------------------------------------------------------------------------------------------- MAT
def _scipy_mat(fields) -> bytes:
    """The straightforward encoding: scipy's savemat with evpose's fixed header text."""
    bio = io.BytesIO()
    savemat(bio, fields, oned_as="row", do_compression=False)
    data = bytearray(bio.getvalue())
    data[:116] = b"MATLAB 5.0 MAT-file, Platform: evpose export".ljust(116, b" ")
    return bytes(data)


def _fields(n_events: int, k: int, seed: int = 0) -> dict:
    """A dict shaped like an E-POSE window's .mat fields (see evpose.core.export.epose._mat_fields)."""
    rng = np.random.default_rng(seed)
    ev = np.empty((n_events, 4), order="F")
    ev[:, 0] = rng.integers(0, 346, n_events)
    ev[:, 1] = rng.integers(0, 260, n_events)
    ev[:, 2] = np.sort(rng.random(n_events))
    ev[:, 3] = rng.choice([-1.0, 1.0], n_events)
    names = np.array([f"object_{j}" for j in range(k)], dtype=object)
    return {
        "pose": rng.normal(size=(4, 4 * k)),
        "keypointprojections": rng.normal(size=(8, 5 * k)),
        "centerInfo": rng.normal(size=(1, 2 * k)),
        "cameraPose": rng.normal(size=(4, 4))[:3, :],           # a strided view
        "time": np.array([[0.125]]),
        "events": ev,
        "cls_index": np.arange(1.0, k + 1)[None, :],
        "t_start_us": np.array([[-(2 ** 40)]], np.int64),
        "t_label_us": np.array([[2 ** 62]], np.int64),
        "clock_skew_ppm": np.array([[np.nan]]),
        "distCoeffs": rng.normal(size=(1, 5)),
        "object_names": names,
        "bbox_obj": np.full((k, 4), -1.0),
        "visib_fract": np.array([[np.inf] * k]),
        "a": np.zeros((0, 0)),                       # name within the 4-byte small-data element
        "abcd": np.ones((1, 1), np.int64),
        "abcde": np.zeros((2, 0), np.int64),        # empty: data in a small-data element
        "row": np.arange(3.0),                      # 1-D: scipy's row convention (written by scipy)
        "c_order": np.arange(12.0).reshape(3, 4),
        "transposed": np.arange(12, dtype=np.int64).reshape(3, 4).T,
    }


@pytest.mark.parametrize("n_events,k", [(0, 1), (1, 1), (3, 2), (1000, 5)])
def test_savemat_bytes_is_scipy_byte_for_byte(n_events, k):
    fields = _fields(n_events, k, seed=n_events)
    data = savemat_bytes(fields)
    assert data == _scipy_mat(fields)
    back = loadmat(io.BytesIO(data))
    for name, v in fields.items():
        if v.dtype == object:
            assert [str(s[0]) for s in back[name].ravel()] == list(v)
        else:
            assert np.array_equal(back[name], np.atleast_2d(v), equal_nan=True), name
            assert back[name].dtype == v.dtype, name


def test_savemat_names_cache_follows_the_names():
    a = {"object_names": np.array(["box", "cyl"], dtype=object)}
    b = {"object_names": np.array(["box", "drill"], dtype=object)}
    assert savemat_bytes(a) == _scipy_mat(a)
    assert savemat_bytes(b) == _scipy_mat(b)
    assert savemat_bytes(a) == _scipy_mat(a)
