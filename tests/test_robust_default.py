"""The default estimator's safety net: fallback chain, stability check, the standard-error
stopping rule, the status of a result and ``vesselid identify``'s exit code 3."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from _refine import refine_with_fixed_point_map

from vesselid.errors import EstimationFailedError, FallbackWarning, NoUsableModelError
from vesselid.identify import identify
from vesselid.identify.data import from_log
from vesselid.identify.fallback import CHAIN, identify_with_fallback
from vesselid.identify.methods import LeastSquares
from vesselid.identify.stability import jacobians, stability_report
from vesselid.plant.catalogue import get_system

pytestmark = pytest.mark.filterwarnings("ignore::vesselid.errors.ExperimentDesignWarning")


@pytest.fixture(scope="module")
def log():
    return get_system("heave").simulate(4000, n_runs=1, seed=5).to_log()


class _NoEstimate(LeastSquares):
    """An estimator that runs but never finds a finite estimate."""

    name = "no-estimate"

    def estimate_parameters(self, data, spec, **kw):
        it = super().estimate_parameters(data, spec, **kw)
        it.theta[:] = np.nan
        it.reason[:] = "instrument matrix singular"
        return it


def test_default_accepted_is_the_estimator_itself(log):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        chained = identify(log)
        direct = identify(log, fallback=False)
    assert np.array_equal(chained.params.to_numpy(), direct.params.to_numpy())
    assert np.array_equal(chained.cov.to_numpy(), direct.cov.to_numpy())
    assert chained.diagnostics["fallback_chain"] == [
        {"method": "auto", "outcome": "accepted",
         "reason": chained.diagnostics["fallback_chain"][0]["reason"]}]
    assert "fallback_chain" not in direct.diagnostics
    assert chained.status == "ok"
    payload = json.loads(chained.to_json())
    assert payload["status"] == "ok" and payload["stability"]["stable"] is True
    assert payload["fallback_chain"][0]["outcome"] == "accepted"


def test_failed_default_falls_back_and_says_so(log):
    with pytest.raises(EstimationFailedError):
        identify(log, method=_NoEstimate())
    with pytest.warns(FallbackWarning, match="no-estimate"):
        res = identify(log, method=_NoEstimate(), fallback=True)
    chain = res.diagnostics["fallback_chain"]
    assert [c["method"] for c in chain] == ["no-estimate", "auto"]
    assert chain[0]["outcome"] == "raised" and "singular" in chain[0]["reason"]
    assert res.method == "auto" and res.status == "ok"
    text = res.summary()
    assert "fallback chain: no-estimate (raised) → auto (accepted)" in text
    assert json.loads(res.to_json())["fallback_chain"][1]["method"] == "auto"


def test_no_finite_estimate_anywhere_raises_with_the_chain(log):
    with pytest.raises(NoUsableModelError, match="no estimator gave a finite") as exc:
        identify_with_fallback(log, None, (_NoEstimate(), _NoEstimate()))
    assert [c["outcome"] for c in exc.value.chain] == ["raised", "raised"]


def test_bad_input_is_raised_by_the_first_member(log):
    from vesselid.errors import IdentificationError

    with pytest.raises(IdentificationError, match="combine"):
        identify(log, combine="nonsense")


def test_chain_order_is_documented():
    assert CHAIN[0] == "auto" and CHAIN[-1] == "ls"
    from vesselid.identify import registry

    assert set(CHAIN) <= set(registry.names())


def test_jacobian_of_the_heave_model_by_hand():
    spec = get_system("heave").identification_spec(aggregate=False)
    theta = np.array([0.99, -0.1, 1.0])
    w = np.array([[-0.5], [0.0], [0.7]])
    jac = jacobians(spec, theta, w, np.ones((3, 1)))
    np.testing.assert_allclose(jac[:, 0, 0], 0.99 - 0.2 * np.abs(w[:, 0]))


def test_stability_report_flags_an_unstable_model(log):
    data, spec = from_log(log, None)
    good = stability_report(data, spec, np.array([0.99, -0.1, 1.0]))
    assert good["stable"] and good["spectral_radius"]["operating_point"] < 1
    bad = stability_report(data, spec, np.array([1.2, 0.05, 1.0]))
    assert not bad["stable"] and bad["unbounded_experiments"] == [0]
    assert bad["sentence"].startswith("UNSTABLE") and bad["spectral_radius"]["median"] > 1


def test_standard_error_rule_only_where_the_residual_rule_fails(log):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = identify(log, method="iv-zero-mean")
        short = identify(log, method="iv-zero-mean", max_iter=2)
    assert full.converged and full.stop_reason == "converged"
    step = short.diagnostics["fixed_point_step_se"]
    assert short.converged == (step < 0.1)
    if short.converged:
        assert short.stop_reason.startswith("converged in standard-error units")
        assert f"{step:.2g}" in short.stop_reason
    else:
        assert short.stop_reason == "maximum iterations reached"


def test_status_of_an_unstable_result(log):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="ls")
    data, spec = from_log(log, None)
    res.diagnostics["stability"] = stability_report(data, spec, np.array([1.2, 0.05, 1.0]))
    assert res.status == "unstable" and "UNSTABLE" in res.status_reason
    res.diagnostics["stability"]["stable"] = True
    res.diagnostics["fit_free_run"] = {"w": float("nan")}
    assert res.status == "non-finite" and "free-run fit of w" in res.status_reason


def test_cli_exit_code_3_without_a_usable_model(tmp_path, log, monkeypatch, capsys):
    from vesselid import identify as ident_pkg
    from vesselid.cli import main

    path = tmp_path / "trial.csv"
    log.save(path)

    def no_model(*a, **k):
        raise NoUsableModelError("no estimator gave a finite estimate — auto: singular")

    monkeypatch.setattr(ident_pkg, "identify", no_model)
    code = main(["identify", str(path)])
    err = capsys.readouterr().err
    assert code == 3 and len(err.strip().splitlines()) == 1
    assert "no usable model" in err

    monkeypatch.undo()
    real = ident_pkg.identify

    def unstable(*a, **k):
        res = real(*a, **{**k, "method": "ls"})
        data, spec = from_log(log, None)
        res.diagnostics["stability"] = stability_report(data, spec,
                                                        np.array([1.2, 0.05, 1.0]))
        return res

    monkeypatch.setattr(ident_pkg, "identify", unstable)
    out_json = tmp_path / "r.json"
    export = tmp_path / "m.toml"
    code = main(["identify", str(path), "--json", str(out_json), "--export", str(export)])
    err = capsys.readouterr().err
    assert code == 3 and "UNSTABLE" in err.strip().splitlines()[-1]
    assert json.loads(out_json.read_text())["status"] == "unstable"
    assert not export.exists()


def _hovering(amp: float):
    """A state that hovers around zero, its pulses of ±amp small against the sensor noise."""
    from vesselid.model.spec import ModelSpec
    from vesselid.plant.disturbances import Gaussian
    from vesselid.plant.signals import RandomPulses
    from vesselid.plant.systems import System

    return System(spec=ModelSpec("s", ["x"], ["u"], {"x": ["x", "x*|x|", "u"]},
                                 theta0={"x": [0.9, -0.5, 1.0]}),
                  inputs={"u": RandomPulses(-amp, amp, 5, 30)},
                  sensor_noise={"x": Gaussian(0, 0.1)},
                  process_noise={"x": Gaussian(0, 0.02)}, x0={"x": 0.0})


def test_smoothness_warning_once_where_the_bias_matters():
    from vesselid.errors import ExperimentDesignWarning
    from vesselid.identify.diagnostics import SMOOTHNESS_BIAS_SE

    log = _hovering(0.05).simulate(20000, seed=1).to_log()
    with pytest.warns(ExperimentDesignWarning) as rec:
        res = identify(log, method="iv-zero-mean")
    lines = [str(w.message) for w in rec if issubclass(w.category, ExperimentDesignWarning)]
    assert len(lines) == 1 and "A10/A15" in lines[0] and "standard errors" in lines[0]
    rep = res.diagnostics["smoothness"]["x"]
    assert rep["matters"] and rep["bias_se"] >= SMOOTHNESS_BIAS_SE
    # the predicted bias is real: some parameter is off by more than 1.5 of its SEs
    assert res.compare()["error_in_std_errors"].abs().max() > 1.5
    assert json.loads(res.to_json())["smoothness"]["x"]["share_within_eta"] > 0.5
    assert res.summary().count("smoothness (A10/A15)") == 1


def test_excitation_names_a_constant_input_and_the_lost_terms():
    from vesselid.model.spec import ModelSpec
    from vesselid.plant.disturbances import Gaussian
    from vesselid.plant.signals import RandomPulses, StaticOffset
    from vesselid.plant.systems import System

    # a two-input vessel-like model whose second input (rpm) is held constant in every run
    system = System(spec=ModelSpec("s", ["x"], ["u", "n"], {"x": ["x", "x*|x|", "u", "n*|n|"]},
                                   theta0={"x": [0.9, -0.1, 1.0, 0.01]}),
                    inputs={"u": RandomPulses(0.1, 0.3, 10, 50), "n": StaticOffset(2.0)},
                    sensor_noise={"x": Gaussian(0, 0.02)}, x0={"x": 1.0})
    log = system.simulate(3000, seed=2).to_log()
    with pytest.raises(EstimationFailedError, match=r"n\*\|n\|.*'n' constant"):
        identify(log, method="iv-zero-mean")
    with pytest.warns(FallbackWarning):
        res = identify(log)
    exc = res.diagnostics["excitation"]
    assert exc["not_excited"] == ["n"] and exc["unidentifiable"] == {"x": [["n*|n|"]]}
    assert res.method == "ls"
    outcomes = {c["method"]: c["outcome"] for c in res.diagnostics["fallback_chain"]}
    assert outcomes["auto"] == "raised" and outcomes["ls"] == "accepted"
    assert "input 'n' is not excited" in res.summary()


def _noisy_map_refinement(monkeypatch, noise: float, average: bool):
    """:func:`refined_iv` on a heave log with ``T(θ) = θ0 + (θ − θ0)/2 + noise·N(0, 1)``
    (a stall: the residual cannot fall below the noise)."""
    jitter = np.random.default_rng(5)
    return refine_with_fixed_point_map(
        monkeypatch,
        lambda th, t0: t0 + 0.5 * (th - t0) + noise * jitter.standard_normal(th.shape),
        max_iter=500, average=average)


def test_stall_averaging_locates_the_fixed_point(monkeypatch):
    from vesselid.identify import estimators

    plain, target = _noisy_map_refinement(monkeypatch, 1e-6, average=False)
    assert "stall_average" not in plain.info  # the batched path: untouched
    avg, _ = _noisy_map_refinement(monkeypatch, 1e-6, average=True)
    assert avg.reason[0] == estimators.STOP_STALLED and not avg.converged[0]
    info = avg.info["stall_average"]
    assert info["groups"][0] and info["evaluations"] == estimators.STALL_AVERAGE
    # undamped, the iterates form an AR(1) with coefficient 1/2 and innovation sd 1e-6
    # about θ0: their mean has sd 1e-6/(1 − 1/2)/√32 (long-run variance); the reported
    # precision says so and the mean is that close
    sd_mean = 1e-6 / 0.5 / np.sqrt(32)
    np.testing.assert_allclose(info["sd_of_mean"][0], sd_mean, rtol=0.6)
    assert np.all(np.abs(avg.theta[0] - target) < 4 * sd_mean)
    assert np.all(np.abs(info["mean_step"][0]) < 4 * sd_mean)
