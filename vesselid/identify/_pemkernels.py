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
log σ_e]``; ``log σ = −inf`` switches a disturbance off. :func:`gaussian_filter` filters
rows independently (the line search's trial points), so it takes a row range and runs
under :func:`vesselid.core.threads.run_ranges`; :func:`gaussian_filter_tangent` filters
one row together with the exact derivatives of its innovations and their variances with
respect to chosen entries of ψ (the tangent recursion of the same filter: the
sensitivities of the Fisher scoring in one pass, with the square roots and divisions of
the row shared by every direction).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["N_NOISE", "bartlett_lagged", "gaussian_filter", "gaussian_filter_tangent",
           "quasi_scores", "selection_sums", "term_kinds"]

#: Noise parameters after θ in a parameter row (μ_w, ρ_v, σ_v, ρ_c, σ_c, σ_w, σ_e).
N_NOISE = 7

_SQ3 = np.sqrt(3.0)
_TINY = 1e-300
#: Directions of the tangent recursion advanced together in vector registers.
_LANES = 16


@njit(inline="always")
def _sigma_predict(mr, pr, c0, c1, c2, c3, c4):  # pragma: no cover
    """The three-point (σ = √3) prediction of ``h(r) = c0 + c1 r + c2|r| + c3 r|r| + c4 r²``
    through the relative speed ``r ~ N(mr, pr)``: the points ``r1, r2`` and their moduli,
    the predicted mean ``eh``, the points' deviations ``d0, d1, d2`` from it, the variance
    ``vh`` of ``h`` and the gain ``cov(h, r) / pr``."""
    spread = _SQ3 * np.sqrt(pr)
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
    return spread, r1, r2, a0, a1, a2, eh, d0, d1, d2, vh, gain


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
                pred = _sigma_predict(mr, pr, coef[0, i], coef[1, i], coef[2, i],
                                      coef[3, i], coef[4, i])
                eh, vh, gain = pred[6], pred[10], pred[11]
                p00[i] = vh + sw2[i]
                p01[i] = rv[i] * gain * (q01 + q11)
                p02[i] = rc[i] * gain * (q02 + q12)
                p11[i] = rv[i] * rv[i] * q11 + qv[i]
                p12[i] = rv[i] * rc[i] * q12
                p22[i] = rc[i] * rc[i] * q22 + qc[i]
                m0[i] = eh + mw[i]
                m1[i] = rv[i] * x1
                m2[i] = rc[i] * x2


@njit(cache=True, nogil=True)
def gaussian_filter_tangent(psi, idx, y, u, starts, p_init, kind, fa, fb,
                            eps, var, deps, dvar, grad, fisher, nll):  # pragma: no cover
    """:func:`gaussian_filter` of the one row ``psi`` (P + 7,) into ``eps``/``var`` (T,)
    with the derivatives ``deps[k, j] = ∂ε(k)/∂ψ[idx[j]]`` and ``dvar[k, j] =
    ∂S(k)/∂ψ[idx[j]]`` (T, d): every line of the filter differentiated (forward mode),
    the directions advancing together sample by sample. Where a variance is clipped at
    its floor its derivative is taken as zero; ``|r|`` is differentiated as ``sign r``.
    The first sample of every experiment holds no innovation: derivatives 0 there.
    Also the scoring's sums over the innovations (all but the first sample of each
    experiment): the negative log-likelihood ``nll[0] = Σ ½ (log S + ε²/S)``, its
    gradient ``grad[j] = Σ ∂ε_j ε/S + ½ ∂S_j (1/S − ε²/S²)`` and the Fisher information
    ``fisher[i, j] = Σ ∂ε_i ∂ε_j / S + ½ ∂S_i ∂S_j / S²`` (d, d).
    """
    n_par = kind.shape[0]
    n_u = u.shape[1]
    n_sig = 1 + n_u
    nd = idx.size
    # the directions padded to a multiple of _LANES (padding: no parameter, derivatives
    # zero): the compiled loop over directions runs in vector registers only from that
    # many iterations on, and a padded pass costs less than an unpadded one
    ndp = max(_LANES, ((nd + _LANES - 1) // _LANES) * _LANES)
    fv = np.empty(2 * n_sig + 1)
    fv[0] = 1.0
    fv[n_sig] = 1.0
    fv[2 * n_sig] = 1.0
    tf = np.empty(n_par)
    mw = psi[n_par]
    rv = np.tanh(psi[n_par + 1])
    sv2 = np.exp(2.0 * psi[n_par + 2])
    rc = np.tanh(psi[n_par + 3])
    sc2 = np.exp(2.0 * psi[n_par + 4])
    sw2 = np.exp(2.0 * psi[n_par + 5])
    se2 = np.exp(2.0 * psi[n_par + 6])
    qv = sv2 * (1.0 - rv * rv)
    qc = sc2 * (1.0 - rc * rc)
    # per direction: the θ term it moves (-1: none) and the noise parameters' derivatives
    term = np.full(ndp, -1, dtype=np.int64)
    tkind = np.zeros(ndp, dtype=np.int64)
    dmw = np.zeros(ndp)
    drv = np.zeros(ndp)
    dsv2 = np.zeros(ndp)
    drc = np.zeros(ndp)
    dsc2 = np.zeros(ndp)
    dsw2 = np.zeros(ndp)
    dse2 = np.zeros(ndp)
    dqv = np.zeros(ndp)
    dqc = np.zeros(ndp)
    for j in range(nd):
        p = idx[j]
        if p < n_par:
            term[j] = p
            tkind[j] = kind[p]
        elif p == n_par:
            dmw[j] = 1.0
        elif p == n_par + 1:
            drv[j] = 1.0 - rv * rv
            dqv[j] = -2.0 * sv2 * rv * drv[j]
        elif p == n_par + 2:
            dsv2[j] = 2.0 * sv2
            dqv[j] = 2.0 * qv
        elif p == n_par + 3:
            drc[j] = 1.0 - rc * rc
            dqc[j] = -2.0 * sc2 * rc * drc[j]
        elif p == n_par + 4:
            dsc2[j] = 2.0 * sc2
            dqc[j] = 2.0 * qc
        elif p == n_par + 5:
            dsw2[j] = 2.0 * sw2
        else:
            dse2[j] = 2.0 * se2
    coef = np.zeros(5)
    basis = np.empty((5, 3))
    # the direct effect of each direction on h at the three points (θ directions only)
    dir0 = np.zeros(ndp)
    dir1 = np.zeros(ndp)
    dir2 = np.zeros(ndp)
    n_theta = 0
    for j in range(nd):
        if term[j] >= 0:
            n_theta = j + 1
    dm0 = np.empty(ndp)
    dm1 = np.empty(ndp)
    dm2 = np.empty(ndp)
    dp00 = np.empty(ndp)
    dp01 = np.empty(ndp)
    dp02 = np.empty(ndp)
    dp11 = np.empty(ndp)
    dp12 = np.empty(ndp)
    dp22 = np.empty(ndp)
    cur_e = np.zeros(ndp)
    cur_s = np.zeros(ndp)
    acc_f = np.zeros((nd, ndp))
    acc_g = np.zeros(nd)
    acc_v = 0.0
    for s in range(starts.size - 1):
        a, b = starts[s], starts[s + 1]
        m0 = y[a]
        m1 = 0.0
        m2 = 0.0
        p00 = p_init[s]
        p01 = 0.0
        p02 = 0.0
        p11 = sv2
        p12 = 0.0
        p22 = sc2
        for j in range(ndp):
            dm0[j] = 0.0
            dm1[j] = 0.0
            dm2[j] = 0.0
            dp00[j] = 0.0
            dp01[j] = 0.0
            dp02[j] = 0.0
            dp11[j] = dsv2[j]
            dp12[j] = 0.0
            dp22[j] = dsc2[j]
        for k in range(a, b):
            yk = y[k]
            last = k == b - 1
            if not last:
                for q in range(n_u):
                    fv[1 + q] = u[k, q]
                    fv[n_sig + 1 + q] = abs(u[k, q])
                for t in range(n_par):
                    tf[t] = fv[fa[t]] * fv[fb[t]]
                coef[:] = 0.0
                for t in range(n_par):
                    coef[kind[t]] += psi[t] * tf[t]
            e = yk - m0 - m2
            sk = p00 + 2.0 * p02 + p22 + se2
            s_live = 1.0
            if sk < _TINY:
                sk = _TINY
                s_live = 0.0
            eps[k] = e
            var[k] = sk
            for j in range(ndp):
                cur_e[j] = -dm0[j] - dm2[j]
                cur_s[j] = s_live * (dp00[j] + 2.0 * dp02[j] + dp22[j] + dse2[j])
            for j in range(nd):
                deps[k, j] = cur_e[j]
                dvar[k, j] = cur_s[j]
            if k > a:  # an innovation: the scoring's sums
                inv_k = 1.0 / sk
                we = e * inv_k
                ws = 0.5 * (inv_k - e * e * inv_k * inv_k)
                acc_v += 0.5 * (np.log(sk) + e * e * inv_k)
                half2 = 0.5 * inv_k * inv_k
                for i in range(nd):
                    acc_g[i] += cur_e[i] * we + cur_s[i] * ws
                    ai = cur_e[i] * inv_k
                    bi = cur_s[i] * half2
                    for j in range(ndp):
                        acc_f[i, j] += ai * cur_e[j] + bi * cur_s[j]
            if last:
                continue
            h0, h1, h2 = p00 + p02, p01 + p12, p02 + p22
            inv = 1.0 / sk
            k0, k1, k2 = h0 * inv, h1 * inv, h2 * inv
            x0 = m0 + k0 * e
            x1 = m1 + k1 * e
            x2 = m2 + k2 * e
            q00 = p00 - k0 * h0
            q01 = p01 - k0 * h1
            q02 = p02 - k0 * h2
            q11 = p11 - k1 * h1
            q12 = p12 - k1 * h2
            q22 = p22 - k2 * h2
            mr = x0 + x1
            pr = q00 + 2.0 * q01 + q11
            r_live = 1.0
            if pr < _TINY:
                pr = _TINY
                r_live = 0.0
            c0, c1, c2, c3, c4 = coef[0], coef[1], coef[2], coef[3], coef[4]
            (spread, r1, r2, a0, a1, a2, eh, d0, d1, d2, vh,
             gain) = _sigma_predict(mr, pr, c0, c1, c2, c3, c4)
            # slopes of h at the three points, and the direct effect of the θ directions
            s0 = c1 + c2 * np.sign(mr) + 2.0 * c3 * a0 + 2.0 * c4 * mr
            s1 = c1 + c2 * np.sign(r1) + 2.0 * c3 * a1 + 2.0 * c4 * r1
            s2 = c1 + c2 * np.sign(r2) + 2.0 * c3 * a2 + 2.0 * c4 * r2
            basis[0, 0], basis[0, 1], basis[0, 2] = 1.0, 1.0, 1.0
            basis[1, 0], basis[1, 1], basis[1, 2] = mr, r1, r2
            basis[2, 0], basis[2, 1], basis[2, 2] = a0, a1, a2
            basis[3, 0], basis[3, 1], basis[3, 2] = mr * a0, r1 * a1, r2 * a2
            basis[4, 0], basis[4, 1], basis[4, 2] = mr * mr, r1 * r1, r2 * r2
            for j in range(n_theta):
                t = term[j]
                if t >= 0:
                    w = tf[t]
                    kk = tkind[j]
                    dir0[j] = w * basis[kk, 0]
                    dir1[j] = w * basis[kk, 1]
                    dir2[j] = w * basis[kk, 2]
            half_spread = spread / (2.0 * pr)
            inv6pr = 1.0 / (6.0 * pr)
            gain_pr = gain / pr
            sv01 = q01 + q11
            sc02 = q02 + q12
            rvg = rv * gain
            rcg = rc * gain
            inv2 = inv * inv
            for j in range(ndp):
                de = -dm0[j] - dm2[j]
                dsk = s_live * (dp00[j] + 2.0 * dp02[j] + dp22[j] + dse2[j])
                dh0 = dp00[j] + dp02[j]
                dh1 = dp01[j] + dp12[j]
                dh2 = dp02[j] + dp22[j]
                dinv = -inv2 * dsk
                dk0 = dh0 * inv + h0 * dinv
                dk1 = dh1 * inv + h1 * dinv
                dk2 = dh2 * inv + h2 * dinv
                dx0 = dm0[j] + dk0 * e + k0 * de
                dx1 = dm1[j] + dk1 * e + k1 * de
                dx2 = dm2[j] + dk2 * e + k2 * de
                dq00 = dp00[j] - dk0 * h0 - k0 * dh0
                dq01 = dp01[j] - dk0 * h1 - k0 * dh1
                dq02 = dp02[j] - dk0 * h2 - k0 * dh2
                dq11 = dp11[j] - dk1 * h1 - k1 * dh1
                dq12 = dp12[j] - dk1 * h2 - k1 * dh2
                dq22 = dp22[j] - dk2 * h2 - k2 * dh2
                dmr = dx0 + dx1
                dpr = r_live * (dq00 + 2.0 * dq01 + dq11)
                dspread = half_spread * dpr
                dg0 = s0 * dmr + dir0[j]
                dg1 = s1 * (dmr + dspread) + dir1[j]
                dg2 = s2 * (dmr - dspread) + dir2[j]
                deh = (4.0 * dg0 + dg1 + dg2) / 6.0
                dd0, dd1, dd2 = dg0 - deh, dg1 - deh, dg2 - deh
                dvh = (8.0 * d0 * dd0 + 2.0 * d1 * dd1 + 2.0 * d2 * dd2) / 6.0
                dgain = ((dd1 - dd2) * spread + (d1 - d2) * dspread) * inv6pr - gain_pr * dpr
                dp00[j] = dvh + dsw2[j]
                dp01[j] = (drv[j] * gain + rv * dgain) * sv01 + rvg * (dq01 + dq11)
                dp02[j] = (drc[j] * gain + rc * dgain) * sc02 + rcg * (dq02 + dq12)
                dp11[j] = 2.0 * rv * drv[j] * q11 + rv * rv * dq11 + dqv[j]
                dp12[j] = (drv[j] * rc + rv * drc[j]) * q12 + rv * rc * dq12
                dp22[j] = 2.0 * rc * drc[j] * q22 + rc * rc * dq22 + dqc[j]
                dm0[j] = deh + dmw[j]
                dm1[j] = drv[j] * x1 + rv * dx1
                dm2[j] = drc[j] * x2 + rc * dx2
            p00 = vh + sw2
            p01 = rv * gain * sv01
            p02 = rc * gain * sc02
            p11 = rv * rv * q11 + qv
            p12 = rv * rc * q12
            p22 = rc * rc * q22 + qc
            m0 = eh + mw
            m1 = rv * x1
            m2 = rc * x2
        # the first sample of an experiment holds no innovation
        eps[a] = 0.0
        var[a] = 1.0
        for j in range(nd):
            deps[a, j] = 0.0
            dvar[a, j] = 0.0
    nll[0] = acc_v
    for i in range(nd):
        grad[i] = acc_g[i]
        for j in range(nd):
            fisher[i, j] = acc_f[i, j]

@njit(cache=True, nogil=True)
def bartlett_lagged(sc, starts, bw, out):  # pragma: no cover
    """``out[k] = Σ_{l=1..bw} (1 − l/(bw+1)) sc[k − l]`` over lags within the experiment
    of ``k`` (``starts``), for scores ``sc`` (T, d): the Bartlett long-run variance of
    the scores is ``scᵀsc + C + Cᵀ`` with ``C = scᵀ out``."""
    nd = sc.shape[1]
    out[:, :] = 0.0
    for s in range(starts.size - 1):
        a, b = starts[s], starts[s + 1]
        for k in range(a + 1, b):
            for lag in range(1, min(bw, k - a) + 1):
                w = 1.0 - lag / (bw + 1.0)
                for j in range(nd):
                    out[k, j] += w * sc[k - lag, j]


@njit(cache=True, nogil=True, error_model="numpy")
def quasi_scores(je, js, eps, var, out):  # pragma: no cover
    """The per-sample scores of the quasi-likelihood, ``out[k, j] = ∂ε_j(k) ε/S +
    ½ ∂S_j(k) (1/S − ε²/S²)`` for sensitivities ``je``, ``js`` (d, T), innovations
    ``eps`` and variances ``var`` (T,), 0 where not finite; (T, d). The operations of
    the numpy expression ``je * (eps / S) + 0.5 * js * (1/S − eps·eps/S/S)`` (``/S`` as the
    product with ``1/S``) in its order, element by element: the same numbers."""
    d = je.shape[0]
    for k in range(eps.size):
        inv = 1.0 / var[k]
        we = eps[k] * inv
        ws = inv - eps[k] * eps[k] * inv * inv
        for j in range(d):
            v = je[j, k] * we + 0.5 * js[j, k] * ws
            out[k, j] = v if np.isfinite(v) else 0.0


@njit(cache=True, nogil=True)
def selection_sums(z, out):  # pragma: no cover
    """``out[j] = Σ_i z[i, J_i]²`` over the rows ``i`` of ``z`` (N, k) whose largest
    ``|z[i, ·]|`` is in column ``J_i = j`` (the first largest; a NaN counts as the
    largest, as in ``np.argmax``), summed in row order: ``np.bincount(J, weights=z[i,
    J]**2)``, the same numbers."""
    out[:] = 0.0
    for i in range(z.shape[0]):
        best = 0
        top = abs(z[i, 0])
        if not np.isnan(top):
            for j in range(1, z.shape[1]):
                v = abs(z[i, j])
                if np.isnan(v):
                    best = j
                    break
                if v > top:
                    best, top = j, v
        w = z[i, best]
        out[best] += w * w


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
