"""Tests of the model-based controller (vesselid.control)."""

from __future__ import annotations

import numpy as np
import pytest

from vesselid.control import ControlError, FeedbackLinearizingController, run_control_experiment
from vesselid.seatrial import seatrial_spec


def test_controller_tracks_with_theta0():
    spec = seatrial_spec()
    exp = run_control_experiment({"θ0": spec.theta0_vector()}, steps=1200, seed=0)
    row = exp.table.loc["θ0"]
    assert not row["diverged"]
    # with current 0.05 m/s and wind 1 m/s: steps 0.3→0.45 m/s and 0→45°→−30° included
    assert row["rms_u (m/s)"] < 0.05
    assert row["rms_psi (deg)"] < 15.0
    tr = exp.traces["θ0"]
    last = tr[(tr["t"] > 70.0) & (tr["t"] < 80.0)]  # settled on 45° before the next step
    assert np.all(np.abs(np.degrees(last["psi"].to_numpy()) - 45.0) < 3.0)


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
