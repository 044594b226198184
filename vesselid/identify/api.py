"""``identify``: a trial log and a model spec in, an :class:`IdentificationResult` out."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from vesselid.identify.base import Estimator
from vesselid.identify.options import DEFAULT_COMBINE, FitOptions
from vesselid.identify.registry import DEFAULT_METHOD, get_estimator
from vesselid.identify.results import IdentificationResult
from vesselid.model.spec import ModelSpec

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["DEFAULT_COMBINE", "asymptotic_covariance", "identify"]


def identify(log: Any, spec: ModelSpec | None = None, method: str | Estimator = DEFAULT_METHOD,
             options: FitOptions | None = None, **overrides: Any) -> IdentificationResult:
    """Identify the parameters of a second-order modulus model from a trial log.

    Parameters
    ----------
    log : TrialLog or DataFrame
        Trial log with one column per state, input and (for aggregate relations)
        sensor; an optional ``experiment`` column splits it into experiments.
    spec : ModelSpec, optional
        Model structure; default the spec stored in the log's metadata.
    method : str or Estimator
        A name in :data:`ESTIMATORS` (default :data:`DEFAULT_METHOD`) or an
        estimator object.
    options : FitOptions, optional
        The options of the estimation as one object
        (:class:`~vesselid.identify.options.FitOptions`, validated when built); the
        keywords below replace its fields.
    **overrides
        The fields of :class:`~vesselid.identify.options.FitOptions` by name (a bad value
        is an :class:`~vesselid.errors.IdentificationError`, an unknown name a
        ``TypeError``), and ``fallback`` and ``dt_tolerance``:
    combine : {"pooled", "stacked"}
        Multi-experiment form: ``"stacked"`` solves the ``p N_E`` equations (6)/(10)
        in the least-squares sense as the paper writes them; ``"pooled"`` sums the
        per-experiment normal equations (the default; see docs/method-notes.md).
    target : {"measured", "aggregated"}
        Regression target with an ``[aggregate]`` relation: the measured state
        ``y₁(k)`` as in (10) (default) or the aggregated signal ``ỹ(k)`` (the reading
        that reproduces Table 2). Without an aggregate relation both are ``y(k)``.
    cov_type : str, optional
        Covariance estimator (``--cov``); default the package default.
    cov_config : mapping, optional
        Options of the covariance estimator (e.g. kernel, bandwidth).
    instruments : ndarray (T, P), optional
        User-supplied instruments (rows aligned with the log's experiments in
        ``TrialLog.experiments()`` order, columns in parameter order); skips the
        refined iteration (methods ``iv`` and ``iv-zero-mean`` only).
    theta_start : array-like, optional
        Start of the refined iteration instead of the LS estimate.
    max_iter, tol : int, float
        Refined-iteration limits (relative fixed-point residual).
    eta : mapping state -> float, optional
        Known noise bounds for the A10/A15 design check; default ``3 σ`` of the LS
        one-step residuals of each state.
    design_threshold : float
        Largest share of samples within ``η`` of zero before warning.
    weak_instrument_cond : float
        Warn when the equilibrated ``ZᵀΦ`` has a larger condition number.
    min_samples : int, optional
        Minimum samples per experiment (default: parameters per equation + 2).
    sensor_noise : mapping state -> float, or False, optional
        Std of the white sensor noise on each regressor signal; the refined-IV family
        (``auto``, ``sriv``, ``gmm-*``) then corrects the square modulus regressors for
        it (``y|y| − σ² sign(y)``, ``y² − σ²``; :mod:`vesselid.identify.eiv`). Default
        the log's ``metadata["sensor_noise_std"]`` (written by ``vesselid sea-trial``);
        ``False``: no correction.
    noise_order : int, optional
        AR order of the noise-model prefilter of the estimators that use one (``sriv``,
        ``auto``'s fallback) instead of their default 4 (an integer in 1..50). A setting
        of the estimator, never read from the log: ``vesselid sea-trial`` prints the order
        its trials need (:data:`vesselid.studies.planner.SRIV_ORDER`, 16); a
        ``metadata["noise_order"]`` in a log is ignored with a ``FutureWarning``.
    fallback : bool, optional
        Run the fallback chain (:mod:`vesselid.identify.fallback`): when ``method`` fails
        on this log (no finite estimate, an unstable model, non-finite fit figures, no
        convergence), the next estimator of :data:`~vesselid.identify.fallback.CHAIN` is
        tried, and the result records every estimator tried
        (``diagnostics["fallback_chain"]``). Default: on for the default method (by
        name), off for an explicitly chosen one; never with ``instruments``.

    dt_tolerance : float or None, optional
        Relative tolerance of the sampling check (:func:`vesselid.data.sampling.check_sampling`,
        default :data:`vesselid.data.sampling.DEFAULT_TOLERANCE`): a log with a ``time``
        column whose steps are irregular beyond it, or whose interval disagrees with the
        spec's ``dt``, is refused (:class:`~vesselid.data.sampling.SamplingError`, one line
        naming ``vesselid ingest --dt``) — the model is a discrete-time model at ``dt``.
        ``None`` skips the check (rows taken as samples at ``dt`` whatever the time column
        says).

    Returns
    -------
    IdentificationResult

    Raises
    ------
    LogValidationError
        Missing columns, NaN/inf, non-increasing time; irregular sampling or an interval
        other than the spec's ``dt`` (:class:`~vesselid.data.sampling.SamplingError`).
    RankDeficientError
        Collinear regressors; the message names the terms.
    IdentificationError
        Too few samples, unknown method or option.
    EstimationFailedError
        No finite estimate (an explicitly chosen method: singular instrument equations,
        an auxiliary model that diverges from every start); with the fallback chain
        :class:`~vesselid.errors.NoUsableModelError`, only when no estimator of the chain
        gave a finite one (``exc.chain`` lists them).

    Notes
    -----
    Check ``result.status`` (``"ok"``, ``"not converged"``, ``"unstable"``,
    ``"non-finite"``) before using an estimate: the last three are returned for
    inspection, never as a usable model (``vesselid identify`` exits 3 on them).
    """
    _check_sampling(log, spec, overrides.pop("dt_tolerance", "default"))
    fallback = overrides.pop("fallback", None)
    fit_options = FitOptions.of(options, **overrides)
    if fallback is None:
        fallback = isinstance(method, str) and method == DEFAULT_METHOD
    if fallback and fit_options.instruments is None:
        from vesselid.identify.fallback import CHAIN, identify_with_fallback

        first = get_estimator(method)
        return identify_with_fallback(
            log, spec, (first, *(m for m in CHAIN if m != first.name)), fit_options)
    return get_estimator(method).fit(log, spec, fit_options)



def _check_sampling(log: Any, spec: ModelSpec | None, tolerance: Any) -> None:
    """``identify``'s sampling check (``dt_tolerance``; ``None``: none)."""
    if tolerance is None:
        return
    data = getattr(log, "data", log)
    if not hasattr(data, "columns") or "time" not in data.columns:
        return  # rows are the samples; from_log refuses what is not a log
    import numbers

    from vesselid.data.sampling import DEFAULT_TOLERANCE, check_sampling

    if isinstance(tolerance, str) and tolerance == "default":
        tolerance = DEFAULT_TOLERANCE
    if isinstance(tolerance, bool) or not isinstance(tolerance, numbers.Real):
        from vesselid.errors import IdentificationError

        raise IdentificationError(f"dt_tolerance must be a number in [0, 1) or None, "
                                  f"got {tolerance!r}")
    model = spec if spec is not None else getattr(log, "spec", None)
    check_sampling(data, getattr(model, "dt", None), tolerance=float(tolerance))

def asymptotic_covariance(
    log: Any,
    spec: ModelSpec | None = None,
    *,
    method: str | Estimator = DEFAULT_METHOD,
    cov_type: str | None = None,
    cov_config: Mapping[str, Any] | None = None,
    **fit_options: Any,
) -> pd.DataFrame:
    """Predicted covariance of ``method``'s estimate for a planned trial.

    Simulate the planned trial (inputs, experiment lengths, the vessel's best-known
    θ and disturbances) into ``log`` and call this: the estimator runs on it and the
    sandwich ``(AᵀWA)⁻¹AᵀW Ŝ W A(AᵀWA)⁻¹`` (``A = Σ ζ φᵀ`` with the estimator's own
    instruments — simulated from the auxiliary model, plus delayed measurements when
    ``auto``'s C and colour tests keep them — and ``Ŝ`` the ``cov_type`` long-run
    variance of ``ζ ε``) is returned, indexed like ``identify(...).params``. Warnings of the fit are
    silenced (a planning call, not an identification).
    """
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, spec, method, cov_type=cov_type, cov_config=cov_config,
                       **fit_options)
    return res.cov
