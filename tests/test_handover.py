"""Arrays handed over to the long-log steps of identify (a one-item list the callee empties
and frees): the same numbers as the arrays passed as they are, and the list emptied."""

from __future__ import annotations

import numpy as np

from vesselid.identify import gmm, kernels, validity
from vesselid.identify.data import from_arrays
from vesselid.identify.estimators import estimate
from vesselid.plant.systems import heave


def _one_log(n_runs: int = 1, samples: int = 3000):
    system = heave()
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(samples, n_runs=n_runs, seed=3)
    data = from_arrays(spec, sim.y, sim.u, experiments_per_group=n_runs)
    theta = estimate(data, spec, "iv-zero-mean").theta
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    return data, spec, theta, phi


def test_colour_test_with_handed_over_instruments() -> None:
    data, spec, theta, phi = _one_log()
    z, _ = gmm.simulated_instruments(data, spec, theta)
    ref = gmm.colour_test(data, spec, phi, z.copy())
    held = [z]
    del z
    got = gmm.colour_test(data, spec, phi, held)
    assert held == []
    np.testing.assert_array_equal(got[0], ref[0])
    np.testing.assert_array_equal(got[1], ref[1])


def test_solve_equations_with_handed_over_regressors() -> None:
    data, spec, theta, phi = _one_log()
    z, _ = gmm.simulated_instruments(data, spec, theta)
    lagged = [gmm.lagged_regressors(data, spec, lag) for lag in gmm.LAGS]

    def blocks():
        return gmm.instrument_blocks(spec, "combined", None, z, lagged)

    ref = gmm.solve_equations(data, spec, phi, blocks(), keep_designs=True)
    held = [phi.copy()]
    got = gmm.solve_equations(data, spec, held, blocks(), keep_designs=True, release=True)
    assert held == []
    np.testing.assert_array_equal(got.theta, ref.theta)
    np.testing.assert_array_equal(got.j, ref.j)
    for a, b in zip(got.designs, ref.designs, strict=True):
        for x, y in zip(a[:3], b[:3], strict=True):
            np.testing.assert_array_equal(x, y)


def test_halves_of_one_experiment_are_its_rows() -> None:
    data, _, _, _ = _one_log()
    halves = validity._halves(data)
    assert halves.target is data.target and halves.u is data.u
    assert halves.starts.tolist() == [0, 1500, 3000] and halves.n_groups == 2
    # several experiments: every experiment's first halves, then the second halves
    data2, _, _, _ = _one_log(n_runs=2, samples=1000)
    halves2 = validity._halves(data2)
    order = np.r_[0:500, 1000:1500, 500:1000, 1500:2000]
    np.testing.assert_array_equal(halves2.target, data2.target[order])
    assert halves2.target is not data2.target
