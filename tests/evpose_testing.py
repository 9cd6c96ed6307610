"""Helpers shared by tests (a uniquely named module: every test folder has its own conftest)."""
from __future__ import annotations


def half_davis_camera() -> dict:
    """DAVIS346 calibration at half resolution (173x130): same lens, 4x fewer pixels, fast tests."""
    from evpose.core.data.camera import CameraModel

    return CameraModel.davis346().binned(2).to_dict()


#: The shared synthetic scene: 3 objects, trajectory B at 0.5 m/s, clock offset and pose error injected.
TINY_SCENE = dict(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=0.8,
                  offset_us=20_000, skew_ppm=0.0, pose_error_mm=5.0, pose_error_deg=3.0, seed=3)


def msidx_cache_file(path):
    """Where EventStore caches the index and validation of an event file (the user cache dir)."""
    import hashlib
    from pathlib import Path

    from evpose.core.data.event_index import default_cache_dir

    return default_cache_dir() / f"{hashlib.sha1(str(Path(path).resolve()).encode()).hexdigest()}.npz"


def describe_file_differences(got: dict, ref: dict, root_got=None, root_ref=None) -> list[str]:
    """The names whose contents differ between two ``{name: bytes}`` trees (or, with ``root_got`` / ``root_ref``,
    two ``{name: digest}`` snapshots of those folders), each with what differs: for a PNG whether the decoded
    pixels are equal (only the deflate stream differs) or how many pixels of which channels differ; so that a
    rare byte difference says where it comes from when it happens."""
    from pathlib import Path

    import cv2
    import numpy as np

    out = []
    for name in sorted(k for k in got if k in ref and got[k] != ref[k]):
        a, b = got[name], ref[name]
        if root_got is not None:
            a, b = (Path(root_got) / name).read_bytes(), (Path(root_ref) / name).read_bytes()
        note = f"{len(a)} vs {len(b)} bytes"
        if name.endswith(".png"):
            ia = cv2.imdecode(np.frombuffer(a, np.uint8), cv2.IMREAD_UNCHANGED)
            ib = cv2.imdecode(np.frombuffer(b, np.uint8), cv2.IMREAD_UNCHANGED)
            if ia is None or ib is None or ia.shape != ib.shape:
                note += ", undecodable or of another shape"
            elif np.array_equal(ia, ib):
                same_raw = _png_scanlines(a) == _png_scanlines(b)
                note += (", same pixels and same scanlines (only the deflate stream differs)" if same_raw else
                         ", same pixels but other scanline bytes (filter bytes or padding differ)")
            else:
                diff = (ia != ib).reshape(ia.shape[0], ia.shape[1], -1)
                where = np.argwhere(diff.any(axis=2))
                chans = np.flatnonzero(diff.any(axis=(0, 1))).tolist()
                r, c = where[0]
                note += (f", {len(where)} pixels differ (channels {chans} in OpenCV's BGR order; first at row {r}, "
                         f"column {c}: {ia[r, c].tolist()} vs {ib[r, c].tolist()})")
        out.append(f"{name}: {note}")
    return out


def _png_scanlines(png: bytes) -> bytes | None:
    """The inflated IDAT data of a PNG (filter byte + row per scanline), or None when it cannot be read."""
    import struct
    import zlib

    pos, idat = 8, b""
    try:
        while pos < len(png):
            n, kind = struct.unpack(">I4s", png[pos:pos + 8])
            if kind == b"IDAT":
                idat += png[pos + 8:pos + 8 + n]
            pos += 12 + n
        return zlib.decompress(idat)
    except (struct.error, zlib.error):
        return None


# --------------------------------------------------------------------------- datasets of the dataset tests
#: ``tests/dataset/test_triage_verdicts.py``'s five scenes (bench/screenshot_dataset_view.py shows them too).
TRIAGE_SCENES = ("a_right", "b_clock", "c_pose", "d_mounting", "e_broken")
#: ``tests/dataset/test_campaign.py``'s campaign: one placement and mounting recorded at three speeds (m/s).
CAMPAIGN_SPEEDS = {"slow": 0.1, "mid": 0.5, "fast": 1.0}


def _edit_manifest(scene, change) -> None:
    import tomllib

    import tomli_w

    manifest = tomllib.loads((scene / "scene.toml").read_text())
    change(manifest)
    (scene / "scene.toml").write_text(tomli_w.dumps(manifest))


def moved_pose(T, mm: float, deg: float, axis) -> list:
    """``T`` (4x4) turned by ``deg`` about the unit ``axis`` and shifted ``mm`` along it, as a nested list."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, dtype=np.float64).copy()
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    T[:3, :3] = Rotation.from_rotvec(np.radians(deg) * axis).as_matrix() @ T[:3, :3]
    T[:3, 3] += mm * 1e-3 * axis
    return T.tolist()


def build_triage_dataset(base, root) -> None:
    """Five scenes in ``root`` from one recording generated in ``base`` (3 objects, 2.5 s at 0.5 m/s, half
    resolution; its labels right): ``a_right`` unchanged, ``b_clock`` its clock 20 ms off, ``c_pose`` the box 5 mm /
    3 deg off, ``d_mounting`` the camera mounted 2 mm / 0.5 deg off the flange, ``e_broken`` an unreadable events
    file."""
    import shutil

    import numpy as np

    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    generate(base, SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5, duration_s=2.5,
                               seed=12, max_px_per_frame=0.5, camera=half_davis_camera()))
    for name in TRIAGE_SCENES:
        shutil.copytree(base, root / name)
    _edit_manifest(root / "b_clock", lambda m: m["clock"].update(offset_us=20_000))

    def box_off(m):
        box = next(o for o in m["objects"] if o["name"] == "box")
        box["T_base_obj"] = moved_pose(box["T_base_obj"], 5.0, 3.0, [0.3, -0.5, 0.8])
    _edit_manifest(root / "c_pose", box_off)
    # the recorded poses become the flange's, the camera mounted 2 mm / 0.5 deg off it
    _edit_manifest(root / "d_mounting", lambda m: m["trajectory"].update(
        frame="tcp", hand_eye=moved_pose(np.eye(4), 2.0, 0.5, [1.0, 0.4, -0.2])))
    (root / "e_broken" / "events.h5").write_bytes(b"not an hdf5 file")


def generate_campaign(root) -> None:
    """The campaign's three scenes in ``root/<slow|mid|fast>``: 3 objects each 3 mm / 1.5 deg off (the same error,
    pose_error_seed 5), the hand-eye 2 mm / 0.5 deg off, 2.5 s at 0.1 / 0.5 / 1.0 m/s, half resolution, seed 21."""
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    for name, speed in CAMPAIGN_SPEEDS.items():
        generate(root / name, SynthConfig(
            objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=speed, duration_s=2.5, seed=21,
            pose_error_mm=3.0, pose_error_deg=1.5, pose_error_seed=5, hand_eye_error_mm=2.0, hand_eye_error_deg=0.5,
            max_px_per_frame=0.5, camera=half_davis_camera()))
