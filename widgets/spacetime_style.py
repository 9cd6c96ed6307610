"""Colours and sizes of the space-time view (RGBA in [0, 1], sizes in screen pixels)."""
from __future__ import annotations

#: Event colours, as in the frame view (``core.label.represent``): ON red, OFF blue.
ON_RGBA = (1.0, 0.0, 0.0, 0.55)
OFF_RGBA = (0.0, 0.0, 1.0, 0.55)
BACKGROUND = "white"
CAGE_RGBA = (0.45, 0.45, 0.45, 0.8)
SLAB_RGBA = (0.3, 0.3, 0.3, 0.07)
SLAB_EDGE_RGBA = (0.2, 0.2, 0.2, 0.9)
TEXT_RGBA = (0.15, 0.15, 0.15, 1.0)
POINT_SIZE_PX = 2.0
POINT_ANTIALIAS = 0.0      # a 2 px sprite instead of 5-8 px: software GL (Xvfb, VMs) fills 2-3x faster
TUBE_WIDTH_PX = 2.0
TUBE_CASING_PX = 5.0       # a white casing under each tube keeps it legible inside a dense event cloud
TUBE_CASING_RGBA = (1.0, 1.0, 1.0, 0.9)

#: Draw order of the scene's visuals (lower first; equal orders keep their creation order).
ORDER_CAGE = -1            # the span's sensor box under everything
ORDER_POINTS = 0
ORDER_SLAB = 1
ORDER_SLAB_EDGE = 2
ORDER_TUBE_CASING = 3
ORDER_TUBES = 4
ORDER_TEXT = 5             # axis names and tick labels on top
