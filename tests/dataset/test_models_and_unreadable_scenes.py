"""Issue 22, parts 3 and 4, in the process.

``dataset export --format bop`` refuses, before any scene is exported, scenes that give one obj_id to different
models (:func:`evpose.core.dataset.bop_dataset.check_models`) -- and only those: the same model in another file
is the same model, as the merge compares the PLY bytes. A scene that cannot be read stays a scene of the dataset,
with its reason, in both kinds of dataset (the commands report it: ``tests/faults/test_outputs_and_merge.py``)."""
from __future__ import annotations

import shutil
import struct

import pytest

from evpose.core.dataset.bop_dataset import BopAssemblyError, check_models
from evpose.core.dataset.dataset import Dataset, DatasetError


def set_mesh(scene, old: str, new: str) -> None:
    toml = scene / "scene.toml"
    toml.write_text(toml.read_text().replace(f'mesh = "{old}"', f'mesh = "{new}"'))


def test_the_same_model_in_another_file_passes(dataset_copy):
    b = dataset_copy / "scene_b"
    shutil.copyfile(b / "models" / "box.ply", b / "models" / "box_copy.ply")
    set_mesh(b, "models/box.ply", "models/box_copy.ply")             # same bytes elsewhere: the digest says so
    c = dataset_copy / "scene_c"
    data = (c / "models" / "cylinder.ply").read_bytes()
    head = data.index(b"\n", data.index(b"format")) + 1
    (c / "models" / "cylinder_2.ply").write_bytes(data[:head] + b"comment converted by hand\n" + data[head:])
    set_mesh(c, "models/cylinder.ply", "models/cylinder_2.ply")       # other bytes, the same model: loaded, compared
    check_models(Dataset.open(dataset_copy))
    body = data.index(b"end_header\n") + len(b"end_header\n")
    x0 = struct.unpack("<f", data[body:body + 4])[0]
    (c / "models" / "cylinder_2.ply").write_bytes(data[:body] + struct.pack("<f", x0 + 1e-3) + data[body + 4:])
    with pytest.raises(BopAssemblyError, match="cylinder_2.ply"):
        check_models(Dataset.open(dataset_copy))


@pytest.mark.parametrize("change", ["other mesh", "other name"])
def test_one_obj_id_for_two_models_is_refused_naming_the_scene_and_object(dataset_copy, change):
    b = dataset_copy / "scene_b"
    if change == "other mesh":
        set_mesh(b, "models/box.ply", "models/cylinder.ply")
    else:                                  # the model file names the object: another name is another model
        toml = b / "scene.toml"
        toml.write_text(toml.read_text().replace('name = "box"', 'name = "crate"'))
    with pytest.raises(BopAssemblyError) as e:
        check_models(Dataset.open(dataset_copy))
    msg = str(e.value)
    assert msg.startswith(f"{b / 'scene.toml'}: objects[0]: ") and "scene 'scene_a'" in msg and "\n" not in msg
    assert "distinct class ids" in msg
    check_models(Dataset.open(dataset_copy), objects="cylinder,flatbox")       # the box is not exported: fine


def test_unreadable_scenes_stay_in_the_dataset_with_their_reason(dataset_copy):
    import os

    (dataset_copy / "loop").symlink_to("loop")
    (dataset_copy / "gone").symlink_to(dataset_copy.parent / "moved_away")
    (dataset_copy / "scene_b" / "scene.toml").unlink()
    os.mkfifo(dataset_copy / "scene_b" / "scene.toml")
    (dataset_copy / "notes").mkdir()                              # no scene.toml: not a scene
    ds = Dataset.open(dataset_copy)
    errors = {ref.name: ref.error for ref in ds.scenes}
    assert list(errors) == ["gone", "loop", "scene_a", "scene_b", "scene_c"]
    assert "moved_away, which does not exist" in errors["gone"] and "symbolic links" in errors["loop"]
    assert "scene.toml: is a FIFO" in errors["scene_b"] and errors["scene_a"] is None
    with pytest.raises(DatasetError, match="is a FIFO"):
        ds.open_scene(ds.scene("scene_b"))
    (dataset_copy / "dataset.toml").write_text('format = "evpose-dataset/1"\nscenes = ["scene_a", "loop"]\n')
    listed = Dataset.open(dataset_copy)
    assert [(r.name, r.error is None) for r in listed.scenes] == [("scene_a", True), ("loop", False)]
