"""Covariance estimators against linearmodels on identical instruments and regressors."""

from __future__ import annotations

import itertools

import linearmodels.iv as lm_iv
import linearmodels.iv.covariance as lm_cov
import numpy as np
import pytest

from vesselid.identify.covariance import (
    COVARIANCE_ESTIMATORS,
    CovarianceError,
    automatic_bandwidth,
    get_covariance_estimator,
    iv_covariance,
    kernel_weights,
)

TOL = 1e-10


def _problem(rng, n=300, p=3, ma=-0.7, const=0.3):
    """A just-identified IV problem with smooth instruments and an MA(1) error."""
    z = np.cumsum(rng.normal(size=(n, p)), axis=0) * 0.1 + rng.normal(size=(n, p))
    phi = z @ rng.normal(size=(p, p)) + rng.normal(size=(n, p))
    e = np.convolve(rng.normal(size=n + 1), [1.0, ma], "valid")
    y = phi @ np.array([1.0, -2.0, 0.5][:p]) + const + e
    return z, phi, y


def _zero_mean_iv(z, phi, y, starts):
    zc = z.copy()
    for s in range(len(starts) - 1):
        sl = slice(starts[s], starts[s + 1])
        zc[sl] -= zc[sl].mean(axis=0)
    theta = np.linalg.solve(zc.T @ phi, zc.T @ y)
    return zc, theta, y - phi @ theta


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


@pytest.mark.parametrize(
    ("cov_type", "config", "lm_type", "lm_config"),
    [
        ("unadjusted", {}, "unadjusted", {}),
        ("hac", {"kernel": "bartlett", "bandwidth": 7}, "kernel", {"kernel": "bartlett",
                                                                  "bandwidth": 7}),
        ("hac", {"kernel": "qs", "bandwidth": 5.5}, "kernel", {"kernel": "qs", "bandwidth": 5.5}),
        ("hac", {"kernel": "parzen", "bandwidth": 9}, "kernel", {"kernel": "parzen",
                                                                "bandwidth": 9}),
    ],
)
def test_zero_mean_iv_matches_iv2sls_with_constant(cov_type, config, lm_type, lm_config):
    rng = np.random.default_rng(1)
    z, phi, y = _problem(rng)
    n = y.size
    zc, theta, resid = _zero_mean_iv(z, phi, y, [0, n])
    res = iv_covariance(zc, phi, resid, zero_mean=True, skip_first=False, cov_type=cov_type,
                        **config)
    fit = lm_iv.IV2SLS(y, np.ones((n, 1)), phi, z).fit(cov_type=lm_type, debiased=False,
                                                       **lm_config)
    np.testing.assert_allclose(fit.params.to_numpy()[1:], theta, rtol=1e-10)
    assert _rel(res.cov, fit.cov.to_numpy()[1:, 1:]) < TOL
    assert res.cov_type == cov_type


def test_plain_iv_and_ls_match_iv2sls_without_constant():
    rng = np.random.default_rng(2)
    z, phi, y = _problem(rng, const=0.0)
    theta = np.linalg.solve(z.T @ phi, z.T @ y)
    res = iv_covariance(z, phi, y - phi @ theta, skip_first=False, cov_type="hac",
                        kernel="bartlett", bandwidth=4)
    fit = lm_iv.IV2SLS(y, None, phi, z).fit(cov_type="kernel", kernel="bartlett", bandwidth=4,
                                            debiased=False)
    assert _rel(res.cov, fit.cov.to_numpy()) < TOL
    beta = np.linalg.lstsq(phi, y, rcond=None)[0]
    res_ls = iv_covariance(phi, phi, y - phi @ beta, skip_first=False, cov_type="unadjusted")
    fit_ls = lm_iv.IV2SLS(y, phi, None, None).fit(cov_type="unadjusted", debiased=False)
    assert _rel(res_ls.cov, fit_ls.cov.to_numpy()) < TOL


