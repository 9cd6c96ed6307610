"""A small cache of decoded event blocks in front of :meth:`EventStore.window`, bounded in bytes, with
prefetch in the direction of motion (issue 14: scrubbing that keeps up).

The recording is cut into blocks of ``block_us`` microseconds on a fixed grid
(``[origin + k * block_us, origin + (k + 1) * block_us)``, origin = the store's ``ms_index_t0_us``).
:meth:`EventChunkCache.window` assembles any window from the blocks it overlaps: blocks already decoded
are served from memory (a *hit*), the others are read from the store once (a *miss*) and kept. Least
recently used blocks are evicted as soon as the decoded bytes exceed ``max_bytes``: the cache's memory is
:attr:`EventChunkCache.nbytes`, never more than ``max_bytes`` plus one block. A window wider than half
the budget is read from the store directly (a long space-time span must not flush the neighbours of the
current window).

:meth:`EventChunkCache.prefetch` decodes the blocks ahead of a time in the direction of motion; the
app's frame worker calls it when it has no request, checking ``should_stop`` between blocks, so a new
request never waits for more than one block read.

Thread safety: one cache may be shared by several threads (the frame and space-time workers). Blocks
are read outside the lock (h5py serialises the reads anyway); two threads missing the same block both
read it and one copy is kept.
"""
from __future__ import annotations

import operator
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from evpose.core.data.events import EventArray

__all__ = ["EventChunkCache", "CacheStats", "DEFAULT_BLOCK_US", "DEFAULT_MAX_BYTES"]

#: Block length on the time grid, µs: a 10 ms window touches one or two blocks.
DEFAULT_BLOCK_US = 20_000
#: Decoded bytes kept (13 B per event: x, y uint16, t int64, p uint8): ~1.3 s of a 1 M ev/s recording.
DEFAULT_MAX_BYTES = 16 * 2**20


def event_nbytes(ev: EventArray) -> int:
    """Bytes held by the four columns of ``ev``."""
    return int(ev.x.nbytes + ev.y.nbytes + ev.t.nbytes + ev.p.nbytes)


@dataclass
class CacheStats:
    """Counters since the cache was made (or :meth:`EventChunkCache.clear`), in blocks."""

    hits: int = 0            # blocks served from memory to window()
    misses: int = 0          # blocks window() had to read from the store
    prefetched: int = 0      # blocks read by prefetch()
    prefetch_used: int = 0   # prefetched blocks later served to window()
    evicted: int = 0
    direct_reads: int = 0    # windows too wide for the cache, read from the store directly


