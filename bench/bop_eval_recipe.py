"""The README's BOP evaluation recipe ("Using it with the toolkit") run for real with thodan/bop_toolkit.

Run: ``.venv/bin/python bench/bop_eval_recipe.py [--toolkit SRC] [--workdir DIR] [--keep]``, ``SRC`` a checkout, an
extracted archive or a bare git repository of the toolkit (default: ``$EVPOSE_BOP_TOOLKIT``). The toolkit is not on
PyPI; its evaluation imports numpy, scipy, imageio and pypng (``png``): the script says which are missing (put them
on ``PYTHONPATH`` or ``pip install pypng imageio``); its ``numpy<2.0.0`` pin is not needed (run with numpy 2.4).
Also imported by ``tests/core/test_bop_eval_recipe.py``.

Steps, each as the README writes it (:data:`README_SPANS` are the recipe's backticked spans; the test checks that
the README has exactly these):

1. copy the toolkit's ``bop_toolkit_lib/`` and ``scripts/`` into a temporary folder (the source is never modified);
2. register the dataset ``NAME`` (:data:`DATASET`) in ``bop_toolkit_lib/dataset_params.py`` and make the two edits
   of ``scripts/eval_bop19_pose.py``; a line the recipe edits that is not found stops the run with one line
   (:class:`RecipeMismatch`: the recipe no longer matches this toolkit);
3. generate a tiny synthetic scene with evpose (3 built-in shapes, 0.3 s, 173 x 130 camera), export it to BOP
   as ``$BOP_PATH/NAME`` (6 images of 50 ms, 18 targets) and link ``models_eval``;
4. write two result files (BOP19 CSV): ``gt``, every target's ground-truth pose, and ``shifted``, every pose moved
   by :data:`SHIFT` of its object's diameter along the camera's optical axis;
5. run ``scripts/eval_bop19_pose.py`` in a child process (``BOP_PATH`` set, the copy on ``PYTHONPATH``, ``python``
   = this interpreter: the toolkit starts ``python`` for every metric);
6. check the toolkit's scores: ``gt`` 1.0 for MSSD, MSPD and their mean; ``shifted`` MSSD exactly the fraction of
   BOP19's thresholds (0.05, 0.10, ... 0.50 of the diameter) above 0.22 (0.6), MSPD the value computed here
   independently (projection with ``cam_K``, the continuous symmetries of ``models_info.json``, errors scaled to a
   640 px wide image, thresholds 5 ... 50 px), strictly between 0 and 1.

Exit status: 0 all checks pass, 1 a check failed or the recipe does not match the toolkit, 2 no toolkit or a
module it needs is missing.
"""
from __future__ import annotations

import argparse
import ast
import io
import json
import math
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

ENV_VAR = "EVPOSE_BOP_TOOLKIT"
#: The dataset's name in the toolkit (no ``_`` or ``-``: the toolkit splits result file names at them).
DATASET = "evpose"
#: Shift of the ``shifted`` estimates, a fraction of the object's diameter (none of BOP19's MSSD thresholds).
SHIFT = 0.22
#: BOP19's thresholds (``eval_bop19_pose.py``'s ``correct_th``): MSSD in diameters, MSPD in px of a 640 px image.
MSSD_TH = np.arange(0.05, 0.51, 0.05)
MSPD_TH = np.arange(5, 51, 5)
#: ``max_sym_disc_step`` of ``eval_bop19_pose.py`` (discretisation of a continuous symmetry).
SYM_STEP = 0.01

# ---------------------------------------------------------------- the recipe, in the README's words
DATASET_PARAMS = "bop_toolkit_lib/dataset_params.py"
EVAL_SCRIPT = "scripts/eval_bop19_pose.py"
MODEL_PARAMS_FN, SPLIT_PARAMS_FN = "get_model_params", "get_split_params"
OBJ_IDS, SYM_OBJ_IDS = "obj_ids", "symmetric_obj_ids"
#: The branch added to ``get_split_params`` (``NAME``, ``WIDTH``, ``HEIGHT`` filled in; scene 0 of split test).
SPLIT_BRANCH = ('elif dataset_name == "NAME":', 'p["scene_ids"] = {"test": [0]}[split]',
                'p["im_size"] = (WIDTH, HEIGHT)', 'p["im_modalities"] = ["rgb"]',
                'supported_error_types = ["ad", "add", "adi", "mssd", "mspd"]')
