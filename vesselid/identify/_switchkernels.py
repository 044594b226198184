"""Compiled interacting-multiple-model filter of the switching-current estimator
(:mod:`vesselid.identify.switching`).

One state equation of Definition 2.1 with a two-level Markov ("telegraph") current::

    r(k)   = x(k) + v(k)                         v(k) ∈ {−c, +c}
    x(k+1) = Φᵀ([r(k); u(k)]) θ + μ_w + w(k)     w white, std σ_w
    P(v(k+1) ≠ v(k)) = p                         (a symmetric two-state Markov chain)
    y(k)   = x(k) + e(k)                         e white, std σ_e

The level is hidden, so the filter keeps one Gaussian ``N(m_j, P_j)`` of ``x(k)`` per
level ``j`` of ``v(k − 1)`` — the level that moved the state to ``x(k)``, which ``y(k)``
discriminates — with its probability ``μ_j`` (Blom & Bar-Shalom's interacting multiple
model): the posteriors are mixed by the chain's transition probabilities into one
Gaussian per level of ``v(k)`` (the interaction step), each is propagated through
``h(r) = c₀ + c₁ r + c₂|r| + c₃ r|r| + c₄ r²`` with the exact mean and variance of ``h``
under a Gaussian ``r`` (``h`` is a quadratic on each side of ``r = 0``, so both follow
from the truncated normal moments of orders 0–4), and updated with the measurement by
the Kalman update. The likelihood of ``y(k)`` is the mixture ``Σ_j μ_j⁻ N(y; m_j⁻, P_j⁻ + σ_e²)``.

Parameter rows ``ψ = [θ (P), μ_w, log c, logit 2p, log σ_w, log σ_e]`` (``p = ½ / (1 +
e^{−z})`` in ``(0, ½)``: a persistent chain).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["N_NOISE", "switching_filter"]

#: Noise parameters after θ in a parameter row (μ_w, log c, logit 2p, log σ_w, log σ_e).
N_NOISE = 5

_TINY = 1e-300
_INV_SQRT2 = 1.0 / math.sqrt(2.0)
_INV_SQRT2PI = 1.0 / math.sqrt(2.0 * math.pi)
_LOG_2PI = math.log(2.0 * math.pi)


@njit(inline="always")
def _side_moments(sgn, m, s, phi, tail, out):  # pragma: no cover
    """``out[n] = E[d^n 1{sgn·(m + d) > 0}]`` for ``d ~ N(0, s²)``, ``n = 0..4``
    (Stein's identity: ``N_n = s² ((n−1) N_{n−2} + sgn (−m)^{n−1} pdf(−m))``)."""
    s2 = s * s
    pdf_s = sgn * phi * s  # s² · sgn · φ(m/s)/s
    out[0] = tail
    out[1] = pdf_s
    out[2] = s2 * out[0] + pdf_s * (-m)
    out[3] = s2 * 2.0 * out[1] + pdf_s * m * m
    out[4] = s2 * 3.0 * out[2] - pdf_s * m * m * m


@njit(inline="always")
def _predict(m, pr, c0, c1, c2, c3, c4, mp, mn):  # pragma: no cover
    """Exact mean and variance of ``h(r)`` for ``r ~ N(m, pr)``."""
    s = math.sqrt(max(pr, _TINY))
    z = m / s
    phi = _INV_SQRT2PI * math.exp(-0.5 * z * z)
    up = 0.5 * math.erfc(-z * _INV_SQRT2)   # P(r > 0)
    dn = 0.5 * math.erfc(z * _INV_SQRT2)    # P(r < 0)
    _side_moments(1.0, m, s, phi, up, mp)
    _side_moments(-1.0, m, s, phi, dn, mn)
    # h on each side as a quadratic in d = r − m: A + B d + C d²
    bp, cp = c1 + c2, c3 + c4
    bn, cn = c1 - c2, c4 - c3
    ap = c0 + m * (bp + cp * m)
    an = c0 + m * (bn + cn * m)
    h0 = ap if m >= 0.0 else an
    ap -= h0
    an -= h0
    bp2, bn2 = bp + 2.0 * cp * m, bn + 2.0 * cn * m
    e1 = (ap * mp[0] + bp2 * mp[1] + cp * mp[2]) + (an * mn[0] + bn2 * mn[1] + cn * mn[2])
    e2 = (ap * ap * mp[0] + 2.0 * ap * bp2 * mp[1] + (bp2 * bp2 + 2.0 * ap * cp) * mp[2]
          + 2.0 * bp2 * cp * mp[3] + cp * cp * mp[4]
          + an * an * mn[0] + 2.0 * an * bn2 * mn[1] + (bn2 * bn2 + 2.0 * an * cn) * mn[2]
          + 2.0 * bn2 * cn * mn[3] + cn * cn * mn[4])
    return h0 + e1, max(e2 - e1 * e1, 0.0)


@njit(cache=True, nogil=True)
def switching_filter(psi, y, u, starts, p_init, kind, fa, fb, ll, total):  # pragma: no cover
    """Per-sample log-likelihoods ``ll[j, k]`` (when ``ll`` has ``T`` columns; pass
    ``(R, 0)`` for none) and their sums ``total[j]`` of the rows of ``psi`` (R, P + 5)
    on the measured state ``y`` (T,) with inputs ``u`` (T, m); experiments ``starts``
    (S + 1,) restart the filter (both levels equally likely, mean ``y(start)``, variance
    ``p_init[s]``); the terms in the form of
    :func:`vesselid.identify._pemkernels.term_kinds`. The first sample of every
    experiment holds no likelihood (``ll = 0`` there)."""
    n_par = kind.shape[0]
    n_u = u.shape[1]
    n_sig = 1 + n_u
    n = y.size
    keep = ll.shape[1] == n
    fv = np.empty(2 * n_sig + 1)
    fv[0] = 1.0
    fv[n_sig] = 1.0
    fv[2 * n_sig] = 1.0
    coef = np.zeros(5)
    mp = np.empty(5)
    mn = np.empty(5)
    mx = np.empty(2)
    px = np.empty(2)
    mu = np.empty(2)
    lik = np.empty(2)
    hm = np.empty(2)
    hp = np.empty(2)
    for j in range(psi.shape[0]):
        mw = psi[j, n_par]
        c = math.exp(psi[j, n_par + 1])
        p = 0.5 / (1.0 + math.exp(-psi[j, n_par + 2]))
        sw2 = math.exp(2.0 * psi[j, n_par + 3])
        se2 = math.exp(2.0 * psi[j, n_par + 4])
        acc = 0.0
        for s in range(starts.size - 1):
            a, b = starts[s], starts[s + 1]
            for i in range(2):
                mx[i] = y[a]
                px[i] = p_init[s]
                mu[i] = 0.5
            for k in range(a, b):
                yk = y[k]
                # update with y(k) = x(k) + e(k), one Gaussian per level
                big = -np.inf
                for i in range(2):
                    sk = max(px[i] + se2, _TINY)
                    e = yk - mx[i]
                    lik[i] = -0.5 * (_LOG_2PI + math.log(sk) + e * e / sk)
                    if lik[i] > big:
                        big = lik[i]
                    g = px[i] / sk
                    mx[i] += g * e
                    px[i] = max(px[i] - g * px[i], 0.0)
                tot = 0.0
                for i in range(2):
                    lik[i] = mu[i] * math.exp(lik[i] - big)
                    tot += lik[i]
                tot = max(tot, _TINY)
                lk = big + math.log(tot)
                if k == a:
                    lk = 0.0
                else:
                    for i in range(2):
                        mu[i] = lik[i] / tot
                if keep:
                    ll[j, k] = lk
                acc += lk
                if k == b - 1:
                    continue
                # predict x(k+1) given the level at k
                for q in range(n_u):
                    fv[1 + q] = u[k, q]
                    fv[n_sig + 1 + q] = abs(u[k, q])
                for t in range(5):
                    coef[t] = 0.0
                for t in range(n_par):
                    coef[kind[t]] += psi[j, t] * fv[fa[t]] * fv[fb[t]]
                # mix the posteriors of x(k) (indexed by the level at k − 1) into one
                # Gaussian per level at k (IMM's interaction step) ...
                w00 = (1.0 - p) * mu[0]
                w10 = p * mu[1]
                w11 = (1.0 - p) * mu[1]
                w01 = p * mu[0]
                c0l = w00 + w10
                c1l = w11 + w01
                if c0l > _TINY:
                    a1, a2 = w00 / c0l, w10 / c0l
                    m0n = a1 * mx[0] + a2 * mx[1]
                    p0n = (a1 * (px[0] + (mx[0] - m0n) ** 2)
                           + a2 * (px[1] + (mx[1] - m0n) ** 2))
                else:
                    m0n, p0n = mx[0], px[0]
                if c1l > _TINY:
                    a1, a2 = w11 / c1l, w01 / c1l
                    m1n = a1 * mx[1] + a2 * mx[0]
                    p1n = (a1 * (px[1] + (mx[1] - m1n) ** 2)
                           + a2 * (px[0] + (mx[0] - m1n) ** 2))
                else:
                    m1n, p1n = mx[1], px[1]
                hm[0], hp[0], hm[1], hp[1] = m0n, p0n, m1n, p1n
                sm = c0l + c1l
                if sm > 0.0:
                    mu[0], mu[1] = c0l / sm, c1l / sm
                else:
                    mu[0], mu[1] = 0.5, 0.5
                # ... and predict x(k+1) through h with that level's current
                for i in range(2):
                    lev = c if i == 1 else -c
                    eh, vh = _predict(hm[i] + lev, hp[i], coef[0], coef[1], coef[2],
                                      coef[3], coef[4], mp, mn)
                    mx[i] = eh + mw
                    px[i] = vh + sw2
        total[j] = acc
