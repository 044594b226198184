"""Identification: exact recovery, consistency trends, safeguards, bad input."""

import json
import warnings

import numpy as np
import pandas as pd
import pytest
from _refine import refine_with_fixed_point_map

from vesselid.data.logs import TrialLog
from vesselid.errors import (
    ConvergenceWarning,
    ExperimentDesignWarning,
    IdentificationError,
    LogValidationError,
    RankDeficientError,
    WeakInstrumentWarning,
)
from vesselid.identify import estimators, from_arrays, identify
from vesselid.identify.estimators import estimate, refined_iv
from vesselid.model.spec import ModelSpec
from vesselid.plant.disturbances import Gaussian, Uniform
from vesselid.plant.signals import RandomPulses, StaticOffset
from vesselid.plant.systems import System, heave

METHODS = ["ls", "iv", "iv-zero-mean"]

MIMO_SPEC = ModelSpec(
    name="surge_yaw",
    states=["u", "r"],
    inputs=["X", "N"],
    equations={"u": ["u", "u*|u|", "X", "r*r"], "r": ["r", "r*|r|", "u*r", "N"]},
    theta0={"u": [0.95, -0.05, 0.1, 0.02], "r": [0.9, -0.1, -0.01, 0.2]},
)


def mimo_system(noise: float = 0.0, current: float = 0.0, sensor: bool = False) -> System:
    zero_ok = {"u": Gaussian(0, noise), "r": Gaussian(0, noise)}
    spec = MIMO_SPEC.with_aggregate({"u": "u - u_c"}) if sensor else MIMO_SPEC
    return System(
        spec=spec,
        inputs={"X": StaticOffset(3.0, Uniform(0, 2.0)), "N": RandomPulses(-0.5, 0.5, 5, 40)},
        current={"u": Gaussian(current, noise)} if noise or current else {},
        current_sign={"u": -1},
        process_noise=zero_ok if noise else {},
        sensor_noise=zero_ok if noise else {},
        current_sensor_noise={"u": Gaussian(0, noise)} if sensor else {},
        x0={"u": 1.0, "r": 0.0},
    )


def noise_free_heave() -> System:
    return heave(variance=0.0, xi_mean=0.0)


# ------------------------------------------------------------------ exact recovery
@pytest.mark.parametrize("method", METHODS)
def test_noise_free_siso_exact(method):
    log = noise_free_heave().simulate(3000, seed=1).to_log()
    res = identify(log, method=method)
    np.testing.assert_allclose(res.params.to_numpy(), [0.99, -0.1, 1.0], rtol=0, atol=1e-8)
    assert res.converged


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("combine", ["pooled", "stacked"])
def test_noise_free_mimo_multi_experiment_exact(method, combine):
    log = mimo_system().simulate(1500, n_runs=3, seed=2).to_log()
    assert log.data["experiment"].nunique() == 3
    res = identify(log, method=method, combine=combine)
    np.testing.assert_allclose(res.params.to_numpy(), MIMO_SPEC.theta0_vector(), atol=1e-8)
    assert res.n_experiments == 3
    assert list(res.params.index.get_level_values("equation").unique()) == ["u", "r"]


def test_noise_free_aggregated_exact():
    """With a current sensor but no noise, the aggregated predictor (9) is exact."""
    sys_ = mimo_system(noise=0.0, current=0.0, sensor=True)
    sys_ = System(**{**sys_.__dict__, "current": {"u": Gaussian(0.1, 0.05)},
                     "current_sensor_noise": {"u": Gaussian(0.0, 0.0)}})
    log = sys_.simulate(2000, n_runs=2, seed=4).to_log()
    assert log.spec.aggregate
    for method in METHODS:
        res = identify(log, method=method)
        # the process has no noise w, only the current inside: the aggregated state is exact
        np.testing.assert_allclose(res.params.to_numpy(), MIMO_SPEC.theta0_vector(), atol=1e-8)


def test_user_supplied_instruments_equal_ls_when_z_is_phi():
    from vesselid.identify import kernels
    from vesselid.identify.data import from_log

    log = heave().simulate(2000, seed=3).to_log()
    spec = log.spec.with_aggregate(None)
    data, _ = from_log(log, spec)
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    ls = identify(log, spec, method="ls")
    iv = identify(log, spec, method="iv", instruments=np.nan_to_num(phi))
    np.testing.assert_allclose(iv.params, ls.params, rtol=1e-10)
    assert iv.iterations == 0 and iv.stop_reason.startswith("user-supplied")