MODELS_EVAL_LINK = "ln -s models $BOP_PATH/NAME/models_eval"
ERRORS_KEY, VSD = 'p["errors"]', "vsd"
FINAL_SCORE_LINE = ('final_scores["bop19_average_recall"] = np.mean([average_recalls["vsd"], '
                    'average_recalls["mssd"], average_recalls["mspd"]])')
VSD_TERM = 'average_recalls["vsd"], '
RESULT_NAME = "METHOD_NAME-test.csv"
TARGETS = "test_targets_bop19.json"
#: Every backticked span of the README's recipe paragraph (the edits above and the names it mentions).
README_SPANS = (("$BOP_PATH/NAME", "datasets_path", "NAME", "_", "-", DATASET_PARAMS, MODEL_PARAMS_FN, OBJ_IDS,
                 "models_info.json", SYM_OBJ_IDS, "symmetries_continuous", SPLIT_PARAMS_FN) + SPLIT_BRANCH
                + ("models_eval/", MODELS_EVAL_LINK, EVAL_SCRIPT, VSD, ERRORS_KEY, FINAL_SCORE_LINE, VSD_TERM,
                   "KeyError: 'vsd'", "python", RESULT_NAME, "METHOD", TARGETS, "bench/bop_eval_recipe.py",
                   "--toolkit", "$" + ENV_VAR, "tests/core/test_bop_eval_recipe.py"))
#: Modules the evaluation imports (module -> pip name), besides the standard library.
TOOLKIT_MODULES = {"numpy": "numpy", "scipy": "scipy", "imageio": "imageio", "png": "pypng"}


class RecipeMismatch(RuntimeError):
    """A line the README's recipe edits is not in the toolkit (one line: file and what is missing)."""


class NoToolkit(RuntimeError):
    """No toolkit source, or a module its evaluation needs is missing."""


class MissingModules(NoToolkit):
    """A module the toolkit's evaluation imports is missing (its pip names in the message)."""


# ---------------------------------------------------------------- the toolkit copy
def find_toolkit(explicit=None) -> Path | None:
    """The toolkit source given, else ``$EVPOSE_BOP_TOOLKIT``, else None."""
    src = explicit or os.environ.get(ENV_VAR)
    return Path(src).expanduser() if src else None


def is_git_dir(path: Path) -> bool:
    return (path / "HEAD").is_file() and (path / "objects").is_dir()


