"""Compute ``fn(i)`` for many items in forked worker processes started as a tree.

:func:`fork_map` is for jobs whose function and data the workers inherit (the Monte
Carlo's chunks: the study, the loaded compiled kernels): nothing is pickled on the way
out, only each item's result on the way back.

Why not :class:`concurrent.futures.ProcessPoolExecutor`: with ``fork`` it forks every
worker from the calling process, one after the other, before the first item starts, and
a fork of a process with the compiled kernels loaded costs milliseconds of that
process's CPU (its page tables are copied). Here the calling process forks one child;
each process responsible for a range of workers forks a child for the upper half of its
range and keeps the lower half, until it is one worker. The ``W`` workers are then
running after about ``log₂ W + 1`` forks in a chain instead of ``W``, each starts on the
items as soon as its own forks are done, and the caller spends one fork.

The workers take the items in order from a shared counter (each the next one when it
finishes one) and send each result back through a pipe of their own; the caller gathers
them in item order. A worker's exception is raised in the caller (the first in item
order); a worker that dies without reporting raises :class:`WorkerDied`. When the caller
leaves early (an exception, ``KeyboardInterrupt``), every worker is killed.
"""

from __future__ import annotations

import os
import pickle
import signal
import time
import traceback
from collections.abc import Callable
from typing import Any

__all__ = ["WorkerDied", "fork_map", "start_chains"]


class WorkerDied(RuntimeError):
    """A worker process ended without sending all its results."""


#: Of the last :func:`fork_map` in this process: each worker's start chain (CPU seconds
#: of the forks before it could take its first item, :func:`start_chains`).
_LAST_CHAINS: list[float] = []


def start_chains() -> list[float]:
    """Of the last :func:`fork_map` in this process, for each worker: the CPU seconds
    spent before it could take its first item by the processes that started it (each
    ancestor's CPU up to and including its fork of the next process on the way, the
    worker's own up to its first item), not the caller's. Benchmarks add the largest to
    the caller's CPU for the critical path on free cores."""
    return list(_LAST_CHAINS)


def _chains(split: list[float], forked: list[float], workers: int) -> list[float]:
    """Each worker's start chain from every process's CPU when its parent had forked it
    (``forked``) and its own before its first item (``split``). The process that ends up
    as worker ``w`` is the one created for the range starting at ``w``
    (:func:`_worker_tree`)."""
    out = []
    for w in range(workers):
        lo, hi, total = 0, workers, 0.0
        while hi - lo > 1:
            mid = (lo + hi + 1) // 2
            if w >= mid:
                lo = mid
                total += forked[mid]
            else:
                hi = mid
        out.append(total + split[w])
    return out


