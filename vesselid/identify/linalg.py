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
"""

from __future__ import annotations

import numpy as np

__all__ = ["COND_MAX", "condition_number", "gmm_solve", "inv_sym", "solve"]

#: Systems whose (equilibrated) condition number exceeds this are treated as singular.
COND_MAX = 1e15


def _equilibrated_cond(a: np.ndarray) -> np.ndarray:
    """Condition numbers of a stack ``(G, n, m)`` after unit-norm row and column scaling."""
    r = np.linalg.norm(a, axis=2, keepdims=True)
    c = np.linalg.norm(a, axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        scaled = a / r / c
    out = np.full(a.shape[0], np.inf)
    good = np.all(np.isfinite(scaled), axis=(1, 2))
    if good.any():
        out[good] = np.linalg.cond(scaled[good])
    return out


def solve(a: np.ndarray, b: np.ndarray, *, cond_max: float = COND_MAX
          ) -> tuple[np.ndarray, np.ndarray]:
    """Solve a stack of square systems ``a[g] x[g] = b[g]``.

    Parameters
    ----------
    a : ndarray (G, P, P)
    b : ndarray (G, P)
    cond_max : float
        Systems with a larger condition number are flagged singular.

    Returns
    -------
    x : ndarray (G, P)
        Solutions; NaN rows where ``ok`` is False.
    ok : ndarray (G,) bool
        False for singular, ill-conditioned or non-finite systems.
    """
    ok = np.all(np.isfinite(a), axis=(1, 2)) & np.all(np.isfinite(b), axis=1)
    out = np.full(b.shape, np.nan)
    if not ok.any():
        return out, ok
    try:
        out[ok] = np.linalg.solve(a[ok], b[ok][..., None])[..., 0]
    except np.linalg.LinAlgError:
        for j in np.flatnonzero(ok):
            try:
                out[j] = np.linalg.solve(a[j], b[j])
            except np.linalg.LinAlgError:
                ok[j] = False
    # guard against numerically singular systems that solve() does not reject
    cond = np.full(a.shape[0], np.inf)
    if ok.any():
        cond[ok] = np.linalg.cond(a[ok])
    ok &= np.isfinite(cond) & (cond < cond_max) & np.all(np.isfinite(out), axis=1)
    out[~ok] = np.nan
    return out, ok


def inv_sym(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of a stack of symmetric positive definite matrices ``(G, K, K)``.

    Returns ``(inverse, ok)``; rows that are singular or not finite get NaN and
    ``ok = False``.
    """
    ok = np.all(np.isfinite(s), axis=(1, 2))
    cond = np.full(s.shape[0], np.inf)
    if ok.any():
        cond[ok] = np.linalg.cond(s[ok])
    ok &= cond < COND_MAX
    out = np.full(s.shape, np.nan)
    if ok.any():
        inv = np.linalg.inv(s[ok])
        out[ok] = 0.5 * (inv + np.swapaxes(inv, 1, 2))
    return out, ok


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
