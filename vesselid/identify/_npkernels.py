"""The estimation kernels without compiled code: numpy plus one Python recursion.

For a small log, loading numba and its cached kernels (≈ 0.4 s of process start: the
import, the target initialisation with its ``scipy.linalg`` BLAS check, one file per
kernel) costs more than the whole estimation, so :mod:`vesselid.identify.backend` runs
these instead. Same arguments and results as the compiled kernels of
:mod:`vesselid.identify.kernels` and :mod:`vesselid.identify._ivkernels`:

* The regressors are evaluated with :func:`vesselid.model.regressors.evaluate` (the same
  products: bit-identical to the compiled ``regressors``).
* The auxiliary-model recursion ``x̂(k) = Φᵀ([x̂(k−1); u(k−1)]) θ`` (and the simulation
  ``x(k+1) = Φᵀ([x(k) + v(k); u(k)]) θ + w(k)``) is a Python loop generated once per
  model structure with the terms unrolled into scalar code — the same operations in the
  same order as the compiled one-step update, so the simulated states are bit-identical;
  ≈ 0.1–0.2 µs per sample for the heave model.
* Sums over samples are numpy reductions and matrix products: equal to the compiled
  sequential sums to rounding, not bit for bit (``tests/test_npkernels.py``).

The combined-instrument GMM pass (``combined_moments``) has no numpy version; the
backend takes the compiled one for it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from vesselid.model.regressors import evaluate, factor_source

__all__ = [
    "AUX_DIVERGED",
    "AUX_OK",
    "MODE_LAGGED",
    "MODE_LS",
    "MODE_SIMULATED",
    "ar_filter",
    "autocov",
    "center",
    "cross_sums",
    "design_centre",
    "design_scan",
    "instrument_matrix",
    "moments",
    "noise_window",
    "recursion",
    "regressor_matrix",
    "simulated_regressors",
]

AUX_OK = 0
AUX_DIVERGED = 1
MODE_LS = 0
MODE_SIMULATED = 1
MODE_LAGGED = 2

_LOCK = threading.Lock()
_RECURSIONS: dict[tuple, Callable] = {}


# ------------------------------------------------------------------- the recursion
def _recursion_source(n: int, m: int, fac: np.ndarray, eq: np.ndarray, inner: bool,
                      additive: bool) -> str:
    """Python source of ``run(x, u, v, w, th, lim, k0, k1)`` for one structure.

    ``x`` is a list of per-state lists (``x[i][k0]`` holds the start), ``u`` per-input
    lists; ``v``/``w`` per-state lists (used if ``inner``/``additive``). Fills
    ``x[i][k0+1 … k1−1]`` and returns the first index whose state is non-finite or beyond
    ``lim`` (or ``k1`` if none); that state is stored, the rest left as they are.
    """

    def factor(idx: int) -> str | None:
        src = factor_source(idx, n + m)
        if src is None:
            return None
        j, modulus = src
        name = f"s{j}" if j < n else f"e{j - n}"
        return f"abs({name})" if modulus else name

    lines = ["def run(x, u, v, w, th, lim, k0, k1):"]
    add = lines.append
    for p in range(fac.shape[0]):
        add(f"    t{p} = th[{p}]")
    for i in range(n):
        add(f"    x{i} = x[{i}]")
        add(f"    c{i} = x{i}[k0]")
        if inner:
            add(f"    v{i} = v[{i}]")
        if additive:
            add(f"    w{i} = w[{i}]")
    for j in range(m):
        add(f"    u{j} = u[{j}]")
    add("    for k in range(k0, k1 - 1):")
    for i in range(n):
        add(f"        s{i} = c{i} + v{i}[k]" if inner else f"        s{i} = c{i}")
    for j in range(m):
        add(f"        e{j} = u{j}[k]")
    for i in range(n):
        expr = f"w{i}[k]" if additive else "0.0"
        for p in range(fac.shape[0]):
            if int(eq[p]) != i:
                continue
            parts = [f for f in (factor(int(fac[p, 0])), factor(int(fac[p, 1])))
                     if f is not None]
            prod = " * ".join(parts) if parts else "1.0"
            expr = f"({expr} + t{p} * ({prod}))"
        add(f"        c{i} = {expr}")
    for i in range(n):
        add(f"        x{i}[k + 1] = c{i}")
    cond = " or ".join(f"not abs(c{i}) <= lim" for i in range(n))
    add(f"        if {cond}:")
    add("            return k + 1")
    add("    return k1")
    return "\n".join(lines) + "\n"


def recursion(fac: np.ndarray, eq: np.ndarray, n: int, m: int, *, inner: bool = False,
              additive: bool = False) -> Callable:
    """The generated Python recursion of one structure (cached; see
    :func:`_recursion_source`). The code is built from the integer factor layout only."""
    fac = np.asarray(fac, dtype=np.int64)
    eq = np.asarray(eq, dtype=np.int64)
    key = (int(n), int(m), fac.tobytes(), eq.tobytes(), bool(inner), bool(additive))
    with _LOCK:
        fn = _RECURSIONS.get(key)
        if fn is None:
            namespace: dict = {}
            exec(compile(_recursion_source(int(n), int(m), fac, eq, inner, additive),
                         "<vesselid recursion>", "exec"), namespace)
            fn = _RECURSIONS[key] = namespace["run"]
    return fn


def _states(fac, eq, theta, x0, u, lim) -> tuple[np.ndarray, int]:
    """Auxiliary states ``x̂`` over one segment (``x̂[0] = x0``) and the first bad index
    (``len(u)`` if none); states after it are NaN."""
    n, (t_len, m) = x0.shape[0], u.shape
    run = recursion(fac, eq, n, m)
    xs = [[0.0] * t_len for _ in range(n)]
    for i in range(n):
        xs[i][0] = float(x0[i])
    bad = run(xs, [u[:, j].tolist() for j in range(m)], None, None,
              [float(t) for t in theta], float(lim), 0, t_len)
    x = np.array(xs, dtype=np.float64).T.reshape(t_len, n)
    if bad < t_len:
        x[bad + 1:] = np.nan
    return x, bad


def _rows(sig: np.ndarray, u: np.ndarray, fac: np.ndarray) -> np.ndarray:
    """``Φ([sig(k); u(k)])`` for every row (bit-identical to the compiled regressors)."""
    return evaluate(fac, np.concatenate([sig, u], axis=1))


# --------------------------------------------------------------------- the kernels
def regressor_matrix(regsig, u, starts, fac):
    """Φ rows: row ``k`` uses ``[ỹ(k−1); u(k−1)]``; each segment's first row is NaN."""
    out = np.full((regsig.shape[0], fac.shape[0]), np.nan)
    if regsig.shape[0] > 1:
        out[1:] = _rows(regsig[:-1], u[:-1], fac)
    out[starts[:-1]] = np.nan
    return out


