"""Fixed-b critical values for Bartlett-HAC intervals of a GMM estimate, at the
design's effective bandwidth ratio.

A HAC long-run variance is computed from *estimated* scores
``ĝ(k) = z(k) ε̂(k) = g(k) − z(k) φ(k)ᵀ (θ̂ − θ)``: the estimation error enters every
score, and the kernel sums it over its window, so the variance shrinks exactly when the
estimate is far from θ (a log whose error is large reports a small standard error). In
the fixed-b asymptotics of Kiefer & Vogelsang (2005) this is the Brownian bridge in the
limit of the t statistic; its 97.5 % quantile grows with the ratio ``b = M/T`` of the
Bartlett bandwidth ``M = L + 1`` (``L`` lags) to the sample size.

On a short log whose instruments are persistent (input pulses tens of samples wide)
the shrinkage is far stronger than ``M/T`` says: the product ``z(k) φ(k)ᵀ`` that
carries the estimation error into the scores is concentrated in a few pulses. Its
size for parameter ``p`` is measured directly: with ``ℓ_p`` the row of the influence
matrix (``θ̂ − θ ≈ L Σ g``, Windmeijer's ``C + D C₁``) and ``u_p = V_{·p}/V_pp`` (the
direction in which the other estimates move with ``θ̂_p``), the HAC variance of
``θ̂_p`` evaluated at residuals ``d`` away from ``θ̂_p`` along ``u_p`` is
``V_pp + α d + b_p d²`` with

    b_p = Σ_{k,l} w(k − l) s(k) s(l),   s(k) = ℓ_pᵀ z(k) φ(k)ᵀ u_p,

the same Bartlett weights ``w`` (per experiment); ``Σ_k s(k) = ((I + D) u_p)_p``, 1 for
a fixed weight. With a constant ``z φᵀ`` it is
``M/T`` up to ``O(M²/T²)``: the fixed-b ratio; it is the *effective* ratio otherwise.
The reported interval uses the Kiefer–Vogelsang (2005) Bartlett critical value at
``b_p`` (their cubic fit of the quantile, valid for ``0 ≤ b ≤ 1``): the covariance
scales each standard error by ``q(b_p)/1.96``
(:meth:`vesselid.identify.covariance.CovarianceEstimator.estimate`), for two-step GMM
estimates (``gmm``, ``auto`` with the delayed instruments; influence ``C + D C₁``) and
the just-identified IV estimates (influence ``A⁻¹``): ``sriv`` (``auto``'s fallback),
the refined IV ``iv-zero-mean`` / ``iv`` (and IV with given instruments) and the
closed-loop refined IV ``cl-iv``. Evidence: ``scripts/robustness_study.py`` (short logs),
``scripts/calibration.py``, ``scripts/closed_loop_study.py`` and
``tests/test_fixedb.py`` (refined IV on short logs).
"""

from __future__ import annotations

import numpy as np

from vesselid.identify.movingsums import moving_sums

__all__ = [
    "BARTLETT_QUANTILES",
    "bartlett_critical_value",
    "bartlett_cross",
    "critical_scaling",
    "effective_b",
    "influence_directions",
]

#: Kiefer & Vogelsang (2005, Table 1 fit): quantile ``q(b) = a0 + a1 b + a2 b² + a3 b³``
#: of the fixed-b limit of the Bartlett-HAC t statistic, per upper-tail probability
#: ``1 − level`` of the one-sided quantile (two-sided 95 % intervals use 0.975).
BARTLETT_QUANTILES: dict[float, tuple[float, float, float, float]] = {
    0.90: (1.2816, 1.3040, 0.5135, -0.3386),
    0.95: (1.6449, 2.1859, 0.3142, -0.3427),
    0.975: (1.9600, 2.9694, 0.4160, -0.5324),
    0.99: (2.3263, 4.1618, 0.5368, -0.9060),
}


