"""Seeded noise processes: moments, bounds, determinism, serialisation."""

import math

import numpy as np
import pytest
from _stats import assert_mean_within, assert_std_within, within_se

from vesselid.errors import VesselidError
from vesselid.plant.disturbances import (
    Constant,
    Gaussian,
    GaussMarkov,
    TruncatedGaussian,
    Uniform,
    Zero,
    process_from_dict,
)
from vesselid.plant.signals import PRBS, Multisine, RandomPulses, StaticOffset, input_from_dict

N = 200_000


def draw(p, seed=0, n=N):
    return p.sample(np.random.default_rng(seed), n)


@pytest.mark.parametrize(
    "process",
    [
        Gaussian(0.1, 0.1),
        Gaussian.from_variance(-0.05, 0.01),
        Uniform(0.2, 0.5),
        TruncatedGaussian(0.0, 0.1, 0.2),
        GaussMarkov(0.3, 0.05, time_constant=20.0),
        GaussMarkov(0.0, 0.05, time_constant=20.0, bound=0.1),
        Constant(0.1) + Gaussian(0, 0.02),
    ],
)
def test_moments_and_bounds(process):
    x = draw(process)
    # SEs of the mean and std derived for the process (an AR(1) for Gauss–Markov)
    pole = process.pole if isinstance(process, GaussMarkov) else 0.0
    assert_mean_within(x, process.mean, std=process.std, pole=pole)
    assert_std_within(x, process.std, pole=pole)
    if math.isfinite(process.bound):
        assert np.all(np.abs(x - process.mean) <= process.bound)
    np.testing.assert_array_equal(x, draw(process))
    assert process_from_dict(process.to_dict()) == process


def test_gauss_markov_is_coloured():
    x = draw(GaussMarkov(0, 1, time_constant=10.0))
    lag1 = np.corrcoef(x[:-1], x[1:])[0, 1]
    rho = math.exp(-0.1)
    # Bartlett: SE of the lag-1 autocorrelation of an AR(1) is √((1 − ρ²)/N), white 1/√N
    assert within_se(lag1, rho, math.sqrt((1 - rho**2) / N), k=5)
    white = draw(Gaussian(0, 1))
    assert within_se(np.corrcoef(white[:-1], white[1:])[0, 1], 0.0, 1 / math.sqrt(N), k=5)


def test_zero_and_sum():
    assert np.all(draw(Zero(), n=10) == 0)
    assert (Zero() + Zero()).is_zero
    s = Constant(1.0) + Constant(2.0)
    assert np.all(draw(s, n=5) == 3.0)


def test_bad_parameters():
    with pytest.raises(VesselidError):
        Gaussian(0, -1)
    with pytest.raises(VesselidError):
        GaussMarkov(0, 1, time_constant=0)
    with pytest.raises(ValueError):
        process_from_dict({"kind": "nope"})


def test_random_pulses():
    p = RandomPulses(0.1, 0.3, 10, 100)
    u = draw(p, n=20_000)
    assert u.min() >= 0.1 and u.max() <= 0.3
    change = np.flatnonzero(np.diff(u) != 0)
    widths = np.diff(change)
    assert widths.min() >= 10 and widths.max() <= 100
    assert input_from_dict(p.to_dict()) == p
    with pytest.raises(VesselidError):
        RandomPulses(0.3, 0.1)


def test_static_offset_prbs_multisine():
    s = StaticOffset(1.0, Uniform(0, 0.5))
    u = draw(s, n=10_000)
    assert u.min() >= 0.5
    assert_mean_within(u, 1.0)  # white: SE = std/√n from the same draw
    prbs = draw(PRBS(-1, 1, nbits=7, hold=3), n=3000)
    assert set(np.unique(prbs)) == {-1.0, 1.0}
    assert np.all(prbs[0::3][:100] == prbs[1::3][:100])
    ms = Multisine((0.01, 0.05), 0.5, offset=2.0)
    m = draw(ms, n=10_000)
    # a finite sum of a sinusoid is at most 1/|sin(πf)| (geometric series), so the mean of
    # n samples is within Σ a / (n |sin(πf)|) of the offset; the peak is at most 2 + Σ a
    bound = np.sum(0.5 / (m.size * np.abs(np.sin(np.pi * np.array([0.01, 0.05])))))
    assert abs(m.mean() - 2.0) <= bound and m.max() <= 3.0
    for design in (s, PRBS(-1, 1, 7, 3), ms):
        assert input_from_dict(design.to_dict()).to_dict() == design.to_dict()


def test_ar1_filter_is_lfilter_bit_for_bit() -> None:
    from scipy import signal as sps

    from vesselid.core.filters import ar1_filter

    rng = np.random.default_rng(5)
    x = rng.standard_normal((4, 3000))
    y0 = rng.standard_normal(4)
    for a in (0.0, 0.5, 0.999):
        ref = sps.lfilter([1.0], [1.0, -a], x, axis=1, zi=(a * y0)[:, None])[0]
        assert np.array_equal(ar1_filter(x, a, a * y0), ref)
