"""Fixed-b critical values at the effective bandwidth ratio (two-step GMM intervals):
hand-computed sums, Kiefer–Vogelsang's quantiles, linearmodels with the corrections
off, and Monte Carlo coverage on short logs (slow)."""

from __future__ import annotations

import math
import warnings

import linearmodels.iv as lm_iv
import numpy as np
import pytest

from vesselid.errors import CovarianceError
from vesselid.identify.covariance import get_covariance_estimator
from vesselid.identify.fixedb import (
    BARTLETT_QUANTILES,
    bartlett_critical_value,
    bartlett_cross,
    effective_b,
)


def _bartlett_matrix(n: int, lags: int) -> np.ndarray:
    j = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    return np.clip(1.0 - j / (lags + 1.0), 0.0, None)


def test_bartlett_cross_is_the_double_sum_within_experiments():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(40, 3)), rng.normal(size=(40, 3))
    segs = [slice(1, 15), slice(16, 40)]
    for lags in (0, 1, 4, 30):
        want = np.zeros(3)
        for s in segs:
            w = _bartlett_matrix(s.stop - s.start, lags)
            want += np.einsum("kj,kl,lj->j", x[s], w, y[s])
        np.testing.assert_allclose(bartlett_cross(x, y, lags, segs), want, rtol=1e-12)
        np.testing.assert_allclose(bartlett_cross(x, x, lags, segs),
                                   np.einsum("kj,kl,lj->j", x[1:15], _bartlett_matrix(14, lags),
                                             x[1:15])
                                   + np.einsum("kj,kl,lj->j", x[16:], _bartlett_matrix(24, lags),
                                               x[16:]), rtol=1e-12)


def test_effective_b_of_a_homogeneous_design_is_m_over_t():
    """Constant ``ℓᵀ z φᵀ u = 1/T``: ``b = Σ_{k,l} w(k−l)/T² = (T + 2 Σ_j (1 − j/M)(T − j))/T²``,
    ``M/T`` up to ``O(M²/T²)``."""
    t, lags = 500, 9
    m = lags + 1
    zl = [np.full((t, 1), 1.0 / t)]
    b = effective_b(zl, np.ones((t, 1)), np.array([[2.0]]), np.array([0]), lags,
                    [slice(0, t)])
    want = (t + 2 * sum((1 - j / m) * (t - j) for j in range(1, m))) / t**2
    np.testing.assert_allclose(b, [want], rtol=1e-12)
    assert abs(b[0] - m / t) < (m / t) ** 2


def test_effective_b_per_equation_and_block_forms_agree():
    """Two equations, each parameter's influence within its own instruments: the one-array
    form equals the per-equation form; a joint covariance across equations is allowed."""
    rng = np.random.default_rng(2)
    t, eq = 60, np.array([0, 0, 1, 1, 1])
    zl_block = rng.normal(size=(t, 5))
    zl_list = [np.where(eq[None, :] == e, zl_block, 0.0) for e in range(2)]
    phi = rng.normal(size=(t, 5))
    r = rng.normal(size=(5, 5))
    cov = r @ r.T + np.eye(5)
    segs = [slice(0, 25), slice(25, t)]
    got = effective_b(zl_block, phi, cov, eq, 3, segs)
    np.testing.assert_allclose(got, effective_b(zl_list, phi, cov, eq, 3, segs), rtol=1e-12)
    # by hand for one parameter of the second equation
    u = cov[:, 3] / cov[3, 3]
    s = zl_block[:, 3] * (phi[:, 2:] @ u[2:])
    want = sum(s[sl] @ _bartlett_matrix(sl.stop - sl.start, 3) @ s[sl] for sl in segs)
    assert got[3] == pytest.approx(want, rel=1e-12)


