"""Benchmark ``vesselid/Heave-v0``: raw single-env steps/s and vector env-steps/s.

Run ``python scripts/bench_envs_heave.py``. Reports medians over ``repeats`` timed runs
after a warm-up (numba compilation and caches excluded), with ``CartPole-v1`` as the
reference for the single environment. A benchmark, never a timed test.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import gymnasium as gym
import numpy as np

import vesselid  # noqa: F401  (registers the environments)

__all__ = ["bench_heave"]


def _single_rate(env_id: str, action: Any, steps: int, repeats: int) -> float:
    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    step, reset = env.step, env.reset
    for _ in range(2000):  # warm-up
        if step(action)[2]:
            reset()
    rates = []
    for _ in range(repeats):
        reset(seed=0)
        t0 = time.perf_counter()
        for _ in range(steps):
            if step(action)[2]:  # terminated: CartPole falls over
                reset()
        rates.append(steps / (time.perf_counter() - t0))
    env.close()
    return statistics.median(rates)


def _vector_rate(env_id: str, num_envs: int, steps: int, repeats: int) -> float:
    envs = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    envs.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (num_envs, 1)).astype(np.float32)
    for _ in range(50):  # warm-up
        envs.step(actions)
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            envs.step(actions)
        rates.append(steps * num_envs / (time.perf_counter() - t0))
    envs.close()
    return statistics.median(rates)


def bench_heave(
    repeats: int = 5, steps: int = 100_000, num_envs: int = 1024, vector_steps: int = 1000
) -> dict[str, float]:
    """Median throughput of the heave environment and of CartPole-v1.

    Parameters
    ----------
    repeats : int
        Timed runs per measurement (the median is reported).
    steps : int
        Steps per timed run of a single environment.
    num_envs : int
        Sub-environments of the vector environment.
    vector_steps : int
        Vector steps per timed run.

    Returns
    -------
    dict
        ``heave_steps_per_s`` and ``cartpole_steps_per_s`` (raw ``env.unwrapped.step``
        calls per second), ``heave_vector_env_steps_per_s`` (sub-environment steps per
        second with ``num_envs`` environments) and ``num_envs``.
    """
    heave = _single_rate("vesselid/Heave-v0", np.array([0.2], dtype=np.float32), steps, repeats)
    cartpole = _single_rate("CartPole-v1", 1, steps, repeats)
    vector = _vector_rate("vesselid/Heave-v0", num_envs, vector_steps, repeats)
    return {
        "heave_steps_per_s": heave,
        "cartpole_steps_per_s": cartpole,
        "heave_vector_env_steps_per_s": vector,
        "num_envs": float(num_envs),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--num-envs", type=int, default=1024)
    args = parser.parse_args()
    res = bench_heave(args.repeats, args.steps, args.num_envs)
    print(f"Heave-v0 raw env.unwrapped.step : {res['heave_steps_per_s']:>12,.0f} steps/s")
    print(f"CartPole-v1 raw (reference)     : {res['cartpole_steps_per_s']:>12,.0f} steps/s")
    print(f"Heave-v0 vector, {args.num_envs} envs      : "
          f"{res['heave_vector_env_steps_per_s']:>12,.0f} env-steps/s")
    print(f"(medians of {args.repeats} runs)")


if __name__ == "__main__":
    main()
