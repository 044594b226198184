"""Trial planner: covariance algebra, manoeuvre schedules, plan-trial CLI."""

import json
import math

import numpy as np
import pytest

from vesselid.cli import main
from vesselid.plant.vessels import VesselModel, cybership2
from vesselid.studies.manoeuvres import (
    AccelerationStopping,
    ManoeuvreError,
    Programme,
    ThrusterSquare,
    TurningCircle,
    ZigZag,
    manoeuvre_from_dict,
)
from vesselid.studies.planner import (
    Information,
    PlannerError,
    _ar1_meat,
    _fir,
    _stationary_meat,
    plan_trial,
    sriv_prefilter,
)


def _brute(y, r):
    n = y.shape[0]
    out = np.zeros((y.shape[1], y.shape[1]))
    for k in range(n):
        for m in range(n):
            out += np.outer(y[k], y[m]) * r(abs(k - m))
    return out


def test_ar1_and_stationary_meat_match_the_double_sum():
    rng = np.random.default_rng(0)
    y = rng.standard_normal((60, 3))
    np.testing.assert_allclose(_ar1_meat(y, 0.8), _brute(y, lambda t: 0.8**t), rtol=1e-10)
    acov = np.array([2.0, -0.7, 0.3, 0.1])
    want = _brute(y, lambda t: acov[t] if t < acov.size else 0.0)
    np.testing.assert_allclose(_stationary_meat(y, acov), want, rtol=1e-9, atol=1e-9)


def test_sriv_prefilter_moments():
    """The SRIV meat identity Σ_k ζ_f(k) ε_f(k) = Σ_j ε(j) y(j) with y the adjoint
    (reversed) filter of ζ_f, and Yule–Walker of an AR(1) autocovariance gives
    C(q) = 1 − a q⁻¹ exactly (what gmm.ar_coefficients estimates)."""
    rng = np.random.default_rng(2)
    z = rng.standard_normal((50, 3))
    eps = rng.standard_normal((50, 1))
    c = np.array([1.0, 0.6, -0.2, 0.1])
    zf, ef = _fir(z, c), _fir(eps, c)
    assert np.all(zf[:3] == 0)  # rows before the filter order are dropped
    np.testing.assert_allclose(zf.T @ ef, _fir(zf, c, reverse=True).T @ eps, rtol=1e-12)
    a = 0.9
    got = sriv_prefilter(np.array([a ** np.arange(5)]))[0]
    np.testing.assert_allclose(got, [1.0, -a, 0.0, 0.0, 0.0], atol=1e-12)


def test_centring_of_summed_blocks_is_exact():
    rng = np.random.default_rng(1)
    z = rng.standard_normal((80, 2)) + np.array([3.0, -1.0])
    phi = z + 0.1 * rng.standard_normal(z.shape)
    eps = rng.standard_normal(80)

    def info(sl):
        za = np.hstack([z[sl], np.ones((z[sl].shape[0], 1))])
        pa = np.hstack([phi[sl], np.ones((z[sl].shape[0], 1))])
        return Information([za.T @ pa], [za.T @ za], [za.T @ eps[sl]], za.shape[0])

    c = (info(slice(0, 30)) + info(slice(30, 80))).centred()
    zc = z - z.mean(axis=0)
    np.testing.assert_allclose(c.a[0], zc.T @ phi, rtol=1e-10)
    np.testing.assert_allclose(c.s[0], zc.T @ zc, rtol=1e-10)
    np.testing.assert_allclose(c.b[0], zc.T @ eps, rtol=1e-10, atol=1e-12)


def test_zigzag_switches_at_the_heading_and_small_rudder_is_reported():
    v = VesselModel(cybership2.HULL, dt=0.1)
    zz = ZigZag(thrust=2.0, rudder=35.0, heading=20.0)
    f = Programme([zz]).schedule(v, 3000, warmup=300)
    assert f.shape == (3300, 3) and np.all(np.abs(f) <= np.array(v.force_max) + 1e-12)
    x = v.run(f, np.zeros(3))
    psi = v.dt * np.concatenate([[0.0], np.cumsum(x[:-1, 2])])
    switch = np.flatnonzero(np.diff(f[:, 2]) != 0) + 1
    switch = switch[switch > 300]
    base = psi[300]
    assert switch.size >= 3
    np.testing.assert_allclose(np.abs(np.degrees(psi[switch] - base)), 20.0, atol=3.0)
    with pytest.raises(ManoeuvreError, match="does not answer"):
        Programme([ZigZag(thrust=2.0, rudder=10.0, heading=10.0)]).schedule(v, 3000)
    with pytest.raises(ManoeuvreError, match="actuator limits"):
        Programme([AccelerationStopping(thrust=3.0)]).schedule(v, 100)
    tc = TurningCircle(thrust=1.0, side=-1)
    assert manoeuvre_from_dict(tc.to_dict()) == tc
    p = Programme([tc, zz], [100, 200])
    assert Programme.from_dict(json.loads(json.dumps(p.to_dict()))) == p


