"""Simulation of (1a)-(1b): hand-computed steps, batching, determinism, divergence."""

import numpy as np
import pytest
from _stats import assert_mean_within, assert_std_within

from vesselid.errors import SimulationDivergedError
from vesselid.model.spec import ModelSpec
from vesselid.plant.catalogue import get_system
from vesselid.plant.simulate import simulate_states, step_states
from vesselid.plant.systems import heave, siso_example

SPEC = ModelSpec(name="heave", states=["w"], inputs=["tau"],
                 equations={"w": ["w", "w*|w|", "tau"]}, theta0={"w": [0.99, -0.1, 1.0]})


def test_three_steps_by_hand():
    """x(k+1) = a (x+v) + n (x+v)|x+v| + f u + w, computed by hand."""
    u = np.array([[0.2], [0.3], [-0.1], [0.0]])
    v = np.array([[0.1], [-0.2], [0.05], [0.0]])
    w = np.array([[0.01], [0.0], [-0.02], [0.0]])
    x = simulate_states(SPEC, u, x0=[1.0], v=v, w=w)
    # k=0: r=1.1   -> 0.99*1.1 - 0.1*1.21 + 0.2 + 0.01 = 1.178
    # k=1: r=0.978 -> 0.99*0.978 - 0.1*0.978*0.978 + 0.3 + 0 = 1.17257...
    r0 = 1.1
    x1 = 0.99 * r0 - 0.1 * r0 * abs(r0) + 0.2 + 0.01
    r1 = x1 - 0.2
    x2 = 0.99 * r1 - 0.1 * r1 * abs(r1) + 0.3
    r2 = x2 + 0.05
    x3 = 0.99 * r2 - 0.1 * r2 * abs(r2) - 0.1 - 0.02
    assert x1 == pytest.approx(1.178)
    np.testing.assert_allclose(x[:, 0], [1.0, x1, x2, x3], rtol=0, atol=1e-15)


def test_negative_state_uses_modulus():
    x = simulate_states(SPEC, np.zeros((2, 1)), x0=[-2.0])
    assert x[1, 0] == pytest.approx(0.99 * -2.0 - 0.1 * -2.0 * 2.0)


def test_batch_equals_single_runs():
    rng = np.random.default_rng(1)
    u = rng.uniform(0.1, 0.3, (4, 50, 1))
    v = rng.normal(0, 0.1, (4, 50, 1))
    batch = simulate_states(SPEC, u, x0=[1.0], v=v)
    for r in range(4):
        np.testing.assert_array_equal(batch[r], simulate_states(SPEC, u[r], x0=[1.0], v=v[r]))


def test_per_run_theta():
    u = np.full((2, 5, 1), 0.2)
    th = np.array([[0.99, -0.1, 1.0], [0.5, 0.0, 2.0]])
    x = simulate_states(SPEC, u, theta=th, x0=[0.0])
    assert x[1, 1, 0] == pytest.approx(0.4)
    assert x[0, 1, 0] == pytest.approx(0.2)


def test_step_states_matches_simulation():
    u = np.random.default_rng(2).uniform(0, 0.3, (20, 1))
    x = simulate_states(SPEC, u, x0=[1.0])
    out = np.empty((1, 1))
    xk = np.array([[1.0]])
    for k in range(19):
        step_states(SPEC.codes.factors, SPEC.codes.equation, SPEC.theta0_vector(), xk,
                    np.zeros((1, 1)), u[k : k + 1], np.zeros((1, 1)), out)
        xk = out.copy()
        assert xk[0, 0] == x[k + 1, 0]


def test_divergence_is_reported_not_returned():
    unstable = SPEC.with_theta0(np.array([1.0, 0.5, 1.0]))
    with pytest.raises(SimulationDivergedError, match="diverged in 1 of 1 run"):
        simulate_states(unstable, np.full((500, 1), 1.0), x0=[1.0])
    x = simulate_states(unstable, np.full((500, 1), 1.0), x0=[1.0], raise_on_divergence=False)
    assert np.isnan(x[-1, 0])
    assert isinstance(SimulationDivergedError("x"), ValueError)


