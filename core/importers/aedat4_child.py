"""The AEDAT4 reading process: iniVation's ``dv-processing`` reads the file, the importer gets its events and poses
through a pipe (``python aedat4_child.py REC.aedat4 POSES``, POSES = 1 or 0; see
:func:`evpose.core.importers.aedat4_reader.child_command`). Imports nothing of evpose.

Why a process of its own: on some corrupt packets ``dv-processing`` 2.0 spins forever inside
``getNextEventBatch`` while holding the GIL (measured: about half of randomly corrupted files), so no thread of
the importer could notice; a crash in its C++ code would take the importer down with it. Run apart, a stall or a
crash ends as one clear error in :mod:`evpose.core.importers.aedat4_reader`.

Protocol on the original stdout (fd 1 is pointed at stderr before ``dv_processing`` loads, so library output
cannot corrupt it): frames ``kind (1 byte) | length (uint64 LE) | payload``:

``S``  empty: the library is loaded (the file is opened next);
``H``  JSON: ``camera``, ``streams``, ``event_stream``, ``pose_streams``, ``resolution`` [w, h], ``time_range``
       [t0, t1] (µs);
``E``  events: ``n`` (uint64), then ``t`` (n int64 µs), ``x``, ``y`` (n int16 each), ``p`` (n int8);
``P``  poses: ``n``, then ``t`` (n int64 µs), then n x 7 float64 ``tx ty tz qw qx qy qz`` (metres; the file's
       float32 values);
``D``  JSON: counts and the pose ``referenceFrame -> targetFrame`` pairs; the last frame of a good read;
``X``  JSON ``error``: the library refused the file.
"""
from __future__ import annotations

import json
import os
import struct
import sys
import time

FRAME = struct.Struct("<cQ")
#: Events sent per frame at most, and the longest a read batch waits before it is sent (s).
FRAME_EVENTS = 1 << 20
FRAME_SECONDS = 0.2
_POSE_BATCH = 1 << 16


class _Out:
    def __init__(self, fd: int):
        self.f = os.fdopen(fd, "wb", buffering=1 << 20)

    def send(self, kind: bytes, *parts) -> None:
        views = [memoryview(p).cast("B") for p in parts]
        self.f.write(FRAME.pack(kind, sum(len(v) for v in views)))
        for v in views:
            self.f.write(v)

    def send_json(self, kind: bytes, doc: dict) -> None:
        self.send(kind, json.dumps(doc).encode())


def _header(rec) -> dict:
    names = list(rec.getStreamNames())
    events = [s for s in names if rec.isStreamOfEventType(s)]
    poses = [s for s in names if rec.isStreamOfPoseType(s)]
    ev = "events" if "events" in events else (events[0] if events else None)
    res = rec.getEventResolution(ev) if ev else None
    rng = rec.getTimeRange()
    return {"camera": rec.getCameraName(), "streams": names, "event_streams": events, "event_stream": ev,
            "pose_streams": poses, "resolution": list(res) if res else None,
            "time_range": [int(rng[0]), int(rng[1])] if rng else None}


def _send_events(out: _Out, batches: list) -> int:
    """One ``E`` frame of the held batches' columns (no concatenation: each column is written part by part)."""
    n = sum(len(c[0]) for c in batches)
    out.send(b"E", struct.pack("<Q", n), *(c[k] for k in range(4) for c in batches))
    batches.clear()
    return n


def _events(out: _Out, rec, stream: str) -> int:
    import numpy as np

    batches, held, total, last = [], 0, 0, time.monotonic()
    while True:
        b = rec.getNextEventBatch(stream)
        if b is None:
            break
        a = b.numpy()                    # a view into the batch's packets: the columns are copied out at once
        if len(a):
            batches.append((np.ascontiguousarray(a["timestamp"], np.int64), np.ascontiguousarray(a["x"], np.int16),
                            np.ascontiguousarray(a["y"], np.int16), np.ascontiguousarray(a["polarity"], np.int8)))
            held += len(a)
        if held >= FRAME_EVENTS or (held and time.monotonic() - last > FRAME_SECONDS):
            total += _send_events(out, batches)
            held, last = 0, time.monotonic()
    if batches:
        total += _send_events(out, batches)
    return total


def _poses(out: _Out, rec, stream: str) -> tuple[int, dict]:
    import numpy as np

    t, v, frames, total = [], [], {}, 0
    while True:
        p = rec.getNextPose(stream)
        if p is not None:
            t.append(int(p.timestamp))
            v.append((*p.translation, *p.rotation))
            key = f"{p.referenceFrame} -> {p.targetFrame}"
            frames[key] = frames.get(key, 0) + 1
        if t and (p is None or len(t) >= _POSE_BATCH):
            out.send(b"P", struct.pack("<Q", len(t)), np.asarray(t, np.int64), np.asarray(v, np.float64))
            total += len(t)
            t, v = [], []
        if p is None:
            return total, frames


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    out = _Out(os.dup(1))
    os.dup2(2, 1)                    # anything the library prints goes to stderr, never into the frames
    try:
        import dv_processing as dv

        out.send(b"S")
        out.f.flush()
        rec = dv.io.MonoCameraRecording(argv[0])
        head = _header(rec)
        out.send_json(b"H", head)
        n_ev = _events(out, rec, head["event_stream"]) if head["event_stream"] else 0
        n_pose, frames = 0, {}
        if argv[1] == "1" and head["pose_streams"]:
            stream = "poses" if "poses" in head["pose_streams"] else head["pose_streams"][0]
            n_pose, frames = _poses(out, rec, stream)
        out.send_json(b"D", {"events": n_ev, "poses": n_pose, "pose_frames": frames})
    except Exception as exc:  # noqa: BLE001 - every refusal of the library goes to the importer as one message
        out.send_json(b"X", {"error": f"{exc} ({type(exc).__name__})"})
    out.f.flush()


if __name__ == "__main__":
    main()
