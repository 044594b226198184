"""The paper's estimators as objects: least squares (16) and refined IV (4)/(6).

Both run on the compiled moment kernels of :mod:`vesselid.identify.estimators`
(one fused pass per refined-IV iteration over a whole Monte Carlo batch).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from vesselid.identify.backend import kernels
from vesselid.identify.base import Estimator, _UserInstrumentMixin, square_designs
from vesselid.identify.data import RegressionData
from vesselid.identify.estimators import IterationResult, estimate
from vesselid.model.spec import ModelSpec

__all__ = ["LeastSquares", "RefinedIV"]


class LeastSquares(Estimator):
    """Least squares (16): ``θ = (Σ φφᵀ)⁻¹ Σ φ y``; biased under errors in variables."""

    name: ClassVar[str] = "ls"
    label: ClassVar[str] = "least squares (16)"
    short: ClassVar[str] = "LS"
    plot_label: ClassVar[str] = "LS"
    uses_instruments: ClassVar[bool] = False

    def estimate_parameters(self, data: RegressionData, spec: ModelSpec, *,
                            combine: str = "pooled", theta_start: np.ndarray | None = None,
                            max_iter: int = 100, tol: float = 1e-9,
                            keep_history: bool = False) -> IterationResult:
        return estimate(data, spec, "ls", combine=combine)

    def equation_designs(self, data, spec, it, phi, combine):
        return square_designs(data, spec, phi, phi, it.theta[0], zero_mean=False,
                              combine=combine)


class RefinedIV(_UserInstrumentMixin, Estimator):
    """Refined instrumental variables, instruments simulated from the auxiliary model.

    Parameters
    ----------
    zero_mean : bool
        Subtract each instrument's mean per experiment (A7): the paper's IV_{E{ζ}=0},
        consistent under Lemma 3.1 (and Lemma 4.1 with an aggregated predictor (9)).
        ``False`` is the paper's plain "IV" row (biased when E{ζ} ≠ 0).
    """

    multi_experiment: ClassVar[tuple[str, ...]] = ("pooled", "stacked")

    def __init__(self, zero_mean: bool = True) -> None:
        super().__init__(zero_mean=zero_mean)
        self.zero_mean = bool(zero_mean)

    @property
    def name(self) -> str:  # type: ignore[override]
        return "iv-zero-mean" if self.zero_mean else "iv"

    @property
    def label(self) -> str:  # type: ignore[override]
        return ("refined IV, zero-mean instruments (IV_E{ζ}=0)" if self.zero_mean
                else "refined instrumental variables (4)/(6)")

    @property
    def short(self) -> str:  # type: ignore[override]
        return "IV_E{ζ}=0" if self.zero_mean else "IV"

    @property
    def plot_label(self) -> str:  # type: ignore[override]
        return "IV, E{ζ}=0" if self.zero_mean else "IV"

    def estimate_parameters(self, data: RegressionData, spec: ModelSpec, *,
                            combine: str = "pooled", theta_start: np.ndarray | None = None,
                            max_iter: int = 100, tol: float = 1e-9,
                            keep_history: bool = False) -> IterationResult:
        return estimate(data, spec, self.name, combine=combine, theta_start=theta_start,
                        max_iter=max_iter, tol=tol, keep_history=keep_history)

    def equation_designs(self, data, spec, it, phi, combine):
        codes = spec.codes
        z, _ = kernels.instrument_matrix(data.target, data.u, data.starts, it.theta_aux[0],
                                         codes.factors, codes.equation, spec.n_states)
        return square_designs(data, spec, z, phi, it.theta[0], zero_mean=self.zero_mean,
                              combine=combine, fixed_b=True)

    def describe(self, it: IterationResult) -> dict[str, Any]:
        return {"instruments": "simulated (auxiliary model)" + (
            ", zero-mean per experiment" if self.zero_mean else "")}
