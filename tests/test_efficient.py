"""Estimators beyond the paper: exact recovery, agreement with linearmodels, C test,
consistency trend."""

import warnings

import numpy as np
import pandas as pd
import pytest

from vesselid.identify import ESTIMATORS, from_arrays, get_estimator, identify
from vesselid.identify.data import from_log
from vesselid.plant.systems import heave

NEW = ["lagged-2sls", "sriv", "gmm", "auto"]


@pytest.mark.parametrize("method", list(ESTIMATORS))
def test_every_registered_estimator_is_exact_on_noise_free_data(method):
    log = heave(variance=0.0, xi_mean=0.0).simulate(2000, n_runs=2, seed=1).to_log()
    if method == "cl-iv":  # a closed-loop estimator needs a closed-loop log
        from vesselid.plant.closedloop import heave_pi_design, simulate_closed_loop

        d = heave_pi_design()
        log = simulate_closed_loop(heave(variance=0.0, xi_mean=0.0), d.controller,
                                   d.reference, dither=d.dither, n_samples=2000, n_runs=2,
                                   seed=1).to_log()
    res = identify(log, method=method)
    np.testing.assert_allclose(res.params.to_numpy(), [0.99, -0.1, 1.0], atol=1e-8)
    assert np.all(np.isfinite(res.std_errors))


def _lagged_frame(y, u):
    k = np.arange(3, y.size)
    return pd.DataFrame({"y": y[k], "c": 1.0, "tau": u[k - 1], "w1": y[k - 1],
                         "ww1": y[k - 1] * np.abs(y[k - 1]), "w2": y[k - 2],
                         "ww2": y[k - 2] * np.abs(y[k - 2]), "w3": y[k - 3],
                         "ww3": y[k - 3] * np.abs(y[k - 3])})


def test_lagged_2sls_equals_linearmodels_iv2sls():
    from linearmodels.iv import IV2SLS

    sim = heave(pulse_design="alternating").simulate(3000, seed=4)
    d = _lagged_frame(sim.y[0, :, 0], sim.u[0, :, 0])
    ref = IV2SLS(d["y"], d[["c", "tau"]], d[["w1", "ww1"]],
                 d[["w2", "ww2", "w3", "ww3"]]).fit(cov_type="unadjusted")
    spec = heave().identification_spec(aggregate=False)
    it = get_estimator("lagged-2sls").estimate_parameters(from_arrays(spec, sim.y, sim.u), spec)
    np.testing.assert_allclose(it.theta[0], ref.params[["w1", "ww1", "tau"]], rtol=1e-10)


def test_gmm_equals_linearmodels_ivgmm_params_and_j():
    """On the final instruments and rows, our two-step HAC GMM and Hansen's J equal
    linearmodels IVGMM (Bartlett kernel, same bandwidth, centred scores)."""
    from linearmodels.iv import IVGMM

    from vesselid.identify.gmm import hac_lags

    log = heave(pulse_design="alternating").simulate(4000, seed=5).to_log()
    data, spec = from_log(log, log.spec.with_aggregate(None))
    it = get_estimator("gmm").estimate_parameters(data, spec, keep_history=True)
    z, phi, y, _, _ = it.info["solution"].designs[0]
    bw = hac_lags(4000)
    ref = IVGMM(y, None, phi, z, weight_type="kernel", kernel="bartlett", bandwidth=bw,
                center=True).fit(iter_limit=2, cov_type="unadjusted")
    np.testing.assert_allclose(it.theta[0], np.asarray(ref.params), rtol=1e-8)
    np.testing.assert_allclose(it.info["j_stat"][0, 0], ref.j_stat.stat, rtol=1e-6)
    assert it.info["j_df"][0] == z.shape[1] - phi.shape[1] == 4


