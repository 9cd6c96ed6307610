"""Colours and sizes of the space-time view (RGBA in [0, 1], sizes in screen pixels)."""
from __future__ import annotations

#: Event colours, as in the frame view (``core.label.represent``): ON red, OFF blue.
ON_RGBA = (1.0, 0.0, 0.0, 0.55)
OFF_RGBA = (0.0, 0.0, 1.0, 0.55)
#: Events farther than the band from every silhouette, when events are coloured by object: faint, still by polarity.
DIM_ON_RGBA = (0.85, 0.45, 0.45, 0.16)
DIM_OFF_RGBA = (0.45, 0.5, 0.85, 0.16)
#: Alpha of the events within the band (drawn in their object's colour).
BAND_ALPHA = 0.9
#: Alpha of the tubes' translucent surfaces.
SURFACE_ALPHA = 0.16
BACKGROUND = "white"
CAGE_RGBA = (0.45, 0.45, 0.45, 0.8)
SLAB_RGBA = (0.3, 0.3, 0.3, 0.07)
SLAB_EDGE_RGBA = (0.2, 0.2, 0.2, 0.9)
TEXT_RGBA = (0.15, 0.15, 0.15, 1.0)
POINT_SIZE_PX = 2.0
POINT_ANTIALIAS = 0.0      # a 2 px sprite instead of 5-8 px: software GL (Xvfb, VMs) fills 2-3x faster
TUBE_WIDTH_PX = 1.5
TUBE_CASING_PX = 3.5       # a white casing under each tube keeps it legible inside a dense event cloud
TUBE_CASING_RGBA = (1.0, 1.0, 1.0, 0.8)

#: Draw order of the scene's visuals (lower first; equal orders keep their creation order): the dimmed events
#: under the tubes' skins, the events near the silhouettes on top.
ORDER_CAGE = -1            # the span's sensor box under everything
ORDER_POINTS = 0
ORDER_SLAB = 1
ORDER_SLAB_EDGE = 2
ORDER_SURFACES = 3
ORDER_TUBE_CASING = 4
ORDER_TUBES = 5
ORDER_BAND_POINTS = 6
ORDER_TEXT = 7             # axis names and tick labels on top
