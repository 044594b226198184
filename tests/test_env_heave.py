"""``vesselid/Heave-v0``: dynamics, spaces, info, rendering and trial-log recording."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from _stats import assert_mean_within, assert_std_within
from numpy.testing import assert_allclose, assert_array_equal

import vesselid  # noqa: F401  (registers the environments)
from vesselid.data.logs import TrialLog
from vesselid.envs.heave import HeaveEnv, HeaveVectorEnv
from vesselid.envs.recorder import TrialRecorder, VectorTrialRecorder
from vesselid.errors import VesselidError
from vesselid.plant.simulate import simulate_states
from vesselid.plant.systems import heave

ENV_ID = "vesselid/Heave-v0"
THETA0 = np.array([0.99, -0.1, 1.0])
NOISE_FREE = {
    "current_mean": 0.0, "current_std": 0.0, "xi_mean": 0.0, "xi_std": 0.0,
    "sensor_std": 0.0, "current_sensor_std": 0.0,
}
INFO_KEYS = {"w_a", "w_r", "w_c", "xi", "y1", "w_ref"}


def _rollout(env, actions, seed=0, options=None):
    _, info = env.reset(seed=seed, options=options)
    infos, rewards = [info], []
    for a in actions:
        _, r, term, _, info = env.step(a)
        assert not term
        infos.append(info)
        rewards.append(r)
    return infos, np.array(rewards)


def _ols(log: TrialLog, aggregate: bool = False) -> np.ndarray:
    """Least squares on [w, w|w|, tau] from consecutive rows of every experiment."""
    phi, y = [], []
    for _, frame in log.experiments():
        w = frame["w"].to_numpy()
        r = w - frame["w_c"].to_numpy() if aggregate else w
        tau = frame["tau"].to_numpy()
        phi.append(np.column_stack([r[:-1], r[:-1] * np.abs(r[:-1]), tau[:-1]]))
        y.append(w[1:])
    return np.linalg.lstsq(np.vstack(phi), np.concatenate(y), rcond=None)[0]


# ------------------------------------------------------------------------- dynamics
def test_noise_free_env_matches_simulate_states() -> None:
    env = gym.make(ENV_ID, **NOISE_FREE).unwrapped
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1, 1, size=(500, 1)).astype(np.float32)
    infos, _ = _rollout(env, actions, options={"w0": 0.7})
    tau = np.array([env.thrust(a) for a in actions])
    x = simulate_states(heave().spec, tau[:, None], x0=np.array([0.7]))
    w_a = np.array([i["w_a"] for i in infos])
    assert_allclose(w_a[:500], x[:, 0], rtol=0, atol=1e-12)
    y1 = np.array([i["y1"] for i in infos])
    assert_array_equal(y1, w_a)


def test_dynamics_info_and_reward_with_noise() -> None:
    env = gym.make(ENV_ID, current_mean=0.1, action_cost=0.3).unwrapped
    assert env.current_sensor  # default on iff current_mean != 0 (as systems.heave)
    obs, info = env.reset(seed=5)
    assert set(info) == INFO_KEYS | {"y2"}
    for a in np.linspace(-1, 1, 50, dtype=np.float32):
        tau = env.thrust([a])
        w_r = info["w_a"] - info["w_c"]
        expected = 0.99 * w_r - 0.1 * w_r * abs(w_r) + tau + info["xi"]
        ref = info["w_ref"]
        obs, r, term, trunc, new = env.step(np.array([a], dtype=np.float32))
        assert new["w_a"] == pytest.approx(expected, abs=1e-14)
        assert r == pytest.approx(-((new["w_a"] - ref) ** 2) - 0.3 * tau**2, abs=1e-14)
        assert set(new) == set(info)
        assert new["w_r"] == new["w_a"] - new["w_c"]
        assert_array_equal(obs, np.array([new["y1"], new["y2"], new["w_ref"]], np.float32))
        assert not term and not trunc
        info = new


def test_noise_statistics_follow_the_kwargs() -> None:
    env = HeaveEnv(current_mean=0.1, current_std=0.2, xi_mean=-0.3, xi_std=0.05,
                   sensor_std=0.4, current_sensor=True, current_sensor_std=0.01)
    _, info = env.reset(seed=0)
    rows = [info]
    for _ in range(4000):
        rows.append(env.step(np.array([0.0], np.float32))[4])
    arr = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    # white Gaussian draws: tolerances from the SEs of the mean and std of 4001 samples
    assert_mean_within(arr["w_c"], 0.1, std=0.2)
    assert_std_within(arr["w_c"], 0.2)
    assert_mean_within(arr["xi"], -0.3, std=0.05)
    assert_std_within(arr["xi"], 0.05)
    assert_std_within(arr["y1"] - arr["w_a"], 0.4)
    assert_std_within(arr["y2"] - arr["w_c"], 0.01)


def test_paper_defaults() -> None:
    env = HeaveEnv()
    settings = env.log_metadata()["settings"]
    assert settings["current_mean"] == 0.0
    assert settings["xi_mean"] == pytest.approx(-0.05)
    for key in ("current_std", "xi_std", "sensor_std", "current_sensor_std"):
        assert settings[key] == pytest.approx(0.1)  # variance 0.01
    assert not env.current_sensor
    assert env.observation_space.shape == (2,) and env.observation_space.dtype == np.float32
    assert env.action_space.low[0] == -1 and env.action_space.high[0] == 1
    assert env.model_spec.theta0_vector().tolist() == THETA0.tolist()
    assert gym.spec(ENV_ID).max_episode_steps == 1000


def test_action_mapping_clips_and_scales() -> None:
    env = HeaveEnv(thrust_range=(-0.2, 0.6))
    assert env.thrust([-1.0]) == pytest.approx(-0.2)
    assert env.thrust([1.0]) == pytest.approx(0.6)
    assert env.thrust([0.0]) == pytest.approx(0.2)
    assert env.thrust([7.0]) == pytest.approx(0.6)
    assert env.thrust([-7.0]) == pytest.approx(-0.2)


def test_constant_and_random_reference() -> None:
    env = HeaveEnv(reference=0.8)
    _, info = env.reset(seed=0)
    refs = [info["w_ref"]] + [env.step(np.zeros(1))[4]["w_ref"] for _ in range(300)]
    assert set(refs) == {0.8}
    env = HeaveEnv(reference="random", reference_range=(0.5, 1.5), reference_hold=(10, 20))
    _, info = env.reset(seed=0)
    refs = np.array([info["w_ref"]] + [env.step(np.zeros(1))[4]["w_ref"] for _ in range(300)])
    switches = np.flatnonzero(np.diff(refs) != 0)
    assert 300 / 21 <= switches.size <= 300 / 10 + 1
    assert np.all(np.diff(np.r_[-1, switches]) >= 10)
    assert refs.min() >= 0.5 and refs.max() <= 1.5


def test_terminates_when_velocity_leaves_the_envelope() -> None:
    env = HeaveEnv(thrust_range=(0.0, 5.0), velocity_limit=2.0, initial_velocity=(0.0, 0.1),
                   reference=1.0)
    env.reset(seed=0)
    for _ in range(100):
        _, _, terminated, _, info = env.step(np.ones(1, np.float32))
        if terminated:
            assert abs(info["w_a"]) > 2.0
            break
    else:
        pytest.fail("no termination")


@pytest.mark.parametrize(
    "kwargs",
    [{"current_std": -1.0}, {"thrust_range": (1.0, 0.0)}, {"reference": "sine"},
     {"reference": 20.0}, {"reference_hold": (0, 5)}, {"velocity_limit": 0.0},
     {"render_mode": "ansi"}],
)
def test_invalid_settings_raise_domain_errors(kwargs) -> None:
    with pytest.raises(VesselidError):
        HeaveEnv(**kwargs)
    with pytest.raises(ValueError):
        HeaveVectorEnv(num_envs=2, **{k: v for k, v in kwargs.items() if k != "render_mode"}
                       | ({"render_mode": "human"} if "render_mode" in kwargs else {}))


def test_vector_env_matches_single_env() -> None:
    kw = dict(NOISE_FREE, reference=1.0)
    n = 5
    venv = HeaveVectorEnv(num_envs=n, max_episode_steps=0, **kw)
    w0 = np.linspace(0.0, 1.2, n)
    _, vinfo = venv.reset(seed=0, options={"w0": w0})
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, size=(100, n, 1)).astype(np.float32)
    v_w = [vinfo["w_a"]]
    v_r = []
    for a in actions:
        _, r, _, _, vinfo = venv.step(a)
        v_w.append(vinfo["w_a"])
        v_r.append(r)
    for i in range(n):
        env = HeaveEnv(**kw)
        infos, rewards = _rollout(env, actions[:, i], options={"w0": w0[i]})
        assert_array_equal(np.array([x["w_a"] for x in infos]), np.array(v_w)[:, i])
        assert_array_equal(rewards, np.array(v_r)[:, i])


def test_render_human_is_safe_headless() -> None:
    env = gym.make(ENV_ID, render_mode="human")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    assert env.render() is None
    env.close()
    env.close()


def test_vector_render_rgb_array() -> None:
    envs = HeaveVectorEnv(num_envs=2, render_mode="rgb_array")
    envs.reset(seed=0)
    for _ in range(3):
        envs.step(envs.action_space.sample())
    frames = envs.render()
    assert len(frames) == 2 and all(f.dtype == np.uint8 and f.shape[2] == 3 for f in frames)
    envs.close()


# ------------------------------------------------------------------------ recording
def test_recorder_round_trip_csv(tmp_path) -> None:
    env = TrialRecorder(gym.make(ENV_ID, current_mean=0.1))
    env.reset(seed=11)
    env.action_space.seed(11)
    for _ in range(30):
        env.step(env.action_space.sample())
    env.reset(seed=12)
    for _ in range(20):
        env.step(env.action_space.sample())
    log = env.to_log()
    assert list(log.data.columns) == ["experiment", "time", "w", "tau", "w_c", "w_ref",
                                      "true_w", "true_current_w", "true_process_w"]
    assert log.experiment_ids == [0, 1]
    assert [len(f) for _, f in log.experiments()] == [30, 20]
    assert_array_equal(log.data["time"].to_numpy()[:30], np.arange(30.0))
    meta = log.metadata
    assert meta["seed"] == 11 and meta["reset_seeds"] == [11, 12]
    assert meta["env_id"] == ENV_ID and meta["env_kwargs"]["current_mean"] == 0.1
    assert meta["spec"]["aggregate"] == {"w": "w - w_c"}
    assert meta["episodes"][0]["finished"] is False and meta["episodes"][0]["steps"] == 30
    path = env.save(tmp_path / "heave.csv")
    loaded = TrialLog.load(path)
    assert (tmp_path / "heave.json").is_file()
    import pandas.testing as pd_testing
    pd_testing.assert_frame_equal(loaded.data, log.data)
    assert loaded.metadata == meta
    assert loaded.spec == env.unwrapped.model_spec


def test_recorder_drops_the_dangling_last_observation() -> None:
    env = TrialRecorder(gym.make(ENV_ID, max_episode_steps=10))
    obs, _ = env.reset(seed=0)
    done = False
    while not done:
        *_, term, trunc, _ = env.step(env.action_space.sample())
        done = term or trunc
    env.reset(seed=1)
    log = env.to_log()
    assert [len(f) for _, f in log.experiments()] == [10]
    assert log.metadata["episodes"][0]["truncated"] is True
    assert log.data["w"].iloc[0] == pytest.approx(float(obs[0]), abs=1e-6)


def test_identification_of_noise_free_recording_is_exact() -> None:
    env = TrialRecorder(gym.make(ENV_ID, max_episode_steps=150, **NOISE_FREE))
    env.action_space.seed(0)
    for seed in range(3):
        env.reset(seed=seed)
        done = False
        while not done:
            *_, term, trunc, _ = env.step(env.action_space.sample())
            done = term or trunc
    log = env.to_log()
    assert log.experiment_ids == [0, 1, 2]
    assert_allclose(_ols(log), THETA0, rtol=0, atol=1e-8)


def test_identification_with_constant_measured_current_is_exact() -> None:
    kw = dict(NOISE_FREE, current_mean=0.2, current_sensor=True)
    env = TrialRecorder(gym.make(ENV_ID, **kw))
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(300):
        env.step(env.action_space.sample())
    log = env.to_log()
    assert env.model_spec.sensors == ("w_c",)
    assert_allclose(log.data["w_c"], 0.2)
    assert_allclose(_ols(log, aggregate=True), THETA0, rtol=0, atol=1e-8)


def test_vector_recorder_splits_autoreset_episodes_exactly(tmp_path) -> None:
    envs = VectorTrialRecorder(
        gym.make_vec(ENV_ID, num_envs=4, vectorization_mode="vector_entry_point",
                     max_episode_steps=40, **NOISE_FREE)
    )
    envs.reset(seed=0)
    envs.action_space.seed(0)
    for _ in range(130):  # 3 full episodes per env (40 steps + 1 reset step) + 7 steps
        envs.step(envs.action_space.sample())
    log = envs.to_log()
    meta = log.metadata["episodes"]
    assert len(meta) == 16
    assert [m["env_index"] for m in meta[:8]] == [0, 1, 2, 3, 0, 1, 2, 3]
    assert all(m["steps"] == 40 and m["truncated"] for m in meta[:12])
    assert all(m["steps"] == 7 and not m["finished"] for m in meta[12:])
    for _, frame in log.experiments():
        assert_array_equal(frame["time"].to_numpy(), np.arange(len(frame), dtype=float))
    assert_allclose(_ols(log), THETA0, rtol=0, atol=1e-8)
    assert len(envs.to_log(include_unfinished=False).experiment_ids) == 12
    path = envs.save(tmp_path / "vec.csv")
    assert TrialLog.load(path).experiment_ids == list(range(16))


@pytest.mark.parametrize("settings", [{}, {"current_mean": 0.1, "reference_hold": (1, 3)},
                                      {"reference": 0.9, "velocity_limit": 1.2,
                                       "initial_velocity": (0.0, 1.0),
                                       "thrust_range": (-2.0, 3.0)}])
def test_single_env_is_the_vector_core_with_one_env(settings) -> None:
    """The single environment's scalar step reproduces the batched core with ``n = 1``
    bit for bit: observations, rewards, terminations, info, across noise blocks,
    reference changes, terminations and stepping on past the end (next-step reset)."""
    from vesselid.envs.heave import SINGLE_BLOCK, _Core

    env = HeaveEnv(**settings)
    core = _Core(env._cfg, 1, SINGLE_BLOCK)
    rng = np.random.default_rng(3)
    actions = rng.uniform(-1.5, 1.5, size=(2 * SINGLE_BLOCK + 50, 1))
    obs, info = env.reset(seed=5, options={"w0": 0.4})
    core.reset(np.random.default_rng(5), 0.4)
    done = 0
    for a in actions:
        assert_array_equal(obs, core.obs()[0])
        assert info == {k: float(v[0]) for k, v in core.info().items()}
        obs, r, term, trunc, info = env.step(a)
        rv, tv, _ = core.step(a)
        assert (r, term, trunc) == (float(rv[0]), bool(tv[0]), False)
        done += term
    if "velocity_limit" in settings:
        assert done > 3  # terminations and the steps after them were exercised


@pytest.mark.parametrize("settings", [{}, {"current_mean": 0.1, "reference_hold": (1, 3),
                                           "reference_range": (0.5, 1.0), "velocity_limit": 1.2,
                                           "initial_velocity": (0.0, 1.0),
                                           "thrust_range": (-2.0, 3.0)}])
def test_observations_stay_as_returned(settings) -> None:
    """Every observation is an array of its own: later steps, reference changes, noise
    blocks and resets never change one returned earlier, nor does writing into one."""
    from vesselid.envs.heave import SINGLE_BLOCK

    env = HeaveEnv(**settings)
    obs, _ = env.reset(seed=2)
    kept, copies, done = [obs], [obs.copy()], 0
    actions = np.random.default_rng(0).uniform(-1, 1, size=(2 * SINGLE_BLOCK + 10, 1))
    for i, a in enumerate(actions):
        obs, _, term, _, _ = env.step(a)
        kept.append(obs)
        copies.append(obs.copy())
        done += term
        if term and i % 2:
            obs, _ = env.reset()
            kept.append(obs)
            copies.append(obs.copy())
    kept[5][:] = 99.0
    copies[5][:] = 99.0
    for obs, copy in zip(kept, copies, strict=True):
        assert_array_equal(obs, copy)
    assert done > 3 or not settings  # terminations, resets and autoresets were exercised


def test_pickled_and_copied_env_steps_on_identically() -> None:
    import copy
    import pickle

    env = HeaveEnv(current_mean=0.1)
    env.reset(seed=4)
    actions = np.random.default_rng(1).uniform(-1, 1, size=(1100, 1)).astype(np.float32)
    for a in actions[:100]:
        env.step(a)
    clones = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))]
    for a in actions[100:]:
        obs, r, term, trunc, info = env.step(a)
        for clone in clones:
            o, *rest = clone.step(a)
            assert_array_equal(o, obs)
            assert rest == [r, term, trunc, info]


def test_subclass_step_override_is_called() -> None:
    class Counting(HeaveEnv):
        calls = 0

        def step(self, action):
            Counting.calls += 1
            return super().step(action)

    sub = Counting()
    sub.reset(seed=0)
    out = sub.step(np.array([0.5], np.float32))
    ref = HeaveEnv()
    ref.reset(seed=0)
    assert Counting.calls == 1
    assert_array_equal(out[0], ref.step(np.array([0.5], np.float32))[0])
