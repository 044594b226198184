"""Compiled per-experiment helpers of the explicit-matrix estimators (GMM, SRIV).

All work on concatenated rows with experiment boundaries ``starts`` and a row mask
``valid``; nothing crosses an experiment boundary.

* :func:`simulated_regressors` — instruments from the auxiliary model, one
  parameter vector per group (batched refined IV).
* :func:`center` — subtract each column's mean over the valid rows of a segment.
* :func:`ar_filter` — ``x_f(k) = Σ_j c_j x(k − j)`` per segment (valid only where
  all ``p + 1`` inputs are valid).
* :func:`autocov` — residual autocovariances per segment (Yule–Walker).
* :func:`cross_sums` — ``Σ z φᵀ``, ``Σ z y``, ``Σ z zᵀ`` per segment.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["ar_filter", "autocov", "center", "cross_sums", "simulated_regressors"]


@njit(cache=True)
def simulated_regressors(target, u, starts, group, theta, fac, eq, limit):
    """``ζ(k) = Φ([x̂(k−1); u(k−1)])`` with ``x̂`` simulated from ``theta[group[s]]``.

    Returns ``(z (T, P) with NaN in each segment's first row, ok (S,) bool)``; a
    segment whose simulation leaves ``±limit[s]`` is all NaN and not ok.
    """
    t_len, n = target.shape
    m = u.shape[1]
    n_par = fac.shape[0]
    n_f = 2 * (n + m) + 1
    z = np.full((t_len, n_par), np.nan)
    ok = np.ones(starts.shape[0] - 1, dtype=np.bool_)
    f = np.empty(n_f)
    f[n_f - 1] = 1.0
    xh = np.empty(n)
    for s in range(starts.shape[0] - 1):
        a = starts[s]
        b = starts[s + 1]
        th = theta[group[s]]
        for i in range(n):
            xh[i] = target[a, i]
        for k in range(a + 1, b):
            for i in range(n):
                f[i] = xh[i]
                f[n + m + i] = abs(xh[i])
                xh[i] = 0.0
            for j in range(m):
                f[n + j] = u[k - 1, j]
                f[2 * n + m + j] = abs(u[k - 1, j])
            for p in range(n_par):
                zp = f[fac[p, 0]] * f[fac[p, 1]]
                z[k, p] = zp
                xh[eq[p]] += th[p] * zp
            bad = False
            for i in range(n):
                if not abs(xh[i]) <= limit[s]:
                    bad = True
            if bad:
                ok[s] = False
                for kk in range(a, b):
                    for p in range(n_par):
                        z[kk, p] = np.nan
                break
    return z, ok


@njit(cache=True)
def center(x, starts, valid):
    """Subtract each column's mean over the valid rows of every segment (in place copy)."""
    out = x.copy()
    k_cols = x.shape[1]
    mean = np.empty(k_cols)
    for s in range(starts.shape[0] - 1):
        cnt = 0
        mean[:] = 0.0
        for k in range(starts[s], starts[s + 1]):
            if valid[k]:
                cnt += 1
                for j in range(k_cols):
                    mean[j] += x[k, j]
        if cnt == 0:
            continue
        for j in range(k_cols):
            mean[j] /= cnt
        for k in range(starts[s], starts[s + 1]):
            for j in range(k_cols):
                out[k, j] = x[k, j] - mean[j]
    return out


@njit(cache=True)
def ar_filter(x, starts, valid, coef):
    """``x_f(k) = Σ_j coef[s, j] x(k − j)``, ``j = 0 … p`` per segment ``s``.

    Returns ``(x_f, valid_f)``; a row is valid when it and its ``p`` predecessors
    (inside the segment) are valid.
    """
    t_len, k_cols = x.shape
    p = coef.shape[1] - 1
    out = np.zeros((t_len, k_cols))
    vf = np.zeros(t_len, dtype=np.bool_)
    for s in range(starts.shape[0] - 1):
        a = starts[s]
        for k in range(a + p, starts[s + 1]):
            good = True
            for j in range(p + 1):
                if not valid[k - j]:
                    good = False
                    break
            if not good:
                continue
            vf[k] = True
            for c in range(k_cols):
                acc = 0.0
                for j in range(p + 1):
                    acc += coef[s, j] * x[k - j, c]
                out[k, c] = acc
    return out, vf


@njit(cache=True)
def autocov(e, starts, valid, p):
    """Sums ``Σ ẽ(k) ẽ(k − j)``, ``j = 0 … p``, of the segment-demeaned ``e``
    over pairs of valid rows, and the number of valid rows, per segment."""
    n_seg = starts.shape[0] - 1
    out = np.zeros((n_seg, p + 1))
    cnt = np.zeros(n_seg)
    for s in range(n_seg):
        a = starts[s]
        b = starts[s + 1]
        mean = 0.0
        c = 0
        for k in range(a, b):
            if valid[k]:
                mean += e[k]
                c += 1
        if c == 0:
            continue
        mean /= c
        cnt[s] = c
        for k in range(a, b):
            if not valid[k]:
                continue
            ek = e[k] - mean
            for j in range(p + 1):
                if k - j >= a and valid[k - j]:
                    out[s, j] += ek * (e[k - j] - mean)
    return out, cnt


@njit(cache=True)
def cross_sums(z, phi, y, starts, valid):
    """Per segment: ``Σ z φᵀ`` (S, K, P), ``Σ z y`` (S, K), ``Σ z zᵀ`` (S, K, K), count."""
    n_seg = starts.shape[0] - 1
    k_cols = z.shape[1]
    p_cols = phi.shape[1]
    a_out = np.zeros((n_seg, k_cols, p_cols))
    b_out = np.zeros((n_seg, k_cols))
    m_out = np.zeros((n_seg, k_cols, k_cols))
    cnt = np.zeros(n_seg)
    for s in range(n_seg):
        for k in range(starts[s], starts[s + 1]):
            if not valid[k]:
                continue
            cnt[s] += 1
            for i in range(k_cols):
                zi = z[k, i]
                b_out[s, i] += zi * y[k]
                for j in range(p_cols):
                    a_out[s, i, j] += zi * phi[k, j]
                for j in range(i, k_cols):
                    m_out[s, i, j] += zi * z[k, j]
        for i in range(k_cols):
            for j in range(i):
                m_out[s, i, j] = m_out[s, j, i]
    return a_out, b_out, m_out, cnt

