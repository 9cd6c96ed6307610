"""Benchmark: evpose.core.label.raster.Rasterizer against open3d's RaycastingScene on a DAVIS346 frame.

Run ``python bench/bench_raster.py`` (``--json``: one JSON document of the headline figures). For each scene, ~50 frames with slightly varying poses
(after a warm-up) are rendered by

* ``ours``: :class:`evpose.core.label.raster.Rasterizer` (``render_objects``: models and poses)
  with the numba kernels (``backend="numba"``, kernels warmed up first), one thread;
* ``2 thr``: the same with ``threads=2`` (the meshes split over two threads, each into its own z-buffer,
  merged by the minimum key), as the app's overlay worker runs it; open3d's cast below also uses
  every core (its TBB pool);
* ``numpy``: the rasteriser before issue 14, the baseline of ``numpy/ours``: the same class with
  ``backend="numpy"`` (the vectorised numpy pipeline that was the whole rasteriser before the kernels)
  on models whose face arrays are writable copies, which turns off the back-face culling of closed
  meshes (``evpose.core.data.mesh_closure``) added since;
* ``no cull``: the numba kernels with culling off (writable faces), to show what culling adds;
* ``o3d cast``: open3d ``cast_rays`` with the BVH already built for the frame's poses (the
  build is not timed: the lower bound of DESIGN section 8, "build it once per pose set");
* ``o3d build+cast``: the scene rebuilt for each frame's poses, then cast (what a per-frame
  ray caster really costs when poses change every frame);
* ``o3d obj-frame``: one scene per object built once in the object frame, the pixel rays moved
  into each object's frame per frame and the nearest hit kept (an alternative design that
  needs no rebuild).

Rays are the pixel-centre rays of ``camera.pixel_rays()``; IoU per object compares the
visible masks of ours and open3d's (minimum over the frames). Times are medians in ms, with
the minimum beside ours and open3d's cast (robust to other processes on a shared machine).
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from evpose.core.data.camera import CameraModel  # noqa: E402
from evpose.core.data.geometry import T_from_rotvec, apply_T, inv_T, make_T  # noqa: E402
from evpose.core.data.objects import ObjectModel  # noqa: E402
from evpose.core.label.raster import Rasterizer  # noqa: E402

MODELS = REPO.parent / "shared/assets/epose/models"
N_FRAMES = 50
N_WARM = 5


def load_models(names):
    """Real E-POSE meshes, or procedural stand-ins of similar size if the assets are absent."""
    if MODELS.is_dir() and all((MODELS / n).is_file() for n in names):
        return [ObjectModel.from_file(MODELS / n) for n in names], "E-POSE meshes"
    import trimesh

    out = []
    for i, n in enumerate(names):
        mesh = trimesh.creation.icosphere(subdivisions=6, radius=0.06 + 0.01 * i)   # 81920 faces
        mesh.vertices *= [1.0, 0.7 + 0.2 * i, 1.3]
        out.append(ObjectModel.from_trimesh(mesh, n))
    return out, "procedural stand-ins (assets absent)"


def unculled(model: ObjectModel) -> ObjectModel:
    """The same mesh with a writable copy of its faces: the rasteriser never culls those."""
    m = ObjectModel(model.name, model.vertices_m, model.faces)
    m.faces = np.array(m.faces)
    return m


def centred(model: ObjectModel, rotvec, t):
    return T_from_rotvec(rotvec, t) @ make_T(np.eye(3), -model.bbox_center_m)


TABLE = ObjectModel("table", np.array([[-1.5, 0.12, -1.0], [1.5, 0.12, -1.0], [1.5, 0.12, 2.0], [-1.5, 0.12, 2.0]]),
                    np.array([[0, 1, 2], [0, 2, 3]]))
BASE_POSES = [([0.3, 0.5, 0.1], [-0.06, 0.0, 0.45]), ([1.2, -0.3, 0.4], [0.06, 0.03, 0.55]),
              ([-1.3, 0.2, 0.0], [0.0, -0.02, 0.36]), ([0.5, -1.0, 0.7], [-0.09, -0.04, 0.5]),
              ([2.0, 0.4, -0.5], [0.1, -0.05, 0.6])]


def frames(models, rng, n, table=False):
    """n frames of camera-frame meshes: base poses with ~1 deg / ~2 mm jitter (plus a table)."""
    out = []
    for _ in range(n):
        meshes = []
        for m, (rv, t) in zip(models, BASE_POSES):
            T = centred(m, np.asarray(rv) + rng.normal(0, 0.02, 3), np.asarray(t) + rng.normal(0, 0.002, 3))
            meshes.append((apply_T(T, m.vertices_m), m.faces, T))
        if table:   # 2 triangles, 3 m square, 12 cm below the camera, crossing the camera plane
            T = T_from_rotvec(rng.normal(0, 0.01, 3))
            meshes.append((apply_T(T, TABLE.vertices_m), TABLE.faces, T))
        out.append(meshes)
    return out


class Open3D:
    """open3d ray casting through the pixel centres of a camera."""

    def __init__(self, camera: CameraModel):
        import open3d as o3d

        self.o3d = o3d
        xy, valid = camera.pixel_rays()
        self.valid = valid
        d = np.concatenate([np.nan_to_num(xy), np.ones(xy.shape[:2] + (1,))], axis=2)
        self.dirs = d.reshape(-1, 3)
        self.rays = o3d.core.Tensor(np.concatenate([np.zeros_like(d), d], axis=2).astype(np.float32))
        self.near = camera.near_m
        self.shape = xy.shape[:2]
        self._obj_scenes: dict = {}

    def build(self, meshes):
        scene = self.o3d.t.geometry.RaycastingScene()
        for V, F, _ in meshes:
            scene.add_triangles(self.o3d.core.Tensor(np.asarray(V, np.float32)),
                                self.o3d.core.Tensor(np.asarray(F, np.uint32)))
        return scene

    def cast(self, scene):
        ans = scene.cast_rays(self.rays)
        t = ans["t_hit"].numpy()
        hit = np.isfinite(t) & self.valid & (t > self.near)
        return np.where(hit, ans["geometry_ids"].numpy().astype(np.int64), -1)

    def object_frame(self, models, meshes):
        """Nearest hit over per-object scenes built once in the object frame."""
        best_t = np.full(self.shape, np.inf, np.float32)
        best_k = np.full(self.shape, -1, np.int64)
        for k, (V, F, T) in enumerate(meshes):
            model = models[k] if k < len(models) else TABLE
            key, Vo = id(model), model.vertices_m
            if key not in self._obj_scenes:
                sc = self.o3d.t.geometry.RaycastingScene()
                sc.add_triangles(self.o3d.core.Tensor(np.asarray(Vo, np.float32)),
                                 self.o3d.core.Tensor(np.asarray(F, np.uint32)))
                self._obj_scenes[key] = sc
            Ti = inv_T(T)
            o = np.broadcast_to(Ti[:3, 3], self.dirs.shape)
            d = self.dirs @ Ti[:3, :3].T
            rays = np.concatenate([o, d], axis=1).astype(np.float32).reshape(self.shape + (6,))
            t = self._obj_scenes[key].cast_rays(self.o3d.core.Tensor(rays))["t_hit"].numpy()
            closer = (t < best_t) & (t > self.near)
            best_t[closer] = t[closer]
            best_k[closer] = k
        best_k[~self.valid] = -1
        return best_k


def run_scene(label, camera, raster, o3d_caster, models, rng, table=False, baseline=None, raster2=None):
    """Time one scene. The contenders run in separate passes over the same frames: open3d's
    (TBB) worker threads keep spinning for a while after a call returns and would slow down
    whatever runs right after them on a machine with few cores."""
    seq = frames(models, rng, N_WARM + N_FRAMES, table)
    n_obj = len(seq[0])
    med = lambda x: 1e3 * float(np.median(x[N_WARM:]))  # noqa: E731
    # ours: the models and their poses (render_objects transforms, culls and rasterises)
    all_models = list(models) + ([TABLE] if table else [])
    t_ours, ours = [], []
    for i, meshes in enumerate(seq):
        if i == N_WARM:
            raster.timings.clear()
        poses = [T for _, _, T in meshes]
        t0 = time.perf_counter()
        res = raster.render_objects(all_models, poses)
        t_ours.append(time.perf_counter() - t0)
        ours.append(res.obj_index)
    stages = {k: 1e3 * v / N_FRAMES for k, v in raster.timings.items()}
    t_two, same2 = [], True                          # the same kernels, meshes split over two threads
    for i, meshes in enumerate(seq):
        poses = [T for _, _, T in meshes]
        t0 = time.perf_counter()
        res = raster2.render_objects(all_models, poses)
        t_two.append(time.perf_counter() - t0)
        same2 &= bool(np.array_equal(res.obj_index, ours[i]))
    plain = [unculled(m) for m in all_models]
    t_base, t_nocull, same = [], [], True
    for i, meshes in enumerate(seq):                 # the numpy pipeline (no culling) on the same frames
        poses = [T for _, _, T in meshes]
        t0 = time.perf_counter()
        res = baseline.render_objects(plain, poses)
        t1 = time.perf_counter()
        res2 = raster.render_objects(plain, poses)
        t_base.append(t1 - t0)
        t_nocull.append(time.perf_counter() - t1)
        same &= bool(np.array_equal(res.obj_index, ours[i])) and bool(np.array_equal(res2.obj_index, ours[i]))
    time.sleep(0.2)
    # open3d, scene rebuilt per frame (Embree builds the BVH lazily, in the first cast)
    t_build, t_cast, ious = [], [], np.ones((len(seq), n_obj))
    for i, meshes in enumerate(seq):
        t0 = time.perf_counter()
        scene = o3d_caster.build(meshes)
        ref = o3d_caster.cast(scene)
        t1 = time.perf_counter()
        o3d_caster.cast(scene)                 # BVH built: the cast alone
        t2 = time.perf_counter()
        t_build.append(t1 - t0)
        t_cast.append(t2 - t1)
        for k in range(n_obj):
            a, b = ours[i] == k, ref == k
            u = np.count_nonzero(a | b)
            ious[i, k] = np.count_nonzero(a & b) / u if u else 1.0
    # open3d, one scene per object in its own frame (built once), rays moved per frame
    t_objf = []
    for meshes in seq:
        t0 = time.perf_counter()
        o3d_caster.object_frame(models, meshes)
        t_objf.append(time.perf_counter() - t0)
    time.sleep(0.2)
    n_tri = sum(len(F) for _, F, _ in seq[0])
    return dict(label=label, tris=n_tri, ours=med(t_ours), two=med(t_two), same2=same2, numpy=med(t_base), numpy_min=1e3 * min(t_base[N_WARM:]),
                nocull=med(t_nocull),
                same_as_numpy=same, ours_min=1e3 * min(t_ours[N_WARM:]), cast=med(t_cast),
                cast_min=1e3 * min(t_cast[N_WARM:]), build=med(t_build), objf=med(t_objf),
                iou=ious[N_WARM:].min(axis=0), stages=stages)


FIRST_FRAME = """
import sys, time, json
t0 = time.perf_counter()
sys.path.insert(0, {repo!r})
from evpose.core.data.camera import CameraModel
from evpose.core.label.raster import Rasterizer
sys.path.insert(0, {bench!r})
from bench_raster import load_models, frames
camera = CameraModel.from_json({cam!r})
r = Rasterizer(camera)
models, _ = load_models(["drill.obj", "cracker_box.obj", "mustard_bottle.stl"])
meshes = frames(models, __import__("numpy").random.default_rng(0), 1)[0]
t1 = time.perf_counter()
warm = r.warm_up() if {warm} else 0.0
t2 = time.perf_counter()
r.render_objects(models, [T for _, _, T in meshes])
t3 = time.perf_counter()
print(json.dumps(dict(import_setup=t1 - t0, warm_up=warm, first_frame=t3 - t2)))
"""


def first_frame_latency() -> dict:
    """First-frame time in a fresh process: with an empty numba cache (cold: compiles), with the
    cache filled (warm: loads), and with the cache filled and warm_up() run before the frame (as
    the app does in a background thread at start-up)."""
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        cam = str(REPO.parent / "shared/assets/epose/camera_davis346.json")
        for name, warm in (("cold", False), ("cached", False), ("cached+warm_up", True)):
            code = FIRST_FRAME.format(repo=str(REPO.parent), bench=str(REPO / "bench"), cam=cam, warm=warm)
            if not Path(cam).is_file():
                code = code.replace(f"CameraModel.from_json({cam!r})", "CameraModel.davis346()")
            res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            out[name] = json.loads(res.stdout.strip().splitlines()[-1])
    return out


def main() -> None:
    import numpy

    as_json = "--json" in sys.argv[1:]
    cam_path = MODELS.parent / "camera_davis346.json"
    camera = CameraModel.from_json(cam_path) if cam_path.is_file() else CameraModel.davis346()
    t0 = time.perf_counter()
    raster = Rasterizer(camera)
    setup_s = time.perf_counter() - t0
    warm_s = raster.warm_up()
    baseline = Rasterizer(camera, backend="numpy")
    raster2 = Rasterizer(camera, threads=2)
    raster2.warm_up()
    o3d_caster = Open3D(camera)
    rng = np.random.default_rng(1)
    big, src = load_models(["nine_hole_peg.stl", "wrench.stl", "mustard_bottle.stl"])
    mid, _ = load_models(["drill.obj", "cracker_box.obj", "mustard_bottle.stl"])
    five, _ = load_models(["nine_hole_peg.stl", "wrench.stl", "mustard_bottle.stl", "sugar_box.obj", "scissors.stl"])
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    latency = first_frame_latency()
    rows = [
        run_scene("3 objects: peg, wrench, mustard", camera, raster, o3d_caster, big, rng, baseline=baseline, raster2=raster2),
        run_scene("3 objects: drill, cracker, mustard", camera, raster, o3d_caster, mid, rng, baseline=baseline, raster2=raster2),
        run_scene("5 objects: peg...mustard, sugar, scissors", camera, raster, o3d_caster, five, rng,
                  baseline=baseline, raster2=raster2),
        run_scene("1 object: nine_hole_peg", camera, raster, o3d_caster, big[:1], rng, baseline=baseline, raster2=raster2),
        run_scene("table plane + 3 objects (peg...)", camera, raster, o3d_caster, big, rng, table=True,
                  baseline=baseline, raster2=raster2),
    ]
    if as_json:
        print(json.dumps(dict(
            camera=f"DAVIS346 {camera.width}x{camera.height} with distortion", meshes=src, frames=N_FRAMES,
            load_average=load,
            backend=raster.backend, setup_ms=1e3 * setup_s, warm_up_ms=1e3 * warm_s, first_frame_s=latency,
            baseline="numpy pipeline without back-face culling (the rasteriser before issue 14)",
            o3d_threads="open3d casts with its TBB pool (every core)",
            scenes=[dict(scene=r["label"], triangles=r["tris"], ours_ms=r["ours"], ours_min_ms=r["ours_min"],
                         ours_2_threads_ms=r["two"], two_threads_same=r["same2"],
                         o3d_cast_over_ours_2_threads=r["cast"] / r["two"],
                         baseline_ms=r["numpy"], numba_no_cull_ms=r["nocull"],
                         o3d_cast_ms=r["cast"], baseline_over_ours=r["numpy"] / r["ours"],
                         ours_over_o3d_cast=r["ours"] / r["cast"], same_as_baseline=r["same_as_numpy"],
                         min_iou=[float(x) for x in r["iou"]], stages_ms=r["stages"]) for r in rows]), indent=1))
        return
    print(f"evpose raster benchmark: DAVIS346 {camera.width}x{camera.height} with distortion, {src}")
    print(f"python {platform.python_version()}, numpy {numpy.__version__}, open3d {o3d_caster.o3d.__version__}, "
          f"{os.cpu_count()} cpus, load average {load:.2f}; Rasterizer setup {setup_s * 1e3:.0f} ms")
    print(f"median over {N_FRAMES} frames (poses jittered ~1 deg / 2 mm per frame) after {N_WARM} warm-up frames\n")
    print(f"backend {raster.backend}; kernels warmed up in {warm_s * 1e3:.0f} ms; first frame in a fresh process: "
          + ", ".join(f"{k} {v['first_frame'] * 1e3:.0f} ms (warm_up {v['warm_up'] * 1e3:.0f} ms)"
                      for k, v in latency.items()) + "\n")
    print("baseline 'before': the numpy pipeline without back-face culling (the rasteriser before issue 14); "
          "'no cull': the numba kernels without culling; '2 thr': Rasterizer(threads=2), the meshes split over two "
          "threads (as the app's overlay worker runs it); open3d's cast uses its TBB pool on every core\n")
    head = (f"{'scene':41s} {'tris':>7s} {'ours':>6s} {'(min)':>6s} {'2 thr':>6s} {'no cull':>7s} {'before':>6s} {'befor/':>6s} {'o3d cast':>8s} {'(min)':>6s} {'o3d build':>9s} "
            f"{'o3d obj':>8s} {'ours/':>6s} {'build+cast/':>11s}  IoU vs open3d per object")
    sub = (f"{'':41s} {'':>7s} {'ms':>6s} {'ms':>6s} {'ms':>6s} {'ms':>7s} {'ms':>6s} {'ours':>6s} {'ms':>8s} {'ms':>6s} {'+cast ms':>9s} {'frame ms':>8s} "
           f"{'cast':>6s} {'ours':>11s}  (min over frames)")
    print(head)
    print(sub)
    print("-" * len(head))
    for r in rows:
        iou = " ".join(f"{x:.4f}" for x in r["iou"])
        print(f"{r['label']:41s} {r['tris']:7d} {r['ours']:6.2f} {r['ours_min']:6.2f} {r['two']:6.2f} {r['nocull']:7.2f} {r['numpy']:6.2f} "
              f"{r['numpy'] / r['ours']:6.2f} {r['cast']:8.2f} "
              f"{r['cast_min']:6.2f} {r['build']:9.1f} {r['objf']:8.2f} {r['ours'] / r['cast']:6.2f} "
              f"{r['build'] / r['ours']:11.1f}  {iou}" + ("" if r["same_as_numpy"] else "  MASKS DIFFER FROM THE BASELINE")
              + ("" if r["same2"] else "  2 THREADS DIFFER"))
    print("\nwhere our time goes (ms per frame, mean):")
    for r in rows:
        st = r["stages"]
        total = sum(st.values())
        top = max(st, key=st.get)
        parts = ", ".join(f"{k} {v:.2f}" for k, v in st.items())
        print(f"  {r['label']:41s} {parts}  -> dominant: {top} ({100 * st[top] / total:.0f} %)")


if __name__ == "__main__":
    main()
