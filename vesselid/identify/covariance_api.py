"""Call site of the covariance estimators (``cov_type``) for the checked ``fit`` path.

The covariance estimators themselves live in :mod:`vesselid.identify.covariance`
(registry ``COVARIANCE_ESTIMATORS``). This module resolves a name to a function of
one :class:`~vesselid.identify.base.EquationDesign`, so estimators never need to
know which covariance estimator is used. ``unadjusted`` (white, homoskedastic
equation error) is always available here as well, as the reference.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from vesselid.errors import IdentificationError

__all__ = ["available", "default_cov_type", "resolve", "unadjusted"]


def _registry() -> dict[str, Any]:
    try:
        from vesselid.identify import covariance
    except ImportError:
        return {}
    return dict(getattr(covariance, "COVARIANCE_ESTIMATORS", {}))


def available() -> list[str]:
    """Names accepted by ``cov_type`` (``--cov``)."""
    names = list(_registry())
    if "unadjusted" not in names:
        names.insert(0, "unadjusted")
    return names


def default_cov_type() -> str:
    """The package default covariance estimator."""
    try:
        from vesselid.identify import covariance
    except ImportError:
        return "unadjusted"
    return str(getattr(covariance, "DEFAULT_COV_TYPE", "unadjusted"))


def unadjusted(design: Any, *, combine: str = "pooled") -> np.ndarray:
    """``σ² (AᵀWA)⁻¹ AᵀW ZᵀZ W A (AᵀWA)⁻¹`` with ``A = ZᵀΦ`` (``W = I``, ``K = P``: the
    classical ``σ² A⁻¹ ZᵀZ A⁻ᵀ``); ``combine="stacked"`` gives the sandwich of the
    stacked equations (6)/(10). White, homoskedastic equation error assumed."""
    z, phi, resid, starts = design.z, design.phi, design.resid, design.starts
    p = phi.shape[1]
    ok = np.isfinite(resid)
    sigma2 = float(np.mean(resid[ok] ** 2)) if ok.any() else float("nan")
    segs = [slice(int(starts[s]), int(starts[s + 1])) for s in range(starts.size - 1)]
    a_list = [z[sl].T @ phi[sl] for sl in segs]
    m_list = [z[sl].T @ z[sl] for sl in segs]
    n_list = [sl.stop - sl.start for sl in segs]
    a_sum = np.sum(a_list, axis=0)
    m_sum = np.sum(m_list, axis=0)
    try:
        if combine == "stacked" and len(a_list) > 1:
            h = sum(a.T @ a / n**2 for a, n in zip(a_list, n_list, strict=True))
            meat = sum(a.T @ m @ a / n**4 for a, m, n in zip(a_list, m_list, n_list,
                                                            strict=True))
            h_inv = np.linalg.inv(h)
            return sigma2 * h_inv @ meat @ h_inv
        if a_sum.shape[0] == p:
            a_inv = np.linalg.inv(a_sum)
            return sigma2 * a_inv @ m_sum @ a_inv.T
        w = design.weight if design.weight is not None else np.linalg.inv(m_sum)
        bread = np.linalg.inv(a_sum.T @ w @ a_sum)
        return sigma2 * bread @ a_sum.T @ w @ m_sum @ w @ a_sum @ bread
    except np.linalg.LinAlgError:
        return np.full((p, p), np.nan)


def resolve(cov_type: str | None, cov_config: Mapping[str, Any] | None = None
            ) -> tuple[str, Callable[..., tuple[np.ndarray, str]]]:
    """``(name, function(design, combine=...) -> (covariance (P, P), label))``."""
    name = default_cov_type() if cov_type is None else cov_type
    config = dict(cov_config or {})
    try:
        from vesselid.identify import covariance
    except ImportError:
        covariance = None  # type: ignore[assignment]
    if covariance is None:
        if name != "unadjusted" or config:
            raise IdentificationError(f"unknown cov_type {name!r} or options; choose from "
                                      f"{available()}")
        return name, lambda design, combine="pooled": (unadjusted(design, combine=combine),
                                                       "unadjusted")
    if name not in covariance.COVARIANCE_ESTIMATORS:
        raise IdentificationError(f"unknown cov_type {name!r}; choose from {available()}")
    try:
        est = covariance.get_covariance_estimator(name, **config)
    except (TypeError, ValueError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise IdentificationError(f"cov_type {name!r}: {msg}") from None

    def fn(design: Any, *, combine: str = "pooled") -> tuple[np.ndarray, str]:
        res = est.estimate(design.z, design.phi, design.resid, design.starts,
                           weight=design.weight, zero_mean=design.zero_mean, combine=combine,
                           skip_first=False,
                           weight_jacobian=getattr(design, "weight_jacobian", None),
                           fixed_b_square=bool(getattr(design, "fixed_b", False)))
        return np.asarray(res.cov, dtype=float), str(res.label)

    return name, fn
