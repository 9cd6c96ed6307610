"""The sensor size a Prophesee header implies when it has no ``% geometry`` line (issue 26.3).

Files recorded with Metavision before ~2021 (and the EVT / DAT samples in public repositories) name the camera
plugin, the sensor or its generation, but not the pixel array: ``% plugin_name hal_plugin_gen31_fx3``,
``% sensor_generation 4.1``, ``% serial_number ...``. Each Prophesee sensor has one array size, so the name tells it:

=======================================================  ===========
header names                                             size
=======================================================  ===========
Gen4 / Gen4.1 (``gen4``, ``gen41``), IMX636, IMX646      1280 × 720
Gen3 ATIS (``atis``)                                     480 × 360
Gen3 / Gen3.1 VGA (``gen3``, ``gen31``)                  640 × 480
GenX320 (``genx320``)                                    320 × 320
=======================================================  ===========

:func:`size_from_header` returns the size with the header line it came from (the import report states it as an
assumption); None when nothing in the header names a known sensor (then ``--width/--height`` are asked for).
"""
from __future__ import annotations

import re

__all__ = ["SENSOR_SIZES", "size_from_header"]

#: Sensor name patterns (lower case, matched in the header's plugin, sensor and generation lines) -> (width, height).
#: Ordered: the first match wins (genx320 and atis before the generations).
SENSOR_SIZES = (
    (r"genx_?320", (320, 320)),
    (r"imx_?6[34]6", (1280, 720)),
    (r"gen_?4(\.?[01])?(?![0-9])", (1280, 720)),
    (r"atis", (480, 360)),
    (r"gen_?3(\.?[01])?(?![0-9])", (640, 480)),
)
#: Header keys that name the sensor (``% key value`` lines).
_KEYS = ("plugin_name", "sensor_name", "sensor_generation")


def size_from_header(lines) -> tuple[tuple[int, int], str] | None:
    """``((width, height), the header line)`` from the sensor a header's ``%`` lines name, or None.

    ``lines``: the header's lines (str, with or without the leading ``%``). A ``sensor_generation`` of ``4.1`` /
    ``3.1`` counts as ``gen41`` / ``gen31``."""
    for raw in lines:
        line = raw.lstrip("%").strip()
        parts = line.split(None, 1)
        if len(parts) < 2 or parts[0] not in _KEYS:
            continue
        value = parts[1].strip().lower()
        if parts[0] == "sensor_generation":
            value = "gen" + value.replace(".", "")
        for pattern, size in SENSOR_SIZES:
            if re.search(pattern, value):
                return size, "% " + line
    return None
