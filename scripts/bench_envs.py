"""Benchmark of the CyberShip II manoeuvring environments (merged into scripts/bench.py).

Measures the median raw step rate of the single environment (``env.unwrapped.step``,
after warm-up) and the env-step rate of the vector environment with 1024 sub-envs.
Run: ``python scripts/bench_envs.py``.
"""

from __future__ import annotations

import statistics
import time

import numpy as np


def bench_manoeuvring(repeats: int = 5, *, single_steps: int = 20_000,
                      vector_steps: int = 300, num_envs: int = 1024) -> dict[str, float]:
    """Median steps/s of ``Manoeuvring3DOFEnv`` and env-steps/s of the vector env.

    Parameters
    ----------
    repeats : int
        Timed repetitions; the median is reported.
    single_steps, vector_steps : int
        Steps per repetition of the single and the vector environment.
    num_envs : int
        Sub-environments of the vector environment.

    Returns
    -------
    dict
        ``{"single_steps_per_s", "vector_env_steps_per_s", "num_envs"}``.
    """
    from vesselid.envs.manoeuvring import Manoeuvring3DOFEnv, Manoeuvring3DOFVectorEnv

    env = Manoeuvring3DOFEnv()
    env.reset(seed=0)
    step = env.unwrapped.step
    action = np.array([0.6, 0.1, 0.2], dtype=np.float32)
    for _ in range(2_000):  # warm-up (compilation, first noise blocks)
        step(action)
    single = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(single_steps):
            step(action)
        single.append(single_steps / (time.perf_counter() - t0))
    env.close()

    venv = Manoeuvring3DOFVectorEnv(num_envs)
    venv.reset(seed=0)
    actions = np.tile(action, (num_envs, 1))
    for _ in range(100):
        venv.step(actions)
    vector = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(vector_steps):
            venv.step(actions)
        vector.append(vector_steps * num_envs / (time.perf_counter() - t0))
    venv.close()
    out = {
        "single_steps_per_s": statistics.median(single),
        "vector_env_steps_per_s": statistics.median(vector),
        "num_envs": float(num_envs),
    }
    print(f"Manoeuvring3DOF single: {out['single_steps_per_s']:,.0f} steps/s (median of "
          f"{repeats})")
    print(f"Manoeuvring3DOF vector ({num_envs} envs): {out['vector_env_steps_per_s']:,.0f} "
          f"env-steps/s (median of {repeats})")
    return out


if __name__ == "__main__":
    bench_manoeuvring()
