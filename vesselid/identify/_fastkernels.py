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


# Pieces of generated code shared by the two generators below (each writes lines with
# ``add``; the generated text, and so the numba cache, is what it was before they shared).
def _term(p: int, sig: str, n: int, m: int, fac: np.ndarray) -> str:
    """Regressor ``p`` of the signals named ``sig`` (``d``: data, ``x``: simulated)."""
    return _product(_factor(int(fac[p, 0]), n, m, sig), _factor(int(fac[p, 1]), n, m, sig))


def _head(add: Callable[[str], None], title: str, signature: tuple[str, ...]) -> None:
    """Docstring, imports and the start of ``_segment`` (its group and sample range)."""
    add(f'"""Generated by vesselid.identify._fastkernels{title}; do not edit."""')
    add("import numpy as np")
    add("from numba import njit")
    add("")
    add("")
    add("@njit(cache=True, inline='always')")
    for line in signature:
        add(line)
    add("    g = group[s]")
    add("    if not active[g]:")
    add("        return")
    add("    a = starts[s]")
    add("    b = starts[s + 1]")


def _data_row(add: Callable[[str], None], ind: str, n: int, lags: tuple[tuple[str, int], ...],
              m: int = 0) -> None:
    """Row ``k``'s data signals (named, delayed by ``lags``) with their moduli, then
    (``m``) the inputs ``u(k−1)``."""
    for i in range(n):
        for sig, lag in lags:
            add(f"{ind}{sig}{i} = regsig[k - {lag}, {i}]")
            add(f"{ind}a{sig}{i} = abs({sig}{i})")
    for j in range(m):
        add(f"{ind}v{j} = u[k - 1, {j}]")
        add(f"{ind}av{j} = abs(v{j})")


def _advance(add: Callable[[str], None], ind: str, n: int, m: int, fac: np.ndarray,
             eq: np.ndarray, z: str) -> None:
    """The simulated regressors (named ``z``) and the one-step update ``x = Φᵀθ``
    (summed in parameter order), leaving the segment's loop if ``x`` leaves the limit."""
    for p in range(fac.shape[0]):
        add(f"{ind}{z}{p} = {_term(p, 'x', n, m, fac)}")
    for i in range(n):
        expr = "0.0"
        for p in range(fac.shape[0]):
            if int(eq[p]) == i:
                expr = f"({expr} + th{p} * {z}{p})"
        add(f"{ind}x{i} = {expr}")
    cond = " or ".join(f"not (abs(x{i}) <= lim)" for i in range(n))
    add(f"{ind}if {cond}:")
    add(f"{ind}    status[s] = 1")
    add(f"{ind}    break")


def _entry_point(add: Callable[[str], None], params: str, args: str) -> None:
    """``segments``: ``_segment`` over the segments ``lo .. hi - 1`` (serial, ``nogil``;
    :func:`vesselid._threads.run_ranges` runs ranges on threads)."""
    add("")
    add("")
    add("@njit(cache=True, nogil=True)")
    add(f"def segments(lo, hi, {params}):")
    add("    for s in range(lo, hi):")
    add(f"        _segment(s, {args})")


