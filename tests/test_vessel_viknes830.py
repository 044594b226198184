"""The second vessel (Viknes 830) end to end: catalogue, CLI, environment, controller,
sea trial and identification."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vesselid.cli import main
from vesselid.identify import identify
from vesselid.plant.catalogue import get_system, vessel_module, vessel_names

VESSEL = "viknes830"


def test_registered_and_spec_from_the_published_table() -> None:
    assert VESSEL in vessel_names()
    module = vessel_module(VESSEL)
    p, spec = module.PARAMETERS, module.HULL.spec(0.1)
    th = spec.theta0_series()
    # θ_u[u|u|] = dt X_|u|u / m,  θ_v[u r] = −dt,  θ_r[r] = 1 + dt N_r / I_z
    assert th[("u", "u*|u|")] == pytest.approx(0.1 * p["X_uu"] / p["m"])
    assert th[("v", "u*r")] == pytest.approx(-0.1)
    assert th[("r", "r")] == pytest.approx(1.0 + 0.1 * p["N_r"] / p["I_z"])
    assert [str(t) for t in spec.equations["r"]] == ["r", "N"]


def test_simulate_cli(tmp_path, capsys) -> None:
    out = tmp_path / "v.csv"
    assert main(["simulate", "--system", VESSEL, "--samples", "300", "--seed", "1",
                 "--out", str(out)]) == 0
    assert out.exists() and (tmp_path / "v.toml").exists()


def test_sea_trial_cli(tmp_path, capsys) -> None:
    assert main(["sea-trial", "--vessel", VESSEL, "--experiments", "2", "--samples", "300",
                 "--format", "csv", "--seed", "0", "--out", str(tmp_path)]) == 0
    from vesselid.data.logs import TrialLog

    assert (tmp_path / f"{VESSEL}.toml").exists()
    log = TrialLog.load(tmp_path / "seatrial.csv")
    assert log.metadata["vessel"] == VESSEL and log.spec.name == VESSEL


def test_environment_check_env() -> None:
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    env = gym.make("vesselid/Manoeuvring3DOF-v0", vessel=VESSEL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)
    np.testing.assert_allclose(env.unwrapped._core.force_max,
                               vessel_module(VESSEL).HULL.force_max)
    obs, _ = env.reset(seed=0)
    for _ in range(50):
        obs, _, term, _, info = env.step(np.array([0.5, 0.0, 0.1], dtype=np.float32))
    assert np.all(np.isfinite(obs)) and not term and info["nu"][0] > 0


def test_controller_realises_its_closed_loop() -> None:
    """θ0 is the plant: with no disturbances or sensor noise the feedback-linearised loop
    tracks a 4 m/s, 29° reference exactly as designed (to round-off, unsaturated steps)."""
    from _closed_loop import QUIET, closed_loop_residuals, quiet_env

    from vesselid.control.controllers import FeedbackLinearizingController, run_control_experiment
    from vesselid.studies.seatrial import seatrial_spec

    spec = seatrial_spec(vessel=VESSEL, structure="full")
    ref = lambda t: (4.0, 0.5 if t > 20 else 0.0)  # noqa: E731
    res = run_control_experiment({"θ0": spec.theta0_vector()}, spec, steps=1200, reference=ref,
                                 initial_speed=4.0, env_options=quiet_env(), **QUIET)
    assert not res.table.loc["θ0", "diverged"]
    ctrl = FeedbackLinearizingController(spec, spec.theta0_vector(), reference=ref)
    du, dr, tol = closed_loop_residuals(ctrl, res.traces["θ0"])
    assert du <= tol and dr <= tol, (du, dr, tol)


def test_identify_within_standard_errors() -> None:
    """IV with zero-mean instruments lands within 4 SE of θ0 on every parameter (the
    SE come from the same fit); LS is biased by the noisy regressors (some |z| > 4)."""
    system = get_system(VESSEL)
    log = system.simulate(20000, n_runs=2, seed=1).to_log()
    theta0 = system.spec.theta0_vector()
    z = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for method in ("ls", "iv-zero-mean"):
            res = identify(log, method=method)
            z[method] = (res.params.to_numpy() - theta0) / res.std_errors.to_numpy()
    assert np.all(np.abs(z["iv-zero-mean"]) < 4.0), z["iv-zero-mean"]
    assert np.any(np.abs(z["ls"]) > 4.0), z["ls"]
