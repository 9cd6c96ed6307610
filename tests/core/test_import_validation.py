"""Importer validation, one test per case: unsorted/overlapping/late events, out-of-sensor events, duplicate and
non-monotonic pose times, NaN, non-unit quaternions, non-orthonormal rotations, time-unit guessing, empty
topics/files, atomicity (failure, cancel, Ctrl-C), parsers of calibration files."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from test_importers import (  # noqa: F401
    assert_events_equal,
    assert_traj_equal,
    epose_windows,
    no_leftovers,
    read_scene,
    src,
    write_bag,
    write_epose_export,
    write_npz,
    write_rpg,
    write_ycbev,
)

from evpose.core.data.events import Cancelled, EventArray
from evpose.core.data.trajectory import Trajectory
from evpose.core.importers import ImportFailure, import_scene
from evpose.core.importers.calibration_formats import load_yaml_mapping
from evpose.core.importers.time_guess import guess_time_unit


def _npz(src, tmp_path, **kw):
    return write_npz(tmp_path / "rec.npz", kw.pop("ev", src.ev), kw.pop("traj", src.traj), src.cam, **kw)


# ------------------------------------------------------------------------------------------------ events
def test_unsorted_events_inside_a_chunk_are_sorted(src, tmp_path):
    ev = src.ev
    order = np.arange(len(ev))
    swap = np.flatnonzero(np.diff(ev.t) > 0)[::97][:500]          # swap neighbours with different times
    order[swap], order[swap + 1] = swap + 1, swap
    p = _npz(src, tmp_path, ev=ev[order])
    import_scene("npz", [p], tmp_path / "scene")
    got, _, _, rep = read_scene(tmp_path / "scene")
    assert_events_equal(got, ev)
    assert rep["counts"]["events_decreasing_steps"] == len(swap)
    assert any("sorted events inside" in r for r in rep["repairs"])


def test_overlapping_bag_messages_are_merged(src, tmp_path):
    ev = src.ev
    M = 20_000
    msgs = [np.arange(i, min(i + M, len(ev))) for i in range(0, len(ev), M)]
    for k in range(len(msgs) - 1):                                 # exchange 30 events across each boundary
        a, b = msgs[k], msgs[k + 1]
        msgs[k], msgs[k + 1] = np.concatenate([a[:-30], b[:30]]), np.concatenate([a[-30:], b[30:]])
    bag = write_bag(tmp_path / "o.bag", ev, src.traj, reorder=msgs, numpy_encode=True, width=173, height=130)
    import_scene("epose-bag", [bag], tmp_path / "scene", camera=str(src.cam_json))
    got, _, _, rep = read_scene(tmp_path / "scene")
    assert np.all(np.diff(got.t) >= 0)
    key = lambda e: np.lexsort((e.p, e.y, e.x, e.t))              # noqa: E731 equal times may swap order
    for f in "xytp":
        np.testing.assert_array_equal(getattr(got, f)[key(got)], getattr(ev, f)[key(ev)])
    assert rep["counts"]["chunks_overlapping"] == len(msgs) - 1


def test_late_events_refused_or_dropped(src, tmp_path):
    ev = src.ev
    M = 20_000
    msgs = [np.arange(i, min(i + M, len(ev))) for i in range(0, len(ev), M)]
    late = msgs[0][:10]
    msgs[0] = msgs[0][10:]
    msgs[-1] = np.concatenate([late, msgs[-1]])                   # 0.7 s late: beyond the 100 ms window
    bag = write_bag(tmp_path / "late.bag", ev, src.traj, reorder=msgs, numpy_encode=True)
    with pytest.raises(ImportFailure) as ei:
        import_scene("epose-bag", [bag], tmp_path / "s1", camera=str(src.cam_json))
    msg = str(ei.value)
    assert "late.bag" in msg and f"message {len(msgs) - 1} on /dvs/events" in msg and ": t:" in msg
    assert not (tmp_path / "s1").exists()
    no_leftovers(tmp_path)
    import_scene("epose-bag", [bag], tmp_path / "s2", camera=str(src.cam_json), repair=True)
    got, _, _, rep = read_scene(tmp_path / "s2")
    assert rep["counts"]["events_dropped_late"] == 10 and len(got) == len(ev) - 10
    # a larger reorder window takes them in
    import_scene("epose-bag", [bag], tmp_path / "s3", camera=str(src.cam_json), reorder_window_us=1_000_000)
    got, _, _, _ = read_scene(tmp_path / "s3")
    assert_events_equal(got, ev)


def test_out_of_sensor_events_refused_or_dropped_and_counted(src, tmp_path):
    """Issue 22: without --repair an event off the sensor is refused (it used to be dropped silently)."""
    ev = src.ev
    x = ev.x.astype(np.int16).copy()
    y = ev.y.astype(np.int16).copy()
    bad = [5, 1000, 200_000]
    x[5], y[1000], x[200_000] = 173, -1, 5000
    p = tmp_path / "r.npz"
    np.savez(p, x=x, y=y, t=ev.t, p=ev.p, t_us=src.traj.t_us, position=src.traj.positions_m,
             quaternion=src.traj.quats_xyzw, K=src.cam.K, dist=src.cam.dist, width=173, height=130)
    with pytest.raises(ImportFailure, match=r"r\.npz: events \[0, \d+\), event 5: x: 173 is outside the 173x130 "
                                            r"sensor .*--repair"):
        import_scene("npz", [p], tmp_path / "refused")
    import_scene("npz", [p], tmp_path / "scene", repair=True)
    got, _, _, rep = read_scene(tmp_path / "scene")
    keep = np.ones(len(ev), bool)
    keep[bad] = False
    assert_events_equal(got, ev[keep])
    assert rep["counts"]["events_dropped_outside_sensor"] == 3
    assert any("outside the 173x130 sensor" in r for r in rep["repairs"])


def test_bad_polarity_and_fractional_pixels_refused(src, tmp_path):
    ev = src.ev[np.arange(1000)]
    pp = ev.p.astype(np.int64)
    pp[7] = 3
    p = write_npz(tmp_path / "a.npz", EventArray(ev.x, ev.y, ev.t, ev.p), src.traj, src.cam)
    np.savez(tmp_path / "b.npz", **{**dict(np.load(p)), "p": pp})
    with pytest.raises(ImportFailure, match=r"b\.npz: events \[0, 1000\), event 7: p: polarity must be 0/1"):
        import_scene("npz", [tmp_path / "b.npz"], tmp_path / "s")
    xf = ev.x.astype(float)
    xf[3] = 2.5
    np.savez(tmp_path / "c.npz", **{**dict(np.load(p)), "x": xf})
    with pytest.raises(ImportFailure, match=r"c\.npz: events \[0, 1000\), event 3: x: expected an integer"):
        import_scene("npz", [tmp_path / "c.npz"], tmp_path / "s")
    no_leftovers(tmp_path)


def test_nan_event_time_refused_or_dropped(src, tmp_path):
    t = src.ev.t / 1e6
    t[123] = np.nan
    p = _npz(src, tmp_path, t=t)
    with pytest.raises(ImportFailure, match=r"rec\.npz: event 123: t: not finite"):
        import_scene("npz", [p], tmp_path / "s1")
    import_scene("npz", [p], tmp_path / "s2", repair=True)
    got, _, _, rep = read_scene(tmp_path / "s2")
    assert len(got) == len(src.ev) - 1 and rep["counts"]["events_dropped_nonfinite_t"] == 1


def test_nan_pixel_refused(src, tmp_path):
    x = src.ev.x.astype(float)
    x[42] = np.inf
    p = write_npz(tmp_path / "r.npz", src.ev, src.traj, src.cam)
    np.savez(p, **{**dict(np.load(p)), "x": x})
    with pytest.raises(ImportFailure, match=r"r\.npz: events \[0, \d+\), event 42: x: not finite"):
        import_scene("npz", [p], tmp_path / "s1")
    import_scene("npz", [p], tmp_path / "s2", repair=True)
    got, _, _, rep = read_scene(tmp_path / "s2")
    assert len(got) == len(src.ev) - 1


# ------------------------------------------------------------------------------------------------ poses
def test_duplicate_and_non_monotonic_pose_times(src, tmp_path):
    tr = src.traj
    # exact duplicate sample: dropped and reported, no --repair needed
    idx = np.insert(np.arange(len(tr)), 10, 10)
    dup = Trajectory.__new__(Trajectory)
    p = write_npz(tmp_path / "a.npz", src.ev, tr, src.cam)
    base = dict(np.load(p))
    np.savez(tmp_path / "dup.npz", **{**base, "t_us": tr.t_us[idx], "position": tr.positions_m[idx],
                                      "quaternion": tr.quats_xyzw[idx]})
    import_scene("npz", [tmp_path / "dup.npz"], tmp_path / "s1")
    _, got, _, rep = read_scene(tmp_path / "s1")
    assert_traj_equal(got, tr)
    assert any("repeated timestamp" in r for r in rep["repairs"])
    # conflicting duplicate: refused naming the record, kept-last with --repair
    pos = tr.positions_m[idx].copy()
    pos[11] += 0.01
    np.savez(tmp_path / "conf.npz", **{**base, "t_us": tr.t_us[idx], "position": pos, "quaternion": tr.quats_xyzw[idx]})
    with pytest.raises(ImportFailure, match=r"conf\.npz: pose 11: t_us: time repeats with a different pose"):
        import_scene("npz", [tmp_path / "conf.npz"], tmp_path / "s2")
    import_scene("npz", [tmp_path / "conf.npz"], tmp_path / "s3", repair=True)
    _, got, _, _ = read_scene(tmp_path / "s3")
    assert len(got) == len(tr) and np.allclose(got.positions_m[10], pos[11])
    # decreasing times
    o = np.arange(len(tr))
    o[20], o[21] = 21, 20
    np.savez(tmp_path / "dec.npz", **{**base, "t_us": tr.t_us[o], "position": tr.positions_m[o],
                                      "quaternion": tr.quats_xyzw[o]})
    with pytest.raises(ImportFailure, match=r"dec\.npz: pose 21: t_us: time decreases"):
        import_scene("npz", [tmp_path / "dec.npz"], tmp_path / "s4")
    import_scene("npz", [tmp_path / "dec.npz"], tmp_path / "s5", repair=True)
    _, got, _, rep = read_scene(tmp_path / "s5")
    assert_traj_equal(got, tr)
    assert any("sorted 1 out-of-order" in r for r in rep["repairs"])
    no_leftovers(tmp_path)
    del dup


def test_nan_pose_in_text_names_line_and_field(src, tmp_path):
    folder = write_rpg(tmp_path / "seq", src.ev, src.traj, src.cam, n=2000)
    lines = (folder / "groundtruth.txt").read_text().splitlines()
    tok = lines[4].split()
    tok[6] = "nan"
    lines[4] = " ".join(tok)
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(ImportFailure, match=r"groundtruth\.txt: line 5: qz: not finite"):
        import_scene("rpg", [folder], tmp_path / "s", width=173, height=130)


def test_non_unit_quaternions_normalised(src, tmp_path):
    p = write_npz(tmp_path / "a.npz", src.ev, src.traj, src.cam)
    q = src.traj.quats_xyzw * np.linspace(0.5, 2.0, len(src.traj))[:, None]
    np.savez(tmp_path / "q.npz", **{**dict(np.load(p)), "quaternion": q})
    import_scene("npz", [tmp_path / "q.npz"], tmp_path / "s")
    _, got, _, rep = read_scene(tmp_path / "s")
    assert_traj_equal(got, src.traj)
    assert any("normalised" in r and "non-unit quaternion" in r for r in rep["repairs"])


def test_non_orthonormal_rotation_refused_then_projected(src, tmp_path):
    T = src.traj.T()
    T[5, :3, :3] *= 1.05                                            # residual ~0.1
    p = write_npz(tmp_path / "a.npz", src.ev, src.traj, src.cam, T_base_cam=True)
    np.savez(tmp_path / "r.npz", **{**dict(np.load(p)), "T_base_cam": T})
    with pytest.raises(ImportFailure, match=r"r\.npz: pose 5: T: rotation is not orthonormal .* pass --repair"):
        import_scene("npz", [tmp_path / "r.npz"], tmp_path / "s1")
    import_scene("npz", [tmp_path / "r.npz"], tmp_path / "s2", repair=True)
    _, got, _, rep = read_scene(tmp_path / "s2")
    assert_traj_equal(got, src.traj, tol=1e-9)                     # uniform scale: projection is exact
    assert any("projected onto SO(3)" in r and "pose 5" in r for r in rep["repairs"])
    # a T_base_obj file given by the user
    Tobj = np.asarray(src.man.objects[0].T_base_obj_raw).copy()
    Tobj[0, 0] += 0.2
    tf = tmp_path / "T_bad.json"
    tf.write_text(json.dumps(Tobj.tolist()))
    with pytest.raises(ImportFailure, match=r"T_bad\.json: \(file\): T_base_obj: rotation is not orthonormal"):
        import_scene("npz", [p], tmp_path / "s3", repair=False, objects=f"box={src.man.objects[0].mesh}:{tf}")
    import_scene("npz", [tmp_path / "r.npz"], tmp_path / "s4", repair=True, objects=f"box={src.man.objects[0].mesh}:{tf}")
    _, _, man, _ = read_scene(tmp_path / "s4")
    assert man.object("box").repair_rotation and man.object("box").rotation_residual > 0.1
    no_leftovers(tmp_path)


# ------------------------------------------------------------------------------------------------ time units
@pytest.mark.parametrize("unit", ["s", "ms", "us", "ns"])
def test_time_unit_guessed_and_reported(src, tmp_path, unit, capsys):
    t = {"s": src.ev.t / 1e6, "ms": src.ev.t / 1e3, "us": src.ev.t, "ns": src.ev.t * 1000}[unit]
    pt = {"s": src.traj.t_us / 1e6, "ms": src.traj.t_us / 1e3, "us": src.traj.t_us, "ns": src.traj.t_us * 1000}[unit]
    p = write_npz(tmp_path / "a.npz", src.ev, src.traj, src.cam)
    d = dict(np.load(p))
    del d["t_us"]
    np.savez(tmp_path / "u.npz", **{**d, "t": t, "pose_t": pt})
    import_scene("npz", [tmp_path / "u.npz"], tmp_path / "s", log=print)
    got, traj, _, rep = read_scene(tmp_path / "s")
    assert_events_equal(got, src.ev)
    assert_traj_equal(traj, src.traj)
    tu = rep["time_units"]
    assert tu["u.npz:t (events)"]["unit"] == unit and tu["u.npz:pose_t"]["unit"] == unit
    out = capsys.readouterr().out
    assert "assumed: u.npz:t (events): times in" in out            # also echoed by the log (stderr in the CLI)


def test_time_unit_forced(src, tmp_path):
    p = write_npz(tmp_path / "a.npz", src.ev, src.traj, src.cam, t=src.ev.t * 1000)
    import_scene("npz", [p], tmp_path / "s", time_unit="ns")
    got, _, _, rep = read_scene(tmp_path / "s")
    assert_events_equal(got, src.ev)
    assert rep["time_units"]["a.npz:t (events)"]["why"] == "--time-unit"


def test_guess_time_unit_rules():
    rng = np.random.default_rng(0)
    rel_us = np.cumsum(rng.integers(0, 3, 100_000))                 # ~1 M ev/s relative µs
    assert guess_time_unit(rel_us, kind="events")[0] == "us"
    assert guess_time_unit(rel_us * 1000, kind="events")[0] == "ns"
    assert guess_time_unit(rel_us / 1e6, kind="events")[0] == "s"
    assert guess_time_unit(1.7e12 + rel_us / 1e3, kind="events")[0] == "ms"     # epoch milliseconds
    poses = np.arange(200) * 4000                                    # 250 Hz
    assert guess_time_unit(poses, kind="poses")[0] == "us"
    assert guess_time_unit(poses / 1e6, kind="poses")[0] == "s"
    assert guess_time_unit(poses * 1000, kind="poses")[0] == "ns"
    assert guess_time_unit(1_468_940_293.0 + poses / 1e6, kind="poses")[0] == "s"


def test_rpg_wrong_unit_detected(src, tmp_path):
    """events.txt with integer µs instead of seconds: the format says seconds, the numbers say µs (warned)."""
    folder = write_rpg(tmp_path / "seq", src.ev, src.traj, src.cam, n=0)
    ev = src.ev[np.arange(50_000)]
    (folder / "events.txt").write_text("".join(f"{t} {x} {y} {p}\n" for t, x, y, p in zip(ev.t, ev.x, ev.y, ev.p)))
    import_scene("rpg", [folder], tmp_path / "s", width=173, height=130)
    got, _, _, rep = read_scene(tmp_path / "s")
    assert_events_equal(got, ev)
    assert any("format specifies seconds" in w and "microseconds" in w for w in rep["warnings"])


def test_rpg_float_fallback_block(src, tmp_path):
    folder = write_rpg(tmp_path / "seq", src.ev, src.traj, src.cam, n=0)
    ev = src.ev[np.arange(20_000)]
    (folder / "events.txt").write_text("# t x y p\n" + "".join(
        f"{t / 1e6:.15e} {x} {y} {p}\n" for t, x, y, p in zip(ev.t, ev.x, ev.y, ev.p)))
    import_scene("rpg", [folder], tmp_path / "s", width=173, height=130)
    got, _, _, rep = read_scene(tmp_path / "s")
    assert np.abs(got.t - ev.t).max() <= 1                           # 7 significant digits of 1.7e9 s: ~µs
    assert any("parsed as float64" in a for a in rep["assumptions"])
    (folder / "events.txt").write_text("0.5 1 2 1\n0.6 1 2 0\n0.7 x 2 1\n")
    with pytest.raises(ImportFailure, match=r"events\.txt: line 3: -: not a table"):
        import_scene("rpg", [folder], tmp_path / "s2", width=173, height=130)


# ------------------------------------------------------------------------------------------------ empty inputs
def test_empty_topics_and_files(src, tmp_path):
    b1 = write_bag(tmp_path / "nopose.bag", src.ev[np.arange(100)], src.traj, poses=False, numpy_encode=True)
    with pytest.raises(ImportFailure, match=r"nopose\.bag: \(topics\): /dvs/pose: the topic has no messages"):
        import_scene("epose-bag", [b1], tmp_path / "s", camera=str(src.cam_json))
    b2 = write_bag(tmp_path / "noev.bag", src.ev, src.traj, events=False, numpy_encode=True)
    with pytest.raises(ImportFailure, match=r"noev\.bag: \(topics\): /dvs/events: the topic has no messages"):
        import_scene("epose-bag", [b2], tmp_path / "s", camera=str(src.cam_json))
    with pytest.raises(ImportFailure, match=r"nopose\.bag: \(topics\): /other: no such topic"):
        import_scene("epose-bag", [b1], tmp_path / "s", camera=str(src.cam_json), pose_topic="/other")
    (tmp_path / "empty.bag").write_bytes(b"")
    with pytest.raises(ImportFailure, match=r"empty\.bag: \(bag header/index\)"):
        import_scene("epose-bag", [tmp_path / "empty.bag"], tmp_path / "s")
    e = EventArray.empty()
    p = write_npz(tmp_path / "e.npz", e, src.traj, src.cam)
    with pytest.raises(ImportFailure, match=r"e\.npz: array 't': t: no events"):
        import_scene("npz", [p], tmp_path / "s")
    folder = write_rpg(tmp_path / "seq", src.ev, src.traj, src.cam, n=0)
    with pytest.raises(ImportFailure, match=r"events\.txt: \(all records\): events: no events"):
        import_scene("rpg", [folder], tmp_path / "s", width=173, height=130)
    (folder / "groundtruth.txt").write_text("# nothing\n")
    with pytest.raises(ImportFailure, match=r"groundtruth\.txt: \(file\): t: no pose samples"):
        import_scene("rpg", [folder], tmp_path / "s", width=173, height=130)
    assert not (tmp_path / "s").exists()
    no_leftovers(tmp_path)


def test_bag_header_stamps_zero_fall_back_to_record_time(src, tmp_path):
    from evpose.core.importers.epose_bag_codec import encode_pose_stamped, parse_pose_stamped

    t, v = parse_pose_stamped(encode_pose_stamped(1_500_000_000_123_456_789, [1, 2, 3], [0, 0, 0, 1], frame_id="b"))
    assert t == 1_500_000_000_123_457 and v.tolist() == [1, 2, 3, 0, 0, 0, 1]


# ------------------------------------------------------------------------------------------------ atomicity
def test_cancel_and_interrupt_leave_nothing(src, tmp_path):
    p = write_npz(tmp_path / "a.npz", src.ev, src.traj, src.cam)
    calls = []
    with pytest.raises(Cancelled):
        import_scene("npz", [p], tmp_path / "scene", cancel=lambda: (calls.append(1), len(calls) > 1)[1])
    assert not (tmp_path / "scene").exists()
    no_leftovers(tmp_path)

    def boom(f, m):
        if f > 0.1:
            raise KeyboardInterrupt

    folder = write_rpg(tmp_path / "seq", src.ev, src.traj, src.cam)
    with pytest.raises(KeyboardInterrupt):
        import_scene("rpg", [folder], tmp_path / "scene", width=173, height=130, progress=boom)
    assert not (tmp_path / "scene").exists()
    no_leftovers(tmp_path)
    # an existing scene survives a failed --force import untouched
    import_scene("npz", [p], tmp_path / "scene")
    before = sorted(q.name for q in (tmp_path / "scene").iterdir())
    with pytest.raises(Cancelled):
        import_scene("npz", [p], tmp_path / "scene", force=True, cancel=lambda: True)
    assert sorted(q.name for q in (tmp_path / "scene").iterdir()) == before
    with pytest.raises(ImportFailure, match=r"scene: \(output\): --out: the folder exists and is not empty"):
        import_scene("npz", [p], tmp_path / "scene")
    no_leftovers(tmp_path)


# ------------------------------------------------------------------------------------------------ epose-export specifics
def test_epose_export_one_based_and_boundary(src, tmp_path):
    import scipy.io

    folder = tmp_path / "exp"
    edge = int(np.flatnonzero((src.ev.x == 172) | (src.ev.y == 129))[0])
    wins = write_epose_export(folder, src, n_windows=(int(src.ev.t[edge]) - int(src.ev.t[0])) // 10_000 + 2)
    for f in sorted(folder.glob("*_data.mat")):                     # rewrite with 1-based pixels
        d = scipy.io.loadmat(f)
        if d["events"].size:
            d["events"][:, :2] += 1
        scipy.io.savemat(f, {k: v for k, v in d.items() if not k.startswith("__")})
    meshes = ",".join(f"{o.name}={o.mesh}:{src.T_files[o.name]}" for o in src.man.objects)
    import_scene("epose-export", [folder], tmp_path / "s1", objects=meshes, one_based=True, width=173, height=130)
    got, _, _, rep = read_scene(tmp_path / "s1")
    n = int(wins[-1][0][-1]) + 1
    assert_events_equal(got, src.ev[np.arange(n)])
    # issue 22: events off the sensor are refused without --repair (they were dropped silently), with the hint
    with pytest.raises(ImportFailure, match=r"y: 130 is outside the 173x130 sensor .*1-based: --one-based"):
        import_scene("epose-export", [folder], tmp_path / "refused", objects=meshes, width=173, height=130)
    import_scene("epose-export", [folder], tmp_path / "s2", objects=meshes, width=173, height=130, repair=True)
    _, _, _, rep = read_scene(tmp_path / "s2")
    assert rep["counts"].get("events_dropped_outside_sensor", 0) > 0
    assert any("1-based" in w for w in rep["warnings"])


def test_epose_export_matlab_v73(src, tmp_path):
    """MATLAB -v7.3 files are HDF5 with column-major (transposed) datasets."""
    import h5py

    folder = tmp_path / "exp"
    folder.mkdir()
    wins = write_epose_export(tmp_path / "ref", src, n_windows=5)
    import scipy.io

    for f in sorted((tmp_path / "ref").glob("*.mat")):
        d = scipy.io.loadmat(f)
        with h5py.File(folder / f.name, "w", userblock_size=512) as h:
            for k in ("events", "pose", "time", "intrinsicMatrix", "cls_index"):
                h.create_dataset(k, data=np.asarray(d[k], float).T)
        with open(folder / f.name, "r+b") as fh:                      # MATLAB's 128-byte header (version 0x0200)
            fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
                     .ljust(116) + bytes(8) + b"\x00\x02IM")
    meshes = ",".join(f"{o.name}={o.mesh}:{src.T_files[o.name]}" for o in src.man.objects)
    import_scene("epose-export", [folder], tmp_path / "s", objects=meshes)
    got, _, _, _ = read_scene(tmp_path / "s")
    n = int(wins[-1][0][-1]) + 1
    assert_events_equal(got, src.ev[np.arange(n)])


# ------------------------------------------------------------------------------------------------ parsers
def test_yaml_calibration_is_read_with_a_yaml_library(tmp_path):
    """PyYAML reads block and flow lists, comments, quoted scalars and OpenCV's ``%YAML:1.0`` header."""
    text = """%YAML:1.0
---
# comment
intrinsics:
  cam0:
    camera_matrix: [553.5, 553.4, 346.6, 216.5]   # fx fy cx cy
    distortion_coeffs:
    - -0.094
    - 1e-05
    - 0
    - 0
    model: 'pinhole'
    nested:
    - [1, 2]
    - [3, 4.5]
    resolution: [346, 260]
empty:
flag: true
"""
    d = load_yaml_mapping(text, "c.yaml")
    assert d["intrinsics"]["cam0"]["camera_matrix"] == [553.5, 553.4, 346.6, 216.5]
    assert d["intrinsics"]["cam0"]["nested"] == [[1, 2], [3, 4.5]] and d["intrinsics"]["cam0"]["model"] == "pinhole"
    assert d["empty"] is None and d["flag"] is True
    from evpose.core.importers.calibration import load_camera
    from evpose.core.importers.report import ImportContext

    (tmp_path / "c.yaml").write_text(text)
    cam = load_camera(tmp_path / "c.yaml", ImportContext("t", [], log=None))
    assert cam.K[0, 0] == 553.5 and cam.K[1, 2] == 216.5 and (cam.width, cam.height) == (346, 260)
    np.testing.assert_array_equal(cam.dist, [-0.094, 1e-05, 0, 0])     # YAML 1.1 reads 1e-05 as text: still a number


