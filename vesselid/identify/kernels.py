"""Compiled moment kernels for least squares and instrumental variables.

Data of many experiments (and many Monte Carlo runs) are concatenated along time;
``starts[s] : starts[s+1]`` is segment (experiment) ``s``, which belongs to
parameter group ``group[s]`` (one group per independent estimate). For every
segment the kernels accumulate, over the equations ``k = 1 … N_s − 1`` of the
one-step-ahead predictor (3) / (9),

* ``S_zφ = Σ z(k) φᵀ(k)`` (within each state equation's block only),
* ``S_zy = Σ z(k) y_i(k)``, ``S_z = Σ z(k)``, ``S_φ = Σ φ(k)``, ``S_y = Σ y(k)``,

where ``φ(k) = Φ([ỹ(k−1); u(k−1)])`` are the regressors built from the regressor
signal ``ỹ`` (the measured state, or the aggregated state of eq. (9)), ``y`` is the
target measurement, and ``z(k)`` is either ``φ(k)`` itself (least squares (16)) or
the instrument ``ζ(k) = Φ([x̂(k−1); u(k−1)])`` computed from a simulation of the
auxiliary model ``x̂(k+1) = Φᵀ([x̂(k); u(k)]) θ_g`` (paper §6, Thil et al. 2008).
Zero-mean instruments (A7) follow from these sums without a second pass:
``Σ (z − z̄) φᵀ = S_zφ − S_z S_φᵀ / N``.

The simulation and the accumulation are fused, so one refined-IV iteration over a
whole Monte Carlo study is one pass over the data.
"""

from __future__ import annotations

import numpy as np

from vesselid.core.threads import run_ranges
from vesselid.identify._fastkernels import specialised_moments
from vesselid.model.regressors import fill_factors_xu, kernel, one_step, regressors

__all__ = ["AUX_DIVERGED", "AUX_OK", "instrument_matrix", "moments", "regressor_matrix"]

AUX_OK = 0
AUX_DIVERGED = 1

#: Instrument modes of :func:`moments`.
MODE_LS = 0
MODE_SIMULATED = 1
MODE_LAGGED = 2


#: Below this many samples the serial kernels are used (thread start-up costs more).
PARALLEL_MIN_SAMPLES = 200_000


@kernel(nogil=True)
def _moments_range(
    lo, hi, regsig, target, u, starts, group, theta, active, mode, fac, eq, block_start,
    block_src, limit, s_zphi, s_zy, s_z, s_phi, s_y, count, status,
):
    for s in range(lo, hi):
        _moments_segment(s, regsig, target, u, starts, group, theta, active, mode, fac, eq,
                         block_start, block_src, limit, s_zphi, s_zy, s_z, s_phi, s_y, count,
                         status)


def moments(
    regsig, target, u, starts, group, theta, active, mode, fac, eq, block_start, block_src,
    limit, s_zphi, s_zy, s_z, s_phi, s_y, count, status,
):
    """Accumulate per-segment LS/IV moments (see module docstring).

    Parameters
    ----------
    regsig, target : (T, n) float arrays
    u : (T, m) float array
    starts : (S+1,) int array
    group : (S,) int array, group of each segment
    theta : (G, P) auxiliary-model parameters per group (used in ``MODE_SIMULATED``)
    active : (G,) bool, groups to process (others are left untouched)
    mode : int, instruments: ``MODE_LS`` (z = φ), ``MODE_SIMULATED`` (auxiliary model
        ``theta``) or ``MODE_LAGGED`` (basic IV, ``ζ(k) = Φ([ỹ(k−2); u(k−1)])``)
    fac, eq : factor-coded terms (:class:`vesselid.model.regressors.RegressorLayout`) and their
    equations;
        ``block_start`` (n+1,) parameter offsets per equation; ``block_src`` (n,): an
        earlier equation with the same terms (whose ``S_zφ``, ``S_z``, ``S_φ`` block is
        copied instead of accumulated again), or the equation itself
    limit : (S,) float, divergence limit of the auxiliary simulation per segment
    s_zphi (S,P,P), s_zy (S,P), s_z (S,P), s_phi (S,P), s_y (S,n), count (S,), status (S,)
        Outputs, overwritten for active segments.

    Segments run in parallel threads when there are several and enough samples
    (:func:`vesselid.core.threads.run_ranges`; one serial kernel either way).
    """
    parallel = starts.shape[0] > 2 and target.shape[0] >= PARALLEL_MIN_SAMPLES
    if mode in (MODE_LS, MODE_SIMULATED):
        # same computation, unrolled for this structure (bit-identical, several times faster)
        fast = specialised_moments(regsig.shape[1], u.shape[1], fac, eq, block_start)
        if fast is not None and fast(
                parallel, regsig, target, u, starts, group, theta, active,
                mode == MODE_SIMULATED, limit, s_zphi, s_zy, s_z, s_phi, s_y, count, status):
            return
    run_ranges(_moments_range, starts.shape[0] - 1,
               (regsig, target, u, starts, group, theta, active, mode, fac, eq, block_start,
                block_src, limit, s_zphi, s_zy, s_z, s_phi, s_y, count, status),
               parallel=parallel)


