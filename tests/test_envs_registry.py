"""Every registered ``vesselid/`` environment follows the Gymnasium API.

Parametrised over the registry, as Gymnasium's own ``tests/envs/test_envs.py``:
``check_env`` without warnings, a seeded determinism rollout, the vector entry point
(shapes, determinism, next-step autoreset), rendering and the recorder contract.
An id whose module does not exist yet is skipped with a reason, and tested as soon as
the module appears.
"""

from __future__ import annotations

import importlib.util
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence

import vesselid  # noqa: F401  (registers the environments)
from vesselid.envs import ENV_IDS, register_envs
from vesselid.envs.recorder import TrialRecorder, VectorTrialRecorder

REGISTERED = sorted(i for i in gym.registry if i.startswith("vesselid/"))


def _require(env_id: str) -> gym.envs.registration.EnvSpec:
    spec = gym.spec(env_id)
    module = str(spec.entry_point).split(":")[0]
    # a registered id whose module is missing is a broken registration: fail, never skip
    assert importlib.util.find_spec(module) is not None, f"{env_id}: module {module} is missing"
    return spec


def test_registry_lists_the_vesselid_envs() -> None:
    assert set(ENV_IDS) <= set(REGISTERED)
    assert {"vesselid/Heave-v0", "vesselid/Manoeuvring3DOF-v0"} <= set(REGISTERED)
    for env_id in ENV_IDS:
        spec = gym.spec(env_id)
        assert spec.max_episode_steps and spec.max_episode_steps > 0
        assert isinstance(spec.entry_point, str) and isinstance(spec.vector_entry_point, str)


def test_register_envs_is_idempotent() -> None:
    before = {i: gym.spec(i) for i in ENV_IDS}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        register_envs()
        register_envs()
    assert all(gym.spec(i) is before[i] for i in ENV_IDS)


@pytest.mark.parametrize("env_id", REGISTERED)
def test_check_env(env_id: str) -> None:
    _require(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(env_id)
        check_env(env.unwrapped)
        env.close()


@pytest.mark.parametrize("env_id", REGISTERED)
def test_seeded_rollout_is_deterministic(env_id: str) -> None:
    _require(env_id)
    env_1, env_2 = gym.make(env_id), gym.make(env_id)
    obs_1, info_1 = env_1.reset(seed=42)
    obs_2, info_2 = env_2.reset(seed=42)
    assert data_equivalence(obs_1, obs_2, exact=True)
    assert data_equivalence(info_1, info_2, exact=True)
    keys = set(info_1)
    env_1.action_space.seed(42)
    for _ in range(200):
        action = env_1.action_space.sample()
        out_1 = env_1.step(action)
        out_2 = env_2.step(action)
        for a, b in zip(out_1, out_2, strict=True):
            assert data_equivalence(a, b, exact=True)
        assert env_1.observation_space.contains(out_1[0])
        assert set(out_1[4]) == keys, "info must have the same keys in reset and step"
        if out_1[2] or out_1[3]:
            obs_1, _ = env_1.reset(seed=7)
            obs_2, _ = env_2.reset(seed=7)
            assert data_equivalence(obs_1, obs_2, exact=True)
    env_1.close()
    env_2.close()


@pytest.mark.parametrize("env_id", REGISTERED)
def test_make_vec_vector_entry_point(env_id: str) -> None:
    _require(env_id)
    n, horizon = 4, 3

    def make() -> gym.vector.VectorEnv:
        return gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point",
                            max_episode_steps=horizon)

    envs_1, envs_2 = make(), make()
    assert not isinstance(envs_1.unwrapped, (gym.vector.SyncVectorEnv, gym.vector.AsyncVectorEnv))
    assert envs_1.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    obs_1, info_1 = envs_1.reset(seed=3)
    obs_2, info_2 = envs_2.reset(seed=3)
    assert obs_1.shape == (n, *envs_1.single_observation_space.shape)
    assert envs_1.observation_space.contains(obs_1)
    assert data_equivalence(obs_1, obs_2, exact=True)
    assert data_equivalence(info_1, info_2, exact=True)
    envs_1.action_space.seed(3)
    for t in range(2 * horizon + 2):
        actions = envs_1.action_space.sample()
        obs_1, rew_1, term_1, trunc_1, info_1 = envs_1.step(actions)
        obs_2, rew_2, term_2, trunc_2, info_2 = envs_2.step(actions)
        for a, b in ((obs_1, obs_2), (rew_1, rew_2), (term_1, term_2), (trunc_1, trunc_2),
                     (info_1, info_2)):
            assert data_equivalence(a, b, exact=True)
        assert obs_1.shape == (n, *envs_1.single_observation_space.shape)
        assert obs_1.dtype == envs_1.single_observation_space.dtype
        assert rew_1.shape == term_1.shape == trunc_1.shape == (n,)
        assert term_1.dtype == trunc_1.dtype == np.bool_
        assert not term_1.any()
        # next-step autoreset: truncated at steps 3 and 7, reset (reward 0) at steps 4 and 8
        step = t + 1
        assert trunc_1.all() == (step % (horizon + 1) == horizon)
        if step % (horizon + 1) == 0:
            assert np.all(rew_1 == 0) and not trunc_1.any()
    envs_1.close()
    envs_2.close()


@pytest.mark.parametrize("env_id", REGISTERED)
def test_render_rgb_array(env_id: str) -> None:
    _require(env_id)
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(5):
        env.step(env.action_space.sample())
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.dtype == np.uint8
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.shape[0] > 50
    env.close()


@pytest.mark.parametrize("env_id", REGISTERED)
def test_recorder_contract(env_id: str) -> None:
    _require(env_id)
    env = TrialRecorder(gym.make(env_id))
    spec = env.unwrapped.model_spec
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(20):
        env.step(env.action_space.sample())
    log = env.to_log()
    log.validate(spec)
    assert len(log) == 20
    assert list(log.data.columns[:2]) == ["experiment", "time"]
    assert log.metadata["env_id"] == env_id
    assert log.spec == spec

    envs = VectorTrialRecorder(gym.make_vec(env_id, num_envs=3,
                                            vectorization_mode="vector_entry_point"))
    envs.reset(seed=0)
    for _ in range(10):
        envs.step(envs.action_space.sample())
    vlog = envs.to_log()
    vlog.validate(spec)
    assert len(vlog) == 30 and vlog.experiment_ids == [0, 1, 2]
    assert list(vlog.data.columns) == list(log.data.columns)
