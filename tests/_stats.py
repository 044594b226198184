"""Shared statistical helpers for tests: tolerances derived from the run count / standard
errors of the same run, never seed-tuned constants.

* :func:`binomial_ok` — is an observed count of successes compatible with probability
  ``p`` (two-sided exact binomial test at level ``alpha``)?
* :func:`wilson_interval` — Wilson score interval of a proportion.
* :func:`within_se` — is an estimate within ``k`` standard errors of its target?
"""

from __future__ import annotations

import numpy as np
from scipy import stats

__all__ = ["binomial_ok", "wilson_interval", "within_se"]


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