def instrument_matrix(target, u, starts, theta, fac, eq, n):
    """Instruments ``ζ(k) = Φ([x̂(k−1); u(k−1)])`` and the auxiliary states (no limit)."""
    t_len = target.shape[0]
    z_out = np.full((t_len, fac.shape[0]), np.nan)
    x_out = np.empty((t_len, n))
    for s in range(starts.shape[0] - 1):
        a, b = int(starts[s]), int(starts[s + 1])
        if b <= a:
            continue
        x, _ = _states(fac, eq, theta, target[a], u[a:b], np.inf)
        x_out[a:b] = x
        if b - a > 1:
            z_out[a + 1:b] = _rows(x[:-1], u[a:b - 1], fac)
    return z_out, x_out


def simulated_regressors(target, u, starts, group, theta, fac, eq, limit):
    """``ζ(k)`` simulated from ``theta[group[s]]``; a diverged segment is NaN, not ok."""
    t_len = target.shape[0]
    z = np.full((t_len, fac.shape[0]), np.nan)
    ok = np.ones(starts.shape[0] - 1, dtype=np.bool_)
    for s in range(starts.shape[0] - 1):
        a, b = int(starts[s]), int(starts[s + 1])
        if b <= a:
            continue
        x, bad = _states(fac, eq, theta[group[s]], target[a], u[a:b], limit[s])
        if bad < b - a:
            ok[s] = False
            continue
        if b - a > 1:
            z[a + 1:b] = _rows(x[:-1], u[a:b - 1], fac)
    return z, ok