@pytest.mark.parametrize("text, where", [
    ("intrinsics:\n  cam0:\n\tcamera_matrix: [1, 2, 3, 4]\n", r"line 3, column 1: -: not valid YAML"),
    ("intrinsics:\n  cam0:\n    camera_matrix: [1, 2\n",
     r"line 4, column 1: -: not valid YAML \(expected ',' or '\]'.* flow sequence that starts at line 3\)"),
    ("a:\n  b: 1\n    c: 2\n", r"line 3, column \d+: -: not valid YAML"),
    ("intrinsics: {cam0: [1, 2}\n", r"line 1, column \d+: -: not valid YAML"),
    ("# nothing but a comment\n", r"\(file\): -: empty YAML document"),
    ("- 1\n- 2\n", r"\(file\): -: expected a mapping at the top level, got a list"),
])
def test_malformed_yaml_names_the_file_and_line(tmp_path, text, where):
    from evpose.core.importers.calibration import load_camera
    from evpose.core.importers.report import ImportContext

    (tmp_path / "cam.yaml").write_text(text)
    with pytest.raises(ImportFailure, match=r"cam\.yaml: " + where):
        load_camera(tmp_path / "cam.yaml", ImportContext("t", [], log=None))


@pytest.mark.parametrize("cam0, record, field, message", [
    ("[1, 2, 3, 4]", "intrinsics", "cam0", "expected a mapping, got a list"),
    ("{camera_matrix: hello, resolution: [346, 260]}", "intrinsics.cam0", "camera_matrix",
     "expected numbers, got 'hello'"),
    ("{camera_matrix: {fx: 1}, resolution: [346, 260]}", "intrinsics.cam0", "camera_matrix",
     "expected numbers, got a mapping"),
    ("{camera_matrix: [1, 1, true, 1], resolution: [346, 260]}", "intrinsics.cam0", "camera_matrix",
     "expected numbers, got True"),
    ("{camera_matrix: [[[1]], 1, 1, 1], resolution: [346, 260]}", "intrinsics.cam0", "camera_matrix",
     "expected a list of numbers, got lists nested too deeply"),
    ("{camera_matrix: [1, 1, 1], resolution: [346, 260]}", "intrinsics.cam0", "camera_matrix",
     "expected \\[fx, fy, cx, cy\\], got 3 numbers"),
    ("{camera_matrix: [1, 1, 1, 1], distortion_coeffs: [a, b, c, d], resolution: [346, 260]}", "intrinsics.cam0",
     "distortion_coeffs", "expected numbers, got 'a'"),
    ("{camera_matrix: [1, 1, 1, 1], resolution: [wide, 260]}", "intrinsics.cam0", "resolution",
     "expected an integer number of pixels, got 'wide'"),
    ("{camera_matrix: [1, 1, 1, 1], resolution: [[346], 260]}", "intrinsics.cam0", "resolution",
     "expected an integer number of pixels, got a list"),
    ("{camera_matrix: [1, 1, 1, 1], distortion_model: [radtan]}", "intrinsics.cam0", "distortion_model",
     "\"\\['radtan'\\]\" is not supported"),
])
def test_yaml_with_unexpected_types_names_the_file_and_field(tmp_path, cam0, record, field, message):
    """Values of the wrong type end in one error naming the file, the entry and the field -- never a
    TypeError, and never a silently wrong camera (``true`` is not 1.0)."""
    from evpose.core.importers.calibration import load_camera
    from evpose.core.importers.report import ImportContext

    (tmp_path / "cam.yaml").write_text(f"intrinsics:\n  cam0: {cam0}\n")
    with pytest.raises(ImportFailure, match=rf"cam\.yaml: {re.escape(record)}: {field}: {message}"):
        load_camera(tmp_path / "cam.yaml", ImportContext("t", [], log=None))


