"""The cache of decoded event blocks in front of EventStore.window (issue 14, point 3): exact windows, a bound
in bytes, hits for neighbouring windows, prefetch in the direction of motion."""
import numpy as np
import pytest

from evpose.core.data.event_cache import EventChunkCache, event_nbytes
from evpose.core.data.event_store import EventStore
from evpose.core.data.event_writer import write_events_h5
from evpose.core.data.events import EventArray

pytestmark = pytest.mark.usefixtures("private_cache")

BLOCK_US = 10_000


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """1 s of events at ~100 k ev/s with uneven density (bursts), times from 1_000_123 µs."""
    rng = np.random.default_rng(5)
    n = 100_000
    t = np.sort(1_000_123 + np.concatenate([rng.integers(0, 1_000_000, n // 2),
                                            rng.normal(400_000, 30_000, n // 2).astype(np.int64).clip(0, 999_999)]))
    ev = EventArray(rng.integers(0, 346, n), rng.integers(0, 260, n), t, rng.integers(0, 2, n))
    path = tmp_path_factory.mktemp("cache") / "events.h5"
    write_events_h5(path, ev)
    with EventStore(path) as s:
        yield s


def same(a: EventArray, b: EventArray) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in "xytp")


def test_windows_equal_the_store_s_at_any_alignment(store):
    cache = EventChunkCache(max_bytes=4 * 2**20, block_us=BLOCK_US)
    rng = np.random.default_rng(1)
    t_first, t_last = store.t_first_us, store.t_last_us
    starts = list(rng.integers(t_first - 20_000, t_last + 20_000, 60)) + [t_first, t_last, t_last + 1]
    for t0 in starts:
        for length in (1, 999, 10_000, 10_001, 35_000):
            t0 = int(t0)
            assert same(cache.window(store, t0, t0 + length), store.window(t0, t0 + length)), (t0, length)
    assert len(cache.window(store, 5, 5)) == 0 and len(cache.window(store, 9, 3)) == 0


def test_neighbouring_windows_hit_and_the_bytes_stay_bounded(store):
    block_bytes = event_nbytes(store.window(store.t_first_us, store.t_first_us + BLOCK_US))
    budget = 6 * block_bytes                           # a handful of blocks
    cache = EventChunkCache(max_bytes=budget, block_us=BLOCK_US)
    t = store.t_first_us + 200_000
    cache.window(store, t, t + 10_000)                 # touches two blocks (unaligned)
    misses = cache.stats.misses
    assert misses == 2 and cache.stats.hits == 0
    cache.window(store, t + 1, t + 9_999)              # same blocks again: no read
    assert cache.stats.misses == misses and cache.stats.hits == 2
    sizes = []
    for k in range(60):                                 # scrub across the dense burst and beyond
        cache.window(store, t + 10_000 * k, t + 10_000 * (k + 1))
        sizes.append(cache.nbytes)
        assert cache.nbytes <= budget
        assert cache.nbytes == sum(event_nbytes(cache._blocks[j]) for j in cache.cached_blocks())
    assert cache.stats.evicted > 0 and max(sizes) > budget // 2
    # the bound holds for the least recently used order: the newest blocks are kept
    last = cache.block_of(store, t + 600_000 - 1)
    assert cache.cached_blocks()[-1] == last


def test_a_window_wider_than_half_the_budget_bypasses_the_cache(store):
    cache = EventChunkCache(max_bytes=200_000, block_us=BLOCK_US)
    t = store.t_first_us
    assert same(cache.window(store, t, t + 500_000), store.window(t, t + 500_000))
    assert cache.stats.direct_reads == 1 and len(cache) == 0 and cache.nbytes == 0


def test_prefetch_reads_ahead_in_the_direction_of_motion(store):
    cache = EventChunkCache(max_bytes=8 * 2**20, block_us=BLOCK_US)
    t = store.t_first_us + 500_000
    k = cache.block_of(store, t)
    assert cache.prefetch(store, t, +1, 3 * BLOCK_US) == 4
    assert set(cache.cached_blocks()) == {k, k + 1, k + 2, k + 3}
    assert cache.stats.prefetched == 4 and cache.stats.misses == 0
    cache.window(store, t + 10_000, t + 20_000)        # the next window forward: served from the prefetch
    assert cache.stats.misses == 0 and cache.stats.prefetch_used >= 1
    assert cache.prefetch(store, t, -1, 2 * BLOCK_US) == 2     # backwards: k-1, k-2 (k is held)
    assert {k - 1, k - 2} <= set(cache.cached_blocks())
    stops = iter([False, True])
    assert cache.prefetch(store, t + 200_000, +1, 10 * BLOCK_US, should_stop=lambda: next(stops)) == 1


def test_prefetch_keeps_within_half_the_budget_and_the_file(store):
    block_bytes = event_nbytes(store.window(store.t_first_us, store.t_first_us + BLOCK_US))
    cache = EventChunkCache(max_bytes=10 * block_bytes, block_us=BLOCK_US)
    assert cache.prefetch(store, store.t_first_us + 100_000, +1, 50 * BLOCK_US) <= 6
    cache.clear()
    k_last = cache.block_of(store, store.t_last_us)
    n = cache.prefetch(store, cache.block_span(store, k_last)[0], +1, 5 * BLOCK_US)    # nothing beyond the file
    assert n == 1 and cache.cached_blocks() == [k_last]


def test_another_store_drops_the_old_blocks(store, tmp_path):
    other_path = tmp_path / "other.h5"
    write_events_h5(other_path, EventArray(np.array([1]), np.array([2]), np.array([1_000_200]), np.array([1])))
    cache = EventChunkCache(block_us=BLOCK_US)
    cache.window(store, store.t_first_us, store.t_first_us + 30_000)
    assert cache.nbytes > 0
    with EventStore(other_path) as other:
        ev = cache.window(other, 1_000_000, 1_010_000)
        assert len(ev) == 1 and ev.y[0] == 2
        assert cache.nbytes == event_nbytes(ev) and len(cache) == 1


def test_shrink_keeps_the_most_recently_used_blocks_and_the_counters(store):
    """The app's idle release (issue 25.4): all but the newest blocks go, the accounting stays exact, the windows
    read afterwards are the store's."""
    cache = EventChunkCache(max_bytes=8 * 2**20, block_us=BLOCK_US)
    t = store.t_first_us + 100_000
    for k in range(8):
        cache.window(store, t + 10_000 * k, t + 10_000 * (k + 1))
    newest = cache.cached_blocks()[-1]
    keep = event_nbytes(cache._blocks[newest])
    misses, n = cache.stats.misses, cache.nbytes
    assert cache.shrink(keep) == n - keep
    assert cache.cached_blocks() == [newest] and cache.nbytes == keep and cache.stats.misses == misses
    assert cache.shrink(0) == keep and len(cache) == 0 and cache.nbytes == 0
    assert same(cache.window(store, t, t + 10_000), store.window(t, t + 10_000))
