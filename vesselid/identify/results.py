"""The identification results object (after linearmodels' ``iv/results.py``)."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pandas as pd

from vesselid.core.jsonio import strict
from vesselid.errors import IdentificationError
from vesselid.identify.diagnostic_records import (
    EquationSpecification,
    ExcitationReport,
    FallbackAttempt,
    FeedbackTest,
    FirstStage,
    MeanCurrentTest,
    ParameterStabilityTest,
    SmoothnessReport,
    StabilityReport,
    StallAverage,
    TestStatistic,
    frozen_mapping,
    records,
)
from vesselid.identify.diagnostics import normalized_error
from vesselid.model.spec import ModelSpec

if TYPE_CHECKING:
    from vesselid.identify.specification import ResidualCorrelation

__all__ = ["IdentificationResult", "assess"]


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
        ``oscillation``, ``fixed_point_residual``, ``combine``, warnings raised: the
        JSON-ready entries that ``vesselid identify --json`` writes. Each entry is also a
        typed property of the same name (listed in :data:`DIAGNOSTICS`; records from
        :mod:`vesselid.identify.diagnostic_records`), e.g. ``result.whiteness["w"].pvalue``;
        None where the estimator does not produce the entry.
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

    #: The typed diagnostic properties, one per entry of :attr:`diagnostics` (the entry of
    #: the same name), in the order docs/guide/diagnostics.md lists them.
    DIAGNOSTICS: ClassVar[tuple[str, ...]] = (
        "combine", "cov_type", "cov_label", "cov_config", "target", "instrument_condition",
        "fit_one_step", "fit_free_run", "fixed_point_residual", "convergence_rule",
        "fixed_point_step_se", "fixed_point_step_own_se", "stall_average", "oscillation", "start",
        "instruments", "noise_model", "sensor_noise_correction", "instrument_choice", "choice",
        "choice_reason", "auto_choice", "hansen_j_combined", "c_test_lagged", "colour_test",
        "colour_test_prefilter", "sargan_hansen_j", "parameter_stability", "mean_current",
        "specification", "design", "design_eta", "design_eta_source", "smoothness",
        "modulus_states", "whiteness", "residual_correlation", "feedback", "stability",
        "excitation", "fallback_chain", "assumption", "disturbance_model", "model_choice",
        "log_likelihood", "noise_parameters", "controller", "streamed", "passes", "warnings")

    # --- typed diagnostics (one property per entry of ``diagnostics``) -------------------
    # Each reads its entry on access (estimators such as the fallback path add entries
    # after construction); None where the estimator does not produce the entry.

    def _entry(self, key: str, convert: Callable[[Any], Any] | None = None) -> Any:
        value = self.diagnostics.get(key)
        return value if value is None or convert is None else convert(value)

    @property
    def combine(self) -> str:
        """How several experiments were combined: ``"pooled"`` (one set of moment
        equations over all experiments, the paper's (10) stacked per experiment and
        summed) or ``"stacked"`` (the per-experiment equations solved jointly)."""
        return str(self.diagnostics.get("combine", "pooled"))

    @property
    def cov_type(self) -> str | None:
        """Name of the covariance estimator of :attr:`cov` (``unadjusted``, ``hac``,
        ``cluster``; an estimator with its own covariance names it)."""
        return self._entry("cov_type")

    @property
    def cov_label(self) -> str | None:
        """The covariance estimator in words (kernel and bandwidth for ``hac``)."""
        return self._entry("cov_label")

    @property
    def cov_config(self) -> Mapping[str, Any] | None:
        """Streamed results: the covariance estimator's settings (kernel, bandwidth)."""
        return self._entry("cov_config", frozen_mapping)

    @property
    def target(self) -> str | None:
        """Regression target: ``"measured"`` (``y1(k)``, eq. (10)) or ``"aggregated"``
        (the aggregated-state predictor ``ỹ(k)``, eq. (9))."""
        return self._entry("target")

    @property
    def instrument_condition(self) -> dict[str, float]:
        """Condition number of ``ZᵀΦ`` per equation (dimensionless; large: weak
        instruments). ``{}`` where the estimator has no instruments."""
        return dict(self.diagnostics.get("instrument_condition", {}))

    @property
    def fit_one_step(self) -> Mapping[str, float] | None:
        """One-step-ahead prediction fit per state, NRMSE in per cent
        (``100 (1 − ‖y − ŷ‖/‖y − ȳ‖)``, ŷ from eq. (9); 100: perfect)."""
        return self._entry("fit_one_step", frozen_mapping)

    @property
    def fit_free_run(self) -> Mapping[str, float] | None:
        """Free-run simulation fit per state on the log's own inputs, NRMSE in per cent
        (as :attr:`fit_one_step`)."""
        return self._entry("fit_free_run", frozen_mapping)

    @property
    def fixed_point_residual(self) -> float | None:
        """Relative fixed-point residual ``‖T(θ̂) − θ̂‖/‖θ̂‖`` of the refined IV iteration
        (dimensionless; 0 for closed forms)."""
        return self._entry("fixed_point_residual")

    @property
    def convergence_rule(self) -> str | None:
        """The stopping rule that applied, in words."""
        return self._entry("convergence_rule")

    @property
    def fixed_point_step_se(self) -> float | None:
        """Last fixed-point step, in standard errors of the parameters (largest over the
        parameters; the result's own standard errors)."""
        return self._entry("fixed_point_step_se")

    @property
    def fixed_point_step_own_se(self) -> float | None:
        """Last fixed-point step in the iteration's own standard errors (for ``auto``,
        ``sriv`` and ``gmm``: those of the IV_E{ζ}=0 iteration that supplied the
        instruments); the convergence rule compares it with 0.1."""
        return self._entry("fixed_point_step_own_se")

    @property
    def stall_average(self) -> StallAverage | None:
        """The averaged steps of a stalled iteration (None where it did not stall)."""
        return self._entry("stall_average", StallAverage.from_dict)

    @property
    def oscillation(self) -> bool | None:
        """Whether the refined IV iteration oscillated between iterates."""
        return self._entry("oscillation")

    @property
    def start(self) -> str | None:
        """The estimate the iteration started from (e.g. ``"ls"``); None: closed form."""
        return self._entry("start")

    @property
    def instruments(self) -> str | None:
        """The instruments used, in words (None: least squares)."""
        return self._entry("instruments")

    @property
    def noise_model(self) -> str | None:
        """The equation-error noise model of the prefilter (``"none"``, ``AR(p)``, …)."""
        return self._entry("noise_model")

    @property
    def sensor_noise_correction(self) -> str | None:
        """The correction for sensor noise in the regressors (``"none"`` where none)."""
        return self._entry("sensor_noise_correction")

    @property
    def instrument_choice(self) -> str | None:
        """``auto``: the instrument set chosen and why (detail)."""
        return self._entry("instrument_choice")

    @property
    def choice(self) -> str | None:
        """``auto``'s choice as one token: ``combined``, ``sriv`` or ``pem-<model>``."""
        return self._entry("choice")

    @property
    def choice_reason(self) -> str | None:
        """``auto``'s choice in one plain sentence."""
        return self._entry("choice_reason")

    @property
    def auto_choice(self) -> str | None:
        """Why ``auto`` handed the log to another estimator (a declared closed loop)."""
        return self._entry("auto_choice")

    @property
    def hansen_j_combined(self) -> tuple[TestStatistic, ...] | None:
        """Hansen J test of the combined (simulated + delayed) instrument set, one per
        group of experiments; χ²(df) under valid instruments."""
        return self._entry("hansen_j_combined", records(TestStatistic.from_dict))

    @property
    def c_test_lagged(self) -> tuple[TestStatistic, ...] | None:
        """Difference-in-J (C) test of the delayed-measurement instruments, one per group;
        χ²(df) under their validity (rejection: coloured disturbances)."""
        return self._entry("c_test_lagged", records(TestStatistic.from_dict))

    @property
    def colour_test(self) -> tuple[TestStatistic, ...] | None:
        """Test of colour in the equation error, one per group; χ²(df) under white
        disturbances."""
        return self._entry("colour_test", records(TestStatistic.from_dict))

    @property
    def colour_test_prefilter(self) -> str | None:
        """The prefilter of the colour test (``"none"`` or ``AR(p)``)."""
        return self._entry("colour_test_prefilter")

    @property
    def sargan_hansen_j(self) -> tuple[TestStatistic, ...] | None:
        """``lagged-2sls``: Sargan–Hansen J test of the over-identifying restrictions,
        one per group; χ²(df) under valid instruments."""
        return self._entry("sargan_hansen_j", records(TestStatistic.from_dict))

    @property
    def parameter_stability(self) -> ParameterStabilityTest | None:
        """Split-sample Wald test of constant parameters (``auto``; one state)."""
        return self._entry("parameter_stability", ParameterStabilityTest.from_dict)

    @property
    def mean_current(self) -> MeanCurrentTest | None:
        """Test of a mean current inside the modulus (``auto``, where it applies)."""
        return self._entry("mean_current", MeanCurrentTest.from_dict)

    @property
    def specification(self) -> Mapping[str, EquationSpecification] | None:
        """Instrument strength, endogeneity and over-identification tests per equation."""
        return self._entry("specification",
                           lambda v: frozen_mapping(v, EquationSpecification.from_dict))

    @property
    def first_stage(self) -> Mapping[str, FirstStage] | None:
        """First-stage diagnostics per equation (linearmodels' ``first_stage``): partial
        F and R² of the excluded instruments, Cragg–Donald statistic."""
        spec = self.specification
        return None if spec is None else frozen_mapping(
            {s: e.first_stage for s, e in spec.items() if e.first_stage is not None})

    @property
    def endogeneity(self) -> Mapping[str, TestStatistic] | None:
        """Durbin–Wu–Hausman test per equation (linearmodels' ``wu_hausman``/``durbin``);
        rejection: least squares is biased on this log."""
        spec = self.specification
        return None if spec is None else frozen_mapping(
            {s: e.endogeneity for s, e in spec.items() if e.endogeneity is not None})

    @property
    def hansen_j(self) -> Mapping[str, TestStatistic] | None:
        """Hansen J over-identification test per equation (linearmodels' ``j_stat``/
        ``sargan``); rejection: some instrument is correlated with the equation error."""
        spec = self.specification
        return None if spec is None else frozen_mapping(
            {s: e.hansen_j for s, e in spec.items() if e.hansen_j is not None})

    @property
    def design(self) -> pd.DataFrame | None:
        """Design check per experiment and state (a copy): the share of samples within
        ``eta`` of zero and the sign changes behind assumptions A10/A15 (the modulus
        states must cross zero rarely and sharply), ``ok`` per row."""
        design = self.diagnostics.get("design")
        return design.copy() if isinstance(design, pd.DataFrame) else design

    @property
    def design_eta(self) -> Mapping[str, float] | None:
        """The margin ``η`` around zero per modulus state (the state's units)."""
        return self._entry("design_eta", frozen_mapping)

    @property
    def design_eta_source(self) -> str | None:
        """Where :attr:`design_eta` comes from (given, or 3 × the residual std)."""
        return self._entry("design_eta_source")

    @property
    def smoothness(self) -> Mapping[str, SmoothnessReport] | None:
        """The modulus's non-smoothness per modulus state and the bias it can cause
        (A10/A15)."""
        return self._entry("smoothness", lambda v: frozen_mapping(v, SmoothnessReport.from_dict))

    @property
    def modulus_states(self) -> tuple[str, ...] | None:
        """States inside a modulus ``|·|`` of the model."""
        return self._entry("modulus_states", tuple)

    @property
    def whiteness(self) -> Mapping[str, TestStatistic] | None:
        """Ljung–Box test of the one-step residual per state (20 lags; χ²(df) under a
        white residual)."""
        return self._entry("whiteness", lambda v: frozen_mapping(v, TestStatistic.from_dict))

    @property
    def residual_correlation(self) -> ResidualCorrelation | None:
        """Residual autocorrelation and residual–input cross-correlation with their
        band (MATLAB ``resid``; :meth:`plot_residuals` draws it)."""
        def convert(v: Mapping[str, Any]) -> ResidualCorrelation:
            from vesselid.identify.specification import ResidualCorrelation

            return ResidualCorrelation(
                lags=np.asarray(v["lags"]), acf=np.asarray(v["acf"], dtype=float),
                cross_lags=np.asarray(v["cross_lags"]),
                ccf=np.asarray(v["ccf"], dtype=float), band=v["band"], level=v["level"],
                outputs=list(v["outputs"]), inputs=list(v["inputs"]), n=v["n"])

        return self._entry("residual_correlation", convert)

    @property
    def feedback(self) -> FeedbackTest | None:
        """Test of feedback from the outputs to the input (open loop: none)."""
        return self._entry("feedback", FeedbackTest.from_dict)

    @property
    def stability(self) -> StabilityReport | None:
        """Stability of the identified model on the log (drives :attr:`status`)."""
        return self._entry("stability", StabilityReport.from_dict)

    @property
    def excitation(self) -> ExcitationReport | None:
        """Whether the log's inputs excite the model's terms."""
        return self._entry("excitation", ExcitationReport.from_dict)

    @property
    def fallback_chain(self) -> tuple[FallbackAttempt, ...] | None:
        """The estimators the default path tried, in order, and what became of each."""
        return self._entry("fallback_chain", records(FallbackAttempt.from_dict))

    @property
    def assumption(self) -> str | None:
        """``pem``: the disturbance assumption the estimate rests on, in words."""
        return self._entry("assumption")

    @property
    def disturbance_model(self) -> str | None:
        """``pem``: the disturbance model chosen (``"current"`` or ``"sensor"``)."""
        return self._entry("disturbance_model")

    @property
    def model_choice(self) -> str | None:
        """``pem``: the disturbance-model choice with its likelihoods and Vuong test."""
        return self._entry("model_choice")

    @property
    def log_likelihood(self) -> Mapping[str, float] | None:
        """``pem``: Gaussian log-likelihood per disturbance model (nats)."""
        return self._entry("log_likelihood", frozen_mapping)

    @property
    def noise_parameters(self) -> Mapping[str, float] | None:
        """``pem``: the disturbance model's parameters (standard deviations in the
        state's units, AR coefficients dimensionless)."""
        return self._entry("noise_parameters", frozen_mapping)

    @property
    def controller(self) -> Mapping[str, Any] | None:
        """``cl-iv``: the controller the closed-loop instruments were simulated with."""
        return self._entry("controller", frozen_mapping)

    @property
    def streamed(self) -> bool | None:
        """Whether the result was estimated out of core, experiment by experiment
        (:func:`vesselid.identify.streaming.identify_stream`)."""
        return self._entry("streamed")

    @property
    def passes(self) -> int | None:
        """Streamed results: passes over the data files."""
        return self._entry("passes")

    @property
    def warnings(self) -> tuple[str, ...]:
        """The warnings raised while estimating, as messages."""
        return tuple(self.diagnostics.get("warnings", ()))

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


