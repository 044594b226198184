"""The closed-loop study scripts: the bias-variant study's instruments and experiment
subsets are cl-iv's own, its cross-fit and jackknife arithmetic, and the per-run table of
scripts/closed_loop_study.py reproduces its summary."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest
from _scripts import load_script

from vesselid.identify.backend import kernels
from vesselid.identify.closedloop import ClosedLoopIV
from vesselid.identify.data import from_log
from vesselid.identify.loop import closed_loop_signals
from vesselid.plant.closedloop import DESIGNS


@pytest.fixture(scope="module")
def bias_study():
    return load_script("closed_loop_bias_study")


@pytest.fixture(scope="module")
def small_log():
    d = DESIGNS["3dof"](samples=400)
    log = d.simulate(seed=np.random.SeedSequence(5).spawn(2)[0]).to_log(aggregate=False)
    data, spec = from_log(log, d.spec, sensor_noise=False)
    return d, log, data, spec, closed_loop_signals(log, d.spec)


def test_variant_instruments_are_cl_iv_instruments(bias_study, small_log) -> None:
    """Started at the measured first state, the study's instrument simulation is exactly
    the estimator's (so 'theta0' differs from cl-iv only in the auxiliary model)."""
    _, _, data, spec, sig = small_log
    theta = spec.theta0_vector() * 1.01
    z_est, status = ClosedLoopIV().with_signals(sig).instruments(data, spec, theta)
    assert np.all(status == 0)
    z = bias_study.instruments(data, spec, theta, sig)
    np.testing.assert_array_equal(np.where(np.isfinite(z), z, 0.0), z_est)
    # started at the reference the first rows differ
    z_ref = bias_study.instruments(data, spec, theta, sig, "reference")
    first = data.segment(0)
    assert not np.allclose(z_ref[first][1:5], z_est[first][1:5])


def test_subset_of_every_experiment_is_the_data(bias_study, small_log) -> None:
    _, _, data, spec, sig = small_log
    sub, sub_sig = bias_study._subset(data, sig, list(range(data.n_segments)))
    full = ClosedLoopIV().with_signals(sig).estimate_parameters(data, spec).theta[0]
    again = ClosedLoopIV().with_signals(sub_sig).estimate_parameters(sub, spec).theta[0]
    np.testing.assert_array_equal(full, again)
    one, one_sig = bias_study._subset(data, sig, [2])
    np.testing.assert_array_equal(one.target, data.target[data.segment(2)])
    np.testing.assert_array_equal(one_sig.reference, sig.reference[data.segment(2)])
    assert one.starts.tolist() == [0, data.lengths[2]]


