"""The adaptive feedback-linearising controller (recursive IV inside the loop)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from _closed_loop import QUIET, quiet_env

from vesselid.control.controllers import AdaptiveFeedbackLinearizingController, ControlError
from vesselid.errors import IdentificationError
from vesselid.studies.seatrial import seatrial_spec


def test_adapted_gains_equal_the_changed_plant_without_noise() -> None:
    """θ0 of the full structure is the plant; with the actuators at 60 % and no noise the
    surge and yaw equation errors are exactly ``0.6 θ X`` and ``0.6 θ N``: the recursive IV
    inside the loop recovers the changed gains (to the float32 rounding of the actions)."""
    import gymnasium as gym

    import vesselid.envs  # noqa: F401

    spec = seatrial_spec(structure="full")
    ctrl = AdaptiveFeedbackLinearizingController(spec, spec.theta0_vector(), warmup=50)
    env = gym.make("vesselid/Manoeuvring3DOF-v0", max_episode_steps=600, vessel=spec.name,
                   dt=ctrl.dt, force_max=tuple(ctrl.fmax), current_direction=0.0,
                   wind_direction=0.0, **QUIET, **quiet_env())
    _, info = env.reset(seed=0, options={"nu": [0.3, 0.0, 0.0], "eta": [0.0, 0.0, 0.0]})
    for k in range(500):
        a = ctrl(info, k * ctrl.dt)
        _, _, term, _, info = env.step((0.6 * a).astype(np.float32))
        assert not term
    g0 = ctrl._g0
    np.testing.assert_allclose([ctrl._gain[("u", "X")], ctrl._gain[("r", "N")]],
                               [0.6 * g0[0], 0.6 * g0[1]], rtol=1e-3)
    assert np.all(np.abs(ctrl._bias()) < 1e-5)


def test_bad_options() -> None:
    spec = seatrial_spec()
    with pytest.raises(ControlError, match="gain_bounds"):
        AdaptiveFeedbackLinearizingController(spec, spec.theta0_vector(), gain_bounds=(2, 3))
    with pytest.raises(IdentificationError, match="forgetting"):
        AdaptiveFeedbackLinearizingController(spec, spec.theta0_vector(), forgetting=math.nan)
