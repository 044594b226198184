"""The joint disturbance model at its boundary (``joint-local``): the sensor-noise variance
estimated without its bound at zero, its covariance with the variance the choice of ρ_c
adds, and the Monte Carlo behaviour under a single Gauss–Markov current."""

import numpy as np
import pytest
from _stats import binomial_ok, bonferroni_z
from scipy import integrate, stats

from vesselid.errors import IdentificationError
from vesselid.identify import from_arrays, identify, pem
from vesselid.identify.efficient import InstrumentalGMM
from vesselid.identify.registry import entry
from vesselid.plant.systems import heave
from vesselid.studies.calibration import heave_scenario

THETA0 = np.array([0.99, -0.1, 1.0])


def test_selection_weights_one_point_and_identical_points_add_nothing():
    assert pem._selection_weights(np.ones((1, 1))) == pytest.approx([1.0], rel=0.03)
    w = pem._selection_weights(np.ones((3, 3)))  # the same z three times
    assert w.sum() == pytest.approx(1.0, rel=0.03)


def test_selection_weights_of_independent_points_by_hand():
    """Two independent z: ``E[max(Z₁², Z₂²)] = ∫ (1 − F(t)²) dt`` (F the χ²₁ CDF),
    split evenly; the quadrature's error is that of the mean of 20 000 draws."""
    exact, _ = integrate.quad(lambda t: 1.0 - stats.chi2.cdf(t, 1) ** 2, 0, np.inf)
    w = pem._selection_weights(np.eye(2))
    draws = np.max(pem._normals(2) ** 2, axis=1)
    se = draws.std() / np.sqrt(draws.size)
    assert abs(w.sum() - exact) < 4 * se, (w, exact, se)
    assert abs(w[0] - w[1]) < 8 * se


def test_selection_weights_are_fixed_numbers():
    a = pem._selection_weights(np.array([[1.0, 0.5], [0.5, 1.0]]))
    pem._NORMALS.clear()
    b = pem._selection_weights(np.array([[1.0, 0.5], [0.5, 1.0]]))
    np.testing.assert_array_equal(a, b)


@pytest.mark.slow
@pytest.mark.parametrize("boundary", ["unbounded", "auto"])
def test_single_gauss_markov_current_unbiased_and_covered(boundary):
    """A Gauss–Markov current alone (calibration scenario, random pulses): ``auto`` with
    ``pem_boundary="unbounded"`` or the default ``"auto"`` (the current is Gaussian)
    takes the likelihood fallback; its estimate is within Bonferroni-corrected Monte
    Carlo standard errors of θ0 on every parameter and its 95 % intervals cover at a
    rate a binomial test accepts."""
    system, _, _ = heave_scenario("gm-current-random")
    spec = system.identification_spec(aggregate=False)
    runs = 80
    sim = system.simulate(10_000, n_runs=runs, seed=41)
    est = InstrumentalGMM(**{**entry("auto").options, "pem_boundary": boundary})
    it = est.estimate_parameters(from_arrays(spec, sim.y, sim.u), spec)
    assert (it.info["instrument_set"] == "pem").all()
    assert np.isin(it.info["pem_model"], ["joint-local", "joint", "current"]).all()
    assert (it.info["pem_model"] == "joint-local").mean() > 0.5
    err = it.theta - THETA0
    z = err.mean(0) / (err.std(0, ddof=1) / np.sqrt(runs))
    assert np.all(np.abs(z) < bonferroni_z(3)), z
    se = np.sqrt(np.einsum("gii->gi", it.info["pem_cov_conservative"]))
    hits = (np.abs(err) <= 1.959964 * se).sum(0)
    assert all(binomial_ok(int(h), runs, 0.95) for h in hits), hits


def test_bad_boundary_is_a_one_line_reason():
    log = heave().simulate(500, seed=1).to_log()
    with pytest.raises(IdentificationError, match="pem_boundary must be one of"):
        identify(log, method=InstrumentalGMM("auto", pem_boundary="none"))
    with pytest.raises(IdentificationError, match="boundary must be one of"):
        pem.fit_groups(None, None, np.zeros((1, 3)), boundary="open")
