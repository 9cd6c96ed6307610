"""The options of ``evpose import`` (one dataclass; CLI flags map 1:1) and their bounds.

Every option is checked once, before any file is read; a bad value ends as an :class:`ImportFailure`
naming the flag.
"""
from __future__ import annotations

from dataclasses import dataclass

from evpose.core.importers.failure import ImportFailure
from evpose.core.importers.time_units import TIME_UNITS

#: Default reorder window of :class:`EventSink` (µs): events may arrive up to this much out of order.
DEFAULT_REORDER_WINDOW_US = 100_000
#: Longest accepted event stream (s): the ms index costs 8 bytes per ms, and a longer span is nearly always a corrupt
#: time stamp or a wrong time unit.
DEFAULT_MAX_SPAN_S = 4 * 3600.0


@dataclass
class ImportOptions:
    """All importer options (CLI flags map 1:1; unused ones are ignored by a format).

    Units: µs for times, metres for lengths unless stated.
    """

    repair: bool = False                 # drop bad events, project rotations, sort poses instead of refusing
    force: bool = False                  # replace an existing non-empty --out folder
    name: str | None = None              # scene name (default: --out folder name)
    camera: str | None = None            # calibration file: our JSON, OpenCV/YCB-Ev JSON, DSEC/Kalibr YAML, RPG calib.txt
    width: int | None = None             # sensor size override, pixels
    height: int | None = None
    objects: str | None = None           # "name=mesh.obj:T_base_obj.json,..." (T optional for formats that derive it)
    time_unit: str | None = None         # force the unit of guessable times: s, ms, us, ns
    offset_us: int | None = None         # clock prior override (pose minus event time, µs)
    reorder_window_us: int = DEFAULT_REORDER_WINDOW_US
    max_span_s: float = DEFAULT_MAX_SPAN_S  # refuse event times spanning more (a corrupt time stamp, or wrong unit)
    compression: str | None = "blosc-lz4"
    # epose-bag / epose-export
    assets: str | None = None            # folder laid out like shared/assets/epose
    scene: str | None = None             # scenes.json key (aliases and time_shifts.csv names accepted)
    sequence: str | None = None          # time_shifts.csv sequence, e.g. R_05_ml (case-insensitive)
    events_topic: str = "/dvs/events"
    pose_topic: str = "/dvs/pose"
    pose_time: str = "header"            # header | bag: time stamp of PoseStamped samples
    one_based: bool = False              # epose-export: event x/y are 1-based (MATLAB)
    classes: str | None = None           # epose-export: "cls=name,..." mapping of cls_index to object names
    # dsec
    events_mode: str = "copy"            # copy | link | reference
    camera_key: str = "cam0"             # which camera of a DSEC/Kalibr YAML
    # ycbev
    models: str | None = None            # BOP models folder (obj_000001.ply, mm)
    mesh_scale: float | None = None
    frame_us: int = 33333                # frame period of scene_gt.json images, µs (YCB-Ev: 1000000 // 30)
    frame_index_offset: int = 1          # image j is at time_origin + (j + offset) * frame_us
    time_origin_us: int = 0              # added to every YCB-Ev time (the files count from the recording start)
    rgb_to_event: str | None = "auto"    # calib_stereo_c2ev.json: "auto" (found beside the sequence), a path, or "none"

    def check(self) -> None:
        if self.time_unit is not None and self.time_unit not in TIME_UNITS:
            raise ImportFailure("(options)", "--time-unit", "time_unit", f"expected one of {', '.join(TIME_UNITS)}, "
                                f"got {self.time_unit!r}")
        if self.events_mode not in ("copy", "link", "reference"):
            raise ImportFailure("(options)", "--events-mode", "events_mode",
                                f"expected copy, link or reference, got {self.events_mode!r}")
        if self.pose_time not in ("header", "bag"):
            raise ImportFailure("(options)", "--pose-time", "pose_time", f"expected header or bag, got {self.pose_time!r}")
        if not float(self.max_span_s) > 0:
            raise ImportFailure("(options)", "--max-span-s", "max_span_s", "must be positive")
        if int(self.reorder_window_us) < 0:
            raise ImportFailure("(options)", "--reorder-window-ms", "reorder_window_us", "must be >= 0")
        for k in ("width", "height"):
            v = getattr(self, k)
            if v is not None and int(v) <= 0:
                raise ImportFailure("(options)", f"--{k}", k, f"must be positive, got {v}")
        if int(self.frame_us) <= 0:
            raise ImportFailure("(options)", "--frame-us", "frame_us", f"must be positive, got {self.frame_us}")
