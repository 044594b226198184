"""Shared test helper: the refined iteration with its fixed-point map replaced."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from vesselid.identify import estimators
from vesselid.identify.data import from_arrays
from vesselid.plant.systems import heave


def refine_with_fixed_point_map(monkeypatch, fixed_point_map: Callable, max_iter: int, *,
                                average: bool = False):
    """Run :func:`~vesselid.identify.estimators.refined_iv` on a small heave log with
    ``T(θ)`` replaced by ``fixed_point_map(θ, θ0)`` (inside ``stall_averaging()`` when
    ``average``); returns the result and θ0."""
    system = heave()
    spec = system.identification_spec()
    sim = system.simulate(500, n_runs=1, seed=0)
    data = from_arrays(spec, sim.y, sim.u)
    target = spec.theta0_vector()
    seen = {}
    real_compute = estimators.compute_moments

    def fake_compute(data_, spec_, theta=None, **kw):
        seen["theta"] = np.array(theta, copy=True)
        return real_compute(data_, spec_, theta, **kw)

    def fake_solve(mom, data_, spec_, *, active=None, **kw):
        th = seen["theta"]
        ok = np.ones(th.shape[0], dtype=bool) if active is None else active.copy()
        return np.where(ok[:, None], fixed_point_map(th, target), np.nan), ok

    monkeypatch.setattr(estimators, "compute_moments", fake_compute)
    # every evaluation of T through compute_moments (not the refined iteration's direct
    # call of the structure's compiled kernel), so that the fake sees each θ
    monkeypatch.setattr(estimators, "_bound_moments", lambda *a, **k: None)
    monkeypatch.setattr(estimators, "solve_moments", fake_solve)
    if average:
        with estimators.stall_averaging():
            return estimators.refined_iv(data, spec, target[None] + 0.01,
                                         max_iter=max_iter), target
    return estimators.refined_iv(data, spec, target[None] + 0.01, max_iter=max_iter), target
