"""Chunks sized in work (issue 27.2): probes first, then chunks of about TARGET_TASK_CPU_S of measured CPU each,
whatever the number of windows; a slow scene gets small chunks, a fast one big ones; every task handed out once,
in order."""
from __future__ import annotations

import pytest

from evpose.core.export.chunks import MAX_CHUNK_WINDOWS, PROBE_WINDOWS, TARGET_TASK_CPU_S, ChunkPlanner


def drain(cost_s: float, n: int = 5000, in_flight: int = 4, prior=None) -> tuple[list[int], list]:
    """Hand out every chunk of ``n`` windows costing ``cost_s`` CPU s each, ``in_flight`` chunks out at a time
    (as the Dask executor does: the first ones before any cost is known)."""
    tasks = list(range(n))
    p = ChunkPlanner(tasks, prior=prior)
    out, flying = [], []
    while True:
        while len(flying) < in_flight and p.may_submit(len(flying)):
            c = p.next()
            if c is None:
                break
            flying.append(c)
        if not flying:
            break
        c = flying.pop(0)
        out.extend(c)
        p.record(len(c), cost_s * len(c))
    return p.sizes, out


@pytest.mark.parametrize("cost_s", [0.2, 0.05, 0.004])
def test_chunks_hold_the_target_cpu_once_the_cost_is_known(cost_s):
    sizes, handed = drain(cost_s)
    assert handed == list(range(5000))                       # each window once, in order
    assert sizes[:2] == [PROBE_WINDOWS] * 2                  # two probes while nothing is measured, not one
    steady = sizes[2:-1]                                     # per worker (the last one takes what is left)
    expect = min(MAX_CHUNK_WINDOWS, round(TARGET_TASK_CPU_S / cost_s))
    assert steady and all(s == expect for s in steady), (cost_s, steady[:5])
    assert all(2.0 <= s * cost_s <= 10.0 for s in steady) or expect == MAX_CHUNK_WINDOWS


def test_a_slow_scene_gets_smaller_chunks_than_a_fast_one():
    slow, _ = drain(0.25)
    fast, _ = drain(0.01)
    assert max(slow[2:]) == 16 and min(fast[2:-1]) == 400
    assert len(slow) > 10 * len(fast) / 2


def test_the_estimate_follows_the_measured_cost_not_the_count():
    p = ChunkPlanner(list(range(1000)), target_s=2.0, probe=2)
    assert p.next() == [0, 1] and p.cpu_per_window_s is None
    p.record(2, 0.2)                                          # 0.1 s a window -> 20 windows
    assert len(p.next()) == 20
    p.record(20, 0.2)                                         # now 0.4 s over 22 windows: ~0.018 -> 110
    assert len(p.next()) == round(2.0 / (0.4 / 22))
    assert p.remaining == 1000 - 2 - 20 - 110


def test_big_results_cap_the_chunk_in_bytes():
    """HDF5 returns each window's frames (~0.7 MB for a DAVIS346): a cheap window must not make a 512-window,
    360 MB message."""
    import numpy as np

    from evpose.core.export.chunks import MAX_CHUNK_BYTES, result_bytes

    p = ChunkPlanner(list(range(5000)))
    chunk = p.next()
    payload = {"frames/counts": np.zeros((2, 260, 346), np.uint16), "frames/three_channel": np.zeros((260, 346, 3), np.uint8)}
    results = [({"i": i}, payload, "") for i in chunk]
    assert result_bytes(results) == len(chunk) * (2 * 260 * 346 * 2 + 260 * 346 * 3)
    p.record(len(chunk), 0.001 * len(chunk), result_bytes(results))     # 1 ms a window: 4000 by CPU alone
    n = len(p.next())
    assert n == MAX_CHUNK_BYTES // (2 * 260 * 346 * 2 + 260 * 346 * 3) and n < 512
    p2 = ChunkPlanner(list(range(5000)))
    p2.record(len(p2.next()), 0.004, result_bytes([({"i": 0}, None, "")] * 4))  # files written on the worker
    assert len(p2.next()) == 512


def test_later_scenes_start_from_the_measured_cost_without_probes():
    """At 64 workers two probes per worker put half of E-POSE's windows in 4-window chunks
    (bench/bench_cluster_scale.py); a scene after the first starts from the cost measured on it."""
    first = ChunkPlanner(list(range(1000)))
    c = first.next()
    assert len(c) == PROBE_WINDOWS and first.may_submit(1) and not first.may_submit(2)
    first.record(len(c), 0.02 * len(c))
    assert first.may_submit(10) and first.measured == (0.02, 0.0)
    sizes, handed = drain(0.02, prior=first.measured)
    assert sizes[0] == 200 and PROBE_WINDOWS not in sizes[:-1] and handed == list(range(5000))
    # the scene's own cost replaces the prior as soon as its first chunk is back
    p = ChunkPlanner(list(range(1000)), prior=(0.02, 0.0))
    p.record(len(p.next()), 0.1 * 200)
    assert p.cpu_per_window_s == 0.1 and len(p.next()) == 40


def test_the_last_work_is_split_over_the_workers_not_above_half_a_second():
    """The end of the run's last scene: at most remaining / (2 workers) windows a chunk, not under MIN_TASK_CPU_S of
    CPU, so two workers finish together instead of one running a last 4 s chunk alone; while other scenes run
    (tail_workers 0) the chunks keep their 4 s."""
    from evpose.core.export.chunks import MIN_TASK_CPU_S, TARGET_TASK_CPU_S

    def cut(tail_workers):
        p = ChunkPlanner(list(range(1000)), prior=(0.01, 0))         # 10 ms a window: 400 windows = 4 s
        p.tail_workers = tail_workers
        out = []
        while (c := p.next()) is not None:
            out += c
        assert out == list(range(1000))
        return p.sizes

    assert cut(lambda: 0) == [400, 400, 200]
    sizes = cut(lambda: 2)
    assert sizes[0] == 250 and sizes[1] == 188 and max(sizes) <= TARGET_TASK_CPU_S / 0.01
    assert all(s >= MIN_TASK_CPU_S / 0.01 for s in sizes[:-1]) and sum(sizes) == 1000
    assert sizes[-2] == 50 and sizes[-1] <= 50 and len(sizes) <= 11


def test_chunks_hold_whole_groups():
    """A writer that writes a group of windows as one file (BOP shards of 8) gets chunks that end where a group
    ends, whatever size the planner aims at; the pool's fixed chunks too; no task twice or lost."""
    from evpose.core.export.pool import chunk_tasks

    tasks = [i for i in range(300) if i % 7]             # gaps: windows left out
    group = lambda i: i // 8                             # noqa: E731
    for prior in (None, (0.4, 0), (0.001, 0)):           # probes of 4, chunks of ~10, chunks of 512
        p = ChunkPlanner(tasks, prior=prior, group=group)
        chunks = []
        while (c := p.next()) is not None:
            chunks.append(c)
            p.record(len(c), 0.4 * len(c))
        assert [t for c in chunks for t in c] == tasks
        assert all(group(a[-1]) != group(b[0]) for a, b in zip(chunks, chunks[1:]))
    fixed = chunk_tasks(tasks, 4, group)
    assert [t for c in fixed for t in c] == tasks and len(fixed) > 4
    assert all(group(a[-1]) != group(b[0]) for a, b in zip(fixed, fixed[1:]))
