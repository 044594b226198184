"""The identification results object (after linearmodels' ``iv/results.py``)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import pandas as pd

from vesselid.core.jsonio import strict
from vesselid.errors import IdentificationError
from vesselid.identify.diagnostics import normalized_error
from vesselid.model.spec import ModelSpec

__all__ = ["IdentificationResult"]


@dataclass
class IdentificationResult:
    """Estimates of a second-order modulus model with their diagnostics.

    Attributes
    ----------
    params : Series
        Estimates indexed by ``(equation, term)``.
    cov : DataFrame
        Asymptotic covariance of the estimates (block-diagonal per equation), from
        the covariance estimator named in ``diagnostics["cov_type"]`` (``unadjusted``:
        white equation error, ``σ² A⁻¹ ZᵀZ A⁻ᵀ`` for IV, ``σ² (ΦᵀΦ)⁻¹`` for LS, a
        sandwich for the stacked multi-experiment form).
    residuals : DataFrame
        One-step prediction errors ``y(k) − φᵀ(k)θ̂`` per state (NaN at the first
        sample of each experiment, which has no predecessor).
    converged, iterations, stop_reason
        Outcome of the refined-IV iteration (LS: closed form).
    diagnostics : dict
        ``design`` (A10/A15 margins per experiment and state), ``instrument_condition``
        (per equation), ``fit_one_step`` / ``fit_free_run`` (NRMSE %, per state),
        ``oscillation``, ``fixed_point_residual``, ``combine``, warnings raised.
    label : str
        The estimator's long label (set by the estimator that made the result, so this
        module needs no registry; empty: the method name is shown).
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
    label: str = ""

    @cached_property
    def std_errors(self) -> pd.Series:
        """Standard errors (square root of the covariance diagonal)."""
        return pd.Series(np.sqrt(np.clip(np.diag(self.cov.to_numpy()), 0, None)),
                         index=self.params.index, name="std_error")

    def conf_int(self, level: float = 0.95) -> pd.DataFrame:
        """Normal-approximation confidence intervals."""
        if not 0 < level < 1:
            raise IdentificationError("level must be in (0, 1)")
        from vesselid.identify._special import norm_ppf  # = stats.norm.ppf, light imports

        q = norm_ppf(0.5 + level / 2)
        return pd.DataFrame({"lower": self.params - q * self.std_errors,
                             "upper": self.params + q * self.std_errors})

    def to_control(self, **kwargs: Any) -> Any:
        """The identified model as a discrete-time python-control ``NonlinearIOSystem``.

        See :func:`vesselid.model.export.to_control` (keyword arguments ``dt``, ``name``).
        """
        from vesselid.model.export import to_control

        return to_control(self.spec, self.params, **kwargs)

    def export(self, path: Any, **kwargs: Any) -> Any:
        """Write the spec with θ̂ (as θ0), standard errors and covariance; atomic.

        See :func:`vesselid.model.export.export_model`; ``ModelSpec.load`` reads it back.
        """
        from vesselid.model.export import export_model

        return export_model(self, path, **kwargs)

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
            out["normalized_error"] = normalized_error(out["estimate"], out["theta0"])
            out["error_in_std_errors"] = (out["estimate"] - out["theta0"]) / out["std_error"]
        return out

    @property
    def status(self) -> str:
        """``"ok"``, ``"not converged"``, ``"unstable"`` or ``"non-finite"`` (NaN/inf
        parameters or fit figures): only ``"ok"`` is a usable model; :attr:`status_reason`
        says why in one line (``vesselid identify`` exits 3 on the last two)."""
        return self._status()[0]

    @property
    def status_reason(self) -> str:
        """One line: why :attr:`status` is what it is."""
        return self._status()[1]

    def _status(self) -> tuple[str, str]:
        bad = [f"{eq}: {t}" for (eq, t), v in self.params.items() if not np.isfinite(v)]
        if bad:
            return "non-finite", "non-finite parameters (" + ", ".join(bad[:4]) + ")"
        figs = [f"{kind} fit of {st}"
                for kind, key in (("one-step", "fit_one_step"), ("free-run", "fit_free_run"))
                for st, v in self.diagnostics.get(key, {}).items() if not np.isfinite(v)]
        stab = self.diagnostics.get("stability") or {}
        if stab and not stab.get("stable", True):
            return "unstable", "the identified model is " + str(stab.get("sentence"))
        if figs:
            return "non-finite", "non-finite fit figures (" + ", ".join(figs) + ")"
        if not self.converged:
            return "not converged", f"the estimator did not converge ({self.stop_reason})"
        return "ok", "converged, finite and stable on the log"

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
            f"Model {self.spec.name!r} — {self.label or self.method}",
            f"experiments: {self.n_experiments}   samples: {self.n_samples}   "
            f"combine: {self.diagnostics.get('combine', 'pooled')}   "
            f"target: {self.diagnostics.get('target', 'measured')}",
            f"covariance: {self.diagnostics.get('cov_label', 'unadjusted')}",
            f"converged: {self.converged}   iterations: {self.iterations}   "
            f"stop: {self.stop_reason}",
            f"status: {self.status} — {self.status_reason}",
        ]
        chain = self.diagnostics.get("fallback_chain") or []
        if len(chain) > 1:
            lines.append("fallback chain: " + " → ".join(
                f"{t['method']} ({t['outcome']})" for t in chain))
            lines.extend(f"  {t['method']}: {t['outcome']} — {t['reason']}" for t in chain)
        # auto's plain sentence of its choice stands in for the instrument-choice detail
        choice = "choice_reason" if self.diagnostics.get("choice_reason") else "instrument_choice"
        for key in ("instruments", "noise_model", choice, "assumption",
                    "sensor_noise_correction"):
            if self.diagnostics.get(key) not in (None, "none"):
                lines.append(f"{key.replace('_', ' ')}: {self.diagnostics[key]}")
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
        stab = self.diagnostics.get("stability")
        if stab:
            lines.append(f"stability: {stab.get('sentence', '')}")
        for sentence in (self.diagnostics.get("excitation") or {}).get("sentences", []):
            lines.append(f"excitation: {sentence}")
        for rep in (self.diagnostics.get("smoothness") or {}).values():
            lines.append(f"smoothness (A10/A15): {rep['sentence']}")
        from vesselid.identify.specification import summary_lines

        lines.extend(summary_lines(self.diagnostics.get("specification", {})))
        for s_name, lb in self.diagnostics.get("whiteness", {}).items():
            lines.append(f"whiteness {s_name}: {lb.get('sentence', '')}")
        for w in self.diagnostics.get("warnings", []):
            lines.append(f"warning: {w}")
        return "\n".join(lines)

    def plot_residuals(self, *, title: str | None = None):
        """MATLAB ``resid``-style figure: residual autocorrelation and residual–input
        cross-correlation with confidence bands (:func:`vesselid.core.figures.residual_analysis`).

        Returns a matplotlib ``Figure`` (save it with ``fig.savefig``).
        """
        from vesselid.core.figures import residual_analysis

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
        top = ("stability", "fallback_chain", "smoothness", "excitation")
        diag: dict[str, Any] = {
            k: v for k, v in self.diagnostics.items() if k not in ("design", *top)
        }
        if isinstance(design, pd.DataFrame):
            diag["design"] = json.loads(design.to_json(orient="records"))
        return strict({
            "method": self.method,
            "params": self._per_state(self.params),
            "stderr": self._per_state(self.std_errors),
            "cov_type": self.diagnostics.get("cov_type"),
            "converged": bool(self.converged),
            "iterations": int(self.iterations),
            "stop_reason": self.stop_reason,
            "experiments": int(self.n_experiments),
            "samples": int(self.n_samples),
            "status": self.status,
            "status_reason": self.status_reason,
            **{k: self.diagnostics[k] for k in top if k in self.diagnostics},
            "diagnostics": diag,
        })

    def to_json(self, **kwargs: Any) -> str:
        from vesselid.core.fileio import strict_json

        return strict_json(self.to_dict(), **({"indent": 2} | kwargs))