def _source(n: int, m: int, fac: np.ndarray, eq: np.ndarray, blocks: np.ndarray) -> str:
    n_par = fac.shape[0]
    blk = [list(range(int(blocks[i]), int(blocks[i + 1]))) for i in range(n)]
    ind = " " * 8
    lines: list[str] = []
    add = lines.append
    _head(add, "", (
        "def _segment(s, regsig, target, u, starts, group, theta, active, use_sim, limit,",
        "             s_zphi, s_zy, s_z, s_phi, s_y, count, status):"))
    add("    status[s] = 0")
    add("    count[s] = b - a - 1")
    add("    lim = limit[s]")
    for p in range(n_par):
        add(f"    th{p} = theta[g, {p}]")
    for i in range(n):
        add(f"    x{i} = target[a, {i}]")
        add(f"    ly{i} = 0.0")

    def sums(i: int, p: int) -> list[tuple[str, str, str]]:
        """The local sums of parameter ``p`` (equation ``i``): name, increment, output."""
        return ([(f"lzy{p}", f"z{p} * y{i}", f"s_zy[s, {p}]"),
                 (f"lz{p}", f"z{p}", f"s_z[s, {p}]"),
                 (f"lphi{p}", f"phi{p}", f"s_phi[s, {p}]")]
                + [(f"lzphi{p}_{q}", f"z{p} * phi{q}", f"s_zphi[s, {p}, {q}]") for q in blk[i]])

    for i in range(n):
        for p in blk[i]:
            for local, _, _ in sums(i, p):
                add(f"    {local} = 0.0")

    def body(sim: bool) -> None:
        add(f"{ind}for k in range(a + 1, b):")
        i2 = ind + "    "
        _data_row(add, i2, n, (("d", 1),), m)
        for p in range(n_par):
            add(f"{i2}phi{p} = {_term(p, 'd', n, m, fac)}")
        if sim:
            for i in range(n):
                add(f"{i2}ax{i} = abs(x{i})")
            _advance(add, i2, n, m, fac, eq, "z")
        else:
            for p in range(n_par):
                add(f"{i2}z{p} = phi{p}")
        for i in range(n):
            add(f"{i2}y{i} = target[k, {i}]")
            add(f"{i2}ly{i} += y{i}")
            for p in blk[i]:
                for local, inc, _ in sums(i, p):
                    add(f"{i2}{local} += {inc}")

    add("    if use_sim:")
    body(True)
    add("    else:")
    body(False)
    for i in range(n):
        for p in blk[i]:
            for local, _, out in sums(i, p):
                add(f"    {out} = {local}")
            for q in range(n_par):
                if q not in blk[i]:  # another equation's regressor
                    add(f"    s_zphi[s, {p}, {q}] = 0.0")
        add(f"    s_y[s, {i}] = ly{i}")
    args = ("regsig, target, u, starts, group, theta, active, use_sim, limit, "
            "s_zphi, s_zy, s_z, s_phi, s_y, count, status")
    _entry_point(add, args, args)
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
    # data signals of row k: at k−1 (φ) and, for columns of type 2 / 3 (lagged
    # instruments), at k−2 / k−3
    lags = (("d", 1), *((sig, lag) for sig, lag in (("l", 2), ("o", 3)) if (ztype == lag).any()))
    lines: list[str] = []
    add = lines.append

    def load_row(ind: str) -> None:
        # data signals, regressors φ and instruments z of row k (x̂(k−1) and u(k−1) are
        # loaded by inputs_and_state)
        _data_row(add, ind, n, lags)
        for p in range(n_par):
            add(f"{ind}phi{p} = {_term(p, 'd', n, m, fac)}")
        for c in range(k_tot):
            add(f"{ind}z{c} = {_term(int(zpar[c]), lag_sig[int(ztype[c])], n, m, fac)}")

    def window_step(ind: str, entering: bool) -> None:
        # slide the HAC window (a ring of lags + 1 scores) one sample: the new scores sc
        # enter (or, draining at the end, zeros), the oldest leave; accumulate h hᵀ
        add(f"{ind}slot = cnt % (lags + 1)")
        for c in range(k_tot):
            if entering:
                add(f"{ind}sc{c} = (z{c} - mz{c}) * e{int(zeq[c])} - mg{c}")
                add(f"{ind}h{c} += sc{c} - ring[slot, {c}]")
                add(f"{ind}ring[slot, {c}] = sc{c}")
            else:
                add(f"{ind}h{c} -= ring[slot, {c}]")
                add(f"{ind}ring[slot, {c}] = 0.0")
        add(f"{ind}cnt += 1")
        for c in range(k_tot):
            for c2 in range(c, k_tot):
                add(f"{ind}lh{c}_{c2} += h{c} * h{c2}")

    def inputs_and_state(ind: str) -> None:
        _data_row(add, ind, 0, (), m)
        for i in range(n):
            add(f"{ind}ax{i} = abs(x{i})")

    _head(add, " (combined instruments)", (
        "def _segment(s, regsig, target, u, starts, group, theta, active, limit, second,",
        "             theta1, means_z, means_phi, means_y, means_g, lags, s_a, s_b, s_m, s_z,",
        "             s_phi, s_y, count, status, s_hac):"))
    add("    lim = limit[s]")
    for p in range(n_par):
        add(f"    th{p} = theta[g, {p}]")
    add("    status[s] = 0")
    for i in range(n):
        add(f"    x{i} = target[a, {i}]")
    add("    cnt = 0")
    add("    if not second:")
    ind = " " * 8
    # the local sums of the first pass: name, increment and outputs
    sums: list[tuple[str, str, tuple[str, ...]]] = []
    for c in range(k_tot):
        sums += [(f"lb{c}", f"z{c} * target[k, {int(zeq[c])}]", (f"s_b[s, {c}]",)),
                 (f"lz{c}", f"z{c}", (f"s_z[s, {c}]",))]
        sums += [(f"la{c}_{p}", f"z{c} * phi{p}", (f"s_a[s, {c}, {p}]",)) for p in own[c]]
        sums += [(f"lm{c}_{c2}", f"z{c} * z{c2}", (f"s_m[s, {c}, {c2}]", f"s_m[s, {c2}, {c}]"))
                 for c2 in range(c, k_tot)]
    sums += [(f"lphi{p}", f"phi{p}", (f"s_phi[s, {p}]",)) for p in range(n_par)]
    sums += [(f"ly{i}", f"target[k, {i}]", (f"s_y[s, {i}]",)) for i in range(n)]
    for local, _, _ in sums:
        add(f"{ind}{local} = 0.0")
    add(f"{ind}for k in range(a + 1, b):")
    i2 = ind + "    "
    inputs_and_state(i2)
    add(f"{i2}if k >= a + 3:")
    i3 = i2 + "    "
    load_row(i3)
    add(f"{i3}cnt += 1")
    for local, inc, _ in sums:
        add(f"{i3}{local} += {inc}")
    _advance(add, i2, n, m, fac, eq, "q")
    add(f"{ind}count[s] = cnt")
    for local, _, outs in sums:
        for out in outs:
            add(f"{ind}{out} = {local}")
    for c in range(k_tot):
        for p in range(n_par):
            if p not in own[c]:  # another equation's regressor
                add(f"{ind}s_a[s, {c}, {p}] = 0.0")
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
    window_step(i3, True)
    _advance(add, i2, n, m, fac, eq, "q")
    add(f"{ind}for _ in range(lags):")
    window_step(i2, False)
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
    _entry_point(add, full, args)
    return "\n".join(lines) + "\n"