@pytest.mark.parametrize("bomb, message", [
    ("wide", "more than 64 numbers"),              # a list of 1000 aliases of a list of 1000 numbers
    ("deep", "lists nested too deeply"),           # aliases of aliases: 10**9 numbers nine levels deep
])
def test_yaml_alias_bomb_is_refused_quickly(tmp_path, bomb, message):
    """Aliases nest references without copying: the checks stop long before anything is expanded."""
    from evpose.core.importers.calibration import load_camera
    from evpose.core.importers.report import ImportContext

    if bomb == "wide":
        lines, top = ["a0: &a0 [" + ", ".join(["1"] * 1000) + "]", "m: &m [" + ", ".join(["*a0"] * 1000) + "]"], "m"
    else:
        lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
        lines, top = lines + [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)], "a8"
    lines += ["intrinsics:", "  cam0:", f"    camera_matrix: *{top}", "    resolution: [346, 260]"]
    (tmp_path / "cam.yaml").write_text("\n".join(lines) + "\n")
    with pytest.raises(ImportFailure, match=rf"cam\.yaml: intrinsics\.cam0: camera_matrix: .*{message}"):
        load_camera(tmp_path / "cam.yaml", ImportContext("t", [], log=None))


def test_camera_file_formats(src, tmp_path):
    from evpose.core.importers.calibration import load_camera
    from evpose.core.importers.report import ImportContext

    ctx = ImportContext("t", [], log=None)
    K, d = src.cam.K, src.cam.dist
    (tmp_path / "calib.txt").write_text(" ".join(repr(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d)))
    cam = load_camera(tmp_path / "calib.txt", ctx, default_size=(240, 180))
    assert (cam.width, cam.height) == (240, 180) and np.allclose(cam.K, K) and np.allclose(cam.dist, d)
    assert any("assumed 240x180" in a for a in ctx.report.assumptions)
    (tmp_path / "kalibr.yaml").write_text(f"cam0:\n  intrinsics: [{K[0, 0]}, {K[1, 1]}, {K[0, 2]}, {K[1, 2]}]\n"
                                          "  distortion_model: equidistant\n  distortion_coeffs: [0, 0, 0, 0]\n"
                                          "  resolution: [173, 130]\n")
    with pytest.raises(ImportFailure, match=r"kalibr\.yaml: cam0: distortion_model: 'equidistant' is not supported"):
        load_camera(tmp_path / "kalibr.yaml", ctx)
    (tmp_path / "bad.json").write_text('{"K": [[1, 0, 0], [0, 1, 0]], "width": 3, "height": 3}')
    with pytest.raises(ImportFailure, match=r"bad\.json: \(file\): K/dist: K: expected a 3x3"):
        load_camera(tmp_path / "bad.json", ctx)
    (tmp_path / "inf.json").write_text('{"K": [[1, 0, 1], [0, 1, 1], [0, 0, 1]], "width": Infinity, "height": 3}')
    with pytest.raises(ImportFailure, match=r"inf\.json: \(file\): width: expected an integer number of pixels"):
        load_camera(tmp_path / "inf.json", ctx)
    (tmp_path / "cv.json").write_text('{"camera_matrix": [[1, 0, 1], [0, 1, 1], [0, 0, 1]], "img_size": [3, 3], '
                                      '"distortion_coefficients": [["k1"]]}')
    with pytest.raises(ImportFailure, match=r"cv\.json: \(file\): distortion_coefficients: expected numbers, got 'k1'"):
        load_camera(tmp_path / "cv.json", ctx)


