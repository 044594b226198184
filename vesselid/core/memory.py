"""Return freed array memory to the operating system (glibc's allocator).

glibc serves a large block by ``mmap`` and unmaps it on ``free``, but after the first
such ``free`` it raises its mmap threshold to the freed size (up to 32 MiB), so that
later arrays of that size come from the heap, whose freed blocks stay mapped. A
pipeline that makes many temporaries of ``N`` float64 (8 MB at 10⁶ samples) then
keeps a high-water mark of every stage's temporaries in its resident memory. A fixed
threshold (:func:`unmap_large_blocks`) switches the adjustment off: blocks from
``MMAP_THRESHOLD`` up are mapped and returned on ``free``, and the peak resident memory
follows the arrays alive at once. Results are unchanged (only where memory comes from).
Fixing the mmap threshold also stops glibc's adjustment of the heap's trim threshold,
which then stays at 128 KiB: a long log's row-block temporaries (a few hundred kB, from
the heap) would give the top of the heap back on every ``free`` and fault it in again on
the next block (~10 % of ``identify``'s CPU on a 4·10⁶-sample log).
:func:`unmap_large_blocks` sets it to ``TRIM_THRESHOLD``: the heap then keeps up to that
much free memory at its top (it holds only blocks below ``MMAP_THRESHOLD``).

Arrow (Parquet logs) allocates from its own pool, mimalloc by default, which keeps freed
and partly used pages of its 1 GiB arena resident; a frame read from Parquet keeps the
buffers Arrow decoded (zero-copy columns), so where Arrow allocates is where the log
lives. :func:`arrow_system_allocator` makes the C library's allocator Arrow's default
pool (before pyarrow is imported): with the fixed threshold each large column is then a
mapping of its own.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

__all__ = ["MMAP_THRESHOLD", "TRIM_THRESHOLD", "arrow_system_allocator",
           "unmap_large_blocks"]

#: Blocks of at least this many bytes are mapped (and unmapped on free).
MMAP_THRESHOLD = 1 << 20
#: Free memory at the top of the heap kept for the next blocks (not given back).
TRIM_THRESHOLD = 16 << 20
_M_TRIM_THRESHOLD = -1  # mallopt parameters (malloc.h)
_M_MMAP_THRESHOLD = -3
_ARROW_POOL = "ARROW_DEFAULT_MEMORY_POOL"


def unmap_large_blocks(threshold: int = MMAP_THRESHOLD, trim: int = TRIM_THRESHOLD) -> bool:
    """Fix glibc's mmap threshold at ``threshold`` bytes and its heap trim threshold at
    ``trim`` bytes; False where there is no glibc (other platforms keep their allocator's
    behaviour)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # pragma: no cover - musl and others
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    mapped = bool(mallopt(_M_MMAP_THRESHOLD, int(threshold)))
    return bool(mallopt(_M_TRIM_THRESHOLD, int(trim))) and mapped


def arrow_system_allocator() -> bool:
    """Make the C library's allocator Arrow's default memory pool for this process.

    Arrow chooses its default pool once, from ``ARROW_DEFAULT_MEMORY_POOL``, when pyarrow
    is imported: this sets that variable (a value already in the environment is kept)
    and so works only before the import. Returns whether the C library's allocator is
    (or will be) the default pool."""
    if "pyarrow" in sys.modules:
        pa = sys.modules["pyarrow"]
        try:
            return bool(pa.default_memory_pool().backend_name == "system")
        except AttributeError:  # pragma: no cover - a partial or very old pyarrow
            return False
    return os.environ.setdefault(_ARROW_POOL, "system") == "system"
