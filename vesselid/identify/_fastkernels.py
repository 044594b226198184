"""Moment kernels specialised to one model structure (generated source, compiled once).

The generic kernel of :mod:`vesselid.identify.kernels` reads the factor layout of
every term from arrays at every sample. For a given structure — the number of
states ``n`` and inputs ``m``, the factor layout, the equations of the terms — this
module writes the same computation with all loops over states, inputs and terms
unrolled into scalar code (factors spelled through
:func:`vesselid.model.regressors.factor_source`), and compiles it with numba.

* The operations and their order are exactly those of the generic kernel (same
  auxiliary-model recursion, same divergence test, same accumulation order), so
  the two give bit-identical moments (tested on every catalogue structure); the
  specialised kernel only removes the indexing overhead (≈ 3–5× faster). Small
  structures keep one local scalar per accumulated product; larger ones
  (:data:`MAX_UNROLLED_PRODUCTS`) keep their sums in local arrays updated by loops,
  which compiles in seconds where the scalar form takes minutes.
* The generated module is written once per structure to a private per-user cache
  directory (:func:`kernel_dir`) and only rewritten if its text changes, so numba's
  on-disk cache of the compiled code stays valid across processes. Its file name is
  a digest of the source, the numba and Python versions and
  :data:`vesselid.model.regressors.SALT`, so an edit of the kernel module invalidates it.
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

from vesselid.model.regressors import SALT, factor_source

__all__ = [
    "MAX_KEPT_FILES",
    "MAX_SPECIALISED_PARAMS",
    "MAX_SPECIALISED_PRODUCTS",
    "MAX_UNROLLED_PRODUCTS",
    "PRUNE_AFTER_DAYS",
    "SpecialisedMoments",
    "kernel_dir",
    "moment_products",
    "prune",
    "specialised_combined",
    "specialised_moments",
]

#: Larger structures use the generic combined-instrument pass (unrolled code grows as P²).
MAX_SPECIALISED_PARAMS = 24

#: Moment structures whose distinct equation blocks accumulate more products ``z_p φ_q``
#: per sample (:func:`moment_products`) use the generic kernel (unrolled code grows as
#: their number): 24², one 24-term equation, so every structure of at most 24 parameters
#: qualifies; the 25-parameter CyberShip II sea-trial model (blocks 5, 10, 10, the last
#: two with the same terms) accumulates 125.
MAX_SPECIALISED_PRODUCTS = 24 * 24

#: Structures accumulating more products than this (:func:`moment_products`) keep their
#: sums in small local arrays updated by loops instead of one scalar per product: the
#: unrolled form's compile time grows faster than the square of its products (about a
#: minute of CPU for the CyberShip II sea-trial model's 125, minutes beyond), the looped
#: form's with the number of parameters (seconds; ``python scripts/bench.py --only
#: new_structure``). Both add the same products in the same order.
MAX_UNROLLED_PRODUCTS = 64

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
    (:func:`vesselid.model.regressors.factor_source`); None for the constant 1."""
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
    :func:`vesselid.core.threads.run_ranges` runs ranges on threads)."""
    add("")
    add("")
    add("@njit(cache=True, nogil=True)")
    add(f"def segments(lo, hi, {params}):")
    add("    for s in range(lo, hi):")
    add(f"        _segment(s, {args})")


def _duplicate_blocks(fac: np.ndarray, blocks: np.ndarray) -> list[int]:
    """For each equation, the first equation whose terms have the same factor codes (or
    itself): its regressors, instruments and so its ``S_zφ``, ``S_z``, ``S_φ`` block are
    the same numbers (the generic kernel copies them too, ``block_src``)."""
    keys = [np.asarray(fac[int(blocks[i]):int(blocks[i + 1])]).tobytes()
            for i in range(len(blocks) - 1)]
    return [keys.index(k) for k in keys]


def moment_products(fac: np.ndarray, blocks: np.ndarray) -> int:
    """Products ``z_p φ_q`` the specialised moment kernel accumulates per sample: the
    squared sizes of the distinct equation blocks (the size of its unrolled code)."""
    src = _duplicate_blocks(fac, blocks)
    return sum((int(blocks[i + 1]) - int(blocks[i])) ** 2
               for i in range(len(blocks) - 1) if src[i] == i)


#: Arguments of the generated moment kernel's ``_segment`` and ``segments``.
_MOMENT_ARGS = ("regsig, target, u, starts, group, theta, active, use_sim, limit, "
                "s_zphi, s_zy, s_z, s_phi, s_y, count, status")


def _moment_head(add: Callable[[str], None], title: str, n_par: int) -> None:
    """The start of a moment kernel's ``_segment``: its status, count, limit and the
    group's parameters ``th0 …``."""
    _head(add, title, (
        "def _segment(s, regsig, target, u, starts, group, theta, active, use_sim, limit,",
        "             s_zphi, s_zy, s_z, s_phi, s_y, count, status):"))
    add("    status[s] = 0")
    add("    count[s] = b - a - 1")
    add("    lim = limit[s]")
    for p in range(n_par):
        add(f"    th{p} = theta[g, {p}]")


