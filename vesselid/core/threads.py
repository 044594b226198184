"""Run one compiled serial kernel over index ranges in parallel threads.

Every batched kernel of the package loops over independent items (Monte Carlo runs,
experiment segments) and is compiled *once*, serial, with ``nogil=True`` and the item
range ``[lo, hi)`` as its first two arguments. :func:`run_ranges` splits the items into
contiguous chunks that the calling thread and ``threads − 1`` pool threads take in
turn; the kernel releases the GIL, so the chunks run on all cores.

Why not ``numba.prange``: a ``parallel=True`` kernel is a second compilation of the same
loop (and the parfor passes make it the slowest one to compile: the fused GMM moment
kernel took 6.7 s of CPU parallel against 2.1 s serial), while the serial twin was
needed anyway for small problems. One serial kernel serves both, so a first run compiles
each kernel once. Every item is computed by the same code whatever the chunking, so the
results are bit-identical to a serial loop.

The number of threads is numba's (``numba.get_num_threads()``, i.e. ``NUMBA_NUM_THREADS``
or :func:`numba.set_num_threads` in the calling thread), so ``n_jobs`` of the Monte Carlo
runner keeps working.

A worker process of a pool (the Monte Carlo's) runs its kernels in its own thread
(:class:`serial_here`); the pool's workers count themselves while they compute
(:func:`share_cores`, :class:`busy`), so that a worker whose long job still runs when the
others have run out of work can spread it over the cores they leave idle
(:func:`idle_cores`: ``run_ranges(idle=True)``, :func:`ahead`). Where work goes never
changes a number.
"""

from __future__ import annotations

import contextvars
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any

__all__ = ["CHUNKS_PER_THREAD", "ahead", "aside", "background", "busy", "collect",
           "idle_cores", "n_threads", "run_ranges", "serial", "serial_here", "share_cores",
           "span_clock", "usable_cores"]

#: Chunks per thread (several, so that uneven items — early divergence, converged groups
#: skipped — still balance).
CHUNKS_PER_THREAD = 4

_POOL: ThreadPoolExecutor | None = None
_BACKGROUND: ThreadPoolExecutor | None = None
_AHEAD: ThreadPoolExecutor | None = None
_ASIDE: ThreadPoolExecutor | None = None
_AHEAD_JOBS: list[Future] = []
#: Jobs computed ahead at once (:func:`ahead`).
AHEAD_JOBS = 2
_POOL_SIZE = 0
_LOCK = threading.Lock()
_LOCAL = threading.local()
#: In a worker process of a pool of concurrent workers (:func:`share_cores`): the count
#: of the pool's workers computing now (a shared integer) and the cores they run on.
_SHARED: tuple[Any, int] | None = None


def n_threads() -> int:
    """Threads a parallel call uses: numba's current setting for the calling thread,
    at most the cores this process may run on (:func:`usable_cores`; numba's default
    counts every CPU of the machine, also those outside the process's affinity mask)."""
    import numba

    return max(1, min(int(numba.get_num_threads()), usable_cores()))