@pytest.mark.parametrize("kernel", ["bartlett", "parzen"])
def test_per_experiment_hac_has_no_cross_experiment_lags(kernel):
    """Pooled zero-mean IV over 3 experiments = IV2SLS with experiment dummies on data with
    enough zero rows between the experiments that no kernel lag crosses a boundary."""
    rng = np.random.default_rng(3)
    lengths = [150, 200, 120]
    parts = [_problem(rng, n=m) for m in lengths]
    z = np.vstack([p[0] for p in parts])
    phi = np.vstack([p[1] for p in parts])
    y = np.concatenate([p[2] for p in parts])
    starts = np.concatenate([[0], np.cumsum(lengths)])
    zc, _theta, resid = _zero_mean_iv(z, phi, y, starts)
    bw = 6
    res = iv_covariance(zc, phi, resid, starts, zero_mean=True, skip_first=False,
                        cov_type="hac", kernel=kernel, bandwidth=bw)
    gap = bw + 1  # finite-support kernels: no lag reaches across the zero rows
    rows = []
    for s, m in enumerate(lengths):
        sl = slice(starts[s], starts[s + 1])
        dummies = np.zeros((m, len(lengths)))
        dummies[:, s] = 1.0
        rows.append((y[sl], dummies, phi[sl], z[sl]))
        rows.append((np.zeros(gap), np.zeros((gap, len(lengths))), np.zeros((gap, 3)),
                     np.zeros((gap, 3))))
    yy, dd, pp, zz = (np.concatenate([r[i] for r in rows]) for i in range(4))
    fit = lm_iv.IV2SLS(yy, dd, pp, zz).fit(cov_type="kernel", kernel=kernel, bandwidth=bw,
                                           debiased=False)
    assert _rel(res.cov, fit.cov.to_numpy()[3:, 3:]) < TOL
    # and the unadjusted pooled form equals 2SLS with dummies (no padding needed)
    res_u = iv_covariance(zc, phi, resid, starts, zero_mean=True, skip_first=False,
                          cov_type="unadjusted")
    d = np.zeros((y.size, 3))
    for s in range(3):
        d[starts[s]:starts[s + 1], s] = 1
    fit_u = lm_iv.IV2SLS(y, d, phi, z).fit(cov_type="unadjusted", debiased=False)
    assert _rel(res_u.cov, fit_u.cov.to_numpy()[3:, 3:]) < TOL


def test_two_equations_joint_covariance_blocks():
    """Diagonal blocks are the per-equation covariances; the cross block is the
    sandwich of the cross-products of the two equations' scores."""
    rng = np.random.default_rng(4)
    n = 400
    z1, phi1, y1 = _problem(rng, n=n, p=2)
    z2, phi2, y2 = _problem(rng, n=n, p=3)
    y2 = y2 + 0.5 * (y1 - phi1 @ np.array([1.0, -2.0]))  # correlated errors
    np.hstack([z1, z2])
    phi = np.hstack([phi1, phi2])
    eq = np.array([0, 0, 1, 1, 1])
    zc1, _th1, r1 = _zero_mean_iv(z1, phi1, y1, [0, n])
    zc2, _th2, r2 = _zero_mean_iv(z2, phi2, y2, [0, n])
    zc = np.hstack([zc1, zc2])
    resid = np.column_stack([r1, r2])
    for cov_type, cfg in (("unadjusted", {}), ("hac", {"kernel": "bartlett", "bandwidth": 5})):
        joint = iv_covariance(zc, phi, resid, None, eq, zero_mean=True, skip_first=False,
                              cov_type=cov_type, **cfg).cov
        one = iv_covariance(zc1, phi1, r1, zero_mean=True, skip_first=False,
                            cov_type=cov_type, **cfg).cov
        two = iv_covariance(zc2, phi2, r2, zero_mean=True, skip_first=False,
                            cov_type=cov_type, **cfg).cov
        assert _rel(joint[:2, :2], one) < TOL and _rel(joint[2:, 2:], two) < TOL
        assert np.abs(joint[:2, 2:]).max() > 1e-3 * np.sqrt(one[0, 0] * two[0, 0])
        np.testing.assert_allclose(joint, joint.T)
        assert np.all(np.linalg.eigvalsh(joint) > 0)