def _moment_row(add: Callable[[str], None], ind: str, n: int, m: int, fac: np.ndarray,
                eq: np.ndarray, blocks: np.ndarray, src: list[int], needed: list[int],
                sim: bool) -> str:
    """The sample loop's head and row ``k``'s regressors ``phi…`` (those in ``needed``)
    and instruments ``z…`` (simulated when ``sim``, else the regressors; a duplicate
    block's from its source's); returns the indent of the loop body."""
    add(f"{ind}for k in range(a + 1, b):")
    i2 = ind + "    "
    _data_row(add, i2, n, (("d", 1),), m)
    for p in needed:
        add(f"{i2}phi{p} = {_term(p, 'd', n, m, fac)}")
    if sim:
        for i in range(n):
            add(f"{i2}ax{i} = abs(x{i})")
        _advance(add, i2, n, m, fac, eq, "z")
    else:
        for p in range(fac.shape[0]):
            i = int(eq[p])  # a duplicate block's regressor: its source's
            q = p + int(blocks[src[i]]) - int(blocks[i])
            add(f"{i2}z{p} = phi{q}")
    return i2


def _moment_layout(n: int, fac: np.ndarray, blocks: np.ndarray
                   ) -> tuple[int, list[list[int]], list[int], list[int]]:
    """The layout both moment-kernel generators share: the parameter count, each
    equation's parameters, each equation's source block (:func:`_duplicate_blocks`) and
    the regressors a distinct block accumulates (those only a duplicate block uses are
    never computed)."""
    blk = [list(range(int(blocks[i]), int(blocks[i + 1]))) for i in range(n)]
    src = _duplicate_blocks(fac, blocks)
    needed = [p for i in range(n) if src[i] == i for p in blk[i]]
    return fac.shape[0], blk, src, needed


def _source(n: int, m: int, fac: np.ndarray, eq: np.ndarray, blocks: np.ndarray) -> str:
    if moment_products(fac, blocks) > MAX_UNROLLED_PRODUCTS:
        return _looped_source(n, m, fac, eq, blocks)
    n_par, blk, src, needed = _moment_layout(n, fac, blocks)
    ind = " " * 8
    lines: list[str] = []
    add = lines.append
    _moment_head(add, "", n_par)
    for i in range(n):
        add(f"    x{i} = target[a, {i}]")
        add(f"    ly{i} = 0.0")

    def sums(i: int, p: int) -> list[tuple[str, str, str]]:
        """The local sums of parameter ``p`` (equation ``i``): name, increment, output
        (a duplicate block accumulates only ``S_zy``)."""
        if src[i] != i:
            return [(f"lzy{p}", f"z{p} * y{i}", f"s_zy[s, {p}]")]
        return ([(f"lzy{p}", f"z{p} * y{i}", f"s_zy[s, {p}]"),
                 (f"lz{p}", f"z{p}", f"s_z[s, {p}]"),
                 (f"lphi{p}", f"phi{p}", f"s_phi[s, {p}]")]
                + [(f"lzphi{p}_{q}", f"z{p} * phi{q}", f"s_zphi[s, {p}, {q}]") for q in blk[i]])

    for i in range(n):
        for p in blk[i]:
            for local, _, _ in sums(i, p):
                add(f"    {local} = 0.0")

    def body(sim: bool) -> None:
        i2 = _moment_row(add, ind, n, m, fac, eq, blocks, src, needed, sim)
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
        off = int(blocks[src[i]]) - int(blocks[i])
        for p in blk[i]:
            for local, _, out in sums(i, p):
                add(f"    {out} = {local}")
            if src[i] != i:  # copied from the first equation with these terms
                add(f"    s_z[s, {p}] = lz{p + off}")
                add(f"    s_phi[s, {p}] = lphi{p + off}")
                for q in blk[i]:
                    add(f"    s_zphi[s, {p}, {q}] = lzphi{p + off}_{q + off}")
            for q in range(n_par):
                if q not in blk[i]:  # another equation's regressor
                    add(f"    s_zphi[s, {p}, {q}] = 0.0")
        add(f"    s_y[s, {i}] = ly{i}")
    _entry_point(add, _MOMENT_ARGS, _MOMENT_ARGS)
    return "\n".join(lines) + "\n"


