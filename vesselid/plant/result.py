"""The one result type of every plant: arrays ``(runs, samples, ·)``, a tidy frame and a
trial log.

:class:`SimulationResult` owns the frame layout (``experiment``, ``time``, then the
plant's named signal columns) and the trial-log metadata (spec, system settings, seeds,
version, sizes); a plant's result class (:class:`vesselid.plant.systems.Simulation`,
:class:`vesselid.plant.vessels.VesselSimulation`) names its signals and columns only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["SimulationResult"]


class SimulationResult:
    """Base of simulation results (subclasses are dataclasses with ``seed`` and
    ``spawn_keys`` fields)."""

    seed: int | None
    spawn_keys: list | None

    def _lead(self) -> np.ndarray:
        """An array with the ``(runs, samples)`` leading axes."""
        raise NotImplementedError

    def _dt(self) -> float:
        raise NotImplementedError

    def columns(self) -> dict[str, np.ndarray]:
        """Named signal columns (flattened run by run) after ``experiment, time``."""
        raise NotImplementedError

    @property
    def n_runs(self) -> int:
        return int(self._lead().shape[0])

    @property
    def n_samples(self) -> int:
        return int(self._lead().shape[1])

    def to_frame(self) -> Any:
        """Tidy trial-log frame: one row per sample, runs are experiments."""
        import pandas as pd

        n_r, n_k = self.n_runs, self.n_samples
        return pd.DataFrame({
            "experiment": np.repeat(np.arange(n_r, dtype=np.int64), n_k),
            "time": np.tile(np.arange(n_k) * self._dt(), n_r),
            **self.columns(),
        })

    def _trial_log(self, spec: Any, system: dict[str, Any]) -> Any:
        """:class:`~vesselid.data.logs.TrialLog` of :meth:`to_frame` with the standard metadata."""
        from vesselid import __version__
        from vesselid.data.logs import TrialLog

        meta = {
            "spec": spec.to_dict(),
            "system": system,
            "seed": self.seed,
            "spawn_keys": self.spawn_keys,
            "vesselid_version": __version__,
            "samples_per_experiment": self.n_samples,
            "experiments": self.n_runs,
        }
        return TrialLog(self.to_frame(), meta)