def toolkit_version(src: Path) -> str:
    """The commit of a git source (a bare repository or a checkout), else the folder."""
    git = ["git", f"--git-dir={src}"] if is_git_dir(src) else ["git", "-C", str(src)]
    r = subprocess.run(git + ["rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return f"{src} @ {r.stdout.strip()}" if r.returncode == 0 and (is_git_dir(src) or (src / ".git").exists()) \
        else str(src)


def copy_toolkit(src: Path, dst: Path) -> Path:
    """Copy ``bop_toolkit_lib/`` (without its ``tests/``: large data files a snapshot may lack) and ``scripts/``
    of ``src`` (a folder, or a bare git repository: its HEAD) into the new folder ``dst``; ``src`` is only read."""
    parts = ("bop_toolkit_lib", "scripts")
    dst.mkdir(parents=True)
    if is_git_dir(src):
        tar = subprocess.run(["git", f"--git-dir={src}", "archive", "--format=tar", "HEAD", *parts,
                              ":(exclude)bop_toolkit_lib/tests"],
                             capture_output=True, check=True).stdout
        with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
            tf.extractall(dst, filter="data")
    elif all((src / p).is_dir() for p in parts):
        for p in parts:
            shutil.copytree(src / p, dst / p, ignore=shutil.ignore_patterns("__pycache__", "tests"))
    else:
        raise NoToolkit(f"{src}: not a BOP toolkit (no bop_toolkit_lib/ and scripts/, not a git repository)")
    return dst


# ---------------------------------------------------------------- the README's edits
def _function(tree, name: str, rel: str) -> ast.FunctionDef:
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name == name:
            return node
    raise RecipeMismatch(f"{rel}: no function {name}() -- the README's recipe no longer matches this toolkit")


def _dict_assigned(fn: ast.FunctionDef, var: str, rel: str) -> ast.Dict:
    """The dict literal of ``var = {...}[dataset_name]`` in ``fn``."""
    for node in ast.walk(fn):
        if (isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == [var]
                and isinstance(node.value, ast.Subscript) and isinstance(node.value.value, ast.Dict)):
            return node.value.value
    raise RecipeMismatch(f"{rel}: no '{var} = {{...}}[dataset_name]' in {fn.name}() -- the README's recipe no "
                         "longer matches this toolkit")


def edit_dataset_params(text: str, obj_ids, sym_obj_ids, width: int, height: int, rel=DATASET_PARAMS) -> str:
    """Register :data:`DATASET` as the README says: ``NAME`` in ``get_model_params``' ``obj_ids`` and
    ``symmetric_obj_ids``, the :data:`SPLIT_BRANCH` before ``get_split_params``' final ``else:``."""
    tree, lines = ast.parse(text), text.splitlines(keepends=True)
    inserts = []                                    # (line index, text) inserted before that line
    model_fn = _function(tree, MODEL_PARAMS_FN, rel)
    for var, ids in ((OBJ_IDS, obj_ids), (SYM_OBJ_IDS, sym_obj_ids)):
        d = _dict_assigned(model_fn, var, rel)
        if not d.keys:
            raise RecipeMismatch(f"{rel}: {var} of {MODEL_PARAMS_FN}() is empty -- the recipe no longer matches")
        indent = " " * d.keys[0].col_offset
        inserts.append((d.keys[0].lineno - 1, f'{indent}"{DATASET}": {list(map(int, ids))},\n'))
    split_fn = _function(tree, SPLIT_PARAMS_FN, rel)
    raises = [n for n in ast.walk(split_fn) if isinstance(n, ast.Raise) and "Unknown BOP dataset" in ast.unparse(n)]
    k = raises[0].lineno - 2 if len(raises) == 1 else -1
    while k > 0 and not lines[k].strip():
        k -= 1
    if k < 0 or lines[k].strip() != "else:":
        raise RecipeMismatch(f"{rel}: no 'else: raise ValueError(\"Unknown BOP dataset ...\")' at the end of "
                             f"{SPLIT_PARAMS_FN}()'s dataset branches -- the README's recipe no longer matches")
    indent = lines[k][:len(lines[k]) - len(lines[k].lstrip())]
    fill = {"NAME": DATASET, "WIDTH": str(int(width)), "HEIGHT": str(int(height))}
    branch = []
    for i, line in enumerate(SPLIT_BRANCH):
        for key, value in fill.items():
            line = line.replace(key, value)
        branch.append(indent + ("    " if i else "") + line + "\n")
    inserts.append((k, "".join(branch)))
    for at, new in sorted(inserts, reverse=True):
        lines.insert(at, new)
    return _compiled("".join(lines), rel)


def edit_eval_script(text: str, rel=EVAL_SCRIPT) -> str:
    """The README's two edits of ``eval_bop19_pose.py``: the ``vsd`` entry out of ``p["errors"]``, and
    ``average_recalls["vsd"], `` out of the final-score line."""
    tree, lines = ast.parse(text), text.splitlines(keepends=True)
    mismatch = "-- the README's recipe no longer matches this toolkit"
    # 1. the final-score statement, structurally the README's line
    want = ast.dump(ast.parse(FINAL_SCORE_LINE).body[0])
    finals = [n for n in ast.walk(tree) if isinstance(n, ast.Assign) and ast.dump(n) == want]
    if len(finals) != 1:
        raise RecipeMismatch(f"{rel}: {len(finals)} statements {FINAL_SCORE_LINE!r} (expected one) {mismatch}")
    # 2. the vsd entry of p["errors"]
    entries = []
    for node in tree.body:
        if (isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["p"]
                and isinstance(node.value, ast.Dict)):
            for key, value in zip(node.value.keys, node.value.values):
                if isinstance(key, ast.Constant) and key.value == "errors" and isinstance(value, ast.List):
                    entries += [e for e in value.elts if isinstance(e, ast.Dict) and any(
                        isinstance(k, ast.Constant) and k.value == "type" and isinstance(v, ast.Constant)
                        and v.value == VSD for k, v in zip(e.keys, e.values))]
    if len(entries) != 1:
        raise RecipeMismatch(f"{rel}: no entry with \"type\": \"{VSD}\" in {ERRORS_KEY} {mismatch}")
    e = entries[0]
    first, last = lines[e.lineno - 1], lines[e.end_lineno - 1]
    if first[:e.col_offset].strip() or last[e.end_col_offset:].strip() not in ("", ","):
        raise RecipeMismatch(f"{rel}: the {VSD} entry of {ERRORS_KEY} does not stand on lines of its own {mismatch}")
    # the final-score edit inside its statement's lines (the toolkit wraps it)
    f = finals[0]
    stmt = "".join(lines[f.lineno - 1:f.end_lineno])
    if stmt.count(VSD_TERM) != 1:
        raise RecipeMismatch(f"{rel}: {VSD_TERM!r} is not written once in the final-score statement {mismatch}")
    new = lines[:e.lineno - 1] + lines[e.end_lineno:f.lineno - 1] + [stmt.replace(VSD_TERM, "")] \
        + lines[f.end_lineno:]
    return _compiled("".join(new), rel)


def _compiled(text: str, rel: str) -> str:
    try:
        compile(text, rel, "exec")
    except SyntaxError as exc:
        raise RecipeMismatch(f"{rel}: the recipe's edits leave a syntax error ({exc.msg}, line {exc.lineno})") \
            from None
    return text


def apply_recipe(toolkit: Path, bop_path: Path, obj_ids, sym_obj_ids, width: int, height: int) -> None:
    """The README's edits of a toolkit copy and the ``models_eval`` link of the export ``bop_path/NAME``."""
    p = toolkit / DATASET_PARAMS
    p.write_text(edit_dataset_params(p.read_text(), obj_ids, sym_obj_ids, width, height))
    p = toolkit / EVAL_SCRIPT
    p.write_text(edit_eval_script(p.read_text()))
    _, target, link = MODELS_EVAL_LINK.split()[-3:]            # ln -s models $BOP_PATH/NAME/models_eval
    os.symlink(target, Path(link.replace("$BOP_PATH", str(bop_path)).replace("NAME", DATASET)))


# ---------------------------------------------------------------- the export and the estimates
def make_export(work: Path, bop_path: Path) -> dict:
    """A tiny synthetic scene exported to BOP as ``bop_path/DATASET``; returns its camera.json."""
    from evpose.core.data.camera import CameraModel
    from evpose.core.export import export_scene
    from evpose.core.sim.synth import generate
    from evpose.core.sim.synth_config import SynthConfig

    cam = CameraModel.davis346()                     # at half resolution (pixel centres at integers)
    K = cam.K.copy()
    K[:2] *= 0.5
    K[:2, 2] = (cam.K[:2, 2] + 0.5) / 2 - 0.5
    camera = {"width": cam.width // 2, "height": cam.height // 2, "K": K.tolist(), "dist": cam.dist.tolist()}
    generate(work / "scene", SynthConfig(objects=("box", "cylinder", "flatbox"), trajectory="B", speed_mps=0.5,
                                         duration_s=0.3, seed=3, camera=camera))
    export_scene(work / "scene", "bop", bop_path / DATASET, window_us=50_000)
    return json.loads((bop_path / DATASET / "camera.json").read_text())


def _load(path: Path, int_keys=True):
    d = json.loads(path.read_text())
    return {int(k): v for k, v in d.items()} if int_keys else d


def estimates(ds: Path, shift: float) -> list[dict]:
    """One estimate per target instance: its ground-truth pose, moved by ``shift`` diameters along the camera's
    optical axis (away from the camera: the image moves less than the model, MSPD is partly right)."""
    info = _load(ds / "models" / "models_info.json")
    out = []
    for tg in json.loads((ds / TARGETS).read_text()):
        scene = ds / "test" / f"{tg['scene_id']:06d}"
        gts = _load(scene / "scene_gt.json")[tg["im_id"]]
        for gt in (g for g in gts if g["obj_id"] == tg["obj_id"]):
            t = np.asarray(gt["cam_t_m2c"], float) + [0.0, 0.0, shift * info[tg["obj_id"]]["diameter"]]
            out.append({"scene_id": tg["scene_id"], "im_id": tg["im_id"], "obj_id": tg["obj_id"],
                        "R": np.asarray(gt["cam_R_m2c"], float), "t": t,
                        "R_gt": np.asarray(gt["cam_R_m2c"], float).reshape(3, 3),
                        "t_gt": np.asarray(gt["cam_t_m2c"], float)})
    return out


def write_results(path: Path, ests: list[dict]) -> None:
    """BOP19 CSV: ``scene_id,im_id,obj_id,score,R,t,time`` (R row-major, t in mm, time -1: not measured)."""
    rows = ["scene_id,im_id,obj_id,score,R,t,time"]
    for e in ests:
        rows.append(f"{e['scene_id']},{e['im_id']},{e['obj_id']},1.0,{' '.join(map(repr, map(float, e['R'])))},"
                    f"{' '.join(map(repr, map(float, e['t'])))},-1")
    path.write_text("\n".join(rows) + "\n")


def _sym_transforms(model_info: dict) -> list[tuple[np.ndarray, np.ndarray]]:
    """Identity and each continuous symmetry discretised in ceil(pi / SYM_STEP) rotations (BOP's definition)."""
    syms = [(np.eye(3), np.zeros(3))]
    for s in model_info.get("symmetries_continuous", []):
        a, c = np.asarray(s["axis"], float), np.asarray(s["offset"], float)
        a /= np.linalg.norm(a)
        n = int(math.ceil(math.pi / SYM_STEP))
        for i in range(1, n):
            th = 2 * math.pi * i / n
            A = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            R = np.eye(3) + math.sin(th) * A + (1 - math.cos(th)) * A @ A
            syms.append((R, c - R @ c))
    return syms


def expected_recalls(ds: Path, ests: list[dict], width: int) -> dict:
    """MSSD and MSPD recalls of ``ests`` computed here, independently of the toolkit."""
    import trimesh

    info = _load(ds / "models" / "models_info.json")
    K = np.asarray(_load(ds / "test" / "000000" / "scene_camera.json")[0]["cam_K"], float).reshape(3, 3)
    pts = {o: np.asarray(trimesh.load(ds / "models" / f"obj_{o:06d}.ply", process=False).vertices, float)
           for o in info}
    syms = {o: _sym_transforms(info[o]) for o in info}

    def proj(X):
        x = X @ K.T
        return x[:, :2] / x[:, 2:]

    mssd, mspd = [], []
    for e in ests:
        X = pts[e["obj_id"]]
        pe = X @ e["R"].reshape(3, 3).T + e["t"]
        mssd_e, mspd_e = math.inf, math.inf
        for R, t in syms[e["obj_id"]]:
            pg = (X @ R.T + t) @ e["R_gt"].T + e["t_gt"]
            mssd_e = min(mssd_e, np.linalg.norm(pe - pg, axis=1).max())
            mspd_e = min(mspd_e, np.linalg.norm(proj(pe) - proj(pg), axis=1).max())
        mssd.append(mssd_e / info[e["obj_id"]]["diameter"])
        mspd.append(mspd_e * 640.0 / width)
    recall = lambda err, ths: float(np.mean([np.mean(np.asarray(err) < th) for th in ths]))  # noqa: E731
    return {"mssd": recall(mssd, MSSD_TH), "mspd": recall(mspd, MSPD_TH)}


# ---------------------------------------------------------------- the toolkit's run
def child_env(toolkit: Path, bop_path: Path, bin_dir: Path) -> tuple[dict, str]:
    """The child's environment: ``BOP_PATH``, the toolkit copy first on ``PYTHONPATH``, and a ``python`` that is
    this interpreter first on ``PATH`` (the toolkit starts ``python`` for every metric); and that ``python``."""
    bin_dir.mkdir(parents=True, exist_ok=True)
    wrapper = bin_dir / "python"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" "$@"\n')
    wrapper.chmod(0o755)
    env = dict(os.environ, BOP_PATH=str(bop_path))
    env["PYTHONPATH"] = os.pathsep.join([str(toolkit)] + [p for p in [env.get("PYTHONPATH")] if p])
    env["PATH"] = os.pathsep.join([str(bin_dir), env.get("PATH", "")])
    return env, str(wrapper)


def missing_modules(toolkit: Path, env: dict, python: str) -> list[str]:
    """Modules the evaluation needs that the child cannot import (pip names)."""
    code = ("import importlib, json, sys\nmissing = []\n"
            f"for m in {list(TOOLKIT_MODULES)!r}:\n"
            "    try: importlib.import_module(m)\n    except ImportError: missing.append(m)\n"
            "if not missing:\n"
            "    for m in ['inout', 'misc', 'dataset_params', 'pose_error', 'pose_matching', 'score',\n"
            "              'rendering.renderer_batch']:\n"
            "        try: importlib.import_module('bop_toolkit_lib.' + m)\n"
            "        except ModuleNotFoundError as exc: missing.append(exc.name)\n"
            "print(json.dumps(missing))\n")
    r = subprocess.run([python, "-c", code], env=env, cwd=toolkit, capture_output=True, text=True)
    if r.returncode != 0:
        raise NoToolkit(f"the toolkit's modules do not import: {(r.stderr.strip().splitlines() or [''])[-1]}")
    return [TOOLKIT_MODULES.get(m, m) for m in json.loads(r.stdout)]


def run_eval(toolkit: Path, env: dict, python: str, results: Path, eval_path: Path, names: list[str],
             log: Path) -> None:
    cmd = [python, EVAL_SCRIPT, f"--result_filenames={','.join(names)}", f"--results_path={results}",
           f"--eval_path={eval_path}", "--num_workers=1"]
    with open(log, "w") as f:
        rc = subprocess.run(cmd, env=env, cwd=toolkit, stdout=f, stderr=subprocess.STDOUT).returncode
    if rc != 0:
        tail = log.read_text().strip().splitlines()[-1:]
        raise RuntimeError(f"{EVAL_SCRIPT} failed (exit {rc}): {tail[0] if tail else ''} (log: {log})")


def run(source, work) -> dict:
    """The whole recipe in the existing, empty folder ``work``; returns ``{"toolkit", "targets", "image_size",
    "eval_s", "scores": {method: {...}}, "expected": {...}, "checks": [(name, ok, detail)]}``. Raises
    :class:`NoToolkit` or :class:`RecipeMismatch`."""
    src, work = Path(source), Path(work)
    if not src.exists():
        raise NoToolkit(f"{src}: no such folder")
    toolkit = copy_toolkit(src, work / "bop_toolkit")
    bop_path, results, eval_path = work / "bop", work / "results", work / "eval"
    for d in (bop_path, results, eval_path):
        d.mkdir()
    env, python = child_env(toolkit, bop_path, work / "bin")
    missing = missing_modules(toolkit, env, python)
    if missing:
        raise MissingModules(f"the toolkit's evaluation needs modules missing here: {', '.join(missing)} "
                        f"(pip install {' '.join(missing)}, or put them on PYTHONPATH)")
    cam = make_export(work, bop_path)
    ds = bop_path / DATASET
    info = _load(ds / "models" / "models_info.json")
    apply_recipe(toolkit, bop_path, sorted(info), sorted(o for o, m in info.items() if "symmetries_continuous" in m
                                                         or "symmetries_discrete" in m), cam["width"], cam["height"])
    methods = {"gt": 0.0, "shifted": SHIFT}
    ests, names = {}, []
    for method, shift in methods.items():
        ests[method] = estimates(ds, shift)
        names.append(RESULT_NAME.replace("METHOD", method).replace("NAME", DATASET))
        write_results(results / names[-1], ests[method])
    t0 = time.perf_counter()
    run_eval(toolkit, env, python, results, eval_path, names, work / "eval_bop19_pose.log")
    eval_s = time.perf_counter() - t0
    scores, expected, checks = {}, {}, []
    for (method, shift), name in zip(methods.items(), names):
        s = _load(eval_path / Path(name).stem / "scores_bop19.json", int_keys=False)
        scores[method] = {"mssd": s["bop19_average_recall_mssd"], "mspd": s["bop19_average_recall_mspd"],
                          "bop19": s["bop19_average_recall"]}
        expected[method] = expected_recalls(ds, ests[method], cam["width"])
        for m in ("mssd", "mspd"):
            checks.append((f"{method} {m.upper()} = {expected[method][m]:.4f} (computed here)",
                           abs(scores[method][m] - expected[method][m]) < 1e-9, f"{scores[method][m]:.4f}"))
        mean = (scores[method]["mssd"] + scores[method]["mspd"]) / 2
        checks.append((f"{method} BOP19 recall = mean of MSSD and MSPD", abs(scores[method]["bop19"] - mean) < 1e-9,
                       f"{scores[method]['bop19']:.4f}"))
    checks.append(("gt scores 1.0", all(v == 1.0 for v in scores["gt"].values()), str(scores["gt"])))
    checks.append(("shifted MSSD = 0.6 (6 of 10 thresholds above 0.22)", abs(scores["shifted"]["mssd"] - 0.6) < 1e-9,
                   f"{scores['shifted']['mssd']:.4f}"))
    checks.append(("shifted MSPD between 0 and 1", 0.0 < scores["shifted"]["mspd"] < 1.0,
                   f"{scores['shifted']['mspd']:.4f}"))
    return {"toolkit": toolkit_version(src), "targets": len(ests["gt"]),
            "image_size": (cam["width"], cam["height"]), "eval_s": eval_s, "scores": scores, "expected": expected,
            "checks": checks}


def summary(r: dict) -> str:
    lines = [f"BOP toolkit {r['toolkit']}: the README's recipe applied ({DATASET_PARAMS}: {DATASET} registered; "
             f"{EVAL_SCRIPT}: {VSD} entry and term removed)",
             f"export: {r['targets']} targets, {r['image_size'][0]} x {r['image_size'][1]} images; "
             f"{EVAL_SCRIPT} took {r['eval_s']:.0f} s",
             "method    MSSD    MSPD    BOP19 (MSSD, MSPD computed here)"]
    for m, s in r["scores"].items():
        lines.append(f"{m:8s}  {s['mssd']:.4f}  {s['mspd']:.4f}  {s['bop19']:.4f}  "
                     f"({r['expected'][m]['mssd']:.4f}, {r['expected'][m]['mspd']:.4f})")
    lines += [f"{'ok  ' if ok else 'FAIL'}  {name}: {detail}" for name, ok, detail in r["checks"]]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--toolkit", help=f"checkout, extracted archive or bare git repository (default ${ENV_VAR})")
    ap.add_argument("--workdir", help="where the temporary folder goes (default: the system's)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder (toolkit copy, export, scores)")
    args = ap.parse_args(argv)
    src = find_toolkit(args.toolkit)
    if src is None:
        print(f"no BOP toolkit: pass --toolkit or set {ENV_VAR} (a checkout of github.com/thodan/bop_toolkit)")
        return 2
    work = Path(tempfile.mkdtemp(prefix="bop_eval_recipe-", dir=args.workdir))
    try:
        r = run(src, work)
    except NoToolkit as exc:
        print(exc)
        return 2
    except RecipeMismatch as exc:
        print(exc)
        return 1
    finally:
        if args.keep:
            print(f"kept {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
    print(summary(r))
    ok = all(c[1] for c in r["checks"])
    print("PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
