"""Keep freed memory in the process's heap during long batched computations.

glibc's ``malloc`` serves a large block (at first anything above 128 KiB) with its own
``mmap`` and unmaps it when freed, and it returns the top of the heap to the system
once more than a threshold of it is free. A Monte Carlo chunk allocates and frees
arrays of ``runs × samples`` doubles (megabytes each) many times over, so every chunk
faults its memory in afresh; under a hypervisor a page fault on memory that went back
to the system is expensive (``scripts/bench.py --only mc_threads`` runs the Monte
Carlo both ways).

:func:`keep_heap` sets glibc's thresholds so that blocks up to the largest size glibc
allows come from the heap and freed memory stays there for reuse: the process keeps
its peak heap instead of returning it. Forked worker processes inherit the setting.
It does nothing off glibc, or where ``VESSELID_KEEP_HEAP=0``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
import threading

__all__ = ["keep_heap"]

# mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3

#: Largest block served from the heap: glibc's limit for ``M_MMAP_THRESHOLD`` on 64-bit
#: (half its 64 MiB heap size; larger values are refused).
MMAP_THRESHOLD = 32 * 1024 * 1024
#: Free memory at the top of the heap kept before any is returned to the system.
TRIM_THRESHOLD = 1024 * 1024 * 1024

_LOCK = threading.Lock()
_DONE: list[bool] = []


def keep_heap() -> bool:
    """Set glibc's ``malloc`` to keep freed memory for reuse (module docstring), once
    per process. Returns whether the setting is in effect (``False`` off Linux/glibc
    or with ``VESSELID_KEEP_HEAP=0``)."""
    with _LOCK:
        if not _DONE:
            _DONE.append(_apply())
        return _DONE[0]


def _apply() -> bool:
    if os.environ.get("VESSELID_KEEP_HEAP", "1").strip() == "0":
        return False
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
        if not ctypes.CDLL(None).gnu_get_libc_version:  # glibc only (not musl)
            return False
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
    ok &= mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
    return bool(ok)
