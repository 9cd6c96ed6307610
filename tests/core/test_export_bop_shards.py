"""BOP-webdataset shards (issue 27.4, ``--bop-shards``): the shards hold exactly what the scene-wise export writes
(the same PNG bytes, the masks in bop_toolkit's RLE, each image's entries of scene_gt / scene_gt_info /
scene_camera), one file per shard; they are byte-reproducible (one process, a pool, a resume), a shard is written
whole (a resume after a kill rewrites a shard whose windows were not all journaled), and the dataset assembly links
every scene's shards under one numbering with one key_to_shard.json."""
from __future__ import annotations

import hashlib
import io
import json
import shutil
import tarfile
from itertools import groupby

import cv2
import numpy as np
import pytest

from evpose.core.export import ExportError, export_scene
from evpose.core.export.bop_shards import SHARD_MEMBERS, mask_rle

SD = "test/000000"
WEB = "test_web"


def reference_rle(mask: np.ndarray) -> dict:
    """bop_toolkit's ``pycoco_utils.binary_mask_to_rle`` as its source defines it (groupby over the Fortran-order
    pixels, a leading 0 when the first pixel is set)."""
    counts = []
    for i, (value, run) in enumerate(groupby(mask.ravel(order="F"))):
        if i == 0 and value == 1:
            counts.append(0)
        counts.append(len(list(run)))
    return {"counts": counts, "size": list(mask.shape)}


def decode_rle(rle: dict) -> np.ndarray:
    H, W = rle["size"]
    flat = np.zeros(H * W, bool)
    pos, val = 0, False
    for c in rle["counts"]:
        flat[pos:pos + c] = val
        pos += c
        val = not val
    assert pos == H * W
    return flat.reshape((H, W), order="F")


@pytest.mark.parametrize("case", ["random", "first_set", "empty", "full", "one_px", "last_px"])
def test_mask_rle_is_the_toolkits_encoding(case):
    rng = np.random.default_rng(3)
    m = np.zeros((7, 5), bool)
    if case == "random":
        m = rng.random((13, 9)) < 0.4
    elif case == "first_set":
        m[0, 0] = m[1, 0] = m[3, 2] = True
    elif case == "full":
        m[:] = True
    elif case == "one_px":
        m[4, 3] = True
    elif case == "last_px":
        m[-1, -1] = True
    assert mask_rle(m, m.shape) == reference_rle(m.astype(np.uint8))
    assert np.array_equal(decode_rle(mask_rle(m, m.shape)), m)
    assert mask_rle(None, (4, 6)) == reference_rle(np.zeros((4, 6), np.uint8))


def _members(out) -> dict:
    """key -> {member: bytes} over every shard of ``out``, checking each shard's member order and headers."""
    web = out / WEB
    keys = json.loads((web / "key_to_shard.json").read_text())
    found = {}
    for tar_path in sorted(web.glob("shard-*.tar")):
        n = int(tar_path.stem.split("-")[1])
        with tarfile.open(tar_path) as tar:
            infos = tar.getmembers()
            names = [i.name for i in infos]
            assert names == sorted(names, key=lambda s: (s.split(".")[0], SHARD_MEMBERS.index(s.split(".", 1)[1])))
            assert all(i.mtime == 0 and i.uid == 0 and i.gid == 0 and i.mode == 0o644 for i in infos)
            for i in infos:
                key, ext = i.name.split(".", 1)
                assert keys[key] == n
                found.setdefault(key, {})[ext] = tar.extractfile(i).read()
    assert set(found) == set(keys)
    return found


@pytest.fixture(scope="module")
def plain_and_sharded(tiny_scene_dir, tmp_path_factory):
    root = tmp_path_factory.mktemp("shards")
    plain = export_scene(tiny_scene_dir, "bop", root / "plain")
    sharded = export_scene(tiny_scene_dir, "bop", root / "sharded", format_options={"shard_windows": 8})
    return root, plain, sharded


