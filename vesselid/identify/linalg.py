"""The linear algebra of the estimators, in one place: batched solves and rank checks.

Every estimator solves small square (``P × P``) or over-identified (``K × P``)
systems, one per parameter group (a Monte Carlo run) and state equation. These
helpers solve whole stacks at once and flag — never raise on — singular or
non-finite systems, so one bad run cannot stop a study; the checked ``fit`` path
turns the flags into clear errors.

* :func:`solve` — ``A θ = b`` for a stack of square systems (IV (4), LS (16)).
* :func:`gmm_solve` — ``θ = (AᵀWA)⁻¹ AᵀW b`` for a stack of over-identified moment
  equations ``A = Σ z φᵀ``, ``b = Σ z y`` with weight ``W`` (2SLS: ``W = (Σ z zᵀ)⁻¹``;
  two-step GMM: ``W = Ŝ⁻¹``).
* :func:`inv_sym` — inverse of a stack of symmetric positive (semi)definite matrices.
* :func:`condition_number` — of the row- and column-equilibrated matrix (instrument strength).
* :func:`equilibrate` — row and column scales that remove the units of a matrix.

Units never matter: every rank/condition decision is taken on equilibrated matrices
and the solves scale columns (exactly, by powers of two), so multiplying every
signal by 10^±6 changes the estimates only by rounding.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

__all__ = ["COND_MAX", "condition_number", "equilibrate", "gmm_solve", "inv_sym", "one_blas_thread",
           "pin_blas_to_one_thread", "pow2_scale", "solve", "solve_rows",
           "stacked_row_weights"]

#: Systems whose (equilibrated) condition number exceeds this are treated as singular.
COND_MAX = 1e15


def pow2_scale(norms: np.ndarray) -> np.ndarray:
    """Powers of two ``2^-e`` with ``norms · 2^-e`` in ``[0.5, 1)``; 1 where a norm is 0,
    not finite or would leave the exponent range.

    Scaling by a power of two is exact in floating point, so a column-scaled system is
    solved with bit-identical rounding to the unscaled one (LU with partial pivoting
    picks its pivots within columns) while the scale decisions no longer depend on units.
    """
    norms = np.asarray(norms, dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):
        _, e = np.frexp(np.where(np.isfinite(norms) & (norms > 0), norms, 1.0))
    e = np.clip(e, -1000, 1000)
    return np.ldexp(1.0, -e)


def equilibrate(a: np.ndarray, *, groups: np.ndarray | None = None, max_iter: int = 100,
                tol: float = 1e-15) -> tuple[np.ndarray, np.ndarray]:
    """Row and column scales that equilibrate a stack of matrices ``(G, n, m)``.

    Alternately scales the columns and the rows to unit 2-norm (Sinkhorn–Knopp in the
    2-norm) until the scales settle, so the result does not depend on the units the
    rows and columns came in: for ``a' = U a V`` (diagonal ``U``, ``V``) the scaled
    matrices ``r' a' c'`` and ``r a c`` agree to rounding. ``groups`` (length ``n``)
    ties rows together (one scale for all rows of a group, normalising the group's
    joint norm), e.g. the rows of one instrument in every experiment of a stacked
    system.

    Returns
    -------
    r : ndarray (G, n), c : ndarray (G, m)
        Positive scales (1 where a row/column is zero or not finite).
    """
    a = np.abs(np.asarray(a, dtype=float))
    g_n, n, m = a.shape
    sq = np.where(np.isfinite(a), a, 0.0)
    peak = np.max(sq, axis=(1, 2), keepdims=True)
    sq = sq / np.where(peak > 0, peak, 1.0)  # overflow-safe squares below
    sq = sq * sq
    if groups is not None:
        groups = np.asarray(groups)
        onehot = (groups[:, None] == np.unique(groups)[None, :]).astype(float)  # (n, k)
    # the sweeps call the ufuncs directly (np.max, np.mean are Python wrappers around the
    # same reductions) and keep r and c side by side in one buffer, so that the ratios of
    # the convergence test take one call each: a refined-IV iteration solves a 3 x 3
    # system once, and the sweeps cost their calls, not their arithmetic
    log, maximum, add = np.log, np.maximum.reduce, np.add.reduce
    rc = np.ones((g_n, n + m))
    r, c = rc[:, :n], rc[:, n:]
    for _ in range(max_iter):
        c_new = _inv_sqrt(np.einsum("gij,gi->gj", sq, r * r))
        row = np.einsum("gij,gj->gi", sq, c_new * c_new)
        if groups is not None:
            row = (row @ onehot) @ onehot.T
        r_new = _inv_sqrt(row)
        # fix the free global factor: geometric mean of the row scales is 1
        shift = np.exp(add(log(r_new), axis=1, keepdims=True) / n)
        rc_new = np.empty_like(rc)
        np.divide(r_new, shift, out=rc_new[:, :n])
        np.multiply(c_new, shift, out=rc_new[:, n:])
        change = np.abs(log(rc_new / rc))
        delta = maximum(change, axis=None)
        if delta != delta:  # NaN: as max(max over r, max over c), which may skip it
            delta = max(maximum(change[:, :n], axis=None), maximum(change[:, n:], axis=None))
        rc = rc_new
        r, c = rc[:, :n], rc[:, n:]
        if delta < tol:
            break
    peak = peak[:, :, 0]
    return r.copy(), c / np.where(peak > 0, peak, 1.0)


def _equilibrate_one(a: np.ndarray, max_iter: int, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`equilibrate` of one matrix ``a`` ``(1, n, m)`` without ``groups``: the same
    operations on the same values, bit-identical, in fewer calls (a refined-IV iteration
    solves one 3 × 3 system per step, and the vectorised sweeps cost their calls, not
    their arithmetic). Python floats where the result is exact or correctly rounded
    either way (products, ``1/sqrt``, quotients, sequential sums: numpy adds fewer than 8
    terms and the contraction over the leading axis in order); numpy where its order or
    its ``log``/``exp`` decide the last bit (the row sums over the contiguous axis, the
    logarithms and the exponential of the geometric mean). The convergence test
    ``max |log(new/old)| < tol`` is decided from ``max |new/old − 1|`` where that bounds
    it on the right side with a wide margin (``|log x| ≤ |x − 1|/min(x, 1)`` and
    ``|log x| ≥ |x − 1|/max(x, 1)``), and with numpy's logarithms otherwise."""
    try:
        return _equilibrate_one_loop(np.asarray(a, dtype=float), max_iter, tol)
    except ZeroDivisionError:  # a scale underflowed to 0: numpy's inf/NaN semantics
        return equilibrate(a, max_iter=max_iter, tol=tol)