def test_hand_computed_two_sample_case():
    """Two equations, two parameters: IV with instruments Z solves ZᵀΦθ = Zᵀy exactly."""
    spec = ModelSpec("m", ["x"], ["u"], {"x": ["x", "u"]})
    df = pd.DataFrame({"x": [1.0, 2.0, 3.5], "u": [1.0, 0.5, 0.0]})
    # rows: y(1) = 2 = a·1 + b·1 ; y(2) = 3.5 = a·2 + b·0.5  ->  a = 5/3, b = 1/3
    res = identify(TrialLog(df), spec, method="ls", min_samples=3)
    np.testing.assert_allclose(res.params.to_numpy(), [5 / 3, 1 / 3], atol=1e-12)
    z = np.array([[np.nan, np.nan], [1.0, 0.0], [0.0, 1.0]])
    res_iv = identify(TrialLog(df), spec, method="iv", instruments=z, min_samples=3)
    np.testing.assert_allclose(res_iv.params.to_numpy(), [5 / 3, 1 / 3], atol=1e-12)


# ------------------------------------------------------------ consistency trends
def _batch_errors(system, spec, method, runs, samples, seed):
    sim = system.simulate(samples, n_runs=runs, seed=seed)
    data = from_arrays(spec, sim.y, sim.u, y2=sim.y2 if spec.aggregate else None)
    res = estimate(data, spec, method)
    assert res.converged.all()
    return (res.theta - spec.theta0_vector()) / spec.theta0_vector()


def test_zero_mean_iv_consistent_ls_biased_table1_setting():
    """Table-1 setting (w̄c = 0): RMS error of IV_E{ζ}=0 shrinks ~√10 from 10⁴ to 10⁵
    samples; LS keeps its bias."""
    system = heave()
    spec = system.identification_spec()
    rms = {}
    for method in ("ls", "iv-zero-mean"):
        for n in (10_000, 100_000):
            err = _batch_errors(system, spec, method, 24, n, seed=11)
            rms[method, n] = np.sqrt(np.mean(err**2, axis=0))
    shrink_iv = rms["iv-zero-mean", 10_000] / rms["iv-zero-mean", 100_000]
    shrink_ls = rms["ls", 10_000] / rms["ls", 100_000]
    assert np.all(shrink_iv > 2.0), shrink_iv          # ≈ √10 ≈ 3.2 for a consistent estimator
    assert np.all(shrink_ls[[0, 2]] < 1.3), shrink_ls  # bias dominates: no shrinkage
    assert np.all(rms["ls", 100_000][[0, 2]] > 10 * rms["iv-zero-mean", 100_000][[0, 2]] / 3)


def test_aggregated_predictor_consistent_where_plain_iv_is_not():
    """w̄c = 0.1 with a current meter: the aggregated predictor (9) with zero-mean
    instruments is unbiased (Lemma 4.1); the plain predictor (3) is not (§5)."""
    system = heave(current_mean=0.1, current_sensor=True, xi_mean=-0.05)
    runs, n = 24, 50_000
    agg = _batch_errors(system, system.identification_spec(aggregate=True), "iv-zero-mean",
                        runs, n, seed=5)
    plain = _batch_errors(system, system.identification_spec(aggregate=False), "iv-zero-mean",
                          runs, n, seed=5)
    se_agg = agg.std(axis=0, ddof=1) / np.sqrt(runs)
    se_plain = plain.std(axis=0, ddof=1) / np.sqrt(runs)
    assert np.all(np.abs(agg.mean(axis=0)) < 4 * se_agg), (agg.mean(0), se_agg)
    assert np.any(np.abs(plain.mean(axis=0)) > 6 * se_plain), (plain.mean(0), se_plain)


