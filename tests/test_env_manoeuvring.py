"""Tests of the CyberShip II manoeuvring environments (single and vector)."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from vesselid.envs import register_envs
from vesselid.envs.manoeuvring import Manoeuvring3DOFEnv, Manoeuvring3DOFVectorEnv
from vesselid.plant.catalogue import get_hull
from vesselid.plant.simulate import simulate_states
from vesselid.plant.vessels import VesselSensors, cybership2_spec

ENV_ID = "vesselid/Manoeuvring3DOF-v0"
CALM = {"current_speed": 0.0, "current_variation": 0.0, "wind_speed": 0.0, "wind_gust": 0.0,
        "sensors": VesselSensors.noiseless()}


@pytest.fixture(scope="module", autouse=True)
def _registered() -> None:
    register_envs()


def _actions(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = np.empty((n, 3), dtype=np.float32)
    a[:, 0] = rng.uniform(0.2, 1.0, n)
    a[:, 1:] = rng.uniform(-0.5, 0.5, (n, 2))
    return a


def _rollout(env: Manoeuvring3DOFEnv, actions: np.ndarray, **reset) -> dict[str, np.ndarray]:
    _, info = env.reset(**reset)
    infos = [info]
    for a in actions:
        infos.append(env.step(a)[4])
    return {k: np.stack([i[k] for i in infos]) for k in infos[0]}


def test_check_env_passes_without_warnings() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make(ENV_ID).unwrapped
        check_env(env)
        env.close()


def test_calm_env_matches_simulate_states() -> None:
    env = Manoeuvring3DOFEnv(**CALM)
    acts = _actions(300)
    nu0 = [0.2, 0.01, 0.0]
    rec = _rollout(env, acts, seed=0, options={"nu": nu0})
    ref = simulate_states(cybership2_spec(), rec["tau"][1:], x0=nu0)
    np.testing.assert_allclose(rec["nu"][:-1], ref, rtol=0, atol=1e-12)
    fmax = np.array(get_hull("cybership2").force_max)
    np.testing.assert_allclose(rec["tau"][1:], np.clip(acts, -1, 1) * fmax)


def test_current_enters_as_papers_v_and_w() -> None:
    env = Manoeuvring3DOFEnv(**{**CALM, "current_speed": 0.1, "current_variation": 0.01,
                                "current_time_constant": 5.0})
    rec = _rollout(env, _actions(300), seed=1)
    v = -rec["current"]
    w = np.zeros_like(v)
    w[:-1] = rec["current"][1:]  # w(k) = ν_c(k+1)
    tau = np.zeros_like(v)
    tau[:-1] = rec["tau"][1:]
    ref = simulate_states(cybership2_spec(), tau, x0=rec["nu"][0], v=v, w=w)
    np.testing.assert_allclose(rec["nu"], ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rec["nu_r"], rec["nu"] - rec["current"], atol=1e-15)
    assert np.ptp(rec["current"][:, 0]) > 1e-3


def test_seeded_rollout_is_deterministic_and_info_keys_stable() -> None:
    env = Manoeuvring3DOFEnv(force_noise=0.01)
    acts = _actions(1500)  # crosses a noise block boundary
    a = _rollout(env, acts, seed=5)
    b = _rollout(env, acts, seed=5)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    obs, info = env.reset(seed=5)
    obs2, _, _, _, info2 = env.step(acts[0])
    assert set(info) == set(info2)
    assert {"nu", "nu_r", "eta", "current", "wind", "wind_force", "tau", "gnss", "speed_log",
            "current_meter", "anemometer", "gyro", "heading"} <= set(info)
    assert env.observation_space.contains(obs) and env.observation_space.contains(obs2)


def test_sensor_selection_and_reward() -> None:
    env = Manoeuvring3DOFEnv(sensors={"gnss": 0.01, "speed_log": None, "current_meter": None,
                                      "anemometer": None, "gyro": 0.0, "heading": 0.0})
    obs, info = env.reset(seed=0, options={"nu": [0.3, 0.0, 0.0], "eta": [0.0, 0.0, 0.0]})
    assert obs.shape == (4,) and "speed_log" not in info
    _, reward, term, trunc, info = env.step(np.zeros(3, dtype=np.float32))
    assert not term and not trunc
    expected = -(10.0 * (info["nu"][0] - 0.3) ** 2 + 1.0 * info["eta"][2] ** 2)
    assert reward == pytest.approx(expected)
    row = env.log_row(info)
    assert {"u", "v", "r", "psi", "true_u", "true_u_r"} <= set(row) and "u_log" not in row


def test_render_rgb_array() -> None:
    env = Manoeuvring3DOFEnv(render_mode="rgb_array")
    env.reset(seed=0)
    for a in _actions(20):
        env.step(a)
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    env.close()


def test_render_human_headless() -> None:
    env = Manoeuvring3DOFEnv(render_mode="human")
    env.reset(seed=0)
    env.step(np.zeros(3, dtype=np.float32))
    assert env.render() is None  # human mode draws (headless: Agg) and returns nothing
    env.close()


def test_vector_env_shapes_determinism_and_autoreset() -> None:
    n = 8
    envs = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point",
                        max_episode_steps=5)
    assert isinstance(envs.unwrapped, Manoeuvring3DOFVectorEnv)
    acts = np.tile(_actions(1)[0], (n, 1))

    def run(seed: int) -> list:
        out = [envs.reset(seed=seed)]
        out += [envs.step(acts) for _ in range(7)]
        return out

    a, b = run(3), run(3)
    obs, info = a[0]
    assert obs.shape == (n, 10) and obs.dtype == np.float32
    assert info["nu"].shape == (n, 3)
    for x, y in zip(a, b, strict=True):
        for u, v in zip(x, y, strict=True):
            if isinstance(u, dict):
                for k in u:
                    np.testing.assert_array_equal(u[k], v[k])
            else:
                np.testing.assert_array_equal(u, v)
    # truncation after 5 steps, next-step autoreset on step 6
    _, _, term5, trunc5, _ = a[5]
    assert trunc5.all() and not term5.any()
    _, rew6, _, trunc6, info6 = a[6]
    assert not trunc6.any() and np.all(rew6 == 0.0)
    np.testing.assert_array_equal(info6["tau"], 0.0)
    np.testing.assert_array_equal(info6["eta"][:, :2], 0.0)
    assert set(a[6][4]) == set(info)
    envs.close()


def test_vector_env_matches_single_env_dynamics() -> None:
    """Same initial state and calm conditions: vector and single env give the same ν."""
    n = 3
    venv = Manoeuvring3DOFVectorEnv(n, **CALM)
    env = Manoeuvring3DOFEnv(**CALM)
    nu0 = [0.25, 0.0, 0.02]
    acts = _actions(50)
    venv.reset(seed=0, options={"nu": nu0, "eta": [0.0, 0.0, 0.4]})
    single = _rollout(env, acts, seed=0, options={"nu": nu0, "eta": [0.0, 0.0, 0.4]})
    for k, a in enumerate(acts):
        info = venv.step(np.tile(a, (n, 1)))[4]
        np.testing.assert_allclose(info["nu"], np.tile(single["nu"][k + 1], (n, 1)), atol=1e-14)


def test_single_step_is_the_batched_step_with_one_vessel() -> None:
    """The single environment's float path (``step_single``, ``step_one``, ``info_one``)
    reproduces the batched core's step with ``B = 1`` bit for bit, across noise blocks,
    with actions beyond ±1 (clipped) and the reward's heading wrap."""
    from vesselid.envs.manoeuvring import SINGLE_BLOCK

    env = Manoeuvring3DOFEnv(force_noise=(0.1, 0.1, 0.05), psi_ref=3.0)
    ref = Manoeuvring3DOFEnv(force_noise=(0.1, 0.1, 0.05), psi_ref=3.0)
    env.reset(seed=4)
    ref.reset(seed=4)
    core = ref._core
    actions = np.random.default_rng(2).uniform(-1.5, 1.5, (SINGLE_BLOCK + 100, 3))
    for a in actions.astype(np.float32):
        obs, r, term, _, info = env.step(a)
        core.step(a.astype(np.float64).reshape(1, 3), core.no_skip)
        np.testing.assert_array_equal(obs, core.obs[0])
        assert r == float(core.rewards[0]) and term == bool(core.terminated[0])
        expected = core.info(0)
        assert info.keys() == expected.keys()
        for k in info:
            np.testing.assert_array_equal(info[k], expected[k])