def test_stacked_unadjusted_is_the_sandwich_of_the_stacked_equations():
    rng = np.random.default_rng(5)
    lengths = [200, 300]
    parts = [_problem(rng, n=m) for m in lengths]
    z = np.vstack([p[0] for p in parts])
    phi = np.vstack([p[1] for p in parts])
    y = np.concatenate([p[2] for p in parts])
    starts = np.array([0, 200, 500])
    zc, _, _ = _zero_mean_iv(z, phi, y, starts)
    a = [zc[s:e].T @ phi[s:e] / (e - s) for s, e in itertools.pairwise(starts)]
    b = [zc[s:e].T @ y[s:e] / (e - s) for s, e in itertools.pairwise(starts)]
    theta = np.linalg.lstsq(np.vstack(a), np.concatenate(b), rcond=None)[0]
    resid = y - phi @ theta
    res = iv_covariance(zc, phi, resid, starts, zero_mean=True, combine="stacked",
                        skip_first=False, cov_type="unadjusted")
    eps = np.concatenate([resid[s:e] - resid[s:e].mean()
                          for s, e in itertools.pairwise(starts)])
    sigma2 = eps @ eps / eps.size
    h = sum(ai.T @ ai for ai in a)
    meat = sum(ai.T @ (zc[s:e].T @ zc[s:e]) @ ai / (e - s) ** 2
               for ai, s, e in zip(a, starts[:-1], starts[1:], strict=True))
    expected = sigma2 * np.linalg.inv(h) @ meat @ np.linalg.inv(h)
    assert _rel(res.cov, expected) < TOL


@pytest.mark.parametrize("kernel", ["bartlett", "parzen", "qs"])
@pytest.mark.parametrize("bandwidth", [0.0, 3.0, 7.5, 20.0])
def test_kernel_weights_match_linearmodels(kernel, bandwidth):
    ref = getattr(lm_cov, {"bartlett": "kernel_weight_bartlett", "parzen": "kernel_weight_parzen",
                           "qs": "kernel_weight_quadratic_spectral"}[kernel])(bandwidth, 59)
    ours = kernel_weights(kernel, bandwidth, 59)
    if kernel == "qs" and bandwidth == 0:
        assert ours[0] == 1 and not ours[1:].any()  # lag 0 only
        return
    m = min(ref.size, ours.size)
    np.testing.assert_allclose(ours[:m], ref[:m], atol=1e-14)
    assert not ours[m:].any()


def test_bartlett_weights_match_statsmodels():
    import statsmodels.stats.sandwich_covariance as sw
    for lags in (0, 1, 5, 12):
        np.testing.assert_allclose(kernel_weights("bartlett", lags, lags),
                                   sw.weights_bartlett(lags))


@pytest.mark.parametrize("kernel", ["bartlett", "parzen", "qs"])
def test_newey_west_bandwidth_matches_linearmodels(kernel):
    rng = np.random.default_rng(6)
    x = np.convolve(rng.normal(size=501), [1.0, 0.6], "valid")
    ours = automatic_bandwidth(x, kernel=kernel, rule="newey-west")
    assert ours == lm_cov.kernel_optimal_bandwidth(x, kernel)


