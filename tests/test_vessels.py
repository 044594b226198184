"""Tests of vesselid.plant.vessels: CyberShip II θ0 mapping, batch simulator and physics sanity."""

from __future__ import annotations

import numpy as np
import pytest

from vesselid.errors import SimulationDivergedError, VesselidError
from vesselid.model.regressors import predict
from vesselid.plant.simulate import simulate_states
from vesselid.plant.vessels import (
    CYBERSHIP2,
    VesselDisturbances,
    VesselSensors,
    blendermann_wind_force,
    cybership2_spec,
    cybership2_system,
    simulate_cybership2,
)

QUIET = VesselSensors.noiseless()


def test_spec_structure() -> None:
    spec = cybership2_spec()
    assert spec.name == "cybership2"
    assert spec.states == ("u", "v", "r") and spec.inputs == ("X", "Y", "N")
    assert [str(t) for t in spec.equations["u"]] == ["u", "u*|u|", "v*r", "r*r", "X"]
    assert len(spec.equations["v"]) == len(spec.equations["r"]) == 10
    assert spec.dt == 0.1
    th = spec.theta0_series()
    m11 = CYBERSHIP2.m - CYBERSHIP2.X_udot
    assert th["u", "u"] == pytest.approx(1 + 0.1 * CYBERSHIP2.X_u / m11, rel=1e-14)
    assert th["u", "X"] == pytest.approx(0.1 / m11, rel=1e-14)


@pytest.mark.parametrize("dt", [0.05, 0.1, 0.2])
def test_theta0_mapping_is_exact(dt: float) -> None:
    """Φᵀθ0 equals ν_r + dt M⁻¹(τ − C(ν_r)ν_r − D(ν_r)ν_r) for random arguments."""
    spec = cybership2_spec(dt)
    rng = np.random.default_rng(1)
    theta = spec.theta0_vector()
    for _ in range(50):
        sig = rng.uniform(-1.0, 1.0, 6) * [1.0, 0.5, 0.5, 2.0, 1.5, 1.0]
        pred = predict(spec.codes, theta, sig)
        ref = sig[:3] + dt * CYBERSHIP2.acceleration(sig[:3], sig[3:])
        np.testing.assert_allclose(pred, ref, rtol=0, atol=1e-12)


def test_zero_coefficients_are_dropped() -> None:
    from dataclasses import replace

    c = replace(CYBERSHIP2, N_vv=0.0, X_udot=0.0, Y_vdot=0.0)  # u*v vanishes from both rows
    spec = cybership2_spec(0.1, c)
    assert "u*v" not in [str(t) for t in spec.equations["r"]]
    assert "u*v" not in [str(t) for t in spec.equations["v"]]