def test_critical_values_are_kiefer_vogelsangs():
    assert bartlett_critical_value(0.0) == pytest.approx(1.96)
    # KV (2005) Bartlett, b = 0.1 and 1 (two-sided 5 %)
    assert bartlett_critical_value(0.1) == pytest.approx(1.96 + 0.29694 + 0.00416 - 0.0005324)
    assert bartlett_critical_value(1.0) == pytest.approx(1.96 + 2.9694 + 0.4160 - 0.5324)
    assert bartlett_critical_value(5.0) == bartlett_critical_value(1.0)  # clipped
    b = np.linspace(0, 1, 21)
    for q in BARTLETT_QUANTILES:
        assert np.all(np.diff(bartlett_critical_value(b, q)) > 0)
    with pytest.raises(ValueError, match="quantile"):
        bartlett_critical_value(0.1, 0.5)
    with pytest.raises(CovarianceError, match="fixed_b"):
        get_covariance_estimator("hac", fixed_b="yes")


def _gmm_problem(seed: int = 11, n: int = 300):
    """Over-identified linear IV, persistent instruments, MA(1) error; two-step GMM with a
    Bartlett weight (linearmodels IVGMM) and the centred design."""
    rng = np.random.default_rng(seed)
    z = np.repeat(rng.normal(size=(n // 10, 4)), 10, axis=0) + 0.3 * rng.normal(size=(n, 4))
    phi = z[:, :2] @ np.array([[1.0, 0.3], [0.2, 1.0]]) + 0.5 * rng.normal(size=(n, 2))
    e = np.convolve(rng.normal(size=n + 1), [1.0, -0.6], "valid")
    y = phi @ np.array([0.7, -1.2]) + e
    zc, pc, yc = z - z.mean(0), phi - phi.mean(0), y - y.mean()
    fit = lm_iv.IVGMM(yc, None, pc, zc, weight_type="kernel", kernel="bartlett",
                      bandwidth=4).fit(cov_type="kernel", kernel="bartlett", bandwidth=4,
                                       iter_limit=2)
    w = np.asarray(fit.weight_matrix)
    theta = fit.params.to_numpy()
    return zc, pc, yc - pc @ theta, w, fit


def test_corrections_off_match_linearmodels_ivgmm_and_on_scale_by_the_hand_computed_b():
    z, phi, resid, w, fit = _gmm_problem()
    d = np.array([[0.05, -0.02], [0.01, 0.03]])  # a weight Jacobian (any finite one)
    off = get_covariance_estimator("hac", kernel="bartlett", bandwidth=4,
                                   windmeijer=False).estimate(
        z, phi, resid, weight=w, skip_first=False, weight_jacobian=d)
    ref = fit.cov.to_numpy()
    np.testing.assert_allclose(off.cov, ref, rtol=1e-7)
    assert not off.config.get("fixed_b") and "fixed-b" not in off.label
    # Windmeijer with D = 0 and no fixed-b: the uncorrected two-step covariance again
    plain = get_covariance_estimator("hac", kernel="bartlett", bandwidth=4,
                                     fixed_b=False).estimate(
        z, phi, resid, weight=w, skip_first=False, weight_jacobian=np.zeros((2, 2)))
    np.testing.assert_allclose(plain.cov, ref, rtol=1e-7)
    wind = get_covariance_estimator("hac", kernel="bartlett", bandwidth=4,
                                    fixed_b=False).estimate(
        z, phi, resid, weight=w, skip_first=False, weight_jacobian=d)
    on = get_covariance_estimator("hac", kernel="bartlett", bandwidth=4).estimate(
        z, phi, resid, weight=w, skip_first=False, weight_jacobian=d)
    # by hand: L = C + D C₁, u_p = V_{·p}/V_pp, s(k) = ℓ_pᵀ z(k) φ(k)ᵀ u_p,
    # b_p = sᵀ W_bartlett s, SE_p × q(b_p)/1.96
    a = z.T @ phi
    w1 = np.linalg.inv(z.T @ z)
    infl = (np.linalg.solve(a.T @ w @ a, a.T @ w) + d @ np.linalg.solve(a.T @ w1 @ a, a.T @ w1))
    v = wind.cov
    kern = _bartlett_matrix(z.shape[0], 4)
    b = np.empty(2)
    for p in range(2):
        s = (z @ infl[p]) * (phi @ (v[:, p] / v[p, p]))
        u = v[:, p] / v[p, p]
        assert s.sum() == pytest.approx(1.0 + d[p] @ u, rel=1e-9)  # ℓ_pᵀ A u = (I + D) u
        b[p] = s @ kern @ s
    np.testing.assert_allclose(on.config["effective_b"], b, rtol=1e-9)
    q = (1.96 + b * (2.9694 + b * (0.4160 - 0.5324 * b))) / 1.96
    np.testing.assert_allclose(on.cov, v * np.outer(q, q), rtol=1e-9)
    assert on.config["fixed_b"] and "fixed-b (Kiefer-Vogelsang 2005)" in on.label
    assert np.all(b > 5 / z.shape[0])  # persistent instruments: above M/T
    # rescaling a regressor column rescales the covariance consistently
    scale = np.array([1e3, 1e-2])
    on_s = get_covariance_estimator("hac", kernel="bartlett", bandwidth=4).estimate(
        z, phi * scale, resid, weight=w, skip_first=False,
        weight_jacobian=d / scale[:, None] * scale[None, :])
    np.testing.assert_allclose(on_s.cov * np.outer(scale, scale), on.cov, rtol=1e-8)


def test_gmm_reports_the_fixed_b_scaling():
    from vesselid.identify import identify
    from vesselid.plant.systems import heave

    log = heave(pulse_design="random").simulate(1500, seed=4).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="gmm")
        off = identify(log, method="gmm", cov_config={"fixed_b": False})
    np.testing.assert_array_equal(res.params, off.params)
    ratio = (res.std_errors / off.std_errors).to_numpy()
    assert np.all(ratio > 1.0) and np.all(ratio < 1.5)
    assert "fixed-b" in res.diagnostics["cov_label"]
    assert "fixed-b" not in off.diagnostics["cov_label"]


@pytest.mark.slow
def test_auto_covers_on_short_white_logs():
    """``auto`` on 10³-sample logs of the robustness study's white design (two-step GMM
    in ~95 % of runs): every parameter's 95 % interval covers θ0 within three binomial
    standard errors of 95 %, and the intervals stay honest in width (mean SE / Monte
    Carlo sd below 1.25)."""
    from _scripts import load_script

    from vesselid.identify import identify

    rs = load_script("robustness_study")

    runs = 600
    seeds = np.random.SeedSequence(7).spawn(runs)
    est, se = np.empty((runs, 3)), np.empty((runs, 3))
    for r, s in enumerate(seeds):
        log = rs.simulate(rs.DESIGNS["short"], np.random.default_rng(s), 1000)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify(log, rs.SPEC, "auto")
        est[r], se[r] = res.params.to_numpy(), res.std_errors.to_numpy()
    err = est - np.array(rs.THETA0)
    cover = np.mean(np.abs(err) <= 1.959964 * se, axis=0)
    tol = 3 * math.sqrt(0.95 * 0.05 / runs)
    assert np.all(np.abs(cover - 0.95) <= tol), cover
    assert np.all(se.mean(0) / err.std(0, ddof=1) < 1.25)


def _hand_fixed_b(d, cov_off: np.ndarray, lags: int) -> np.ndarray:
    """``q(b_p)/1.96`` of a just-identified design by hand: ``ℓ_p`` the rows of
    ``A⁻¹`` (``A = Σ z φᵀ``), ``u_p = V_{·p}/V_pp``, ``s(k) = ℓ_pᵀ z(k) φ_c(k)ᵀ u_p`` with
    the regressors centred per experiment, ``b_p = Σ_E sᵀ W_bartlett s``."""
    infl = np.linalg.inv(d.z.T @ d.phi)
    b = np.zeros(cov_off.shape[0])
    for a, e in zip(d.starts[:-1], d.starts[1:], strict=True):
        z, phi = d.z[a:e], d.phi[a:e] - d.phi[a:e].mean(axis=0)
        kern = _bartlett_matrix(e - a, lags)
        for p in range(b.size):
            s = (z @ infl[p]) * (phi @ (cov_off[:, p] / cov_off[p, p]))
            b[p] += s @ kern @ s
    return (1.96 + b * (2.9694 + b * (0.4160 - 0.5324 * b))) / 1.96


def _refined_iv_fits(log, combine: str, lags: int):
    from vesselid.identify import identify
    from vesselid.identify.backend import kernels as kern
    from vesselid.identify.data import from_log
    from vesselid.identify.registry import get_estimator

    est = get_estimator("iv-zero-mean")
    data, spec = from_log(log, None)
    it = est.estimate_parameters(data, spec, combine=combine)
    phi_all = kern.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    (d,) = est.equation_designs(data, spec, it, phi_all, combine)
    cfg = {"kernel": "bartlett", "bandwidth": lags}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        on = identify(log, method="iv-zero-mean", combine=combine, cov_config=cfg)
        off = identify(log, method="iv-zero-mean", combine=combine,
                       cov_config={**cfg, "fixed_b": False})
    np.testing.assert_array_equal(on.params, off.params)
    assert "fixed-b" not in off.diagnostics["cov_label"]
    return d, on, off


def test_refined_iv_intervals_take_the_fixed_b_critical_value():
    """``iv-zero-mean`` on one experiment: with the correction off its standard errors
    are linearmodels' ``IV2SLS`` (constant, Bartlett kernel) on the estimator's final
    rows; by default each is scaled by ``q(b_p)/1.96`` with ``b_p`` computed by hand from
    those rows, and the label says so."""
    from vesselid.plant.systems import heave

    lags = 9
    log = heave(pulse_design="random").simulate(1500, seed=8).to_log()
    d, on, off = _refined_iv_fits(log, "pooled", lags)
    assert d.fixed_b and d.starts.tolist() == [0, d.z.shape[0]]
    theta = on.params.to_numpy()
    y = d.resid + d.phi @ theta
    fit = lm_iv.IV2SLS(y, np.ones((y.size, 1)), d.phi, d.z).fit(
        cov_type="kernel", kernel="bartlett", bandwidth=lags, debiased=False)
    np.testing.assert_allclose(fit.params.to_numpy()[1:], theta, rtol=1e-8)
    v_off, v_on = off.cov.to_numpy(), on.cov.to_numpy()
    np.testing.assert_allclose(v_off, fit.cov.to_numpy()[1:, 1:], rtol=1e-8)
    q = _hand_fixed_b(d, v_off, lags)
    assert np.all(q > 1.0)
    np.testing.assert_allclose(v_on, v_off * np.outer(q, q), rtol=1e-9)
    assert "fixed-b (Kiefer-Vogelsang 2005)" in on.diagnostics["cov_label"]


def test_refined_iv_fixed_b_within_experiments_and_not_stacked():
    """Two experiments: the effective ratio sums the Bartlett products within each
    experiment (by hand); a stacked estimate keeps the normal critical value (the fixed-b
    limit is that of the pooled estimate)."""
    from vesselid.plant.systems import heave

    lags = 6
    log = heave(pulse_design="random").simulate(900, n_runs=2, seed=9).to_log()
    d, on, off = _refined_iv_fits(log, "pooled", lags)
    assert len(d.starts) == 3
    v_off = off.cov.to_numpy()
    q = _hand_fixed_b(d, v_off, lags)
    np.testing.assert_allclose(on.cov.to_numpy(), v_off * np.outer(q, q), rtol=1e-9)
    _, on_s, off_s = _refined_iv_fits(log, "stacked", lags)
    np.testing.assert_array_equal(on_s.cov.to_numpy(), off_s.cov.to_numpy())
    assert "fixed-b" not in on_s.diagnostics["cov_label"]


def test_closed_loop_iv_intervals_take_the_fixed_b_critical_value():
    """``cl-iv`` (just identified, instruments from the simulated closed loop): the same
    scaling, by hand from its final rows, switched off by ``fixed_b=False``."""
    from vesselid.identify import identify
    from vesselid.identify.backend import kernels as kern
    from vesselid.identify.closedloop import ClosedLoopIV, closed_loop_signals
    from vesselid.identify.data import from_log
    from vesselid.plant.closedloop import PID, simulate_closed_loop
    from vesselid.plant.disturbances import Gaussian
    from vesselid.plant.signals import RandomPulses
    from vesselid.plant.systems import heave

    system = heave()
    pid = PID(loops={"tau": "w"}, kp={"tau": 0.3}, ki={"tau": 0.05}, offset={"tau": 0.2})
    sim = simulate_closed_loop(system, pid, {"w": RandomPulses(1.0, 2.0, 50, 200)},
                               dither={"tau": Gaussian(0.0, 0.05)}, n_samples=2000, seed=3)
    log = sim.to_log(aggregate=False)
    spec = system.identification_spec(aggregate=False)
    lags = 12
    cfg = {"kernel": "bartlett", "bandwidth": lags}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        on = identify(log, spec, "cl-iv", cov_config=cfg)
        off = identify(log, spec, "cl-iv", cov_config={**cfg, "fixed_b": False})
    np.testing.assert_array_equal(on.params, off.params)
    est = ClosedLoopIV().with_signals(closed_loop_signals(log, spec))
    data, _ = from_log(log, spec)
    it = est.estimate_parameters(data, spec)
    np.testing.assert_array_equal(it.theta[0], on.params.to_numpy())
    phi = kern.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    (d,) = est.equation_designs(data, spec, it, phi, "pooled")
    v_off = off.cov.to_numpy()
    q = _hand_fixed_b(d, v_off, lags)
    assert np.all(q > 1.0)
    np.testing.assert_allclose(on.cov.to_numpy(), v_off * np.outer(q, q), rtol=1e-9)
    assert "fixed-b" in on.diagnostics["cov_label"]
    assert "fixed-b" not in off.diagnostics["cov_label"]


@pytest.mark.slow
def test_refined_iv_covers_on_short_white_logs():
    """``iv-zero-mean`` on 400-sample logs of the robustness study's white design (input
    pulses tens of samples wide: the estimated residuals leak the estimation error into
    the HAC far more than ``M/T`` says). With the fixed-b critical value every parameter's
    95 % interval covers θ0 within three binomial standard errors of 95 %; the normal
    critical value on the same fits falls short of that on at least one parameter (the
    correction is what makes the intervals hold)."""
    from _scripts import load_script

    from vesselid.identify import identify

    rs = load_script("robustness_study")
    runs = 600
    seeds = np.random.SeedSequence(7).spawn(runs)
    err, se_on, se_off = (np.empty((runs, 3)) for _ in range(3))
    for r, s in enumerate(seeds):
        log = rs.simulate(rs.DESIGNS["short"], np.random.default_rng(s), 400)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            on = identify(log, rs.SPEC, "iv-zero-mean")
            off = identify(log, rs.SPEC, "iv-zero-mean", cov_config={"fixed_b": False})
        err[r] = on.params.to_numpy() - np.array(rs.THETA0)
        se_on[r], se_off[r] = on.std_errors.to_numpy(), off.std_errors.to_numpy()
    tol = 3 * math.sqrt(0.95 * 0.05 / runs)
    cover_on = np.mean(np.abs(err) <= 1.959964 * se_on, axis=0)
    cover_off = np.mean(np.abs(err) <= 1.959964 * se_off, axis=0)
    assert np.all(np.abs(cover_on - 0.95) <= tol), cover_on
    assert np.any(cover_off < 0.95 - tol), cover_off


def test_batched_refined_iv_covariance_is_identifys():
    """The batched Monte Carlo covariance of ``iv-zero-mean`` (``group_covariances``)
    takes the same fixed-b scaling as ``identify``."""
    from vesselid.identify import identify
    from vesselid.identify.data import from_log
    from vesselid.identify.estimators import estimate
    from vesselid.plant.systems import heave
    from vesselid.studies.calibration import group_covariances

    log = heave(pulse_design="random").simulate(1500, n_runs=2, seed=4).to_log()
    data, spec = from_log(log, None)
    it = estimate(data, spec, "iv-zero-mean")
    cov, cfg = group_covariances(data, spec, it.theta, it.theta_aux, method="iv-zero-mean")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="iv-zero-mean")
    np.testing.assert_allclose(cov[0], res.cov.to_numpy(), rtol=1e-10)
    assert cfg[0]["fixed_b"] and len(cfg[0]["critical_value"]) == spec.n_params
