"""The README.txt of an E-POSE-layout export: the conventions of every file, and each deliberate
difference from the original E-POSE scripts (DESIGN section 6)."""
from __future__ import annotations

from evpose.core.export.fingerprint import evpose_version

__all__ = ["readme_text"]


def readme_text(ctx) -> str:
    """The README of the export of ``ctx`` (an :class:`~evpose.core.export.writer.ExportContext`)."""
    scene = ctx.scene
    clock = scene.clock
    names = ", ".join(f"{j}={n}" for j, n in enumerate(ctx.names, 1))
    fp = ctx.fingerprint["windows"]
    win = (f"{fp['window_us']} us" if fp["window_us"] is not None else f"{fp['window_events']} events")
    return f"""E-POSE-layout export of scene "{scene.name}" written by evpose {evpose_version()}.
See export_manifest.json for the exact configuration, clock, corrections and per-window status.

CONVENTIONS
- Windows: consecutive half-open event-time intervals [t0, t1) of {win}, tiling the whole recording
  from its first event; every event is in exactly one window. File prefix NNNN = zero-based window
  index ({ctx.n_digits} digits). Windows without a label (label time outside the trajectory) and windows
  left out by --only-verified have no files; export_manifest.json lists them with the reason.
- Label time: the window {"centre (t0 + (t1 - t0) // 2)" if ctx.label_at == "center" else "end t1"} on the event clock.
  Poses are interpolated at pose time t_pose = t_event + offset_us + skew_ppm*1e-6*(t_event - t_ref_us)
  with offset_us = {clock.offset_us}, skew_ppm = {clock.skew_ppm!r}, t_ref_us = {clock.t_ref_us} (the first event).
  The same clock is used by every product (poses, cameraPose, keypoints, masks, segmentation).
- Distortion: every image and every pixel coordinate is in the RAW (distorted) event camera, the same
  pixels as the events (pixel centres at integer coordinates, 0-based). Nothing is undistorted.
- Units: metres (poses, XYZ, box corners), microseconds (int64 *_us fields), seconds in the
  original fields `time` and `events(:,3)` (since the recording's first event).
- Objects (K in *_obj{{K}}.png and mask_image_all values): {names}. Objects of the scene that are not
  exported still occlude the exported ones.
- Encodings: event_image 8-bit 0/255 (any event); mask_image / mask_image_obj{{K}} 1-bit visible masks;
  mask_image_all 8-bit labels 0 = background, K = object (not saturated); segmented_image(_obj{{K}})
  8-bit 255 where an event lies on the object's visible mask; three_channel_image RGB = (ON count /
  max, OFF count / max, latest event time / max) of this window only.
- Box: axis-aligned box of the mesh in the object frame, enlarged by {ctx.margin_m * 1e3:g} mm on every side.

DELIBERATE DIFFERENCES FROM THE ORIGINAL E-POSE SCRIPTS
 1. Box corners are projected each with its own depth (the original divided every corner by the
    first corner's depth) and with the lens distortion applied once, forward (the original projected
    with a pinhole and then undistorted the result, and clamped negative coordinates to 0).
 2. Keypoints, masks and images share the raw pixel grid; the original undistorted the event images.
 3. cameraPose is T_base_cam at each window's own label time (the original stored the second frame's
    pose in every file). Shape 3x4 kept; the full 4x4 is in T_base_cam.
 4. Masks are z-buffered triangle rasterisations of the mesh (no holes, exact occlusion), not splats of
    mesh vertices; the single-object mask is not dilated; label images are never saturated.
 5. The box margin enlarges the box on every side (the original's "+1 mm" shifted it); default 0.
 6. The 3-channel image is computed from each window's events only (the original never reset its
    accumulators) and its channels are ON count, OFF count and latest time (the original used a sum of
    timestamps and the latest ON / OFF times).
 7. Windows are half-open: the original put the event at each boundary into two windows.
 8. Events at x = 0 or y = 0 are kept in every product (the original dropped them from its images).
 9. One clock model (offset and skew) is applied to all products (the original applied its time
    offset in one script only).
10. File numbering starts at 0000 (the original started at 0001) and every window is written (the
    original skipped its last 6 or 12 windows); windows are not cut at the first pose.
11. centerInfo is the correctly projected object-frame origin; time is the label time (the original
    used the time of the first event after the window end); bbox.txt keeps the original layout with
    correct values (distorted pixels, not clamped).
12. Fields were added to the .mat files (see above); the original fields keep their names and shapes.
"""
