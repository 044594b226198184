"""The identification results object (after linearmodels' ``iv/results.py``)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import pandas as pd

from vesselid.errors import IdentificationError
from vesselid.model import ModelSpec

__all__ = ["IdentificationResult"]

METHOD_LABELS = {
    "ls": "least squares (16)",
    "iv": "refined instrumental variables (4)/(6)",
    "iv-zero-mean": "refined IV, zero-mean instruments (IV_E{ζ}=0)",
}


@dataclass
class IdentificationResult:
    """Estimates of a second-order modulus model with their diagnostics.

    Attributes
    ----------
    params : Series
        Estimates indexed by ``(equation, term)``.
    cov : DataFrame
        Asymptotic covariance of the estimates (block-diagonal per equation),
        computed under the usual white-equation-error assumption
        (``σ² A⁻¹ ZᵀZ A⁻ᵀ`` for IV, ``σ² (ΦᵀΦ)⁻¹`` for LS; a sandwich for the
        stacked multi-experiment form).
    residuals : DataFrame
        One-step prediction errors ``y(k) − φᵀ(k)θ̂`` per state (NaN at the first
        sample of each experiment, which has no predecessor).
    converged, iterations, stop_reason
        Outcome of the refined-IV iteration (LS: closed form).
    diagnostics : dict
        ``design`` (A10/A15 margins per experiment and state), ``instrument_condition``
        (per equation), ``fit_one_step`` / ``fit_free_run`` (NRMSE %, per state),
        ``oscillation``, ``fixed_point_residual``, ``combine``, warnings raised.
    """

    method: str
    spec: ModelSpec
    params: pd.Series
    cov: pd.DataFrame
    residuals: pd.DataFrame
    converged: bool
    iterations: int
    stop_reason: str
    n_samples: int
    n_experiments: int
    diagnostics: dict[str, Any] = field(default_factory=dict)
    history: pd.DataFrame | None = None

    @cached_property
    def std_errors(self) -> pd.Series:
        """Standard errors (square root of the covariance diagonal)."""
        return pd.Series(np.sqrt(np.clip(np.diag(self.cov.to_numpy()), 0, None)),
                         index=self.params.index, name="std_error")

    def conf_int(self, level: float = 0.95) -> pd.DataFrame:
        """Normal-approximation confidence intervals."""
        if not 0 < level < 1:
            raise IdentificationError("level must be in (0, 1)")
        from scipy.special import ndtri  # = stats.norm.ppf, without importing scipy.stats

        q = ndtri(0.5 + level / 2)
        return pd.DataFrame({"lower": self.params - q * self.std_errors,
                             "upper": self.params + q * self.std_errors})

    def compare(self, theta0: Any | None = None) -> pd.DataFrame:
        """Estimates against true values with the paper's normalised error ``(θ̂ − θ0)/θ0``.

        ``theta0`` defaults to the spec's θ0; a Series, mapping or array is accepted.
        """
        if theta0 is None:
            truth = self.spec.theta0_series()
        else:
            truth = pd.Series(self.spec.vector_from(theta0), index=self.params.index)
        out = pd.DataFrame({"estimate": self.params, "theta0": truth,
                            "std_error": self.std_errors})
        with np.errstate(divide="ignore", invalid="ignore"):
            out["normalized_error"] = (out["estimate"] - out["theta0"]) / out["theta0"]
            out["error_in_std_errors"] = (out["estimate"] - out["theta0"]) / out["std_error"]
        return out

    @property
    def instrument_condition(self) -> dict[str, float]:
        return dict(self.diagnostics.get("instrument_condition", {}))

    def summary(self) -> str:
        """A readable table of estimates, standard errors and diagnostics."""
        ci = self.conf_int()
        table = pd.DataFrame({
            "estimate": self.params,
            "std_error": self.std_errors,
            "ci_lower": ci["lower"],
            "ci_upper": ci["upper"],
        })
        if self.spec.theta0 is not None:
            cmp = self.compare()
            table["theta0"] = cmp["theta0"]
            table["norm_error"] = cmp["normalized_error"]
        lines = [
            f"Model {self.spec.name!r} — {METHOD_LABELS.get(self.method, self.method)}",
            f"experiments: {self.n_experiments}   samples: {self.n_samples}   "
            f"combine: {self.diagnostics.get('combine', 'pooled')}",
            f"converged: {self.converged}   iterations: {self.iterations}   "
            f"stop: {self.stop_reason}",
        ]
        if self.spec.aggregate:
            lines.append("aggregated-state predictor (9): "
                         + ", ".join(str(a) for a in self.spec.aggregate.values()))
        lines.append("")
        with pd.option_context("display.float_format", "{:.6g}".format,
                               "display.width", 120):
            lines.append(table.to_string())
        lines.append("")
        fit1 = self.diagnostics.get("fit_one_step", {})
        fitf = self.diagnostics.get("fit_free_run", {})
        for s in self.spec.states:
            lines.append(f"fit {s}: one-step {fit1.get(s, float('nan')):.2f} %   "
                         f"free-run {fitf.get(s, float('nan')):.2f} %   "
                         f"cond(ZᵀΦ) {self.instrument_condition.get(s, float('nan')):.3g}")
        design = self.diagnostics.get("design")
        if isinstance(design, pd.DataFrame) and not design.empty:
            bad = design[~design["ok"]]
            if bad.empty:
                lines.append("experiment design (A10/A15): every state under a modulus keeps "
                             "its margin in every experiment")
            else:
                for _, r in bad.iterrows():
                    lines.append(
                        f"experiment design (A10/A15): state {r['state']} in experiment "
                        f"{r['experiment']} is within η={r['eta']:.3g} of zero in "
                        f"{100 * r['share_within_eta']:.1f} % of samples "
                        f"({r['sign_changes']} sign changes)")
        from vesselid.identify.specification import summary_lines

        lines.extend(summary_lines(self.diagnostics.get("specification", {})))
        for s_name, lb in self.diagnostics.get("whiteness", {}).items():
            lines.append(f"whiteness {s_name}: {lb.get('sentence', '')}")
        for w in self.diagnostics.get("warnings", []):
            lines.append(f"warning: {w}")
        return "\n".join(lines)

    def plot_residuals(self, *, title: str | None = None):
        """MATLAB ``resid``-style figure: residual autocorrelation and residual–input
        cross-correlation with confidence bands (:func:`vesselid.plots.residual_analysis`).

        Returns a matplotlib ``Figure`` (save it with ``fig.savefig``).
        """
        from vesselid.plots import residual_analysis

        rc = self.diagnostics.get("residual_correlation")
        if rc is None:
            raise IdentificationError("this result holds no residual correlations "
                                      "(diagnostics['residual_correlation'])")
        return residual_analysis(rc, title=title or f"Residual analysis — {self.method}")

    def __str__(self) -> str:
        return self.summary()

    def _per_state(self, series: pd.Series) -> dict[str, dict[str, float]]:
        out: dict[str, dict[str, float]] = {}
        for (eq, term), value in series.items():
            out.setdefault(eq, {})[term] = float(value)
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (docs/architecture.md ``identify --json`` contract)."""
        design = self.diagnostics.get("design")
        diag: dict[str, Any] = {
            k: v for k, v in self.diagnostics.items() if k not in ("design",)
        }
        if isinstance(design, pd.DataFrame):
            diag["design"] = json.loads(design.to_json(orient="records"))
        return {
            "method": self.method,
            "params": self._per_state(self.params),
            "stderr": self._per_state(self.std_errors),
            "converged": bool(self.converged),
            "iterations": int(self.iterations),
            "stop_reason": self.stop_reason,
            "experiments": int(self.n_experiments),
            "samples": int(self.n_samples),
            "diagnostics": _jsonable(diag),
        }

    def to_json(self, **kwargs: Any) -> str:
        from vesselid._io import strict_json

        return strict_json(self.to_dict(), **({"indent": 2} | kwargs))


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    return obj