def test_auto_keeps_delayed_instruments_on_white_noise_and_says_why():
    log = heave(pulse_design="alternating").simulate(5000, seed=2).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="auto")
    assert res.diagnostics["instruments"] in ("combined", "simulated")
    assert "C test of the delayed instruments p =" in res.diagnostics["instrument_choice"]
    assert "colour test" in res.diagnostics["instrument_choice"]
    assert "auto used" in res.summary()  # the plain sentence of its choice


@pytest.mark.parametrize(("pulses", "field", "tau", "samples", "p_key", "p_max"), [
    # GM current: the delayed measurements are biased by tens of SEs; C rejects
    ("alternating", "current", 25.0, 10_000, "c_pvalue", 1e-6),
    # GM sensor noise: they bias GMM by several SEs; the colour test sees it (the C test
    # alone missed most runs)
    ("random", "sensor_noise", 20.0, 40_000, "colour_pvalue", 1e-3),
])
def test_auto_rejects_delayed_instruments_under_coloured_disturbances(
        pulses, field, tau, samples, p_key, p_max):
    import dataclasses

    from vesselid.plant.disturbances import GaussMarkov

    system = dataclasses.replace(heave(pulse_design=pulses),
                                 **{field: {"w": GaussMarkov(0.0, 0.1, tau)}})
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(samples, n_runs=4, seed=3)
    it = get_estimator("auto").estimate_parameters(from_arrays(spec, sim.y, sim.u), spec)
    assert (it.info["instrument_set"] != "combined").all()
    if field == "current":  # the tests reject: the prediction-error estimator
        assert (it.info["instrument_set"] == "pem").all()
        # a Gauss–Markov current: alone or with coloured sensor noise (joint; its
        # variance without the bound at zero where the likelihood does not establish it)
        assert np.isin(it.info["pem_model"], ["current", "joint", "joint-local"]).all()
    assert np.all(it.info[p_key] < p_max), it.info[p_key]


