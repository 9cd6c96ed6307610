"""Prophesee / Metavision recordings: EVT 2.0 and EVT 3.0 ``.raw`` and ``.dat`` (``evpose import prophesee
REC.raw|REC.dat [TRAJECTORY [CALIB]]``; without a TRAJECTORY an event-only scene).

The headers are read with ``faery`` (PyPI, Rust decoders for EVT 2.0 / 3.0 and DAT 1 / 2 with Python
bindings; the tests also write their files with its encoders). Metavision's own SDK is not on PyPI. Candidates measured
here (2 cores, 20 M random events at 1 ev/µs; decode only; and files written by faery crossing each time wrap):

============  ===================  ==============================  ===========================================
library       formats              M events/s (EVT2 / EVT3 / DAT)  correctness, upkeep
============  ===================  ==============================  ===========================================
faery 0.7.1   EVT2, EVT3, DAT      120 / 74 / 126, 42 MB flat      exact on dense files and across every wrap;
                                                                   EVT3 events > 8 ms apart across the 24-bit
                                                                   wrap are clamped (see Time), as is any time
                                                                   stepping back (all three); header size and
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

faery reads the headers. The event words of all three are decoded here, EVT 2.0 and DAT with NumPy
(:mod:`evpose.core.importers.prophesee_words`), EVT 3.0 with numba (:mod:`evpose.core.importers.evt3_words`),
because faery clamps every time that steps back to the previous one (on a real Gen4.1 EVT 3.0 recording 0.66 % of
the events came out 1-11 µs late against OpenEB's reading), and skips unknown words without a count: their times go
to the event sink as the file holds them (out of order within the reorder window: put in place, counted; further:
refused, ``--repair`` drops them).
Decoding is a small part of an import (validation and the HDF5 writing dominate: ``bench/bench_import.py``).

Header (:mod:`evpose.core.importers.prophesee_header`): the sensor size comes from ``% geometry WxH`` /
``% format ...;width=W;height=H`` (EVT) or ``% Width`` / ``% Height`` (DAT); a header without it gets the size of
the sensor it names (``% plugin_name hal_plugin_gen31_fx3`` -> 640 x 480, an assumption in the report:
:mod:`evpose.core.importers.prophesee_sensors`), else needs ``--width/--height``. An empty file, one without a ``%`` header, or a header naming no version is refused as not
a Prophesee recording. The version comes from the header too (``% evt 2.0|3.0``, DAT ``% Version``); EVT 2.1 is
refused (faery cannot decode it). External trigger events are counted and ignored; unknown EVT 2.0 words are
counted (``evt2_words_unknown``, ``evt3_words_unknown``) and warned about; EVT 3.0 TIME_LOW words that step back
within their TIME_HIGH are counted (``evt3_time_low_back``) and said in the report.

Time: µs of the sensor clock (since the camera started), int64, plus the header's ``t0`` when a writer stored one;
a trajectory in another clock needs the clock prior ``--offset-us``. The Metavision time counters wrap: EVT 3.0
carries 24 bits (a wrap every 16.8 s), EVT 2.0 34 bits (every 4.77 h), DAT 32 bits (every 71.6 min); all three are
unwrapped, and the tests pin each wrap (EVT 3.0: a TIME_HIGH that falls by more than half its range).

A file whose last word is cut off (a recording stopped mid-write) loses that partial word: a warning, not an
error.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evpose.core.importers.failure import wrap_errors
from evpose.core.importers.object_args import collect_objects
from evpose.core.importers.pose_text import read_pose_text
from evpose.core.importers.prophesee_header import open_decoder, warn_partial_word
from evpose.core.importers.evt3_words import Evt3Words
from evpose.core.importers.prophesee_words import DatWords, Evt2Words
from evpose.core.importers.recording import build_recording_scene, recording_camera, recording_sources
from evpose.core.importers.report import ImportContext
from evpose.core.importers.scene_builder import events_only

SUFFIXES = (".raw", ".dat")
#: Words are decoded in chunks of this many before validation.
CHUNK_EVENTS = 1 << 20


def import_prophesee(sources, out, ctx: ImportContext) -> dict:
    """Import an EVT 2.0 / EVT 3.0 ``.raw`` or ``.dat`` recording (+ trajectory, calibration); returns the summary."""
    rec, traj_file, calib = recording_sources(sources, "prophesee", SUFFIXES)
    objects = collect_objects(ctx, None)
    traj = None
    if traj_file is None:                 # a Prophesee recording holds no poses
        events_only(ctx, rec, objects)
    else:
        traj = read_pose_text(traj_file, ctx)
        ctx.report.assume(f"{traj_file.name}: poses are T_base_cam (camera in the base frame, metres)")
    decoder, head = open_decoder(rec, ctx)
    warn_partial_word(ctx, rec, head)
    camera = recording_camera(ctx, calib, head.size, rec)
    ctx.report.details["prophesee"] = {"version": head.version, "sensor": list(head.size), "header_bytes": head.length}
    with decoder:
        return build_recording_scene(ctx, out, rec, camera, _word_chunks(ctx, rec, head), lambda: traj, objects)


def _word_chunks(ctx: ImportContext, rec: Path, head):
    """``(x, y, t, p, record, fraction)`` chunks of EVT 2.0 / EVT 3.0 / DAT words decoded here, times unchanged."""
    evt2 = head.version == "evt2"
    if head.version == "evt3":
        words, dtype = Evt3Words(head.t0_us), np.dtype("<u2")
    else:
        words = Evt2Words(head.t0_us) if evt2 else DatWords(head.version, head.t0_us)
        dtype = np.dtype("<u4" if evt2 else "<u8")
    size = max(os.path.getsize(rec), 1)
    n = 0
    with open(rec, "rb") as f:
        f.seek(head.payload)
        while True:
            with wrap_errors(rec, f"events after {n:,}", "-", "cannot read"):
                block = np.fromfile(f, dtype, CHUNK_EVENTS)
            if len(block) == 0:
                break
            x, y, t, p = words.decode(block)
            yield x, y, t, p, f"events [{n}, {n + len(t)})", f.tell() / size
            n += len(t)
    if head.version in ("evt2", "evt3"):
        _report_words(ctx, rec, words, head.version)


def _report_words(ctx: ImportContext, rec: Path, words, version: str) -> None:
    """What a word decoder (:class:`Evt2Words`, :class:`Evt3Words`) counted, into the import report."""
    rep, key, name = ctx.report, version, {"evt2": "EVT 2.0", "evt3": "EVT 3.0"}[version]
    if words.n_triggers:
        rep.assume(f"{rec.name}: {words.n_triggers} external trigger event(s) ignored")
    if words.n_skipped:
        rep.counts[f"{key}_words_skipped"] = words.n_skipped
    if getattr(words, "n_time_low_back", 0):
        rep.counts["evt3_time_low_back"] = words.n_time_low_back
        rep.assume(f"{rec.name}: {words.n_time_low_back} TIME_LOW word(s) step back within their TIME_HIGH; their "
                   "events keep the times as written (as OpenEB reads them) and are put in order")
    if getattr(words, "n_no_time", 0):
        rep.counts["evt3_events_before_time"] = words.n_no_time
        rep.warn(f"{rec.name}: {words.n_no_time} event(s) before the stream's first TIME_HIGH and TIME_LOW have no "
                 "time: left out")
    if words.n_unknown:
        rep.counts[f"{key}_words_unknown"] = words.n_unknown
        rep.warn(f"{rec.name}: {words.n_unknown} {name} word(s) of unknown type skipped (first: word "
                 f"{words.first_unknown:,} after the header); the file may be damaged or of another version")