class EventChunkCache:
    """Decoded event blocks of one :class:`~evpose.core.data.event_store.EventStore` at a time, LRU,
    bounded in bytes.

    Parameters
    ----------
    max_bytes : int
        Upper bound of the decoded bytes kept (the bound is checked after each insertion, so the cache
        holds at most ``max_bytes``; a single block larger than the bound is returned but not kept).
    block_us : int
        Block length, µs (> 0).

    Notes
    -----
    The cache follows the store it is asked about: a call with another store (a new scene) drops every
    block of the previous one.
    """

    def __init__(self, max_bytes: int = DEFAULT_MAX_BYTES, block_us: int = DEFAULT_BLOCK_US):
        if int(block_us) <= 0:
            raise ValueError(f"EventChunkCache: block_us must be positive, got {block_us}")
        if int(max_bytes) < 0:
            raise ValueError(f"EventChunkCache: max_bytes must be >= 0, got {max_bytes}")
        self.max_bytes = int(max_bytes)
        self.block_us = int(block_us)
        self._lock = threading.Lock()
        self._blocks: OrderedDict[int, EventArray] = OrderedDict()
        self._unused_prefetch: set[int] = set()
        self._nbytes = 0
        self._store = None
        self.stats = CacheStats()

    # ------------------------------------------------------------------ accounting
    @property
    def nbytes(self) -> int:
        """Decoded bytes held now (the figure the app's memory budget accounts for)."""
        return self._nbytes

    def __len__(self) -> int:
        return len(self._blocks)

    def cached_blocks(self) -> list[int]:
        """Block numbers held, least recently used first."""
        with self._lock:
            return list(self._blocks)

    def clear(self) -> None:
        """Drop every block and forget the store (counters reset)."""
        with self._lock:
            self._blocks.clear()
            self._unused_prefetch.clear()
            self._nbytes = 0
            self._store = None
            self.stats = CacheStats()

    def shrink(self, max_bytes: int = 0) -> int:
        """Drop the least recently used blocks until at most ``max_bytes`` are held (the app's idle release: the
        blocks are read again when needed); the counters go on. Returns the bytes dropped."""
        dropped = 0
        with self._lock:
            while self._blocks and self._nbytes > max_bytes:
                k, ev = self._blocks.popitem(last=False)
                self._unused_prefetch.discard(k)
                nb = event_nbytes(ev)
                self._nbytes -= nb
                dropped += nb
        return dropped

    # ------------------------------------------------------------------ blocks
    def _follow(self, store) -> None:
        """Called with the lock held: a new store drops the old one's blocks."""
        if self._store is not store:
            self._blocks.clear()
            self._unused_prefetch.clear()
            self._nbytes = 0
            self._store = store

    def block_of(self, store, t_us: int) -> int:
        """The block holding time ``t_us`` (µs, absolute) of ``store``."""
        return (operator.index(t_us) - int(store.ms_index_t0_us)) // self.block_us

    def block_span(self, store, k: int) -> tuple[int, int]:
        """``[t0, t1)`` of block ``k`` of ``store``, µs."""
        t0 = int(store.ms_index_t0_us) + k * self.block_us
        return t0, t0 + self.block_us

    def _get(self, store, k: int, prefetch: bool = False) -> EventArray:
        with self._lock:
            self._follow(store)
            ev = self._blocks.get(k)
            if ev is not None:
                self._blocks.move_to_end(k)
                if not prefetch:
                    self.stats.hits += 1
                    if k in self._unused_prefetch:
                        self._unused_prefetch.discard(k)
                        self.stats.prefetch_used += 1
                return ev
        ev = store.window(*self.block_span(store, k))
        with self._lock:
            if self._store is not store:        # the cache moved to another store meanwhile
                return ev
            if prefetch:
                self.stats.prefetched += 1
            else:
                self.stats.misses += 1
            if k in self._blocks:
                return self._blocks[k]
            size = event_nbytes(ev)
            if size <= self.max_bytes:
                self._blocks[k] = ev
                self._nbytes += size
                if prefetch:
                    self._unused_prefetch.add(k)
                self._evict()
        return ev

    def _evict(self) -> None:
        while self._nbytes > self.max_bytes and self._blocks:
            k, ev = self._blocks.popitem(last=False)
            self._nbytes -= event_nbytes(ev)
            self._unused_prefetch.discard(k)
            self.stats.evicted += 1

    def _estimate_nbytes(self, store, t0_us: int, t1_us: int) -> int:
        """Decoded bytes of ``[t0_us, t1_us)`` from the ms index alone (no event read), rounded up to ms."""
        idx = store.ms_to_idx
        if len(idx) == 0:
            return 0
        base = int(store.ms_index_t0_us)
        k0 = min(max((t0_us - base) // 1000, 0), len(idx) - 1)
        k1 = (t1_us - base + 999) // 1000
        i1 = int(idx[k1]) if 0 <= k1 < len(idx) else (store.n_events if k1 >= len(idx) else 0)
        return max(i1 - int(idx[k0]), 0) * 13

    # ------------------------------------------------------------------ reading
    def window(self, store, t0_us, t1_us) -> EventArray:
        """Events of ``store`` with ``t0_us <= t < t1_us`` (µs, absolute): exactly
        ``store.window(t0_us, t1_us)``, assembled from cached blocks."""
        t0_us, t1_us = operator.index(t0_us), operator.index(t1_us)
        if t1_us <= t0_us or store.n_events == 0:
            return EventArray.empty()
        if self._estimate_nbytes(store, t0_us, t1_us) > self.max_bytes // 2:
            with self._lock:
                self.stats.direct_reads += 1
            return store.window(t0_us, t1_us)
        k0, k1 = self.block_of(store, t0_us), self.block_of(store, t1_us - 1)
        parts = []
        for k in range(k0, k1 + 1):
            ev = self._get(store, k)
            b0, b1 = self.block_span(store, k)
            i0 = 0 if t0_us <= b0 else int(np.searchsorted(ev.t, t0_us, side="left"))
            i1 = len(ev) if t1_us >= b1 else int(np.searchsorted(ev.t, t1_us, side="left"))
            if i1 > i0:
                parts.append(ev if (i0 == 0 and i1 == len(ev)) else ev[i0:i1])
        if len(parts) == 1:
            return parts[0]
        return EventArray.concatenate(parts)

    def prefetch(self, store, t_us: int, direction: int, ahead_us: int, should_stop=None) -> int:
        """Decode the blocks from ``t_us`` over ``ahead_us`` in ``direction`` (+1 later, -1 earlier,
        0 both ways), nearest first, at most half the budget; returns the number of blocks read.
        ``should_stop()`` is checked before each block read."""
        if store.n_events == 0 or ahead_us <= 0:
            return 0
        k = self.block_of(store, t_us)
        n = -(-int(ahead_us) // self.block_us)
        if direction > 0:
            order = [k + i for i in range(n + 1)]
        elif direction < 0:
            order = [k - i for i in range(n + 1)]
        else:
            order = [k] + [k + s * i for i in range(1, n + 1) for s in (1, -1)]
        k_first = self.block_of(store, store.t_first_us)
        k_last = self.block_of(store, store.t_last_us)
        read, ahead_bytes, touched = 0, 0, []
        for j in order:
            if not (k_first <= j <= k_last):
                continue
            if should_stop is not None and should_stop():
                break
            with self._lock:
                self._follow(store)
                ev = self._blocks.get(j)
            if ev is None:
                ev = self._get(store, j, prefetch=True)
                read += 1
            touched.append(j)
            ahead_bytes += event_nbytes(ev)
            if ahead_bytes >= self.max_bytes // 2:
                break
        with self._lock:                  # the nearest blocks are the most recently used: evicted last
            for j in reversed(touched):
                if j in self._blocks:
                    self._blocks.move_to_end(j)
        return read