def assess(result: IdentificationResult) -> tuple[str, str]:
    """``(outcome, reason)`` of a result: ``accepted`` or the first failure (module
    docstring), with a one-line reason."""
    params = result.params.to_numpy(dtype=float)
    if not np.all(np.isfinite(params)):
        bad = [f"{eq}: {t}" for (eq, t), v in result.params.items() if not math.isfinite(v)]
        return "non-finite", "non-finite parameters: " + ", ".join(bad[:4])
    figs = {f"{kind} fit {s}": v
            for kind, key in (("one-step", "fit_one_step"), ("free-run", "fit_free_run"))
            for s, v in result.diagnostics.get(key, {}).items()}
    nan_figs = [k for k, v in figs.items() if not math.isfinite(v)]
    stab = result.diagnostics.get("stability") or {}
    if stab and not stab.get("stable", True):
        return "unstable", stab.get("sentence", "unstable")
    if nan_figs:
        return "non-finite", "non-finite fit figures: " + ", ".join(nan_figs)
    if not result.converged:
        return "not converged", str(result.stop_reason)
    return "accepted", _accepted_reason(result)


def _accepted_reason(result: IdentificationResult) -> str:
    stab = result.diagnostics.get("stability") or {}
    rho = (stab.get("spectral_radius") or {}).get("operating_point", float("nan"))
    stop = str(result.stop_reason)
    text = ("converged" if stop == "converged" else f"converged ({stop})") + "; stable on the log"
    if math.isfinite(rho):
        text += f" (spectral radius at the mean operating point {rho:.3g})"
    return text