@pytest.mark.slow
def test_consistency_at_one_million_samples():
    """N = 10⁶: IV_E{ζ}=0 within 4 of its N-scaled standard deviations of θ0, LS far off."""
    system = heave()
    spec = system.identification_spec()
    sd_1e4 = np.array([0.049, 0.24, 0.085])  # Monte Carlo sd at N = 10⁴ (1000 runs)
    sd = sd_1e4 / 10.0
    err_iv = _batch_errors(system, spec, "iv-zero-mean", 2, 1_000_000, seed=21)
    err_ls = _batch_errors(system, spec, "ls", 2, 1_000_000, seed=21)
    assert np.all(np.abs(err_iv) < 4 * sd), err_iv
    assert np.all(np.abs(err_ls[:, 0]) > 20 * sd[0])


# ------------------------------------------------------------------- safeguards
def test_diverging_start_is_an_error_not_nan():
    log = heave().simulate(2000, seed=0).to_log()
    with pytest.raises(IdentificationError, match="diverges"):
        identify(log, method="iv", theta_start={"w": [1.5, 0.2, 1.0]})


def test_batch_marks_only_failing_groups():
    system = heave()
    spec = system.identification_spec()
    sim = system.simulate(2000, n_runs=3, seed=0)
    data = from_arrays(spec, sim.y, sim.u)
    start = np.tile(spec.theta0_vector(), (3, 1))
    start[1] = [1.5, 0.2, 1.0]
    res = refined_iv(data, spec, start, zero_mean=True)
    assert res.reason[1] == estimators.STOP_START_DIVERGED and not res.converged[1]
    assert np.isnan(res.theta[1]).all()
    assert res.converged[[0, 2]].all() and np.isfinite(res.theta[[0, 2]]).all()


def test_period_two_oscillation_is_damped(monkeypatch):
    """A fixed-point map with eigenvalue −1.5 oscillates and diverges undamped; the step
    control halves the step and converges, reporting the oscillation."""
    res, target = refine_with_fixed_point_map(
        monkeypatch, lambda th, t0: t0 - 1.5 * (th - t0), max_iter=200)
    assert res.converged[0]
    assert res.oscillation[0]
    np.testing.assert_allclose(res.theta[0], target, atol=1e-8)


def test_warnings_point_at_the_caller_of_identify():
    log = heave().simulate(5000, seed=0).to_log()
    with pytest.warns(ConvergenceWarning) as record:
        identify(log, method="iv-zero-mean", max_iter=2)
    assert record and {r.filename for r in record} == {__file__}


def test_noisy_fixed_point_map_stalls_and_says_so(monkeypatch):
    """A fixed-point map that jumps at the 1e-6 level for any change of θ (what an
    auxiliary simulation that amplifies rounding looks like) never meets tol: the
    iteration stops once its best residual has not improved for STALL_PATIENCE
    evaluations, reports the stall, and returns an estimate at that noise level."""
    jitter = np.random.default_rng(5)
    res, target = refine_with_fixed_point_map(
        monkeypatch,
        lambda th, t0: t0 + 0.5 * (th - t0) + 1e-6 * jitter.standard_normal(th.shape),
        max_iter=500)
    assert not res.converged[0]
    assert res.reason[0] == estimators.STOP_STALLED
    assert res.iterations[0] < 500
    assert res.residual[0] < estimators.STALL_TOL
    np.testing.assert_allclose(res.theta[0], target, atol=1e-4)


def test_non_convergence_reported_with_warning():
    log = heave().simulate(5000, seed=0).to_log()
    with pytest.warns(ConvergenceWarning, match="did not converge"):
        res = identify(log, method="iv-zero-mean", max_iter=2)
    assert not res.converged
    assert res.stop_reason == "maximum iterations reached"
    assert np.all(np.isfinite(res.params))
    assert res.diagnostics["fixed_point_step_se"] > 0
    assert res.to_dict()["converged"] is False


# ---------------------------------------------------------------- bad structure
def test_rank_deficiency_names_collinear_terms():
    spec = ModelSpec("heave_abs", ["w"], ["tau"], {"w": ["w", "|w|", "tau"]})
    df = noise_free_heave().simulate(1000, seed=0).to_frame()
    assert (df["w"] > 0).all()
    with pytest.raises(RankDeficientError, match=r"equation 'w': w, \|w\|"):
        identify(TrialLog(df), spec, method="ls")


