"""First run with empty caches: compile independent kernels in a helper process.

numba compiles under one process-wide lock, so a process compiles one kernel at a time.
When the on-disk cache is cold (the first run after an install) and at least two cores
are idle, :func:`start` launches ``python -m vesselid.studies.precompile``, which compiles the
explicit-matrix kernels of :data:`KERNELS` with their exact signatures — in the reverse of
the order in which :func:`vesselid.studies.reproduce.warm_up` first calls them — into the shared
``NUMBA_CACHE_DIR``, while the main process compiles the simulation and the generated
GMM kernels (≈ 5 s of CPU). A kernel the helper has cached by the time the main process
first calls it is loaded, not compiled; one it has not is compiled by the main process
itself (the helper is stopped at the end of the warm-up). Results are unaffected:
the same code is compiled with the same signatures either way.

``VESSELID_PRECOMPILE=1`` starts the helper whatever the load, ``0`` never.
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from typing import Any

#: (module, kernel, signature) in the reverse of the order of their first call in
#: ``warm_up`` (so that the helper and the main process meet last, if at all).
#: ``tests/test_precompile.py`` checks these against what ``warm_up`` compiles.
KERNELS: tuple[tuple[str, str, str], ...] = (
    ("vesselid.identify._pemkernels", "bartlett_lagged",
     "(float64[:, ::1], int64[::1], int64, float64[:, ::1])"),
    ("vesselid.identify._pemkernels", "gaussian_filter_tangent",
     "(float64[::1], int64[::1], float64[::1], float64[:, ::1], int64[::1], float64[::1], "
     "int64[::1], int64[::1], int64[::1], float64[::1], float64[::1], float64[:, ::1], "
     "float64[:, ::1], float64[::1], float64[:, ::1], float64[::1])"),
    ("vesselid.identify._pemkernels", "gaussian_filter",
     "(int64, int64, float64[:, ::1], float64[::1], float64[:, ::1], int64[::1], float64[::1], "
     "int64[::1], int64[::1], int64[::1], float64[:, ::1], float64[:, ::1])"),
    ("vesselid.identify._ivkernels", "cond_bound", "(float64[:, ::1], int64, float64)"),
    ("vesselid.identify._ivkernels", "cross_sums",
     "(float64[:, ::1], float64[:, ::1], float64[::1], int64[::1], boolean[::1])"),
    ("vesselid.identify._ivkernels", "design_ar_centre",
     "(float64[:, ::1], float64[:, ::1], int64, int64, float64[:, ::1], int64, boolean[::1], "
     "float64[::1], int64[::1], float64[:, ::1], int64[::1])"),
    ("vesselid.identify._ivkernels", "design_scan",
     "(float64[:, ::1], float64[:, ::1], int64, int64, float64[:, ::1], int64)"),
    ("vesselid.identify._ivkernels", "autocov",
     "(float64[::1], int64[::1], boolean[::1], int64)"),
    ("vesselid.identify._ivkernels", "simulated_regressors",
     "(float64[:, ::1], float64[:, ::1], int64[::1], int64[::1], float64[:, ::1], "
     "int64[:, ::1], int64[::1], float64[::1])"),
    ("vesselid.identify.kernels", "regressor_matrix",
     "(float64[:, ::1], float64[:, ::1], int64[::1], int64[:, ::1])"),
)


def _dispatcher(module: str, name: str) -> Any:
    return getattr(importlib.import_module(module), name)


def _cached(dispatcher: Any) -> bool:
    """Whether numba's on-disk cache of ``dispatcher`` has an index (True when unknown)."""
    try:
        return bool(os.path.exists(dispatcher._cache._cache_file._index_path))
    except Exception:  # numba internals moved: assume cached, start nothing
        return True


def _cores_idle() -> float:
    """Cores available to this process minus the 1-minute load average."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover — not Linux
        cores = os.cpu_count() or 1
    try:
        return cores - os.getloadavg()[0]
    except OSError:  # pragma: no cover
        return 0.0


def start() -> subprocess.Popen | None:
    """Launch the helper if the caches are cold and two cores are idle (see module)."""
    force = os.environ.get("VESSELID_PRECOMPILE", "")
    if force == "0":
        return None
    try:
        if _cached(_dispatcher(*KERNELS[0][:2])):
            return None
    except Exception:  # numba missing or not importable: nothing to do
        return None
    if force != "1" and _cores_idle() < 1.5:
        return None
    try:
        return subprocess.Popen([sys.executable, "-m", "vesselid.studies.precompile"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
    except OSError:
        return None


def stop(proc: subprocess.Popen | None) -> None:
    """Stop the helper (whatever it has not compiled yet, the main process has)."""
    if proc is None:
        return
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:  # pragma: no cover
        proc.kill()
        proc.wait()


def main() -> None:
    """Compile :data:`KERNELS` into the on-disk cache (the helper process)."""
    from numba.core.sigutils import normalize_signature

    for module, name, sig in KERNELS:
        disp = _dispatcher(module, name)
        if not _cached(disp):
            # the argument types as a tuple: numba keys its disk cache by what compile()
            # is given, and a call gives that tuple
            disp.compile(tuple(normalize_signature(sig)[0]))


if __name__ == "__main__":
    main()