def moments(regsig, target, u, starts, group, theta, active, mode, fac, eq, block_start,
            block_src, limit, s_zphi, s_zy, s_z, s_phi, s_y, count, status):
    """Per-segment LS/IV moments (:func:`vesselid.identify.kernels.moments`)."""
    n = regsig.shape[1]
    n_par = fac.shape[0]
    for s in range(starts.shape[0] - 1):
        g = int(group[s])
        if not active[g]:
            continue
        a, b = int(starts[s]), int(starts[s + 1])
        status[s] = AUX_OK
        count[s] = b - a - 1
        end = b  # rows a+1 … end−1 are accumulated
        if b - a > 1:
            phi = _rows(regsig[a:b - 1], u[a:b - 1], fac)
            if mode == MODE_LAGGED:
                lag = np.concatenate([regsig[a:a + 1], regsig[a:b - 2]])[:b - a - 1]
                z = _rows(lag, u[a:b - 1], fac)
            elif mode == MODE_SIMULATED:
                x, bad = _states(fac, eq, theta[g], target[a], u[a:b], limit[s])
                if bad < b - a:
                    status[s] = AUX_DIVERGED
                    end = a + bad
                z = _rows(np.nan_to_num(x[:-1]), u[a:b - 1], fac)
            else:
                z = phi
            rows = end - a - 1
            phi, z, y = phi[:rows], z[:rows], target[a + 1:end]
        else:
            phi = z = np.zeros((0, n_par))
            y = np.zeros((0, n))
        l_zphi = np.zeros((n_par, n_par))
        l_zy = np.zeros(n_par)
        l_z = np.zeros(n_par)
        l_phi = np.zeros(n_par)
        for i in range(n):
            blk = slice(int(block_start[i]), int(block_start[i + 1]))
            l_zy[blk] = z[:, blk].T @ y[:, i]
            j = int(block_src[i])
            src = slice(int(block_start[j]), int(block_start[j + 1]))
            l_z[blk] = z[:, src].sum(axis=0)
            l_phi[blk] = phi[:, src].sum(axis=0)
            l_zphi[blk, blk] = z[:, src].T @ phi[:, src]
        s_zphi[s] = l_zphi
        s_zy[s] = l_zy
        s_z[s] = l_z
        s_phi[s] = l_phi
        s_y[s] = y.sum(axis=0)


def center(x, starts, valid):
    """Subtract each column's mean over the valid rows of every segment (a copy)."""
    out = x.copy()
    for s in range(starts.shape[0] - 1):
        a, b = int(starts[s]), int(starts[s + 1])
        v = valid[a:b]
        cnt = int(v.sum())
        if cnt:
            out[a:b] = x[a:b] - x[a:b][v].sum(axis=0) / cnt
    return out


def ar_filter(x, starts, valid, coef):
    """``x_f(k) = Σ_j coef[s, j] x(k − j)`` per segment; valid where all inputs are."""
    t_len, k_cols = x.shape
    p = coef.shape[1] - 1
    out = np.zeros((t_len, k_cols))
    vf = np.zeros(t_len, dtype=np.bool_)
    for s in range(starts.shape[0] - 1):
        a, b = int(starts[s]), int(starts[s + 1])
        if b - a <= p:
            continue
        good = np.ones(b - a - p, dtype=bool)
        acc = np.zeros((b - a - p, k_cols))
        for j in range(p + 1):
            good &= valid[a + p - j:b - j]
            acc = acc + coef[s, j] * x[a + p - j:b - j]
        vf[a + p:b] = good
        out[a + p:b][good] = acc[good]
    return out, vf


def autocov(e, starts, valid, p):
    """Sums ``Σ ẽ(k) ẽ(k − j)``, ``j = 0 … p``, over pairs of valid rows per segment."""
    n_seg = starts.shape[0] - 1
    out = np.zeros((n_seg, p + 1))
    cnt = np.zeros(n_seg)
    for s in range(n_seg):
        a, b = int(starts[s]), int(starts[s + 1])
        v = valid[a:b]
        c = int(v.sum())
        if c == 0:
            continue
        cnt[s] = c
        d = np.where(v, e[a:b] - e[a:b][v].sum() / c, 0.0)
        for j in range(min(p, b - a - 1) + 1):
            out[s, j] = d[j:] @ d[:b - a - j]
    return out, cnt


def cross_sums(z, phi, y, starts, valid):
    """Per segment ``Σ z φᵀ`` (S, K, P), ``Σ z y`` (S, K), ``Σ z zᵀ`` (S, K, K), count."""
    n_seg = starts.shape[0] - 1
    k_cols, p_cols = z.shape[1], phi.shape[1]
    a_out = np.zeros((n_seg, k_cols, p_cols))
    b_out = np.zeros((n_seg, k_cols))
    m_out = np.zeros((n_seg, k_cols, k_cols))
    cnt = np.zeros(n_seg)
    for s in range(n_seg):
        a, b = int(starts[s]), int(starts[s + 1])
        v = valid[a:b]
        zs, ps, ys = z[a:b][v], phi[a:b][v], y[a:b][v]
        cnt[s] = zs.shape[0]
        a_out[s] = zs.T @ ps
        b_out[s] = zs.T @ ys
        m = zs.T @ zs
        m_out[s] = np.triu(m) + np.triu(m, 1).T  # symmetric from the upper triangle
    return a_out, b_out, m_out, cnt