def _looped_source(n: int, m: int, fac: np.ndarray, eq: np.ndarray, blocks: np.ndarray) -> str:
    """:func:`_source` for large structures: the regressors, the auxiliary model and the
    divergence test unrolled as there, the sums of each distinct equation block in local
    arrays (``zy``, ``z``, ``φ`` and ``zφ``) updated by loops over the block. Every sum
    receives the same products in the same order as in the unrolled form and the
    generic kernel, so the moments are the same numbers; the code grows with the number
    of parameters, not with the products."""
    n_par, blk, src, needed = _moment_layout(n, fac, blocks)
    ind = " " * 8
    lines: list[str] = []
    add = lines.append
    _moment_head(add, " (looped sums)", n_par)
    for i in range(n):
        size = len(blk[i])
        add(f"    x{i} = target[a, {i}]")
        add(f"    ly{i} = 0.0")
        add(f"    azy{i} = np.zeros({size})")
        add(f"    zv{i} = np.empty({size})")
        if src[i] == i:
            add(f"    az{i} = np.zeros({size})")
            add(f"    aphi{i} = np.zeros({size})")
            add(f"    azphi{i} = np.zeros(({size}, {size}))")
            add(f"    pv{i} = np.empty({size})")

    def body(sim: bool) -> None:
        i2 = _moment_row(add, ind, n, m, fac, eq, blocks, src, needed, sim)
        for i in range(n):
            add(f"{i2}y{i} = target[k, {i}]")
            add(f"{i2}ly{i} += y{i}")
            for j, p in enumerate(blk[i]):
                add(f"{i2}zv{i}[{j}] = z{p}")
                if src[i] == i:
                    add(f"{i2}pv{i}[{j}] = phi{p}")
            add(f"{i2}for jj in range({len(blk[i])}):")
            add(f"{i2}    zj = zv{i}[jj]")
            add(f"{i2}    azy{i}[jj] += zj * y{i}")
            if src[i] == i:
                add(f"{i2}    az{i}[jj] += zj")
                add(f"{i2}    aphi{i}[jj] += pv{i}[jj]")
                add(f"{i2}    for qq in range({len(blk[i])}):")
                add(f"{i2}        azphi{i}[jj, qq] += zj * pv{i}[qq]")

    add("    if use_sim:")
    body(True)
    add("    else:")
    body(False)
    for i in range(n):
        lo, size, o = int(blocks[i]), len(blk[i]), src[i]
        add(f"    for jj in range({size}):")
        add(f"        s_zy[s, {lo} + jj] = azy{i}[jj]")
        add(f"        s_z[s, {lo} + jj] = az{o}[jj]")
        add(f"        s_phi[s, {lo} + jj] = aphi{o}[jj]")
        add(f"        for qq in range({n_par}):")  # another equation's regressor
        add(f"            s_zphi[s, {lo} + jj, qq] = 0.0")
        add(f"        for qq in range({size}):")
        add(f"            s_zphi[s, {lo} + jj, {lo} + qq] = azphi{o}[jj, qq]")
        add(f"    s_y[s, {i}] = ly{i}")
    _entry_point(add, _MOMENT_ARGS, _MOMENT_ARGS)
    return "\n".join(lines) + "\n"


#: Larger combined instrument sets use the generic kernel (unrolled code grows as K²).
MAX_COMBINED_COLUMNS = 16


