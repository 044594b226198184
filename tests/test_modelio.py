"""Identified models out: python-control systems and exported spec files."""

from __future__ import annotations

import dataclasses
import warnings

import control as ct
import numpy as np
import pytest

from vesselid.identify import identify
from vesselid.model.export import export_model, load_model, to_control
from vesselid.model.spec import ModelSpec
from vesselid.plant.catalogue import get_system
from vesselid.plant.simulate import simulate_states


@pytest.fixture(scope="module")
def result():
    """An identification result whose parameters are θ0 (a stable model to simulate)."""
    log = get_system("cybership2").simulate(3000, n_runs=2, seed=11).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="ls")
    return dataclasses.replace(res, params=res.spec.theta0_series().rename("estimate"))


def test_to_control_matches_vesselid_simulation(result):
    spec = result.spec
    sys = result.to_control()
    assert sys.isdtime(strict=True) and sys.dt == spec.dt
    assert list(sys.state_labels) == list(spec.states)
    assert list(sys.input_labels) == list(spec.inputs)
    rng = np.random.default_rng(0)
    n = 400
    u = np.column_stack([1.5 + 0.3 * rng.standard_normal(n), 0.1 * rng.standard_normal(n),
                         0.2 * rng.standard_normal(n)])
    x0 = np.array([0.6, 0.01, 0.02])
    theta = result.params.to_numpy()
    ours = simulate_states(spec, u, theta=theta, x0=x0)
    resp = ct.input_output_response(sys, np.arange(n) * spec.dt, u.T, x0)
    np.testing.assert_allclose(resp.states.T, ours, rtol=0, atol=1e-12)


def test_to_control_with_aggregate_sensor_input():
    spec = ModelSpec("heave", ["w"], ["tau"], {"w": ["w", "w*|w|", "tau"]},
                     theta0={"w": [0.9, -0.1, 1.0]}, aggregate={"w": "w - w_c"}, dt=1.0)
    sys = to_control(spec)
    assert list(sys.input_labels) == ["tau", "w_c"]
    rng = np.random.default_rng(1)
    n = 200
    tau = rng.standard_normal((n, 1))
    wc = 0.1 * rng.standard_normal((n, 1))
    ours = simulate_states(spec, tau, x0=np.array([0.2]), v=-wc)
    resp = ct.input_output_response(sys, np.arange(n) * 1.0, np.hstack([tau, wc]).T, [0.2])
    np.testing.assert_allclose(resp.states.T, ours, rtol=0, atol=1e-12)


def test_export_round_trip(result, tmp_path):
    path = result.export(tmp_path / "model.toml")
    spec = ModelSpec.load(path)  # a plain spec whose θ0 is θ̂
    np.testing.assert_array_equal(spec.theta0_vector(), result.params.to_numpy())
    spec2, theta, cov = load_model(path)
    assert spec2 == spec
    np.testing.assert_array_equal(cov, result.cov.to_numpy())
    np.testing.assert_array_equal(theta, result.params.to_numpy())
    sys = to_control(spec)
    lin = ct.linearize(sys, [0.6, 0.0, 0.0], [1.5, 0.0, 0.0])
    assert lin.dt == spec.dt and lin.A.shape == (3, 3)


def test_export_refuses_non_finite(result, tmp_path):
    import copy

    bad = copy.copy(result)
    bad.params = result.params * np.nan
    with pytest.raises(ValueError, match="non-finite"):
        export_model(bad, tmp_path / "m.toml")
    assert not (tmp_path / "m.toml").exists()
