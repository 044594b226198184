"""Prediction-error estimator (``pem``) and ``auto``'s use of it: exact recovery,
consistency under coloured disturbances where the instruments are not, coverage of its
inverse-Fisher intervals, model choice, bad input."""

import json
import warnings

import numpy as np
import pytest
from _stats import binomial_ok

from vesselid.errors import IdentificationError
from vesselid.identify import from_arrays, get_estimator, identify
from vesselid.identify.estimators import estimate
from vesselid.plant.systems import heave
from vesselid.studies.calibration import heave_scenario

THETA0 = np.array([0.99, -0.1, 1.0])


def _batch(scenario, samples, runs, seed):
    system, _, _ = heave_scenario(scenario)
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(samples, n_runs=runs, seed=seed)
    return from_arrays(spec, sim.y, sim.u), spec


def _z(err):
    """Mean error over its Monte Carlo standard error, per parameter."""
    return err.mean(0) / (err.std(0, ddof=1) / np.sqrt(err.shape[0]))


def test_pem_is_exact_on_noise_free_data_without_warnings():
    log = heave(variance=0.0, xi_mean=0.0).simulate(2000, n_runs=2, seed=1).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = identify(log, method="pem")
    np.testing.assert_allclose(res.params.to_numpy(), THETA0, atol=1e-8)
    assert res.converged and res.diagnostics["disturbance_model"] == "none"


@pytest.mark.slow
def test_pem_consistent_under_gauss_markov_current_where_iv_is_not_precise():
    """GM current inside the modulus (time constant 25 samples): PEM's mean error is
    within 4 of its Monte Carlo standard errors, shrinks with N, and its median error on
    the damping is below IV_E{ζ}=0's on the same runs; LS stays biased."""
    errs, med_iv, med_pem = {}, {}, {}
    for n in (3000, 12000):
        data, spec = _batch("gm-current-random", n, 24, seed=21)
        base = estimate(data, spec, "iv-zero-mean")
        it = get_estimator("pem").estimate_parameters(data, spec, base=base)
        assert it.converged.all() and (it.info["pem_model"] == "current").all()
        errs[n] = (it.theta - THETA0) / THETA0
        med_pem[n] = np.median(np.abs(errs[n][:, 1]))
        med_iv[n] = np.median(np.abs((base.theta[:, 1] - THETA0[1]) / THETA0[1]))
        assert np.all(np.abs(_z(errs[n])) < 4.0), (n, _z(errs[n]))
        assert med_pem[n] < med_iv[n], (n, med_pem[n], med_iv[n])
    rms = {n: np.sqrt(np.mean(e**2, axis=0)) for n, e in errs.items()}
    assert np.all(rms[12000] < rms[3000]), rms
    ls = estimate(data, spec, "ls").theta
    assert np.abs(_z((ls - THETA0) / THETA0)).max() > 6.0


@pytest.mark.slow
def test_pem_chooses_the_sensor_noise_model_under_coloured_sensor_noise():
    data, spec = _batch("gm-sensor-alternating", 8000, 12, seed=22)
    it = get_estimator("pem").estimate_parameters(data, spec)
    assert it.converged.all()
    # Vuong z of the current model against the sensor-noise model: negative
    assert np.mean(it.info["pem_model"] == "sensor") >= 0.75, it.info["pem_model"]
    assert np.median(it.info["pem_vuong"]) < 0
    err = (it.theta - THETA0) / THETA0
    assert np.all(np.abs(_z(err)) < 4.0), _z(err)


@pytest.mark.slow
def test_pem_intervals_cover_theta0_under_gauss_markov_current():
    """95 % intervals from the inverse Fisher information: coverage consistent with 95 %
    (exact binomial test at 1e-3 over the run count), both pulse designs."""
    for scenario, seed in (("gm-current-random", 31), ("gm-current-alternating", 32)):
        data, spec = _batch(scenario, 10_000, 120, seed=seed)
        it = get_estimator("pem").estimate_parameters(data, spec)
        se = np.sqrt(np.einsum("gii->gi", it.info["pem_cov"]))
        hits = np.sum(np.abs(it.theta - THETA0) <= 1.96 * se, axis=0)
        for p in range(3):
            assert binomial_ok(int(hits[p]), it.theta.shape[0], 0.95), (scenario, hits)


