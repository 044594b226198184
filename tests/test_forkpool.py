"""core.forkpool: items computed in a tree of forked workers, results in item order,
a worker's exception raised in the caller, a dead worker reported, no process left."""

import multiprocessing
import os

import pytest

from vesselid.core import forkpool

pytestmark = pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(),
                                reason="no fork on this platform")


def _children() -> set[int]:
    """Process ids of this process's live children (Linux), or an empty set."""
    path = f"/proc/{os.getpid()}/task/{os.getpid()}/children"
    if not os.path.exists(path):
        return set()
    with open(path) as fh:
        return {int(p) for p in fh.read().split()}


@pytest.mark.parametrize("workers", [1, 2, 5, 16])
def test_results_in_item_order_from_every_worker(workers):
    before = _children()
    shown = []
    out = forkpool.fork_map(lambda i: (i * i, os.getpid()), 23, workers,
                            on_result=shown.append)
    assert [v for v, _ in out] == [i * i for i in range(23)]
    assert shown == list(range(23))
    pids = {p for _, p in out}
    assert os.getpid() not in pids and len(pids) <= min(workers, 23)
    chains = forkpool.start_chains()
    assert len(chains) == min(workers, 23) and all(c >= 0 for c in chains)
    assert _children() == before


def test_initializer_runs_in_each_worker_before_its_items():
    state = {"ready": False}

    def init():
        state["ready"] = True

    assert forkpool.fork_map(lambda i: state["ready"], 6, 3, initializer=init) == [True] * 6
    assert state["ready"] is False  # the caller's copy untouched


def test_a_workers_exception_is_raised_in_the_caller():
    before = _children()

    def fn(i):
        if i in (4, 7):
            raise ValueError(f"bad item {i}")
        return i

    with pytest.raises(ValueError, match="bad item 4"):
        forkpool.fork_map(fn, 12, 3)
    assert _children() == before


def test_an_unpicklable_result_is_an_error_not_a_hang():
    import threading

    with pytest.raises(TypeError):
        forkpool.fork_map(lambda i: threading.Lock(), 3, 2)


def test_a_worker_that_dies_is_reported():
    def fn(i):
        if i == 2:
            os._exit(3)
        return i

    with pytest.raises(forkpool.WorkerDied, match=r"\[2\]"):
        forkpool.fork_map(fn, 6, 2)


def test_no_items_no_workers():
    assert forkpool.fork_map(lambda i: i, 0, 4) == []


def test_idle_cores_and_spread_ranges_in_a_pool_worker(monkeypatch):
    """A pool worker counts itself busy; ``run_ranges(idle=True)`` splits the items over
    the idle cores (each item computed once, by the same code) and records the span."""
    import numpy as np

    from vesselid.core import threads

    count = multiprocessing.Value("i", 0)
    assert threads.idle_cores() == 0  # not a pool's worker
    monkeypatch.setattr(threads, "_SHARED", (count, 3))
    seen = []

    def kernel(lo, hi, out):
        seen.append((lo, hi))
        out[lo:hi] = np.arange(lo, hi) ** 2

    out = np.zeros(7)
    with threads.serial_here(overlap=True), threads.busy():
        assert threads.idle_cores() == 2
        threads.run_ranges(kernel, 7, (out,), parallel=False, idle=True)
    assert count.value == 0 and threads.idle_cores() == 3
    np.testing.assert_array_equal(out, np.arange(7) ** 2)
    assert sorted(b for b in seen if b[1] > b[0]) == [(0, 2), (2, 4), (4, 7)]
    seen.clear()
    span = threads.span_clock()
    with threads.serial_here(), threads.busy():  # no overlap: one call in this thread
        threads.run_ranges(kernel, 7, (out,), parallel=False, idle=True)
    assert seen == [(0, 7)]
    assert threads.span_clock() == span  # nothing spread, nothing to account for


def test_jobs_computed_ahead_only_on_idle_cores_of_a_pool_worker(monkeypatch):
    from vesselid.core import threads

    assert threads.ahead(lambda: 1) is None  # not a pool's worker
    count = multiprocessing.Value("i", 0)
    monkeypatch.setattr(threads, "_SHARED", (count, 2))
    with threads.serial_here():  # a worker that may not overlap
        assert threads.ahead(lambda: 1) is None
    with threads.serial_here(overlap=True), threads.busy():
        job = threads.ahead(lambda: 7)
        assert job is not None and threads.collect(job) == 7
        with threads.busy():  # both cores busy: nothing ahead
            assert threads.ahead(lambda: 1) is None


def test_the_caller_leaving_early_kills_every_worker():
    """An exception in the caller while workers still compute (here from ``on_result``;
    a KeyboardInterrupt alike) kills the workers at once and leaves no process behind."""
    import time

    before = _children()

    def slow(i):
        if i > 0:
            time.sleep(30)
        return i

    def stop(i):
        raise KeyboardInterrupt

    t0 = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        forkpool.fork_map(slow, 8, 4, on_result=stop)
    assert time.perf_counter() - t0 < 10
    assert _children() == before
