"""Compiled Gaussian filter of the prediction-error estimator (:mod:`vesselid.identify.pem`).

One state equation of Definition 2.1 with the disturbances as filter states::

    r(k)   = x(k) + v(k)                               (the current inside the modulus)
    x(k+1) = Φᵀ([r(k); u(k)]) θ + μ_w + w(k)           w white, std σ_w
    v(k+1) = ρ_v v(k) + σ_v √(1 − ρ_v²) ξ(k)           Gauss–Markov current (ρ_v = 0: white)
    c(k+1) = ρ_c c(k) + σ_c √(1 − ρ_c²) χ(k)           Gauss–Markov sensor noise
    y(k)   = x(k) + c(k) + e(k)                        e white, std σ_e

The measurement is linear, so the update is the Kalman update of the state ``[x, v, c]``.
The prediction propagates the mean and variance of ``h(r) = Φᵀ([r; u]) θ`` by 3-point
Gauss–Hermite quadrature of the scalar ``r`` (the unscented transform with κ = 2: exact for
the quadratic branches of ``r|r|``) and the cross-covariances of ``h`` with ``v`` and ``c``
by statistical linearisation, ``cov(h, s) = cov(h, r) cov(r, s) / var(r)``.

Parameter rows ``ψ = [θ (P), μ_w, atanh ρ_v, log σ_v, atanh ρ_c, log σ_c, log σ_w,
log σ_e]``; ``log σ = −inf`` switches a disturbance off. Each row is filtered
independently (the perturbed rows of a finite-difference Jacobian), so the kernel takes
a row range and runs under :func:`vesselid.core.threads.run_ranges`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["N_NOISE", "gaussian_filter", "term_kinds"]

#: Noise parameters after θ in a parameter row (μ_w, ρ_v, σ_v, ρ_c, σ_c, σ_w, σ_e).
N_NOISE = 7

_SQ3 = np.sqrt(3.0)
_TINY = 1e-300


@njit(cache=True, nogil=True)
def gaussian_filter(lo, hi, psi, y, u, starts, p_init, kind, fa, fb, eps, var):  # pragma: no cover
    """Innovations ``eps[j, k]`` and their variances ``var[j, k]`` for the rows
    ``lo ≤ j < hi`` of ``psi`` (R, P + 7) on the measured state ``y`` (T,) with inputs
    ``u`` (T, m), experiments ``starts`` (S + 1,) restarting the filter (mean
    ``y(start)``, state variance ``p_init[s]``), and the terms in the form of
    :func:`term_kinds`: term ``t`` adds ``θ_t F[fa_t] F[fb_t]`` (``F = [·, u, ·, |u|, 1]``)
    to the coefficient ``kind_t`` of ``h(r) = c₀ + c₁ r + c₂ |r| + c₃ r|r| + c₄ r²``, so
    the three quadrature points cost five products each. The first sample of every
    experiment holds no innovation: ``eps = 0``, ``var = 1`` there (no contribution to the
    likelihood).

    The rows advance together, sample by sample (the inner loop runs over rows): one
    row's recursion is a chain of dependent divisions and square roots, and independent
    rows fill its latency.
    """
    n_par = kind.shape[0]
    n_u = u.shape[1]
    n_sig = 1 + n_u
    nr = hi - lo
    if nr <= 0:
        return
    fv = np.empty(2 * n_sig + 1)
    fv[0] = 1.0
    fv[n_sig] = 1.0
    fv[2 * n_sig] = 1.0
    tf = np.empty(n_par)  # the terms' factors without the state, at sample k
    coef = np.zeros((5, nr))
    mw = np.empty(nr)
    rv = np.empty(nr)
    rc = np.empty(nr)
    sv2 = np.empty(nr)
    sc2 = np.empty(nr)
    sw2 = np.empty(nr)
    se2 = np.empty(nr)
    qv = np.empty(nr)
    qc = np.empty(nr)
    for i in range(nr):
        j = lo + i
        mw[i] = psi[j, n_par]
        rv[i] = np.tanh(psi[j, n_par + 1])
        sv2[i] = np.exp(2.0 * psi[j, n_par + 2])
        rc[i] = np.tanh(psi[j, n_par + 3])
        sc2[i] = np.exp(2.0 * psi[j, n_par + 4])
        sw2[i] = np.exp(2.0 * psi[j, n_par + 5])
        se2[i] = np.exp(2.0 * psi[j, n_par + 6])
        qv[i] = sv2[i] * (1.0 - rv[i] * rv[i])
        qc[i] = sc2[i] * (1.0 - rc[i] * rc[i])
    m0 = np.empty(nr)
    m1 = np.empty(nr)
    m2 = np.empty(nr)
    p00 = np.empty(nr)
    p01 = np.empty(nr)
    p02 = np.empty(nr)
    p11 = np.empty(nr)
    p12 = np.empty(nr)
    p22 = np.empty(nr)
    for s in range(starts.size - 1):
        a, b = starts[s], starts[s + 1]
        for i in range(nr):
            m0[i] = y[a]
            m1[i] = 0.0
            m2[i] = 0.0
            p00[i] = p_init[s]
            p01[i] = 0.0
            p02[i] = 0.0
            p11[i] = sv2[i]
            p12[i] = 0.0
            p22[i] = sc2[i]
        for k in range(a, b):
            yk = y[k]
            first = k == a
            last = k == b - 1
            if not last:
                for q in range(n_u):
                    fv[1 + q] = u[k, q]
                    fv[n_sig + 1 + q] = abs(u[k, q])
                for t in range(n_par):
                    tf[t] = fv[fa[t]] * fv[fb[t]]
                coef[:, :] = 0.0
                for t in range(n_par):
                    kt = kind[t]
                    for i in range(nr):
                        coef[kt, i] += psi[lo + i, t] * tf[t]
            for i in range(nr):
                # update with y(k) = x + c + e
                e = yk - m0[i] - m2[i]
                sk = p00[i] + 2.0 * p02[i] + p22[i] + se2[i]
                sk = max(sk, _TINY)
                if first:
                    eps[lo + i, k] = 0.0
                    var[lo + i, k] = 1.0
                else:
                    eps[lo + i, k] = e
                    var[lo + i, k] = sk
                h0, h1, h2 = p00[i] + p02[i], p01[i] + p12[i], p02[i] + p22[i]
                inv = 1.0 / sk
                k0, k1, k2 = h0 * inv, h1 * inv, h2 * inv
                x0 = m0[i] + k0 * e
                x1 = m1[i] + k1 * e
                x2 = m2[i] + k2 * e
                q00 = p00[i] - k0 * h0
                q01 = p01[i] - k0 * h1
                q02 = p02[i] - k0 * h2
                q11 = p11[i] - k1 * h1
                q12 = p12[i] - k1 * h2
                q22 = p22[i] - k2 * h2
                if last:
                    continue
                # predict x(k+1), v(k+1), c(k+1)
                mr = x0 + x1
                pr = max(q00 + 2.0 * q01 + q11, _TINY)
                spread = _SQ3 * np.sqrt(pr)
                c0, c1, c2 = coef[0, i], coef[1, i], coef[2, i]
                c3, c4 = coef[3, i], coef[4, i]
                r1 = mr + spread
                r2 = mr - spread
                a0, a1, a2 = abs(mr), abs(r1), abs(r2)
                g0 = c0 + mr * (c1 + c3 * a0 + c4 * mr) + c2 * a0
                g1 = c0 + r1 * (c1 + c3 * a1 + c4 * r1) + c2 * a1
                g2 = c0 + r2 * (c1 + c3 * a2 + c4 * r2) + c2 * a2
                eh = (4.0 * g0 + g1 + g2) / 6.0
                d0, d1, d2 = g0 - eh, g1 - eh, g2 - eh
                vh = (4.0 * d0 * d0 + d1 * d1 + d2 * d2) / 6.0
                gain = (d1 - d2) * spread / (6.0 * pr)
                p00[i] = vh + sw2[i]
                p01[i] = rv[i] * gain * (q01 + q11)
                p02[i] = rc[i] * gain * (q02 + q12)
                p11[i] = rv[i] * rv[i] * q11 + qv[i]
                p12[i] = rv[i] * rc[i] * q12
                p22[i] = rc[i] * rc[i] * q22 + qc[i]
                m0[i] = eh + mw[i]
                m1[i] = rv[i] * x1
                m2[i] = rc[i] * x2


def term_kinds(fac: np.ndarray, n_signals: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(kind, fa, fb)`` of the terms ``F[a] F[b]`` (:func:`vesselid.model.regressors.
    encode_terms`, ``F = [x, u, |x|, |u|, 1]`` over ``n_signals = 1 + m`` signals) for
    :func:`gaussian_filter`: ``kind`` 0 (no state factor), 1 (``x``), 2 (``|x|``),
    3 (``x|x|``), 4 (``x²``: ``x·x`` or ``|x|·|x|``); ``fa``/``fb`` index the factors
    without the state (its places hold 1 in the kernel's vector)."""
    fac = np.asarray(fac, dtype=np.int64)
    state, abs_state = 0, n_signals
    kinds = np.empty(fac.shape[0], dtype=np.int64)
    code = {state: 1, abs_state: 2}
    for t, (a, b) in enumerate(fac):
        lo, hi = sorted((code.get(int(a), 0), code.get(int(b), 0)))
        kinds[t] = _KINDS[(lo, hi)]
    return kinds, fac[:, 0].copy(), fac[:, 1].copy()


#: (sorted state codes of the two factors: 0 none, 1 x, 2 |x|) -> coefficient of h(r)
_KINDS = {(0, 0): 0, (0, 1): 1, (0, 2): 2, (1, 2): 3, (1, 1): 4, (2, 2): 4}
