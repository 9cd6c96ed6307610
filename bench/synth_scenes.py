"""Synthetic scenes the benchmarks share, generated once into ``bench/.data`` and reused.

- :func:`ensure_scene`: ``synth_3obj_2s``, a 3-object DAVIS346 sequence of built-in shapes (box, cylinder,
  flatbox; trajectory B at 0.5 m/s, 2 s, seed 1) — the scene of ``bench_export.py``.
- :func:`ensure_ycb_dataset`: ``dataset_ycb``, a dataset folder of scenes with the real YCB meshes of E-POSE
  (``../shared/assets/epose/models``): the first 3, 4 and 5 objects of E-POSE's ``five_obj`` scene — the
  dataset of ``bench_dataset.py``.
- :func:`ensure_ycb_scene`: ``ycb_5obj_5s``, one 5-object, 5 s scene with the real YCB meshes — the realistic
  scene of the export, scrub, space-time and memory benchmarks.
"""
from __future__ import annotations

import contextlib
import shutil
import sys
import tempfile
from pathlib import Path

DATA = Path(__file__).resolve().parent / ".data"
SCENE = DATA / "synth_3obj_2s"
YCB_DATASET = DATA / "dataset_ycb"
MODELS = Path(__file__).resolve().parents[2] / "shared/assets/epose/models"

#: E-POSE's ``five_obj`` scene (its objects in its order).
FIVE_OBJ = ("sugar_box", "drill", "mustard_bottle", "nine_hole_peg", "timer")
#: Scene name -> YCB objects: the first 3, 4 and 5 of :data:`FIVE_OBJ`. Synth numbers class ids by position,
#: so nested lists give every object one class id across the dataset (a BOP dataset needs obj_id -> one model).
YCB_SCENES = {f"{word}_obj": FIVE_OBJ[:n] for word, n in (("three", 3), ("four", 4), ("five", 5))}


@contextlib.contextmanager
def run_dir(prefix: str, root: Path | None = None):
    """A folder of this run's own outputs, ``<root>/<prefix>-XXXXXXXX`` (``root`` defaults to ``bench/.data``),
    created empty by this run and removed with everything in it when the run ends (also on errors). Outputs go
    into new subfolders of it, so a benchmark never deletes a folder it did not create: not an earlier run's,
    not a concurrent run's, nor anything a user put under ``bench/.data``."""
    root = DATA if root is None else Path(root)
    root.mkdir(parents=True, exist_ok=True)
    path = Path(tempfile.mkdtemp(prefix=f"{prefix}-", dir=root))
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)


def new_folder(parent: Path, name: str) -> Path:
    """``parent/name``, created empty here (``FileExistsError`` when it exists): a folder its caller may remove
    whole later, since nothing in it predates the call (an export writes only its own files into it, and
    ``shutil.rmtree`` removes symbolic links without following them)."""
    path = Path(parent) / name
    path.mkdir()
    return path


def tree_size(root: Path) -> tuple[int, int]:
    """Bytes and files under ``root``, each inode once (a BOP dataset's files are hard links)."""
    seen, size = set(), 0
    for p in root.rglob("*"):
        st = p.lstat()
        if p.is_file() and (st.st_dev, st.st_ino) not in seen:
            seen.add((st.st_dev, st.st_ino))
            size += st.st_size
    return size, len(seen)


def file_create_ms(folder: Path, n: int = 300) -> float:
    """Median time to create, write (3 kB), close and rename one new file in ``folder`` (ms): the filesystem's
    own cost per output file, which dominates an export that writes a dozen small files per window on a slow
    or monitored filesystem. Works in a fresh subfolder of ``folder`` and removes it."""
    import statistics
    import time

    with run_dir("create_probe", folder) as d:
        times, data = [], b"x" * 3000
        for i in range(n):
            t = time.perf_counter()
            with open(d / f".{i}.tmp", "wb") as f:
                f.write(data)
            (d / f".{i}.tmp").rename(d / f"{i}.png")
            times.append(time.perf_counter() - t)
    return statistics.median(times) * 1e3


def ensure_synth(folder: Path, cfg, what: str = "") -> Path:
    """``folder`` holding the scene :func:`evpose.core.sim.synth.generate` makes from ``cfg``, generated
    when it has no ``scene.toml`` yet (delete the folder to regenerate)."""
    from evpose.core.sim.synth import generate

    if (folder / "scene.toml").is_file():
        return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    print(f"generating {folder} (once{'; ' + what if what else ''})...", file=sys.stderr)
    generate(folder, cfg, overwrite=True)
    return folder


def ensure_scene() -> Path:
    """The 3-object built-in-shape scene of ``bench_export.py`` (about 2 minutes to generate)."""
    from evpose.core.sim.synth_config import SynthConfig

    return ensure_synth(SCENE, SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5,
                                           duration_s=2.0, offset_us=20_000, pose_error_mm=5.0, pose_error_deg=3.0,
                                           seed=1), "about 2 minutes")


def ensure_ycb_dataset(duration_s: float = 1.5) -> Path:
    """A dataset folder of the :data:`YCB_SCENES` with the real YCB meshes, ``duration_s`` of events each
    (trajectory B at 0.5 m/s, the clock prior right, no pose error), one seed per scene. Raises
    ``FileNotFoundError`` when the E-POSE meshes are absent."""
    from evpose.core.sim.synth_config import SynthConfig

    if not MODELS.is_dir():
        raise FileNotFoundError(f"{MODELS}: the E-POSE YCB meshes are needed (see shared/assets/epose/README.md)")
    root = YCB_DATASET / f"{duration_s:g}s"
    for seed, (name, objects) in enumerate(YCB_SCENES.items(), 1):
        ensure_synth(root / name, SynthConfig(objects=objects, mesh_dir=str(MODELS), trajectory="B", speed_mps=0.5,
                                              duration_s=duration_s, seed=seed), "a minute or two per scene")
    return root


def ensure_ycb_scene(n_objects: int = 5, duration_s: float = 5.0) -> Path:
    """The realistic scene of the performance benchmarks (tracker issue 14): the first ``n_objects`` of
    E-POSE's ``five_obj`` objects with their real YCB meshes, trajectory B at 0.5 m/s, ``duration_s`` of
    events on the full DAVIS346 sensor (5 objects, 5 s: about 5 M events, 495 windows of 10 ms), a 20 ms
    clock-offset prior error and 5 mm / 3 deg pose errors as in :func:`ensure_scene`, seed 1. Cached in
    ``bench/.data/ycb_<n>obj_<d>s``. Raises ``FileNotFoundError`` when the E-POSE meshes are absent."""
    from evpose.core.sim.synth_config import SynthConfig

    if not MODELS.is_dir():
        raise FileNotFoundError(f"{MODELS}: the E-POSE YCB meshes are needed (see shared/assets/epose/README.md)")
    return ensure_synth(DATA / f"ycb_{n_objects}obj_{duration_s:g}s",
                        SynthConfig(objects=FIVE_OBJ[:n_objects], mesh_dir=str(MODELS), trajectory="B",
                                    speed_mps=0.5, duration_s=duration_s, offset_us=20_000, pose_error_mm=5.0,
                                    pose_error_deg=3.0, seed=1), "several minutes")
