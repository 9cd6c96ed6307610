"""Display conversions: event frames as ``uint8 (H, W, 3)`` RGB for the GUI and the exports."""
from __future__ import annotations

import numpy as np

_BACKGROUNDS = ("white", "black")


def check_background(background: str) -> None:
    """ValueError naming ``background`` unless it is "white" or "black"."""
    if background not in _BACKGROUNDS:
        raise ValueError(f"background: expected 'white' or 'black', got {background!r}")


def _robust_max(*arrays, percentile: float = 99.0) -> float:
    """The ``percentile`` of the non-zero magnitudes of ``arrays`` (1.0 when all are zero).

    Taken over non-zero pixels only, so a sparse frame is not scaled by its empty background, and a few
    hot pixels above the percentile saturate alone instead of darkening everything else."""
    if not 0 < percentile <= 100:
        raise ValueError(f"percentile: must be in (0, 100], got {percentile}")
    vals = [np.abs(a[a != 0]).ravel() for a in arrays]
    vals = np.concatenate(vals) if vals else np.empty(0)
    if vals.size == 0:
        return 1.0
    s = float(np.percentile(vals, percentile))
    return s if s > 0 else float(vals.max())


def _to_u8(a: np.ndarray) -> np.ndarray:
    return np.rint(np.clip(a, 0.0, 1.0) * 255.0).astype(np.uint8)


def two_colour(a_on: np.ndarray, a_off: np.ndarray, background: str) -> np.ndarray:
    """ON red, OFF blue at intensities ``a`` in [0, 1]; both at one pixel mix towards magenta.

    Black background: ``(a_on, 0, a_off)``. White background: white blended towards the same colour by
    ``a = max(a_on, a_off)``: ``(1 - a + a_on, 1 - a, 1 - a + a_off)``."""
    check_background(background)
    a_on = np.clip(a_on, 0.0, 1.0)
    a_off = np.clip(a_off, 0.0, 1.0)
    if background == "black":
        rgb = np.stack([a_on, np.zeros_like(a_on), a_off], axis=-1)
    else:
        a = np.maximum(a_on, a_off)
        rgb = np.stack([1.0 - a + a_on, 1.0 - a, 1.0 - a + a_off], axis=-1)
    return _to_u8(rgb)


def polarity_rgb(pos: np.ndarray, neg: np.ndarray, background: str = "white",
                 percentile: float = 99.0) -> np.ndarray:
    """ON/OFF counts as ``uint8 (H, W, 3)``: ON red, OFF blue, on a white or black background.

    Intensity is ``count / s`` clipped to 1, with ``s`` the ``percentile`` of the non-zero counts of both
    polarities together (one scale, so ON and OFF are comparable); a hot pixel saturates alone rather than
    washing out the frame. Exactly red ``(255, 0, 0)`` / blue ``(0, 0, 255)`` at full intensity.
    """
    s = _robust_max(pos, neg, percentile=percentile)
    return two_colour(pos / s, neg / s, background)


def signed_rgb(img: np.ndarray, background: str = "white", percentile: float = 99.0) -> np.ndarray:
    """A signed image (net counts, a voxel bin) as ``uint8 (H, W, 3)``: positive red, negative blue,
    scaled by the ``percentile`` of the non-zero magnitudes."""
    s = _robust_max(img, percentile=percentile)
    return two_colour(img / s, -img / s, background)


def gray_rgb(img: np.ndarray, vmax: float | None = None, percentile: float | None = None,
             invert: bool = False) -> np.ndarray:
    """A non-negative image (spike, counts, time surface) as gray ``uint8 (H, W, 3)``.

    Parameters
    ----------
    img : (H, W) bool, int or float
        Values below 0 are shown as 0.
    vmax : float, optional
        Value shown at full intensity. Default: the ``percentile`` of the non-zero values if given, else
        the maximum (1 for bool images; an all-zero image stays black).
    invert : bool
        Dark marks on white (``255 - gray``), e.g. for a white background.
    """
    img = np.asarray(img)
    a = img.astype(np.float64)
    if vmax is None:
        if img.dtype == bool:
            vmax = 1.0
        elif percentile is not None:
            vmax = _robust_max(np.clip(a, 0, None), percentile=percentile)
        else:
            vmax = float(a.max()) if a.size and a.max() > 0 else 1.0
    if not vmax > 0:
        raise ValueError(f"vmax: must be > 0, got {vmax}")
    g = _to_u8(a / vmax)
    if invert:
        g = 255 - g
    return np.repeat(g[..., None], 3, axis=2)


def three_channel_rgb(img3: np.ndarray) -> np.ndarray:
    """A :func:`~evpose.core.label.event_frames.three_channel.three_channel` image as ``uint8 (H, W, 3)``: R = ON, G = OFF, B = latest time (the channel
    order the E-POSE PNGs are written in); values in [0, 1] map to 0..255."""
    img3 = np.asarray(img3)
    if img3.ndim != 3 or img3.shape[2] != 3:
        raise ValueError(f"img3: expected shape (H, W, 3), got {img3.shape}")
    return _to_u8(img3.astype(np.float64))