def test_acceleration_stopping_with_a_floor_keeps_u_positive():
    v = VesselModel(cybership2.HULL, dt=0.1)
    old = AccelerationStopping(thrust=2.0, astern=2.0, repeats=2)
    new = AccelerationStopping(thrust=2.0, astern=2.0, repeats=2, floor=0.05)
    x_old = v.run(Programme([old]).schedule(v, 4000, warmup=300), np.zeros(3))
    x_new = v.run(Programme([new]).schedule(v, 4000, warmup=300), np.zeros(3))
    assert x_old[300:, 0].min() < 0  # the crash stop reverses the surge speed
    u = x_new[300:, 0]
    assert u.min() > 0.02 and u.max() > 4 * u.min()  # between two positive speeds
    assert "floor" not in old.to_dict() and manoeuvre_from_dict(new.to_dict()) == new
    with pytest.raises(ManoeuvreError, match="floor"):
        Programme([AccelerationStopping(floor=-1.0)]).schedule(v, 100)


def test_thruster_square_visits_all_sign_combinations():
    v = VesselModel(cybership2.HULL, dt=0.1)
    m = ThrusterSquare(thrust=1.4, hold_y=10.0, hold_n=7.0)
    f = Programme([m]).schedule(v, 3000, warmup=300)[300:]
    assert f.shape == (3000, 3) and np.all(np.abs(f) <= np.array(v.force_max) + 1e-12)
    combos = {(np.sign(y), np.sign(n)) for y, n in f[:, 1:]}
    assert combos == {(1, 1), (1, -1), (-1, 1), (-1, -1)}
    assert np.count_nonzero(np.diff(np.sign(f[:, 1]))) == 2999 // 100  # every 10 s
    x = v.run(np.vstack([np.tile([1.4, 0, 0], (300, 1)), f]), np.zeros(3))[300:]
    vr = x[:, 1] * x[:, 2]
    assert (vr > 0).mean() > 0.1 and (vr < 0).mean() > 0.1  # both sign relations
    assert manoeuvre_from_dict(m.to_dict()) == m


