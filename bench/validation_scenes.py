"""The frozen validation family (tracker issue 23): the scenes of ``bench/validation_family.json``, made by the
independent ray-casting generator (:mod:`evpose.core.sim_validation`, ``evpose synth --generator raycast``) and
cached in ``bench/.data/validation/<assets>/<name>`` (``<assets>``: ``epose`` with E-POSE's meshes and camera,
``stand-ins`` without them: procedural meshes of the same sizes, so those scenes differ).

Use :func:`ensure_family` (or :func:`ensure_scene` for one) from a benchmark; run this file to generate or list::

    python bench/validation_scenes.py --list            # the family's table
    python bench/validation_scenes.py --check           # worlds and motions only (seconds per scene)
    python bench/validation_scenes.py --jobs 2 [NAME ...]

A cached scene is reused when its ``ground_truth.json`` was made from the same configuration, seed and generator
version; otherwise it is regenerated (only a folder evpose wrote is ever replaced). The family is frozen before
any estimator is tuned on it: do not edit a scene to make an estimator pass; add a new family instead.
Generating everything takes long (the 24 scenes hold ~190 s of DAVIS346 events at 0.5 px per frame): see the
``stats.runtime_s`` of each ``ground_truth.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))
from synth_scenes import DATA  # noqa: E402

FAMILY = BENCH / "validation_family.json"
#: The calibration family: same generator, other seeds; the only scenes the standard errors' floors are set on.
CALIBRATION = BENCH / "calibration_family.json"
#: Keys of a family entry that are not ValidationConfig fields.
META_KEYS = ("name", "offset_source")


def load_family(path: Path = FAMILY) -> dict:
    """The family document: ``format``, ``generator_version``, ``scenes`` (list of entries)."""
    doc = json.loads(Path(path).read_text())
    if doc.get("format") != "evpose-validation-family/1":
        raise ValueError(f"{path}: format: expected 'evpose-validation-family/1', got {doc.get('format')!r}")
    return doc


def root(family: Path = FAMILY) -> Path:
    from evpose.core.sim_validation.config import ASSETS

    have = (ASSETS / "models").is_dir() and (ASSETS / "camera_davis346.json").is_file()
    kind = "validation" if Path(family).resolve() == FAMILY.resolve() else Path(family).stem.replace("_family", "")
    return DATA / kind / ("epose" if have else "stand-ins")


def config(entry: dict):
    """The :class:`~evpose.core.sim_validation.config.ValidationConfig` of a family entry."""
    from evpose.core.sim_validation.config import ValidationConfig

    kw = {k: v for k, v in entry.items() if k not in META_KEYS}
    kw["objects"] = tuple(kw["objects"])
    return ValidationConfig(**kw)


def _cached(folder: Path, entry: dict, version: int) -> bool:
    gt_path = folder / "ground_truth.json"
    if not ((folder / "scene.toml").is_file() and gt_path.is_file()):
        return False
    gen = json.loads(gt_path.read_text()).get("generator", {})
    want = {k: v for k, v in entry.items() if k not in META_KEYS}
    return gen.get("version") == version and all(gen.get(k) == v for k, v in want.items())


def ensure_scene(entry: dict, version: int | None = None, quiet: bool = False, family: Path = FAMILY) -> Path:
    """The folder of one family scene, generated unless cached (see the module docstring)."""
    from evpose.core.sim_validation.assemble import GENERATOR_VERSION, generate

    version = GENERATOR_VERSION if version is None else version
    if version != GENERATOR_VERSION:
        raise RuntimeError(f"{FAMILY}: generator_version {version}, but the generator is version "
                           f"{GENERATOR_VERSION}: the frozen scenes cannot be remade; make a new family")
    folder = root(family) / entry["name"]
    if _cached(folder, entry, version):
        return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    if not quiet:
        print(f"generating {folder} ...", file=sys.stderr, flush=True)
    t = time.perf_counter()
    summary = generate(folder, config(entry), overwrite=True)
    if not quiet:
        st = summary["stats"]
        print(f"  {entry['name']}: {st['n_events']:,} events, {st['frames_rendered']} frames, "
              f"{time.perf_counter() - t:.0f} s", file=sys.stderr, flush=True)
    return folder


def _ensure_one(args) -> str:
    entry, version, family = args
    return str(ensure_scene(entry, version, family=family))


def ensure_family(names=None, jobs: int = 1, family: Path = FAMILY) -> dict[str, Path]:
    """``name -> folder`` of the family's scenes (all, or those named), generated where not cached,
    ``jobs`` at a time (separate processes)."""
    doc = load_family(family)
    entries = [e for e in doc["scenes"] if names is None or e["name"] in set(names)]
    unknown = set(names or ()) - {e["name"] for e in entries}
    if unknown:
        raise KeyError(f"{FAMILY}: no scene named {', '.join(sorted(unknown))}")
    work = [(e, doc["generator_version"], family) for e in entries]
    if jobs <= 1:
        folders = [_ensure_one(w) for w in work]
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            folders = list(pool.map(_ensure_one, work))
    return {e["name"]: Path(f) for e, f in zip(entries, folders)}


def check(entry: dict) -> str:
    """Build a scene's world and motion without simulating events: objects, clutter, moves (a quick sanity check
    of the family on this machine)."""
    from evpose.core.sim_validation.assemble import _Run

    run = _Run(config(entry))
    kinds = sorted({m.kind for m in run.motion.moves})
    moving = sum(m.T for m in run.motion.moves) / run.span_s
    return (f"{len(run.world.models)} objects ({', '.join(m.source.split('/')[-1] for m in run.world.models)}), "
            f"{len(run.world.clutter)} distractors, {len(run.motion.moves)} moves ({'/'.join(kinds)}), "
            f"moving {moving:.0%} of the time")


def table(doc: dict) -> str:
    head = (f"{'name':<38} {'obj':>3} {'traj':>4} {'m/s':>4} {'s':>4} {'profile':<9} {'Hz':>4} {'clut':>4} "
            f"{'offset us':>9} {'ppm':>5} {'pose err':>9} {'hand-eye':>9} {'seed':>5}")
    rows = [head]
    for e in doc["scenes"]:
        rows.append(f"{e['name']:<38} {len(e['objects']):>3} {e['trajectory']:>4} {e['speed_mps']:>4g} "
                    f"{e['duration_s']:>4g} {e['profile']:<9} {e['pose_rate_hz']:>4g} {e['clutter']:>4} "
                    f"{e['offset_us']:>9} {e['skew_ppm']:>5g} {e['pose_error_mm']:>4g}/{e['pose_error_deg']:<4g} "
                    f"{e['hand_eye_error_mm']:>4g}/{e['hand_eye_error_deg']:<4g} {e['seed']:>5}")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*", help="scenes to generate (default: all)")
    ap.add_argument("--jobs", type=int, default=1, help="scenes generated at a time")
    ap.add_argument("--list", action="store_true", help="print the family's table and exit")
    ap.add_argument("--check", action="store_true", help="build worlds and motions only")
    ap.add_argument("--family", default=str(FAMILY), help="family file (default: the frozen validation family; "
                    "bench/calibration_family.json: the scenes the standard errors' floors are set on)")
    args = ap.parse_args(argv)
    doc = load_family(args.family)
    if args.list:
        print(table(doc))
        return 0
    if args.check:
        for e in doc["scenes"]:
            if not args.names or e["name"] in args.names:
                print(f"{e['name']}: {check(e)}", flush=True)
        return 0
    for name, folder in ensure_family(args.names or None, args.jobs, Path(args.family)).items():
        print(f"{name}\t{folder}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
