"""Tests of the model-based controller (vesselid.control.controllers)."""

from __future__ import annotations

import numpy as np
import pytest
from _closed_loop import QUIET, closed_loop_residuals, quiet_env

from vesselid.control.controllers import (
    ControlError,
    FeedbackLinearizingController,
    run_control_experiment,
)
from vesselid.studies.seatrial import seatrial_spec


def test_controller_realises_its_closed_loop_with_theta0():
    """θ0 of the full structure is the plant itself: without disturbances and sensor noise
    the feedback-linearised loop is the designed one to round-off (mostly unsaturated)."""
    spec = seatrial_spec(structure="full")
    exp = run_control_experiment({"θ0": spec.theta0_vector()}, spec, steps=1800, seed=0,
                                 env_options=quiet_env(), **QUIET)
    ctrl = FeedbackLinearizingController(spec, spec.theta0_vector())
    tr = exp.traces["θ0"]
    assert not exp.table.loc["θ0", "diverged"] and len(tr) == 1800
    assert (np.abs(tr["X"]) < ctrl.fmax[0]).mean() > 0.5
    assert (np.abs(tr["N"]) < ctrl.fmax[2]).mean() > 0.5
    du, dr, tol = closed_loop_residuals(ctrl, tr)
    assert du <= tol and dr <= tol, (du, dr, tol)
    # a wrong model breaks the identity (the check can fail)
    wrong = spec.theta0_vector() * np.where(spec.param_index.get_level_values("term") == "X",
                                            1.3, 1.0)
    exp2 = run_control_experiment({"wrong": wrong}, spec, steps=300, seed=0,
                                  env_options=quiet_env(), **QUIET)
    du2, _, _ = closed_loop_residuals(FeedbackLinearizingController(spec, wrong),
                                      exp2.traces["wrong"])
    assert du2 > 1e3 * tol


def test_controller_tracks_with_theta0_in_current_and_wind():
    """With current 0.05 m/s and wind 1 m/s (steps 0.3→0.45 m/s, 0→45°→−30°): no
    divergence, and every reference step's error shrinks between the second after the
    step and the last 10 s before the next one."""
    spec = seatrial_spec()
    exp = run_control_experiment({"θ0": spec.theta0_vector()}, steps=1800, seed=0)
    assert not exp.table.loc["θ0", "diverged"]
    tr = exp.traces["θ0"]
    t = tr["t"].to_numpy()
    e_u = np.abs(tr["u_ref"] - tr["u"]).to_numpy()
    e_psi = np.abs(np.angle(np.exp(1j * (tr["psi_ref"] - tr["psi"]).to_numpy())))
    for start, end, err in ((20.0, 80.0, e_psi), (80.0, 140.0, e_psi), (60.0, 120.0, e_u),
                            (120.0, 180.0, e_u)):
        early = err[(t >= start) & (t < start + 1.0)].mean()
        late = err[(t >= end - 10.0) & (t < end)].mean()
        assert late < early, (start, early, late)


def test_controller_action_in_bounds_and_sensors():
    spec = seatrial_spec()
    ctrl = FeedbackLinearizingController(spec, spec.theta0_vector())
    info = {"gnss": [0.1, 0.0], "speed_log": [0.1, 0.0], "gyro": [0.0], "heading": [2.0]}
    a = ctrl(info, 30.0)
    assert a.shape == (3,) and np.all(np.abs(a) <= 1.0) and a[1] == 0.0
    with pytest.raises(ControlError):
        ctrl({"gnss": [0.1, 0.0]})


def test_controller_rejects_bad_theta():
    spec = seatrial_spec()
    with pytest.raises(ControlError):
        FeedbackLinearizingController(spec, np.zeros(3))
    theta = spec.theta0_vector().copy()
    theta[[i for i, (eq, t) in enumerate(spec.param_index) if eq == "u" and str(t) == "X"]] = 0
    with pytest.raises(ControlError):
        FeedbackLinearizingController(spec, theta)
