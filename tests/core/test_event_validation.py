"""EventStore validation (issue 11, item 6): events outside the sensor, bad polarities and unsorted times
are refused when the store opens -- naming the file, the field, the first bad index and its value -- by one
chunked pass that is cached with the ms index (a second open reads nothing), never beside the file.

Documented choice: refuse (nothing is silently dropped; ``evpose import ... --repair`` drops with a count).
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from evpose_testing import msidx_cache_file
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import evpose.core.data.event_index as ei
import evpose.core.data.event_validation as ev_val
from evpose.core.data.event_store import EventStore
from evpose.core.data.events import EventFileError

W, H = 346, 260


pytestmark = pytest.mark.usefixtures("private_cache")
cache_file = msidx_cache_file


def events(n=5000, seed=0, t0=10**12):
    rng = np.random.default_rng(seed)
    t = t0 + np.sort(rng.integers(0, 50 * n, n)).astype(np.int64)
    return {"x": rng.integers(0, W, n).astype(np.uint16), "y": rng.integers(0, H, n).astype(np.uint16),
            "t": t, "p": rng.integers(0, 2, n).astype(np.uint8)}


def write(path, cols, *, with_index=False, chunks=(256,)):
    """A DSEC-style file written with h5py alone; ``with_index`` adds a correct ms_to_idx (t_offset = 0
    relative times)."""
    off = int(cols["t"][0]) if len(cols["t"]) else 0
    with h5py.File(path, "w") as f:
        for k, v in cols.items():
            v = v - off if k == "t" else v
            f.create_dataset(f"events/{k}", data=v, chunks=chunks if len(v) else None)
        f["t_offset"] = np.int64(off)
        if with_index:
            t_rel = np.sort(cols["t"] - off)   # from the sorted times: a plausible index even for unsorted data
            f["ms_to_idx"] = np.searchsorted(t_rel, 1000 * np.arange(int(t_rel[-1]) // 1000 + 1)).astype(np.uint64)
    return Path(path)


def counting(monkeypatch):
    calls = {"t": 0, "xyp": 0}
    real_t, real_v = ev_val.scan_index, ev_val.scan_values

    def scan_t(*a, **k):
        calls["t"] += 1
        return real_t(*a, **k)

    def scan_v(*a, **k):
        calls["xyp"] += 1
        return real_v(*a, **k)
    monkeypatch.setattr(ev_val, "scan_index", scan_t)
    monkeypatch.setattr(ev_val, "scan_values", scan_v)
    return calls


# --------------------------------------------------------------------------------------------- refusals
CASES = {
    # name: (column, dtype or None, index, value, field, words in the message)
    "x beyond width": ("x", None, 1234, 1000, "events/x", ["1000 at index 1234", "outside the 346x260 sensor"]),
    "x == width": ("x", None, 4000, W, "events/x", [f"{W} at index 4000", "x must be < width 346"]),
    "y beyond height": ("y", None, 17, 260, "events/y", ["260 at index 17", "y must be < height 260"]),
    "negative y": ("y", np.int16, 77, -5, "events/y", ["-5 at index 77", "negative"]),
    "negative x": ("x", np.int32, 0, -1, "events/x", ["-1 at index 0", "negative"]),
    "polarity 7": ("p", None, 99, 7, "events/p", ["7 at index 99", "expected 0 or 1"]),
    "signed polarity -2": ("p", np.int8, 3, -2, "events/p", ["-2 at index 3", "expected -1, 0 or 1"]),
}


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("with_index", [False, True], ids=["built-index", "file-index"])
def test_bad_values_are_refused_naming_file_field_index_and_value(tmp_path, case, with_index):
    col, dtype, i, v, field, words = CASES[case]
    cols = events()
    if dtype is not None:
        cols[col] = cols[col].astype(dtype)
    cols[col][i] = v
    cols[col][i + 500] = v            # a later bad event too: the first one is named
    path = write(tmp_path / "bad.h5", cols, with_index=with_index)
    with pytest.raises(EventFileError) as e:
        EventStore(path, sensor_size=(W, H))
    msg = str(e.value)
    assert msg.startswith(f"{path}: {field}: ") and e.value.field == field
    for w in words:
        assert w in msg
    # sensor-independent faults are never cached; for the sensor range the cache holds the measured x/y
    # range (not a verdict), so every open with this sensor refuses again
    assert cache_file(path).exists() == ("outside" in msg)
    with pytest.raises(EventFileError, match=words[0]):
        EventStore(path, sensor_size=(W, H))


@pytest.mark.parametrize("with_index", [False, True], ids=["built-index", "file-index"])
def test_unsorted_times_are_refused_even_with_a_plausible_ms_index(tmp_path, with_index):
    cols = events()
    k = 2500
    cols["t"][k], cols["t"][k + 1] = cols["t"][k + 1] + 3, cols["t"][k]     # a decreasing pair inside one ms bin
    path = write(tmp_path / "unsorted.h5", cols, with_index=with_index)
    if with_index:
        with h5py.File(path, "r") as f:                   # the index passes the store's spot checks
            assert "ms_to_idx" in f
    with pytest.raises(EventFileError, match=rf"events/t: not sorted at index {k + 1} "):
        EventStore(path, sensor_size=(W, H))


def test_values_on_the_edges_and_signed_types_are_accepted(tmp_path):
    cols = events()
    cols["x"][10], cols["y"][10] = W - 1, H - 1
    cols["x"] = cols["x"].astype(np.int32)
    cols["p"] = np.where(cols["p"] > 0, 1, -1).astype(np.int8)
    path = write(tmp_path / "ok.h5", cols)
    with EventStore(path, sensor_size=(W, H)) as s:
        ev = s.read(0, s.n_events)
        assert ev.x.max() == W - 1 and ev.y.max() == H - 1 and set(np.unique(ev.p)) == {0, 1}
    cols["p"] = cols["p"] > 0                             # a boolean polarity is always valid
    with EventStore(write(tmp_path / "b.h5", cols), sensor_size=(W, H)) as s:
        assert s.n_events == 5000


def test_without_a_sensor_size_only_sensor_independent_checks_apply(tmp_path):
    cols = events()
    cols["x"][5] = 60000
    path = write(tmp_path / "wide.h5", cols)
    with EventStore(path) as s:                           # no sensor known: a 60000 px column is fine
        assert s.n_events == 5000
    with pytest.raises(EventFileError, match=r"events/x: 60000 at index 5 is outside the 346x260 sensor"):
        EventStore(path, sensor_size=(W, H))              # the cached pass knows x_max: only then searched


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(2, 3000), data=st.data(), kind=st.sampled_from(["x", "y", "p", "t"]),
       scan_chunk=st.sampled_from([1, 7, 256, 2**21]))
def test_property_the_first_bad_event_is_named(tmp_path_factory, monkeypatch, n, data, kind, scan_chunk):
    monkeypatch.setattr(ei, "SCAN_CHUNK_EVENTS", scan_chunk)
    d = tmp_path_factory.mktemp("prop")
    cols = events(n, seed=n)
    first = data.draw(st.integers(1, n - 1), label="first bad index")
    later = data.draw(st.lists(st.integers(first, n - 1), max_size=3), label="later bad indices")
    for i in [first, *later]:
        if kind == "x":
            cols["x"][i] = data.draw(st.integers(W, 65535))
        elif kind == "y":
            cols["y"][i] = data.draw(st.integers(H, 65535))
        elif kind == "p":
            cols["p"][i] = data.draw(st.integers(2, 255))
    if kind == "t":
        cols["t"][first] = cols["t"][first - 1] - data.draw(st.integers(1, 10**6))
    path = write(d / "f.h5", cols, chunks=(min(n, data.draw(st.sampled_from([1, 64, 1024]))),))
    with pytest.raises(EventFileError) as e:
        EventStore(path, sensor_size=(W, H))
    expect = {"x": f"at index {first} is outside", "y": f"at index {first} is outside",
              "p": f"at index {first} is not a polarity", "t": f"not sorted at index {first} "}[kind]
    assert e.value.field == f"events/{kind}" and expect in str(e.value)


# --------------------------------------------------------------------------------------------- cache
def test_second_open_reads_nothing_and_the_cache_is_keyed_by_size_and_mtime(tmp_path, monkeypatch):
    calls = counting(monkeypatch)
    path = write(tmp_path / "ev.h5", events(), with_index=True)
    EventStore(path, sensor_size=(W, H)).close()
    assert calls == {"t": 1, "xyp": 1}
    assert cache_file(path).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ev.h5"]           # nothing beside the file
    for _ in range(2):
        EventStore(path, sensor_size=(W, H)).close()
    assert calls == {"t": 1, "xyp": 1}                                        # cached: no pass at all
    st_ = os.stat(path)
    os.utime(path, ns=(st_.st_atime_ns, st_.st_mtime_ns + 1_000_000))          # touched: validated again
    EventStore(path, sensor_size=(W, H)).close()
    assert calls == {"t": 2, "xyp": 2}
    copy = tmp_path / "copy.h5"                                               # another path: its own entry
    shutil.copy2(path, copy)
    EventStore(copy, sensor_size=(W, H)).close()
    assert calls == {"t": 3, "xyp": 3} and cache_file(copy) != cache_file(path)


def test_a_file_changed_in_place_with_the_same_size_and_mtime_is_not_trusted_by_inode(tmp_path, monkeypatch):
    calls = counting(monkeypatch)
    path = write(tmp_path / "ev.h5", events())
    EventStore(path, sensor_size=(W, H)).close()
    st_ = os.stat(path)
    bad = events()
    bad["x"][3] = 999
    other = write(tmp_path / "other.h5", bad)
    os.replace(other, path)                                                   # same size, new inode
    os.utime(path, ns=(st_.st_atime_ns, st_.st_mtime_ns))
    assert os.stat(path).st_size == st_.st_size
    with pytest.raises(EventFileError, match="events/x: 999 at index 3"):
        EventStore(path, sensor_size=(W, H))
    assert calls["xyp"] == 2


def test_read_only_source_folder_gets_no_cache_file(tmp_path):
    src = tmp_path / "source"
    src.mkdir()
    path = write(src / "events.h5", events())
    os.chmod(src, 0o555)
    try:
        before = sorted(os.listdir(src))
        with EventStore(path, sensor_size=(W, H)) as s:
            assert s.n_events == 5000
        assert sorted(os.listdir(src)) == before and cache_file(path).exists()
    finally:
        os.chmod(src, 0o755)


def test_a_folder_is_refused_before_hdf5_opens_it(tmp_path):
    (tmp_path / "dir.h5").mkdir()
    with pytest.raises(EventFileError, match=r"dir\.h5: \(file\): is a folder, expected a regular file"):
        EventStore(tmp_path / "dir.h5")