def _hac_window(add: Callable[[str], None], ind: str, pre: str, lags: str, k: int,
                pairs: list[tuple[int, int]], entering: bool,
                score: Callable[[int], str]) -> None:
    """Slide a Bartlett HAC window (a ring of ``lags + 1`` scores, names prefixed ``pre``)
    one sample: the new scores ``score(c)`` enter (or, draining at the end, zeros), the
    oldest leave; accumulate ``h hᵀ`` over ``pairs``."""
    add(f"{ind}{pre}slot = {pre}cnt % ({lags} + 1)")
    for c in range(k):
        if entering:
            add(f"{ind}{pre}sc{c} = {score(c)}")
            add(f"{ind}{pre}h{c} += {pre}sc{c} - {pre}ring[{pre}slot, {c}]")
            add(f"{ind}{pre}ring[{pre}slot, {c}] = {pre}sc{c}")
        else:
            add(f"{ind}{pre}h{c} -= {pre}ring[{pre}slot, {c}]")
            add(f"{ind}{pre}ring[{pre}slot, {c}] = 0.0")
    add(f"{ind}{pre}cnt += 1")
    for c, c2 in pairs:
        add(f"{ind}{pre}lh{c}_{c2} += {pre}h{c} * {pre}h{c2}")


class _ColourCode:
    """Generated code of the colour test fused into the combined pass (run when the
    kernel's ``colour`` argument is true; :func:`vesselid.identify.gmm.combined_solution`).

    Per equation the instruments are the simulated regressors ``ζ`` (the combined
    set's type-0 columns) and, per state term, the mean of the estimated regressor
    noise ``η = φ − ζ`` over the rows ``k − hi … k − lo`` of the experiment
    (:func:`vesselid.identify.gmm.noise_instruments`): a running window sum over a
    ring of the last ``whi + 1`` values of ``η``, from row ``a + 1``. Rows
    ``k ≥ a + 1 + hi`` enter. First pass (``second`` false): the sums ``Σ z φᵀ``,
    ``Σ z y``, ``Σ z zᵀ`` (within each equation's block), ``Σ z``, ``Σ φ``, ``Σ y`` and
    the count, of the differences from the first entering row's values (``c_ref``;
    centring raw sums lost up to two digits of Hansen's J to the signals' means);
    second pass: the Bartlett long-run variance of the centred scores with
    the first-step estimate ``ctheta1`` (moving sums over a ring of ``L + 1`` scores,
    ``L = min(lags, b − a − 1)``, drained at the end as
    :func:`vesselid.identify.gmm.hac_sums`). A segment whose auxiliary model diverges
    contributes nothing (the explicit test's rows are all invalid there).
    """

    def __init__(self, fac, eq, ztype, zpar, ckind, cpar, ceq) -> None:
        n_par = fac.shape[0]
        sim = {int(zpar[c]): c for c in range(ztype.shape[0]) if int(ztype[c]) == 0}
        self.n_par = n_par
        self.eq = [int(e) for e in eq]
        self.k = int(ckind.shape[0])
        self.ceq = [int(e) for e in ceq]
        # per colour column: its value's expression; the noise terms (η index, term)
        self.terms = [int(cpar[c]) for c in range(self.k) if int(ckind[c]) == 1]
        self.sim_of = sim
        self.value = []
        for c in range(self.k):
            p = int(cpar[c])
            self.value.append(f"z{sim[p]}" if int(ckind[c]) == 0
                              else f"w{self.terms.index(p)}")
        self.block = [[c2 for c2 in range(self.k) if self.ceq[c2] == self.ceq[c]]
                      for c in range(self.k)]
        self.own = [[p for p in range(n_par) if self.eq[p] == self.ceq[c]]
                    for c in range(self.k)]
        self.n_eq = max(self.eq) + 1

    def _refs(self) -> list[str]:
        """Names of the first pass's reference values (the first entering row's): the sums
        are of the differences from them, so that centring them loses no digits to a
        large mean."""
        return ([f"rv{c}" for c in range(self.k)] + [f"rphi{p}" for p in range(self.n_par)]
                + [f"ry{i}" for i in range(self.n_eq)])

    def _pairs(self) -> list[tuple[int, int]]:
        return [(c, c2) for c in range(self.k) for c2 in self.block[c] if c2 >= c]

    def _sums(self) -> list[tuple[str, str]]:
        """The first pass's sums and what each entering row adds to them (of the
        differences ``d…`` from the reference values), in the order they are written."""
        out: list[tuple[str, str]] = []
        for c in range(self.k):
            out += [(f"cb{c}", f"drv{c} * dry{self.ceq[c]}"), (f"cz{c}", f"drv{c}")]
            out += [(f"ca{c}_{p}", f"drv{c} * drphi{p}") for p in self.own[c]]
        out += [(f"cm{c}_{c2}", f"drv{c} * drv{c2}") for c, c2 in self._pairs()]
        out += [(f"cphi{p}", f"drphi{p}") for p in range(self.n_par)]
        out += [(f"cy{i}", f"dry{i}") for i in range(self.n_eq)]
        return out

    def start(self, add: Callable[[str], None], ind: str, *, second: bool) -> None:
        # every name is bound whatever ``colour`` (numba types each once); the inputs of
        # the second pass are read only when the colour test runs
        add(f"{ind}ering = np.zeros((whi + 1, {max(len(self.terms), 1)}))")
        add(f"{ind}width = whi - wlo + 1.0")
        add(f"{ind}ccnt = 0")
        for j in range(len(self.terms)):
            add(f"{ind}ws{j} = 0.0")
        if not second:
            for name, _ in self._sums():
                add(f"{ind}{name} = 0.0")
            for name in self._refs():
                add(f"{ind}{name} = 0.0")
            return
        add(f"{ind}clag = min(lags, b - a - 1)")
        add(f"{ind}cring = np.zeros((clag + 1, {self.k}))")
        # (the caller passes zeros of the full shapes when the test does not run)
        for p in range(self.n_par):
            add(f"{ind}ct{p} = ctheta1[g, {p}]")
            add(f"{ind}cmphi{p} = cmeans_phi[s, {p}]")
        for i in range(self.n_eq):
            add(f"{ind}cmy{i} = cmeans_y[s, {i}]")
        for c in range(self.k):
            add(f"{ind}cmz{c} = cmeans_z[s, {c}]")
            add(f"{ind}cmg{c} = cmeans_g[s, {c}]")
            add(f"{ind}ch{c} = 0.0")
        for c, c2 in self._pairs():
            add(f"{ind}clh{c}_{c2} = 0.0")

    def row(self, add: Callable[[str], None], ind: str, *, second: bool) -> None:
        add(f"{ind}if colour:")
        i2 = ind + "    "
        # the noise window: ws = Σ_{d=lo}^{hi} η(k − d) over the experiment's rows
        add(f"{i2}ce = k - a - 1")
        add(f"{i2}cold = ce % (whi + 1)")
        add(f"{i2}if ce >= wlo:")
        add(f"{i2}    cnew = (ce - wlo) % (whi + 1)")
        for j in range(len(self.terms)):
            add(f"{i2}    ws{j} += ering[cnew, {j}]")
        add(f"{i2}if ce > whi:")
        for j in range(len(self.terms)):
            add(f"{i2}    ws{j} -= ering[cold, {j}]")
        for j, p in enumerate(self.terms):
            add(f"{i2}ering[cold, {j}] = phi{p} - z{self.sim_of[p]}")
        add(f"{i2}if ce >= whi:")
        i3 = i2 + "    "
        for j in range(len(self.terms)):
            add(f"{i3}w{j} = ws{j} / width")
        if not second:
            values = ([self.value[c] for c in range(self.k)]
                      + [f"phi{p}" for p in range(self.n_par)]
                      + [f"target[k, {i}]" for i in range(self.n_eq)])
            add(f"{i3}if ce == whi:")
            for name, v in zip(self._refs(), values, strict=True):
                add(f"{i3}    {name} = {v}")
            for name, v in zip(self._refs(), values, strict=True):
                add(f"{i3}d{name} = {v} - {name}")
            add(f"{i3}ccnt += 1")
            for name, increment in self._sums():
                add(f"{i3}{name} += {increment}")
            return
        for i in range(self.n_eq):
            add(f"{i3}ec{i} = target[k, {i}] - cmy{i}")
        for p in range(self.n_par):
            add(f"{i3}ec{self.eq[p]} -= (phi{p} - cmphi{p}) * ct{p}")
        self._window(add, i3, True)

    def _window(self, add: Callable[[str], None], ind: str, entering: bool) -> None:
        _hac_window(add, ind, "c", "clag", self.k, self._pairs(), entering,
                    lambda c: f"({self.value[c]} - cmz{c}) * ec{self.ceq[c]} - cmg{c}")

    def finish(self, add: Callable[[str], None], ind: str, *, second: bool) -> None:
        add(f"{ind}if colour and status[s] == 0:")
        i2 = ind + "    "
        if not second:
            add(f"{i2}c_count[s] = ccnt")
            for c in range(self.k):
                add(f"{i2}c_b[s, {c}] = cb{c}")
                add(f"{i2}c_z[s, {c}] = cz{c}")
                for p in self.own[c]:
                    add(f"{i2}c_a[s, {c}, {p}] = ca{c}_{p}")
            for c, c2 in self._pairs():  # upper triangles (the caller mirrors them)
                add(f"{i2}c_m[s, {c}, {c2}] = cm{c}_{c2}")
            for p in range(self.n_par):
                add(f"{i2}c_phi[s, {p}] = cphi{p}")
            for i in range(self.n_eq):
                add(f"{i2}c_y[s, {i}] = cy{i}")
            for j, name in enumerate(self._refs()):
                add(f"{i2}c_ref[s, {j}] = {name}")
            return
        add(f"{i2}for _ in range(clag):")
        self._window(add, i2 + "    ", False)
        for c, c2 in self._pairs():
            add(f"{i2}c_hac[s, {c}, {c2}] = clh{c}_{c2} / (clag + 1.0)")


