"""Invalid actions and step-before-reset raise the same clear errors in every environment."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from vesselid.errors import InvalidActionError

ENVS = ["HeaveEnv", "HeaveVectorEnv", "Manoeuvring3DOFEnv", "Manoeuvring3DOFVectorEnv"]


def _make(name: str):
    import vesselid.envs as envs

    cls = getattr(envs, name)
    return cls(num_envs=2) if name.endswith("VectorEnv") else cls()


@pytest.mark.parametrize("name", ENVS)
def test_invalid_actions_raise(name):
    env = _make(name)
    env.reset(seed=0)
    shape = env.action_space.shape
    for bad, match in [(np.full(shape, np.nan), "finite"), (np.full(shape, -np.inf), "finite"),
                       (np.zeros((shape[0] + 1, *shape[1:])), "shape"),
                       ("abc", "numbers"), (np.full(shape, 1 + 1j), "numbers")]:
        with pytest.raises(InvalidActionError, match=match):
            env.step(bad)
    obs, *_ = env.step(np.zeros(shape, dtype=np.float32))  # still usable afterwards
    assert np.all(np.isfinite(obs))


@pytest.mark.parametrize("name", ENVS)
def test_step_before_reset_raises(name):
    env = _make(name)
    with pytest.raises(gym.error.ResetNeeded):
        env.step(env.action_space.sample())