def test_identify_pem_reports_model_covariance_and_summary():
    system, _, _ = heave_scenario("gm-current-alternating")
    log = system.simulate(6000, seed=4).to_log(aggregate=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="pem")
    assert res.diagnostics["cov_type"] == "fisher"
    assert res.diagnostics["disturbance_model"] == "current"
    assert "Vuong" in res.diagnostics["model_choice"]
    text = res.summary()
    assert "inverse Fisher information" in text and "Gauss–Markov current" in text
    assert np.all(np.isfinite(res.std_errors)) and np.all(res.std_errors > 0)
    # the reported SE is the θ block of the inverse Fisher information of the fit
    it = get_estimator("pem").estimate_parameters(*_one(log))
    np.testing.assert_allclose(res.cov.to_numpy(), it.info["pem_cov"][0], rtol=1e-12)


def _one(log):
    from vesselid.identify.data import from_log

    data, spec = from_log(log, None)
    return data, spec


def test_auto_uses_pem_under_a_coloured_current_and_json_is_strict(tmp_path):
    from vesselid.cli import main

    system, _, _ = heave_scenario("gm-current-random")
    log = system.simulate(10_000, seed=5).to_log(aggregate=False)
    path = tmp_path / "gm.csv"
    log.save(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log)
        code = main(["identify", str(path), "--json", str(tmp_path / "r.json")])
    assert res.diagnostics["instruments"] == "none: prediction-error estimator (PEM)"
    assert "prediction-error estimator" in res.diagnostics["instrument_choice"]
    assert code == 0
    payload = json.loads((tmp_path / "r.json").read_text(),
                         parse_constant=lambda c: pytest.fail(f"non-strict JSON: {c}"))
    assert payload["method"] == "auto"
    np.testing.assert_allclose(
        [payload["params"]["w"][t] for t in ("w", "w*|w|", "tau")], res.params.to_numpy())


def test_auto_on_white_noise_calls_pem_only_where_a_test_or_the_guard_sends_it():
    data, spec = _batch("table1-alternating", 4000, 8, seed=6)
    it = get_estimator("auto").estimate_parameters(data, spec)
    reject = (it.info["c_pvalue"] < 0.01) | (it.info["colour_pvalue"] < 0.05)
    band = ~reject & (it.info["colour_pvalue"] < 0.2)  # the colour test's guard band
    used = it.info["instrument_set"]
    # no test rejects and the colour test's p-value reaches its guard: no likelihood model
    assert (used[~reject & ~band] == "combined").all()
    assert np.isin(used[reject | band], ["pem", "simulated"]).all()
    # in the band the sensor-noise model alone
    assert set(it.info["pem_model"][band & (used == "pem")]) <= {"sensor"}


def test_pem_bad_input_one_line_reasons(capsys, tmp_path):
    from vesselid.cli import main

    est = get_estimator("pem")
    log2 = heave(current_mean=0.1).simulate(500, seed=1).to_log(aggregate=True)
    with pytest.raises(IdentificationError, match=r"pem.*aggregate"):
        identify(log2, method="pem")
    log = heave().simulate(500, seed=1).to_log()
    with pytest.raises(IdentificationError, match="inverse Fisher"):
        identify(log, method="pem", cov_type="hac")
    for bad in ({"scoring_iter": 0}, {"scoring_tol": -1.0}, {"scoring_tol": float("nan")}):
        with pytest.raises(IdentificationError):
            identify(log, method=type(est)(**bad))
    path = tmp_path / "t.csv"
    log.save(path)
    code = main(["identify", str(path), "--method", "pem", "--cov", "hac"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Fisher" in err


def test_joint_fit_that_gains_likelihood_is_scored_to_convergence(monkeypatch):
    """A joint fit that already beats the single process when its first scoring budget
    runs out is continued to convergence (and then reported), not dropped."""
    from test_validity import SPEC as HEAVE
    from test_validity import _log

    from vesselid.identify import pem
    from vesselid.identify.data import from_log
    from vesselid.identify.estimators import estimate

    data, spec = from_log(_log(11, gm_current=0.1, gm_sensor=0.1), HEAVE)
    base = estimate(data, spec, "iv-zero-mean", combine="pooled")
    full = pem.fit_groups(data, spec, base.theta, joint=True)
    assert full["model"][0] == pem.JOINT and full["converged"][0]
    monkeypatch.setattr(pem, "JOINT_ITER", 2)  # the first budget runs out at once
    cut = pem.fit_groups(data, spec, base.theta, joint=True)
    assert cut["model"][0] == pem.JOINT and cut["converged"][0]
    assert cut["lr_joint"][0] > 0
    se = np.sqrt(np.diag(full["cov"][0]))
    assert np.all(np.abs(cut["theta"][0] - full["theta"][0]) < 0.05 * se)