def _equilibrate_one_loop(a: np.ndarray, max_iter: int, tol: float
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The sweeps of :func:`_equilibrate_one` (raises ZeroDivisionError where numpy would
    divide by zero)."""
    a = np.abs(a)
    _, n, m = a.shape
    sq = np.where(np.isfinite(a), a, 0.0)
    peak = np.max(sq, axis=(1, 2), keepdims=True)
    sq = sq / np.where(peak > 0, peak, 1.0)
    sq = sq * sq
    cols = sq[0].T.tolist()
    log, exp, einsum, asarray = np.log, np.exp, np.einsum, np.asarray
    sqrt, inf = math.sqrt, math.inf
    shortcut = 0 < tol <= 0.1
    r = [1.0] * n
    c = [1.0] * m
    c2_arr = np.empty((1, m))
    one = np.empty(1)
    for _ in range(max_iter):
        r2 = [x * x for x in r]
        c_new = []
        for col in cols:  # einsum("gij,gi->gj"): a sequential sum over i
            acc = 0.0
            for i in range(n):
                acc += col[i] * r2[i]
            c_new.append(1.0 / sqrt(acc) if acc > 0 else 1.0)
        c2_arr[0] = [x * x for x in c_new]
        row = einsum("gij,gj->gi", sq, c2_arr)[0].tolist()
        r_new = [1.0 / sqrt(x) if x > 0 else 1.0 for x in row]
        logs = log(asarray(r_new))
        if n < 8:  # numpy's add.reduce of fewer than 8 terms: in order
            tot = 0.0
            for x in logs.tolist():
                tot += x
        else:
            tot = float(np.add.reduce(logs))
        one[0] = tot / n
        shift = float(exp(one)[0])
        rn = [x / shift for x in r_new]
        cn = [x * shift for x in c_new]
        ratios = [x / y for x, y in zip(rn + cn, r + c, strict=True)]
        d = max(abs(x - 1.0) if 0 < x < inf else inf for x in ratios)
        if shortcut and d < 0.5 * tol:
            converged = True
        elif shortcut and 2 * tol < d < inf:
            converged = False
        else:
            change = np.abs(log(asarray([ratios])))
            delta = np.maximum.reduce(change, axis=None)
            if delta != delta:  # NaN: as max(max over r, max over c), which may skip it
                mx = np.maximum.reduce
                delta = max(mx(change[:, :n], axis=None), mx(change[:, n:], axis=None))
            converged = bool(delta < tol)
        r, c = rn, cn
        if converged:
            break
    peak = peak[:, :, 0]
    return np.array([r]), np.array([c]) / np.where(peak > 0, peak, 1.0)


def _inv_sqrt(x: np.ndarray) -> np.ndarray:
    """``1/sqrt(x)`` where ``x > 0``, else 1."""
    if np.minimum.reduce(x, axis=None) > 0:
        return 1.0 / np.sqrt(x)
    pos = x > 0
    return np.where(pos, 1.0 / np.sqrt(np.where(pos, x, 1.0)), 1.0)


def stacked_row_weights(a_n: np.ndarray) -> np.ndarray:
    """Weights of the instrument rows of the stacked equations (6)/(10).

    ``a_n`` (S, K, P) holds the per-experiment ``(1/N_E) Σ z φᵀ``; the stacked
    least-squares problem ``min Σ_E ‖W^½ (b_E − A_E θ)/N_E‖²`` weights instrument ``j``
    (its rows in every experiment alike) by ``W_jj = r_j²`` with ``r`` from
    :func:`equilibrate` of the stacked matrix, so the rows lose their units (the paper
    writes (6) without weights, which silently weights every instrument by the square
    of its unit). Returns the ``K`` diagonal entries of ``W`` (geometric mean 1).
    """
    a_n = np.asarray(a_n, dtype=float)
    s_n, k, p = a_n.shape
    r, _ = equilibrate(a_n.reshape(1, s_n * k, p), groups=np.tile(np.arange(k), s_n))
    return r[0, :k] ** 2


def _cond_one(a: np.ndarray) -> float:
    """``_equilibrated_cond(a[None])[0]`` of one matrix ``a`` (n, m), bit-identical, with
    the checks in Python floats (finite entries, no zero row or column), the scales of
    :func:`_equilibrate_one` and the same SVD of the same scaled matrix (``(a r) c``,
    ``np.linalg.cond``'s ``s[0] / s[-1]``, ``inf`` for a NaN ratio of finite entries)."""
    rows = a.tolist()
    isfinite = math.isfinite
    if not (all(isfinite(x) for row in rows for x in row)
            and all(any(x != 0 for x in row) for row in rows)
            and all(any(row[j] != 0 for row in rows) for j in range(a.shape[1]))):
        return math.inf
    r, c = _equilibrate_one(a[None], max_iter=50, tol=1e-9)
    rs, cs = r[0].tolist(), c[0].tolist()
    scaled = np.array([[(x * ri) * cj for x, cj in zip(row, cs, strict=True)]
                       for row, ri in zip(rows, rs, strict=True)])
    sv = np.linalg.svd(scaled[None], compute_uv=False)[0]
    with np.errstate(all="ignore"):
        ratio = sv[0] / sv[-1]
    return math.inf if ratio != ratio else float(ratio)


def _equilibrated_cond(a: np.ndarray) -> np.ndarray:
    """Condition numbers of a stack ``(G, n, m)`` after :func:`equilibrate`."""
    a = np.asarray(a, dtype=float)
    if a.shape[0] == 1 and a.shape[1] and a.shape[2]:  # one system: fewer calls
        return np.array([_cond_one(a[0])])
    out = np.full(a.shape[0], np.inf)
    good = np.all(np.isfinite(a), axis=(1, 2))
    good &= np.all(np.any(a != 0, axis=1), axis=1) & np.all(np.any(a != 0, axis=2), axis=1)
    if good.any():
        if good.sum() == 1:  # one system (the checked fit): the same scales, fewer calls
            r, c = _equilibrate_one(a[good], max_iter=50, tol=1e-9)
        else:
            r, c = equilibrate(a[good], max_iter=50, tol=1e-9)
        out[good] = np.linalg.cond(a[good] * r[:, :, None] * c[:, None, :])
    return out


def solve(a: np.ndarray, b: np.ndarray, *, cond_max: float = COND_MAX
          ) -> tuple[np.ndarray, np.ndarray]:
    """Solve a stack of square systems ``a[g] x[g] = b[g]``, unit-invariantly.

    The columns of ``a`` are scaled to unit norm by powers of two before the LU solve
    (``x = C y`` with ``(a C) y = b``): exact, so the rounding is that of the unscaled
    solve, and the solution of a system whose unknowns carry units (``a D``) is ``D⁻¹``
    times the unscaled one. The singularity check uses the condition number of the
    row- and column-equilibrated matrix (:func:`condition_number`), so multiplying
    every signal by 10⁶ cannot make a system "singular".

    Parameters
    ----------
    a : ndarray (G, P, P)
    b : ndarray (G, P)
    cond_max : float
        Systems with a larger equilibrated condition number are flagged singular.

    Returns
    -------
    x : ndarray (G, P)
        Solutions; NaN rows where ``ok`` is False.
    ok : ndarray (G,) bool
        False for singular, ill-conditioned or non-finite systems.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape[0] == 1 and b.shape[0] == 1 and a.shape[1]:  # one system: fewer calls
        return _solve_one(a, b, cond_max)
    if 1 < a.shape[0] <= 4 and b.shape[0] == a.shape[0] and a.shape[1]:  # a few: one by one
        few = _solve_few(a, b, cond_max)
        if few is not None:
            return few
    ok = np.all(np.isfinite(a), axis=(1, 2)) & np.all(np.isfinite(b), axis=1)
    out = np.full(b.shape, np.nan)
    if not ok.any():
        return out, ok
    with np.errstate(over="ignore", invalid="ignore"):
        col = pow2_scale(np.sqrt(np.einsum("gij,gij->gj", a[ok], a[ok])))
    a_s = a[ok] * col[:, None, :]
    with np.errstate(all="ignore"):
        try:
            y = np.linalg.solve(a_s, b[ok][..., None])[..., 0]
        except np.linalg.LinAlgError:
            y = np.full(a_s.shape[:2], np.nan)
            for j in range(a_s.shape[0]):
                try:
                    y[j] = np.linalg.solve(a_s[j], b[ok][j])
                except np.linalg.LinAlgError:
                    pass
        out[ok] = y * col
    # numerically singular systems that solve() does not reject, judged on the
    # equilibrated matrix: units must not make a system singular (or regular)
    # (the systems proved regular by the compiled bound skip the exact computation)
    if not _bounds_prove_regular(a[ok], cond_max):
        cond = np.full(a.shape[0], np.inf)
        cond[ok] = _equilibrated_cond(a[ok])
        ok &= np.isfinite(cond) & (cond < cond_max)
    ok &= np.all(np.isfinite(out), axis=1)
    out[~ok] = np.nan
    return out, ok


#: The compiled condition number (equal to rounding) decides that a system is regular only
#: below this fraction of ``cond_max``; elsewhere the exact computation decides.
COND_CLEAR = 1e-3


def _cond_below(a: np.ndarray, cond_max: float) -> bool:
    """``_cond_one(a) < cond_max`` (finite), the decision of :func:`solve` for one system.

    With the compiled kernels loaded, the equilibration scales come from
    :func:`vesselid.identify._ivkernels.equilibrate_one`: the same sweeps with the C
    library's ``log``/``exp``, so the scales agree with the exact ones to rounding (and
    to the convergence tolerance 1e-9 where the two stop one sweep apart). The two
    scaled matrices then differ by diagonal factors within ``1 ± 1e-9`` and entrywise
    roundings, which move a condition number ``κ`` by at most ~``4e-9 + n ε κ``
    relative: far below :data:`COND_CLEAR` for ``κ < COND_CLEAR · cond_max``. The
    compiled side is :func:`vesselid.identify._ivkernels.cond_bound`, one call: the checks,
    those scales and ``‖S‖_F ‖S⁻¹‖_F ≥ κ₂(S)`` of the scaled matrix (Gauss–Jordan, no
    SVD; 4 µs instead of 23 µs a call). So a compiled bound below the margin proves the
    system regular (every refined-IV and GMM solve of a fit: ``κ`` ~ 1e2–1e4); otherwise
    — singular or ill-conditioned systems, the numpy path — :func:`_cond_one` decides.
    The decision is the exact one's; only its cost changes."""
    if _bound_proves_regular(a, 50, cond_max):
        return True
    cond = _cond_one(a)
    return math.isfinite(cond) and cond < cond_max


def _bounds_prove_regular(a: np.ndarray, cond_max: float) -> bool:
    """Whether :func:`_bound_proves_regular` (50 sweeps) proves every system of the stack
    ``a`` (G, n, n) regular. The stacked :func:`_equilibrated_cond` sweeps until every
    system's scales settle, so a system's scales there are its own converged ones up to
    the tolerance 1e-9, as the compiled ones are: the argument of :func:`_cond_below`
    holds system by system, and the decision ``cond < cond_max`` of each is the stack's.
    False (the stack decides) at the first system without such a proof."""
    return all(_bound_proves_regular(a[g], 50, cond_max) for g in range(a.shape[0]))


def _bound_proves_regular(a: np.ndarray, sweeps: int, cond_max: float) -> bool:
    """Whether the compiled bound ``‖S‖_F ‖S⁻¹‖_F ≥ κ₂(S)`` of ``a`` (n, n) after
    ``sweeps`` equilibration sweeps (:func:`vesselid.identify._ivkernels.cond_bound`; inf
    where a check fails) lies below :data:`COND_CLEAR` of ``cond_max``: then κ₂ does too,
    which is what the exact computation decides. False without the compiled kernels."""
    from vesselid.identify.backend import loaded_kernel

    kernel = loaded_kernel("cond_bound")
    return kernel is not None and kernel(np.ascontiguousarray(a), sweeps,
                                         1e-9) < COND_CLEAR * cond_max


try:  # the gufunc behind np.linalg.solve
    from numpy.linalg import _umath_linalg as _ul

    _GESV = _ul.solve
except (ImportError, AttributeError):  # pragma: no cover
    _GESV = None


def _singular(err: str, flag: int) -> None:
    raise np.linalg.LinAlgError("Singular matrix")


def _gesv(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(a, b)`` of float64 stacks ``a`` (G, P, P), ``b`` (G, P, K): its
    LAPACK gufunc under its floating-point error state (a singular matrix raises
    ``LinAlgError``), without its argument handling (one fit's refined iteration solves
    at every step)."""
    if _GESV is None:  # pragma: no cover
        return np.linalg.solve(a, b)
    with np.errstate(call=_singular, invalid="call", over="ignore", divide="ignore",
                     under="ignore"):
        return _GESV(a, b, signature="dd->d")


def _pow2_one(norm: float) -> float:
    """:func:`pow2_scale` of one value (``frexp``/``ldexp`` are exact; a zero or
    non-finite norm is scaled as 1 is, by 1/2)."""
    if not (math.isfinite(norm) and norm > 0):
        norm = 1.0
    return math.ldexp(1.0, -min(max(math.frexp(norm)[1], -1000), 1000))


def _solve_one(a: np.ndarray, b: np.ndarray, cond_max: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`solve` of one system ``a`` (1, P, P), ``b`` (1, P), bit-identical
    (:func:`_solve_system`, the singularity decision of :func:`_cond_below`)."""
    x = _solve_system(a[0], b[0], cond_max, exact=True)
    if x is None or x is False:
        return np.full(b.shape, np.nan), np.zeros(1, dtype=bool)
    return np.array([x]), np.ones(1, dtype=bool)


def _solve_few(a: np.ndarray, b: np.ndarray, cond_max: float
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`solve` of a few systems one by one (:func:`_solve_system`; the stacked LAPACK
    solve is one ``gesv`` per system, the column norms are sequential sums either way).
    The singularity decision of the stack is its equilibrated condition numbers; a system
    whose compiled bound proves it regular takes the stack's decision
    (:func:`_bounds_prove_regular`). None — the stacked path decides — where a system
    with a finite solution lacks that proof."""
    xs = []
    for g in range(a.shape[0]):
        x = _solve_system(a[g], b[g], cond_max, exact=False)
        if x is None:
            return None
        xs.append(x)
    out = np.full(b.shape, np.nan)
    ok = np.zeros(a.shape[0], dtype=bool)
    for g, x in enumerate(xs):
        if x is not False:
            out[g] = x
            ok[g] = True
    return out, ok


def _solve_system(a: np.ndarray, b: np.ndarray, cond_max: float, *, exact: bool
                  ) -> list[float] | bool | None:
    """One system ``a`` (P, P), ``b`` (P,) of :func:`solve` (:func:`_solve_lists` of its
    entries). Returns the solution, False for a singular, ill-conditioned or non-finite
    system, and — without ``exact`` — None where only the exact condition number
    (:func:`_cond_one`) could decide."""
    return _solve_lists(a.tolist(), b.tolist(), a, cond_max, exact=exact)


def solve_rows(rows: list[list[float]], rhs: list[float], cond_max: float = COND_MAX
               ) -> list[float] | None:
    """:func:`solve` of one system given as Python lists, ``rows`` (P lists of P floats)
    and ``rhs`` (P floats): its solution as a list, None where :func:`solve` flags the
    system, bit-identical to ``solve(np.array([rows]), np.array([rhs]))`` (for loops
    that hold their few numbers as Python floats, e.g. the refined iteration of one fit).
    """
    x = _solve_lists(rows, rhs, None, cond_max, exact=True)
    return None if x is False or x is None else x


def _solve_lists(rows: list[list[float]], rhs: list[float], a: np.ndarray | None,
                 cond_max: float, *, exact: bool) -> list[float] | bool | None:
    """The solve of :func:`_solve_system` on the entries ``rows``, ``rhs`` (``a``: the same
    matrix as an array, or None: made from ``rows`` where the condition check needs it):
    the finiteness checks, the power-of-two column scales (the column norms are
    ``einsum``'s sequential sums of squares, ``frexp``/``ldexp`` are exact) and the
    products with them in Python floats (IEEE products; an overflow gives ``inf``
    silently, as under ``errstate``), and the same LAPACK solve of the same scaled system.
    """
    isfinite = math.isfinite
    p = len(rows)
    if not (all(isfinite(x) for row in rows for x in row)
            and all(isfinite(x) for x in rhs)):
        return False
    col = []
    for j in range(p):
        acc = 0.0
        for row in rows:
            acc += row[j] * row[j]
        col.append(_pow2_one(math.sqrt(acc)))
    a_s = np.array([[[x * cj for x, cj in zip(row, col, strict=True)] for row in rows]])
    try:
        y = _gesv(a_s, np.array(rhs, dtype=float).reshape(1, p, 1))[0, :, 0].tolist()
    except np.linalg.LinAlgError:
        return False
    out = [x * cj for x, cj in zip(y, col, strict=True)]
    if not all(isfinite(x) for x in out):
        return False
    if a is None:
        a = np.array(rows, dtype=float)
    if exact:
        return out if _cond_below(a, cond_max) else False
    return out if _bound_proves_regular(a, 50, cond_max) else None


def inv_sym(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of a stack of symmetric positive definite matrices ``(G, K, K)``.

    Symmetrically equilibrated first (``D s D`` with ``D`` the powers of two nearest
    ``1/sqrt(diag s)``), inverted, and scaled back (``D (D s D)⁻¹ D``), so the result
    and the singularity check do not depend on the units of the rows/columns.
    Returns ``(inverse, ok)``; rows that are singular or not finite get NaN and
    ``ok = False``.
    """
    s = np.asarray(s, dtype=float)
    if s.shape[0] == 1 and s.shape[1]:
        return _inv_sym_one(s)
    ok = np.all(np.isfinite(s), axis=(1, 2))
    diag = np.diagonal(s, axis1=1, axis2=2)
    ok &= np.all(diag > 0, axis=1)
    out = np.full(s.shape, np.nan)
    if not ok.any():
        return out, ok
    d = pow2_scale(np.sqrt(diag[ok]))
    x = s[ok] * d[:, :, None] * d[:, None, :]
    cond = np.linalg.cond(x)
    good = np.isfinite(cond) & (cond < COND_MAX)
    res = np.full(x.shape, np.nan)
    if good.any():
        with np.errstate(all="ignore"):
            inv = np.linalg.inv(x[good]) * d[good][:, :, None] * d[good][:, None, :]
        res[good] = 0.5 * (inv + np.swapaxes(inv, 1, 2))
        good[good] = np.all(np.isfinite(res[good]), axis=(1, 2))
    out[ok] = res
    ok[ok] = good
    out[~ok] = np.nan
    return out, ok


def _inv_sym_one(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`inv_sym` of one matrix ``s`` (1, K, K), bit-identical: the checks and the
    power-of-two scales in Python floats, the same scaled matrix, SVD and inverse."""
    out = np.full(s.shape, np.nan)
    rows = s[0].tolist()
    isfinite = math.isfinite
    diag = [rows[i][i] for i in range(len(rows))]
    if not (all(isfinite(x) for row in rows for x in row) and all(x > 0 for x in diag)):
        return out, np.zeros(1, dtype=bool)
    d = [_pow2_one(math.sqrt(x)) for x in diag]
    x = np.array([[[(v * di) * dj for v, dj in zip(row, d, strict=True)]
                   for row, di in zip(rows, d, strict=True)]])
    if not _regular_sym(x):
        return out, np.zeros(1, dtype=bool)
    dd = np.array([d])
    with np.errstate(all="ignore"):
        inv = np.linalg.inv(x) * dd[:, :, None] * dd[:, None, :]
    res = 0.5 * (inv + np.swapaxes(inv, 1, 2))
    if not np.all(np.isfinite(res)):
        return out, np.zeros(1, dtype=bool)
    return res, np.ones(1, dtype=bool)


def _regular_sym(x: np.ndarray) -> bool:
    """``np.linalg.cond(x)[0] < COND_MAX`` (finite) for one scaled matrix ``x`` (1, K, K)
    of :func:`_inv_sym_one`: proved by the compiled bound ``‖x‖_F ‖x⁻¹‖_F ≥ κ₂(x)``
    (:func:`vesselid.identify._ivkernels.cond_bound` without equilibration sweeps, a
    uniform scale only) when it is below :data:`COND_CLEAR` of the threshold, as in
    :func:`_cond_below`; otherwise (and on the numpy path) by the SVD."""
    if _bound_proves_regular(x[0], 0, COND_MAX):
        return True
    cond = np.linalg.cond(x)
    return bool(np.isfinite(cond[0]) and cond[0] < COND_MAX)


def gmm_solve(a: np.ndarray, b: np.ndarray, w: np.ndarray | None = None, *,
              cond_max: float = COND_MAX) -> tuple[np.ndarray, np.ndarray]:
    """``θ = (AᵀWA)⁻¹ AᵀW b`` for a stack of moment equations.

    Parameters
    ----------
    a : ndarray (G, K, P)
        ``Σ z φᵀ`` (K instruments, P parameters, K ≥ P).
    b : ndarray (G, K)
        ``Σ z y``.
    w : ndarray (G, K, K), optional
        Weight; identity when omitted. With ``K == P`` the weight does not matter
        and the square system is solved directly.

    Returns
    -------
    (theta (G, P), ok (G,))
    """
    if a.shape[1] == a.shape[2]:
        return solve(a, b, cond_max=cond_max)
    if w is None:
        aw = np.swapaxes(a, 1, 2)
    else:
        aw = np.einsum("gkp,gkl->gpl", a, w)
    return solve(aw @ a, np.einsum("gpk,gk->gp", aw, b), cond_max=cond_max)


def condition_number(a: np.ndarray) -> float | np.ndarray:
    """Condition number after scaling rows and columns to unit norm.

    ``a`` of shape ``(n, m)`` gives a float, a stack ``(G, n, m)`` an array; a zero
    row or column gives ``inf``.
    """
    arr = np.asarray(a, dtype=float)
    if arr.ndim == 2:
        return float(_equilibrated_cond(arr[None])[0])
    return _equilibrated_cond(arr)


# ------------------------------------------------------------------ BLAS threads
_F = TypeVar("_F", bound=Callable[..., Any])
_BLAS_LOCK = threading.Lock()
_BLAS_STATE: dict[str, Any] = {"depth": 0, "limiter": None}


@functools.lru_cache(maxsize=1)
def _blas_controller() -> Any:
    """threadpoolctl's controller of the BLAS libraries loaded now (numpy's OpenBLAS at
    the least), or None when threadpoolctl finds none."""
    from threadpoolctl import ThreadpoolController

    ctl = ThreadpoolController().select(user_api="blas")
    return ctl if ctl.lib_controllers else None


def pin_blas_to_one_thread() -> None:
    """Put the BLAS libraries loaded now on one thread for the rest of this process
    (threadpoolctl; not restored): for a process that only runs fits, such as a forked
    Monte Carlo worker (its parent has loaded the libraries with a first fit),
    where :func:`one_blas_thread` would otherwise restore more than one thread after each
    fit and start BLAS threads that spin for work on the other workers' cores. The
    numbers are the same (:func:`one_blas_thread`)."""
    ctl = _blas_controller()
    if ctl is not None:
        ctl.limit(limits=1)


def one_blas_thread(fn: _F) -> _F:
    """Run ``fn`` with the BLAS on one thread (restored afterwards; threadpoolctl).

    A fit multiplies tall, narrow matrices (10⁴ rows, a handful of columns): a second
    BLAS thread saves nothing there, and OpenBLAS's waiting threads spin, costing wall
    time and CPU on a busy machine (``scripts/bench.py``). The numbers are the same:
    OpenBLAS splits the output, not the sums, between threads.
    Nested and concurrent calls share one setting; the outermost restores it.
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        ctl = _blas_controller()
        if ctl is None:
            return fn(*args, **kwargs)
        with _BLAS_LOCK:
            if _BLAS_STATE["depth"] == 0:
                _BLAS_STATE["limiter"] = ctl.limit(limits=1)
            _BLAS_STATE["depth"] += 1
        try:
            return fn(*args, **kwargs)
        finally:
            with _BLAS_LOCK:
                _BLAS_STATE["depth"] -= 1
                if _BLAS_STATE["depth"] == 0:
                    _BLAS_STATE["limiter"].restore_original_limits()
                    _BLAS_STATE["limiter"] = None

    return wrapper  # type: ignore[return-value]