def test_andrews_bandwidth_grows_with_persistence_and_is_scale_free():
    rng = np.random.default_rng(7)
    e = rng.normal(size=(5000, 2))
    slow = np.column_stack([np.convolve(e[:, i], 0.95 ** np.arange(200))[:5000] for i in range(2)])
    b_white = automatic_bandwidth(e, kernel="bartlett")
    b_slow = automatic_bandwidth(slow, kernel="bartlett")
    assert b_slow > 5 * b_white
    assert automatic_bandwidth(slow * np.array([1e-3, 1e4]), kernel="qs") == pytest.approx(
        automatic_bandwidth(slow, kernel="qs"))


def test_prewhitened_hac_recovers_ar1_long_run_variance():
    """Scores g = AR(1) with ρ = 0.8: long-run variance σ²/(1−ρ)²; the pre-whitened
    estimate is within a few standard errors of it (SE from the same run's batches)."""
    rng = np.random.default_rng(8)
    n, rho = 20_000, 0.8
    g = np.zeros(n)
    eps = rng.normal(size=n)
    for k in range(1, n):  # small, test-only recursion
        g[k] = rho * g[k - 1] + eps[k]
    z = np.ones((n, 1))
    res = iv_covariance(z, z, g, cov_type="hac", kernel="qs", prewhiten=True, skip_first=False)
    # the "estimate" is the mean; its variance n⁻² × long-run variance
    lrv = res.cov[0, 0] * n
    batches = g.reshape(40, -1).sum(axis=1)
    se = np.std(batches**2 / (n / 40), ddof=1) / np.sqrt(40)
    assert abs(lrv - 1 / (1 - rho) ** 2) < 4 * se


def test_registry_and_validation():
    assert set(COVARIANCE_ESTIMATORS) >= {"unadjusted", "hac", "cluster"}
    with pytest.raises(CovarianceError, match="unknown cov_type"):
        get_covariance_estimator("robust")
    with pytest.raises(CovarianceError, match="kernel"):
        get_covariance_estimator("hac", kernel="triangle")
    with pytest.raises(CovarianceError, match="bandwidth"):
        get_covariance_estimator("hac", bandwidth=-1)
    with pytest.raises(CovarianceError, match="bandwidth"):
        get_covariance_estimator("hac", bandwidth="auto")
    with pytest.raises(CovarianceError, match="options"):
        get_covariance_estimator("unadjusted", kernel="qs")
    with pytest.raises(CovarianceError, match="invalid options"):
        get_covariance_estimator("hac", lags=3)
    assert issubclass(CovarianceError, ValueError)
    rng = np.random.default_rng(9)
    z, phi, y = _problem(rng, n=50)
    with pytest.raises(CovarianceError, match="two experiments"):
        iv_covariance(z, phi, y, cov_type="cluster")
    bad = y.copy()
    bad[10] = np.nan
    with pytest.raises(CovarianceError, match="NaN"):
        iv_covariance(z, phi, bad)
    res = iv_covariance(z, phi, y - y.mean(), np.array([0, 25, 50]), cov_type="cluster")
    assert res.config["clusters"] == 2 and "experiment" in res.label
    auto = iv_covariance(z, phi, y - y.mean())
    assert auto.config["bandwidth_rule"] == "newey-west" and "Bartlett" in auto.label


@pytest.mark.parametrize(("cov_type", "lm_type", "cfg"),
                         [("unadjusted", "unadjusted", {}),
                          ("hac", "kernel", {"kernel": "bartlett", "bandwidth": 6})])
def test_over_identified_2sls_matches_linearmodels(cov_type, lm_type, cfg):
    rng = np.random.default_rng(10)
    z, phi, y = _problem(rng, n=400)
    z_extra = np.hstack([z, np.roll(z[:, :2], 1, axis=0) + rng.normal(size=(400, 2))])
    zc = z_extra - z_extra.mean(axis=0)
    pz = zc @ np.linalg.solve(zc.T @ zc, zc.T @ phi)
    theta = np.linalg.solve(pz.T @ phi, pz.T @ y)
    res = iv_covariance(zc, phi, y - phi @ theta, zero_mean=True, skip_first=False,
                        cov_type=cov_type, **cfg)
    fit = lm_iv.IV2SLS(y, np.ones((400, 1)), phi, z_extra).fit(cov_type=lm_type, debiased=False,
                                                              **cfg)
    np.testing.assert_allclose(fit.params.to_numpy()[1:], theta, rtol=1e-9)
    assert _rel(res.cov, fit.cov.to_numpy()[1:, 1:]) < TOL