def _combined_source(n: int, m: int, fac: np.ndarray, eq: np.ndarray, ztype: np.ndarray,
                     zpar: np.ndarray, zeq: np.ndarray, ckind: np.ndarray, cpar: np.ndarray,
                     ceq: np.ndarray) -> str:
    """Source of the combined-instrument pass of
    :func:`vesselid.identify._ivkernels.combined_moments` for one structure and column
    layout, unrolled (same operations, same order: bit-identical), with the optional
    fused colour test (:func:`_colour_code`; ``ckind``, ``cpar``, ``ceq``: its column
    layout, :func:`vesselid.identify.gmm._colour_layout`)."""
    n_par, k_tot = fac.shape[0], ztype.shape[0]
    colour = _ColourCode(fac, eq, ztype, zpar, ckind, cpar, ceq)
    lag_sig = {0: "x", 2: "l", 3: "o"}
    own = [[p for p in range(n_par) if int(eq[p]) == int(zeq[c])] for c in range(k_tot)]
    # data signals of row k: at k−1 (φ) and, for columns of type 2 / 3 (lagged
    # instruments), at k−2 / k−3
    lags = (("d", 1), *((sig, lag) for sig, lag in (("l", 2), ("o", 3)) if (ztype == lag).any()))
    lines: list[str] = []
    add = lines.append

    def load_row(ind: str, early: bool = False) -> None:
        # data signals, regressors φ and instruments z of row k (x̂(k−1) and u(k−1) are
        # loaded by inputs_and_state); ``early`` (rows a+1, a+2, colour test only): no
        # delayed columns
        _data_row(add, ind, n, (("d", 1),) if early else lags)
        for p in range(n_par):
            add(f"{ind}phi{p} = {_term(p, 'd', n, m, fac)}")
        for c in range(k_tot):
            if not early or int(ztype[c]) == 0:
                add(f"{ind}z{c} = {_term(int(zpar[c]), lag_sig[int(ztype[c])], n, m, fac)}")

    def rows_before_delays(ind: str) -> None:
        # the colour test's noise window starts at row a + 1
        add(f"{ind}elif colour:")
        load_row(ind + "    ", early=True)

    def window_step(ind: str, entering: bool) -> None:
        _hac_window(add, ind, "", "lags", k_tot,
                    [(c, c2) for c in range(k_tot) for c2 in range(c, k_tot)], entering,
                    lambda c: f"(z{c} - mz{c}) * e{int(zeq[c])} - mg{c}")

    def inputs_and_state(ind: str) -> None:
        _data_row(add, ind, 0, (), m)
        for i in range(n):
            add(f"{ind}ax{i} = abs(x{i})")

    _head(add, " (combined instruments)", (
        "def _segment(s, regsig, target, u, starts, group, theta, active, limit, second,",
        "             theta1, means_z, means_phi, means_y, means_g, lags, s_a, s_b, s_m, s_z,",
        "             s_phi, s_y, count, status, s_hac, colour, window, c_in, c_out):"))
    # (tuples: a call of more than 30 arguments compiles to CALL_FUNCTION_EX, which
    # numba cannot inline)
    add("    wlo, whi = window")
    add("    ctheta1, cmeans_z, cmeans_phi, cmeans_y, cmeans_g = c_in")
    add("    c_a, c_b, c_m, c_z, c_phi, c_y, c_count, c_hac, c_ref = c_out")
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
    colour.start(add, ind, second=False)
    add(f"{ind}for k in range(a + 1, b):")
    i2 = ind + "    "
    inputs_and_state(i2)
    add(f"{i2}if k >= a + 3:")
    i3 = i2 + "    "
    load_row(i3)
    add(f"{i3}cnt += 1")
    for local, inc, _ in sums:
        add(f"{i3}{local} += {inc}")
    rows_before_delays(i2)
    colour.row(add, i2, second=False)
    _advance(add, i2, n, m, fac, eq, "q")
    add(f"{ind}count[s] = cnt")
    for local, _, outs in sums:
        for out in outs:
            add(f"{ind}{out} = {local}")
    for c in range(k_tot):
        for p in range(n_par):
            if p not in own[c]:  # another equation's regressor
                add(f"{ind}s_a[s, {c}, {p}] = 0.0")
    colour.finish(add, ind, second=False)
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
    colour.start(add, ind, second=True)
    add(f"{ind}for k in range(a + 1, b):")
    inputs_and_state(i2)
    add(f"{i2}if k >= a + 3:")
    load_row(i3)
    for i in range(n):
        add(f"{i3}e{i} = target[k, {i}] - my{i}")
    for p in range(n_par):
        add(f"{i3}e{int(eq[p])} -= (phi{p} - mphi{p}) * t{p}")
    window_step(i3, True)
    rows_before_delays(i2)
    colour.row(add, i2, second=True)
    _advance(add, i2, n, m, fac, eq, "q")
    add(f"{ind}for _ in range(lags):")
    window_step(i2, False)
    for c in range(k_tot):
        for c2 in range(c, k_tot):
            add(f"{ind}s_hac[s, {c}, {c2}] = lh{c}_{c2} / (lags + 1.0)")
            add(f"{ind}s_hac[s, {c2}, {c}] = s_hac[s, {c}, {c2}]")
    colour.finish(add, ind, second=True)
    colour_args = "colour, window, c_in, c_out"
    args = ("regsig, target, u, starts, group, theta, active, limit, second, theta1, "
            "means_z, means_phi, means_y, means_g, lags, s_a, s_b, s_m, s_z, s_phi, s_y, "
            "count, status, s_hac, " + colour_args)
    full = ("regsig, target, u, starts, group, theta, active, fac, eq, ztype, zpar, zeq, "
            "limit, second, theta1, means_z, means_phi, means_y, means_g, lags, s_a, s_b, "
            "s_m, s_z, s_phi, s_y, count, status, s_hac, " + colour_args)
    # the two passes as two functions compiled apart (not inlined into one): LLVM's time
    # grows faster than the code, and one function of both passes took 2.4x as long to
    # compile as the two halves
    i_if = lines.index("    if not second:")
    i_else = lines.index("    else:", i_if)
    common = lines[:i_if]
    d_line = common.index("@njit(cache=True, inline='always')")
    common[d_line] = "@njit(cache=True, nogil=True)"
    first = [*common, *lines[i_if:i_else]]
    second = [*common, "    if second:", *lines[i_else + 1:]]
    first[d_line + 1] = first[d_line + 1].replace("def _segment(s, ", "def _first(lo, hi, ")
    second[d_line + 1] = second[d_line + 1].replace("def _segment(s, ",
                                                    "def _second(lo, hi, ")
    second[0:d_line] = ["", ""]
    lines[:] = [*_over_segments(first), *_over_segments(second)]
    # the entry point is Python, not a third compiled function: a compiled ``segments``
    # calling both passes links and optimises their code again (≈ 0.5 s of CPU on the
    # first run, measured with numba's compile events)
    add("")
    add("")
    add(f"def segments(lo, hi, {full}):")
    add('    """Pass 1 (``second`` false) or 2 over the segments ``lo .. hi - 1``."""')
    add("    if second:")
    add(f"        _second(lo, hi, {args})")
    add("    else:")
    add(f"        _first(lo, hi, {args})")
    add("")
    add("")
    add("segments.kernels = (_first, _second)")
    return "\n".join(lines) + "\n"


