"""Same inputs, same bytes (issue 22 item 2; DESIGN section 9): one scene exported in every format by one process,
by ``--jobs 2`` and by ``evpose dataset export --workers 2`` (Dask) gives byte-identical files, every file of the
export compared byte for byte, also with BOP shards and label sigmas (the manifest included; only evpose's own bookkeeping under ``.evpose/`` -- its
ownership logs and resume journal, named by process -- differs). Resumes after kill -9 are pinned in
``test_force_and_leftovers.py`` the same way."""
import shutil

import pytest

from evpose_testing import describe_file_differences
from fault_harness import assert_ok, run_cli

ARGS = ("-q", "--window-ms", "20")


def _files(root) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and ".evpose" not in p.relative_to(root).parts}


@pytest.fixture(scope="module")
def one_scene_dataset(tiny_scene_dir, tmp_path_factory):
    ds = tmp_path_factory.mktemp("same_bytes") / "ds"
    shutil.copytree(tiny_scene_dir, ds / "tiny")
    return ds


@pytest.mark.parametrize("fmt, extra", [("epose", ()), ("bop", ()), ("h5", ()),
                                        ("bop", ("--bop-shards", "8")),                       # issue 27.4
                                        ("h5", ("--label-sigma", "offset_us=2000,pose_mm=1,pose_deg=0.5"))],  # 28.1
                         ids=["epose", "bop", "h5", "bop-shards", "h5-label-sigma"])
def test_one_process_jobs_and_dask_workers_write_the_same_bytes(one_scene_dataset, tmp_path, fmt, extra):
    scene = one_scene_dataset / "tiny"
    args = (*ARGS, *extra)
    assert_ok(run_cli("export", scene, "--format", fmt, "--out", tmp_path / "one", *args))
    assert_ok(run_cli("export", scene, "--format", fmt, "--out", tmp_path / "jobs", "--jobs", "2", *args))
    assert_ok(run_cli("dataset", "export", one_scene_dataset, "--format", fmt, "--out", tmp_path / "dask",
                      "--workers", "2", *args, timeout=300))
    ref = _files(tmp_path / "one")
    assert len(ref) >= (3 if fmt == "h5" else 20) and "export_manifest.json" in ref
    for other in ("jobs", "dask/tiny"):
        got = _files(tmp_path / other)
        assert got.keys() == ref.keys(), other
        assert describe_file_differences(got, ref) == [], other
