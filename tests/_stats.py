"""Shared statistical helpers for tests: tolerances derived from the run count / standard
errors of the same run, never seed-tuned constants.

* :func:`binomial_ok` — is an observed count of successes compatible with probability
  ``p`` (two-sided exact binomial test at level ``alpha``)?
* :func:`wilson_interval` — Wilson score interval of a proportion.
* :func:`within_se` — is an estimate within ``k`` standard errors of its target?
* :func:`ar1_mean_se` — standard error of the sample mean of a stationary AR(1) series.
* :func:`std_se` — standard error of a sample standard deviation (Gaussian, AR(1)).
* :func:`assert_mean_within` / :func:`assert_std_within` — the two checks above, with
  a message that shows the derived tolerance.
* :func:`log_sd_ratio_se` — standard error of ``log(s₁/s₂)`` of two independent samples
  (any kurtosis); :func:`bonferroni_z` — the two-sided critical value for ``m`` tests.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

__all__ = [
    "ar1_mean_se",
    "assert_mean_within",
    "assert_std_within",
    "binomial_ok",
    "bonferroni_z",
    "log_sd_ratio_se",
    "std_se",
    "wilson_interval",
    "within_se",
]


def binomial_ok(successes: int, trials: int, p: float, alpha: float = 1e-3) -> bool:
    """Two-sided exact binomial test: True unless ``successes`` of ``trials`` rejects
    the success probability ``p`` at level ``alpha``."""
    return bool(stats.binomtest(int(successes), int(trials), float(p)).pvalue > alpha)


def wilson_interval(successes: int, trials: int, level: float = 0.95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion."""
    z = stats.norm.ppf(0.5 + level / 2)
    n = float(trials)
    ph = successes / n
    den = 1 + z**2 / n
    centre = (ph + z**2 / (2 * n)) / den
    half = z * np.sqrt(ph * (1 - ph) / n + z**2 / (4 * n**2)) / den
    return float(centre - half), float(centre + half)


def within_se(estimate: float, target: float, se: float, k: float = 4.0) -> bool:
    """``|estimate − target| ≤ k · se`` (``se`` from the same run)."""
    return bool(abs(float(estimate) - float(target)) <= k * float(se))


def ar1_mean_se(std: float, pole: float, n: int) -> float:
    """Standard error of the mean of ``n`` samples of a stationary AR(1) with standard
    deviation ``std`` and pole ``a`` (lag-k correlation ``aᵏ``)::

        Var(x̄) = σ²/n · [(1 + a)/(1 − a) − 2a(1 − aⁿ) / (n (1 − a)²)]

    (``a = 0``: the white-noise ``σ/√n``).
    """
    a, n = float(pole), int(n)
    factor = (1 + a) / (1 - a) - 2 * a * (1 - a**n) / (n * (1 - a) ** 2)
    return float(std) * float(np.sqrt(factor / n))


def std_se(std: float, n: int, pole: float = 0.0) -> float:
    """Large-sample standard error of the sample standard deviation of ``n`` Gaussian
    samples, white (``σ/√(2n)``) or AR(1) with pole ``a`` (× √((1 + a²)/(1 − a²)))."""
    a = float(pole)
    return float(std) * float(np.sqrt((1 + a * a) / (1 - a * a) / (2 * int(n))))


def assert_mean_within(samples, target: float, *, k: float = 5.0, pole: float = 0.0,
                       std: float | None = None) -> None:
    """Assert the sample mean is within ``k`` standard errors of ``target``; the SE is
    derived from the same samples (their std, or ``std``) and the AR(1) ``pole``."""
    x = np.asarray(samples, dtype=float).ravel()
    sd = float(np.std(x, ddof=1)) if std is None else float(std)
    se = ar1_mean_se(sd, pole, x.size)
    assert within_se(x.mean(), target, se, k), (
        f"mean {x.mean():.6g} not within {k} SE ({se:.3g}) of {target:.6g}")


def assert_std_within(samples, target: float, *, k: float = 5.0, pole: float = 0.0) -> None:
    """Assert the sample std is within ``k`` standard errors (:func:`std_se`) of ``target``."""
    x = np.asarray(samples, dtype=float).ravel()
    se = std_se(target, x.size, pole)
    assert within_se(x.std(), target, se, k), (
        f"std {x.std():.6g} not within {k} SE ({se:.3g}) of {target:.6g}")


def log_sd_ratio_se(kurtosis: float, n1: int, n2: int) -> float:
    """Large-sample standard error of ``log(s₁ / s₂)`` for two independent samples of
    sizes ``n1``, ``n2`` from distributions with (non-excess) ``kurtosis`` κ:
    ``Var(log s) ≈ (κ − 1) / (4n)`` per sample (delta method; κ = 3: ``1/(2n)``)."""
    k = float(kurtosis)
    return float(np.sqrt((k - 1.0) / (4.0 * int(n1)) + (k - 1.0) / (4.0 * int(n2))))


def bonferroni_z(m: int, alpha: float = 1e-3) -> float:
    """Two-sided normal critical value that keeps the family-wise level ``alpha`` over
    ``m`` comparisons."""
    return float(stats.norm.ppf(1.0 - float(alpha) / (2.0 * max(int(m), 1))))
