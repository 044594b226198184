"""The kurtosis test of the smoothed current (a bimodal, switching current against a
Gaussian one) and ``auto``'s use of it for the joint model's sensor-noise bound."""

import math

import numpy as np
import pytest
from scipy import signal, stats

from vesselid.identify.current_shape import kurtosis_z, smoothed_current_test


def _ar1(rng, n, rho, std):
    e = rng.normal(0.0, std * math.sqrt(1 - rho * rho), n)
    e[0] = rng.normal(0.0, std)
    return signal.lfilter([1.0], [1.0, -rho], e)


def _telegraph(rng, n, level, p):
    flips = rng.random(n) < p
    return level * np.where(np.cumsum(flips) % 2 == 0, 1.0, -1.0)


def test_kurtosis_of_alternating_signs_by_hand():
    """``x = ±1`` alternating: excess kurtosis exactly −2; the autocorrelations are
    ``(−1)^j (T − j)/T``, so the variance is ``(24/T)(1 + 2 Σ_{j≤L} ((T − j)/T)⁴)``."""
    t = 400
    x = np.where(np.arange(t) % 2 == 0, 1.0, -1.0)
    kappa, z = kurtosis_z(x)
    assert kappa == pytest.approx(-2.0, abs=1e-12)
    lags = int(min(t - 1, 10 * math.sqrt(t)))
    j = np.arange(1, lags + 1)
    var = 24.0 / t * (1 + 2 * np.sum(((t - j) / t) ** 4))
    assert z == pytest.approx(-2.0 / math.sqrt(var), rel=1e-10)


def test_short_or_constant_series_give_nan_and_no_rejection():
    assert all(math.isnan(v) for v in kurtosis_z(np.ones(100)))
    assert all(math.isnan(v) for v in kurtosis_z(np.arange(10.0)))
    out = smoothed_current_test([np.zeros(50)], 0.9)
    assert not out["bimodal"] and math.isnan(out["z"])


def test_window_is_the_time_constant():
    rng = np.random.default_rng(0)
    r = [rng.normal(size=500)]
    assert smoothed_current_test(r, math.exp(-1 / 25))["window"] == 25
    assert smoothed_current_test(r, 0.0)["window"] == 1
    assert smoothed_current_test(r, float("nan"))["window"] == 1
    assert smoothed_current_test(r, 0.99999)["window"] == 200


def test_telegraph_rejected_gauss_markov_not():
    """Residual-like traces: a slow current plus white noise of the same size (seeded):
    the switching current is rejected far beyond the level, the Gauss–Markov one not."""
    rng = np.random.default_rng(5)
    n, rho = 10_000, math.exp(-1 / 25)
    tele = _telegraph(rng, n, 0.06, 0.02) + rng.normal(0, 0.08, n)
    gm = _ar1(rng, n, rho, 0.06) + rng.normal(0, 0.08, n)
    assert smoothed_current_test([tele], rho)["z"] < -4
    out = smoothed_current_test([gm[:6000], gm[6000:]], rho)
    assert not out["bimodal"] and out["window"] == 25


@pytest.mark.slow
def test_size_on_gaussian_ar1_traces():
    """Gaussian AR(1) traces plus white noise (ρ = 0.96, smoothed over 25 samples,
    10⁴ samples): the one-sided test rejects at most at its level (one-sided exact
    binomial test), and the spread of its z is not above one by more than four Monte
    Carlo standard errors of a standard deviation."""
    rng = np.random.default_rng(11)
    runs, rho = 300, math.exp(-1 / 25)
    zs = np.array([smoothed_current_test([_ar1(rng, 10_000, rho, 0.06)
                                          + rng.normal(0, 0.08, 10_000)], rho)["z"]
                   for _ in range(runs)])
    rej = int(np.sum(zs < -2.326))
    assert stats.binomtest(rej, runs, 0.01, alternative="greater").pvalue > 1e-3, rej
    assert zs.std(ddof=1) - 1.0 < 4 / math.sqrt(2 * runs), zs.std()


