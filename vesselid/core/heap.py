"""Keep freed memory in the process's heap during long batched computations.

glibc's ``malloc`` serves a large block (at first anything above 128 KiB) with its own
``mmap`` and unmaps it when freed, and it returns the top of the heap to the system
once more than a threshold of it is free. A Monte Carlo chunk allocates and frees
arrays of ``runs × samples`` doubles (megabytes each) many times over, so every chunk
faults its memory in afresh; under a hypervisor a page fault on memory that went back
to the system is expensive (``scripts/bench.py --only mc_threads`` runs the Monte
Carlo both ways).

:func:`kept_heap` is a context: inside it glibc's thresholds are such that blocks up to
the largest size glibc allows come from the heap and freed memory stays there for
reuse (forked worker processes inherit the setting); on leaving it the thresholds are
glibc's documented defaults again (128 KiB each, no longer adjusted dynamically) and
the freed memory goes back to the system (``malloc_trim``). It does nothing off glibc,
or where ``VESSELID_KEEP_HEAP=0``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["kept_heap"]

# mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: Largest block served from the heap: glibc's limit for ``M_MMAP_THRESHOLD`` on 64-bit
#: (half its 64 MiB heap size; larger values are refused).
MMAP_THRESHOLD = 32 * 1024 * 1024
#: Free memory at the top of the heap kept before any is returned to the system.
TRIM_THRESHOLD = 1024 * 1024 * 1024
#: glibc's documented default of both thresholds, set again on leaving :func:`kept_heap`.
DEFAULT_THRESHOLD = 128 * 1024

_LOCK = threading.Lock()
_DEPTH = [0]


@contextmanager
def kept_heap() -> Iterator[bool]:
    """Keep freed memory in the heap for reuse while inside (module docstring); yields
    whether the setting is in effect (``False`` off Linux/glibc or with
    ``VESSELID_KEEP_HEAP=0``). Nested uses keep it until the outermost one leaves."""
    mallopt = _mallopt()
    with _LOCK:
        on = mallopt is not None and (_DEPTH[0] > 0 or _set(mallopt, MMAP_THRESHOLD,
                                                             TRIM_THRESHOLD))
        _DEPTH[0] += on
    try:
        yield on
    finally:
        if on:
            with _LOCK:
                _DEPTH[0] -= 1
                if _DEPTH[0] == 0:
                    _set(mallopt, DEFAULT_THRESHOLD, DEFAULT_THRESHOLD)
                    _trim()


def _set(mallopt: Any, mmap_threshold: int, trim_threshold: int) -> bool:
    ok = mallopt(_M_MMAP_THRESHOLD, mmap_threshold) == 1
    ok &= mallopt(_M_TRIM_THRESHOLD, trim_threshold) == 1
    return bool(ok)


def _libc() -> Any:
    """glibc, or ``None`` (another platform or C library)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        if not ctypes.CDLL(None).gnu_get_libc_version:  # glibc only (not musl)
            return None
    except (OSError, AttributeError):
        return None
    return libc


def _mallopt() -> Any:
    if os.environ.get("VESSELID_KEEP_HEAP", "1").strip() == "0":
        return None
    libc = _libc()
    if libc is None:
        return None
    fn = libc.mallopt
    fn.argtypes = (ctypes.c_int, ctypes.c_int)
    fn.restype = ctypes.c_int
    return fn


def _trim() -> None:
    libc = _libc()
    if libc is not None:
        libc.malloc_trim.argtypes = (ctypes.c_size_t,)
        libc.malloc_trim(0)
