"""What a dataset is (issue 13, point 1): the scene subfolders in name order, or a dataset.toml listing
scene folders with shared defaults; bad dataset files end in one line naming the file and the field."""
from __future__ import annotations

import shutil

import pytest

from evpose.core.dataset.dataset import Dataset, DatasetError


@pytest.fixture
def two_scenes(tiny_scene_dir, tmp_path):
    root = tmp_path / "ds"
    for name in ("b_second", "a_first"):
        shutil.copytree(tiny_scene_dir, root / name)
    (root / "not_a_scene").mkdir()
    (root / "notes.txt").write_text("hello")
    return root


def test_scene_subfolders_in_name_order(two_scenes):
    ds = Dataset.open(two_scenes)
    assert [r.name for r in ds.scenes] == ["a_first", "b_second"]
    assert ds.source == "folder" and ds.name == "ds" and ds.defaults == {}


def test_dataset_toml_lists_scenes_and_gives_defaults(two_scenes):
    """A scene whose scene.toml leaves out [camera] takes the dataset's; a scene's own keys win."""
    toml = two_scenes / "b_second" / "scene.toml"
    text = toml.read_text()
    start = text.index("[camera]")
    end = text.index("\n[", start + 1)
    camera_table = text[start:end]
    toml.write_text(text[:start] + text[end + 1:])            # b_second relies on the defaults
    (two_scenes / "dataset.toml").write_text(
        'format = "evpose-dataset/1"\nname = "mine"\nscenes = ["b_second", "a_first"]\n\n'
        + camera_table.replace("[camera]", "[defaults.camera]") + "\n")
    ds = Dataset.open(two_scenes / "dataset.toml")
    assert ds.name == "mine" and ds.source == "dataset.toml"
    assert [r.name for r in ds.scenes] == ["b_second", "a_first"]          # listed order, not name order
    s_b, s_a = ds.open_scene(ds.scenes[0]), ds.open_scene(ds.scenes[1])
    try:
        assert (s_b.camera.K == s_a.camera.K).all() and s_b.camera.width == s_a.camera.width
    finally:
        s_b.close()
        s_a.close()
    from evpose.core.data.manifest import SceneError
    from evpose.core.data.scene import Scene

    with pytest.raises(SceneError, match="camera"):                          # alone, the scene lacks a camera
        Scene.open(ds.scenes[0].path)


@pytest.mark.parametrize("body, field", [
    ('format = "other"\nscenes = ["a_first"]\n', "format"),
    ('format = "evpose-dataset/1"\nscenes = []\n', "scenes"),
    ('format = "evpose-dataset/1"\nscenes = ["nowhere"]\n', "scenes[0]"),
    ('format = "evpose-dataset/1"\nscenes = ["a_first", "./a_first"]\n', "scenes[1]"),
    ('format = "evpose-dataset/1"\nscenes = ["a_first"]\n[defaults.events]\npath = "x.h5"\n', "defaults.events"),
    ('format = "evpose-dataset/1"\nscenes = ["a_first"]\n[defaults.trajectory]\npath = "t.csv"\n',
     "defaults.trajectory.path"),
    ('format = "evpose-dataset/1"\nscenes = ["a_first"\n', "not valid TOML"),
])
def test_bad_dataset_toml_names_the_file_and_field(two_scenes, body, field):
    (two_scenes / "dataset.toml").write_text(body)
    with pytest.raises(DatasetError) as e:
        Dataset.open(two_scenes)
    assert str(two_scenes / "dataset.toml") in str(e.value) and field in str(e.value)
    assert "\n" not in str(e.value)


def test_a_folder_without_scenes_is_refused(tmp_path):
    with pytest.raises(DatasetError, match="no subfolder holds a scene.toml"):
        Dataset.open(tmp_path)
    with pytest.raises(DatasetError, match="no such folder"):
        Dataset.open(tmp_path / "missing")
