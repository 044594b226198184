"""The prediction-error filter's tangent recursion: its innovations are the filter's own,
bit for bit, and its derivatives are those of the filter (central differences)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("numba")

from vesselid.identify._pemkernels import gaussian_filter, gaussian_filter_tangent, term_kinds


def _log(n: int = 1500, seed: int = 7):
    rng = np.random.default_rng(seed)
    tau = np.repeat(rng.uniform(-0.4, 0.4, n // 50 + 1), 50)[:n]
    v = np.zeros(n)
    for k in range(1, n):  # a Gauss–Markov current
        v[k] = 0.96 * v[k - 1] + 0.03 * rng.normal()
    w = np.zeros(n)
    for k in range(n - 1):
        r = w[k] - v[k]
        w[k + 1] = 0.9 * r - 0.2 * r * abs(r) + 0.8 * tau[k] + 0.05 * rng.normal()
    y = w + 0.05 * rng.normal(size=n)
    return y, np.ascontiguousarray(tau[:, None])


def _filter(row, y, u, starts, p_init, kinds):
    eps, var = np.empty((1, y.size)), np.empty((1, y.size))
    gaussian_filter(0, 1, np.ascontiguousarray(row[None]), y, u, starts, p_init, *kinds,
                    eps, var)
    return eps[0], var[0]


@pytest.mark.parametrize("noise", [
    [0.01, 1.8, -2.3, 0.5, -2.0, -2.3, -2.3],        # both processes (the joint model)
    [0.0, 1.8, -2.3, 0.0, -np.inf, -2.3, -2.3],      # current model: no coloured sensor
    [0.0, 0.0, -2.5, 1.1, -2.4, -2.2, -2.6],         # sensor model
])
def test_tangent_matches_filter_and_differences(noise: list[float]) -> None:
    y, u = _log()
    fac = np.array([[0, 4], [0, 2], [1, 4]], dtype=np.int64)  # x, x|x|, u
    kinds = term_kinds(fac, 2)
    starts = np.array([0, 700, y.size], dtype=np.int64)
    p_init = np.array([np.var(y[:700]), np.var(y[700:])])
    row = np.r_[0.88, -0.18, 0.75, noise]
    idx = np.flatnonzero(np.isfinite(row)).astype(np.int64)
    eps, var = np.empty(y.size), np.empty(y.size)
    deps, dvar = np.empty((y.size, idx.size)), np.empty((y.size, idx.size))
    grad, fisher, nll = np.empty(idx.size), np.empty((idx.size, idx.size)), np.empty(1)
    gaussian_filter_tangent(row, idx, y, u, starts, p_init, *kinds, eps, var, deps, dvar,
                            grad, fisher, nll)
    e0, v0 = _filter(row, y, u, starts, p_init, kinds)
    assert np.array_equal(eps, e0) and np.array_equal(var, v0)
    assert np.all(deps[starts[:-1]] == 0) and np.all(dvar[starts[:-1]] == 0)
    # the scoring's sums: likelihood, gradient and Fisher information of the innovations
    inv = 1.0 / var
    np.testing.assert_allclose(nll[0], np.sum(0.5 * (np.log(var) + eps**2 * inv)),
                               rtol=1e-12)
    want_g = deps.T @ (eps * inv) + 0.5 * dvar.T @ (inv - eps**2 * inv**2)
    want_f = (deps.T * inv) @ deps + 0.5 * (dvar.T * inv**2) @ dvar
    np.testing.assert_allclose(grad, want_g, rtol=1e-9, atol=1e-9 * np.max(np.abs(want_g)))
    np.testing.assert_allclose(fisher, want_f, rtol=1e-9, atol=1e-12 * np.max(np.abs(want_f)))
    for j, p in enumerate(idx):
        h = 1e-5 * max(abs(row[p]), 1.0)
        up, dn = row.copy(), row.copy()
        up[p] += h
        dn[p] -= h
        (e1, v1), (e2, v2) = (_filter(up, y, u, starts, p_init, kinds),
                              _filter(dn, y, u, starts, p_init, kinds))
        fd_e, fd_v = (e1 - e2) / (2 * h), (v1 - v2) / (2 * h)
        # central differences: truncation O(h²), rounding O(1e-16 / h) relative
        scale_e, scale_v = np.max(np.abs(fd_e)) + 1e-12, np.max(np.abs(fd_v)) + 1e-12
        assert np.max(np.abs(deps[:, j] - fd_e)) <= 1e-6 * scale_e, p
        assert np.max(np.abs(dvar[:, j] - fd_v)) <= 1e-6 * scale_v, p


def test_bartlett_lagged_is_the_lag_sum() -> None:
    from vesselid.identify._pemkernels import bartlett_lagged

    rng = np.random.default_rng(3)
    sc = rng.normal(size=(300, 4))
    starts = np.array([0, 120, 121, 300], dtype=np.int64)  # one experiment of one sample
    bw = 7
    out = np.empty_like(sc)
    bartlett_lagged(sc, starts, bw, out)
    seg = np.repeat(np.arange(3), np.diff(starts))
    want = np.zeros((4, 4))  # Σ_lag w Σ_k s(k) s(k−lag)ᵀ within experiments, by hand
    for lag in range(1, bw + 1):
        same = (seg[lag:] == seg[:-lag])[:, None]
        want += (1.0 - lag / (bw + 1.0)) * ((sc[lag:] * same).T @ sc[:-lag])
    np.testing.assert_allclose(sc.T @ out, want, rtol=1e-12, atol=1e-12)


def test_score_and_selection_kernels_equal_their_numpy_formulations():
    """The quasi-ML scores and the selection quadrature's sums, compiled, give the bits of
    the numpy expressions they replace (non-finite scores zeroed, NaN counted largest)."""
    from vesselid.identify._pemkernels import quasi_scores, selection_sums

    rng = np.random.default_rng(1)
    d, t = 7, 2000
    je, js = rng.standard_normal((d, t)) * 1e3, rng.standard_normal((d, t))
    eps, var = rng.standard_normal(t), rng.random(t) + 1e-3
    var[::97], eps[::89] = 0.0, np.inf
    with np.errstate(all="ignore"):
        inv_s = 1.0 / var
        sc = je * (eps * inv_s) + 0.5 * js * (inv_s - eps * eps * inv_s * inv_s)
    out = np.empty((t, d))
    quasi_scores(je, js, eps, var, out)
    np.testing.assert_array_equal(out, np.where(np.isfinite(sc), sc, 0.0).T)
    assert np.all(np.signbit(out) == np.signbit(np.where(np.isfinite(sc), sc, 0.0).T))
    z = rng.standard_normal((5000, 6))
    z[::250, 3] = np.nan
    z[7] = 2.0  # a tie: the first column
    pick = np.argmax(np.abs(z), axis=1)
    want = np.bincount(pick, weights=z[np.arange(z.shape[0]), pick] ** 2, minlength=6)
    got = np.empty(6)
    selection_sums(z, got)
    np.testing.assert_array_equal(got, want)
