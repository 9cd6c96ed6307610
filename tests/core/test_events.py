"""Tests of the event modules: EventArray (events), EventStore (event_store: lazy ms-indexed reader), EventWriter (event_writer: atomic streaming writer)."""
import hashlib
import os
import tempfile
import warnings
from pathlib import Path
from unittest import mock

import h5py
import numpy as np
import pytest
from evpose_testing import msidx_cache_file
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import evpose.core.data.event_index as ei
import evpose.core.data.event_store as es
import evpose.core.data.event_validation as ev_val
import evpose.core.data.event_writer as ew
from evpose.core.data.event_store import EventStore
from evpose.core.data.event_writer import EventWriter, write_events_h5
from evpose.core.data.events import Cancelled, EventArray, EventFileError

pytestmark = pytest.mark.usefixtures("private_cache")
cache_file = msidx_cache_file


def make_events(t, seed=0):
    t = np.asarray(t, np.int64)
    rng = np.random.default_rng(seed)
    return EventArray(rng.integers(0, 640, len(t)), rng.integers(0, 480, len(t)), t, rng.integers(0, 2, len(t)))


def oracle_ms_index(t_rel):
    """DSEC definition, computed independently: ms_to_idx[k] = first index with t_rel >= 1000 k."""
    if len(t_rel) == 0:
        return np.empty(0, np.int64)
    return np.searchsorted(t_rel, 1000 * np.arange(int(t_rel[-1]) // 1000 + 1), side="left").astype(np.int64)


def write_raw(path, ev, *, t_dtype="int64", t_offset=None, with_index=False, index_dtype=np.int64, skip=(),
              override=None, chunks=True):
    """Write a DSEC-style file directly with h5py (no evpose code), optionally malformed."""
    off = 0 if t_offset is None else t_offset
    stored = {"x": ev.x, "y": ev.y, "t": (ev.t - off).astype(t_dtype), "p": ev.p}
    stored.update(override or {})
    with h5py.File(path, "w") as f:
        for k, v in stored.items():
            if f"events/{k}" not in skip:
                f.create_dataset(f"events/{k}", data=v, chunks=chunks if np.ndim(v) and len(v) else None)
        if t_offset is not None:
            f.create_dataset("t_offset", data=np.int64(t_offset))
        if with_index:
            f.create_dataset("ms_to_idx", data=oracle_ms_index(ev.t - off).astype(index_dtype))
    return Path(path)


def assert_same(a: EventArray, b: EventArray):
    assert len(a) == len(b)
    for f in "xytp":
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
        assert getattr(a, f).dtype == getattr(b, f).dtype


def oracle_window(ev, t0, t1):
    i0, i1 = np.searchsorted(ev.t, [t0, t1], side="left")
    return ev[slice(i0, max(i0, i1))]


def file_state(path):
    st_ = os.stat(path)
    return hashlib.sha256(Path(path).read_bytes()).hexdigest(), st_.st_mtime_ns, st_.st_size


def dup_times(n=3000, seed=1, start=1_000_000):
    """Sorted times (µs) with many duplicates and gaps, plus 3 events at every multiple of 10 ms in the span."""
    rng = np.random.default_rng(seed)
    t = start + np.cumsum(rng.choice([0, 0, 0, 1, 7, 250, 999, 1000, 2000, 4321], size=n))
    grid = np.arange(-(-int(t[0]) // 10_000) * 10_000, int(t[-1]), 10_000)
    return np.sort(np.concatenate([t, np.repeat(grid, 3)]))


@pytest.fixture(params=["file_index", "built_index"])
def dup_file(request, tmp_path):
    ev = make_events(dup_times())
    if request.param == "file_index":
        path = write_events_h5(tmp_path / "ev.h5", ev, time_dtype="uint32", chunk_events=64)
    else:
        path = write_raw(tmp_path / "ev.h5", ev)
    return path, ev


# ----------------------------------------------------------------------------------------------- EventArray
def test_eventarray_casts_validates_and_slices():
    e = EventArray([1, 2, 3], np.array([4, 5, 6], np.int32), np.array([10, 10, 20], np.uint32), [True, False, True])
    assert (e.x.dtype, e.y.dtype, e.t.dtype, e.p.dtype) == (np.uint16, np.uint16, np.int64, np.uint8)
    x = np.arange(3, dtype=np.uint16)
    assert EventArray(x, x, np.arange(3), np.zeros(3, np.uint8)).x is x      # no copy when the dtype is right
    assert len(e[1:]) == 2 and list(e[np.array([True, False, True])].t) == [10, 20] and list(e[[2, 0]].x) == [3, 1]
    with pytest.raises(TypeError):
        e[0]
    with pytest.raises(ValueError, match="y"):
        EventArray([1, 2], [1], [1, 2], [0, 1])
    with pytest.raises(ValueError, match="x"):
        EventArray([70000], [1], [1], [0])
    with pytest.raises(ValueError, match="p"):
        EventArray([1], [1], [1], [-1])
    with pytest.raises(TypeError, match="t"):
        EventArray([1], [1], [1.5], [0])
    with pytest.raises(ValueError):
        EventArray(*(np.zeros((2, 2), np.int64),) * 4)
    assert len(EventArray([], [], [], [])) == 0 and EventArray.empty().t.dtype == np.int64
    c = EventArray.concatenate([e[:1], EventArray.empty(), e[1:]])
    assert_same(c, e)
    assert len(EventArray.concatenate([])) == 0


# ----------------------------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("compression", ["blosc-lz4", "gzip", None])
@pytest.mark.parametrize("start", [123_456, 1_700_000_000_000_000, -5_000])
def test_roundtrip_int64(tmp_path, compression, start):
    ev = make_events(dup_times(start=start))
    path = write_events_h5(tmp_path / "a.h5", [ev[:1000], ev[1000:]], compression=compression, chunk_events=128)
    with h5py.File(path) as f:
        assert f["events/t"].dtype == np.int64 and f["ms_to_idx"].dtype == np.int64
        off = int(f["t_offset"][()])
        # relative clocks from the first event's whole ms (issue 26.5: the index follows the recording's duration,
        # not its start on the sensor clock; bins on whole ms as with 0); epoch and negative times from the first event
        assert off == ((int(ev.t[0]) // 1000) * 1000 if start == 123_456 else int(ev.t[0]))
        np.testing.assert_array_equal(f["ms_to_idx"][()], oracle_ms_index(ev.t - off))
        assert len(f["ms_to_idx"]) <= (int(ev.t[-1]) - int(ev.t[0])) // 1000 + 3
    with EventStore(path) as s:
        assert (s.n_events, s.t_first_us, s.t_last_us, s.t_offset_us) == (len(ev), ev.t[0], ev.t[-1], off)
        assert_same(s.read(0, len(ev)), ev)
    assert not list(tmp_path.glob(".*tmp*"))


@pytest.mark.parametrize("t_offset", [None, 1_600_000_000_000_000])
def test_roundtrip_uint32_with_t_offset(tmp_path, t_offset):
    ev = make_events(dup_times(start=1_600_000_000_123_456))
    path = write_events_h5(tmp_path / "u.h5", ev, time_dtype="uint32", t_offset_us=t_offset)
    expect_off = int(ev.t[0]) if t_offset is None else t_offset
    with h5py.File(path) as f:
        assert f["events/t"].dtype == np.uint32 and int(f["t_offset"][()]) == expect_off
        np.testing.assert_array_equal(f["events/t"][()], ev.t - expect_off)
    with EventStore(path) as s:
        assert s.t_offset_us == expect_off and s.ms_index_t0_us == expect_off
        assert_same(s.read(-5, 10**9), ev)


def test_dsec_documented_example_file(tmp_path):
    # the example from DSEC's EventSlicer docstring, with DSEC's uint64 ms_to_idx and a t_offset
    t_rel = np.array([0, 500, 2100, 5000, 5000, 7100, 7200, 7200, 8100, 9000])
    assert list(oracle_ms_index(t_rel)) == [0, 2, 2, 3, 3, 3, 5, 5, 8, 9]
    ev = make_events(t_rel + 10**12)
    path = write_raw(tmp_path / "d.h5", ev, t_dtype="uint32", t_offset=10**12, with_index=True, index_dtype=np.uint64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = EventStore(path)
    assert not Path(f"{path}.msidx.npz").exists()        # the file's own index is used
    assert list(s.ms_to_idx) == [0, 2, 2, 3, 3, 3, 5, 5, 8, 9] and s.ms_to_idx.dtype == np.int64
    assert list(s.window(10**12 + 5000, 10**12 + 7200).t - 10**12) == [5000, 5000, 7100]
    s.close()


# ----------------------------------------------------------------------------------------------- windows
@pytest.mark.parametrize("width", [1, 3, 250, 1000, 1337, 10_000])
def test_consecutive_windows_tile_every_event_exactly_once(dup_file, width):
    path, ev = dup_file
    # narrow windows tile the first 20 ms only (about 60 events, many duplicates), wide ones the whole file
    part_ev = ev if width >= 250 else oracle_window(ev, 0, int(ev.t[0]) + 20_000)
    origin = (int(part_ev.t[0]) // 10_000 - 1) * 10_000      # a multiple of 10 ms before the first event
    with EventStore(path) as s:
        edges = range(origin, int(part_ev.t[-1]) + 3 * width, width)
        parts = [s.window(a, a + width) for a in edges]
    for a, part in zip(edges, parts):
        assert np.all((part.t >= a) & (part.t < a + width))
    assert_same(EventArray.concatenate(parts), part_ev)
    if 10_000 % width == 0:   # triples of events lie exactly on window starts: they land in that window only
        on_edge = np.isin(part_ev.t, np.asarray(edges))
        assert on_edge.sum() >= 6 and len(np.unique(part_ev.t[on_edge])) < on_edge.sum()


def test_window_matches_oracle_and_index_range(dup_file):
    path, ev = dup_file
    rng = np.random.default_rng(5)
    with EventStore(path) as s:
        for _ in range(300):
            t0 = int(rng.integers(ev.t[0] - 5000, ev.t[-1] + 5000))
            t1 = t0 + int(rng.integers(0, 20_000))
            assert_same(s.window(t0, t1), oracle_window(ev, t0, t1))
            assert s.index_range(t0, t1) == tuple(np.searchsorted(ev.t, [t0, t1]))
        q = rng.integers(ev.t[0] - 5000, ev.t[-1] + 5000, 200)
        np.testing.assert_array_equal(s.indices_of(q), np.searchsorted(ev.t, q))
        assert s.index_of(np.int64(ev.t[7])) == np.searchsorted(ev.t, ev.t[7])


def test_empty_zero_length_reversed_and_outside_windows(dup_file):
    path, ev = dup_file
    t_mid = int(ev.t[len(ev) // 2])
    with EventStore(path) as s:
        assert len(s.window(t_mid, t_mid)) == 0
        assert len(s.window(t_mid + 10, t_mid - 10)) == 0
        assert s.index_range(t_mid + 10, t_mid - 10) == (np.searchsorted(ev.t, t_mid + 10),) * 2
        assert len(s.window(ev.t[0] - 10**6, ev.t[0])) == 0                # ends exactly at the first event
        assert len(s.window(ev.t[-1] + 1, ev.t[-1] + 10**6)) == 0           # starts just after the last event
        assert len(s.window(-(2**62), -(2**62) + 5)) == 0 and len(s.window(2**62, 2**62 + 5)) == 0
        assert len(s.window(ev.t[-1], ev.t[-1] + 1)) == np.sum(ev.t == ev.t[-1])
        assert_same(s.window(-(2**62), 2**62), ev)
        assert s.read(5, 2).t.size == 0 and len(s.read(-10, 3)) == 3 and len(s.read(len(ev) - 2, 10**12)) == 2
        with pytest.raises(TypeError):
            s.window(1.5, 2.5)


def test_single_event_file(tmp_path):
    path = write_events_h5(tmp_path / "one.h5", make_events([42_000_017]))
    with EventStore(path) as s:
        assert (s.n_events, s.t_first_us, s.t_last_us) == (1, 42_000_017, 42_000_017)
        assert len(s.window(42_000_017, 42_000_018)) == 1 and len(s.window(42_000_000, 42_000_017)) == 0
        for align in ("start", "end", "center"):
            assert len(s.window_by_count(42_000_017, 5, align)) == (0 if align == "end" else 1)
        starts, counts = s.rate(1000)
        assert list(starts) == [42_000_000] and list(counts) == [1]


def test_zero_event_file(tmp_path):
    path = write_events_h5(tmp_path / "zero.h5", EventArray.empty(), time_dtype="uint32")
    raw = write_raw(tmp_path / "zero_raw.h5", EventArray.empty())
    for p in (path, raw):
        with EventStore(p) as s:
            assert (len(s), s.t_first_us, s.t_last_us) == (0, None, None)
            assert len(s.window(0, 10**9)) == 0 and len(s.window_by_count(5, 10)) == 0
            assert s.index_of(123) == 0 and s.index_range(0, 10) == (0, 0)
            starts, counts = s.rate(1000)
            assert starts.size == 0 and counts.size == 0 and counts.dtype == np.int64
            assert list(s.iter_chunks()) == []


def test_window_by_count_alignments_and_file_ends(dup_file):
    path, ev = dup_file
    n = len(ev)
    with EventStore(path) as s:
        t = int(ev.t[n // 2]) + 1
        i = int(np.searchsorted(ev.t, t))
        assert_same(s.window_by_count(t, 100, "end"), ev[i - 100:i])
        assert_same(s.window_by_count(t, 100, "start"), ev[i:i + 100])
        assert_same(s.window_by_count(t, 101, "center"), ev[i - 50:i + 51])
        assert np.all(s.window_by_count(t, 100, "end").t < t) and np.all(s.window_by_count(t, 100, "start").t >= t)
        # clipped at the file start / end
        assert_same(s.window_by_count(int(ev.t[0]), 50, "end"), EventArray.empty())
        assert_same(s.window_by_count(int(ev.t[2]) + 1, 50, "end"), ev[:np.searchsorted(ev.t, ev.t[2] + 1)])
        assert_same(s.window_by_count(int(ev.t[0]) - 10, 50, "center"), ev[:25])
        assert_same(s.window_by_count(int(ev.t[-1]) + 1, 50, "start"), EventArray.empty())
        assert_same(s.window_by_count(int(ev.t[-1]) + 1, 50, "end"), ev[n - 50:])
        assert_same(s.window_by_count(int(ev.t[-1]) + 1, 50, "center"), ev[n - 25:])
        assert len(s.window_by_count(t, 0)) == 0
        with pytest.raises(ValueError):
            s.window_by_count(t, 10, "middle")
        with pytest.raises(ValueError):
            s.window_by_count(t, -1)


def test_iter_chunks_bounded_and_complete(dup_file):
    path, ev = dup_file
    with EventStore(path) as s:
        chunks = list(s.iter_chunks(chunk_events=700))
        assert max(len(c) for c in chunks) == 700
        assert_same(EventArray.concatenate(chunks), ev)
        t0, t1 = int(ev.t[100]), int(ev.t[2500])
        assert_same(EventArray.concatenate(s.iter_chunks(333, t0, t1)), oracle_window(ev, t0, t1))


# ----------------------------------------------------------------------------------------------- rate
def test_rate_equals_histogram(dup_file):
    path, ev = dup_file
    with EventStore(path) as s:
        for bin_us in (1000, 10_000):
            starts, counts = s.rate(bin_us)
            assert starts.dtype == np.int64 and counts.dtype == np.int64
            assert np.all(np.diff(starts) == bin_us) and np.all((starts - s.t_offset_us) % bin_us == 0)
            assert starts[0] <= ev.t[0] < starts[0] + bin_us and starts[-1] <= ev.t[-1] < starts[-1] + bin_us
            hist, _ = np.histogram(ev.t, bins=np.append(starts, starts[-1] + bin_us))
            np.testing.assert_array_equal(counts, hist)
        for bad in (1500, 0, -1000, 1000.0):
            with pytest.raises(ValueError):
                s.rate(bad)


def test_ten_million_events_in_one_millisecond(tmp_path):
    n = 10**7
    rng = np.random.default_rng(0)
    t = np.concatenate([[3_999_999], np.sort(rng.integers(4_000_000, 4_001_000, n)), [4_001_000, 4_001_001]])
    zeros16 = np.zeros(len(t), np.uint16)
    full = EventArray(zeros16, zeros16, t, np.zeros(len(t), np.uint8))
    path = write_events_h5(tmp_path / "dense.h5", full, time_dtype="uint32", t_offset_us=0)
    nofile = tmp_path / "dense_noindex.h5"
    nofile.write_bytes(path.read_bytes())
    with h5py.File(nofile, "a") as f:
        del f["ms_to_idx"]
    for p in (path, nofile):
        with EventStore(p) as s:
            starts, counts = s.rate(1000)
            assert counts[starts == 4_000_000][0] == n and counts.sum() == n + 3
            assert s.index_range(4_000_000, 4_001_000) == (1, n + 1)
            assert len(s.window(4_000_000, 4_001_000)) == n
            q = 4_000_500
            assert s.index_of(q) == np.searchsorted(t, q)         # bisected inside the dense millisecond
            assert_same(s.window(4_000_250, 4_000_260), oracle_window(full, 4_000_250, 4_000_260))
            assert len(s.window_by_count(4_001_000, 5, "end")) == 5


# ----------------------------------------------------------------------------------------------- ms index cache
def counting_scan(monkeypatch):
    calls = []
    real = ev_val.scan_index

    def scan(*a, **k):
        calls.append(a[0])
        return real(*a, **k)
    monkeypatch.setattr(ev_val, "scan_index", scan)
    return calls


def test_index_built_cached_in_the_cache_dir_and_reused(tmp_path, monkeypatch):
    ev = make_events(dup_times(start=2_500_300))
    path = write_raw(tmp_path / "noidx.h5", ev)
    calls = counting_scan(monkeypatch)
    base = int(ev.t[0]) // 1000 * 1000
    with EventStore(path) as s:
        assert s.ms_index_t0_us == base                  # the ms holding the first event
        np.testing.assert_array_equal(s.ms_to_idx, oracle_ms_index(ev.t - base))
    assert cache_file(path).exists() and len(calls) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["noidx.h5"]        # nothing beside the file
    with EventStore(path) as s:
        np.testing.assert_array_equal(s.ms_to_idx, oracle_ms_index(ev.t - base))
        assert_same(s.window(0, 2**60), ev)
    assert len(calls) == 1                                  # second open: no rescan


def test_stale_or_corrupt_cache_is_rebuilt(tmp_path, monkeypatch):
    path = write_raw(tmp_path / "noidx.h5", make_events(dup_times(seed=1)))
    calls = counting_scan(monkeypatch)
    EventStore(path).close()
    ev2 = make_events(dup_times(seed=2, start=7_000_000), seed=3)      # same count, different times
    write_raw(path, ev2)
    with EventStore(path) as s:
        assert_same(s.window(0, 2**60), ev2)
        np.testing.assert_array_equal(s.ms_to_idx, oracle_ms_index(ev2.t - int(ev2.t[0]) // 1000 * 1000))
    assert len(calls) == 2
    cache_file(path).write_bytes(b"not a zip file")
    with EventStore(path) as s:
        assert_same(s.window(0, 2**60), ev2)
    assert len(calls) == 3


def test_unwritable_directory_falls_back_to_cache_dir(tmp_path, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    ev = make_events(dup_times())
    path = write_raw(ro / "ev.h5", ev)
    os.chmod(ro, 0o555)
    if os.geteuid() == 0:   # root ignores permission bits: emulate the kernel's refusal for that directory
        real = ev_val.write_npz_atomic

        def refuse(target, **arrays):
            if Path(target).parent == ro:
                raise PermissionError(13, "Permission denied", str(target))
            return real(target, **arrays)
        monkeypatch.setattr(ev_val, "write_npz_atomic", refuse)
    calls = counting_scan(monkeypatch)
    try:
        before = file_state(path)
        with EventStore(path, cache_dir=tmp_path / "cache") as s:
            assert_same(s.window(0, 2**60), ev)
        with EventStore(path, cache_dir=tmp_path / "cache") as s:
            assert_same(s.window(0, 2**60), ev)
        assert file_state(path) == before
    finally:
        os.chmod(ro, 0o755)
    key = hashlib.sha1(str(path.resolve()).encode()).hexdigest()
    assert (tmp_path / "cache" / f"{key}.npz").exists() and not list(ro.glob("*.npz"))
    assert len(calls) == 1


def test_input_file_untouched_and_opened_read_only(tmp_path):
    ev = make_events(dup_times())
    path = write_raw(tmp_path / "ev.h5", ev, t_dtype="uint32", t_offset=10**9)
    os.chmod(path, 0o444)
    before = file_state(path)
    with EventStore(path) as s, EventStore(path) as s2, h5py.File(path, "r") as other:
        assert s._h5.mode == "r" and other["events/t"].shape == (len(ev),)
        for a in range(int(ev.t[0]), int(ev.t[-1]), 5000):
            assert_same(s.window(a, a + 5000), s2.window(a, a + 5000))
        s.rate(10_000)
        list(s.iter_chunks(1000))
        s.window_by_count(int(ev.t[100]), 10)
    assert file_state(path) == before
    assert cache_file(path).exists() and not Path(f"{path}.msidx.npz").exists()


def test_file_index_inconsistent_is_ignored_and_short_one_completed(tmp_path):
    ev = make_events(dup_times())
    path = write_raw(tmp_path / "bad.h5", ev, with_index=True)
    with h5py.File(path, "a") as f:
        idx = f["ms_to_idx"][()]
        del f["ms_to_idx"]
        f["ms_to_idx"] = np.zeros_like(idx)
    with pytest.warns(UserWarning, match="ms_to_idx"):
        s = EventStore(path)
    assert_same(s.window(int(ev.t[10]), int(ev.t[2000])), oracle_window(ev, ev.t[10], ev.t[2000]))
    np.testing.assert_array_equal(s.ms_to_idx, oracle_ms_index(ev.t - s.ms_index_t0_us))
    s.close()
    short = write_raw(tmp_path / "short.h5", ev, with_index=True)
    with h5py.File(short, "a") as f:
        idx = f["ms_to_idx"][()]
        del f["ms_to_idx"]
        f["ms_to_idx"] = idx[: len(idx) // 3]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with EventStore(short) as s:
            np.testing.assert_array_equal(s.ms_to_idx, idx)
            hist, _ = np.histogram(ev.t, bins=np.append(s.rate()[0], s.rate()[0][-1] + 1000))
            np.testing.assert_array_equal(s.rate()[1], hist)


# ----------------------------------------------------------------------------------------------- uint32 wrap
@pytest.mark.parametrize("scan_chunk", [2**21, 5, 1])
def test_uint32_wrap_is_unwrapped(tmp_path, monkeypatch, scan_chunk):
    monkeypatch.setattr(ei, "SCAN_CHUNK_EVENTS", scan_chunk)
    off = 10**12
    t_rel = np.concatenate([2**32 - 2500 + np.arange(0, 2500, 97), 2**32 + np.arange(0, 3000, 101)])
    ev = make_events(off + t_rel)
    with h5py.File(tmp_path / "wrap.h5", "w") as f:   # written directly: our writer refuses to wrap
        for k, v in {"x": ev.x, "y": ev.y, "t": (t_rel % 2**32).astype(np.uint32), "p": ev.p}.items():
            f.create_dataset(f"events/{k}", data=v, chunks=(1,))
        f["t_offset"] = np.int64(off)
    for _ in range(2):  # built, then from the cache
        with pytest.warns(UserWarning, match="wrap"):
            s = EventStore(tmp_path / "wrap.h5")
        w = int(np.argmax(t_rel >= 2**32))
        assert list(s.wraps) == [w]
        assert (s.t_first_us, s.t_last_us) == (off + t_rel[0], off + t_rel[-1])
        assert_same(s.read(0, len(ev)), ev)
        assert_same(s.read(w + 3, len(ev)), ev[w + 3:])          # a read that starts after the wrap
        for a, b in [(off + 2**32 - 300, off + 2**32 + 300), (off, off + 2**33), (off + 2**32, off + 2**32 + 1),
                     (off + 2**32 + 1000, off + 2**32 + 2000)]:
            assert_same(s.window(a, b), oracle_window(ev, a, b))
        starts, counts = s.rate(1000)
        np.testing.assert_array_equal(counts, np.histogram(ev.t, np.append(starts, starts[-1] + 1000))[0])
        s.close()


# ----------------------------------------------------------------------------------------------- malformed files
@pytest.mark.parametrize("scan_chunk", [2**21, 4])
@pytest.mark.parametrize("t_dtype", ["int64", "uint32"])
def test_unsorted_times_raise_naming_file_and_field(tmp_path, monkeypatch, scan_chunk, t_dtype):
    monkeypatch.setattr(ei, "SCAN_CHUNK_EVENTS", scan_chunk)
    t = np.arange(1000, 1100, dtype=np.int64) * 10
    t[40] = t[39] - 5       # drop by 5 µs: neither sorted nor a uint32 wrap
    path = write_raw(tmp_path / "unsorted.h5", make_events(t), t_dtype=t_dtype, chunks=(4,))
    with pytest.raises(EventFileError, match=r"events/t: not sorted at index 40 ") as e:
        EventStore(path)
    assert str(path) in str(e.value) and e.value.field == "events/t"
    assert not cache_file(path).exists()


@pytest.mark.parametrize("case, field", [
    ("missing_p", "events/p"), ("missing_t", "events/t"), ("short_x", "events/x"), ("long_y", "events/y"),
    ("float_t", "events/t"), ("2d_x", "events/x"), ("group_p", "events/p"), ("float_offset", "t_offset"),
])
def test_malformed_files_name_the_field(tmp_path, case, field):
    ev = make_events(np.arange(100) * 10)
    path = tmp_path / f"{case}.h5"
    kw = {"missing_p": dict(skip=("events/p",)), "missing_t": dict(skip=("events/t",)),
          "short_x": dict(override={"x": ev.x[:-1]}), "long_y": dict(override={"y": np.append(ev.y, 0)}),
          "float_t": dict(override={"t": ev.t.astype(float)}), "2d_x": dict(override={"x": ev.x.reshape(10, 10)}),
          "group_p": dict(skip=("events/p",)), "float_offset": {}}[case]
    write_raw(path, ev, **kw)
    if case in ("group_p", "float_offset"):
        with h5py.File(path, "a") as f:
            if case == "group_p":
                f.create_group("events/p")
            else:
                f["t_offset"] = 1.5
    with pytest.raises(EventFileError) as e:
        EventStore(path)
    assert str(e.value).startswith(f"{path}: {field}: ") and isinstance(e.value, ValueError)


def test_signed_polarity_and_wide_pixel_types_are_read_as_the_api_types(tmp_path):
    ev = make_events(np.arange(50) * 100)
    path = write_raw(tmp_path / "s.h5", ev, override={"p": np.where(ev.p > 0, 1, -1).astype(np.int8),
                                                    "x": ev.x.astype(np.int32), "y": ev.y.astype(np.uint64)})
    with EventStore(path) as s:
        assert_same(s.read(0, 50), ev)


def test_not_hdf5_and_missing_file(tmp_path):
    (tmp_path / "junk.h5").write_bytes(b"hello")
    with pytest.raises(EventFileError, match="junk.h5"):
        EventStore(tmp_path / "junk.h5")
    with pytest.raises(FileNotFoundError):
        EventStore(tmp_path / "absent.h5")


# ----------------------------------------------------------------------------------------------- writer
def leftovers(d):
    return sorted(p.name for p in Path(d).iterdir())


def test_writer_cancel_and_progress(tmp_path, monkeypatch):
    monkeypatch.setattr(ew, "_FLUSH_EVENTS", 100)
    seen, stop = [], [False]
    ev = make_events(np.arange(1000) * 3)
    w = EventWriter(tmp_path / "c.h5", chunk_events=50, progress=lambda n, tot: seen.append((n, tot)),
                    cancel=lambda: stop[0], expected_events=1000)
    w.append(ev[:250])
    assert seen == [(100, 1000), (200, 1000)]
    stop[0] = True
    with pytest.raises(Cancelled):
        w.append(ev[250:])
    assert leftovers(tmp_path) == []
    # inside a with-block, cancelled from the progress callback: raised by the flush after it
    stop[0] = False
    with pytest.raises(Cancelled):
        with EventWriter(tmp_path / "c.h5", chunk_events=50, cancel=lambda: stop[0],
                         progress=lambda n, tot: stop.__setitem__(0, True)) as w:
            w.append(ev[:150])
    assert stop[0]
    assert leftovers(tmp_path) == []


def test_writer_exception_in_block_leaves_nothing_and_keeps_old_file(tmp_path):
    old = write_events_h5(tmp_path / "x.h5", make_events([1, 2, 3]))
    before = file_state(old)
    with pytest.raises(RuntimeError, match="boom"):
        with EventWriter(tmp_path / "x.h5") as w:
            w.append(make_events(np.arange(10)))
            tmp, final = leftovers(tmp_path)
            assert tmp.startswith(".x.h5.") and tmp.endswith(".tmp") and final == "x.h5"  # hidden, unique
            raise RuntimeError("boom")
    assert leftovers(tmp_path) == ["x.h5"] and file_state(old) == before
    with pytest.raises(ValueError):
        write_events_h5(tmp_path / "y.h5", (make_events([i]) for i in (5, 6, 4)))
    assert leftovers(tmp_path) == ["x.h5"]


def test_writer_refuses_uint32_span_overflow(tmp_path):
    t0 = 10**12
    ok = write_events_h5(tmp_path / "ok.h5", make_events([t0, t0 + 2**32 - 1]), time_dtype="uint32")
    with EventStore(ok) as s:
        assert s.t_last_us == t0 + 2**32 - 1 and len(s.wraps) == 0
    with pytest.raises(ValueError, match="int64"):
        with EventWriter(tmp_path / "bad.h5", time_dtype="uint32") as w:
            w.append(make_events([t0, t0 + 5]))
            w.append(make_events([t0 + 2**32]))
    with pytest.raises(ValueError, match="before t_offset"):
        write_events_h5(tmp_path / "bad.h5", make_events([t0 - 1]), time_dtype="uint32", t_offset_us=t0)
    assert leftovers(tmp_path) == ["ok.h5"]


def test_writer_rejects_decreasing_time(tmp_path):
    w = EventWriter(tmp_path / "d.h5")
    w.append(make_events([10, 20, 20]))
    with pytest.raises(EventFileError, match=r"events/t: not sorted at appended event 3 \(t=19 < previous 20\)"):
        w.append(make_events([19, 30]))
    with pytest.raises(EventFileError, match=r"events/t: not sorted at appended event 5 \(t=25 < previous 30\)"):
        w.append(make_events([20, 30, 25]))
    w.append(x=[1], y=[2], t=[20], p=[1])       # a rejected append changed nothing; equal times are fine
    with EventStore(w.close()) as s:
        assert list(s.read(0, 10).t) == [10, 20, 20, 20] and list(s.read(3, 4).x) == [1]


def test_writer_copies_reused_buffers(tmp_path):
    buf = make_events(np.arange(10))
    w = EventWriter(tmp_path / "b.h5")
    w.append(buf)
    expect = EventArray(buf.x.copy(), buf.y.copy(), buf.t.copy(), buf.p.copy())
    buf.x[:] = 0
    with EventStore(w.close()) as s:
        assert_same(s.read(0, 10), expect)


# ----------------------------------------------------------------------------------------------- property test
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(),
       steps=st.lists(st.sampled_from([0, 0, 0, 1, 3, 499, 500, 999, 1000, 1001, 2500, 7000]),
                      min_size=1, max_size=300),
       start=st.integers(-20_000, 5_000_000),
       layout=st.sampled_from(["writer-int64", "writer-uint32", "raw-int64-noindex", "raw-uint32-index"]))
def test_property_window_equals_searchsorted_oracle(data, steps, start, layout):
    ev = make_events(start + np.cumsum(steps))
    with tempfile.TemporaryDirectory() as d, mock.patch.object(ei, "SCAN_CHUNK_EVENTS", 7), \
            mock.patch.object(es, "_BISECT_MAX", 4):
        path = Path(d) / "e.h5"
        if layout.startswith("writer"):
            write_events_h5(path, ev, time_dtype=layout[7:], chunk_events=16)
        elif layout == "raw-int64-noindex":
            write_raw(path, ev)
        else:
            write_raw(path, ev, t_dtype="uint32", t_offset=int(ev.t[0]) - data.draw(st.integers(0, 3000)),
                      with_index=True)
        lo, hi = int(ev.t[0]) - 3000, int(ev.t[-1]) + 3000
        with EventStore(path) as s:
            for _ in range(10):
                t0 = data.draw(st.integers(lo, hi))
                t1 = data.draw(st.one_of(st.integers(lo, hi), st.sampled_from([int(v) for v in ev.t])))
                assert_same(s.window(t0, t1), oracle_window(ev, t0, t1))
                assert s.index_of(t0) == np.searchsorted(ev.t, t0)
            starts, counts = s.rate(1000)
            np.testing.assert_array_equal(counts, np.histogram(ev.t, np.append(starts, starts[-1] + 1000))[0])
