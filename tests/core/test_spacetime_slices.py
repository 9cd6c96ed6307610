"""Space-time silhouette slices: the slice cache and the idle prefetch give exactly what a fresh computation
gives, stay within their byte bound, and a slice's contours are those of the frame's visible masks."""
from __future__ import annotations

import numpy as np
import pytest

from evpose.core.label.overlay import mask_contours
from evpose.core.label.windows import Window
from evpose.core.views.frame import FrameComputer
from evpose.core.views.spacetime import SpaceTimeComputer
from evpose.core.views.spacetime_slices import SliceCache, compute_slice, slice_key, slice_nbytes, slice_times


@pytest.fixture
def session(scene_copy):
    from evpose.core.session.model import Session

    s = Session.open(scene_copy)
    s.set_time(s.time_range[0] + 300_000)      # mid-motion: events and objects in view
    s.set_view_option(spacetime_span_us=60_000)
    yield s
    s.close()


def assert_same(a, b):
    assert a.t_center_us == b.t_center_us and a.n_total == b.n_total and a.span_us == b.span_us
    assert np.array_equal(a.points, b.points) and np.array_equal(a.polarity, b.polarity)
    assert [(n, c, len(p)) for n, c, p in a.tubes] == [(n, c, len(p)) for n, c, p in b.tubes]
    for (_, _, pa), (_, _, pb) in zip(a.tubes, b.tubes):
        assert all(np.array_equal(u, v) for u, v in zip(pa, pb))


def test_steps_with_cache_and_prefetch_equal_fresh_computations(session):
    fc = SpaceTimeComputer()
    first = fc.spacetime(session.request())
    assert first.tubes and len(first.points)
    assert fc.slice_cache.misses > 0 and fc.slice_cache.hits == 0
    for step in (1, 1, 2, -1):
        fc.prefetch_spacetime()                              # the worker's idle time
        misses = fc.slice_cache.misses
        session.step_windows(step)
        req = session.request()
        ours = fc.spacetime(req)
        if step == 1:       # stepped in the direction of motion: every slice was ready
            assert fc.slice_cache.misses == misses, "the prefetch did not compute the next step's slices"
        assert_same(ours, SpaceTimeComputer().spacetime(req))


def test_a_pose_change_misses_and_matches_a_fresh_computation(session):
    fc = SpaceTimeComputer()
    fc.spacetime(session.request())
    hits = fc.slice_cache.hits
    session.set_offset_correction_us(session.scene.corrections.offset_us + 3_000)   # every pose moves
    req = session.request()
    ours = fc.spacetime(req)
    assert fc.slice_cache.hits == hits, "slices of the old poses were reused"
    assert_same(ours, SpaceTimeComputer().spacetime(req))


