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

Code of large shared libraries that only some steps run stays resident once it ran:
numba loads its cached kernels with LLVM (``libllvmlite``, a 180 MB library whose
static initialisers and kernel loading fault in some 50–70 MB of code and read-only
data, never executed by the loaded kernels), and reading a Parquet log runs Arrow's
and Parquet's code (``libarrow*``, ``libparquet``: 25–30 MB). :func:`release_library_code`
switches on returning those pages: :func:`drop_library_code`, called between the steps
of a fit, applies ``madvise(MADV_DONTNEED)`` to the libraries' read-only mappings that
hold no written page. The pages leave the process's resident set and stay in the page
cache (clean file pages: the memory the machine can reclaim either way); a step that
runs the code again (a kernel loaded later, an Arrow-backed string column) faults in
the pages it touches. Results are unchanged (only which pages are resident).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from typing import Any, ClassVar

__all__ = ["CODE_LIBRARIES", "MMAP_THRESHOLD", "TRIM_THRESHOLD", "arrow_system_allocator",
           "drop_library_code", "release_library_code", "unmap_large_blocks"]

#: Blocks of at least this many bytes are mapped (and unmapped on free).
MMAP_THRESHOLD = 1 << 20
#: Free memory at the top of the heap kept for the next blocks (not given back).
TRIM_THRESHOLD = 16 << 20
_M_TRIM_THRESHOLD = -1  # mallopt parameters (malloc.h)
_M_MMAP_THRESHOLD = -3
_ARROW_POOL = "ARROW_DEFAULT_MEMORY_POOL"
#: Shared libraries whose clean read-only pages :func:`drop_library_code` returns:
#: file-name prefix → the module whose import (or first use) maps the library.
CODE_LIBRARIES = {"libllvmlite": "llvmlite.binding.ffi", "libarrow": "pyarrow.lib",
                  "libparquet": "pyarrow._parquet"}
_MADV_DONTNEED = 4


class _CodeRelease:
    """The switch of :func:`release_library_code` and the mappings it found."""

    enabled = False
    ranges: ClassVar[dict[str, list[tuple[int, int]]]] = {}  # prefix → (start, end)s
    madvise: Any = None


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


def release_library_code(enabled: bool = True) -> bool:
    """Switch :func:`drop_library_code` on (or off) for this process; returns whether it
    can act here (Linux with a C library that has ``madvise``)."""
    _CodeRelease.enabled = bool(enabled)
    if not sys.platform.startswith("linux"):
        return False
    if _CodeRelease.madvise is None:
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            madvise = libc.madvise
        except (OSError, AttributeError):  # pragma: no cover - no madvise
            return False
        madvise.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
        madvise.restype = ctypes.c_int
        _CodeRelease.madvise = madvise
    return True


def _clean_code_mappings(prefixes: list[str]) -> dict[str, list[tuple[int, int]]]:
    """(start, end) of this process's mappings of the libraries whose file names start
    with ``prefixes`` that are read-only and hold no written (anonymous or dirty) page,
    from ``/proc/self/smaps``, by prefix (a prefix with no such mapping is left out). A
    read-only mapping with no written page after the library's loading (its relocations
    written) never gets one: discarding its pages loses nothing, they are read from the
    file again."""
    found: dict[str, list[tuple[int, int]]] = {}
    cur: tuple[int, int] | None = None
    owner, clean = "", False

    def close() -> None:
        if cur is not None and clean:
            found.setdefault(owner, []).append(cur)

    with open("/proc/self/smaps") as fh:
        for line in fh:
            head = line.split(None, 6)
            if not head[0].endswith(":"):  # a mapping's header line
                close()
                cur = None
                name = head[5].strip().rsplit("/", 1)[-1] if len(head) > 5 else ""
                if "w" not in head[1]:
                    for prefix in prefixes:
                        if name.startswith(prefix):
                            start, end = (int(x, 16) for x in head[0].split("-"))
                            cur, owner, clean = (start, end), prefix, True
                            break
            elif cur is not None and head[0] in ("Anonymous:", "Private_Dirty:",
                                                 "Shared_Dirty:") and head[1] != "0":
                clean = False
    close()
    return found


def drop_library_code() -> int:
    """Unmap the resident pages of :data:`CODE_LIBRARIES`' clean read-only mappings from
    this process where :func:`release_library_code` switched it on (else nothing): the
    bytes of address space advised (0 where none of the libraries is loaded). A
    library's mappings are found once, the first call after its module is imported;
    later calls only advise them (microseconds)."""
    if not _CodeRelease.enabled or _CodeRelease.madvise is None:
        return 0
    missing = [prefix for prefix, module in CODE_LIBRARIES.items()
               if prefix not in _CodeRelease.ranges and module in sys.modules]
    if missing:
        try:
            _CodeRelease.ranges.update(_clean_code_mappings(missing))
        except OSError:  # pragma: no cover - no /proc
            _CodeRelease.enabled = False
            return 0
    done = 0
    for ranges in _CodeRelease.ranges.values():
        for start, end in ranges:
            if _CodeRelease.madvise(start, end - start, _MADV_DONTNEED) == 0:
                done += end - start
    return done
