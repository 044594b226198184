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
* :func:`noise_window` — windowed means of the estimated regressor noise (colour test).
* :func:`design_scan`, :func:`design_centre`, :func:`design_ar_centre` — the
  explicit-matrix design of one equation (instruments, regressors, target) masked,
  scaled, (AR-prefiltered and) centred without the stacked temporaries.
* :func:`moving_sums` — :func:`vesselid.identify.covariance.moving_sums` (the Bartlett
  long-run covariances' running-sum differences) in one pass, bit-identical.
* :func:`centred_moving_sums` — the same moving sums of a time-major series minus its
  mean, without the transposed centred copy (bit-identical).
* :func:`equilibrate_one` — the equilibration scales of one small system, to rounding
  (the singularity decision of a checked fit's solves).
* :func:`column_sums` — column sums (of squares) in row order, bit-identical to numpy's.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from vesselid.core.threads import run_ranges
from vesselid.model.regressors import fill_factors_xu, kernel, one_step, regressors

#: Below this many samples the segments run in the calling thread only.
PARALLEL_MIN_SAMPLES = 200_000

__all__ = [
    "ar_filter",
    "autocov",
    "center",
    "centred_moving_sums",
    "column_sums",
    "combined_moments",
    "cond_bound",
    "cross_sums",
    "design_ar_centre",
    "design_centre",
    "design_scan",
    "equilibrate_one",
    "moving_sums",
    "noise_window",
    "simulated_regressors",
]


@kernel()
def simulated_regressors(target, u, starts, group, theta, fac, eq, limit):
    """``ζ(k) = Φ([x̂(k−1); u(k−1)])`` with ``x̂`` simulated from ``theta[group[s]]``.

    Returns ``(z (T, P) with NaN in each segment's first row, ok (S,) bool)``; a
    segment whose simulation leaves ``±limit[s]`` is all NaN and not ok.
    """
    t_len, n = target.shape
    m = u.shape[1]
    n_par = fac.shape[0]
    z = np.full((t_len, n_par), np.nan)
    ok = np.ones(starts.shape[0] - 1, dtype=np.bool_)
    f = np.empty(2 * (n + m) + 1)
    xh = np.empty(n)
    for s in range(starts.shape[0] - 1):
        a = starts[s]
        b = starts[s + 1]
        th = theta[group[s]]
        for i in range(n):
            xh[i] = target[a, i]
        for k in range(a + 1, b):
            fill_factors_xu(xh, u[k - 1], f)
            xh[:] = 0.0
            regressors(fac, f, z[k])
            one_step(eq, th, z[k], xh)
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
def _window_valid(valid, k, p):
    """Whether rows ``k − p … k`` are all valid (the rows an AR(p) filter reads)."""
    for j in range(p + 1):
        if not valid[k - j]:
            return False
    return True


@njit(cache=True, inline="always")
def _fir_at(c, x, k, col, p, scale):
    """``Σ_{j=0}^{p} c[j] · (x[k − j, col] · scale)`` in that order (``scale`` 1.0 is exact:
    the plain filter); inlined into the callers."""
    acc = 0.0
    for j in range(p + 1):
        acc += c[j] * (x[k - j, col] * scale)
    return acc


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
            if not _window_valid(valid, k, p):
                continue
            vf[k] = True
            for c in range(k_cols):
                out[k, c] = _fir_at(coef[s], x, k, c, p, 1.0)
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
    """Per segment: ``Σ z φᵀ`` (S, K, P), ``Σ z y`` (S, K), ``Σ z zᵀ`` (S, K, K), count.
    Each sum runs over the valid rows in order, in small local accumulators (the row's
    values loaded once; the same additions as into the outputs)."""
    n_seg = starts.shape[0] - 1
    k_cols = z.shape[1]
    p_cols = phi.shape[1]
    a_out = np.zeros((n_seg, k_cols, p_cols))
    b_out = np.zeros((n_seg, k_cols))
    m_out = np.zeros((n_seg, k_cols, k_cols))
    cnt = np.zeros(n_seg)
    la = np.empty((k_cols, p_cols))
    lb = np.empty(k_cols)
    lm = np.empty((k_cols, k_cols))
    zr = np.empty(k_cols)
    pr = np.empty(p_cols)
    for s in range(n_seg):
        la[:, :] = 0.0
        lb[:] = 0.0
        lm[:, :] = 0.0
        c = 0.0
        for k in range(starts[s], starts[s + 1]):
            if not valid[k]:
                continue
            c += 1
            yk = y[k]
            for i in range(k_cols):
                zr[i] = z[k, i]
            for j in range(p_cols):
                pr[j] = phi[k, j]
            for i in range(k_cols):
                zi = zr[i]
                lb[i] += zi * yk
                for j in range(p_cols):
                    la[i, j] += zi * pr[j]
                for j in range(i, k_cols):
                    lm[i, j] += zi * zr[j]
        cnt[s] = c
        for i in range(k_cols):
            b_out[s, i] = lb[i]
            for j in range(p_cols):
                a_out[s, i, j] = la[i, j]
            for j in range(k_cols):
                m_out[s, i, j] = lm[i, j] if j >= i else lm[j, i]
    return a_out, b_out, m_out, cnt



@njit(inline="always")
def _combined_row(k, regsig, u, xh, fac, ztype, zpar, f_dat, f_sim, f_l2, f_l3, phi, z):
    fill_factors_xu(regsig[k - 1], u[k - 1], f_dat)
    fill_factors_xu(xh, u[k - 1], f_sim)
    fill_factors_xu(regsig[k - 2], u[k - 1], f_l2)
    fill_factors_xu(regsig[k - 3], u[k - 1], f_l3)
    regressors(fac, f_dat, phi)
    for c in range(ztype.shape[0]):
        p = zpar[c]
        t = ztype[c]
        if t == 0:
            z[c] = f_sim[fac[p, 0]] * f_sim[fac[p, 1]]
        elif t == 2:
            z[c] = f_l2[fac[p, 0]] * f_l2[fac[p, 1]]
        else:
            z[c] = f_l3[fac[p, 0]] * f_l3[fac[p, 1]]


def combined_moments(regsig, target, u, starts, group, theta, active, fac, eq, ztype, zpar,
                     zeq, limit, second, theta1, means_z, means_phi, means_y, means_g, lags,
                     s_a, s_b, s_m, s_z, s_phi, s_y, count, status, s_hac):
    """Fused pass of the combined (simulated + delayed) instrument set, per segment.

    ``second = False``: raw sums over the rows ``k = a+3 … b−1`` — ``Σ z φᵀ`` (S, K, P),
    ``Σ z y_eq(z)`` (S, K), ``Σ z zᵀ`` (S, K, K), ``Σ z``, ``Σ φ``, ``Σ y``, count.
    ``second = True``: the Bartlett long-run variance (moving-sum form) of the scores
    ``(z − z̄) ε − ḡ``, ``ε = (y − ȳ) − (φ − φ̄)ᵀθ₁`` of each column's equation, into
    ``s_hac`` (S, K, K). Instrument column ``c`` is term ``zpar[c]`` of equation
    ``zeq[c]`` evaluated on the simulated state (``ztype 0``) or the measured state
    delayed 2 / 3 samples (``ztype 2 / 3``), inputs at ``k − 1``.
    """
    run_ranges(_combined_range, starts.shape[0] - 1,
               (regsig, target, u, starts, group, theta, active, fac, eq, ztype, zpar, zeq,
                limit, second, theta1, means_z, means_phi, means_y, means_g, lags, s_a, s_b,
                s_m, s_z, s_phi, s_y, count, status, s_hac),
               parallel=starts.shape[0] > 2 and target.shape[0] >= PARALLEL_MIN_SAMPLES)


@kernel(nogil=True)
def _combined_range(lo, hi, regsig, target, u, starts, group, theta, active, fac, eq, ztype,
                    zpar, zeq, limit, second, theta1, means_z, means_phi, means_y, means_g, lags,
                    s_a, s_b, s_m, s_z, s_phi, s_y, count, status, s_hac):
    """Segments ``lo … hi−1`` of :func:`combined_moments` (one serial kernel)."""
    n = regsig.shape[1]
    m = u.shape[1]
    n_par = fac.shape[0]
    k_tot = ztype.shape[0]
    n_f = 2 * (n + m) + 1
    for s in range(lo, hi):
        g = group[s]
        if not active[g]:
            continue
        a = starts[s]
        b = starts[s + 1]
        th = theta[g]
        f_dat = np.empty(n_f)
        f_sim = np.empty(n_f)
        f_l2 = np.empty(n_f)
        f_l3 = np.empty(n_f)
        xh = np.empty(n)
        phi = np.empty(n_par)
        phi_sim = np.empty(n_par)
        z = np.empty(k_tot)
        e = np.empty(n)
        sc = np.empty(k_tot)
        ring = np.zeros((lags + 1, k_tot))
        h = np.zeros(k_tot)
        l_a = np.zeros((k_tot, n_par))
        l_b = np.zeros(k_tot)
        l_m = np.zeros((k_tot, k_tot))
        l_z = np.zeros(k_tot)
        l_phi = np.zeros(n_par)
        l_y = np.zeros(n)
        l_h = np.zeros((k_tot, k_tot))
        status[s] = 0
        for i in range(n):
            xh[i] = target[a, i]
        # advance the auxiliary model to k = a + 3 (rows before have no delayed states)
        cnt = 0
        for k in range(a + 1, b):
            if k >= a + 3:
                _combined_row(k, regsig, u, xh, fac, ztype, zpar, f_dat, f_sim, f_l2,
                              f_l3, phi, z)
                if not second:
                    cnt += 1
                    for c in range(k_tot):
                        zc = z[c]
                        l_b[c] += zc * target[k, zeq[c]]
                        l_z[c] += zc
                        for p in range(n_par):
                            l_a[c, p] += zc * phi[p]
                        for c2 in range(c, k_tot):
                            l_m[c, c2] += zc * z[c2]
                    for p in range(n_par):
                        l_phi[p] += phi[p]
                    for i in range(n):
                        l_y[i] += target[k, i]
                else:
                    th1 = theta1[g]
                    for i in range(n):
                        e[i] = target[k, i] - means_y[s, i]
                    for p in range(n_par):
                        e[eq[p]] -= (phi[p] - means_phi[s, p]) * th1[p]
                    slot = cnt % (lags + 1)
                    for c in range(k_tot):
                        sc[c] = (z[c] - means_z[s, c]) * e[zeq[c]] - means_g[s, c]
                        h[c] += sc[c] - ring[slot, c]
                        ring[slot, c] = sc[c]
                    cnt += 1
                    for c in range(k_tot):
                        hc = h[c]
                        for c2 in range(c, k_tot):
                            l_h[c, c2] += hc * h[c2]
            # advance the auxiliary model: x̂(k) from x̂(k−1), u(k−1)
            fill_factors_xu(xh, u[k - 1], f_sim)
            xh[:] = 0.0
            regressors(fac, f_sim, phi_sim)
            one_step(eq, th, phi_sim, xh)
            bad = False
            for i in range(n):
                if not abs(xh[i]) <= limit[s]:
                    bad = True
            if bad:
                status[s] = 1
                break
        if second:
            # drain the window: the padded tail of the moving sums
            for _ in range(lags):
                slot = cnt % (lags + 1)
                for c in range(k_tot):
                    h[c] -= ring[slot, c]
                    ring[slot, c] = 0.0
                cnt += 1
                for c in range(k_tot):
                    hc = h[c]
                    for c2 in range(c, k_tot):
                        l_h[c, c2] += hc * h[c2]
            for c in range(k_tot):
                for c2 in range(c, k_tot):
                    s_hac[s, c, c2] = l_h[c, c2] / (lags + 1.0)
                    s_hac[s, c2, c] = s_hac[s, c, c2]
        else:
            count[s] = cnt
            for c in range(k_tot):
                s_b[s, c] = l_b[c]
                s_z[s, c] = l_z[c]
                for p in range(n_par):
                    # only the column's own equation (block-diagonal A)
                    s_a[s, c, p] = l_a[c, p] if eq[p] == zeq[c] else 0.0
                for c2 in range(c, k_tot):
                    s_m[s, c, c2] = l_m[c, c2]
                    s_m[s, c2, c] = l_m[c, c2]
            for p in range(n_par):
                s_phi[s, p] = l_phi[p]
            for i in range(n):
                s_y[s, i] = l_y[i]


_FLOAT_MAX = float(np.finfo(np.float64).max)


@njit(cache=True)
def _finite_or_clip(x):
    """``np.nan_to_num`` of one value: NaN → 0, ±inf → ± the largest finite float."""
    if np.isnan(x):
        return 0.0
    if np.isinf(x):
        return _FLOAT_MAX if x > 0 else -_FLOAT_MAX
    return x


@njit(cache=True)
def noise_window(phi, z, cols, starts, lo, hi):
    """:func:`vesselid.identify.gmm.noise_instruments` in one compiled pass, the same
    operations in the same order (bit-identical): ``η = nan_to_num(φ − ζ)`` on the
    columns ``cols``, its running sum over all rows (``np.cumsum``'s sequential order),
    the window means ``(S[k − lo + 1] − S[k − hi]) / (hi − lo + 1)`` where the window lies
    inside the row's experiment after its first row, NaN elsewhere and wherever a
    non-finite simulated column falls in the window."""
    t_len = phi.shape[0]
    n_c = cols.shape[0]
    csum = np.zeros((t_len + 1, n_c))
    bad = np.zeros(t_len + 1, dtype=np.int64)
    for k in range(t_len):
        fin = True
        for j in range(n_c):
            c = cols[j]
            zk = z[k, c]
            if not np.isfinite(zk):
                fin = False
            eta = _finite_or_clip(phi[k, c] - zk)
            csum[k + 1, j] = eta if k == 0 else csum[k, j] + eta
        bad[k + 1] = bad[k] + (0 if fin else 1)
    out = np.full((t_len, n_c), np.nan)
    width = hi - lo + 1.0
    for s in range(starts.shape[0] - 1):
        a = starts[s]
        for r in range(a + 1 + hi, starts[s + 1]):
            if bad[r - lo + 1] - bad[r - hi] > 0:
                continue
            for j in range(n_c):
                out[r, j] = (csum[r - lo + 1, j] - csum[r - hi, j]) / width
    return out


@njit(cache=True)
def design_scan(z, phi, p_lo, p_hi, target, i_eq):
    """Rows where every column of ``[z, phi[:, p_lo:p_hi], target[:, i_eq]]`` is finite,
    and each column's ``max |·|`` over those rows (0 if none): what
    :func:`vesselid.identify.gmm.solve_equations` computes on the stacked matrix."""
    t_len, k_z = z.shape
    n_col = k_z + (p_hi - p_lo) + 1
    valid = np.zeros(t_len, dtype=np.bool_)
    cmax = np.zeros(n_col)
    for k in range(t_len):
        ok = np.isfinite(target[k, i_eq])
        for j in range(k_z):
            if not np.isfinite(z[k, j]):
                ok = False
        for p in range(p_lo, p_hi):
            if not np.isfinite(phi[k, p]):
                ok = False
        if not ok:
            continue
        valid[k] = True
        for j in range(k_z):
            v = abs(z[k, j])
            if v > cmax[j]:
                cmax[j] = v
        for p in range(p_lo, p_hi):
            v = abs(phi[k, p])
            if v > cmax[k_z + p - p_lo]:
                cmax[k_z + p - p_lo] = v
        v = abs(target[k, i_eq])
        if v > cmax[n_col - 1]:
            cmax[n_col - 1] = v
    return valid, cmax


@njit(cache=True)
def design_centre(z, phi, p_lo, p_hi, target, i_eq, valid, col, starts):
    """The masked (invalid rows 0), column-scaled (``col``) and per-segment centred
    ``z``, ``phi[:, p_lo:p_hi]`` and ``target[:, i_eq]`` as three contiguous arrays: the
    same operations in the same order as stacking, ``np.where``, scaling and
    :func:`center` (bit-identical)."""
    t_len, k_z = z.shape
    n_p = p_hi - p_lo
    last = k_z + n_p
    zz = np.empty((t_len, k_z))
    pp = np.empty((t_len, n_p))
    yy = np.empty(t_len)
    for k in range(t_len):
        if valid[k]:
            for j in range(k_z):
                zz[k, j] = z[k, j] * col[j]
            for p in range(n_p):
                pp[k, p] = phi[k, p_lo + p] * col[k_z + p]
            yy[k] = target[k, i_eq] * col[last]
        else:
            for j in range(k_z):
                zz[k, j] = 0.0 * col[j]
            for p in range(n_p):
                pp[k, p] = 0.0 * col[k_z + p]
            yy[k] = 0.0 * col[last]
    mean = np.empty(last + 1)
    for s in range(starts.shape[0] - 1):
        _centre_rows(zz, pp, yy, valid, starts[s], starts[s + 1], mean)
    return zz, pp, yy


@njit(cache=True)
def _centre_rows(zz, pp, yy, valid, a, b, mean):
    """Subtract from rows ``a … b−1`` of ``zz``, ``pp``, ``yy`` their means over the
    ``valid`` rows (in place; nothing when none is valid): :func:`center` of one segment,
    the sums in row order."""
    k_z = zz.shape[1]
    n_p = pp.shape[1]
    last = k_z + n_p
    cnt = 0
    mean[:] = 0.0
    for k in range(a, b):
        if valid[k]:
            cnt += 1
            for j in range(k_z):
                mean[j] += zz[k, j]
            for q in range(n_p):
                mean[k_z + q] += pp[k, q]
            mean[last] += yy[k]
    if cnt == 0:
        return
    for j in range(last + 1):
        mean[j] /= cnt
    for k in range(a, b):
        for j in range(k_z):
            zz[k, j] = zz[k, j] - mean[j]
        for q in range(n_p):
            pp[k, q] = pp[k, q] - mean[k_z + q]
        yy[k] = yy[k] - mean[last]


@njit(cache=True)
def design_ar_centre(z, phi, p_lo, p_hi, target, i_eq, valid, col, starts, coef, group):
    """:func:`design_centre` with the noise-model prefilter: the masked, column-scaled
    ``[z, phi[:, p_lo:p_hi], target[:, i_eq]]`` filtered per segment ``s`` by
    ``coef[group[s]]`` and centred over the filtered valid rows — the same operations in
    the same order as stacking, ``np.where``, scaling, :func:`ar_filter` and
    :func:`center` (bit-identical). Returns ``(zz, pp, yy, valid_f)``."""
    t_len, k_z = z.shape
    n_p = p_hi - p_lo
    last = k_z + n_p
    p = coef.shape[1] - 1
    zz = np.zeros((t_len, k_z))
    pp = np.zeros((t_len, n_p))
    yy = np.zeros(t_len)
    vf = np.zeros(t_len, dtype=np.bool_)
    mean = np.empty(last + 1)
    for s in range(starts.shape[0] - 1):
        a = starts[s]
        b = starts[s + 1]
        c = coef[group[s]]
        for k in range(a + p, b):
            if not _window_valid(valid, k, p):
                continue
            vf[k] = True
            for col_j in range(k_z):
                zz[k, col_j] = _fir_at(c, z, k, col_j, p, col[col_j])
            for q in range(n_p):
                pp[k, q] = _fir_at(c, phi, k, p_lo + q, p, col[k_z + q])
            yy[k] = _fir_at(c, target, k, i_eq, p, col[last])
        _centre_rows(zz, pp, yy, vf, a, b, mean)
    return zz, pp, yy, vf


@njit(cache=True)
def moving_sums(x, lag):
    """:func:`vesselid.identify.covariance.moving_sums` of a C-contiguous ``x`` (q, n),
    bit-identical: the same running sums (``np.cumsum``'s sequential order, its first
    value ``x[:, 0]``) and the same differences ``C[t + lag + 1] − C[t]`` of the
    zero-padded running sum ``C`` (zero before the series, held at the last sum after
    it), one row at a time with the last ``lag + 1`` sums in a ring buffer (no padded
    copy, no second pass)."""
    q, n = x.shape
    m = n + lag
    w = lag + 1
    out = np.empty((q, m))
    ring = np.empty(w)
    for i in range(q):
        acc = 0.0
        j = 0
        for t in range(n):
            acc = x[i, t] if t == 0 else acc + x[i, t]
            b = ring[j] if t > lag else 0.0  # C[t] = the sum of rows 0 … t − lag − 1
            out[i, t] = acc - b
            ring[j] = acc
            j += 1
            if j == w:
                j = 0
        for t in range(n, m):  # C[t + lag + 1] is held at the last sum
            b = ring[j] if t > lag else 0.0
            out[i, t] = acc - b
            j += 1
            if j == w:
                j = 0
    return out


@njit(cache=True)
def centred_moving_sums(g, mean, lag):  # pragma: no cover - compiled
    """:func:`moving_sums` of ``(g − mean)ᵀ`` for a C-contiguous ``g`` (n, q), without
    the transposed centred copy: the same differences ``g(t, i) − mean(i)`` (the values
    ``gᵀ − mean`` holds), summed in the same order, so the result is bit-identical to
    ``moving_sums(g.T.copy() − mean[:, None], lag)``. Time runs in the outer loop (one
    pass over ``g``), one running sum and ring buffer per column."""
    n, q = g.shape
    m = n + lag
    w = lag + 1
    out = np.empty((q, m))
    ring = np.empty((q, w))
    acc = np.zeros(q)
    j = 0
    for t in range(n):
        for i in range(q):
            x = g[t, i] - mean[i]
            acc[i] = x if t == 0 else acc[i] + x
            b = ring[i, j] if t > lag else 0.0
            out[i, t] = acc[i] - b
            ring[i, j] = acc[i]
        j += 1
        if j == w:
            j = 0
    for t in range(n, m):
        for i in range(q):
            b = ring[i, j] if t > lag else 0.0
            out[i, t] = acc[i] - b
        j += 1
        if j == w:
            j = 0
    return out


@njit(cache=True, error_model="numpy")
def equilibrate_one(a, max_iter, tol):
    """The row and column scales of :func:`vesselid.identify.linalg.equilibrate` for one
    matrix ``a`` (n, m) with finite entries and no zero row or column, in compiled
    loops: the same sweeps, with the C library's ``log``/``exp`` and sequential sums
    instead of numpy's (so the scales agree to rounding, not bit for bit). Used only to
    *decide* whether a system is singular, with a margin around the threshold inside
    which the exact computation decides (:func:`vesselid.identify.linalg.solve`)."""
    n, m = a.shape
    peak = 0.0
    for i in range(n):
        for j in range(m):
            v = abs(a[i, j])
            if v > peak:
                peak = v
    sq = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            v = abs(a[i, j]) / peak
            sq[i, j] = v * v
    r = np.ones(n)
    c = np.ones(m)
    r_new = np.empty(n)
    c_new = np.empty(m)
    for _ in range(max_iter):
        for j in range(m):
            acc = 0.0
            for i in range(n):
                acc += sq[i, j] * (r[i] * r[i])
            c_new[j] = 1.0 / np.sqrt(acc) if acc > 0 else 1.0
        tot = 0.0
        for i in range(n):
            acc = 0.0
            for j in range(m):
                acc += sq[i, j] * (c_new[j] * c_new[j])
            r_new[i] = 1.0 / np.sqrt(acc) if acc > 0 else 1.0
            tot += np.log(r_new[i])
        shift = np.exp(tot / n)
        delta = 0.0
        for i in range(n):
            v = r_new[i] / shift
            d = abs(np.log(v / r[i]))
            if not d <= delta:  # NaN counts as not converged
                delta = d if d == d else np.inf
            r[i] = v
        for j in range(m):
            v = c_new[j] * shift
            d = abs(np.log(v / c[j]))
            if not d <= delta:
                delta = d if d == d else np.inf
            c[j] = v
        if delta < tol:
            break
    for j in range(m):
        c[j] = c[j] / peak
    return r, c


@njit(cache=True, inline="always")
def gauss_jordan(m, n, floor, reciprocal):
    """Gauss–Jordan elimination with partial pivoting of the augmented matrix
    ``m[:n, :2n] = [A | I]``, in place, to ``[I | A⁻¹]``; False (``m`` left part-way) where
    a pivot is not above ``floor``. ``reciprocal``: the pivot row is multiplied by
    ``1 / pivot`` (one division), else each entry is divided by the pivot — the two
    round differently, and each caller keeps its own arithmetic:
    :func:`cond_bound` (``floor = 0``, division) and the recursive estimator's small
    inverses (:func:`vesselid.identify.recursive._solve_small`: a pivot floor relative to
    the largest entry, reciprocal).

    Also inlined into :mod:`vesselid.identify.recursive`'s kernel, whose numba cache
    tracks its own file only: a change here needs that module's cache files
    (``__pycache__/recursive.*.nbi``/``.nbc``) removed.
    """
    for k in range(n):
        piv = k
        best = abs(m[k, k])
        for i in range(k + 1, n):
            if abs(m[i, k]) > best:
                best = abs(m[i, k])
                piv = i
        if not best > floor:
            return False
        if piv != k:
            for j in range(2 * n):
                t = m[k, j]
                m[k, j] = m[piv, j]
                m[piv, j] = t
        d = m[k, k]
        if reciprocal:
            inv = 1.0 / d
            for j in range(2 * n):
                m[k, j] *= inv
        else:
            for j in range(2 * n):
                m[k, j] /= d
        for i in range(n):
            if i != k:
                f = m[i, k]
                if f != 0.0:
                    for j in range(2 * n):
                        m[i, j] -= f * m[k, j]
    return True


@njit(cache=True, error_model="numpy")
def cond_bound(a, max_iter, tol):
    """An upper bound of the condition number of the equilibrated square matrix ``a``
    (n, n) that :func:`equilibrate_one` gives: ``‖S‖_F ‖S⁻¹‖_F ≥ κ₂(S)`` of
    ``S = (a r) c``, ``S⁻¹`` by Gauss–Jordan elimination with partial pivoting; ``inf``
    where ``a`` has a non-finite entry, a zero row or column, or a zero pivot. One call
    instead of the checks, the scales, the scaled matrix and its SVD: the fast side of
    :func:`vesselid.identify.linalg._cond_below` (a bound far below its threshold proves
    the system regular; elsewhere the exact computation decides)."""
    n = a.shape[0]
    if a.shape[1] != n or n == 0:
        return np.inf
    for i in range(n):
        row_nz = False
        for j in range(n):
            v = a[i, j]
            if not np.isfinite(v):
                return np.inf
            if v != 0.0:
                row_nz = True
        if not row_nz:
            return np.inf
    for j in range(n):
        col_nz = False
        for i in range(n):
            if a[i, j] != 0.0:
                col_nz = True
        if not col_nz:
            return np.inf
    r, c = equilibrate_one(a, max_iter, tol)
    m = np.empty((n, 2 * n))
    fro = 0.0
    for i in range(n):
        for j in range(n):
            v = (a[i, j] * r[i]) * c[j]
            m[i, j] = v
            fro += v * v
            m[i, n + j] = 1.0 if i == j else 0.0
    if not gauss_jordan(m, n, 0.0, False):
        return np.inf
    fro_inv = 0.0
    for i in range(n):
        for j in range(n):
            v = m[i, n + j]
            fro_inv += v * v
    bound = np.sqrt(fro) * np.sqrt(fro_inv)
    return bound if bound == bound else np.inf


@njit(cache=True)
def column_sums(x, square):
    """``Σ_t x[t, k]`` (``square``: of ``x[t, k]²``) of a C-contiguous ``x`` (T, K), each
    column summed in row order: numpy's ``x.sum(axis=0)`` of such an array with ``K ≥ 2``
    (it adds the rows one after another), bit-identical, without the per-row loop
    overhead or the squared copy."""
    n_rows, n_cols = x.shape
    out = np.zeros(n_cols)
    for t in range(n_rows):
        for k in range(n_cols):
            v = x[t, k]
            out[k] += v * v if square else v
    return out