def test_prefetch_stops_when_asked_and_follows_the_motion(session):
    fc = SpaceTimeComputer()
    assert fc.prefetch_spacetime() == 0                      # nothing requested yet
    fc.spacetime(session.request())
    assert fc.prefetch_spacetime(should_stop=lambda: True) == 0
    session.step_windows(1)
    fc.spacetime(session.request())
    n = fc.prefetch_spacetime()
    assert n > 0
    v = session.view
    span = v.spacetime_span_us
    later = slice_times(v.t_us + v.window_us - span // 2, span, v.spacetime_slices, v.grid_origin_us)
    T_co, _, _ = fc._slice_annotator.poses(later)
    assert all(slice_key(t, T) in fc.slice_cache for t, T in zip(later, T_co))
    assert fc.prefetch_spacetime() == 0                      # all there already


def test_slice_contours_are_the_frame_views_visible_mask_contours(session):
    fc = SpaceTimeComputer()
    req = session.request()
    fc.spacetime(req)
    ann = FrameComputer()._annotator_for(req.scene)          # the frame's annotator (visible masks)
    t = int(session.view.t_us)
    T_co, T_bc, valid = ann.poses([t])
    assert valid[0]
    labels = ann.annotate(Window(-1, t, t + 1, t), pose=(T_co[0], T_bc[0], True))
    got = compute_slice(fc._slice_annotator, t, T_co[0], T_bc[0])
    assert any(c for _, _, c, _ in got)
    for (name, in_view, contours, field), o in zip(got, labels.objects):
        assert name == o.name and in_view == o.in_view
        want = mask_contours(o.mask_visible) if o.in_view else []
        assert len(contours) == len(want) and all(np.array_equal(a, b) for a, b in zip(contours, want))
        assert (field is not None) == bool(want)


def fake_slice(n_points: int, seed: int):
    rng = np.random.default_rng(seed)
    return [("a", True, [rng.integers(0, 100, (n_points, 2)).astype(np.int32)], None), ("b", False, [], None)]


def test_slice_cache_is_bounded_in_bytes_and_keeps_the_recently_used():
    one = slice_nbytes(slice_key(0, np.eye(4)[None]), fake_slice(100, 0))
    cache = SliceCache(max_slices=1000, max_bytes=3 * one + 10)
    keys = [slice_key(t, np.eye(4)[None]) for t in range(6)]
    for k, key in enumerate(keys[:3]):
        cache.put(key, fake_slice(100, k))
    assert len(cache) == 3 and cache.nbytes == 3 * one
    assert cache.get(keys[0]) is not None                    # recently used: kept over keys[1]
    cache.put(keys[3], fake_slice(100, 3))
    assert keys[1] not in cache and keys[0] in cache and keys[3] in cache
    assert cache.nbytes <= cache.max_bytes
    assert cache.nbytes == sum(slice_nbytes(k, cache.get(k)) for k in keys if k in cache)
    cache.put(keys[4], fake_slice(10_000, 4))                # larger than the bound alone: not kept
    assert keys[4] not in cache and cache.nbytes <= cache.max_bytes
    small = SliceCache(max_slices=2)
    for key in keys:
        small.put(key, fake_slice(5, 0))
    assert len(small) == 2 and small.nbytes == 2 * slice_nbytes(keys[0], fake_slice(5, 0))
    small.clear()
    assert len(small) == 0 and small.nbytes == 0


def test_the_computers_slice_cache_stays_within_its_byte_bound(session):
    fc = SpaceTimeComputer()
    fc.slice_cache = SliceCache(max_bytes=120_000)
    for _ in range(6):
        fc.spacetime(session.request())
        assert 0 < fc.slice_cache.nbytes <= 120_000
        session.step_windows(2)


def test_caches_derived_from_slices_keep_no_slice_the_slice_cache_dropped(session):
    """The merged band fields and the joined surface rings recognise a slice by identity without keeping it
    alive: the slice cache's byte bound holds for everything a slice carries."""
    import gc

    fc = SpaceTimeComputer()
    fc.slice_cache.max_bytes = 1 << 20
    for k in range(12):
        session.set_offset_correction_us(session.scene.corrections.offset_us + 700 * (k + 1))   # new poses: new slices
        fc.spacetime(session.request())
    gc.collect()
    live = {id(v) for v, _ in fc.slice_cache._items.values()}
    refs = [r for r, _ in fc.field_cache._items.values()]
    refs += [r for pair, _ in fc.surface_cache._items.values() for r in pair]
    assert refs and all(r() is None or id(r()) in live for r in refs)
    session.set_offset_correction_us(session.scene.corrections.offset_us + 700)
    fc.spacetime(session.request())              # inserts drop the entries of dead slices
    assert len(fc.field_cache) <= len(fc.slice_cache)
    assert all(r() is not None for r, _ in fc.field_cache._items.values())


def test_the_band_fields_and_the_surfaces_stay_within_their_byte_bounds(session):
    """Issue 25.4: the merged fields (H x W x 2 int8 each: 180 kB on a DAVIS346, 1.8 MB on a 1280 x 720 sensor) and
    the joined rings are bounded in bytes, not in entries; what they count is what they hold."""
    from evpose.core.views.spacetime_band import MergedFieldCache, derived_nbytes
    from evpose.core.views.spacetime_surface import SurfaceCache

    cam = session.scene.camera
    field_bytes = cam.height * cam.width * 2
    fc = SpaceTimeComputer()
    fc.field_cache = MergedFieldCache(max_bytes=5 * field_bytes)
    fc.surface_cache = SurfaceCache(max_bytes=20_000)
    for _ in range(6):
        data = fc.spacetime(session.request())
        assert data.surfaces
        fields, rings = fc.field_cache, fc.surface_cache
        assert 0 < fields.nbytes <= 5 * field_bytes and len(fields) <= 5
        assert fields.nbytes == sum(v[1].nbytes for v in fields._items.values())
        assert 0 < rings.nbytes <= 20_000
        assert rings.nbytes == sum(derived_nbytes(v[1]) for v in rings._items.values())
        session.step_windows(3)
    nb = fc.release_caches()
    assert nb > 0 and fc.slice_cache.nbytes == fields.nbytes == rings.nbytes == 0 and len(fields) == len(rings) == 0
    fresh = SpaceTimeComputer().spacetime(session.request())
    assert_same(fc.spacetime(session.request()), fresh)          # made again on demand