# ------------------------------------------------------------------------------------------------ input errors
def test_npz_T_base_cam_3x4_imports(src, tmp_path):
    """(N, 3, 4) transforms (the last row implied) are accepted, as the format says."""
    p = _npz(src, tmp_path, T_base_cam=True)
    with np.load(p) as z:
        d = dict(z)
    d["T_base_cam"] = d["T_base_cam"][:, :3, :]
    np.savez(p, **d)
    import_scene("npz", [p], tmp_path / "scene", log=None)
    _, traj, _, _ = read_scene(tmp_path / "scene")
    assert_traj_equal(traj, src.traj)


def test_npz_width_height_not_integers(src, tmp_path):
    p = _npz(src, tmp_path, width=np.array(["wide"]))
    with pytest.raises(ImportFailure, match=r"rec\.npz: \(archive\): width/height: expected integers, got "):
        import_scene("npz", [p], tmp_path / "scene", log=None)
    assert not (tmp_path / "scene").exists()


def test_objects_T_file_nested_too_deeply(src, tmp_path):
    p = _npz(src, tmp_path)
    mesh = src.man.objects[0].mesh
    (tmp_path / "T.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ImportFailure, match=r"T\.json: \(file\): T_base_obj: JSON nested too deeply"):
        import_scene("npz", [p], tmp_path / "scene", objects=f"box={mesh}:{tmp_path / 'T.json'}", log=None)


def test_epose_export_singular_pose_block_after_repair(src, tmp_path):
    """A pose block with a zero rotation passes --repair's projection but cannot give a camera pose: refused,
    naming the window and the object (not a LinAlgError)."""
    wins = [b for _, b in epose_windows(src, 10_000, 6)]
    labels = src.labels(np.array(wins, np.int64)).copy()
    labels[3, 1, :3, :3] = 0.0
    write_epose_export(tmp_path / "w", src, n_windows=6, labels=labels)
    with pytest.raises(ImportFailure, match=r"w: frame 3: T_cam_obj \[cylinder\]: singular matrix"):
        import_scene("epose-export", [tmp_path / "w"], tmp_path / "scene", objects=src.objects_arg, width=173,
                     height=130, repair=True, log=None)
    no_leftovers(tmp_path)


def test_epose_export_cls_index_not_finite(src, tmp_path):
    write_epose_export(tmp_path / "w", src, n_windows=3, cls=(1, float("nan"), 3))
    with pytest.raises(ImportFailure, match=r"0001_data\.mat: window 1: cls_index: not finite"):
        import_scene("epose-export", [tmp_path / "w"], tmp_path / "scene", objects=src.objects_arg, width=173,
                     height=130, log=None)


def test_epose_export_intrinsics_only_in_later_windows(src, tmp_path):
    """The first window without ``intrinsicMatrix`` (calibration from --camera) and later ones with it."""
    import scipy.io

    write_epose_export(tmp_path / "w", src, n_windows=3)
    first = tmp_path / "w" / "0001_data.mat"
    d = {k: v for k, v in scipy.io.loadmat(str(first)).items() if not k.startswith("__") and k != "intrinsicMatrix"}
    scipy.io.savemat(first, d)
    import_scene("epose-export", [tmp_path / "w"], tmp_path / "scene", objects=src.objects_arg,
                 camera=str(src.cam_json), log=None)
    assert (tmp_path / "scene" / "scene.toml").is_file()


def test_epose_export_classes_not_a_number(src, tmp_path):
    write_epose_export(tmp_path / "w", src, n_windows=1)
    with pytest.raises(ImportFailure, match=r"--classes: inf=box: cls: not a number"):
        import_scene("epose-export", [tmp_path / "w"], tmp_path / "scene", objects=src.objects_arg, classes="inf=box",
                     log=None)


@pytest.mark.parametrize("what", ["deep", "key", "huge_time"])
def test_ycbev_malformed_annotations(src, tmp_path, what):
    """Malformed BOP JSON ends in one error naming the file and the field (no RecursionError, StopIteration or
    OverflowError)."""
    seqd, _, _ = write_ycbev(tmp_path / "y", src, n_frames=4)
    if what == "deep":
        (seqd / "scene_gt.json").write_text("[" * 100_000 + "]" * 100_000)
        pattern = r"scene_gt\.json: \(file\): -: JSON nested too deeply"
    elif what == "key":
        gt = json.loads((seqd / "scene_gt.json").read_text())
        gt["\u00b2"] = gt.pop("1")                                  # '²' is a digit to str.isdigit, not to int()
        (seqd / "scene_gt.json").write_text(json.dumps(gt))
        pattern = r"scene_gt\.json: image '\u00b2': key: image ids must be integers"
    else:
        (seqd / "scene_times.json").write_text(json.dumps({str(i): {"t_label_us": 2**70} for i in range(4)}))
        pattern = r"scene_times\.json: \(file\): t_label_us: outside the int64 µs range"
    with pytest.raises(ImportFailure, match=pattern):
        import_scene("ycbev", [seqd], tmp_path / "scene", log=None)


@pytest.mark.parametrize("scenes, record, field", [
    ({"s": ["box"]}, "scenes/s", "-"),
    ({"s": {"objects": {"box": [["a", "b"], ["c", "d"]]}}}, "s/box", "T_base_obj"),
    ({"s": {"objects": {"box": [[1, 0, 0, 0], [0, 1, 0]]}}}, "s/box", "T_base_obj"),
])
def test_malformed_epose_scenes_json(src, tmp_path, scenes, record, field):
    from evpose.core.importers.epose_assets import load_epose_assets
    from evpose.core.importers.report import ImportContext

    assets = tmp_path / "assets"
    (assets / "models").mkdir(parents=True)
    (assets / "camera_davis346.json").write_text(src.cam_json.read_text())
    (assets / "scenes.json").write_text(json.dumps({"scenes": scenes}))
    with pytest.raises(ImportFailure, match=rf"scenes\.json: {re.escape(record)}: {re.escape(field)}: "):
        load_epose_assets(ImportContext("t", [], log=None), assets, "s", None)


def test_event_sink_bounded_stream_merge():
    """Overlapping chunks over a long stream: output sorted and complete, memory held back stays bounded."""
    from evpose.core.importers.event_sink import EventSink
    from evpose.core.importers.options import ImportOptions
    from evpose.core.importers.report import ImportContext

    class Collect:
        def __init__(self):
            self.parts = []

        def append(self, ev):
            self.parts.append(ev)

    rng = np.random.default_rng(5)
    n, chunk, window = 3_000_000, 20_000, 2_000
    t = np.sort(rng.integers(0, 3_000_000, n))                       # ~1 event/µs
    x, y, p = rng.integers(0, 100, n), rng.integers(0, 100, n), rng.integers(0, 2, n)
    order = np.arange(n)
    for i in range(chunk, n, chunk):                                  # each chunk overlaps the next by 100 events
        order[i - 100:i + 100] = np.concatenate([order[i:i + 100], order[i - 100:i]])
    ctx = ImportContext("t", [], ImportOptions(reorder_window_us=window), log=None)
    w = Collect()
    sink = EventSink(ctx, w, 100, 100, max_pending=1_500_000)
    held = 0
    for i in range(0, n, chunk):
        o = order[i:i + chunk]
        sink.add(x[o], y[o], t[o], p[o], file="f", record=f"chunk {i}")
        held = max(held, sink.n_pending)
    sink.close()
    got = EventArray.concatenate(w.parts)
    assert len(w.parts) > 2 and held <= 1_100_000                    # streamed, not held whole
    np.testing.assert_array_equal(got.t, t)
    assert sink.n_overlap_chunks == n // chunk - 1 and ctx.report.counts["chunks_overlapping"] == n // chunk - 1