def test_shards_hold_what_the_scene_wise_export_writes(plain_and_sharded):
    root, plain, sharded = plain_and_sharded
    assert sharded.written == plain.written > 16
    members = _members(root / "sharded")
    gt = json.loads((root / "plain" / SD / "scene_gt.json").read_text())
    info = json.loads((root / "plain" / SD / "scene_gt_info.json").read_text())
    cam = json.loads((root / "plain" / SD / "scene_camera.json").read_text())
    assert sorted(members) == [f"000000_{int(i):06d}" for i in sorted(gt, key=int)]
    n_masks = 0
    for key, m in members.items():
        assert set(m) == set(SHARD_MEMBERS)
        i = int(key.split("_")[1])
        assert m["rgb.png"] == (root / "plain" / SD / "rgb" / f"{i:06d}.png").read_bytes()
        assert json.loads(m["gt.json"]) == gt[str(i)]
        assert json.loads(m["gt_info.json"]) == info[str(i)]
        assert json.loads(m["camera.json"]) == cam[str(i)]
        for kind in ("mask", "mask_visib"):
            rles = json.loads(m[f"{kind}.json"])
            assert sorted(rles, key=int) == [str(g) for g in range(len(gt[str(i)]))]
            for g, rle in rles.items():
                png = cv2.imread(str(root / "plain" / SD / kind / f"{i:06d}_{int(g):06d}.png"), cv2.IMREAD_UNCHANGED)
                assert np.array_equal(decode_rle(rle), png > 0)
                n_masks += int((png > 0).any())
    assert n_masks > 0                                      # not only empty masks
    # the scene-wise annotations are still written; images and masks only in the shards
    for name in ("scene_gt.json", "scene_gt_info.json", "scene_camera.json"):
        assert (root / "sharded" / SD / name).read_bytes() == (root / "plain" / SD / name).read_bytes()
    assert not (root / "sharded" / SD / "rgb").exists() and not (root / "sharded" / SD / "mask").exists()
    shards = sorted(p.name for p in (root / "sharded" / WEB).glob("shard-*.tar"))
    assert shards == [f"shard-{n:06d}.tar" for n in sorted({int(k.split('_')[1]) // 8 for k in members})]
    assert len(sharded.files) < len(plain.files) - plain.written * 2
    assert f"{WEB}/key_to_shard.json" in sharded.files and all(f"{WEB}/{s}" in sharded.files for s in shards)


def _digest(folder) -> dict:
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and ".evpose" not in p.parts
            and p.name not in ("export_manifest.json", "export_journal.jsonl")}


def test_shards_are_the_same_bytes_from_a_pool_and_after_a_resume(plain_and_sharded, tiny_scene_dir):
    root, _plain, _sharded = plain_and_sharded
    ref = _digest(root / "sharded")
    pooled = root / "pooled"
    export_scene(tiny_scene_dir, "bop", pooled, format_options={"shard_windows": 8}, jobs=2)
    assert _digest(pooled) == ref
    # a kill after a shard was written but before its windows were journaled: the shard is written again, whole
    journal = pooled / ".evpose" / "journal.jsonl"
    lines = journal.read_text().splitlines(keepends=True)
    index = [json.loads(ln)["i"] for ln in lines]
    lost = {min(i for i in index if i // 8 == 1)}
    journal.write_text("".join(ln for ln, i in zip(lines, index) if i not in lost))
    (pooled / WEB / "shard-000002.tar").unlink()          # and a kill before another shard was written
    again = export_scene(tiny_scene_dir, "bop", pooled, format_options={"shard_windows": 8})
    assert again.skipped_complete > 0 and again.written >= 8
    assert _digest(pooled) == ref


def test_bop_shards_option_is_checked(tiny_scene_dir, tmp_path):
    for bad in (-1, 5001, 2.5, True):
        with pytest.raises(ExportError, match="shard_windows"):
            export_scene(tiny_scene_dir, "bop", tmp_path / "x", format_options={"shard_windows": bad})


def test_cli_bop_shards(tiny_scene_dir, tmp_path, capsys):
    from evpose.app.cli import main
    from evpose.app.cli.export import BOP_SHARDS_DEFAULT
    from evpose.core.export.bop_shards import DEFAULT_SHARD_WINDOWS

    assert BOP_SHARDS_DEFAULT == DEFAULT_SHARD_WINDOWS

    assert main(["export", str(tiny_scene_dir), "--format", "bop", "--out", str(tmp_path / "b"), "--bop-shards",
                 "-q"]) == 0
    assert (tmp_path / "b" / WEB / "shard-000000.tar").is_file()
    for args, msg in ((["--format", "epose", "--bop-shards", "4"], "--bop-shards: only for --format bop"),
                      (["--format", "bop", "--bop-shards", "0"], "--bop-shards: must be a number of windows")):
        capsys.readouterr()
        assert main(["export", str(tiny_scene_dir), "--out", str(tmp_path / "c"), "-q", *args]) != 0
        err = capsys.readouterr().err
        assert msg in err and "Traceback" not in err


def test_the_dataset_assembly_numbers_every_scenes_shards_on(tiny_scene_dir, tmp_path):
    from evpose.core.dataset.bop_dataset import BopAssemblyError, assemble_bop

    out = tmp_path / "out"
    names = ["a", "b"]
    for k, name in enumerate(names):
        export_scene(tiny_scene_dir, "bop", out / name, format_options={"shard_windows": 16, "key_scene_id": k})
    bop = assemble_bop(out, names, names)
    keys = json.loads((bop / WEB / "key_to_shard.json").read_text())
    per_scene = [json.loads((out / n / WEB / "key_to_shard.json").read_text()) for n in names]
    n0 = len(set(per_scene[0].values()))
    assert len(keys) == sum(len(k) for k in per_scene)
    assert sorted(p.name for p in (bop / WEB).glob("shard-*.tar")) == \
        [f"shard-{n:06d}.tar" for n in range(n0 + len(set(per_scene[1].values())))]
    for k, scene_keys in enumerate(per_scene):
        for key, n in scene_keys.items():
            g = sorted(set(scene_keys.values())).index(n) + (n0 if k else 0)
            assert key.startswith(f"{k:06d}_") and keys[key] == g
            assert (bop / WEB / f"shard-{g:06d}.tar").samefile(out / names[k] / WEB / f"shard-{n:06d}.tar")
    assert f"{WEB}/key_to_shard.json" in json.loads((bop / "scene_names.json").read_text())["files"]
    # a scene exported alone (its keys say scene 0) cannot be scene 1 of the dataset
    shutil.rmtree(out / "b")
    export_scene(tiny_scene_dir, "bop", out / "b", format_options={"shard_windows": 16})
    with pytest.raises(BopAssemblyError, match="scene id 1"):
        assemble_bop(out, names, names)
    assert json.loads((bop / WEB / "key_to_shard.json").read_text()) == keys     # the dataset kept as it was
