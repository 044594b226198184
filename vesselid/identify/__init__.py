"""Identification of second-order modulus models from trial logs.

>>> from vesselid.identify import identify
>>> result = identify(log, spec, method="iv-zero-mean")   # doctest: +SKIP
>>> print(result.summary())                               # doctest: +SKIP

Methods: ``"ls"`` (16), ``"iv"`` (refined instrumental variables, (4) and (6)),
``"iv-zero-mean"`` (the paper's IV_{E{ζ}=0}, consistent under Lemma 3.1, and with
an ``[aggregate]`` relation in the spec under Lemma 4.1 via the predictor (9)).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from vesselid.diagnostics import (
    collinear_terms,
    condition_number,
    design_margins,
    modulus_signals,
    nrmse_fit,
)
from vesselid.errors import (
    ConvergenceWarning,
    ExperimentDesignWarning,
    IdentificationError,
    RankDeficientError,
    WeakInstrumentWarning,
)
from vesselid.identify import kernels
from vesselid.identify.data import RegressionData, block_starts, from_arrays, from_log
from vesselid.identify.estimators import (
    COMBINE_MODES,
    METHODS,
    STOP_FIXED,
    IterationResult,
    estimate,
    moments_from_matrices,
    solve_moments,
)
from vesselid.identify.results import IdentificationResult
from vesselid.model import ModelSpec
from vesselid.regressors import weights_matrix
from vesselid.simulate import simulate_states

__all__ = [
    "COMBINE_MODES",
    "DEFAULT_COMBINE",
    "METHODS",
    "IdentificationResult",
    "RegressionData",
    "estimate",
    "from_arrays",
    "from_log",
    "identify",
]

#: Default way to combine experiments (see README "Multi-experiment equations").
DEFAULT_COMBINE = "pooled"


def identify(
    log: Any,
    spec: ModelSpec | None = None,
    method: str = "iv-zero-mean",
    *,
    combine: str = DEFAULT_COMBINE,
    instruments: np.ndarray | None = None,
    theta_start: Any | None = None,
    max_iter: int = 100,
    tol: float = 1e-9,
    eta: Mapping[str, float] | None = None,
    design_threshold: float = 0.01,
    weak_instrument_cond: float = 1e6,
    min_samples: int | None = None,
) -> IdentificationResult:
    """Identify the parameters of a second-order modulus model from a trial log.

    Parameters
    ----------
    log : TrialLog or DataFrame
        Trial log with one column per state, input and (for aggregate relations)
        sensor; an optional ``experiment`` column splits it into experiments.
    spec : ModelSpec, optional
        Model structure; default the spec stored in the log's metadata.
    method : {"ls", "iv", "iv-zero-mean"}
        Estimator.
    combine : {"pooled", "stacked"}
        Multi-experiment form: ``"stacked"`` solves the ``p N_E`` equations (6)/(10)
        in the least-squares sense as the paper writes them; ``"pooled"`` sums the
        per-experiment normal equations (the default; see README for the evidence).
    instruments : ndarray (T, P), optional
        User-supplied instruments (rows aligned with the log's experiments in
        ``TrialLog.experiments()`` order, columns in parameter order); skips the
        refined iteration.
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

    Returns
    -------
    IdentificationResult

    Raises
    ------
    LogValidationError
        Missing columns, NaN/inf, non-increasing time.
    RankDeficientError
        Collinear regressors; the message names the terms.
    IdentificationError
        Too few samples, unknown method, an auxiliary model that diverges from the
        start, singular instrument equations.
    """
    if method not in METHODS:
        raise IdentificationError(f"unknown method {method!r}; choose from {list(METHODS)}")
    if combine not in COMBINE_MODES:
        raise IdentificationError(f"unknown combine {combine!r}; choose from {list(COMBINE_MODES)}")
    data, spec = from_log(log, spec, min_samples=min_samples)
    codes = spec.codes
    fac = codes.factors
    names = [f"{eq}: {term}" for eq, term in spec.param_index]
    blocks = block_starts(spec)
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, fac)
    rows = _equation_rows(data)
    _check_rank(phi[rows], spec, blocks, names)

    warn_msgs: list[str] = []

    def _warn(msg: str, category: type[Warning]) -> None:
        warn_msgs.append(msg)
        warnings.warn(msg, category, stacklevel=3)

    if instruments is not None:
        z_user = np.asarray(instruments, dtype=float)
        if z_user.shape != phi.shape:
            raise IdentificationError(
                f"instruments must have shape {phi.shape} (rows × parameters), got {z_user.shape}"
            )
        if not np.all(np.isfinite(z_user[rows])):
            raise IdentificationError("user-supplied instruments hold NaN or inf")
        if method == "ls":
            raise IdentificationError("instruments are not used by method 'ls'")
        mom = moments_from_matrices(data, spec, z_user, phi)
        theta, ok = solve_moments(mom, data, spec, zero_mean=method == "iv-zero-mean",
                                  combine=combine)
        if not ok[0]:
            raise IdentificationError("the IV equations with the supplied instruments are singular")
        it = IterationResult(theta=theta, theta_aux=theta, converged=np.array([True]),
                             iterations=np.array([0]), reason=np.array([STOP_FIXED], dtype=object),
                             residual=np.zeros(1), oscillation=np.zeros(1, dtype=bool))
        z = z_user
    else:
        start = None if theta_start is None else spec.vector_from(theta_start)
        it = estimate(data, spec, method, combine=combine, theta_start=start,
                      max_iter=max_iter, tol=tol, keep_history=True)
        if not np.all(np.isfinite(it.theta[0])):
            tried = ("the LS estimate and basic IV with delayed measurements"
                     if it.start is not None and it.start[0] == "lagged-iv"
                     else "the given start" if theta_start is not None else "the LS estimate")
            raise IdentificationError(
                f"{method}: {it.reason[0]} (starts tried: {tried}); no instrument could be "
                "formed — supply theta_start (a stable model) or instruments, or use longer "
                "or better-excited experiments"
            )
        if method == "ls":
            z = phi
        else:
            z, _ = kernels.instrument_matrix(data.target, data.u, data.starts,
                                             it.theta_aux[0], fac, codes.equation,
                                             spec.n_states)
    theta = it.theta[0]
    if method != "ls" and not bool(it.converged[0]):
        _warn(f"refined IV did not converge ({it.reason[0]}, {int(it.iterations[0])} "
              f"iterations, fixed-point residual {it.residual[0]:.3g}); returning the IV "
              "estimate of the best iterate", ConvergenceWarning)
    if it.oscillation[0]:
        _warn("the refined iteration oscillated; the step was damped", ConvergenceWarning)

    zero_mean = method == "iv-zero-mean"
    zc = _center(z, data) if zero_mean else z
    # one-step predictions φᵀθ̂ of every equation at once (NaN at each experiment's first row)
    pred = phi @ weights_matrix(codes, theta)
    resid = data.target - pred
    cov = np.zeros((spec.n_params, spec.n_params))
    cond: dict[str, float] = {}
    for i, s in enumerate(spec.states):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        cov[sl, sl], cond[s] = _covariance(zc[:, sl], phi[:, sl], resid[:, i], data, combine)
        if method != "ls" and cond[s] > weak_instrument_cond:
            _warn(f"weak instruments in equation {s!r}: cond(ZᵀΦ) = {cond[s]:.3g}",
                  WeakInstrumentWarning)

    from vesselid.identify import specification as spec_tests

    per_equation = {}
    for i, s in enumerate(spec.states):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        if method != "ls":
            per_equation[s] = spec_tests.equation_diagnostics(
                zc[:, sl], phi[:, sl], data.target[:, i], data.starts, zero_mean=zero_mean,
                names=[str(t) for t in spec.equations[s]])
    residual_corr = spec_tests.residual_correlations(
        resid, data.u, data.starts, outputs=list(spec.states), inputs=list(spec.inputs))
    whiteness = spec_tests.ljung_box(resid, data.starts, names=list(spec.states))

    fit_one = {s: nrmse_fit(data.target[rows, i], pred[rows, i])
               for i, s in enumerate(spec.states)}
    fit_free, free_ok = _free_run_fit(data, spec, theta)
    if not free_ok:
        _warn("free-run simulation of the estimated model diverged", ConvergenceWarning)

    if eta is None:
        resid_std = np.sqrt(np.nanmean(resid**2, axis=0))
        eta_used = {s: 3.0 * float(resid_std[i]) for i, s in enumerate(spec.states)}
        eta_source = "3 x std of one-step residuals"
    else:
        eta_used = {s: float(eta.get(s, 0.0)) for s in spec.states}
        eta_source = "given"
    design = design_margins(data.regsig, data.starts, spec, eta_used, data.experiment_ids,
                            threshold=design_threshold)
    for _, r in design[~design["ok"]].iterrows():
        _warn(f"state {r['state']!r} in experiment {r['experiment']} is within η={r['eta']:.3g}"
              f" of zero in {100 * r['share_within_eta']:.1f} % of samples "
              f"({r['sign_changes']} sign changes): the modulus cannot be treated as smooth "
              "(A10/A15)", ExperimentDesignWarning)

    index = spec.param_index
    history = None
    if it.history:
        history = pd.DataFrame(np.vstack([h[0] for h in it.history]),
                               columns=index).rename_axis("iteration")
    diagnostics: dict[str, Any] = {
        "combine": combine,
        "instrument_condition": cond,
        "fit_one_step": fit_one,
        "fit_free_run": fit_free,
        "fixed_point_residual": float(it.residual[0]),
        "oscillation": bool(it.oscillation[0]),
        "start": None if it.start is None else str(it.start[0]),
        "design": design,
        "design_eta": eta_used,
        "design_eta_source": eta_source,
        "modulus_states": modulus_signals(spec),
        "specification": per_equation,
        "whiteness": {k: v.to_dict() for k, v in whiteness.items()},
        "residual_correlation": residual_corr.to_dict(),
        "warnings": warn_msgs,
    }
    return IdentificationResult(
        method=method,
        spec=spec,
        params=pd.Series(theta, index=index, name="estimate"),
        cov=pd.DataFrame(cov, index=index, columns=index),
        residuals=pd.DataFrame(resid, columns=list(spec.states)),
        converged=bool(it.converged[0]),
        iterations=int(it.iterations[0]),
        stop_reason=str(it.reason[0]),
        n_samples=int(data.starts[-1]),
        n_experiments=data.n_segments,
        diagnostics=diagnostics,
        history=history,
    )


def _equation_rows(data: RegressionData) -> np.ndarray:
    rows = np.ones(int(data.starts[-1]), dtype=bool)
    rows[data.starts[:-1]] = False
    return rows


def _check_rank(phi: np.ndarray, spec: ModelSpec, blocks: np.ndarray, names: list[str]) -> None:
    from vesselid.diagnostics import check_moment_range

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


def _center(z: np.ndarray, data: RegressionData) -> np.ndarray:
    """Zero-mean instruments: subtract each component's mean per experiment (A7)."""
    out = z.copy()
    for s in range(data.n_segments):
        sl = slice(int(data.starts[s]) + 1, int(data.starts[s + 1]))
        out[sl] -= out[sl].mean(axis=0)
    return out


