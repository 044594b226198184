"""The plant: what every simulation, manoeuvre, planner and environment runs through.

A plant is a physics spec with its true θ0 (:attr:`Plant.spec`), the disturbances that
move it, the sensors that read it and the inputs that drive it. Two kinds satisfy
:class:`Plant`:

* :class:`vesselid.plant.systems.System` — the heave / §5 systems (state-wise current
  ``q``, process noise ``w``, sensor noise ``e``, input designs);
* :class:`vesselid.plant.vessels.kernel.VesselModel` — a hull in a sea
  (:class:`~vesselid.plant.vessels.environment.VesselDisturbances`: earth-fixed current,
  Blendermann wind, unmodelled forces, plug-in components;
  :class:`~vesselid.plant.vessels.environment.VesselSensors`), simulated by
  :func:`~vesselid.plant.vessels.kernel.simulate_vessel` and stepped by
  :class:`~vesselid.plant.vessels.kernel.VesselBatch` (the environments).

Every user asks the plant, not a copy of it: the noise-free response
(:meth:`Plant.run`: manoeuvre switching instants, the planner's instruments and nominal
path) and the response to random realisations of its process disturbances
(:meth:`Plant.disturbed_paths`: the planner's instrument–regressor cross moment), so a
disturbance added to the plant reaches them all.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from vesselid.model.spec import ModelSpec

__all__ = ["Plant", "heading"]


@runtime_checkable
class Plant(Protocol):
    """A simulated plant (:class:`~vesselid.plant.systems.System`,
    :class:`~vesselid.plant.vessels.kernel.VesselModel`)."""

    @property
    def spec(self) -> ModelSpec:
        """The physics: structure and true θ0 (the model the plant simulates)."""
        ...

    def run(self, inputs: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """Noise-free states ``x(0..n)`` ``(n + 1, n_states)`` for inputs ``(n, n_inputs)``."""
        ...

    def disturbed_paths(self, inputs: np.ndarray, x0: np.ndarray | None = None, *,
                        paths: int, seed: int) -> np.ndarray:
        """States ``(paths, n + 1, n_states)`` under ``paths`` random realisations of the
        process disturbances (no sensor noise), drawn from ``default_rng(seed)``."""
        ...


def heading(states: np.ndarray, dt: float) -> np.ndarray:
    """Heading change ``ψ(k) − ψ(0) = dt Σ_{j<k} r(j)`` along vessel states ``[u, v, r]``
    (the kinematics of the vessel kernel, ``ψ(k+1) = ψ(k) + dt r(k)``)."""
    return dt * np.concatenate([[0.0], np.cumsum(states[:-1, 2])])