def _inputs(n_runs: int, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tau = np.empty((n_runs, n, 3))
    tau[..., 0] = 1.0 + 0.5 * rng.uniform(-1, 1, (n_runs, n))
    tau[..., 1] = 0.2 * rng.uniform(-1, 1, (n_runs, n))
    tau[..., 2] = 0.1 + 0.1 * rng.uniform(-1, 1, (n_runs, n))
    return tau


def test_noiseless_simulation_matches_simulate_states() -> None:
    tau = _inputs(2, 400)
    sim = simulate_cybership2(tau, seed=0, sensors=QUIET, nu0=[0.2, 0.0, 0.0])
    ref = simulate_states(cybership2_spec(), tau, x0=[0.2, 0.0, 0.0])
    np.testing.assert_allclose(sim.nu, ref, rtol=0, atol=1e-12)


def test_disturbed_simulation_is_the_papers_system() -> None:
    """x(k+1) = Φᵀ([x+v; τ])θ0 + w with v = −ν_c and recorded w, all disturbances on."""
    d = VesselDisturbances(
        current_speed=0.1, current_direction=1.0, current_speed_std=0.02,
        current_direction_std=0.2, wind_speed=1.5, wind_direction=-2.0, gust_std=0.3,
        wind_direction_std=0.1, force_noise_std=(0.02, 0.02, 0.01), cubic_surge=True,
    )
    tau = _inputs(3, 500)
    sim = simulate_cybership2(tau, seed=3, disturbances=d)
    ref = simulate_states(cybership2_spec(), tau, x0=sim.nu[:, 0], v=sim.v, w=sim.w)
    np.testing.assert_allclose(sim.nu, ref, rtol=0, atol=1e-12)
    # sensors: speed log = ν_r + e, GNSS = ν + e, current meter = ν_c + e (bounded noise)
    gnss = sim.sensors[..., 0:2]
    log = sim.sensors[..., 2:4]
    assert np.max(np.abs(gnss - sim.nu[..., :2])) <= 3 * 0.005 + 1e-15
    assert np.max(np.abs(log - sim.nu_r[..., :2])) <= 3 * 0.005 + 1e-15
    assert np.abs(sim.tau_wind).max() > 0


def test_deterministic_and_run_subsets() -> None:
    d = VesselDisturbances(current_speed=0.05, current_speed_std=0.01, wind_speed=1.0,
                               gust_std=0.2)
    tau = _inputs(3, 200)
    a = simulate_cybership2(tau, seed=7, disturbances=d)
    b = simulate_cybership2(tau, seed=7, disturbances=d)
    np.testing.assert_array_equal(a.state, b.state)
    seeds = np.random.SeedSequence(7).spawn(3)
    c = simulate_cybership2(tau[1:2], run_seeds=seeds[1:2], disturbances=d)
    np.testing.assert_array_equal(c.state[0], a.state[1])


def test_trial_log_columns() -> None:
    sim = simulate_cybership2(_inputs(2, 50), seed=0)
    frame = sim.to_frame()
    for col in ("experiment", "time", "u", "v", "r", "X", "Y", "N", "psi", "u_log", "v_log",
                "r_log", "u_c", "v_c", "true_u", "true_u_r", "true_psi"):
        assert col in frame.columns
    assert len(frame) == 100
    log = sim.to_log(aggregate="current_meter")
    log.validate()
    assert log.metadata["spec"]["aggregate"] == {"u": "u - u_c", "v": "v - v_c"}


def test_steady_surge_speed_matches_force_balance() -> None:
    X = 1.5
    tau = np.zeros((3000, 3))
    tau[:, 0] = X
    sim = simulate_cybership2(tau, sensors=QUIET)
    u_ss = CYBERSHIP2.steady_surge_speed(X)
    # the root of X = −X_u u − X_|u|u u|u|
    assert -CYBERSHIP2.X_u * u_ss - CYBERSHIP2.X_uu * u_ss**2 == pytest.approx(X)
    assert sim.nu[0, -1, 0] == pytest.approx(u_ss, rel=1e-6)
    cubic = simulate_cybership2(tau, sensors=QUIET,
                                disturbances=VesselDisturbances(cubic_surge=True))
    assert cubic.nu[0, -1, 0] == pytest.approx(CYBERSHIP2.steady_surge_speed(X, cubic_surge=True),
                                               rel=1e-6)


def test_constant_current_drift_and_energy_decay() -> None:
    d = VesselDisturbances(current_speed=0.1, current_direction=0.7)
    sim = simulate_cybership2(np.zeros((6000, 3)), disturbances=d, sensors=QUIET,
                              nu0=[0.3, 0.1, 0.05], eta0=[0.0, 0.0, 0.3])
    nu_r = sim.nu_r[0]
    assert np.linalg.norm(nu_r[-1]) < 1e-3
    # drifts with the current: earth-frame velocity → V_c (cos β, sin β)
    eta = sim.eta[0]
    vel = (eta[-1, :2] - eta[-1001, :2]) / (1000 * 0.1)
    np.testing.assert_allclose(vel, 0.1 * np.array([np.cos(0.7), np.sin(0.7)]), atol=2e-3)
    # kinetic energy of the relative motion decays monotonically (no thrust, no wind)
    mm = CYBERSHIP2.mass_matrix()
    energy = 0.5 * np.einsum("ki,ij,kj->k", nu_r, mm, nu_r)
    assert energy[-1] < 1e-3 * energy[0]
    assert np.all(np.diff(energy) <= 1e-12)


def test_heading_integrates_yaw_rate() -> None:
    tau = np.zeros((500, 3))
    tau[:, 2] = 0.3
    sim = simulate_cybership2(tau, sensors=QUIET, nu0=[0.2, 0.0, 0.0])
    psi, r = sim.eta[0, :, 2], sim.nu[0, :, 2]
    np.testing.assert_allclose(psi[1:], np.cumsum(r[:-1]) * 0.1, atol=1e-12)
    assert psi[-1] > 1.0


def test_wind_force_direction_and_magnitude() -> None:
    f = blendermann_wind_force(np.array([0.0, -np.pi / 2, np.pi]), 1.5)
    assert f[0, 0] < 0 and f[2, 0] > 0  # head wind pushes aft, following wind forward
    assert f[1, 1] < 0  # wind from starboard (γ = −π/2) pushes to port
    assert np.abs(f).max() < 0.3  # a few % to ~20 % of the 1–2 N thrust range


def test_divergence_and_bad_input() -> None:
    with pytest.raises(SimulationDivergedError):
        simulate_cybership2(np.full((50, 3), 1e9), sensors=QUIET, limit=1e3)
    with pytest.raises(VesselidError):
        simulate_cybership2(np.zeros((10, 2)))


def test_catalogue_system() -> None:
    sysm = cybership2_system()
    sim = sysm.simulate(3000, 2, seed=0)
    x = sim.x[:, 500:]
    assert np.all(x[..., 0] > 0.05)
    # experiment 0 turns to starboard, experiment 1 to port
    assert np.all(x[0, :, 1] < 0) and np.all(x[0, :, 2] > 0)
    assert np.all(x[1, :, 1] > 0) and np.all(x[1, :, 2] < 0)
    # v·r < 0 throughout: the logged structure folds v*|r| into r*|v|
    assert np.all(x[..., 1] * x[..., 2] < 0)
    spec = sysm.identification_spec()
    assert "v*|r|" not in [str(t) for t in spec.equations["v"]]
