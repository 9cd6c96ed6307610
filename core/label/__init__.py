"""Labels of one event window: rasteriser, annotation, overlays, event representations."""