def test_gmm_weight_sandwich_matches_ivgmm():
    rng = np.random.default_rng(11)
    n = 400
    z, phi, y = _problem(rng, n=n, const=0.0)
    z_extra = np.hstack([z, rng.normal(size=(n, 2)) + 0.3 * phi[:, :2]])
    fit = lm_iv.IVGMM(y, None, phi, z_extra, weight_type="kernel", kernel="bartlett",
                      bandwidth=5).fit(cov_type="kernel", kernel="bartlett", bandwidth=5,
                                       iter_limit=2)
    w = fit.weight_matrix.to_numpy() if hasattr(fit.weight_matrix, "to_numpy") else np.asarray(
        fit.weight_matrix)
    theta = fit.params.to_numpy()
    res = iv_covariance(z_extra, phi, y - phi @ theta, weight=w, skip_first=False,
                        cov_type="hac", kernel="bartlett", bandwidth=5)
    assert _rel(res.cov, fit.cov.to_numpy()) < TOL


def test_windmeijer_sandwich_is_windmeijers_formula():
    """With the weight's own long-run covariance in the middle (S = W⁻¹), the corrected
    sandwich L S Lᵀ, L = C + D C₁, is Windmeijer's (2005) V + DV + VDᵀ + D V₁ Dᵀ with
    V = (AᵀWA)⁻¹ and V₁ the robust first-step (2SLS) variance; D = 0 gives V."""
    from vesselid.identify.covariance import _windmeijer_sandwich

    rng = np.random.default_rng(3)
    k, p = 6, 3
    a = rng.normal(size=(k, p))
    r = rng.normal(size=(k, k))
    s = r @ r.T + k * np.eye(k)
    w = np.linalg.inv(s)
    r1 = rng.normal(size=(k, k))
    w1 = np.linalg.inv(r1 @ r1.T + k * np.eye(k))
    d = 0.1 * rng.normal(size=(p, p))
    v = np.linalg.inv(a.T @ w @ a)
    c1 = np.linalg.solve(a.T @ w1 @ a, a.T @ w1)
    v1 = c1 @ s @ c1.T
    expected = v + d @ v + v @ d.T + d @ v1 @ d.T
    got = _windmeijer_sandwich(a, [0.4 * s, 0.6 * s], w, w1, d)
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(_windmeijer_sandwich(a, [s], w, w1, np.zeros((p, p))), v,
                               rtol=1e-12)


def test_windmeijer_option_and_weight_jacobian_validation():
    rng = np.random.default_rng(4)
    z, phi, y = _problem(rng, n=200)
    z = np.column_stack([z, z[:, :2] ** 2])
    resid = y - phi @ np.linalg.lstsq(phi, y, rcond=None)[0]
    w = np.linalg.inv(z.T @ z)
    est = get_covariance_estimator("hac")
    assert est.windmeijer
    d = 0.05 * np.eye(3)
    res = est.estimate(z, phi, resid, weight=w, weight_jacobian=d)
    plain = est.estimate(z, phi, resid, weight=w)
    assert res.config["windmeijer"] and "Windmeijer (2005)" in res.label
    assert "windmeijer" not in plain.config and "Windmeijer" not in plain.label
    assert not np.allclose(res.cov, plain.cov)
    off = get_covariance_estimator("hac", windmeijer=False).estimate(
        z, phi, resid, weight=w, weight_jacobian=d)
    np.testing.assert_array_equal(off.cov, plain.cov)
    assert off.config["windmeijer"] is False and "Windmeijer" not in off.label
    # the unit-free correction: rescaling a regressor column rescales D consistently
    scale = np.array([1.0, 1e3, 1e-2])
    res_s = est.estimate(z, phi * scale, resid, weight=w,
                         weight_jacobian=d / scale[:, None] * scale[None, :])
    np.testing.assert_allclose(res_s.cov * np.outer(scale, scale), res.cov, rtol=1e-9)
    for bad in ({"weight_jacobian": d}, {"weight": w, "weight_jacobian": np.eye(2)},
                {"weight": w, "weight_jacobian": np.full((3, 3), np.nan)}):
        with pytest.raises(CovarianceError):
            est.estimate(z, phi, resid, **bad)
    with pytest.raises(CovarianceError, match="windmeijer"):
        get_covariance_estimator("unadjusted", windmeijer="yes")


