"""Recursive LS / IV with forgetting (:mod:`vesselid.identify.recursive`)."""

from __future__ import annotations

import numpy as np
import pytest

from vesselid.errors import IdentificationError
from vesselid.identify import identify
from vesselid.identify.recursive import RecursiveEstimator, recursive_estimate
from vesselid.model.regressors import evaluate
from vesselid.plant.simulate import simulate_states
from vesselid.plant.systems import heave


@pytest.fixture(scope="module")
def stationary():
    system = heave()
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(100_000, seed=11)
    return spec, sim, sim.to_log(aggregate=False)


def _se(res) -> np.ndarray:
    return np.sqrt(np.diag(res.cov.to_numpy()))


def test_rls_at_lambda_one_equals_batch_ls(stationary) -> None:
    spec, _, log = stationary
    rec = recursive_estimate(log, spec, "ls", forgetting=1.0)
    batch = identify(log, spec, "ls")
    np.testing.assert_allclose(rec.params.to_numpy(), batch.params.to_numpy(),
                               rtol=1e-10, atol=1e-12)


def test_sample_by_sample_equals_whole_array(stationary) -> None:
    spec, sim, _ = stationary
    y, u = sim.y[0, :3000], sim.u[0, :3000]
    whole = RecursiveEstimator(spec, "iv", forgetting=0.995)
    whole.run(y, u)
    one = RecursiveEstimator(spec, "iv", forgetting=0.995)
    for k in range(y.shape[0] - 1):
        one.update(y[k], u[k], y[k + 1])
    np.testing.assert_allclose(one.theta, whole.theta, rtol=1e-12)
    chunks = RecursiveEstimator(spec, "iv", forgetting=0.995)
    chunks.run(y[:1200], u[:1200])
    chunks.run(y[1199:], u[1199:], continues=True)  # row 1199 → 1200 is the next sample
    np.testing.assert_allclose(chunks.theta, whole.theta, rtol=1e-12)


def test_riv_delayed_equals_batch_iv_with_the_same_instruments(stationary) -> None:
    """λ = 1: the recursion with delayed-regressor instruments ends at the batch
    IV_E{ζ}=0 with those instruments (user-supplied to identify), far inside 0.1 SE."""
    spec, sim, log = stationary
    y, u = sim.y[0], sim.u[0]
    rec = RecursiveEstimator(spec, "iv", instruments="delayed", delay=1, warmup=3)
    rec.run(y, u)
    phi = evaluate(spec.codes.factors, np.column_stack([y, u]))
    # row k of the batch holds the equation predicting y(k): regressor φ(k−1), ζ = φ(k−2)
    z = np.zeros_like(phi)
    z[1:] = np.vstack([phi[:1], phi[:-2]])
    trimmed = log.data.iloc[1:].reset_index(drop=True)
    batch = identify(trimmed, spec, "iv-zero-mean", instruments=z[1:])
    diff = np.abs(rec.theta - batch.params.to_numpy()) / _se(batch)
    assert diff.max() < 1e-6


def test_riv_auxiliary_equals_batch_refined_iv(stationary) -> None:
    spec, sim, log = stationary
    batch = identify(log, spec, "iv-zero-mean")
    rec = RecursiveEstimator(spec, "iv", instruments="auxiliary",
                             theta_aux=batch.params.to_numpy(), warmup=5)
    rec.run(sim.y[0], sim.u[0])
    diff = np.abs(rec.theta - batch.params.to_numpy()) / _se(batch)
    assert diff.max() < 0.1


def _stepped_heave(seed: int, n: int, k_step: int, factor: float):
    system = heave()
    spec = system.spec
    rng = np.random.default_rng(seed)
    theta0 = spec.theta0_vector()
    theta1 = theta0.copy()
    theta1[2] *= factor
    u = rng.uniform(0.1, 0.3, size=(n // 40 + 1, 1)).repeat(40, axis=0)[:n]
    v = -0.1 * rng.standard_normal((n, 1))
    w = -0.05 + 0.1 * rng.standard_normal((n, 1))
    e = 0.1 * rng.standard_normal((n, 1))
    x1 = simulate_states(spec, u[:k_step + 1], v=v[:k_step + 1], w=w[:k_step + 1], x0=[1.3])
    x2 = simulate_states(spec, u[k_step:], theta=theta1, v=v[k_step:], w=w[k_step:],
                         x0=x1[-1])
    x = np.vstack([x1[:-1], x2])
    return spec, x + e, u, theta1


@pytest.mark.slow
def test_riv_tracks_a_ten_percent_step() -> None:
    """λ = 0.999: 2 000 samples after a 10 % step of the input gain the estimate is within
    2 SE of the new value, SE the spread of the recursive estimate over the stationary
    stretch before the step (its sampling standard deviation at this memory). Over 40
    independent logs at least 32 (binomial: P(≤ 31 | p = 0.95) < 1e-4)."""
    hits = 0
    for seed in range(40):
        spec, y, u, theta1 = _stepped_heave(seed, 40_000, 30_000, 1.10)
        est = RecursiveEstimator(spec, "iv", forgetting=0.999)
        hist = est.run(y, u, history_every=1)
        sd = hist[10_000:29_999, 2].std()
        err = abs(hist[30_000 + 2_000 - 1, 2] - theta1[2])
        hits += err <= 2 * sd
    assert hits >= 32


def test_bad_input() -> None:
    spec = heave().identification_spec(aggregate=False)
    for lam in (0.0, 1.5, -1, float("nan"), "x"):
        with pytest.raises(IdentificationError, match="forgetting"):
            RecursiveEstimator(spec, forgetting=lam)
    with pytest.raises(IdentificationError, match="theta_aux"):
        RecursiveEstimator(spec, instruments="auxiliary")
    est = RecursiveEstimator(spec)
    with pytest.raises(IdentificationError, match="finite"):
        est.update([np.nan], [0.1], [1.0])


def test_shared_gauss_jordan_inverts_with_either_pivot_row_arithmetic() -> None:
    """The one Gauss–Jordan kernel behind cond_bound and the recursive estimator's small
    inverses: partial pivoting (a zero leading entry is fine), [A | I] -> [I | A⁻¹] with
    division or reciprocal scaling of the pivot row, and a refusal at the pivot floor."""
    from vesselid.identify._ivkernels import gauss_jordan

    a = np.array([[0.0, 2.0, 1.0], [1.0, -1.0, 0.5], [3.0, 0.0, -2.0]])
    for reciprocal in (False, True):
        m = np.hstack([a, np.eye(3)])
        assert gauss_jordan(m, 3, 0.0, reciprocal)
        np.testing.assert_allclose(m[:, :3], np.eye(3), atol=1e-15)
        np.testing.assert_allclose(m[:, 3:] @ a, np.eye(3), atol=1e-14)
    singular = np.array([[1.0, 2.0], [2.0, 4.0 + 1e-15]])
    assert not gauss_jordan(np.hstack([singular, np.eye(2)]), 2, 1e-13 * 4.0, True)
    assert gauss_jordan(np.hstack([singular, np.eye(2)]), 2, 0.0, False)  # exact floor 0