def bartlett_critical_value(b: np.ndarray | float, quantile: float = 0.975) -> np.ndarray:
    """Fixed-b critical value of the Bartlett-HAC t statistic at bandwidth ratio ``b``
    (clipped to ``[0, 1]``; ``b = 0`` gives the normal quantile).

    Parameters
    ----------
    b : float or ndarray
        Bandwidth ratio ``M/T`` (or the effective ratio of :func:`effective_b`).
    quantile : {0.90, 0.95, 0.975, 0.99}
        One-sided quantile (0.975: two-sided 95 % intervals).
    """
    if quantile not in BARTLETT_QUANTILES:
        raise ValueError(f"quantile must be one of {sorted(BARTLETT_QUANTILES)}, got {quantile}")
    a0, a1, a2, a3 = BARTLETT_QUANTILES[quantile]
    b = np.clip(np.nan_to_num(np.asarray(b, dtype=float), nan=0.0), 0.0, 1.0)
    return a0 + b * (a1 + b * (a2 + b * a3))


def critical_scaling(b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 95 % fixed-b critical values ``q(b)`` at the effective bandwidth ratios ``b``
    and the factors ``q(b)/1.96`` that scale the standard errors to them."""
    crit = bartlett_critical_value(b)
    return crit, crit / BARTLETT_QUANTILES[0.975][0]


def bartlett_cross(x: np.ndarray, y: np.ndarray, lags: int,
                   segments: list[slice]) -> np.ndarray:
    """``Σ_E Σ_{k,l ∈ E} (1 − |k − l|/(L + 1))₊ x(k, j) y(l, j)`` per column ``j``.

    From moving sums ``h(t) = Σ_{i=0}^{L} x(t − i)`` of each zero-padded experiment:
    ``Σ_t h_x(t) h_y(t) = Σ_{k,l} (L + 1 − |k − l|)₊ x(k) y(l)``.

    Parameters
    ----------
    x, y : ndarray (T, m)
        Series, rows of all experiments concatenated.
    lags : int
        Bartlett lags ``L ≥ 0``.
    segments : list of slice
        Rows of each experiment (the kernel never crosses a boundary).
    """
    lags = int(lags)
    out = np.zeros(x.shape[1])
    for s in segments:
        # time-major rows, as the sums below have always been taken
        hx = np.ascontiguousarray(moving_sums(x[s].T, lags).T)
        hy = hx if y is x else np.ascontiguousarray(moving_sums(y[s].T, lags).T)
        out += np.einsum("tj,tj->j", hx, hy)
    return out / (lags + 1.0)


def influence_directions(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``u_p = V_{·p}/V_pp`` of :func:`effective_b` (columns), and which parameters have
    a positive finite variance."""
    diag = np.diag(cov)
    ok = np.isfinite(diag) & (diag > 0)
    u = np.where(ok[None, :], cov / np.where(ok, diag, 1.0)[None, :], 0.0)
    return u, ok


def effective_b(zl: list[np.ndarray] | np.ndarray, phi: np.ndarray, cov: np.ndarray,
                param_eq: np.ndarray, lags: int, segments: list[slice]) -> np.ndarray:
    """Effective Bartlett bandwidth ratio ``b_p`` of every parameter (module docstring).

    Parameters
    ----------
    zl : list of ndarray (T, P), or ndarray (T, P)
        Per equation ``e``: ``z(k)[cols_e] · ℓ_p[cols_e]`` for every parameter ``p``
        (the instruments of that equation projected on the influence rows); one array
        when each ``ℓ_p`` is zero outside its own equation's instruments (column ``p``:
        ``z(k) · ℓ_p``).
    phi : ndarray (T, P)
        Regressors in the units of ``cov``, centred per experiment where the residuals
        are.
    cov : ndarray (P, P)
        Covariance of the estimate (``L S Lᵀ``).
    param_eq : ndarray (P,)
        Equation of each parameter.
    lags, segments
        Bartlett lags and experiment rows of the HAC.
    """
    u, ok = influence_directions(cov)
    s = np.zeros((phi.shape[0], cov.shape[0]))
    if isinstance(zl, np.ndarray):
        for e in np.unique(param_eq):
            cols = param_eq == e
            s[:, cols] = zl[:, cols] * (phi[:, cols] @ u[np.ix_(cols, cols)])
    else:
        for e, zle in enumerate(zl):
            cols = param_eq == e
            s += zle * (phi[:, cols] @ u[cols])
    b = bartlett_cross(s, s, lags, segments)
    return np.where(ok & np.isfinite(b), b, 0.0)