@pytest.mark.slow
def test_auto_bounds_the_joint_model_on_a_telegraph_current():
    """The robustness study's telegraph current (±0.06, switching w.p. 0.02, 10⁴
    samples): the test finds it bimodal in at least 95 % of runs (one-sided exact
    binomial test; measured 200 of 200), and ``auto`` then reports the bounded joint
    fit, whose covariance carries the spread to the unbounded one."""
    from _scripts import load_script

    from vesselid.identify import from_arrays, get_estimator

    rs = load_script("robustness_study")
    runs = 30
    seeds = np.random.SeedSequence(77).spawn(runs)
    logs = [rs.simulate(rs.DESIGNS["telegraph"], np.random.default_rng(s), 10_000)
            for s in seeds]
    spec = rs.SPEC
    data = from_arrays(spec, np.stack([lg["w"].to_numpy()[:, None] for lg in logs]),
                       np.stack([lg["tau"].to_numpy()[:, None] for lg in logs]))
    it = get_estimator("auto").estimate_parameters(data, spec)
    pem_runs = it.info["instrument_set"] == "pem"
    assert pem_runs.all()
    bounded = int(np.sum(it.info["pem_boundary"] == "bounded"))
    assert stats.binomtest(bounded, runs, 0.95, alternative="less").pvalue > 1e-3, bounded
    assert np.all(it.info["pem_shape_z"][it.info["pem_boundary"] == "bounded"] < -2.326)
    assert not np.isin(it.info["pem_model"], ["joint-local"]).any()
    # and reports the switching-current model where Vuong's test prefers it (measured:
    # 200 of 200 runs of the robustness study)
    switched = int(np.sum(it.info["pem_model"] == "switching"))
    assert stats.binomtest(switched, runs, 0.95, alternative="less").pvalue > 1e-3, switched


def test_auto_on_one_telegraph_log_says_why_and_widens():
    """One telegraph log (6000 samples): ``auto`` without its switching-current model
    reports the bounded joint fit, names the bimodal current in its reason and in
    ``diagnostics["current_shape"]``, and its standard errors are those of the
    always-bounded variant widened by the spread to the unbounded fit (never narrower);
    on a Gauss–Markov log it takes the unbounded one. ``auto`` itself reports the
    switching-current model there (:mod:`vesselid.identify.switching`) and names the
    bimodal current too."""
    import warnings

    from _scripts import load_script

    from vesselid.identify import identify
    from vesselid.identify.efficient import InstrumentalGMM
    from vesselid.identify.registry import entry

    rs = load_script("robustness_study")
    log = rs.simulate(rs.DESIGNS["telegraph"], np.random.default_rng(5), 6_000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        default = identify(log, rs.SPEC)
        res = identify(log, rs.SPEC, InstrumentalGMM(**{**entry("auto").options,
                                                        "pem_switching": False}))
        bounded = identify(log, rs.SPEC, InstrumentalGMM(**{**entry("auto").options,
                                                            "pem_boundary": "bounded",
                                                            "pem_switching": False}))
    assert default.diagnostics["choice"] == "pem-switching"
    assert "looks bimodal" in default.diagnostics["choice_reason"]
    assert default.diagnostics["current_shape"]["kurtosis_z"] < -2.326
    d = res.diagnostics
    assert d["current_shape"]["sensor_noise_bound"] == "bounded"
    assert d["current_shape"]["kurtosis_z"] < -2.326
    assert "looks bimodal" in d["choice_reason"]
    np.testing.assert_array_equal(res.params.to_numpy(), bounded.params.to_numpy())
    assert np.all(res.std_errors.to_numpy() >= bounded.std_errors.to_numpy() * (1 - 1e-12))
    assert np.any(res.std_errors.to_numpy() > bounded.std_errors.to_numpy())
    gm = rs.simulate(rs.DESIGNS["gm-current"], np.random.default_rng(5), 6_000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        g = identify(gm, rs.SPEC).diagnostics
    assert g["current_shape"]["sensor_noise_bound"] == "unbounded"
    assert g["choice"] in ("pem-joint-local", "pem-joint")