def usable_cores() -> int:
    """CPUs the process may run on (its affinity mask where the platform has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return max(1, os.cpu_count() or 1)


def _pool(size: int) -> ThreadPoolExecutor:
    global _POOL, _POOL_SIZE
    with _LOCK:
        if _POOL is None or _POOL_SIZE < size:
            old = _POOL
            _POOL = ThreadPoolExecutor(max_workers=size, thread_name_prefix="vesselid",
                                       initializer=_mark_worker)
            _POOL_SIZE = size
            if old is not None:
                old.shutdown(wait=False)
        return _POOL


def _mark_worker() -> None:
    _LOCAL.worker = True


def serial() -> bool:
    """Whether the calling thread runs kernels serially (a pool thread, or inside
    :func:`serial_here`)."""
    return bool(getattr(_LOCAL, "worker", False))


class serial_here:
    """Context: the calling thread runs every :func:`run_ranges` kernel (and the
    simulation's draws) in itself, not on the pool — for a thread that is itself one
    of several working concurrently (the Monte Carlo's chunk threads and processes).

    ``overlap=True`` still lets the calling thread hand one job to a second thread
    (:func:`background`): for a process that is one of several concurrent workers,
    whose rare long job (the prediction-error fallback's candidate models) would
    otherwise hold up the end of the schedule while the other workers' cores idle. The
    job runs the same code on the same numbers in either thread.
    """

    def __init__(self, *, overlap: bool = False) -> None:
        self.overlap = bool(overlap)

    def __enter__(self) -> serial_here:
        self.old = getattr(_LOCAL, "worker", False), getattr(_LOCAL, "overlap", False)
        _LOCAL.worker, _LOCAL.overlap = True, self.overlap
        return self

    def __exit__(self, *exc: object) -> None:
        _LOCAL.worker, _LOCAL.overlap = self.old


def _forget_pool() -> None:
    """In a forked child: the parent's pool threads do not exist there, so start afresh
    (a pool whose threads are gone would never run the submitted chunks)."""
    global _POOL, _POOL_SIZE, _LOCK, _BACKGROUND, _SHARED, _AHEAD, _AHEAD_JOBS, _ASIDE
    _POOL, _POOL_SIZE, _LOCK, _BACKGROUND, _SHARED = None, 0, threading.Lock(), None, None
    _AHEAD, _AHEAD_JOBS, _ASIDE = None, [], None


def share_cores(count: Any, cores: int) -> None:
    """Declare this process one worker of a pool of concurrent workers on ``cores``
    cores: ``count`` (a ``multiprocessing.Value("i")`` shared by the pool) counts the
    workers inside :class:`busy` now. :func:`idle_cores` then tells how many cores the
    others leave idle (the end of a schedule, where one worker still computes a long
    job)."""
    global _SHARED
    _SHARED = (count, max(1, int(cores)))


class busy:
    """Context: this worker computes (counted in :func:`share_cores`'s count while
    inside); nothing outside a pool's worker."""

    def __enter__(self) -> busy:
        self._add(1)
        return self

    def __exit__(self, *exc: object) -> None:
        self._add(-1)

    @staticmethod
    def _add(step: int) -> None:
        if _SHARED is not None:
            with _SHARED[0].get_lock():
                _SHARED[0].value += step


def idle_cores() -> int:
    """Cores the pool's workers leave idle now (:func:`share_cores`; 0 outside a pool's
    worker). A snapshot: a worker that takes the next job a moment later is not in it,
    so it decides how work is split, never what is computed."""
    if _SHARED is None:
        return 0
    return max(0, _SHARED[1] - int(_SHARED[0].value))


if hasattr(os, "register_at_fork"):  # POSIX
    os.register_at_fork(after_in_child=_forget_pool)


def background(fn: Callable[[], Any]) -> Future | None:
    """``fn()`` started on a second thread, where the calling thread may use more than
    one (:func:`n_threads` above one and not :func:`serial`, or inside
    ``serial_here(overlap=True)``); ``None`` otherwise (the caller runs it itself). That
    thread runs its kernels serially (:func:`serial`); it is not one of
    :func:`run_ranges`'s pool, whose chunks would otherwise wait for ``fn``."""
    global _BACKGROUND
    if (serial() and not getattr(_LOCAL, "overlap", False)) or n_threads() < 2:
        return None
    with _LOCK:
        if _BACKGROUND is None:
            _BACKGROUND = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vesselid-bg",
                                             initializer=_mark_worker)
        return _BACKGROUND.submit(fn)


def _mark_aside() -> None:
    _LOCAL.aside = True


def aside(fn: Callable[[], Any]) -> Future | None:
    """``fn()`` started on a thread of its own, in a copy of the caller's context
    (:func:`contextvars.copy_context`: the kernel choice, numpy's error state), where the
    calling thread may use more than one (:func:`n_threads` above one) and is not itself
    a worker (:func:`serial`); ``None`` otherwise (the caller runs it itself). Unlike
    :func:`background`'s thread, this one may hand a job of its own to
    :func:`background`: for work that runs on two threads itself (a likelihood fit's
    candidate models). ``None`` on the aside thread itself: its one thread would wait
    for a job queued behind the one it runs."""
    global _ASIDE
    if serial() or n_threads() < 2 or getattr(_LOCAL, "aside", False):
        return None
    ctx = contextvars.copy_context()
    with _LOCK:
        if _ASIDE is None:
            _ASIDE = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vesselid-aside",
                                        initializer=_mark_aside)
        return _ASIDE.submit(ctx.run, fn)


def ahead(fn: Callable[[], Any]) -> Future | None:
    """``fn()`` computed ahead on an idle core: in a pool's worker that may overlap
    (``serial_here(overlap=True)``) while a core is idle (:func:`idle_cores`, less the
    jobs computed ahead that still run; at most :data:`AHEAD_JOBS` of them); ``None``
    otherwise. For work the caller will likely need next (a guess: an unused result is
    work thrown away); collect it with :func:`collect`, which also keeps
    :func:`span_clock` honest."""
    global _AHEAD
    if not (getattr(_LOCAL, "worker", False) and getattr(_LOCAL, "overlap", False)):
        return None
    _AHEAD_JOBS[:] = [j for j in _AHEAD_JOBS if not j.done()]
    if len(_AHEAD_JOBS) >= AHEAD_JOBS or idle_cores() <= len(_AHEAD_JOBS):
        return None
    start = time.thread_time() + span_clock()

    def timed() -> tuple[Any, float]:
        c0 = time.thread_time()
        out = fn()
        return out, time.thread_time() - c0

    with _LOCK:
        if _AHEAD is None:
            _AHEAD = ThreadPoolExecutor(max_workers=AHEAD_JOBS,
                                        thread_name_prefix="vesselid-ahead",
                                        initializer=_mark_worker)
        job = _AHEAD.submit(timed)
    job.started = start  # type: ignore[attr-defined]
    _AHEAD_JOBS.append(job)
    return job


def collect(job: Future) -> Any:
    """The result of a job of :func:`ahead` (waiting for it). The calling thread's
    critical path (:func:`span_clock`) then runs at least to the job's end: the job's
    CPU from when it was started, where that is more than this thread's since."""
    out, cpu = job.result()
    mine = time.thread_time() + span_clock() - job.started  # type: ignore[attr-defined]
    if cpu > mine:
        _LOCAL.span = getattr(_LOCAL, "span", 0.0) + (cpu - mine)
    return out


def run_ranges(kernel: Callable[..., Any], n_items: int, args: tuple, *,
               parallel: bool, idle: bool = False) -> None:
    """``kernel(lo, hi, *args)`` over ``[0, n_items)``: one call, or chunks in threads.

    Parameters
    ----------
    kernel : compiled function
        Serial, ``nogil=True``, processes items ``lo ≤ i < hi`` and writes only their
        outputs.
    n_items : int
        Number of independent items.
    args : tuple
        The remaining arguments.
    parallel : bool
        Split across :func:`n_threads` threads (if more than one item and thread).
    idle : bool
        In a pool's worker that may overlap (``serial_here(overlap=True)``): split the
        items into one contiguous block per thread over this thread and the cores the
        pool's other workers leave idle now (:func:`idle_cores`) — for a call whose
        latency holds up the end of a schedule. Elsewhere ``parallel`` decides.
    """
    n_items = int(n_items)
    if getattr(_LOCAL, "worker", False):
        threads = (min(n_items, 1 + idle_cores())
                   if idle and getattr(_LOCAL, "overlap", False) else 1)
        n_chunks = threads
    else:
        threads = n_threads() if parallel and n_items > 1 else 1
        n_chunks = min(n_items, threads * CHUNKS_PER_THREAD)
    if threads <= 1:
        kernel(0, n_items, *args)
        return
    bounds = [n_items * c // n_chunks for c in range(n_chunks + 1)]
    todo = iter(range(n_chunks))  # shared: next() on it is atomic under the GIL
    spread = getattr(_LOCAL, "worker", False)  # over idle cores: the blocks' CPU clocks
    blocks: list[float] = []
    mine = [0.0]

    def work() -> None:
        main = threading.current_thread() is caller
        for c in todo:
            c0 = time.thread_time() if spread else 0.0
            kernel(bounds[c], bounds[c + 1], *args)
            if spread:
                blocks.append(time.thread_time() - c0)
                if main:
                    mine[0] += blocks[-1]

    caller = threading.current_thread()
    kernel(0, 0, *args)  # compile (or load) in the calling thread first, over no item
    # over idle cores: a pool for every core at once (the idle cores grow as the other
    # workers finish; a pool that grew with them would be made anew each time)
    pool = _pool(max(threads, _SHARED[1] if spread and _SHARED is not None else 0) - 1)
    futures = [pool.submit(work) for _ in range(threads - 1)]
    try:
        work()  # the calling thread takes chunks too
    finally:  # never return (or raise) while pool threads still write the outputs
        wait(futures)
    for fut in futures:
        fut.result()
    if spread and blocks:
        # this thread's CPU in the call had every block run on a core of its own: its
        # own CPU outside the blocks plus the longest block (span_clock)
        _LOCAL.span = getattr(_LOCAL, "span", 0.0) + max(blocks) - mine[0]


def span_clock() -> float:
    """Seconds to add to the calling thread's CPU clock (``time.thread_time``) for the
    critical path of its work where every block of its :func:`run_ranges` calls over
    idle cores (``idle=True`` in a pool's worker) runs on a core of its own: the longest
    block in place of the blocks this thread ran itself (accumulated over the thread's
    life; benchmarks read it before and after a job). The blocks are timed with
    their threads' CPU clocks, so the figure holds whichever thread ran which block."""
    return float(getattr(_LOCAL, "span", 0.0))