def test_plan_trial_small_budget_and_cli(capsys):
    plan = plan_trial(8000, 2, block=2000, evaluate_block=1000)
    t = plan.table()
    assert len(plan.programmes) == 2 and np.all(np.isfinite(t["predicted_se"]))
    assert plan.worst_relative_se() > 0
    code = main(["plan-trial", "--samples", "8000", "--experiments", "2", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["experiments"] == 2 and "parameters" in out
    se = [p["predicted_se"] for eq in out["parameters"].values() for p in eq.values()]
    assert all(s is None or math.isfinite(s) for s in se)
    code = main(["plan-trial", "--samples", "10", "--experiments", "2"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    with pytest.raises(PlannerError):
        plan_trial(100, 0)


def test_equation_error_autocovariance_matches_a_simulated_trial():
    """The planner's pooled equation-error autocorrelations (the input of auto's SRIV
    noise model) agree with those of θ0's residuals on a simulated trial of the plan,
    within 4 Bartlett standard errors of the sample autocorrelations."""
    from vesselid.model.regressors import predict
    from vesselid.studies.planner import DisturbanceLevels, design_information
    from vesselid.studies.seatrial import planned_sea_trial_design, simulate_sea_trial

    plan = plan_trial(16000, 2, block=4000, evaluate_block=2000)
    assert plan.estimator == "auto"
    plant = DisturbanceLevels().plant()
    acov = sum(design_information(f, plant, warmup=plan.warmup, acov_only=True).acov
               for f in plan.forces())
    rho_plan = acov[:, 1:] / acov[:, :1]
    log = simulate_sea_trial(2, 8000, seed=3, design=planned_sea_trial_design(plan=plan))
    fr, spec = log.to_frame(), log.spec
    emp = np.zeros_like(acov)
    n = 0
    for _, g in fr.groupby("experiment"):
        x = g[["u", "v", "r"]].to_numpy()
        sig = np.hstack([x, g[["X", "Y", "N"]].to_numpy()])
        eps = x[1:] - predict(spec.codes, spec.theta0_vector(), sig[:-1])
        eps -= eps.mean(axis=0)
        n += eps.shape[0]
        for lag in range(acov.shape[1]):
            emp[:, lag] += (eps[: eps.shape[0] - lag] * eps[lag:]).sum(axis=0)
    rho_emp = emp[:, 1:] / emp[:, :1]
    se = np.sqrt((1 + 2 * np.sum(rho_plan**2, axis=1, keepdims=True)) / n)
    assert np.all(np.abs(rho_emp - rho_plan) < 4 * se), (rho_emp, rho_plan, se)
    assert np.all(rho_plan[:, 0] < -0.3)  # the differenced sensor noise dominates lag 1


def test_modulus_bias_matches_sampled_expectation():
    """E[φ(x+e)] − φ(x) of the modulus regressors near zero (errors in variables at the
    zero crossings) against a sample mean, within 5 sample SE."""
    from vesselid.model.regressors import evaluate
    from vesselid.studies.planner import _modulus_bias

    rng = np.random.default_rng(4)
    # signals [x, y, u]; factor codes s = 0..2, |s| = 3..5, 1 = 6:
    # x*|x|, |x|, x*|y|, x*x, y*u
    layout = np.array([[0, 3], [3, 6], [0, 4], [0, 0], [1, 2]])
    sig = np.array([[0.004, -0.01, 0.3], [-0.002, 0.02, -1.0]])
    std = np.array([0.005, 0.005])
    got = _modulus_bias(layout, sig, std)
    draws = np.stack([evaluate(layout, sig + np.hstack([rng.standard_normal((2, 2)) * std,
                                                         np.zeros((2, 1))]))
                      for _ in range(40000)])
    want = draws.mean(axis=0) - evaluate(layout, sig)
    se = draws.std(axis=0) / np.sqrt(draws.shape[0])
    assert np.all(np.abs(got - want) <= 5 * se + 1e-12)
    assert got[0, 1] > 0.2 * std[0]  # E|x+e| − |x| is of the order of σ near zero
    # the errors-in-variables corrected regressors (y|y| − σ² sign y, y² − σ²; what
    # identify's auto/SRIV evaluate on a sea-trial log): only the bump near zero remains
    got_c = _modulus_bias(layout, sig, std, corrected=True)
    rng = np.random.default_rng(4)
    ys = [sig + np.hstack([rng.standard_normal((2, 2)) * std, np.zeros((2, 1))])
          for _ in range(40000)]
    noisy = np.stack([evaluate(layout, y) for y in ys])
    noisy[:, :, 0] -= std[0] ** 2 * np.sign(np.stack(ys)[:, :, 0])
    noisy[:, :, 3] -= std[0] ** 2
    want_c = noisy.mean(axis=0) - evaluate(layout, sig)
    se_c = noisy.std(axis=0) / np.sqrt(noisy.shape[0])
    assert np.all(np.abs(got_c - want_c) <= 5 * se_c + 1e-12)
    np.testing.assert_array_equal(got_c[:, 1:3], got[:, 1:3])  # |x|, x*|y| unchanged
    big = np.array([[0.05, 0.1, 1.0]])  # |x| = 10 σ: the corrected x|x| is unbiased
    assert abs(_modulus_bias(layout, big, std, corrected=True)[0, 0]) < 1e-12
    assert _modulus_bias(layout, big, std)[0, 0] == pytest.approx(std[0] ** 2)


def test_disturbed_paths_weaken_the_instruments_as_in_a_simulated_trial():
    """The cross moment A = Σ ζ̃ φᵀ of the instruments with the regressors of the disturbed
    vessel: the relative SEs the planner gets from single disturbed paths (a sample of the
    random A) cover those of simulated trials (within 4 sd of log SE over the paths), and
    the effect is real: their mean exceeds the noise-free-path prediction by more than 4
    standard errors of that mean. Without process disturbances the paths are the
    noise-free path (identical information)."""
    from vesselid.model.regressors import evaluate
    from vesselid.plant.simulate import simulate_states
    from vesselid.studies.planner import DisturbanceLevels, design_information
    from vesselid.studies.seatrial import planned_sea_trial_design, simulate_sea_trial

    plan = plan_trial(16000, 2, block=4000, evaluate_block=2000)
    plant = DisturbanceLevels().plant()
    spec = plant.spec
    codes, th = spec.codes, spec.theta0_vector()
    forces = plan.forces()

    def centred(**kw):
        out = None
        for f in forces:
            c = design_information(f, plant, warmup=plan.warmup, **kw).centred()
            out = c if out is None else out + c
        return out

    base = centred()

    def rel_se(a_list):
        out = []
        for i in range(spec.n_states):
            cols = np.flatnonzero(codes.equation == i)
            ai = np.linalg.inv(a_list[i])
            out.append(np.sqrt(np.diag(ai @ base.s[i] @ ai.T)) / np.abs(th[cols]))
        return np.concatenate(out)

    big = np.abs(th) >= 1e-3
    r0 = rel_se(base.a)[big]
    logs = np.log([rel_se(centred(paths=1, seed=s).a)[big] for s in range(8)])
    mean, sd = logs.mean(axis=0), logs.std(axis=0, ddof=1)
    worst = np.argsort(-r0)[:5]
    assert np.all(mean[worst] - np.log(r0[worst]) > 4 * sd[worst] / np.sqrt(logs.shape[0]))
    log = simulate_sea_trial(2, 8000, seed=3, design=planned_sea_trial_design(plan=plan))
    a_data = [0.0] * spec.n_states
    for _, g in log.to_frame().groupby("experiment"):
        tau = g[["X", "Y", "N"]].to_numpy()
        xt = g[["true_u_r", "true_v_r", "true_r"]].to_numpy()
        z = evaluate(codes, np.hstack([simulate_states(spec, tau, x0=xt[0]), tau])[:-1])
        ph = evaluate(codes, np.hstack([xt, tau])[:-1])
        for i in range(spec.n_states):
            cols = np.flatnonzero(codes.equation == i)
            a_data[i] = a_data[i] + (z[:, cols] - z[:, cols].mean(axis=0)).T @ ph[:, cols]
    got = np.log(rel_se(a_data)[big])
    assert np.all(np.abs(got[worst] - mean[worst]) <= 4 * sd[worst]), (got, mean, sd)
    calm = DisturbanceLevels(force_noise_std=(0.0, 0.0, 0.0), gust_std=0.0,
                             wind_direction_std=0.0)
    a = design_information(forces[0], calm.plant(), warmup=plan.warmup)
    b = design_information(forces[0], calm.plant(), warmup=plan.warmup, paths=2)
    assert all(np.allclose(x, y, rtol=1e-12, atol=0) for x, y in zip(a.a, b.a, strict=True))


def test_success_probability_matches_the_normal_model():
    """With a diagonal covariance the sampled probability that every relevant parameter is
    within 10 % equals the product of the normal probabilities (within 4 binomial SE);
    tolerance 0 gives 0, a huge tolerance 1."""
    from dataclasses import replace

    import pandas as pd
    from scipy.stats import norm

    plan = plan_trial(8000, 2, block=2000, evaluate_block=1000)
    t = plan.table()
    rel = t["relevant"].to_numpy()
    th = t["theta0"].abs().to_numpy()
    se = 0.04 * th  # 4 % relative SE, one of them biased
    bias = np.zeros_like(th)
    bias[np.flatnonzero(rel)[0]] = 0.03 * th[np.flatnonzero(rel)[0]]
    pred = replace(plan.prediction,
                   cov=pd.DataFrame(np.diag(se**2), index=plan.prediction.cov.index,
                                    columns=plan.prediction.cov.columns),
                   bias=pd.Series(bias, index=plan.prediction.bias.index))
    diag = replace(plan, prediction=pred)
    want = float(np.prod((norm.cdf((0.1 * th - bias) / se)
                          - norm.cdf((-0.1 * th - bias) / se))[rel]))
    draws = 40000
    got = diag.success_probability(draws=draws)
    assert abs(got - want) <= 4 * math.sqrt(want * (1 - want) / draws), (got, want)
    assert diag.success_probability(tolerance=0.0) == 0.0
    assert diag.success_probability(tolerance=1e6) == 1.0
    assert 0.0 <= plan.success_probability() <= 1.0


def test_the_planner_plans_on_the_default_sea_trial_plant():
    """``DisturbanceLevels()`` is the sea trial's default plant in everything the planner
    models: hull, unmodelled forces, wind, gusts and direction changes, the noise of the
    speed log and gyro and its clipping."""
    import inspect

    from vesselid.plant.vessels import SENSOR_CHANNELS
    from vesselid.studies import seatrial
    from vesselid.studies.planner import DisturbanceLevels

    p = {k: v.default
         for k, v in inspect.signature(seatrial.simulate_sea_trial).parameters.items()}
    dist = seatrial._disturbances(p["current_speed"], p["current_direction"], p["wind_speed"],
                                  p["wind_direction"], p["current_variation"], p["wind_gust"],
                                  p["force_noise"])
    sea = seatrial._plant(p["vessel"], p["dt"], dist, p["sensors"])
    planned = DisturbanceLevels().plant(p["dt"])
    assert planned.hull is sea.hull
    for name in ("wind_speed", "wind_direction", "gust_std", "gust_time_constant",
                 "wind_direction_std", "wind_direction_time_constant", "force_noise_std",
                 "force_noise_time_constant", "wind_on", "wind_model"):
        assert getattr(planned.disturbances, name) == getattr(sea.disturbances, name), name
    assert planned.wind_model == sea.wind_model
    idx = [SENSOR_CHANNELS.index(c) for c in ("u_log", "v_log", "r")]
    np.testing.assert_array_equal(planned.sensors.std_vector()[idx],
                                  sea.sensors.std_vector()[idx])
    assert planned.sensors.clip == sea.sensors.clip