def fork_map(fn: Callable[[int], Any], n_items: int, workers: int, *,
             initializer: Callable[[], None] | None = None,
             on_result: Callable[[int], None] | None = None) -> list[Any]:
    """``[fn(0), …, fn(n_items − 1)]`` computed in ``workers`` forked processes.

    Parameters
    ----------
    fn : callable
        Called with an item index in a worker; its result must pickle.
    n_items, workers : int
        Items, and worker processes (at most ``n_items``).
    initializer : callable, optional
        Run in each worker once, before its first item.
    on_result : callable, optional
        Called in this process with each item index, in item order, as soon as the
        results up to it are in (a progress bar).

    Returns
    -------
    list
        The results in item order.
    """
    import multiprocessing

    n_items, workers = int(n_items), max(1, min(int(workers), int(n_items)))
    if n_items == 0:
        return []
    ctx = multiprocessing.get_context("fork")
    counter = ctx.RawValue("l", 0)  # next item; guarded by lock
    lock = ctx.Lock()
    split = ctx.RawArray("d", workers)  # each worker's CPU before its first item
    forked = ctx.RawArray("d", workers)  # its parent's CPU once it had forked it
    pipes = [ctx.Pipe(duplex=False) for _ in range(workers)]
    results: list[Any] = [None] * n_items
    done = [False] * n_items
    pid = os.fork()
    if pid == 0:  # pragma: no cover - runs in the forked worker processes
        try:
            os.setpgid(0, 0)
            # a background process group writing to the terminal (warnings) is not
            # stopped
            signal.signal(signal.SIGTTOU, signal.SIG_IGN)
            _worker_tree(fn, n_items, workers, counter, lock, (split, forked), pipes,
                         initializer)
        finally:
            os._exit(1)  # (_worker_tree exits itself; never run the caller's code here)
    try:  # every worker in one process group (also set in the child: no race)
        os.setpgid(pid, pid)
    except (PermissionError, ProcessLookupError):  # the child set it (and may have run)
        pass
    for _, writer in pipes:
        writer.close()
    import selectors

    readers = {reader: w for w, (reader, _) in enumerate(pipes)}
    failure: tuple[int, BaseException] | None = None
    shown = 0
    finished = False
    ready = selectors.DefaultSelector()
    try:
        for reader in readers:
            ready.register(reader, selectors.EVENT_READ)
        while readers:
            for key, _ in ready.select():
                reader = key.fileobj
                try:
                    i, ok, value = reader.recv()
                except EOFError:
                    ready.unregister(reader)
                    del readers[reader]
                    reader.close()
                    continue
                if not ok:
                    if failure is None or i < failure[0]:
                        failure = (i, value)
                    _stop(counter, lock, n_items)  # the others take no more items
                    continue
                results[i], done[i] = value, True
                while shown < n_items and done[shown]:
                    if on_result is not None:
                        on_result(shown)
                    shown += 1
        finished = True
    finally:
        ready.close()
        if not finished:
            _kill(pid)
        for reader in readers:
            reader.close()
        _reap(pid)
    _LAST_CHAINS[:] = _chains(list(split), list(forked), workers)
    if failure is not None:
        raise failure[1]
    if not all(done):
        raise WorkerDied(f"a worker process ended without computing items "
                         f"{[i for i in range(n_items) if not done[i]][:5]}")
    return results


def _worker_tree(fn: Callable[[int], Any], n_items: int, workers: int, counter: Any,
                 lock: Any, clocks: tuple[Any, Any], pipes: list,
                 initializer: Callable[[], None] | None
                 ) -> None:  # pragma: no cover - runs in the forked worker processes
    """The forked child of :func:`fork_map`: split ``[0, workers)`` into a tree of
    processes (each forks a child for the upper half of its range and keeps the lower
    half), then work as worker ``lo`` of its range; never returns."""
    status = 1
    split, forked = clocks
    try:
        lo, hi = 0, workers
        children = []
        while hi - lo > 1:
            mid = (lo + hi + 1) // 2
            child = os.fork()
            if child == 0:
                lo, children = mid, []
            else:
                forked[mid] = time.process_time()
                children.append(child)
                hi = mid
        writer = pipes[lo][1]
        for w, (reader, other) in enumerate(pipes):
            reader.close()
            if w != lo:
                other.close()
        split[lo] = time.process_time()  # this process's CPU (its forks) so far
        if initializer is not None:
            initializer()
        while True:
            with lock:
                i = counter.value
                if i >= n_items:
                    break
                counter.value = i + 1
            try:
                msg = (i, True, fn(i))
            except BaseException as exc:  # sent to the caller
                msg = (i, False, _picklable(exc))
            try:
                writer.send(msg)
            except (pickle.PicklingError, TypeError, AttributeError) as exc:
                writer.send((i, False, _picklable(exc)))
            if not msg[1]:
                break
        writer.close()
        status = 0
        for child in children:
            os.waitpid(child, 0)
    finally:
        os._exit(status)


def _stop(counter: Any, lock: Any, n_items: int) -> None:
    """Set the shared counter past the last item (under the lock, unless a worker that
    died holding it keeps it: then without)."""
    got = lock.acquire(timeout=1.0)
    try:
        counter.value = n_items
    finally:
        if got:
            lock.release()


def _picklable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError with its text and traceback."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # any failure to round-trip
        text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        return RuntimeError(f"{type(exc).__name__} in a worker process:\n{text}")


def _kill(group: int) -> None:
    """Kill every worker (their process group)."""
    try:
        os.killpg(group, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _reap(pid: int) -> None:
    """Wait for the first worker process (it waits for the processes it forked)."""
    try:
        os.waitpid(pid, 0)
    except ChildProcessError:
        pass