def _over_segments(lines: list[str]) -> list[str]:
    """A generated per-segment function (body from ``g = group[s]``) as a loop over the
    segments ``lo .. hi - 1``: the body indented once more, its early ``return`` (an
    inactive group) a ``continue``."""
    start = lines.index("    g = group[s]")
    body = ["        continue" if line == "        return" else line
            for line in lines[start:]]
    return [*lines[:start], "    for s in range(lo, hi):",
            *(("    " + line) if line.strip() else line for line in body)]




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
        from vesselid.core.fileio import atomic_write_text

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
    threads when ``parallel``, :func:`vesselid.core.threads.run_ranges`) and returns True.
    If numba fails to compile the generated code at its first call, it warns once,
    disables itself and returns False, and the caller runs the generic kernel instead.
    Errors of an already compiled kernel propagate.
    """

    def __init__(self, segments: Callable) -> None:
        self.kernel = segments
        self.failed = False
        #: every compiled kernel has a signature (numba keeps it): the check below, which
        #: costs numba's signature list on every call, is done until it first holds
        self.compiled = False

    def __call__(self, parallel: bool, *args) -> bool:
        if self.failed:
            return False
        fn = self.kernel
        # a generated Python entry point names its compiled kernels (compiled on first use)
        if not self.compiled and not all(getattr(k, "signatures", ())
                                         for k in getattr(fn, "kernels", (fn,))):
            try:
                fn(0, 0, *args)  # compile here, in the calling thread, over no segment
            except Exception as exc:
                self.failed = True
                warnings.warn(f"generated moment kernel failed to compile "
                              f"({type(exc).__name__}: "
                              f"{str(exc).splitlines()[0] if str(exc) else ''}); using the "
                              "generic kernel", RuntimeWarning, stacklevel=3)
                return False
        self.compiled = True
        from vesselid.core.threads import run_ranges

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
    if (moment_products(fac, blocks) > MAX_SPECIALISED_PRODUCTS
            or os.environ.get("VESSELID_GENERIC_KERNELS")):
        return None
    key = (int(n), int(m), fac.tobytes(), eq.tobytes(), np.asarray(blocks).tobytes())
    return _cached_kernel(key, "moment", lambda: _source(
        int(n), int(m), np.asarray(fac), np.asarray(eq), np.asarray(blocks)))


def specialised_combined(
    n: int, m: int, fac: np.ndarray, eq: np.ndarray, ztype: np.ndarray, zpar: np.ndarray,
    zeq: np.ndarray, ckind: np.ndarray, cpar: np.ndarray, ceq: np.ndarray
) -> SpecialisedMoments | None:
    """The specialised combined-instrument pass for this structure and column layout
    (with the fused colour test of the colour layout ``ckind``, ``cpar``, ``ceq``), or
    None (use :func:`vesselid.identify._ivkernels.combined_moments`, and the explicit
    colour test).

    Call the result as ``kern(parallel, *args, *colour_args)`` with the arguments of
    ``combined_moments`` and the colour test's (``colour`` false: none computed); it
    returns False if the generated code could not be compiled.
    """
    if (max(ztype.shape[0], ckind.shape[0]) > MAX_COMBINED_COLUMNS
            or fac.shape[0] > MAX_SPECIALISED_PARAMS
            or os.environ.get("VESSELID_GENERIC_KERNELS")):
        return None
    arrays = [np.ascontiguousarray(a, dtype=np.int64)
              for a in (fac, eq, ztype, zpar, zeq, ckind, cpar, ceq)]
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