def noise_window(phi, z, cols, starts, lo, hi):
    """Window means of the estimated regressor noise ``η = nan_to_num(φ − ζ)`` on the
    columns ``cols`` (:func:`vesselid.identify._ivkernels.noise_window`, the numpy
    formulation it was written from: bit-identical)."""
    t_len = phi.shape[0]
    eta = np.nan_to_num(phi[:, cols] - z[:, cols])
    csum = np.zeros((t_len + 1, eta.shape[1]))
    np.cumsum(eta, axis=0, out=csum[1:])
    rows = np.arange(t_len)
    seg_start = np.repeat(starts[:-1], np.diff(starts))
    ok = rows - hi >= seg_start + 1  # the segment's first row has no instrument
    out = np.full_like(eta, np.nan)
    r = rows[ok]
    out[ok] = (csum[r - lo + 1] - csum[r - hi]) / (hi - lo + 1)
    bad = ~np.all(np.isfinite(z[:, cols]), axis=1)
    if bad.any():  # a diverged simulation invalidates its whole window
        cb = np.concatenate([[0], np.cumsum(bad)])
        hit = np.zeros(t_len, dtype=bool)
        hit[r] = (cb[r - lo + 1] - cb[r - hi]) > 0
        out[hit] = np.nan
    return out


def _design_stack(z, phi, p_lo, p_hi, target, i_eq):
    return np.column_stack([z, phi[:, p_lo:p_hi], target[:, i_eq]])


def design_scan(z, phi, p_lo, p_hi, target, i_eq):
    """Rows where every column of ``[z, φ[:, p_lo:p_hi], y_i]`` is finite, and each
    column's ``max |·|`` over them (0 if none)."""
    stack = _design_stack(z, phi, p_lo, p_hi, target, i_eq)
    valid = np.all(np.isfinite(stack), axis=1)
    return valid, np.max(np.abs(stack[valid]), axis=0, initial=0.0)


def design_centre(z, phi, p_lo, p_hi, target, i_eq, valid, col, starts):
    """Masked (invalid rows 0), column-scaled and per-segment centred ``z``, ``φ`` block
    and ``y_i`` (contiguous arrays)."""
    k_z = z.shape[1]
    stack = np.where(valid[:, None], _design_stack(z, phi, p_lo, p_hi, target, i_eq),
                     0.0) * col
    stack = center(stack, starts, valid)
    return (np.ascontiguousarray(stack[:, :k_z]),
            np.ascontiguousarray(stack[:, k_z:k_z + p_hi - p_lo]),
            np.ascontiguousarray(stack[:, -1]))


def simulate_states(spec, u, *, theta, x0, v=None, limit: float = 1e8,
                    raise_on_divergence: bool = False) -> np.ndarray:
    """One run of :func:`vesselid.plant.simulate.simulate_states` (``w = 0``; diverged states
    NaN from the sample after the failing one). Only ``raise_on_divergence=False``."""
    if raise_on_divergence:  # pragma: no cover - the diagnostics never ask for it
        raise NotImplementedError("use vesselid.plant.simulate.simulate_states")
    codes = spec.codes
    u = np.asarray(u, dtype=np.float64)
    t_len, m = u.shape
    n = spec.n_states
    run = recursion(codes.factors, codes.equation, n, m, inner=v is not None)
    xs = [[0.0] * t_len for _ in range(n)]
    x0 = np.asarray(x0, dtype=np.float64)
    for i in range(n):
        xs[i][0] = float(x0[i])
    vv = None if v is None else [np.asarray(v, dtype=np.float64)[:, i].tolist()
                                 for i in range(n)]
    bad = run(xs, [u[:, j].tolist() for j in range(m)], vv, None,
              [float(t) for t in np.asarray(theta, dtype=np.float64)], float(limit), 0,
              t_len)
    x = np.array(xs, dtype=np.float64).T.reshape(t_len, n)
    if bad < t_len:
        x[bad + 1:] = np.nan
    return x