def test_one_run_variants(bias_study, small_log) -> None:
    """Every variant gives a finite estimate; the log declares its sensor noise and the
    shipped cl-iv corrects for it; the θ0-instrument step equals the IV step
    computed by hand; the jackknife is K θ̂ − (K − 1) mean of the leave-one-out fits."""
    d, _, data, spec, sig = small_log
    seed = np.random.SeedSequence(5)
    out = bias_study.one_run(d, seed, bias_study.VARIANTS)
    assert set(out) == set(bias_study.VARIANTS)
    assert all(np.all(np.isfinite(v)) for v in out.values())
    assert not np.array_equal(out["cl-iv"], out["uncorrected"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        np.testing.assert_allclose(out["uncorrected"], ClosedLoopIV().with_signals(sig)
                                   .estimate_parameters(data, spec).theta[0], rtol=0,
                                   atol=1e-12)
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    z = bias_study.instruments(data, spec, spec.theta0_vector(), sig)
    np.testing.assert_allclose(out["theta0"], bias_study._iv_step(data, spec, z, phi),
                               rtol=0, atol=1e-12)
    k = data.n_segments
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loo = [ClosedLoopIV().with_signals(s).estimate_parameters(sub, spec).theta[0]
               for sub, s in (bias_study._subset(data, sig, [j for j in range(k) if j != i])
                              for i in range(k))]
    np.testing.assert_allclose(out["jackknife"],
                               k * out["uncorrected"] - (k - 1) * np.mean(loo, axis=0),
                               rtol=0, atol=1e-12)


def test_study_per_run_table_reproduces_summary(tmp_path) -> None:
    study = load_script("closed_loop_study")
    path = tmp_path / "runs.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        table, rates = study.run_design("heave", 3, 11, progress=False, samples=600,
                                        save_runs=path)
    runs = pd.read_csv(path)
    theta0 = runs[runs.estimator == "theta0"].iloc[0, 3:].to_numpy(float)
    for m in ("ls", "iv-zero-mean", "cl-iv"):
        a = runs[runs.estimator == m].iloc[:, 3:].to_numpy(float)
        assert a.shape == (3, theta0.size)
        t = table[table.estimator == m]
        np.testing.assert_allclose(t["bias"].to_numpy(), a.mean(axis=0) - theta0,
                                   rtol=1e-6, atol=1e-12)
    se = runs[runs.estimator == "cl-iv se"].iloc[:, 3:].to_numpy(float)
    se_normal = runs[runs.estimator == "cl-iv se normal"].iloc[:, 3:].to_numpy(float)
    assert np.all(se > 0)
    # the default intervals take the fixed-b critical value (above 1.96), the normal
    # ones are those of the same fits with fixed_b=False
    assert np.all(se >= se_normal) and np.any(se > se_normal)
    c = table[table.estimator == "cl-iv"]
    err = runs[runs.estimator == "cl-iv"].iloc[:, 3:].to_numpy(float) - theta0
    np.testing.assert_allclose(c["coverage_normal_%"].to_numpy(),
                               100 * np.mean(np.abs(err) <= 1.96 * se_normal, axis=0))
    assert rates["runs"] == 3


def test_study_runs_do_not_depend_on_workers(tmp_path) -> None:
    """The same per-run table from one process and from forked workers; a time limit
    that leaves fewer than two finished runs is refused."""
    study = load_script("closed_loop_study")
    tables = []
    for workers in (1, 2):
        path = tmp_path / f"runs_{workers}.csv"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            study.run_design("heave", 4, 12, progress=False, samples=400, save_runs=path,
                             workers=workers)
        tables.append(path.read_bytes())
    assert tables[0] == tables[1]
    with warnings.catch_warnings(), pytest.raises(SystemExit, match="time limit"):
        warnings.simplefilter("ignore")
        study.run_design("heave", 4, 12, progress=False, samples=400, time_limit=1e-9)


@pytest.fixture(scope="module")
def decomposition():
    return load_script("closed_loop_bias_decomposition")


def test_decomposition_is_exact_without_noise(decomposition) -> None:
    """No sensor or process noise: cl-iv and the θ0-instrument IV recover θ0 to rounding
    and the control variate and the bump term vanish; with noise, the run's cl-iv error is
    the estimate identify() returns."""
    import dataclasses

    from vesselid.identify import identify
    from vesselid.plant.vessels.cybership2 import cybership2_system

    d = DESIGNS["3dof"](samples=600)
    quiet = dataclasses.replace(d, system=cybership2_system(
        sensor_noise_std=(0.0, 0.0, 0.0), process_noise_std=(0.0, 0.0, 0.0)))
    out = decomposition.decompose_run(quiet, np.random.SeedSequence(3))
    scale = np.abs(d.spec.theta0_vector()) + 1e-3
    for k in ("cl-iv", "iv0", "cv", "bump"):
        assert np.all(np.abs(out[k]) <= 1e-8 * scale), (k, out[k])
    out = decomposition.decompose_run(d, np.random.SeedSequence(4))
    log = d.simulate(seed=np.random.SeedSequence(4)).to_log(aggregate=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, d.spec, "cl-iv")
    np.testing.assert_allclose(out["cl-iv"], res.params.to_numpy() - d.spec.theta0_vector(),
                               rtol=0, atol=1e-9)


@pytest.mark.slow
def test_control_variate_bias_of_cl_iv(decomposition) -> None:
    """16 logs of the CyberShip II loop (4 x 3000): the control variate has mean zero
    (every parameter within 3.48 of its standard errors: two-sided 1 % over 25), it
    carries most of cl-iv's run-to-run variation (the rest below half the Monte Carlo sd),
    and cl-iv's bias measured with it is, at its upper 3.48-SE bound, below 0.095 Monte
    Carlo sd — the bias a 1000-run study resolves at |z| = 3."""
    d = DESIGNS["3dof"](samples=3000)
    runs = [decomposition.decompose_run(d, ss.spawn(2)[0])
            for ss in np.random.SeedSequence(77).spawn(16)]
    a = {k: np.array([r[k] for r in runs]) for k in runs[0]}
    n = len(runs)
    sd = a["cl-iv"].std(axis=0, ddof=1)
    cv_z = a["cv"].mean(axis=0) / (a["cv"].std(axis=0, ddof=1) / np.sqrt(n))
    assert np.all(np.abs(cv_z) <= 3.48), cv_z
    adj = a["cl-iv"] - a["cv"]
    assert np.all(adj.std(axis=0, ddof=1) <= 0.5 * sd), adj.std(axis=0, ddof=1) / sd
    se = adj.std(axis=0, ddof=1) / np.sqrt(n)
    upper = np.abs(adj.mean(axis=0)) - 3.48 * se
    assert np.all(upper <= 0.095 * sd), upper / sd