def _load(source: str) -> Callable | None:
    """Write (if needed), check and import the generated module; None if not possible."""
    import numba

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
    return _cached_kernel(key, "moment", lambda: _source(
        int(n), int(m), np.asarray(fac), np.asarray(eq), np.asarray(blocks)))


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
    return _cached_kernel(key, "combined-instrument",
                          lambda: _combined_source(int(n), int(m), *arrays))


def _cached_kernel(key: tuple, what: str,
                   source: Callable[[], str]) -> SpecialisedMoments | None:
    """The kernels of ``key``, generated from ``source()`` and loaded on first use (once
    per process); None when they cannot be loaded or failed to compile (then the caller
    runs the generic kernel)."""
    with _LOCK:
        if key in _CACHE:
            kern = _CACHE[key]
            return None if kern is None or kern.failed else kern
        try:
            segs = _load(source())
        except (OSError, ImportError, SyntaxError) as exc:
            warnings.warn(f"cannot load a generated {what} kernel ({exc}); using the generic "
                          "kernel", RuntimeWarning, stacklevel=3)
            segs = None
        kern = None if segs is None else SpecialisedMoments(segs)
        _CACHE[key] = kern
        return kern


def _clear() -> None:  # test helper
    with _LOCK:
        _CACHE.clear()
        _PRUNED.clear()
