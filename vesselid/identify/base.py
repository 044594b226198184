"""Estimator objects: an unchecked batched fast path and a checked ``fit``.

Follows linearmodels' split (``iv/model.py``, ``iv/results.py``):

* :meth:`Estimator.estimate_parameters` — arrays in, parameter arrays out, for
  every parameter group (Monte Carlo run) at once; no validation, no DataFrames.
  Failed groups are NaN rows with a stop reason, never an exception.
* :meth:`Estimator.fit` — validates the log and the options, estimates, computes
  the covariance (``cov_type``) and diagnostics, and builds an
  :class:`~vesselid.identify.results.IdentificationResult` from one dict.

A new estimator is one subclass that implements ``estimate_parameters`` and
``equation_designs`` (the final instruments, regressors and residuals of each
state equation, from which covariance and diagnostics follow) and one entry in
:data:`vesselid.identify.registry.ESTIMATORS`. ``__init__`` stores options only
(scikit-learn convention); they are validated in ``fit``/``estimate_parameters``.
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from vesselid.core.memory import drop_library_code
from vesselid.errors import (
    ConvergenceWarning,
    EstimationFailedError,
    ExperimentDesignWarning,
    IdentificationError,
    RankDeficientError,
    UnstableModelWarning,
    WeakInstrumentWarning,
)
from vesselid.identify import backend, linalg
from vesselid.identify.backend import kernels
from vesselid.identify.data import RegressionData, block_starts, from_log
from vesselid.identify.diagnostics import (
    collinear_terms,
    design_frame,
    design_rows,
    free_run_ratio,
    modulus_signals,
    nrmse_fit,
    smoothness_report,
)
from vesselid.identify.estimators import (
    COMBINE_MODES,
    STOP_FIXED,
    STOP_MAX_ITER,
    STOP_STALLED,
    IterationResult,
    moments_from_matrices,
    solve_moments,
    stall_averaging,
)
from vesselid.identify.excitation import excitation_report
from vesselid.identify.options import TARGETS, FitOptions
from vesselid.identify.results import IdentificationResult
from vesselid.identify.stability import free_run_states, stability_report
from vesselid.model.spec import ModelSpec

__all__ = ["TARGETS", "EquationDesign", "Estimator", "FitOptions", "equation_rows"]

#: The standard-error stopping rule of the refined iteration: where the relative residual
#: rule (``tol``) is not reached because the iteration ran out of evaluations or stalled,
#: it has converged when its last fixed-point step ``|T(θ) − θ|`` is below ``SE_TOL``
#: standard errors of every parameter (the estimate no longer moves on the scale of its
#: own uncertainty). A diverging auxiliary model or a singular system stays a failure.
SE_TOL = 0.1
SE_RULE_REASONS = (STOP_MAX_ITER, STOP_STALLED)


@dataclass
class EquationDesign:
    """The final estimating equations of one state equation (valid rows only).

    ``z`` (n, K) instruments as used (centred / prefiltered where the estimator does
    so), ``phi`` (n, P) regressors and ``resid`` (n,) residuals on the same footing,
    ``starts`` (S+1,) experiment boundaries into these rows, ``weight`` the GMM
    weight (K, K) when ``K > P`` or the row weight of the stacked equations (None: just
    identified, pooled), ``zero_mean`` whether the
    rows carry per-experiment constants (centred instruments), ``weight_jacobian``
    (P, P) the derivative ``∂θ₂/∂θ₁`` of a two-step GMM estimate with respect to its
    2SLS first step through the estimated weight (None: the weight is not estimated),
    from which the covariance adds Windmeijer's (2005) finite-sample correction.
    ``fixed_b``: a just-identified estimate whose Bartlett-HAC standard errors are scaled
    to the fixed-b critical value at the effective bandwidth ratio
    (:mod:`vesselid.identify.fixedb`; two-step GMM estimates with ``weight_jacobian``
    always are).
    ``owned``: ``z``, ``phi`` and ``resid`` are the estimator's own buffers (no other
    array of the fit, the log or the caller shares them), which the last step that reads
    them may overwrite.
    """

    z: np.ndarray
    phi: np.ndarray
    resid: np.ndarray
    starts: np.ndarray
    weight: np.ndarray | None = None
    zero_mean: bool = False
    weight_jacobian: np.ndarray | None = None
    owned: bool = False
    fixed_b: bool = False


class _Warner:
    """The warnings of one ``fit``: each is issued at once, pointing at the caller of
    :func:`~vesselid.identify.identify`, and listed in ``messages`` (the result's
    ``diagnostics["warnings"]``). Called from the steps of ``fit`` only (the stack depth
    below that caller is fixed: this call, the step, ``fit``, its two decorators — BLAS
    threads and kernel choice — and ``identify``)."""

    STACKLEVEL = 7

    def __init__(self) -> None:
        self.messages: list[str] = []

    def __call__(self, msg: str, category: type[Warning]) -> None:
        self.messages.append(msg)
        warnings.warn(msg, category, stacklevel=self.STACKLEVEL)


@dataclass
class _FitRun:
    """What the steps of :meth:`Estimator.fit` find, in the order they find it."""

    opts: FitOptions
    warn: _Warner
    cov_name: str = ""
    cov_fn: Any = None
    data: RegressionData = None  # type: ignore[assignment]
    spec: ModelSpec = None  # type: ignore[assignment]
    phi: np.ndarray = None  # type: ignore[assignment]
    rows: np.ndarray = None  # type: ignore[assignment]
    blocks: np.ndarray = None  # type: ignore[assignment]
    excitation: dict[str, Any] = field(default_factory=dict)
    it: IterationResult = None  # type: ignore[assignment]
    designs: list[EquationDesign] = field(default_factory=list)
    feedback: dict[str, Any] = field(default_factory=dict)
    pred_weights: np.ndarray = None  # type: ignore[assignment]
    resid: np.ndarray = None  # type: ignore[assignment]
    cov: np.ndarray = None  # type: ignore[assignment]
    cov_label: str = ""
    own_cov: np.ndarray | None = None
    cond: dict[str, float] = field(default_factory=dict)
    converged: bool = False
    stop_reason: str = ""
    step_se: float = 0.0
    own_step_se: float = 0.0
    stall_info: dict[str, Any] | None = None
    specification: dict[str, Any] = field(default_factory=dict)
    residual_checks: dict[str, Any] = field(default_factory=dict)
    fit_one: dict[str, float] = field(default_factory=dict)
    fit_free: dict[str, float] = field(default_factory=dict)
    design: Any = None
    stability: dict[str, Any] = field(default_factory=dict)
    eta_source: str = ""
    eta_used: dict[str, float] = field(default_factory=dict)
    smoothness: dict[str, Any] = field(default_factory=dict)


def _prefilters(est: Any) -> bool:
    """The estimator has an AR noise-model prefilter whose order ``noise_order`` sets."""
    return bool(getattr(est, "noise_order", 0))


def equation_rows(data: RegressionData) -> np.ndarray:
    """Rows that hold an equation (every row but the first of each experiment)."""
    rows = np.ones(int(data.starts[-1]), dtype=bool)
    rows[data.starts[:-1]] = False
    return rows


def _valid_starts(data: RegressionData, valid: np.ndarray) -> np.ndarray:
    counts = [int(valid[data.segment(s)].sum()) for s in range(data.n_segments)]
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


class Estimator:
    """Base class of the registered estimators (see module docstring).

    Class attributes
    ----------------
    name : str
        Registry key (``--method``).
    label : str
        Long name (``summary()`` title).
    short : str
        Row label of tables (the paper's notation where it has one).
    plot_label : str
        Matplotlib label.
    uses_instruments : bool
        False for least squares.
    multi_experiment : tuple of str
        Supported ``combine`` modes.
    """

    name: ClassVar[str] = ""
    label: ClassVar[str] = ""
    short: ClassVar[str] = ""
    plot_label: ClassVar[str] = ""
    uses_instruments: ClassVar[bool] = True
    multi_experiment: ClassVar[tuple[str, ...]] = COMBINE_MODES
    #: the estimator evaluates its regressors with the errors-in-variables correction of
    #: the square modulus terms when the data carry the sensor noise
    #: (:mod:`vesselid.identify.eiv`); others ignore ``sensor_noise``
    corrects_sensor_noise: ClassVar[bool] = False
    #: ``fit`` warns when the estimator's iteration did not converge (set for the
    #: iterative estimators without instruments; the instrumental ones always warn)
    reports_convergence: ClassVar[bool] = False

    def __init__(self, **options: Any) -> None:
        self.options = dict(options)

    @property
    def experiment_constants(self) -> bool:
        """The estimator carries a constant per experiment (zero-mean instruments, or a
        constant among the instruments): terms constant within every experiment are
        then not identifiable (:mod:`vesselid.identify.excitation`)."""
        return bool(self.uses_instruments and getattr(self, "zero_mean", True))

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in self.options.items())
        return f"{type(self).__name__}({opts})"

    # ----------------------------------------------------------- fast path
    def estimate_parameters(
        self,
        data: RegressionData,
        spec: ModelSpec,
        *,
        combine: str = "pooled",
        theta_start: np.ndarray | None = None,
        max_iter: int = 100,
        tol: float = 1e-9,
        keep_history: bool = False,
    ) -> IterationResult:  # pragma: no cover - abstract
        """Estimate every parameter group of ``data`` (unchecked, batched)."""
        raise NotImplementedError

    def equation_designs(
        self, data: RegressionData, spec: ModelSpec, it: IterationResult, phi: np.ndarray,
        combine: str,
    ) -> list[EquationDesign]:  # pragma: no cover - abstract
        """Final instruments, regressors and residuals per state equation (one group)."""
        raise NotImplementedError

    def defers_designs(self, it: IterationResult) -> bool:
        """Whether :meth:`equation_designs` of ``it`` is better called when the
        covariance needs the designs (they are formed again there instead of being held
        through the feedback test; a long log's designs are the fit's largest arrays).
        It is then called with ``phi=None``: it forms the rows it needs itself."""
        return False

    def describe(self, it: IterationResult) -> dict[str, Any]:
        """Estimator-specific diagnostics of a one-group result (JSON-ready)."""
        return {}

    def own_covariance(self, it: IterationResult) -> np.ndarray | None:
        """The covariance of a one-group result when the estimator computes its own
        (a likelihood's inverse Fisher information); ``None``: the covariance estimator
        ``cov_type`` works on :meth:`equation_designs`."""
        return None

    def result_warnings(self, it: IterationResult) -> list[tuple[str, type[Warning]]]:
        """Warnings of a one-group result the estimator's own diagnostics raise
        (``(message, category)``; reported like the design warnings)."""
        return []

    def own_covariance_label(self, it: IterationResult) -> tuple[str, str]:
        """``(cov_type, label)`` of :meth:`own_covariance`."""
        return "fisher", "inverse Fisher information (quasi-ML)"

    def check_covariance(self, cov_type: str | None) -> None:
        """Refuse a ``cov_type`` the estimator cannot honour (one-line reason)."""

    # ---------------------------------------------------------- checked path
    def check_options(self, *, combine: str) -> None:
        """Validate options; raise :class:`IdentificationError` with a one-line reason."""
        if combine not in COMBINE_MODES:
            raise IdentificationError(
                f"unknown combine {combine!r}; choose from {list(COMBINE_MODES)}")
        if combine not in self.multi_experiment:
            raise IdentificationError(
                f"method {self.name!r} supports combine={list(self.multi_experiment)}, "
                f"not {combine!r}")

    @backend.chooses_kernels
    @linalg.one_blas_thread
    def fit(
        self,
        log: Any,
        spec: ModelSpec | None = None,
        options: FitOptions | Mapping[str, Any] | None = None,
        **overrides: Any,
    ) -> IdentificationResult:
        """Identify θ from a trial log (see :func:`vesselid.identify.identify`).

        Parameters
        ----------
        log : TrialLog or DataFrame
        spec : ModelSpec, optional
            Default the log's spec.
        options : FitOptions or mapping, optional
            The options of the estimation (:class:`~vesselid.identify.options.FitOptions`).
        **overrides
            Fields of :class:`~vesselid.identify.options.FitOptions` by name (the
            keywords of :func:`~vesselid.identify.identify`), replacing those of
            ``options``.
        """
        run = _FitRun(FitOptions.of(options, **overrides), _Warner())
        self._resolve(run)
        # between the steps, the code pages of the libraries that read the log and
        # loaded the compiled kernels leave the process where the command asked for it
        # (core.memory)
        drop_library_code()
        self._regression(run, log, spec)
        drop_library_code()
        self._estimate(run)
        drop_library_code()
        self._feedback(run, log)
        drop_library_code()
        self._covariance(run)
        self._convergence(run)
        drop_library_code()
        self._specification(run)
        drop_library_code()
        self._fit_quality(run)
        self._estimator_warnings(run)
        return self._result(run)

    # The steps of ``fit``, in order. Each reads and fills ``run`` (:class:`_FitRun`); a
    # warning goes through ``run.warn`` from the step itself (it points at the caller of
    # identify() and is listed in ``diagnostics["warnings"]``).
    def _resolve(self, run: _FitRun) -> None:
        """The options this estimator can honour, and the covariance estimator."""
        from vesselid.identify import covariance_api

        opts = run.opts
        self.check_options(combine=opts.combine)
        self.check_covariance(opts.cov_type)
        run.cov_name, run.cov_fn = covariance_api.resolve(opts.cov_type, opts.cov_config)

    def _regression(self, run: _FitRun, log: Any, spec: ModelSpec | None) -> None:
        """The regression data, regressor matrix and identifiability of the log
        (rank and excitation; refused with one line)."""
        opts = run.opts
        legacy = getattr(log, "metadata", None)
        legacy = legacy.get("noise_order") if isinstance(legacy, Mapping) else None
        if legacy is not None and opts.noise_order is None and _prefilters(self):
            run.warn(f"the log's metadata['noise_order'] ({legacy!r}) is not an estimator "
                     f"setting and is ignored; pass noise_order={legacy!r} (vesselid identify "
                     f"--noise-order {legacy!r}) to use that AR order of the noise model",
                     FutureWarning)
        data, spec = from_log(log, spec, min_samples=opts.min_samples,
                              sensor_noise=opts.sensor_noise, noise_order=opts.noise_order)
        if opts.target == "aggregated":
            if not spec.aggregate:
                raise IdentificationError("target 'aggregated' needs an [aggregate] relation "
                                          "in the spec (a disturbance sensor)")
            data = replace(data, target=data.regsig)
        names = [f"{eq}: {term}" for eq, term in spec.param_index]
        blocks = block_starts(spec)
        phi = self._regressor_rows(data, spec)
        if self.corrects_sensor_noise:
            from vesselid.identify.eiv import remember_regressors

            remember_regressors(data, spec, phi)  # the estimator's own rows (data is ours)
        rows = equation_rows(data)
        # one experiment: every row but the first, as a view (no gathered copy)
        _check_rank(phi[1:] if data.n_segments == 1 else phi[rows], spec, blocks, names)
        excitation = excitation_report(data, spec, phi, rows)
        if excitation["unidentifiable"] and self.experiment_constants:
            lost = "; ".join(f"equation {st!r}: {', '.join(g)}"
                             for st, groups in excitation["unidentifiable"].items()
                             for g in groups)
            why = (f" (input(s) {', '.join(map(repr, excitation['not_excited']))} constant "
                   "within every experiment)" if excitation["not_excited"] else "")
            raise EstimationFailedError(
                f"{self.name}: not identifiable with a constant per experiment — {lost}"
                f"{why}; drop the term(s) from the spec or vary the input within the "
                "experiments")
        run.data, run.spec, run.phi, run.rows, run.blocks = data, spec, phi, rows, blocks
        run.excitation = excitation

    def _regressor_rows(self, data: RegressionData, spec: ModelSpec) -> np.ndarray:
        """The regressor matrix of the fit (with the errors-in-variables correction where
        the estimator applies it)."""
        if self.corrects_sensor_noise:
            from vesselid.identify.eiv import corrected_regressor_matrix

            return corrected_regressor_matrix(data, spec)
        return kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)

    def _estimate(self, run: _FitRun) -> None:
        """The estimate (one IV solve with user instruments, else the estimator's
        iteration) and its final estimating equations; no finite estimate is refused."""
        opts, data, spec = run.opts, run.data, run.spec
        if opts.instruments is not None:
            if not self.uses_instruments:
                raise IdentificationError(f"instruments are not used by method {self.name!r}")
            if not isinstance(self, _UserInstrumentMixin):
                raise IdentificationError(
                    f"method {self.name!r} builds its own instruments; use method 'iv' or "
                    "'iv-zero-mean' with user-supplied instruments")
            run.it, run.designs = self._fit_user_instruments(data, spec, run.phi,
                                                             opts.instruments, opts.combine)
            return
        start = None if opts.theta_start is None else spec.vector_from(opts.theta_start)
        with stall_averaging():  # a stall locates its fixed point by averaging
            it = self.estimate_parameters(data, spec, combine=opts.combine, theta_start=start,
                                          max_iter=opts.max_iter, tol=opts.tol,
                                          keep_history=True)
        if not np.all(np.isfinite(it.theta[0])) and not self.uses_instruments:
            raise EstimationFailedError(
                f"{self.name}: {it.reason[0]}; the likelihood could not be maximised "
                "from the IV_E{ζ}=0 start — use longer or better-excited experiments, "
                "or method 'auto'")
        if not np.all(np.isfinite(it.theta[0])):
            tried = ("the LS estimate and basic IV with delayed measurements"
                     if it.start is not None and it.start[0] == "lagged-iv"
                     else "the given start" if opts.theta_start is not None
                     else "the LS estimate")
            raise EstimationFailedError(
                f"{self.name}: {it.reason[0]} (starts tried: {tried}); no instrument could "
                "be formed — supply theta_start (a stable model) or instruments, or use "
                "longer or better-excited experiments"
            )
        run.it = it
        run.designs = (None if self.defers_designs(it) else
                       self.equation_designs(data, spec, it, run.phi, opts.combine))
        # the rows a GMM solution kept to build the designs: the designs hold what the
        # later steps read (the centred targets kept with them are as large as a column)
        sol = (it.info or {}).get("solution")
        if getattr(sol, "designs", None) is not None:
            sol.designs = None

    def _feedback(self, run: _FitRun, log: Any) -> None:
        """The closed-loop check of an open-loop estimator (:mod:`vesselid.identify.loop`)."""
        if not getattr(self, "open_loop", True):
            return
        from vesselid.errors import ClosedLoopWarning
        from vesselid.identify.loop import feedback_check

        it = run.it
        own = run.designs if self.name == "iv-zero-mean" and run.opts.instruments is None else None
        first = it.info.get("base") if it.info else None  # IV_E{ζ}=0 first step
        run.feedback, fb_msg = feedback_check(self.name, log, run.data, run.spec, own,
                                              first if own is None else None)
        if fb_msg:
            run.warn(fb_msg, ClosedLoopWarning)

    def _covariance(self, run: _FitRun) -> None:
        """Residuals, the covariance of the estimate (the estimator's own, or ``cov_type``
        on each equation's design) and the instrument condition per equation."""
        spec, theta = run.spec, run.it.theta[0]
        weights = np.zeros((spec.n_params, spec.n_states))
        weights[np.arange(spec.n_params), spec.codes.equation] = theta
        # the one-step predictions are formed again where the fit figures need them (the
        # same product): on a long log they would be held through every test between
        run.pred_weights = weights
        run.resid = run.data.target - run.phi @ weights
        cov = np.zeros((spec.n_params, spec.n_params))
        run.cov_label = run.cov_name
        run.own_cov = self.own_covariance(run.it)
        if run.designs is None:  # deferred to here (:meth:`defers_designs`)
            # a long log's designs are formed again with their own regressor rows: the
            # fit's are not held through them and the tests (formed again for the fit
            # figures, the same numbers)
            from vesselid.identify.eiv import forget_regressors

            forget_regressors(run.data)
            run.phi = None
            run.designs = self.equation_designs(run.data, spec, run.it, None,
                                                run.opts.combine)
        if run.own_cov is not None:
            cov = np.array(run.own_cov, dtype=float)
            run.cov_name, run.cov_label = self.own_covariance_label(run.it)
        for i, s in enumerate(spec.states):
            sl = slice(int(run.blocks[i]), int(run.blocks[i + 1]))
            d = run.designs[i]
            run.cond[s] = linalg.condition_number(d.z.T @ d.phi)
            if run.own_cov is None:
                cov[sl, sl], run.cov_label = run.cov_fn(d, combine=run.opts.combine)
            if self.uses_instruments and run.cond[s] > run.opts.weak_instrument_cond:
                run.warn(f"weak instruments in equation {s!r}: cond(ZᵀΦ) = {run.cond[s]:.3g}",
                         WeakInstrumentWarning)
        run.cov = cov

    def _convergence(self, run: _FitRun) -> None:
        """Whether the iteration converged: the ``tol`` rule, or the standard-error rule
        (``SE_TOL``) where ``tol`` was not reached (module constants)."""
        it, cov, tol = run.it, run.cov, run.opts.tol
        # the last step T(θ) − θ of the refined iteration (for GMM/SRIV: of the IV_E{ζ}=0
        # iteration that supplied their instruments)
        src = it.info.get("base", it)
        step_se = _fixed_point_step_in_se((src.theta - src.theta_aux)[0], cov)
        converged, stop_reason = bool(it.converged[0]), str(it.reason[0])
        own_step_se = step_se
        if self.uses_instruments and not converged and stop_reason in SE_RULE_REASONS:
            # the iteration's step in its own estimator's standard errors (for GMM/SRIV/auto
            # the IV_E{ζ}=0 iteration that supplied their instruments)
            cov_own = cov if src is it else _base_covariance(run.data, run.spec, src,
                                                            run.cov_fn)
            own_step_se = _fixed_point_step_in_se((src.theta - src.theta_aux)[0], cov_own)
            what = f"the last fixed-point step is {own_step_se:.2g} standard errors"
            avg = src.info.get("stall_average")
            if avg is not None and bool(avg["groups"][0]):
                mean_se = _fixed_point_step_in_se(avg["mean_step"][0], cov_own)
                sd_se = _fixed_point_step_in_se(avg["sd_of_mean"][0], cov_own)
                own_step_se = max(mean_se, sd_se)
                what = (f"averaged over {avg['evaluations']} further steps of the stalled "
                        f"iteration, its mean step is {mean_se:.2g} and the fixed point is "
                        f"located to {sd_se:.2g} standard errors")
                run.stall_info = {"evaluations": int(avg["evaluations"]),
                                  "mean_step_se": mean_se, "location_se": sd_se}
            if own_step_se < SE_TOL:
                # stopped moving within SE_TOL standard errors: converged in the units that
                # matter for the estimate (SE_TOL)
                converged = True
                stop_reason = (f"converged in standard-error units: {what} (< {SE_TOL:g}); "
                               f"relative residual {it.residual[0]:.3g} above tol {tol:g} "
                               f"({stop_reason})")
        if self.reports_convergence and not bool(it.converged[0]):
            run.warn(f"{self.name}: the likelihood maximisation did not converge "
                     f"({it.reason[0]}, {int(it.iterations[0])} iterations); returning the "
                     "last iterate", ConvergenceWarning)
        elif self.uses_instruments and not converged:
            size = ("" if not np.isfinite(own_step_se) else
                    f"; its last fixed-point step is at most {own_step_se:.2g} standard errors "
                    "of any parameter")
            run.warn(f"refined IV did not converge ({it.reason[0]}, {int(it.iterations[0])} "
                     f"iterations, fixed-point residual {it.residual[0]:.3g}); returning the "
                     f"IV estimate of the best iterate{size}", ConvergenceWarning)
        if it.oscillation[0]:
            run.warn("the refined iteration oscillated; the step was damped", ConvergenceWarning)
        run.converged, run.stop_reason = converged, stop_reason
        run.step_se, run.own_step_se = step_se, own_step_se

    def _specification(self, run: _FitRun) -> None:
        """Instrument strength, endogeneity and over-identification (not for a
        likelihood), and the residual checks."""
        if run.own_cov is None:
            run.specification = _specification_tests(run.spec, run.designs, run.it.theta[0],
                                                     run.blocks, run.cov_name)
        # no later step reads the designs (the tests may have centred them in place), nor
        # the rows a GMM solution kept to build them: on a long log they are the largest
        # arrays of the fit
        run.designs = []
        sol = (run.it.info or {}).get("solution")
        if getattr(sol, "designs", None) is not None:
            sol.designs = None
        run.residual_checks = _residual_checks(run.spec, run.data, run.resid)
        if not np.all(np.isfinite(run.cov)):
            run.warn("the covariance of the estimates could not be computed (singular "
                     "instrument or moment matrix); standard errors are reported as null",
                     WeakInstrumentWarning)

    def _fit_quality(self, run: _FitRun) -> None:
        """One-step and free-run fit, stability, and the A10/A15 design and smoothness
        checks of the estimated model."""
        data, spec, theta, opts = run.data, run.spec, run.it.theta[0], run.opts
        phi = run.phi if run.phi is not None else self._regressor_rows(data, spec)
        pred = phi @ run.pred_weights
        run.fit_one = {s: nrmse_fit(data.target[run.rows, i], pred[run.rows, i])
                       for i, s in enumerate(spec.states)}
        del pred
        sims = free_run_states(data, spec, theta)
        run.fit_free, free_ok = _free_run_fit(data, spec, theta, sims)
        if not free_ok:
            run.warn("free-run simulation of the estimated model diverged", ConvergenceWarning)
        run.stability = stability_report(data, spec, theta, sims)
        if not run.stability["stable"]:
            run.warn(f"the identified model is {run.stability['sentence']}",
                     UnstableModelWarning)
        if opts.eta is None:
            resid_std = np.sqrt(np.nanmean(run.resid**2, axis=0))
            run.eta_used = {s: 3.0 * float(resid_std[i]) for i, s in enumerate(spec.states)}
            run.eta_source = "3 x std of one-step residuals"
        else:
            run.eta_used = {s: float(opts.eta.get(s, 0.0)) for s in spec.states}
            run.eta_source = "given"
        design_checks = design_rows(data.regsig, data.starts, spec, run.eta_used,
                                    data.experiment_ids, threshold=opts.design_threshold)
        run.design = design_frame(design_checks)  # design_margins(...), worded from its rows
        run.smoothness = smoothness_report(data, spec, theta, sims, design_checks,
                                           run.eta_used, opts.eta is None, run.cov, phi,
                                           corrected=(self.corrects_sensor_noise
                                                      and data.regressor_noise is not None))
        for rep in run.smoothness.values():
            if rep["matters"]:
                run.warn(rep["sentence"], ExperimentDesignWarning)

    def _estimator_warnings(self, run: _FitRun) -> None:
        """The warnings of the estimator's own diagnostics (:meth:`result_warnings`)."""
        for msg, category in self.result_warnings(run.it):
            run.warn(msg, category)

    def _result(self, run: _FitRun) -> IdentificationResult:
        """The :class:`IdentificationResult` of the steps' findings."""
        it, spec, opts = run.it, run.spec, run.opts
        index = spec.param_index
        history = None
        if it.history:
            steps = np.vstack([h[0] for h in it.history])
            history = pd.DataFrame(steps, columns=index,
                                   index=pd.RangeIndex(steps.shape[0], name="iteration"))
        closed_note = None
        if self.name == "auto" and run.feedback:
            # auto stayed open loop on a log that is (or looks) closed loop: say so first
            from vesselid.identify.loop import closed_loop_note

            closed_note = closed_loop_note(run.feedback)
        diagnostics: dict[str, Any] = {
            "combine": opts.combine,
            "cov_type": run.cov_name,
            "cov_label": run.cov_label,
            "target": _target_rule(spec, opts.target),
            "instrument_condition": run.cond,
            "fit_one_step": run.fit_one,
            "fit_free_run": run.fit_free,
            "fixed_point_residual": float(it.residual[0]),
            "convergence_rule": (f"relative fixed-point residual < tol ({opts.tol:g}); or, "
                                 f"where that is not reached, the last fixed-point step "
                                 f"< {SE_TOL:g} standard errors"
                                 if self.uses_instruments and opts.instruments is None
                                 else "closed form"
                                 if it.reason[0] in ("closed form", STOP_FIXED)
                                 else "the estimator's own"),
            "stability": run.stability,
            "excitation": run.excitation,
            "fixed_point_step_se": run.step_se,
            "fixed_point_step_own_se": run.own_step_se,
            **({"stall_average": run.stall_info} if run.stall_info else {}),
            "oscillation": bool(it.oscillation[0]),
            "start": None if it.start is None else str(it.start[0]),
            **self.describe(it),
            **({"specification": run.specification} if run.specification else {}),
            "design": run.design,
            "design_eta": run.eta_used,
            "design_eta_source": run.eta_source,
            "smoothness": run.smoothness,
            "modulus_states": modulus_signals(spec),
            **run.residual_checks,
            **({"feedback": run.feedback} if run.feedback else {}),
            "warnings": run.warn.messages,
        }
        if closed_note is not None:
            prior = diagnostics.get("choice_reason")
            diagnostics["choice_reason"] = closed_note + (f" {prior}" if prior else "")
        results: dict[str, Any] = {
            "method": self.name,
            "spec": spec,
            "params": pd.Series(it.theta[0], index=index, name="estimate"),
            "cov": pd.DataFrame(run.cov, index=index, columns=index),
            "residuals": pd.DataFrame(run.resid, columns=list(spec.states)),
            "converged": run.converged,
            "iterations": int(it.iterations[0]),
            "stop_reason": run.stop_reason,
            "n_samples": int(run.data.starts[-1]),
            "n_experiments": run.data.n_segments,
            "diagnostics": diagnostics,
            "history": history,
            "label": self.label,
        }
        return IdentificationResult(**results)


class _UserInstrumentMixin:
    """Estimators that accept a user-supplied instrument matrix (one IV solve)."""

    zero_mean: bool = False

    def _fit_user_instruments(self, data, spec, phi, instruments, combine):
        rows = equation_rows(data)
        z_user = np.asarray(instruments, dtype=float)
        if z_user.shape != phi.shape:
            raise IdentificationError(
                f"instruments must have shape {phi.shape} (rows × parameters), got "
                f"{z_user.shape}")
        if not np.all(np.isfinite(z_user[rows])):
            raise IdentificationError("user-supplied instruments hold NaN or inf")
        mom = moments_from_matrices(data, spec, z_user, phi)
        theta, ok = solve_moments(mom, data, spec, zero_mean=self.zero_mean, combine=combine)
        if not ok[0]:
            raise IdentificationError("the IV equations with the supplied instruments are "
                                      "singular")
        it = IterationResult(theta=theta, theta_aux=theta, converged=np.array([True]),
                             iterations=np.array([0]),
                             reason=np.array([STOP_FIXED], dtype=object),
                             residual=np.zeros(1), oscillation=np.zeros(1, dtype=bool))
        return it, square_designs(data, spec, z_user, phi, theta[0], zero_mean=self.zero_mean,
                                  combine=combine, fixed_b=True)


def center_segments(x: np.ndarray, data: RegressionData) -> np.ndarray:
    """Subtract each column's mean per experiment over its equation rows (A7)."""
    out = x.copy()
    for s in range(data.n_segments):
        sl = slice(int(data.starts[s]) + 1, int(data.starts[s + 1]))
        out[sl] -= out[sl].mean(axis=0)
    return out


def square_designs(data: RegressionData, spec: ModelSpec, z: np.ndarray, phi: np.ndarray,
                   theta: np.ndarray, *, zero_mean: bool, combine: str = "pooled",
                   fixed_b: bool = False) -> list[EquationDesign]:
    """Designs of a just-identified estimator with full-length ``z``/``phi`` (T, P).

    ``fixed_b``: the designs ask for the fixed-b critical value at each parameter's
    effective bandwidth ratio (:attr:`EquationDesign.fixed_b`; the IV estimates: refined
    IV, open and closed loop, and IV with given instruments).

    With ``combine="stacked"`` and several experiments, ``weight`` holds the row weights
    the stacked solve used (:func:`vesselid.identify.linalg.stacked_row_weights`), so
    the covariance is that of the estimator actually computed.
    """
    rows = equation_rows(data)
    zc = center_segments(z, data) if zero_mean else z
    blocks = block_starts(spec)
    starts = _valid_starts(data, rows)
    out = []
    for i in range(spec.n_states):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        res = data.target[rows, i] - phi[rows, sl] @ theta[sl]
        d = EquationDesign(z=zc[rows, sl], phi=phi[rows, sl], resid=res, starts=starts,
                           zero_mean=zero_mean, fixed_b=fixed_b)
        if combine == "stacked" and starts.size > 2:
            a_n = np.stack([d.z[a:b].T @ d.phi[a:b] / max(b - a, 1)
                            for a, b in itertools.pairwise(starts)])
            w = linalg.stacked_row_weights(a_n)
            # the global factor is free: make W O(1) against the unit-norm instrument
            # columns the covariance works with (no overflow for signals of 1e±60)
            zs = np.sqrt(np.einsum("ij,ij->j", d.z, d.z))
            ok = (zs > 0) & np.isfinite(zs)
            if ok.any():
                w = w / np.exp(np.mean(np.log(w[ok] * zs[ok] ** 2)))
            d.weight = np.diag(w)
        out.append(d)
    return out




def _specification_tests(spec: ModelSpec, designs: list[EquationDesign], theta: np.ndarray,
                         blocks: np.ndarray, cov_type: str) -> dict[str, Any]:
    """Instrument strength, endogeneity of LS and over-identification per equation
    (:mod:`vesselid.identify.specification`, when available), on the estimator's own
    final instruments and regressors."""
    try:
        from vesselid.identify import specification
    except ImportError:
        return {}
    fn = getattr(specification, "equation_diagnostics", None)
    if fn is None:  # pragma: no cover - older module
        return {}
    from vesselid.identify.covariance import LARGE_ROWS

    out: dict[str, Any] = {}
    # equations with the same terms share their rows' work (one equation: nothing to
    # share, and nothing kept for another)
    shared: dict[str, Any] = {}
    for i, s in enumerate(spec.states):
        d = designs[i]
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        # a long log's rows are centred in the designs' own buffers (the designs' last
        # use: no second copy of the instruments), its target formed in the residual's;
        # short logs keep them as they are
        large = d.owned and np.shape(d.z)[0] > LARGE_ROWS
        if large:
            y = d.resid
            y += d.phi @ theta[sl]
        else:
            y = d.resid + d.phi @ theta[sl]
        out[s] = fn(d.z, d.phi, y, d.starts, zero_mean=d.zero_mean, skip_first=False,
                    names=[str(t) for t in spec.equations[s]], cov_type=cov_type,
                    shared=shared if spec.n_states > 1 else None, overwrite=large)
    return out


def _residual_checks(spec: ModelSpec, data: RegressionData, resid: np.ndarray
                     ) -> dict[str, Any]:
    """Residual whiteness (Ljung–Box) and residual–input cross-correlation."""
    try:
        from vesselid.identify import specification
    except ImportError:
        return {}
    corr = specification.residual_correlations(
        resid, data.u, data.starts, outputs=list(spec.states), inputs=list(spec.inputs))
    white = specification.ljung_box(resid, data.starts, names=list(spec.states))
    return {"whiteness": {k: v.to_dict() for k, v in white.items()},
            "residual_correlation": corr.to_dict()}


def _target_rule(spec: ModelSpec, target: str) -> str:
    """The documented target rule, as reported in results.

    ``"measured"`` (default): the measured state ``y₁(k)`` is predicted, as in (4)
    and (10); an ``[aggregate]`` relation only changes the regressors (9).
    ``"aggregated"``: the aggregated signal ``ỹ(k)`` is also the target — the
    reading that reproduces the paper's Table 2 (``vesselid reproduce --table 2``
    uses it and says so). Both are consistent with zero-mean simulated instruments
    when the current is independent of the input.
    """
    if not spec.aggregate:
        return "measured"
    return target


def _check_rank(phi: np.ndarray, spec: ModelSpec, blocks: np.ndarray, names: list[str]) -> None:
    from vesselid.identify.diagnostics import check_moment_range

    check_moment_range(phi, names)  # overflow first: a Gram matrix of inf says nothing
    problems = []
    gram = phi.T @ phi  # one BLAS pass; each block's full-rank screen reads its part
    for i, s in enumerate(spec.states):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        terms = [str(t) for t in spec.equations[s]]
        for group in collinear_terms(phi[:, sl], terms, gram=gram[sl, sl]):
            problems.append(f"equation {s!r}: {', '.join(group)}")
    if problems:
        hint = ""
        mod = modulus_signals(spec)
        if mod:
            hint = (" (a state that never changes sign makes |x| equal ±x; use experiments "
                    "that cover both signs or drop one of the terms)")
        raise RankDeficientError("collinear regressors — " + "; ".join(problems) + hint)


def _free_run_fit(data: RegressionData, spec: ModelSpec, theta: np.ndarray,
                  sims: list[np.ndarray] | None = None):
    """Free-run (simulation) fit per state, ``100 (1 − r)`` (:func:`free_run_ratio`)."""
    ratio, all_ok = free_run_ratio(data, spec, theta, sims)
    fit = 100.0 * (1.0 - ratio)
    return {st: float(fit[i]) for i, st in enumerate(spec.states)}, all_ok


def _base_covariance(data: RegressionData, spec: ModelSpec, base: IterationResult,
                     cov_fn: Any) -> np.ndarray:
    """The covariance of the IV_E{ζ}=0 iteration ``base``'s own estimate (its designs:
    instruments simulated from its auxiliary model, centred; pooled)."""
    if not np.all(np.isfinite(base.theta[0])):
        return np.full((spec.n_params, spec.n_params), np.nan)
    codes = spec.codes
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, codes.factors)
    # the designs of methods.RefinedIV(zero_mean=True) for this iteration
    z, _ = kernels.instrument_matrix(data.target, data.u, data.starts, base.theta_aux[0],
                                     codes.factors, codes.equation, spec.n_states)
    designs = square_designs(data, spec, z, phi, base.theta[0], zero_mean=True)
    blocks = block_starts(spec)
    cov = np.zeros((spec.n_params, spec.n_params))
    for i, d in enumerate(designs):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        cov[sl, sl] = cov_fn(d, combine="pooled")[0]
    return cov


def _fixed_point_step_in_se(step: np.ndarray, cov: np.ndarray) -> float:
    """The largest last fixed-point step ``|T(θ) − θ|`` of any parameter, in that
    parameter's standard errors (``0`` for a closed form; ``inf`` where a standard error
    is zero or undefined while the step is not)."""
    step = np.abs(np.nan_to_num(np.asarray(step, dtype=float), nan=np.inf))
    se = np.sqrt(np.abs(np.diag(cov)))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(step == 0, 0.0, step / se)
    ratio = np.where(np.isfinite(ratio), ratio, np.inf)
    return float(ratio.max()) if ratio.size else 0.0
