"""The refined IV of one group (a fit) on Python floats gives the numbers of the batched
path, and :func:`vesselid.identify.linalg.solve_rows` those of :func:`linalg.solve`."""

from __future__ import annotations

import numpy as np
import pytest

from vesselid.identify import linalg, validity
from vesselid.identify.data import from_log
from vesselid.identify.estimators import least_squares, refined_iv
from vesselid.plant.systems import heave

FIELDS = ("theta", "theta_aux", "converged", "iterations", "residual", "oscillation")


@pytest.fixture(scope="module")
def halves():
    log = heave().simulate(3000, seed=5).to_log(aggregate=False)
    data, spec = from_log(log, log.spec)[:2]
    two = validity._halves(data)  # the two halves as two groups of one batch
    return spec, two, [validity._group(two, g) for g in (0, 1)]


@pytest.mark.parametrize("zero_mean", [True, False])
@pytest.mark.parametrize(("scale", "options"), [
    (1.0, {}),                                   # converges
    (1.6, {"max_iter": 6, "tol": 1e-14}),        # stops at the cap
    (1.3, {"min_step": 0.5, "max_iter": 40}),    # rejected steps, step control
    ((1.1, 0.2, 1.0), {"limit_factor": 1.5}),    # one half's start diverges
    (60.0, {}),                                  # the start itself diverges
])
def test_one_group_equals_its_row_of_the_batch(halves, zero_mean, scale, options) -> None:
    spec, two, subs = halves
    start = least_squares(two, spec)[0] * np.asarray(scale)
    batch = refined_iv(two, spec, start, zero_mean=zero_mean, **options)
    for g in (0, 1):
        one = refined_iv(subs[g], spec, start[g:g + 1].copy(), zero_mean=zero_mean, **options)
        for name in FIELDS:
            got, want = getattr(one, name)[0], getattr(batch, name)[g]
            assert np.asarray(got).tobytes() == np.asarray(want).tobytes(), (name, g)
        assert one.reason[0] == batch.reason[g]


def test_one_group_keeps_its_history_and_averages_a_stall(halves) -> None:
    from vesselid.identify.estimators import stall_averaging

    spec, _, subs = halves
    start = least_squares(subs[0], spec)[0] * 1.2
    plain = refined_iv(subs[0], spec, start.copy(), zero_mean=True)
    kept = refined_iv(subs[0], spec, start.copy(), zero_mean=True, keep_history=True)
    assert kept.theta.tobytes() == plain.theta.tobytes()
    assert len(kept.history) == int(kept.iterations[0])
    assert kept.history[-1].shape == (1, spec.n_params)
    with stall_averaging(4):  # a converged fit is untouched by the stall averaging
        again = refined_iv(subs[0], spec, start.copy(), zero_mean=True)
    assert again.theta.tobytes() == plain.theta.tobytes() and "stall_average" not in again.info


def test_solve_rows_equals_solve() -> None:
    rng = np.random.default_rng(3)
    for _ in range(300):
        p = int(rng.integers(1, 7))
        a = rng.standard_normal((p, p)) * 10.0 ** rng.integers(-6, 7, size=p)
        b = rng.standard_normal(p)
        x, ok = linalg.solve(a[None], b[None])
        got = linalg.solve_rows(a.tolist(), b.tolist())
        assert bool(ok[0]) and got is not None
        assert np.array(got).tobytes() == x[0].tobytes()
    # singular, rank-deficient and non-finite systems are flagged alike
    for a in ([[1.0, 2.0], [2.0, 4.0]], [[0.0, 0.0], [0.0, 0.0]], [[1.0, np.inf], [0.0, 1.0]],
              [[1.0, 1.0], [1.0, 1.0 + 1e-17]]):
        x, ok = linalg.solve(np.array([a]), np.array([[1.0, 2.0]]))
        assert not ok[0] and linalg.solve_rows(a, [1.0, 2.0]) is None
