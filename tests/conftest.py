"""Known failures recorded in one place, so that they stay visible in every test report.

Each entry is a test that fails in a clean-checkout run of the whole suite, for the reason
given. They are marked ``xfail`` (not strict: some pass on some machines) with the reason,
never skipped, so that they stay open work in plain sight. Remove an entry when its test
passes again.
"""

from __future__ import annotations

import os
import platform

import pytest


def _pin_blas_kernels() -> None:
    """Select OpenBLAS's Haswell kernels on x86-64 CPUs with AVX2/FMA, before numpy loads.

    ``tests/test_digests.py`` pins the float64 bytes of seeded estimates. OpenBLAS picks its
    compute kernels from the CPU at load time, and its AVX-512 (SkylakeX) kernels round the
    last bits of a matrix product differently from the AVX2 (Haswell/Zen) ones, so the same
    code gives different digests on different x86 machines. Every x86-64 CPU of the last
    decade runs the Haswell kernels, so the suite pins them; an explicit
    ``OPENBLAS_CORETYPE`` in the environment wins.
    """
    if "OPENBLAS_CORETYPE" in os.environ:
        return
    if platform.machine().lower() not in {"x86_64", "amd64"}:
        return
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            flags = fh.read()
    except OSError:
        return
    if " avx2" in flags and " fma" in flags:
        os.environ["OPENBLAS_CORETYPE"] = "Haswell"


_pin_blas_kernels()

# identify() takes numpy kernels for small logs while numba is not imported yet
# (vesselid.identify.backend): equal to the compiled ones to rounding, not bit for bit. So
# that no result of the suite depends on which test happened to load numba first, the
# suite uses the compiled kernels; tests/test_npkernels.py sets the variable per test to
# check the numpy path, the automatic choice and their agreement.
os.environ.setdefault("VESSELID_KERNELS", "compiled")

KNOWN_FAILURES: dict[str, str] = {
    "tests/test_reproduce.py::test_paper_size_matches_published_tables":
        "sd band derived from Monte Carlo SEs: the f sd of Table 2 IV and "
        "IV_E{zeta}=0 is ~12 % below the published sd, z = -4.1 and -4.15 against the "
        "Bonferroni 4.03 (the unpublished pulse widths); the NaN default-estimator row is "
        "excluded",
}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        base = item.nodeid.split("[", 1)[0]
        reason = KNOWN_FAILURES.get(base)
        if reason is not None:
            item.add_marker(pytest.mark.xfail(reason=f"known failure: {reason}", strict=False))
