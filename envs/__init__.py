"""Gymnasium environments of vesselid (installed as ``vesselid.envs``).

``import vesselid`` calls :func:`register_envs`, which registers

* ``vesselid/Heave-v0`` — heave velocity control, the paper's §6 system
  (:class:`~vesselid.envs.heave.HeaveEnv`, vector: :class:`~vesselid.envs.heave.HeaveVectorEnv`);
* ``vesselid/Manoeuvring3DOF-v0`` — surge/sway/yaw manoeuvring
  (:class:`~vesselid.envs.manoeuvring.Manoeuvring3DOFEnv`, vector:
  :class:`~vesselid.envs.manoeuvring.Manoeuvring3DOFVectorEnv`).

Registration uses string entry points, so nothing here imports an environment module
(or numba) until an environment is made. The classes and the trial recorders
(:class:`~vesselid.envs.recorder.TrialRecorder`,
:class:`~vesselid.envs.recorder.VectorTrialRecorder`) are exported lazily::

    import gymnasium as gym
    import vesselid  # registers the environments

    env = gym.make("vesselid/Heave-v0")
    envs = gym.make_vec("vesselid/Heave-v0", num_envs=1024,
                        vectorization_mode="vector_entry_point")
"""

from __future__ import annotations

from typing import Any

from vesselid.core.lazy import lazy_attributes

__all__ = [
    "ENV_IDS",
    "HeaveEnv",
    "HeaveVectorEnv",
    "Manoeuvring3DOFEnv",
    "Manoeuvring3DOFVectorEnv",
    "TrialRecorder",
    "VectorTrialRecorder",
    "register_envs",
]

#: Registration of every vesselid environment: id -> keyword arguments of ``gym.register``.
_REGISTRY: dict[str, dict[str, Any]] = {
    "vesselid/Heave-v0": {
        "entry_point": "vesselid.envs.heave:HeaveEnv",
        "vector_entry_point": "vesselid.envs.heave:HeaveVectorEnv",
        "max_episode_steps": 1000,
    },
    "vesselid/Manoeuvring3DOF-v0": {
        "entry_point": "vesselid.envs.manoeuvring:Manoeuvring3DOFEnv",
        "vector_entry_point": "vesselid.envs.manoeuvring:Manoeuvring3DOFVectorEnv",
        "max_episode_steps": 2000,
    },
}

#: Ids of the vesselid environments.
ENV_IDS: tuple[str, ...] = tuple(_REGISTRY)

_LAZY = {
    "HeaveEnv": "vesselid.envs.heave",
    "HeaveVectorEnv": "vesselid.envs.heave",
    "Manoeuvring3DOFEnv": "vesselid.envs.manoeuvring",
    "Manoeuvring3DOFVectorEnv": "vesselid.envs.manoeuvring",
    "TrialRecorder": "vesselid.envs.recorder",
    "VectorTrialRecorder": "vesselid.envs.recorder",
}


def register_envs() -> None:
    """Register the vesselid environments with gymnasium (idempotent).

    Ids already in ``gymnasium.registry`` are left untouched, so calling this again
    (or after a user registered an id themselves) is harmless.

    Raises
    ------
    ImportError
        If gymnasium is not installed.
    """
    import gymnasium

    for env_id, kwargs in _REGISTRY.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, **kwargs)


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, __all__)