@pytest.mark.parametrize("kernel", ["bartlett", "qs"])
def test_sriv_covariance_matches_iv2sls_on_its_prefiltered_rows(kernel):
    """SRIV (``auto``'s fallback) hands the covariance its final rows: instruments,
    regressors and residuals after the AR noise-model prefilter, instruments centred.
    Its standard errors equal linearmodels ``IV2SLS`` with a constant on exactly those
    rows (``y = ε + φθ``) with the same kernel and bandwidth, and ``identify`` reports
    them (``fixed_b=False``; by default, Bartlett kernel, each scaled by its fixed-b
    critical value over 1.96)."""
    import warnings

    from vesselid.identify import identify
    from vesselid.identify.backend import kernels as kern
    from vesselid.identify.data import from_log
    from vesselid.identify.registry import get_estimator
    from vesselid.plant.systems import heave

    log = heave(pulse_design="random").simulate(3000, seed=5).to_log()
    est = get_estimator("sriv")
    data, spec = from_log(log, None)
    it = est.estimate_parameters(data, spec, keep_history=True)
    phi_all = kern.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    (d,) = est.equation_designs(data, spec, it, phi_all, "pooled")
    theta = it.theta[0]
    assert d.zero_mean and d.weight is None and d.starts.tolist() == [0, d.z.shape[0]]
    bw = 11
    res = iv_covariance(d.z, d.phi, d.resid, d.starts, zero_mean=True, skip_first=False,
                        cov_type="hac", kernel=kernel, bandwidth=bw)
    y = d.resid + d.phi @ theta
    fit = lm_iv.IV2SLS(y, np.ones((y.size, 1)), d.phi, d.z).fit(
        cov_type="kernel", kernel=kernel, bandwidth=bw, debiased=False)
    np.testing.assert_allclose(fit.params.to_numpy()[1:], theta, rtol=1e-8)
    assert _rel(res.cov, fit.cov.to_numpy()[1:, 1:]) < 1e-8
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fitted = identify(log, method="sriv", cov_config={"kernel": kernel, "bandwidth": bw,
                                                          "fixed_b": False})
        scaled = identify(log, method="sriv", cov_config={"kernel": kernel, "bandwidth": bw})
    assert _rel(fitted.cov.to_numpy(), res.cov) < 1e-10
    fb = get_covariance_estimator("hac", kernel=kernel, bandwidth=bw).estimate(
        d.z, d.phi, d.resid, d.starts, zero_mean=True, skip_first=False, fixed_b_square=True)
    assert _rel(scaled.cov.to_numpy(), fb.cov) < 1e-10
    if kernel == "bartlett":
        from vesselid.identify.fixedb import bartlett_critical_value

        q = bartlett_critical_value(np.asarray(fb.config["effective_b"])) / 1.96
        assert np.all(q > 1.0)
        np.testing.assert_allclose(fb.cov, res.cov * np.outer(q, q), rtol=1e-10)
    else:  # the kernel's fixed-b quantiles are Bartlett's only
        np.testing.assert_array_equal(fb.cov, res.cov)
