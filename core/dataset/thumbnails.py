"""Thumbnails of the triage report: each object's worst window as the event frame (ON red, OFF blue) with every
object's projected contour on it, the object's own drawn thicker -- the labels checked against this camera's own
events, as a dataset author looks at them. One PNG per object, base64 for a ``data:`` URI (the report stays one
self-contained file); made on the worker that scores the scene (:func:`evpose.core.dataset.tasks.triage_task`).
"""
from __future__ import annotations

import base64

import cv2
import numpy as np

__all__ = ["window_thumbnail", "worst_window_thumbnails"]


def window_thumbnail(scene, window: dict, focus: str | None = None) -> bytes:
    """PNG bytes of the event frame of ``window`` (``t0_us``, ``t1_us``, ``t_label_us``) with the objects'
    contours at its label time (``focus``: the object drawn thicker). Deterministic bytes (OpenCV's PNG encoder
    at a fixed level)."""
    from evpose.core.label.annotate import Annotator
    from evpose.core.label.labels import Request
    from evpose.core.label.overlay import mask_contours, object_color
    from evpose.core.label.represent import to_rgb
    from evpose.core.label.windows import Window

    cam = scene.camera
    t0, t1, tl = int(window["t0_us"]), int(window["t1_us"]), int(window["t_label_us"])
    ev = scene.events.window(t0, t1)
    rgb = np.ascontiguousarray(to_rgb("polarity", ev, cam.width, cam.height, t0, t1))
    request = Request(keypoints=False, masks_visible=False, label_map=True, amodal=False)
    lab = Annotator(scene, request).annotate(Window(int(window.get("index", -1)), t0, t1, tl))
    if lab.label_map is not None:
        for k, name in enumerate(scene.object_names):
            contours = mask_contours(lab.label_map == k)
            if contours:
                cv2.polylines(rgb, [c.reshape(-1, 1, 2).astype(np.int32) for c in contours], True,
                              object_color(k), 2 if name == focus else 1, lineType=cv2.LINE_8)
    ok, png = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 6])
    if not ok:
        raise RuntimeError("OpenCV could not encode a thumbnail")
    return png.tobytes()


def worst_window_thumbnails(scene, score: dict) -> dict:
    """Per object of ``scene``: ``{"window", "t_label_us", "png_b64"}`` of its worst window with enough events to
    judge (:func:`evpose.core.dataset.triage_scores.object_scores`), when it has one."""
    from evpose.core.dataset.triage_scores import object_scores

    windows = score["windows"]
    out = {}
    for name in scene.object_names:
        worst = object_scores(score, name)["worst"]
        if not worst:
            continue
        w = windows[int(worst[0]["index"])]
        try:
            png = window_thumbnail(scene, w, name)
        except Exception as exc:         # a picture is not worth the scene's triage: say why it is missing
            out[name] = {"window": int(w["index"]), "t_label_us": int(w["t_label_us"]),
                         "error": f"{type(exc).__name__}: {exc}"}
            continue
        out[name] = {"window": int(w["index"]), "t_label_us": int(w["t_label_us"]),
                     "png_b64": base64.b64encode(png).decode("ascii")}
    return out
