"""Prophesee / Metavision recordings: EVT 2.0 and EVT 3.0 ``.raw`` and ``.dat`` (``evpose import prophesee
REC.raw|REC.dat [TRAJECTORY [CALIB]]``).

The files are read with ``faery`` (PyPI, Rust decoders for EVT 2.0 / 3.0 and DAT 1 / 2 with Python bindings;
the tests also write their files with its encoders). Metavision's own SDK is not on PyPI. Candidates measured
here (2 cores, 20 M random events at 1 ev/µs; decode only; and files written by faery crossing each time wrap):

============  ===================  ==============================  ===========================================
library       formats              M events/s (EVT2 / EVT3 / DAT)  correctness, upkeep
============  ===================  ==============================  ===========================================
faery 0.7.1   EVT2, EVT3, DAT      120 / 74 / 126, 42 MB flat      exact on dense files and across every wrap;
                                                                   EVT3 events > 8 ms apart across the 24-bit
                                                                   wrap are clamped (see Time); header size and
                                                                   version read; corrupt words refused with an
                                                                   error, never a crash or a hang (fuzzed);
                                                                   released 2026
expelliarmus  EVT2, EVT3, DAT      155 / 82 / 149, 59 MB           EVT3 times off by 4096 µs whenever events
1.1.12                                                             are > ~4 ms apart; EVT2 wrong after the
                                                                   2**34 µs wrap; no header size; last release
                                                                   2023
evt3 0.4.1    EVT3 only            -- / 82 / --, 108 MB            exact on EVT3 (sparse wraps too), but decodes
                                                                   EVT2 and DAT files as EVT3 garbage without
                                                                   complaint
evlib 0.13.2  many                 not installed                   pulls polars, pyarrow and pandera (~100 MB)
============  ===================  ==============================  ===========================================

faery is the one library that reads all three formats right. Decoding is a small part of an import (validation
and the HDF5 writing dominate: ``bench/bench_import.py``).

Header: the sensor size comes from ``% geometry WxH`` / ``% format ...;width=W;height=H`` (EVT) or ``% Width`` /
``% Height`` (DAT); a header without it needs ``--width/--height``. The version comes from the header too
(``% evt 2.0|3.0``, DAT ``% Version``); EVT 2.1 is refused (faery cannot decode it). External trigger events are
counted and ignored.

Time: µs of the sensor clock (since the camera started), int64, plus the header's ``t0`` when a writer stored one;
a trajectory in another clock needs the clock prior ``--offset-us``. The Metavision time counters wrap: EVT 3.0
carries 24 bits (a wrap every 16.8 s), EVT 2.0 34 bits (every 4.77 h), DAT 32 bits (every 71.6 min); faery
unwraps all three, and the tests pin each wrap. For EVT 3.0 faery counts a wrap only when TIME_HIGH (4096 µs
steps) falls from its last two values to its first ones, so a stream with no TIME_HIGH word in the 8 ms before a
wrap (events that sparse; sensors emit TIME_HIGH as time passes) keeps the old time, clamped. Any other backward
step is clamped by faery to the previous time (a corrupt word cannot reorder the stream).

A file whose last word is cut off (a recording stopped mid-write) loses that partial word: a warning, not an
error.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evpose.core.importers.failure import ImportFailure, wrap_errors
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.pose_text import read_pose_text
from evpose.core.importers.recording import build_recording_scene, recording_camera, recording_sources
from evpose.core.importers.report import ImportContext

SUFFIXES = (".raw", ".dat")
#: Bytes faery reads per packet (one packet per read): progress is estimated from it.
READ_BYTES = 1 << 16
#: Event packets are gathered into chunks of about this many events before validation.
CHUNK_EVENTS = 1 << 20
_WORD_BYTES = {"evt2": 4, "evt3": 2, "dat1": 8, "dat2": 8}
_MAX_HEADER_BYTES = 1 << 20


def import_prophesee(sources, out, ctx: ImportContext) -> dict:
    """Import an EVT 2.0 / EVT 3.0 ``.raw`` or ``.dat`` recording (+ trajectory, calibration); returns the summary."""
    rec, traj_file, calib = recording_sources(sources, "prophesee", SUFFIXES)
    if traj_file is None:
        raise ImportFailure(rec, "(arguments)", "TRAJECTORY", "a Prophesee recording holds no poses: give "
                            "REC TRAJECTORY [CALIB]")
    traj = read_pose_text(traj_file, ctx)
    ctx.report.assume(f"{traj_file.name}: poses are T_base_cam (camera in the base frame, metres)")
    objects = collect_objects(ctx, None)
    decoder, version, size = open_decoder(rec, ctx)
    header_bytes = _header_length(rec)
    _warn_partial_word(ctx, rec, version, header_bytes)
    camera = recording_camera(ctx, calib, size, rec)
    ctx.report.details["prophesee"] = {"version": version, "sensor": list(size), "header_bytes": header_bytes}
    with decoder:
        return build_recording_scene(ctx, out, rec, camera, _chunks(ctx, decoder, rec, version), lambda: traj,
                                     objects)


def open_decoder(rec: Path, ctx: ImportContext):
    """``(faery decoder, version, (width, height))``; the size from the header, else ``--width/--height``."""
    from faery.extension import dat, evt

    opts = ctx.options
    fallback = (int(opts.width), int(opts.height)) if opts.width and opts.height else None
    is_dat = rec.suffix.lower() == ".dat"
    try:
        if is_dat:
            d = dat.Decoder(str(rec), fallback, None)
            version, size = d.version, d.dimensions
            if d.event_type not in ("cd", "2d"):
                raise ImportFailure(rec, "(header)", "event type", f"{d.event_type} events, not CD (change detection) "
                                    "events")
        else:
            d = evt.Decoder(str(rec), fallback, None)
            version, size = d.version, d.dimensions
    except ImportFailure:
        raise
    except BaseException as exc:  # noqa: BLE001 - faery's Rust errors (and panics) become one line
        if not isinstance(exc, Exception) and type(exc).__name__ != "PanicException":
            raise
        raise ImportFailure(rec, "(header)", "-", _header_message(str(exc))) from None
    if version not in _WORD_BYTES:
        raise ImportFailure(rec, "(header)", "format", f"{version} is not supported (EVT 2.0, EVT 3.0 or DAT)")
    if size is None:
        raise ImportFailure(rec, "(header)", "geometry", "no sensor size in the header: pass --width and --height")
    return d, version, (int(size[0]), int(size[1]))


def _header_message(msg: str) -> str:
    if "size" in msg:
        return f"{msg}: pass --width and --height"
    return f"not a readable Prophesee recording ({msg})"


def _header_length(rec: Path) -> int:
    """Bytes of the ``%`` text header (the lines starting with ``%`` at the start of the file)."""
    n = 0
    with open(rec, "rb") as f:
        while n < _MAX_HEADER_BYTES:
            line = f.readline(_MAX_HEADER_BYTES)
            if not line.startswith(b"%"):
                break
            n += len(line)
    return n


def _warn_partial_word(ctx: ImportContext, rec: Path, version: str, header: int) -> None:
    payload = os.path.getsize(rec) - header - (2 if version.startswith("dat") else 0)
    extra = payload % _WORD_BYTES[version] if payload > 0 else 0
    if extra:
        ctx.report.warn(f"{rec.name}: the last {extra} byte(s) are not a whole {_WORD_BYTES[version]}-byte "
                        f"{version.upper()} word (recording cut off?); ignored")


def _columns(version: str, a: np.ndarray) -> tuple:
    """``(x, y, t int64, p)`` of one faery event array (EVT: ``on``; DAT: ``payload``)."""
    p = a["payload"] if version.startswith("dat") else a["on"]
    return a["x"], a["y"], a["t"].astype(np.int64), p


def _chunks(ctx: ImportContext, decoder, rec: Path, version: str):
    """``(x, y, t, p, record, fraction)`` chunks of about :data:`CHUNK_EVENTS` events; faery's refusals of corrupt
    words become an ImportFailure naming the event index."""
    size = max(os.path.getsize(rec), 1)
    held, n_held, n, n_packets, n_triggers, end = [], 0, 0, 0, 0, False
    it = iter(decoder)
    while not end:
        with wrap_errors(rec, f"events after {n + n_held:,}", "-", "corrupt data"):
            try:
                pk = next(it)
            except StopIteration:
                pk, end = None, True
            except BaseException as exc:  # noqa: BLE001 - a Rust panic is a BaseException
                if isinstance(exc, (KeyboardInterrupt, SystemExit)):
                    raise
                raise RuntimeError(str(exc)) from None
        if pk is not None:
            n_packets += 1
            if isinstance(pk, dict):
                n_triggers += len(pk.get("triggers", ()))
                pk = pk.get("events")
            if pk is not None and len(pk):
                held.append(pk)
                n_held += len(pk)
        if held and (end or n_held >= CHUNK_EVENTS):
            a = held[0] if len(held) == 1 else np.concatenate(held)
            yield (*_columns(version, a), f"events [{n}, {n + len(a)})", min(n_packets * READ_BYTES / size, 1.0))
            n += len(a)
            held, n_held = [], 0
    if n_triggers:
        ctx.report.assume(f"{rec.name}: {n_triggers} external trigger event(s) ignored")