def _covariance(z, phi, resid, data: RegressionData, combine: str):
    """Asymptotic covariance of one equation block and the condition number of ZᵀΦ."""
    p = phi.shape[1]
    a_list, m_list, n_list = [], [], []
    for s in range(data.n_segments):
        sl = slice(int(data.starts[s]) + 1, int(data.starts[s + 1]))
        zs, ps = z[sl], phi[sl]
        a_list.append(zs.T @ ps)
        m_list.append(zs.T @ zs)
        n_list.append(zs.shape[0])
    ok = np.isfinite(resid)
    sigma2 = float(np.mean(resid[ok] ** 2)) if ok.any() else float("nan")
    a_sum = np.sum(a_list, axis=0)
    cond = condition_number(a_sum)
    try:
        if combine == "pooled" or len(a_list) == 1:
            a_inv = np.linalg.inv(a_sum)
            cov = sigma2 * a_inv @ np.sum(m_list, axis=0) @ a_inv.T
        else:
            h = sum(a.T @ a / n**2 for a, n in zip(a_list, n_list, strict=True))
            meat = sum(a.T @ m @ a / n**4 for a, m, n in zip(a_list, m_list, n_list, strict=True))
            h_inv = np.linalg.inv(h)
            cov = sigma2 * h_inv @ meat @ h_inv
    except np.linalg.LinAlgError:
        cov = np.full((p, p), np.inf)
    return cov, cond


def _free_run_fit(data: RegressionData, spec: ModelSpec, theta: np.ndarray):
    """Free-run (simulation) fit per state, experiment by experiment."""
    fits_num = np.zeros(spec.n_states)
    fits_den = np.zeros(spec.n_states)
    all_ok = True
    for s in range(data.n_segments):
        sl = data.segment(s)
        y = data.target[sl]
        v = data.sensor[sl] if data.sensor is not None else None
        x = simulate_states(spec, data.u[sl], theta=theta, x0=y[0], v=v,
                            raise_on_divergence=False)
        if not np.all(np.isfinite(x)):
            all_ok = False
            continue
        fits_num += np.sum((y - x) ** 2, axis=0)
        fits_den += np.sum((y - y.mean(axis=0)) ** 2, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit = 100.0 * (1.0 - np.sqrt(fits_num / fits_den))
    if not all_ok and not np.any(fits_den):
        fit[:] = np.nan
    return {st: float(fit[i]) for i, st in enumerate(spec.states)}, all_ok