def test_same_seed_bit_identical_log():
    a = heave(current_mean=0.1).simulate(2000, n_runs=2, seed=7).to_frame()
    b = heave(current_mean=0.1).simulate(2000, n_runs=2, seed=7).to_frame()
    c = heave(current_mean=0.1).simulate(2000, n_runs=2, seed=8).to_frame()
    assert a.equals(b)
    assert not a.equals(c)


def test_runs_depend_only_on_their_own_seed():
    system = heave()
    seeds = np.random.SeedSequence(3).spawn(4)
    full = system.simulate(300, run_seeds=seeds)
    part = system.simulate(300, run_seeds=seeds[2:])
    np.testing.assert_array_equal(full.y[2:], part.y)


def test_heave_log_columns_and_ground_truth():
    sim = heave(current_mean=0.1, current_sensor=True).simulate(1000, seed=0)
    df = sim.to_frame()
    assert {"experiment", "time", "w", "tau", "w_c", "true_w", "true_current_w",
            "true_process_w"} <= set(df.columns)
    # y1 = w_a + e1; y2 = w_c + e2; current enters as v = -w_c
    e1 = df["w"] - df["true_w"]
    assert_std_within(e1, 0.1)  # white sensor noise, σ = 0.1 (tolerance from its SE)
    assert_mean_within(df["true_current_w"], 0.1)
    w_a, w_c, xi = df["true_w"].to_numpy(), df["true_current_w"].to_numpy(), \
        df["true_process_w"].to_numpy()
    tau = df["tau"].to_numpy()
    wr = w_a[:-1] - w_c[:-1]
    np.testing.assert_allclose(w_a[1:], 0.99 * wr - 0.1 * wr * np.abs(wr) + tau[:-1] + xi[:-1],
                               atol=1e-12)


def test_siso_example_keeps_margin():
    sim = siso_example(v_mean=0.1).simulate(5000, seed=0)
    assert sim.x.min() > 0.1 + 0.1 + 0.1 + 0.1  # A15 margin of §5
    assert get_system("siso").spec.name == "siso_example"


def test_a_system_is_a_plant_whose_disturbed_paths_draw_as_simulate():
    """``System.run`` is the noise-free simulation; ``System.disturbed_paths`` draws the
    current and process noise as ``simulate`` draws a run, so with a constant input the
    first path is that run's true state, bit for bit; more paths differ."""
    from dataclasses import replace

    from vesselid.plant.catalogue import get_system
    from vesselid.plant.disturbances import GaussMarkov
    from vesselid.plant.plant import Plant
    from vesselid.plant.signals import ConstantInput

    base = get_system("heave", current_mean=0.1)
    system = replace(base, inputs={"tau": ConstantInput(0.2)},
                     process_noise={"w": GaussMarkov(0.0, 0.02, 5.0, 1.0, 0.06)})
    assert isinstance(system, Plant)
    n = 400
    sim = system.simulate(n, run_seeds=[np.random.SeedSequence(11)])
    u = np.full((n, 1), 0.2)
    paths = system.disturbed_paths(u, paths=3, seed=11)
    assert paths.shape == (3, n + 1, 1)
    np.testing.assert_array_equal(paths[0, :n], sim.x[0])
    assert not np.allclose(paths[1], paths[0])
    calm = replace(system, current={}, process_noise={})
    np.testing.assert_array_equal(calm.disturbed_paths(u, paths=1, seed=0)[0], calm.run(u))
    # steady state of w = 0.99 w − 0.1 w|w| + 0.2 (θ0 of the heave vehicle): 0.1 w² + 0.01 w = 0.2
    np.testing.assert_allclose(calm.run(u)[-1], (-0.1 + np.sqrt(0.01 + 8.0)) / 2, rtol=1e-8)