def test_auto_falls_back_without_prefilter_on_a_low_pass_filtered_log():
    """A log whose metadata records a low-pass (wave) filter: ``auto``'s fallback uses the
    simulated instruments without the whitening AR prefilter (IV_E{ζ}=0-like) and says
    so (the prediction-error model has no filter in it); the same data without the record
    fall back to the prediction-error estimator, and without it to SRIV."""
    import dataclasses
    import warnings

    from vesselid.identify import identify
    from vesselid.identify.efficient import InstrumentalGMM
    from vesselid.plant.disturbances import GaussMarkov

    system = dataclasses.replace(heave(pulse_design="alternating"),
                                 current={"w": GaussMarkov(0.0, 0.1, 25.0)})
    log = system.simulate(20_000, seed=3).to_log()
    spec = system.identification_spec(aggregate=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = identify(log, spec)
        sriv = identify(log, spec, method=InstrumentalGMM("auto", noise_order=4, refine=1))
        log.metadata["wave_filter"] = {"kind": "butterworth", "columns": ["w"]}
        low = identify(log, spec)
    assert plain.diagnostics["instruments"] == "none: prediction-error estimator (PEM)"
    assert plain.diagnostics["disturbance_model"] in ("current", "joint", "joint-local")
    assert sriv.diagnostics["instruments"] == low.diagnostics["instruments"] == "simulated"
    assert sriv.diagnostics["noise_model"].startswith("AR(4) prefilter")
    assert low.diagnostics["noise_model"] == "none (the log is low-pass filtered)"
    assert "no noise-model prefilter" in low.diagnostics["instrument_choice"]
    assert not np.array_equal(sriv.params.to_numpy(), low.params.to_numpy())


@pytest.mark.parametrize("method", ["gmm", "sriv"])
def test_option_validation(method):
    from vesselid.errors import IdentificationError
    from vesselid.identify.efficient import InstrumentalGMM

    log = heave().simulate(500, seed=0).to_log()
    with pytest.raises(IdentificationError, match="combine"):
        identify(log, method=method, combine="stacked")
    with pytest.raises(IdentificationError, match="noise_order"):
        identify(log, method=InstrumentalGMM("simulated", noise_order=-1))
    with pytest.raises(IdentificationError, match="instruments must be"):
        identify(log, method=InstrumentalGMM("nope"))
    with pytest.raises(IdentificationError, match="alpha"):
        identify(log, method=InstrumentalGMM("auto", alpha=2.0))
    with pytest.raises(IdentificationError, match="colour_alpha"):
        identify(log, method=InstrumentalGMM("auto", colour_alpha=0.0))


def test_asymptotic_covariance_for_trial_planning():
    from vesselid.identify import asymptotic_covariance

    log = heave(pulse_design="alternating").simulate(4000, seed=8).to_log()
    cov = asymptotic_covariance(log)
    assert cov.shape == (3, 3) and np.all(np.isfinite(cov.to_numpy()))
    assert np.all(np.diag(cov.to_numpy()) > 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = identify(log).cov
    np.testing.assert_allclose(cov.to_numpy(), ref.to_numpy())


@pytest.mark.slow
def test_default_estimator_consistent_white_noise():
    """Table-1 setting: the default's RMS error shrinks ~√10 from 10⁴ to 10⁵ samples and
    its mean error at 10⁵ is within 4 standard errors of zero."""
    from vesselid.identify import DEFAULT_METHOD

    system = heave(pulse_design="alternating")
    spec = system.identification_spec(aggregate=False)
    est = get_estimator(DEFAULT_METHOD)
    rms, errs = {}, {}
    for n in (10_000, 100_000):
        sim = system.simulate(n, n_runs=16, seed=12)
        theta = est.estimate_parameters(from_arrays(spec, sim.y, sim.u), spec).theta
        errs[n] = (theta - spec.theta0_vector()) / spec.theta0_vector()
        rms[n] = np.sqrt(np.mean(errs[n] ** 2, axis=0))
    assert np.all(rms[10_000] / rms[100_000] > 2.0), rms
    se = errs[100_000].std(axis=0, ddof=1) / np.sqrt(16)
    assert np.all(np.abs(errs[100_000].mean(axis=0)) < 4 * se)


def test_colour_test_has_its_level_on_white_noise():
    """Table-1 white disturbances: the colour statistic is χ²(2), so it rejects at 5 % in
    a binomially compatible fraction of runs (exact binomial test at 1e-3)."""
    from _stats import binomial_ok
    from scipy.stats import chi2

    from vesselid.identify import gmm, kernels
    from vesselid.identify.estimators import estimate

    system = heave(pulse_design="alternating")
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(5000, n_runs=120, seed=11)
    data = from_arrays(spec, sim.y, sim.u)
    theta = estimate(data, spec, "iv-zero-mean").theta
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    z, _ = gmm.simulated_instruments(data, spec, theta)
    stat, df = gmm.colour_test(data, spec, phi, z)
    assert df.tolist() == [2]
    rejected = int(np.sum(chi2.sf(stat[:, 0], 2) < 0.05))
    assert binomial_ok(rejected, 120, 0.05), rejected


def test_noise_instruments_window_and_boundaries():
    from vesselid.identify import gmm, kernels

    system = heave()
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(300, n_runs=2, seed=1)
    data = from_arrays(spec, sim.y, sim.u)
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    z, _ = gmm.simulated_instruments(data, spec, np.array([[0.99, -0.1, 1.0]] * 2))
    eta = gmm.noise_instruments(data, spec, phi, z, window=(2, 5))
    endo = gmm.state_terms(spec)
    raw = phi[:, endo] - z[:, endo]
    for s in range(2):
        a = int(data.starts[s])
        assert np.isnan(eta[a:a + 6]).all() and np.isfinite(eta[a + 6:a + 300]).all()
        k = a + 50
        np.testing.assert_allclose(eta[k], raw[k - 5:k - 1].mean(axis=0), rtol=1e-12)
    with pytest.raises(ValueError, match="window"):
        gmm.noise_instruments(data, spec, phi, z, window=(0, 3))


def _noise_instruments_numpy(data, spec, phi, z_sim, window):
    """The numpy formulation the compiled colour-test instrument must equal bit for bit."""
    from vesselid.identify.gmm import state_terms

    lo, hi = window
    endo = state_terms(spec)
    eta = np.nan_to_num(phi[:, endo] - z_sim[:, endo])
    csum = np.zeros((eta.shape[0] + 1, eta.shape[1]))
    np.cumsum(eta, axis=0, out=csum[1:])
    rows = np.arange(eta.shape[0])
    seg_start = np.repeat(data.starts[:-1], np.diff(data.starts))
    ok = rows - hi >= seg_start + 1
    out = np.full_like(eta, np.nan)
    r = rows[ok]
    out[ok] = (csum[r - lo + 1] - csum[r - hi]) / (hi - lo + 1)
    bad = ~np.all(np.isfinite(z_sim[:, endo]), axis=1)
    if bad.any():
        cb = np.concatenate([[0], np.cumsum(bad)])
        hit = np.zeros(eta.shape[0], dtype=bool)
        hit[r] = (cb[r - lo + 1] - cb[r - hi]) > 0
        out[hit] = np.nan
    return out


def test_noise_instruments_compiled_equal_numpy_formulation():
    from vesselid.identify import gmm, kernels

    system = heave(pulse_design="alternating")
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(300, n_runs=3, seed=5)
    data = from_arrays(spec, sim.y, sim.u)
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    theta = np.tile(spec.theta0_vector(), (3, 1))
    z_sim, _ = gmm.simulated_instruments(data, spec, theta)
    z_sim[400, 0] = np.nan  # a diverged simulation inside run 1's windows
    z_sim[50, 1] = np.inf   # η clipped to the largest float
    phi[700, 1] = -np.inf
    for window in (gmm.COLOUR_WINDOW, (1, 1), (3, 8)):
        got = gmm.noise_instruments(data, spec, phi, z_sim, window)
        ref = _noise_instruments_numpy(data, spec, phi, z_sim, window)
        np.testing.assert_array_equal(got, ref)
        assert np.isfinite(got).any() and np.isnan(got).any()


def test_weight_jacobian_equals_finite_difference_of_two_step_gmm():
    """Windmeijer's D = ∂θ₂/∂θ₁ (through the HAC weight S(θ₁)⁻¹, same Bartlett
    bandwidth, per-experiment lags and centring) equals a central difference of the
    two-step estimate re-weighted at perturbed first steps, and ∂S/∂θ equals a central
    difference of S (exact: S is quadratic in θ)."""
    from vesselid.identify.efficient import _starts_of
    from vesselid.identify.gmm import hac_lags, hac_sums, hac_sums_derivative

    log = heave(pulse_design="alternating").simulate(3000, n_runs=2, seed=5).to_log()
    data, spec = from_log(log, log.spec.with_aggregate(None))
    it = get_estimator("gmm").estimate_parameters(data, spec, keep_history=True)
    sol = it.info["solution"]
    z, phi, y, valid, _ = sol.designs[0]
    starts = _starts_of(valid, sol)
    assert np.all(valid[np.concatenate([np.arange(a + 3, b) for a, b in
                                        zip(data.starts[:-1], data.starts[1:], strict=True)])])
    bw = hac_lags(3000)
    every = np.ones(z.shape[0], dtype=bool)
    a, b = z.T @ phi, z.T @ y
    w1 = np.linalg.inv(z.T @ z)
    th1 = np.linalg.solve(a.T @ w1 @ a, a.T @ w1 @ b)

    def long_run(t):
        return hac_sums(z, y - phi @ t, starts, every, bw).sum(axis=0)

    def two_step(t):
        w = np.linalg.inv(long_run(t))
        return np.linalg.solve(a.T @ w @ a, a.T @ w @ b)

    np.testing.assert_allclose(two_step(th1), it.theta[0], rtol=1e-9)
    h = 1e-3 * np.abs(th1)
    d_fd = np.column_stack([(two_step(th1 + h[j] * np.eye(3)[j])
                             - two_step(th1 - h[j] * np.eye(3)[j])) / (2 * h[j])
                            for j in range(3)])
    d = sol.jacobians[0]
    np.testing.assert_allclose(d, d_fd, atol=1e-5 * np.abs(d).max())
    u = np.random.default_rng(1).normal(size=z.shape[1])
    ds_u = hac_sums_derivative(z, phi, y - phi @ th1, starts, every, bw, u)
    for j in range(3):
        step = h[j] * np.eye(3)[j]
        fd = (long_run(th1 + step) - long_run(th1 - step)) @ u / (2 * h[j])
        np.testing.assert_allclose(ds_u[:, j], fd, atol=1e-9 * np.abs(fd).max())


def test_gmm_standard_errors_carry_the_windmeijer_correction():
    """gmm (and auto when it keeps the delayed instruments) report Windmeijer-corrected
    SEs and say so; the estimates are unchanged and ``windmeijer=False`` gives the plain
    sandwich; estimators without an estimated weight are untouched."""
    log = heave(pulse_design="alternating").simulate(4000, n_runs=2, seed=5).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="gmm")
        plain = identify(log, method="gmm", cov_config={"windmeijer": False})
        sriv = identify(log, method="sriv")
    assert "Windmeijer (2005)" in res.diagnostics["cov_label"]
    assert res.diagnostics["cov_type"] == "hac"
    assert "Windmeijer" not in plain.diagnostics["cov_label"]
    assert "Windmeijer" not in sriv.diagnostics["cov_label"]
    np.testing.assert_array_equal(res.params.to_numpy(), plain.params.to_numpy())
    assert not np.array_equal(res.std_errors.to_numpy(), plain.std_errors.to_numpy())
    np.testing.assert_allclose(res.std_errors.to_numpy(), plain.std_errors.to_numpy(),
                               rtol=0.2)


def test_hac_sums_derivative_with_gaps_and_experiments():
    """∂S/∂θ of :func:`hac_sums` with invalid rows inside experiments (zeroed, time kept)
    and per-experiment centring equals a central difference (S is quadratic in θ)."""
    from vesselid.identify.gmm import hac_sums, hac_sums_derivative

    rng = np.random.default_rng(7)
    n, k, p = 400, 5, 2
    z, phi = rng.normal(size=(n, k)), rng.normal(size=(n, p)) + 0.3
    y = phi @ np.array([0.5, -1.0]) + rng.normal(size=n)
    starts = np.array([0, 150, 400])
    valid = rng.random(n) > 0.1
    theta = np.array([0.4, -0.9])
    for u in np.eye(k):  # every column of ∂S/∂θ_j
        ds_u = hac_sums_derivative(z, phi, y - phi @ theta, starts, valid, 6, u)
        for j in range(p):
            step = 0.01 * np.eye(p)[j]
            fd = (hac_sums(z, y - phi @ (theta + step), starts, valid, 6).sum(axis=0)
                  - hac_sums(z, y - phi @ (theta - step), starts, valid, 6).sum(axis=0)) / 0.02
            np.testing.assert_allclose(ds_u[:, j], fd @ u, atol=1e-9 * np.abs(fd).max())


def _colour_reference(data, spec, theta):
    """The explicit colour test (rows, stacked instruments) of instruments simulated
    from ``theta``."""
    from vesselid.identify import gmm, kernels

    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    z, _ = gmm.simulated_instruments(data, spec, theta)
    return gmm.colour_test(data, spec, phi, z)


@pytest.mark.parametrize("scenario", ["table1-alternating", "gm-sensor-random"])
def test_fused_colour_test_equals_the_explicit_one(scenario):
    """The colour test fused into the combined GMM pass (``auto``'s Monte Carlo path)
    gives the explicit statistic to rounding (1e-9 relative) on white and coloured
    designs, groups of two experiments, a group whose auxiliary model diverges and a
    group with a NaN segment; the combined estimates do not change (bit for bit)."""
    import dataclasses

    from vesselid.identify import gmm
    from vesselid.identify.estimators import estimate
    from vesselid.studies.calibration import heave_scenario

    system, aggregate, _ = heave_scenario(scenario)
    spec = system.identification_spec(aggregate=aggregate)
    sim = system.simulate(3000, n_runs=10, seed=21)
    data = from_arrays(spec, sim.y, sim.u, experiments_per_group=2)
    theta = estimate(data, spec, "iv-zero-mean").theta
    theta[1] = np.abs(theta[1]) + 1.5  # group 1: the auxiliary model diverges
    target, regsig = data.target.copy(), data.regsig.copy()
    seg = data.segment(5)  # group 2, second experiment: NaN from row 100 (not simulated)
    target[seg.start + 100:seg.stop] = np.nan
    regsig[seg.start + 100:seg.stop] = np.nan
    seg = data.segment(6)  # group 3: NaN measurements in rows 500-509 (left out)
    regsig[seg.start + 500:seg.start + 510] = np.nan
    data = dataclasses.replace(data, target=target, regsig=regsig)
    fused, _ = gmm.combined_solution(data, spec, theta, colour=gmm.COLOUR_WINDOW)
    plain, _ = gmm.combined_solution(data, spec, theta)
    for field in ("theta", "ok", "j", "c"):
        np.testing.assert_array_equal(getattr(fused, field), getattr(plain, field))
    stat, df = _colour_reference(data, spec, theta)
    np.testing.assert_array_equal(fused.colour_df, df)
    ok = fused.colour_ok
    # non-finite sums (NaN rows in a simulated experiment): the caller computes those
    # groups explicitly
    np.testing.assert_array_equal(ok, np.arange(5) != 3)
    assert stat[1, 0] == 0.0 and fused.colour[1, 0] == 0.0  # nothing left to test
    assert stat[2, 0] > 0 and np.isfinite(stat).all()
    np.testing.assert_allclose(fused.colour[ok], stat[ok], rtol=1e-9, atol=0)


@pytest.mark.slow
def test_auto_decision_and_estimates_do_not_depend_on_the_fused_colour_test(monkeypatch):
    """``auto`` batched with the fused colour test and with the explicit one (generic
    kernels) makes the same choice and the same estimates, bit for bit; the statistics
    agree to 1e-9 relative (white and coloured sensor noise, both choices taken)."""
    from vesselid.identify.estimators import estimate
    from vesselid.studies.calibration import heave_scenario

    est = get_estimator("auto")
    for scenario in ("table1-alternating", "gm-sensor-alternating"):
        system, aggregate, _ = heave_scenario(scenario)
        spec = system.identification_spec(aggregate=aggregate)
        sim = system.simulate(4000, n_runs=16, seed=8)
        data = from_arrays(spec, sim.y, sim.u)
        base = estimate(data, spec, "iv-zero-mean")
        fast = est.estimate_parameters(data, spec, base=base)
        with monkeypatch.context() as m:
            m.setenv("VESSELID_GENERIC_KERNELS", "1")
            slow = est.estimate_parameters(data, spec, base=base)
        np.testing.assert_array_equal(fast.theta, slow.theta)
        np.testing.assert_array_equal(fast.info["instrument_set"], slow.info["instrument_set"])
        np.testing.assert_allclose(fast.info["colour_stat"], slow.info["colour_stat"],
                                   rtol=1e-9, atol=0)
        if scenario.startswith("gm"):
            assert (fast.info["instrument_set"] != "combined").any()


def test_prefiltered_design_in_one_pass_is_bit_identical(monkeypatch):
    """SRIV's prefiltered, centred design (``design_ar_centre``) equals stacking,
    masking, scaling, ``ar_filter`` and ``center`` bit for bit (several groups with their
    own noise models, a diverged group's NaN instruments)."""
    from vesselid.identify import gmm, kernels

    system = heave()
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(2000, n_runs=6, seed=2)
    data = from_arrays(spec, sim.y, sim.u, experiments_per_group=2)
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    theta = np.tile(spec.theta0_vector(), (3, 1))
    theta[1] = np.abs(theta[1]) + 1.5
    z, _ = gmm.simulated_instruments(data, spec, theta)
    rng = np.random.default_rng(0)
    ar = np.concatenate([np.ones((3, 1, 1)), 0.3 * rng.standard_normal((3, 1, 4))], axis=2)
    blocks = gmm.instrument_blocks(spec, "simulated", phi, z, None)
    fast = gmm.solve_equations(data, spec, phi, blocks, ar=ar, keep_designs=False)
    monkeypatch.setattr(gmm, "numpy_active", lambda: True)  # the stacked formulation
    slow = gmm.solve_equations(data, spec, phi, blocks, ar=ar, keep_designs=False)
    for field in ("theta", "ok", "j", "c"):
        np.testing.assert_array_equal(getattr(fast, field), getattr(slow, field))
    assert np.isfinite(fast.theta[0]).all() and not fast.ok[1]


def test_whitened_colour_test_by_hand_equals_linearmodels_j():
    """The AR(2)-whitened colour test on one run, computed by hand: Yule–Walker AR(2) of
    the demeaned IV_E{ζ}=0 residual, target / regressors / instruments (simulated ζ and
    the noise averaged over lags 3–18) prefiltered by ``Ĉ(q)`` with scipy's ``lfilter``,
    rows whose filter window is complete, centred; Hansen's J of linearmodels ``IVGMM``
    (two-step, Bartlett kernel, same bandwidth, centred moments) equals the statistic."""
    from linearmodels.iv import IVGMM
    from scipy.signal import lfilter

    from vesselid.identify import gmm, kernels
    from vesselid.identify.estimators import estimate

    system = heave(pulse_design="random")
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(3000, seed=21)
    data = from_arrays(spec, sim.y, sim.u)
    theta = estimate(data, spec, "iv-zero-mean").theta
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    z, _ = gmm.simulated_instruments(data, spec, theta)
    stat, df = gmm.colour_test(data, spec, phi, z, theta=theta, noise_order=2)
    assert df.tolist() == [2] and gmm.whitened_colour_window(2) == (3, 18)

    y = data.target[:, 0]
    e = y - phi @ theta[0]
    ok = np.isfinite(e)
    d = e[ok] - e[ok].mean()
    r = [d[j:] @ d[:d.size - j] for j in range(3)]
    c = np.linalg.solve([[r[0], r[1]], [r[1], r[0]]], r[1:])
    ar = np.array([1.0, -c[0], -c[1]])
    endo = gmm.state_terms(spec)
    raw = phi[:, endo] - z[:, endo]
    eta = np.full_like(raw, np.nan)
    for k in range(19, y.size):
        eta[k] = raw[k - 18:k - 2].mean(axis=0)
    stack = np.column_stack([y, phi, z, eta])
    rows = np.isfinite(stack).all(axis=1)
    filt = lfilter(ar, [1.0], np.where(rows[:, None], stack, 0.0), axis=0)
    keep = rows & np.roll(rows, 1) & np.roll(rows, 2)
    keep[:2] = False
    f = filt[keep] - filt[keep].mean(axis=0)
    ref = IVGMM(f[:, 0], None, f[:, 1:4], f[:, 4:], weight_type="kernel", kernel="bartlett",
                bandwidth=gmm.hac_lags(y.size), center=True).fit(iter_limit=2)
    np.testing.assert_allclose(stat[0, 0], ref.j_stat.stat, rtol=1e-6)


def test_whitened_colour_test_size_on_white_noise_and_power_on_coloured_sensor_noise():
    """AR(2)-whitened colour test at 5 %: on the white Table-1 design its rejections are
    binomially compatible with 5 % (exact test at 1e-3, 120 runs); under Gauss–Markov
    sensor noise (random pulses, time constant 20) it rejects in at least 90 % of runs
    (one-sided exact binomial at 1e-3; measured 98.3 % over 1000 runs of 10⁴ samples,
    ``scripts/colour_study.py``). The test fails if the window reached into the MA(1)
    lags (size) or the prefilter removed the noise correlation (power)."""
    import dataclasses

    from _stats import binomial_ok
    from scipy.stats import binomtest, chi2

    from vesselid.identify import gmm, kernels
    from vesselid.identify.estimators import estimate
    from vesselid.plant.disturbances import GaussMarkov

    def rejections(system, samples, runs, seed):
        spec = system.identification_spec(aggregate=False)
        sim = system.simulate(samples, n_runs=runs, seed=seed)
        data = from_arrays(spec, sim.y, sim.u)
        theta = estimate(data, spec, "iv-zero-mean").theta
        phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
        z, _ = gmm.simulated_instruments(data, spec, theta)
        stat, df = gmm.colour_test(data, spec, phi, z, theta=theta, noise_order=2)
        return int(np.sum(chi2.sf(stat[:, 0], df[0]) < 0.05))

    white = rejections(heave(pulse_design="alternating"), 5000, 120, 11)
    assert binomial_ok(white, 120, 0.05), white
    coloured = dataclasses.replace(heave(pulse_design="random"),
                                   sensor_noise={"w": GaussMarkov(0.0, 0.1, 20.0)})
    power = rejections(coloured, 10_000, 60, 12)
    assert binomtest(power, 60, 0.9, alternative="less").pvalue > 1e-3, power


def test_auto_with_the_whitened_colour_test():
    """``InstrumentalGMM("auto", colour_order=2)``: the decision uses the whitened test
    (its statistic is :func:`gmm.colour_test`'s with ``noise_order=2`` at the IV_E{ζ}=0
    estimate), batched and one-log paths agree, and the result says which test ran."""
    from vesselid.errors import IdentificationError
    from vesselid.identify import gmm, kernels
    from vesselid.identify.efficient import InstrumentalGMM

    est = InstrumentalGMM("auto", noise_order=4, refine=1, colour_order=2, name="auto-w")
    system = heave(pulse_design="random")
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(4000, n_runs=3, seed=3)
    data = from_arrays(spec, sim.y, sim.u)
    it = est.estimate_parameters(data, spec)
    theta0 = it.info["base"].theta
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    z, _ = gmm.simulated_instruments(data, spec, theta0)
    stat, _ = gmm.colour_test(data, spec, phi, z, theta=theta0, noise_order=2)
    np.testing.assert_allclose(it.info["colour_stat"], stat, rtol=1e-12)
    log = system.simulate(4000, seed=3).to_log()
    res = identify(log, method=est)
    one = est.estimate_parameters(from_log(log, log.spec.with_aggregate(None))[0], spec)
    np.testing.assert_allclose(res.params.to_numpy(), one.theta[0], rtol=1e-10)
    assert res.diagnostics["colour_test_prefilter"] == "AR(2)"
    assert "AR(2)-whitened colour test" in res.diagnostics["instrument_choice"]
    assert get_estimator("auto").colour_order == 0  # the registered default: unfiltered
    with pytest.raises(IdentificationError, match="colour_order"):
        identify(log, method=InstrumentalGMM("auto", colour_order=-1))
    with pytest.raises(ValueError, match="start after"):
        gmm.colour_test(data, spec, phi, z, (2, 10), theta=theta0, noise_order=2)
    with pytest.raises(ValueError, match="needs theta"):
        gmm.colour_test(data, spec, phi, z, noise_order=2)