def test_unexcited_input_is_named():
    spec = ModelSpec("m", ["w"], ["tau", "idle"], {"w": ["w", "w*|w|", "tau", "idle"]})
    df = noise_free_heave().simulate(1000, seed=0).to_frame().assign(idle=0.0)
    with pytest.raises(RankDeficientError, match="idle"):
        identify(TrialLog(df), spec, method="iv")


def test_weak_instruments_warn_with_condition_number():
    log = heave().simulate(3000, seed=0).to_log()
    spec = log.spec.with_aggregate(None)
    from vesselid.identify import kernels
    from vesselid.identify.data import from_log

    data, _ = from_log(log, spec)
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    z = np.nan_to_num(phi.copy())
    rng = np.random.default_rng(0)
    z[:, 1] = z[:, 0] * (1 + 1e-9 * rng.standard_normal(z.shape[0]))
    with pytest.warns(WeakInstrumentWarning, match="cond"):
        identify(log, spec, method="iv", instruments=z)


# --------------------------------------------------------------------- bad logs
def test_bad_logs():
    df = heave().simulate(500, seed=0).to_frame()
    spec = heave().identification_spec()
    with pytest.raises(LogValidationError, match="'tau'"):
        identify(TrialLog(df.drop(columns="tau")), spec)
    bad = df.copy()
    bad.loc[17, "w"] = np.nan
    with pytest.raises(LogValidationError, match=r"'w'.*row 17"):
        identify(TrialLog(bad), spec)
    bad = df.copy()
    bad.loc[3, "tau"] = np.inf
    with pytest.raises(LogValidationError, match="'tau'"):
        identify(TrialLog(bad), spec)
    with pytest.raises(IdentificationError, match="experiment 0 has 4 samples"):
        identify(TrialLog(df.head(4)), spec)
    with pytest.raises(IdentificationError, match="unknown method"):
        identify(TrialLog(df), spec, method="ml")
    with pytest.raises(LogValidationError, match="w_c"):
        identify(TrialLog(df), spec.with_aggregate({"w": "w - w_c"}))


# ---------------------------------------------------------------- results object
def test_results_object():
    log = heave(current_mean=0.1, current_sensor=True).simulate(5000, seed=1).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExperimentDesignWarning)
        res = identify(log, method="iv-zero-mean")
    assert res.params.index.names == ["equation", "term"]
    assert res.params.loc[("w", "w*|w|")] == res.params.iloc[1]
    ci = res.conf_int(0.9)
    assert (ci["lower"] < res.params).all() and (res.params < ci["upper"]).all()
    cmp = res.compare()
    np.testing.assert_allclose(cmp["normalized_error"],
                               (res.params - [0.99, -0.1, 1.0]) / [0.99, -0.1, 1.0])
    text = res.summary()
    assert "w*|w|" in text and "zero-mean" in text and "w - w_c" in text
    payload = json.loads(res.to_json())
    assert set(payload) >= {"method", "params", "stderr", "converged", "iterations",
                            "experiments", "samples", "diagnostics"}
    assert payload["params"]["w"]["tau"] == pytest.approx(res.params.loc[("w", "tau")])
    assert res.residuals.shape == (5000, 1) and np.isnan(res.residuals.iloc[0, 0])
    assert res.history is not None and len(res.history) == res.iterations


def test_design_check_warns_on_sign_changes_and_passes_static_offset():
    log = heave().simulate(5000, seed=0).to_log()  # Gaussian noise: w crosses zero
    res = identify(log, method="ls")
    assert not res.diagnostics["design"]["ok"].all()
    smooth = res.diagnostics["smoothness"]["w"]  # ... but too rarely to bias the estimate
    assert smooth["share_within_eta"] > 0.01 and not smooth["matters"]
    siso = System(
        spec=ModelSpec("s", ["x"], ["u"], {"x": ["x", "x*|x|", "u"]},
                       theta0={"x": [0.5, -0.1, 1.0]}),
        inputs={"u": StaticOffset(1.0, Uniform(0, 0.3))},
        sensor_noise={"x": Uniform(0, 0.05)},
        x0={"x": 1.5},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExperimentDesignWarning)
        res = identify(siso.simulate(3000, seed=0).to_log(), method="iv-zero-mean",
                       eta={"x": 0.05})
    assert res.diagnostics["design"]["ok"].all()
    assert res.diagnostics["design"]["sign_changes"].sum() == 0