@kernel(inline="always")
def _moments_segment(
    s, regsig, target, u, starts, group, theta, active, mode, fac, eq, block_start, block_src,
    limit, s_zphi, s_zy, s_z, s_phi, s_y, count, status,
):
    n = regsig.shape[1]
    m = u.shape[1]
    n_par = fac.shape[0]
    n_f = 2 * (n + m) + 1
    g = group[s]
    if not active[g]:
        return
    a = starts[s]
    b = starts[s + 1]
    f_dat = np.empty(n_f)
    f_sim = np.empty(n_f)
    xh = np.empty(n)
    phi = np.empty(n_par)
    z = np.empty(n_par)
    # local accumulators keep the inner loop in cache
    l_zphi = np.zeros((n_par, n_par))
    l_zy = np.zeros(n_par)
    l_z = np.zeros(n_par)
    l_phi = np.zeros(n_par)
    l_y = np.zeros(n)
    for i in range(n):
        xh[i] = target[a, i]
    status[s] = AUX_OK
    count[s] = b - a - 1
    th = theta[g]
    for k in range(a + 1, b):
        fill_factors_xu(regsig[k - 1], u[k - 1], f_dat)
        regressors(fac, f_dat, phi)
        if mode == MODE_LAGGED:
            # basic IV: regressors of the measurements two samples back
            kk = k - 2 if k - 2 >= a else a
            fill_factors_xu(regsig[kk], u[k - 1], f_sim)
            regressors(fac, f_sim, z)
        elif mode == MODE_SIMULATED:
            # advance the auxiliary model: x̂(k) = Φᵀ([x̂(k−1); u(k−1)]) θ
            fill_factors_xu(xh, u[k - 1], f_sim)
            regressors(fac, f_sim, z)
            for i in range(n):
                xh[i] = 0.0
            one_step(eq, th, z, xh)
            bad = False
            for i in range(n):
                if not np.isfinite(xh[i]) or abs(xh[i]) > limit[s]:
                    bad = True
            if bad:
                status[s] = AUX_DIVERGED
                break
        else:
            for p in range(n_par):
                z[p] = phi[p]
        for i in range(n):
            yi = target[k, i]
            l_y[i] += yi
            if block_src[i] != i:  # same terms as an earlier equation: only S_zy differs
                for p in range(block_start[i], block_start[i + 1]):
                    l_zy[p] += z[p] * yi
                continue
            for p in range(block_start[i], block_start[i + 1]):
                zp = z[p]
                l_zy[p] += zp * yi
                l_z[p] += zp
                l_phi[p] += phi[p]
                for q in range(block_start[i], block_start[i + 1]):
                    l_zphi[p, q] += zp * phi[q]
    for i in range(n):
        j = block_src[i]
        if j != i:
            off = block_start[j] - block_start[i]
            for p in range(block_start[i], block_start[i + 1]):
                l_z[p] = l_z[p + off]
                l_phi[p] = l_phi[p + off]
                for q in range(block_start[i], block_start[i + 1]):
                    l_zphi[p, q] = l_zphi[p + off, q + off]
    for p in range(n_par):
        s_zy[s, p] = l_zy[p]
        s_z[s, p] = l_z[p]
        s_phi[s, p] = l_phi[p]
        for q in range(n_par):
            s_zphi[s, p, q] = l_zphi[p, q]
    for i in range(n):
        s_y[s, i] = l_y[i]


@kernel()
def regressor_matrix(regsig, u, starts, fac):
    """Φ rows for every equation: row ``k`` of the output uses ``[ỹ(k−1); u(k−1)]``.

    The first row of each segment has no predecessor and is left as NaN.
    """
    t_len, n = regsig.shape
    m = u.shape[1]
    n_par = fac.shape[0]
    out = np.full((t_len, n_par), np.nan)
    f = np.empty(2 * (n + m) + 1)
    for s in range(starts.shape[0] - 1):
        for k in range(starts[s] + 1, starts[s + 1]):
            fill_factors_xu(regsig[k - 1], u[k - 1], f)
            regressors(fac, f, out[k])
    return out


@kernel()
def instrument_matrix(target, u, starts, theta, fac, eq, n):
    """Instruments ``ζ(k) = Φ([x̂(k−1); u(k−1)])`` and the auxiliary states ``x̂``.

    ``x̂`` restarts from the measured target at the start of every segment. Rows
    that are first in their segment are NaN in ``Z``.
    """
    t_len = target.shape[0]
    m = u.shape[1]
    n_par = fac.shape[0]
    z_out = np.full((t_len, n_par), np.nan)
    x_out = np.empty((t_len, n))
    f = np.empty(2 * (n + m) + 1)
    for s in range(starts.shape[0] - 1):
        a = starts[s]
        for i in range(n):
            x_out[a, i] = target[a, i]
        for k in range(a + 1, starts[s + 1]):
            fill_factors_xu(x_out[k - 1], u[k - 1], f)
            regressors(fac, f, z_out[k])
            for i in range(n):
                x_out[k, i] = 0.0
            one_step(eq, theta, z_out[k], x_out[k])
    return z_out, x_out
