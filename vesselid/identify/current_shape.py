"""Is the current inside the modulus Gaussian? A kurtosis test of its smoothed trace.

The prediction-error estimator (:mod:`vesselid.identify.pem`) predicts the modulus
``(x − v)|x − v|`` from a Gaussian conditional distribution of the current ``v``. A
switching ("telegraph", tidal-step) current has a bimodal one: the likelihood model is
then misspecified, and which of its fits is least biased is no longer a question the
likelihood answers (``scripts/robustness_study.py``). The innovations of the fitted model
do not show it (they are whitened: a switch shows only at the switch), but the current
itself does. The one-step residual of the current-model fit,

    r(k) = y(k+1) − θ̂ᵀ φ(y(k), u(k)),

carries ``−(a + 2 n |x(k)|) v(k)`` plus white noise; its moving average over the
current's time constant ``L`` (from the fitted ``ρ_v``) averages the white part away and
keeps the slow current. A Gauss–Markov current gives a Gaussian trace — a scale mixture
of Gaussians, through the gain ``a + 2n|x|``, so if anything leptokurtic — while a
current that jumps between levels gives a platykurtic (bimodal) one.

The statistic is the sample excess kurtosis ``κ̂`` of the smoothed trace standardised
with its variance under a Gaussian stationary series, ``Var κ̂ ≈ (24/T) Σ_j ρ_j⁴``
(Lomnicki 1961; Lobato & Velasco 2004 use it in their normality test for dependent
data), ``ρ_j`` the trace's sample autocorrelations. The test rejects a Gaussian current
for a bimodal one when ``z = κ̂ / sd(κ̂)`` is below ``−z_{1−α}`` (one-sided: heavy-tailed
sensor noise makes the trace leptokurtic, not bimodal).

Measured (``scripts/robustness_study.py`` designs, 200 runs × 10⁴ samples, α = 1 %):
rejects a single Gauss–Markov current and a Gauss–Markov current with Gauss–Markov
sensor noise in 0 % of runs (median ``z`` +2.1 and +1.6), a telegraph current ±0.06
switching w.p. 0.02 a sample in 100 % (median ``z`` −5.5).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.special import ndtr

__all__ = ["SHAPE_ALPHA", "kurtosis_z", "smoothed_current_test"]

#: Level of the one-sided test (a bimodal current against a Gaussian one).
SHAPE_ALPHA = 0.01
#: Longest smoothing window (samples): currents slower than this are smoothed over it.
MAX_WINDOW = 200


def kurtosis_z(x: np.ndarray) -> tuple[float, float]:
    """Excess kurtosis of the series ``x`` and its z-value under a Gaussian stationary
    series: ``κ̂ / sqrt((24/T)(1 + 2 Σ_{j≥1} ρ̂_j⁴))`` with the sample autocorrelations
    up to lag ``min(T − 1, 10 √T)``. ``(nan, nan)`` for fewer than 20 samples or a
    constant series."""
    x = np.asarray(x, dtype=float)
    t = x.size
    if t < 20:
        return float("nan"), float("nan")
    x = x - x.mean()
    m2 = float(np.mean(x * x))
    if not (m2 > 0 and np.isfinite(m2)):
        return float("nan"), float("nan")
    kappa = float(np.mean(x ** 4)) / (m2 * m2) - 3.0
    spec = np.fft.rfft(x, 2 * t)
    acf = np.fft.irfft(spec * np.conj(spec), 2 * t)[: t] / (t * m2)
    lags = int(min(t - 1, 10.0 * math.sqrt(t)))
    var = 24.0 / t * (1.0 + 2.0 * float(np.sum(acf[1: lags + 1] ** 4)))
    return kappa, kappa / math.sqrt(var)


def _moving_average(r: np.ndarray, window: int) -> np.ndarray:
    if r.size < window:
        return r[:0]
    c = np.concatenate([[0.0], np.cumsum(r)])
    return (c[window:] - c[:-window]) / window


def smoothed_current_test(residuals: list[np.ndarray], rho: float,
                          alpha: float = SHAPE_ALPHA) -> dict[str, Any]:
    """The test of the module docstring on one-step residuals (one array per
    experiment, no residual across experiments) of a current-model fit with the fitted
    current correlation ``rho``.

    Returns ``{"z", "kurtosis", "window", "pvalue", "bimodal"}``: the z-value, the
    excess kurtosis of the smoothed trace, the moving-average window (the time constant
    ``−1/ln ρ`` rounded, 1 to :data:`MAX_WINDOW`), the one-sided p-value and whether it is
    below ``alpha``. ``bimodal`` is False when the statistic is not finite."""
    rho = float(rho)
    if np.isfinite(rho) and 0.0 < rho < 1.0:
        window = int(min(MAX_WINDOW, max(1, round(-1.0 / math.log(rho)))))
    else:
        window = 1
    pieces = [_moving_average(np.asarray(r, dtype=float), window) for r in residuals]
    trace = np.concatenate([p - p.mean() for p in pieces if p.size]) if any(
        p.size for p in pieces) else np.empty(0)
    kappa, z = kurtosis_z(trace)
    p = float(ndtr(z)) if np.isfinite(z) else float("nan")
    return {"z": z, "kurtosis": kappa, "window": window, "pvalue": p,
            "bimodal": bool(np.isfinite(z) and p < alpha)}
