"""Moment kernels specialised to one model structure (generated source, compiled once).

The generic kernel of :mod:`vesselid.identify.kernels` reads the factor layout of
every term from arrays at every sample. For a given structure — the number of
states ``n`` and inputs ``m``, the factor layout, the equations of the terms — this
module writes the same computation with all loops over states, inputs and terms
unrolled into scalar code (factors spelled through
:func:`vesselid.regressors.factor_source`), and compiles it with numba.

* The operations and their order are exactly those of the generic kernel (same
  auxiliary-model recursion, same divergence test, same accumulation order), so
  the two give bit-identical moments (tested on every catalogue structure); the
  specialised kernel only removes the indexing overhead (≈ 3–5× faster).
* The generated module is written once per structure to a private per-user cache
  directory (:func:`kernel_dir`) and only rewritten if its text changes, so numba's
  on-disk cache of the compiled code stays valid across processes. Its file name is
  a digest of the source, the numba and Python versions and
  :data:`vesselid.regressors.SALT`, so an edit of the kernel module invalidates it.
* Code is only executed from a directory that is owned by the current user and
  closed to everybody else (mode ``0o700``; an own directory that is more open is
  tightened); otherwise — and whenever writing, importing or compiling the generated
  code fails — the generic kernel is used. There is no shared-temporary-directory
  fallback.
* Files not used for :data:`PRUNE_AFTER_DAYS` days are deleted (at most
  :data:`MAX_KEPT_FILES` are kept), with their numba cache files.
* Only the least-squares and simulated-instrument modes are specialised, and the
  fused combined-instrument (simulated + delayed) GMM pass of
  :func:`vesselid.identify._ivkernels.combined_moments` (:func:`specialised_combined`,
  up to :data:`MAX_COMBINED_COLUMNS` instrument columns); other modes use the generic
  kernel. ``VESSELID_GENERIC_KERNELS=1`` disables generation.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import os
import stat
import sys
import threading
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numba
import numpy as np

from vesselid.regressors import SALT, factor_source

__all__ = [
    "MAX_KEPT_FILES",
    "MAX_SPECIALISED_PARAMS",
    "PRUNE_AFTER_DAYS",
    "SpecialisedMoments",
    "kernel_dir",
    "prune",
    "specialised_combined",
    "specialised_moments",
]

#: Larger structures use the generic kernel (unrolled code grows as P²).
MAX_SPECIALISED_PARAMS = 24

#: Generated kernels unused for this many days are deleted.
PRUNE_AFTER_DAYS = 30

#: At most this many generated kernels are kept (least recently used go first).
MAX_KEPT_FILES = 64

_PREFIX = "vesselid_moments_"

_LOCK = threading.Lock()
_CACHE: dict[tuple, SpecialisedMoments | None] = {}
_PRUNED: set[Path] = set()


def _default_dir() -> Path:
    """Per-user cache location: ``%LOCALAPPDATA%`` on Windows, else XDG / ``~/.cache``."""
    if os.name == "nt":
        base = os.environ.get("LOCALAPPDATA")
        root = Path(base) if base else Path.home() / "AppData" / "Local"
        return root / "vesselid" / "kernels"
    base = os.environ.get("XDG_CACHE_HOME")
    root = Path(base) if base and Path(base).is_absolute() else Path.home() / ".cache"
    return root / "vesselid" / "kernels"


def _uid() -> int | None:
    """The current user id, or None where the platform has none (Windows)."""
    getuid = getattr(os, "getuid", None)
    return None if getuid is None else getuid()


def _owned(path: Path, kind: Callable[[int], bool], *, follow: bool) -> os.stat_result | None:
    """``path``'s stat if it is of ``kind`` and owned by the current user (any owner where
    the platform has no user ids), else None."""
    try:
        st = path.stat() if follow else path.lstat()
    except OSError:
        return None
    uid = _uid()
    if not kind(st.st_mode) or (uid is not None and st.st_uid != uid):
        return None
    return st


def _private(path: Path) -> bool:
    """True if ``path`` is a directory only the current user can use.

    POSIX: owned by us with no group/other permissions (an own directory that is more
    open is tightened to ``0o700``), inside a parent that only we or root can change,
    or that is sticky. Without POSIX user ids (Windows) the per-user profile's ACLs
    protect the default location; the directory must be a real directory.
    """
    st = _owned(path, stat.S_ISDIR, follow=True)
    uid = _uid()
    if st is None or uid is None:
        return st is not None
    if st.st_mode & 0o077:
        try:
            os.chmod(path, 0o700)
            st = path.stat()
        except OSError:
            return False
        if st.st_mode & 0o077:
            return False
    try:
        pst = path.resolve().parent.stat()
    except OSError:
        return False
    return pst.st_uid in (uid, 0) and (not pst.st_mode & 0o022 or bool(pst.st_mode & stat.S_ISVTX))


def kernel_dir() -> Path | None:
    """Private per-user directory of the generated kernels, or None (use the generic one).

    ``$VESSELID_KERNEL_DIR`` if set, else ``~/.cache/vesselid/kernels`` (XDG) or
    ``%LOCALAPPDATA%\\vesselid\\kernels`` (Windows). Created with mode ``0o700``; used
    only if :func:`_private` accepts it. Never a shared temporary directory.
    """
    env = os.environ.get("VESSELID_KERNEL_DIR")
    path = Path(env).expanduser() if env else _default_dir()
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError:
        return None
    return path if _private(path) else None


def _safe_file(path: Path) -> bool:
    """A generated file we may execute: a regular file we own, writable by us only."""
    st = _owned(path, stat.S_ISREG, follow=False)
    return st is not None and (_uid() is None or not st.st_mode & 0o022)


def prune(directory: Path, *, now: float | None = None,
          max_age_days: float = PRUNE_AFTER_DAYS, keep: int = MAX_KEPT_FILES) -> list[Path]:
    """Delete generated kernels unused for ``max_age_days`` (or beyond the ``keep`` most
    recently used) together with their numba cache files; returns the deleted modules.

    "Used" is the file's modification time, refreshed whenever a kernel is loaded.
    """
    now = time.time() if now is None else now
    try:
        files = [(p.stat().st_mtime, p) for p in directory.glob(f"{_PREFIX}*.py")]
    except OSError:
        return []
    files.sort(reverse=True)
    gone: list[Path] = []
    for rank, (mtime, path) in enumerate(files):
        if rank < keep and now - mtime < max_age_days * 86400.0:
            continue
        stem = path.stem
        with contextlib.suppress(OSError):
            path.unlink()
            gone.append(path)
        cache = directory / "__pycache__"
        with contextlib.suppress(OSError):
            for extra in cache.glob(f"{stem}.*"):
                with contextlib.suppress(OSError):
                    extra.unlink()
    return gone


def _factor(idx: int, n: int, m: int, sig: str) -> str | None:
    """Variable name of factor ``idx`` of the layout ``F = [s, |s|, 1]`` with ``s = [x; u]``
    (:func:`vesselid.regressors.factor_source`); None for the constant 1."""
    src = factor_source(idx, n + m)
    if src is None:
        return None
    j, modulus = src
    name = f"{sig}{j}" if j < n else f"v{j - n}"
    return "a" + name if modulus else name


def _product(f0: str | None, f1: str | None) -> str:
    # the generic kernel multiplies by the factor 1.0, which is exact: drop it
    parts = [f for f in (f0, f1) if f is not None]
    return " * ".join(parts) if parts else "1.0"


def _source(n: int, m: int, fac: np.ndarray, eq: np.ndarray, blocks: np.ndarray) -> str:
    n_par = fac.shape[0]
    blk = [list(range(int(blocks[i]), int(blocks[i + 1]))) for i in range(n)]
    ind = " " * 8
    lines: list[str] = []
    add = lines.append
    add('"""Generated by vesselid.identify._fastkernels; do not edit."""')
    add("import numpy as np")
    add("from numba import njit")
    add("")
    add("")
    add("@njit(cache=True, inline='always')")
    add("def _segment(s, regsig, target, u, starts, group, theta, active, use_sim, limit,")
    add("             s_zphi, s_zy, s_z, s_phi, s_y, count, status):")
    add("    g = group[s]")
    add("    if not active[g]:")
    add("        return")
    add("    a = starts[s]")
    add("    b = starts[s + 1]")
    add("    status[s] = 0")
    add("    count[s] = b - a - 1")
    add("    lim = limit[s]")
    for p in range(n_par):
        add(f"    th{p} = theta[g, {p}]")
    for i in range(n):
        add(f"    x{i} = target[a, {i}]")
        add(f"    ly{i} = 0.0")
    for i in range(n):
        for p in blk[i]:
            add(f"    lzy{p} = 0.0")
            add(f"    lz{p} = 0.0")
            add(f"    lphi{p} = 0.0")
            for q in blk[i]:
                add(f"    lzphi{p}_{q} = 0.0")

    def term(p: int, sig: str) -> str:
        return _product(_factor(int(fac[p, 0]), n, m, sig), _factor(int(fac[p, 1]), n, m, sig))

    def body(sim: bool) -> None:
        add(f"{ind}for k in range(a + 1, b):")
        i2 = ind + "    "
        for i in range(n):
            add(f"{i2}d{i} = regsig[k - 1, {i}]")
            add(f"{i2}ad{i} = abs(d{i})")
        for j in range(m):
            add(f"{i2}v{j} = u[k - 1, {j}]")
            add(f"{i2}av{j} = abs(v{j})")
        for p in range(n_par):
            add(f"{i2}phi{p} = {term(p, 'd')}")
        if sim:
            for i in range(n):
                add(f"{i2}ax{i} = abs(x{i})")
            for p in range(n_par):
                add(f"{i2}z{p} = {term(p, 'x')}")
            for i in range(n):
                terms = [f"th{p} * z{p}" for p in range(n_par) if int(eq[p]) == i]
                expr = "0.0"
                for t in terms:
                    expr = f"({expr} + {t})"
                add(f"{i2}x{i} = {expr}")
            cond = " or ".join(f"not (abs(x{i}) <= lim)" for i in range(n))
            add(f"{i2}if {cond}:")
            add(f"{i2}    status[s] = 1")
            add(f"{i2}    break")
        else:
            for p in range(n_par):
                add(f"{i2}z{p} = phi{p}")
        for i in range(n):
            add(f"{i2}y{i} = target[k, {i}]")
            add(f"{i2}ly{i} += y{i}")
            for p in blk[i]:
                add(f"{i2}lzy{p} += z{p} * y{i}")
                add(f"{i2}lz{p} += z{p}")
                add(f"{i2}lphi{p} += phi{p}")
                for q in blk[i]:
                    add(f"{i2}lzphi{p}_{q} += z{p} * phi{q}")

    add("    if use_sim:")
    body(True)
    add("    else:")
    body(False)
    for i in range(n):
        for p in blk[i]:
            add(f"    s_zy[s, {p}] = lzy{p}")
            add(f"    s_z[s, {p}] = lz{p}")
            add(f"    s_phi[s, {p}] = lphi{p}")
            for q in range(n_par):
                val = f"lzphi{p}_{q}" if q in blk[i] else "0.0"
                add(f"    s_zphi[s, {p}, {q}] = {val}")
        add(f"    s_y[s, {i}] = ly{i}")
    args = ("regsig, target, u, starts, group, theta, active, use_sim, limit, "
            "s_zphi, s_zy, s_z, s_phi, s_y, count, status")
    add("")
    add("")
    add("@njit(cache=True, nogil=True)")
    add(f"def segments(lo, hi, {args}):")
    add("    for s in range(lo, hi):")
    add(f"        _segment(s, {args})")
    return "\n".join(lines) + "\n"


#: Larger combined instrument sets use the generic kernel (unrolled code grows as K²).
MAX_COMBINED_COLUMNS = 16


def _combined_source(n: int, m: int, fac: np.ndarray, eq: np.ndarray, ztype: np.ndarray,
                     zpar: np.ndarray, zeq: np.ndarray) -> str:
    """Source of the combined-instrument pass of
    :func:`vesselid.identify._ivkernels.combined_moments` for one structure and column
    layout, unrolled (same operations, same order: bit-identical)."""
    n_par, k_tot = fac.shape[0], ztype.shape[0]
    lag_sig = {0: "x", 2: "l", 3: "o"}
    own = [[p for p in range(n_par) if int(eq[p]) == int(zeq[c])] for c in range(k_tot)]
    lines: list[str] = []
    add = lines.append

    def term(p: int, sig: str) -> str:
        return _product(_factor(int(fac[p, 0]), n, m, sig), _factor(int(fac[p, 1]), n, m, sig))

    def load_row(ind: str) -> None:
        # signals of row k: data at k−1 (φ), delayed data at k−2 / k−3, x̂(k−1), u(k−1)
        for i in range(n):
            add(f"{ind}d{i} = regsig[k - 1, {i}]")
            add(f"{ind}ad{i} = abs(d{i})")
            if (ztype == 2).any():
                add(f"{ind}l{i} = regsig[k - 2, {i}]")
                add(f"{ind}al{i} = abs(l{i})")
            if (ztype == 3).any():
                add(f"{ind}o{i} = regsig[k - 3, {i}]")
                add(f"{ind}ao{i} = abs(o{i})")
        for p in range(n_par):
            add(f"{ind}phi{p} = {term(p, 'd')}")
        for c in range(k_tot):
            add(f"{ind}z{c} = {term(int(zpar[c]), lag_sig[int(ztype[c])])}")

    def advance(ind: str) -> None:
        for p in range(n_par):
            add(f"{ind}q{p} = {term(p, 'x')}")
        for i in range(n):
            expr = "0.0"
            for p in range(n_par):
                if int(eq[p]) == i:
                    expr = f"({expr} + th{p} * q{p})"
            add(f"{ind}x{i} = {expr}")
        cond = " or ".join(f"not (abs(x{i}) <= lim)" for i in range(n))
        add(f"{ind}if {cond}:")
        add(f"{ind}    status[s] = 1")
        add(f"{ind}    break")

    def inputs_and_state(ind: str) -> None:
        for j in range(m):
            add(f"{ind}v{j} = u[k - 1, {j}]")
            add(f"{ind}av{j} = abs(v{j})")
        for i in range(n):
            add(f"{ind}ax{i} = abs(x{i})")

    add('"""Generated by vesselid.identify._fastkernels (combined instruments); do not edit."""')
    add("import numpy as np")
    add("from numba import njit")
    add("")
    add("")
    add("@njit(cache=True, inline='always')")
    add("def _segment(s, regsig, target, u, starts, group, theta, active, limit, second,")
    add("             theta1, means_z, means_phi, means_y, means_g, lags, s_a, s_b, s_m, s_z,")
    add("             s_phi, s_y, count, status, s_hac):")
    add("    g = group[s]")
    add("    if not active[g]:")
    add("        return")
    add("    a = starts[s]")
    add("    b = starts[s + 1]")
    add("    lim = limit[s]")
    for p in range(n_par):
        add(f"    th{p} = theta[g, {p}]")
    add("    status[s] = 0")
    for i in range(n):
        add(f"    x{i} = target[a, {i}]")
    add("    cnt = 0")
    add("    if not second:")
    ind = " " * 8
    for c in range(k_tot):
        add(f"{ind}lb{c} = 0.0")
        add(f"{ind}lz{c} = 0.0")
        for p in own[c]:
            add(f"{ind}la{c}_{p} = 0.0")
        for c2 in range(c, k_tot):
            add(f"{ind}lm{c}_{c2} = 0.0")
    for p in range(n_par):
        add(f"{ind}lphi{p} = 0.0")
    for i in range(n):
        add(f"{ind}ly{i} = 0.0")
    add(f"{ind}for k in range(a + 1, b):")
    i2 = ind + "    "
    inputs_and_state(i2)
    add(f"{i2}if k >= a + 3:")
    i3 = i2 + "    "
    load_row(i3)
    add(f"{i3}cnt += 1")
    for c in range(k_tot):
        add(f"{i3}lb{c} += z{c} * target[k, {int(zeq[c])}]")
        add(f"{i3}lz{c} += z{c}")
        for p in own[c]:
            add(f"{i3}la{c}_{p} += z{c} * phi{p}")
        for c2 in range(c, k_tot):
            add(f"{i3}lm{c}_{c2} += z{c} * z{c2}")
    for p in range(n_par):
        add(f"{i3}lphi{p} += phi{p}")
    for i in range(n):
        add(f"{i3}ly{i} += target[k, {i}]")
    advance(i2)
    add(f"{ind}count[s] = cnt")
    for c in range(k_tot):
        add(f"{ind}s_b[s, {c}] = lb{c}")
        add(f"{ind}s_z[s, {c}] = lz{c}")
        for p in range(n_par):
            add(f"{ind}s_a[s, {c}, {p}] = " + (f"la{c}_{p}" if p in own[c] else "0.0"))
        for c2 in range(c, k_tot):
            add(f"{ind}s_m[s, {c}, {c2}] = lm{c}_{c2}")
            add(f"{ind}s_m[s, {c2}, {c}] = lm{c}_{c2}")
    for p in range(n_par):
        add(f"{ind}s_phi[s, {p}] = lphi{p}")
    for i in range(n):
        add(f"{ind}s_y[s, {i}] = ly{i}")
    add("    else:")
    for p in range(n_par):
        add(f"{ind}t{p} = theta1[g, {p}]")
        add(f"{ind}mphi{p} = means_phi[s, {p}]")
    for i in range(n):
        add(f"{ind}my{i} = means_y[s, {i}]")
    for c in range(k_tot):
        add(f"{ind}mz{c} = means_z[s, {c}]")
        add(f"{ind}mg{c} = means_g[s, {c}]")
        add(f"{ind}h{c} = 0.0")
        for c2 in range(c, k_tot):
            add(f"{ind}lh{c}_{c2} = 0.0")
    add(f"{ind}ring = np.zeros((lags + 1, {k_tot}))")
    add(f"{ind}for k in range(a + 1, b):")
    inputs_and_state(i2)
    add(f"{i2}if k >= a + 3:")
    load_row(i3)
    for i in range(n):
        add(f"{i3}e{i} = target[k, {i}] - my{i}")
    for p in range(n_par):
        add(f"{i3}e{int(eq[p])} -= (phi{p} - mphi{p}) * t{p}")
    add(f"{i3}slot = cnt % (lags + 1)")
    for c in range(k_tot):
        add(f"{i3}sc{c} = (z{c} - mz{c}) * e{int(zeq[c])} - mg{c}")
        add(f"{i3}h{c} += sc{c} - ring[slot, {c}]")
        add(f"{i3}ring[slot, {c}] = sc{c}")
    add(f"{i3}cnt += 1")
    for c in range(k_tot):
        for c2 in range(c, k_tot):
            add(f"{i3}lh{c}_{c2} += h{c} * h{c2}")
    advance(i2)
    add(f"{ind}for _ in range(lags):")
    add(f"{i2}slot = cnt % (lags + 1)")
    for c in range(k_tot):
        add(f"{i2}h{c} -= ring[slot, {c}]")
        add(f"{i2}ring[slot, {c}] = 0.0")
    add(f"{i2}cnt += 1")
    for c in range(k_tot):
        for c2 in range(c, k_tot):
            add(f"{i2}lh{c}_{c2} += h{c} * h{c2}")
    for c in range(k_tot):
        for c2 in range(c, k_tot):
            add(f"{ind}s_hac[s, {c}, {c2}] = lh{c}_{c2} / (lags + 1.0)")
            add(f"{ind}s_hac[s, {c2}, {c}] = s_hac[s, {c}, {c2}]")
    args = ("regsig, target, u, starts, group, theta, active, limit, second, theta1, "
            "means_z, means_phi, means_y, means_g, lags, s_a, s_b, s_m, s_z, s_phi, s_y, "
            "count, status, s_hac")
    full = ("regsig, target, u, starts, group, theta, active, fac, eq, ztype, zpar, zeq, "
            "limit, second, theta1, means_z, means_phi, means_y, means_g, lags, s_a, s_b, "
            "s_m, s_z, s_phi, s_y, count, status, s_hac")
    add("")
    add("")
    add("@njit(cache=True, nogil=True)")
    add(f"def segments(lo, hi, {full}):")
    add("    for s in range(lo, hi):")
    add(f"        _segment(s, {args})")
    return "\n".join(lines) + "\n"


def _load(source: str) -> Callable | None:
    """Write (if needed), check and import the generated module; None if not possible."""
    digest = hashlib.sha256(
        (source + numba.__version__ + sys.version + SALT).encode()).hexdigest()[:16]
    name = f"{_PREFIX}{digest}"
    if name in sys.modules:
        return sys.modules[name].segments
    directory = kernel_dir()
    if directory is None:
        return None
    if directory not in _PRUNED:
        _PRUNED.add(directory)
        prune(directory)
    path = directory / f"{name}.py"
    try:
        current = path.read_text(encoding="utf-8") if _safe_file(path) else None
    except (OSError, UnicodeDecodeError):
        current = None
    if current != source:
        from vesselid._io import atomic_write_text

        atomic_write_text(path, source)  # replaces whatever is there (a link, a foreign file)
    if not _safe_file(path):
        return None
    with contextlib.suppress(OSError):
        os.utime(path)  # mark as used (pruning keeps recently used kernels)
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:  # pragma: no cover
        return None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    try:
        spec.loader.exec_module(mod)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return mod.segments


class SpecialisedMoments:
    """The generated kernel of one structure, with a fallback.

    One serial ``nogil`` kernel over a segment range; calling the object runs it (over
    threads when ``parallel``, :func:`vesselid._threads.run_ranges`) and returns True.
    If numba fails to compile the generated code at its first call, it warns once,
    disables itself and returns False, and the caller runs the generic kernel instead.
    Errors of an already compiled kernel propagate.
    """

    def __init__(self, segments: Callable) -> None:
        self.kernel = segments
        self.failed = False

    def __call__(self, parallel: bool, *args) -> bool:
        if self.failed:
            return False
        fn = self.kernel
        if not getattr(fn, "signatures", ()):
            try:
                fn(0, 0, *args)  # compile here, in the calling thread, over no segment
            except Exception as exc:
                self.failed = True
                warnings.warn(f"generated moment kernel failed to compile "
                              f"({type(exc).__name__}: "
                              f"{str(exc).splitlines()[0] if str(exc) else ''}); using the "
                              "generic kernel", RuntimeWarning, stacklevel=3)
                return False
        from vesselid._threads import run_ranges

        run_ranges(fn, args[3].shape[0] - 1, args, parallel=parallel)
        return True


def specialised_moments(
    n: int, m: int, fac: np.ndarray, eq: np.ndarray, blocks: np.ndarray
) -> SpecialisedMoments | None:
    """The specialised kernels for this structure, or None (use the generic one).

    Call the result as ``kern(parallel, regsig, target, u, starts, group, theta, active,
    use_sim, limit, s_zphi, s_zy, s_z, s_phi, s_y, count, status)``; it returns False if
    the generated code could not be compiled (then run the generic kernel).
    """
    if fac.shape[0] > MAX_SPECIALISED_PARAMS or os.environ.get("VESSELID_GENERIC_KERNELS"):
        return None
    key = (int(n), int(m), fac.tobytes(), eq.tobytes(), np.asarray(blocks).tobytes())
    with _LOCK:
        if key in _CACHE:
            kern = _CACHE[key]
            return None if kern is None or kern.failed else kern
        try:
            segs = _load(_source(int(n), int(m), np.asarray(fac), np.asarray(eq),
                                 np.asarray(blocks)))
        except (OSError, ImportError, SyntaxError) as exc:
            warnings.warn(f"cannot load a generated moment kernel ({exc}); using the generic "
                          "kernel", RuntimeWarning, stacklevel=2)
            segs = None
        kern = None if segs is None else SpecialisedMoments(segs)
        _CACHE[key] = kern
        return kern


def specialised_combined(
    n: int, m: int, fac: np.ndarray, eq: np.ndarray, ztype: np.ndarray, zpar: np.ndarray,
    zeq: np.ndarray
) -> SpecialisedMoments | None:
    """The specialised combined-instrument pass for this structure and column layout, or
    None (use :func:`vesselid.identify._ivkernels.combined_moments`).

    Call the result as ``kern(parallel, *args)`` with the arguments of
    ``combined_moments``; it returns False if the generated code could not be compiled.
    """
    if (ztype.shape[0] > MAX_COMBINED_COLUMNS or fac.shape[0] > MAX_SPECIALISED_PARAMS
            or os.environ.get("VESSELID_GENERIC_KERNELS")):
        return None
    arrays = [np.ascontiguousarray(a, dtype=np.int64) for a in (fac, eq, ztype, zpar, zeq)]
    key = ("combined", int(n), int(m), *(a.tobytes() for a in arrays))
    with _LOCK:
        if key in _CACHE:
            kern = _CACHE[key]
            return None if kern is None or kern.failed else kern
        try:
            segs = _load(_combined_source(int(n), int(m), *arrays))
        except (OSError, ImportError, SyntaxError) as exc:
            warnings.warn(f"cannot load a generated combined-instrument kernel ({exc}); using "
                          "the generic kernel", RuntimeWarning, stacklevel=2)
            segs = None
        kern = None if segs is None else SpecialisedMoments(segs)
        _CACHE[key] = kern
        return kern


def _clear() -> None:  # test helper
    with _LOCK:
        _CACHE.clear()
        _PRUNED.clear()