def test_direct_aggregated_measurement_exact():
    """A speed log measuring w_r = w_a − w_c directly (Remark 4.3) gives exact recovery on
    noise-free data with a current, where the plain predictor is biased."""
    system = heave(variance=0.0, xi_mean=0.0)
    system = System(**{**system.__dict__, "current": {"w": Uniform(0.1, 0.05)}})
    df = system.simulate(3000, seed=0).to_frame()
    df["w_log"] = df["true_w"] - df["true_current_w"]
    spec = system.spec.with_aggregate({"w": "w_log"})
    for method in METHODS:
        res = identify(TrialLog(df), spec, method=method)
        np.testing.assert_allclose(res.params.to_numpy(), [0.99, -0.1, 1.0], atol=1e-8)
    biased = identify(TrialLog(df), spec.with_aggregate(None), method="ls")
    assert np.max(np.abs(biased.params.to_numpy() - [0.99, -0.1, 1.0])) > 1e-3


def test_lagged_iv_start_when_ls_model_diverges(monkeypatch):
    """If the LS auxiliary model diverges, the iteration starts from basic IV with
    delayed measurements as instruments and says so."""
    log = heave().simulate(5000, seed=0).to_log()
    real = estimators.refined_iv
    calls = []

    def flaky(data, spec, start, **kw):
        res = real(data, spec, start, **kw)
        if not calls:  # pretend the LS start diverged
            res.reason[:] = estimators.STOP_START_DIVERGED
            res.theta[:] = np.nan
        calls.append(start.copy())
        return res

    monkeypatch.setattr(estimators, "refined_iv", flaky)
    res = identify(log, method="iv-zero-mean")
    assert res.diagnostics["start"] == "lagged-iv"
    assert len(calls) == 2 and not np.allclose(calls[0], calls[1])
    assert res.converged and np.all(np.isfinite(res.params))


def test_segment_abs_max_equals_the_per_segment_loop():
    """The vectorised divergence-limit scale equals ``max |x[a:b]|`` per segment exactly,
    with empty segments (0) and NaN (propagated) included."""
    from vesselid.identify.data import segment_abs_max

    rng = np.random.default_rng(0)
    for _ in range(200):
        n, t = int(rng.integers(1, 4)), int(rng.integers(0, 40))
        x = rng.normal(size=(t, n)) * 10
        if t and rng.random() < 0.3:
            x[rng.integers(t), rng.integers(n)] = np.nan
        starts = np.concatenate([[0], np.sort(rng.integers(0, t + 1, rng.integers(0, 5))), [t]])
        ref = np.array([np.max(np.abs(x[starts[s]:starts[s + 1]]), initial=0.0)
                        for s in range(starts.size - 1)])
        np.testing.assert_array_equal(segment_abs_max(x, starts), ref)


def test_pin_blas_to_one_thread_holds_for_the_process():
    """A worker's setting: after a first fit has loaded every BLAS library, one BLAS
    thread, kept after further fits (whose own one-thread setting restores the pinned
    one). In a process of its own: the setting is for the rest of the process."""
    import subprocess
    import sys

    code = """
import warnings
warnings.simplefilter("ignore")
from threadpoolctl import threadpool_info
from vesselid.identify import identify, linalg
from vesselid.plant.systems import heave
def blas():
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
log = heave().simulate(500, seed=1).to_log()
identify(log)
linalg.pin_blas_to_one_thread()
pinned = blas()
identify(log)
print(pinned, blas())
assert pinned and set(pinned) == {1} and set(blas()) == {1}
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=False)
    assert out.returncode == 0, out.stderr[-2000:]


def test_fit_restores_blas_threads():
    """``fit`` runs the BLAS on one thread and restores the caller's setting."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from vesselid.identify import identify, linalg
    from vesselid.plant.systems import heave

    def blas_threads() -> list[int]:
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    assert linalg._blas_controller() is not None  # numpy's OpenBLAS at the least
    with threadpool_limits(limits=2, user_api="blas"):
        seen = []
        linalg.one_blas_thread(lambda: seen.append(blas_threads()))()
        assert seen and all(n == 1 for n in seen[0])
        assert all(n == 2 for n in blas_threads())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            identify(heave().simulate(500, seed=1).to_log())
        assert all(n == 2 for n in blas_threads())