def test_single_step_info_is_a_dict_of_that_step() -> None:
    """The single environment's info (views made on first read) holds the values of its
    own step even when read after later steps, and behaves as the plain dict of those
    views: keys, membership, ``|``, item assignment, copies and pickling (a plain dict)."""
    import copy
    import pickle

    env = Manoeuvring3DOFEnv()
    ref = Manoeuvring3DOFEnv()
    env.reset(seed=3)
    ref.reset(seed=3)
    a = np.array([0.5, -0.2, 0.1], dtype=np.float32)
    info = env.step(a)[4]
    ref.step(a)
    expected = ref._core.info(0)
    for _ in range(3):
        env.step(a)  # later steps do not move the first step's info
    assert isinstance(info, dict) and len(info) == len(expected)
    assert list(info) == list(expected) and "nu" in info and "nope" not in info
    for k, v in expected.items():
        np.testing.assert_array_equal(info[k], v)
    for other in (dict(info), {**info}, info.copy(), copy.deepcopy(info),
                  pickle.loads(pickle.dumps(info))):
        assert type(other) is dict and list(other) == list(expected)
        np.testing.assert_array_equal(other["eta"], expected["eta"])
    merged = env.step(a)[4] | {"episode": 1}
    assert merged["episode"] == 1 and len(merged) == len(expected) + 1
    later = env.step(a)[4]
    later["episode"] = 2
    assert later.pop("episode") == 2 and len(later) == len(expected)


def test_pickled_and_copied_env_steps_on_identically():
    import copy
    import pickle

    env = Manoeuvring3DOFEnv()
    env.reset(seed=4)
    actions = np.random.default_rng(1).uniform(-1, 1, size=(1100, 3)).astype(np.float32)
    for a in actions[:100]:
        env.step(a)
    clones = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    for n, a in enumerate(actions[100:]):  # across a disturbance block
        obs, r, term, trunc, info = env.step(a)
        for clone in clones:
            o, *rest, i = clone.step(a)
            assert o.tolist() == obs.tolist() and rest == [r, term, trunc]
            if n % 100 == 0:
                assert i.keys() == info.keys()
                for k in info:
                    np.testing.assert_array_equal(i[k], info[k])


def test_subclass_step_override_is_called():
    class Counting(Manoeuvring3DOFEnv):
        calls = 0

        def step(self, action):
            Counting.calls += 1
            return super().step(action)

    sub = Counting()
    sub.reset(seed=0)
    out = sub.step(np.zeros(3, np.float32))
    ref = Manoeuvring3DOFEnv()
    ref.reset(seed=0)
    assert Counting.calls == 1
    np.testing.assert_array_equal(out[0], ref.step(np.zeros(3, np.float32))[0])
