"""Event frames of one window: counts, spike, E-POSE 3-channel, time surface, voxel grid; undistortion of
events; display RGB. :mod:`evpose.core.label.represent` names them for the views.

Every function here is **stateless**: its result is a pure function of the events it is given (and of the
window bounds). Nothing is carried over from an earlier window. (The original E-POSE scripts never reset
their 3-channel accumulators between windows, so every image also held all earlier windows; we must not.)

Conventions (DESIGN section 3):

* times are int64 µs of the event clock; a window is half-open ``[t0_us, t1_us)``; functions that take a
  window raise ``ValueError`` for events outside it (an event at ``t1_us`` belongs to the next window);
* pixel ``(u, v) = (x, y)``; images are indexed ``[v, u]``, shape ``(H, W)``;
* polarity-split outputs are ordered **positive (ON, p=1) first, negative (OFF, p=0) second**;
* events with ``x >= width``, ``y >= height`` or ``p > 1`` raise ``ValueError`` naming the field (never
  wrapped into another pixel); ``x = 0`` / ``y = 0`` are ordinary pixels and are counted.

Accumulation uses ``np.bincount`` (sums) and ``np.maximum.at`` / ``np.minimum.at`` (latest time per
pixel; with NumPy >= 1.25 these take a fast path of about bincount speed and, unlike fancy assignment,
do not depend on the events being time-sorted or on the order in which duplicate indices are written).
"""
