"""Least squares, instrumental variables and the refined-IV iteration, batched over groups.

This is the unchecked fast path (in the spirit of linearmodels' ``estimate_parameters``):
arrays in, parameter arrays out, no DataFrames. :func:`vesselid.identify.identify`
wraps it with validation, covariance, diagnostics and a results object, and the
Monte Carlo engine calls it directly for thousands of runs at once.

Equations (paper):

* LS (16): ``θ = (Σ φφᵀ)⁻¹ Σ φ y``.
* IV (4): ``θ = sol{ Σ ζ (y − φᵀθ) = 0 }``; with zero-mean instruments (A7) ζ is
  centred per experiment and component.
* Multi-experiment (6)/(10): ``stacked`` solves the ``p·N_E`` equations
  ``(1/N_D) Σ_k Z_E (y − Φᵀθ) = 0`` in the least-squares sense, each instrument's rows
  weighted to be unit-free (:func:`vesselid.identify.linalg.stacked_row_weights`);
  ``pooled`` sums the per-experiment normal equations, ``(Σ_E Σ_k Z_E Φᵀ) θ = Σ_E Σ_k Z_E y``.
  With one experiment both are the same.
* Refined IV (§6, Young 2008): instruments simulated from the latest estimate,
  iterated to a fixed point ``θ = T(θ)``, with step control (below).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from vesselid.errors import IdentificationError
from vesselid.identify import linalg
from vesselid.identify.backend import kernels
from vesselid.identify.data import (
    RegressionData,
    block_starts,
    duplicate_blocks,
)
from vesselid.identify.options import COMBINE_MODES
from vesselid.model.spec import ModelSpec

__all__ = [
    "COMBINE_MODES",
    "IterationResult",
    "Moments",
    "compute_moments",
    "estimate",
    "least_squares",
    "refined_iv",
    "solve_moments",
]


#: Reasons the refined iteration stops.
STOP_CONVERGED = "converged"
STOP_MAX_ITER = "maximum iterations reached"
STOP_DIVERGED = "auxiliary model diverged"
STOP_START_DIVERGED = "auxiliary model of the initial estimate diverges"
STOP_SINGULAR = "instrument matrix singular"
STOP_FIXED = "user-supplied instruments (no iteration)"
STOP_STALLED = ("stalled: the fixed-point residual stopped decreasing (the auxiliary "
                "simulation is numerically sensitive to θ)")

#: Stall rule of the refined iteration: stop when the best fixed-point residual has not
#: improved for ``STALL_PATIENCE`` evaluations of ``T`` while it is below ``STALL_TOL``.
STALL_PATIENCE = 20
STALL_TOL = 1e-4

#: Evaluations of ``T`` averaged after a stall by the checked path (:func:`stall_averaging`).
STALL_AVERAGE = 96

_STALL_AVERAGE: ContextVar[int] = ContextVar("stall_average", default=0)


@contextmanager
def stall_averaging(evaluations: int = STALL_AVERAGE) -> Iterator[None]:
    """Inside this block a stalled refined iteration locates its fixed point by averaging.

    A stall is a fixed-point map whose value jumps at the level of the auxiliary
    simulation's numerical sensitivity (``T(θ) = θ* + noise``): its residual cannot fall
    below that noise, but the mean of ``evaluations`` further evaluations
    ``θ ← T(θ)`` locates ``θ*`` to ``sd / √evaluations``. The averaged estimate
    and that precision are returned (``info["stall_average"]``), so that the caller can
    judge convergence in standard errors. Only groups that stalled are touched: converged
    iterations are bit-identical with or without it. ``identify`` uses it; the batched
    Monte Carlo path does not.
    """
    token = _STALL_AVERAGE.set(int(evaluations))
    try:
        yield
    finally:
        _STALL_AVERAGE.reset(token)


@dataclass
class Moments:
    """Per-segment sums (see :mod:`vesselid.identify.kernels`)."""

    zphi: np.ndarray
    zy: np.ndarray
    z: np.ndarray
    phi: np.ndarray
    y: np.ndarray
    count: np.ndarray
    status: np.ndarray


def _empty_moments(n_seg: int, n_par: int, n: int) -> Moments:
    return Moments(
        zphi=np.zeros((n_seg, n_par, n_par)),
        zy=np.zeros((n_seg, n_par)),
        z=np.zeros((n_seg, n_par)),
        phi=np.zeros((n_seg, n_par)),
        y=np.zeros((n_seg, n)),
        count=np.zeros(n_seg, dtype=np.int64),
        status=np.zeros(n_seg, dtype=np.int64),
    )


def _layout(spec: ModelSpec) -> tuple[np.ndarray, np.ndarray]:
    """``(block_starts(spec), duplicate_blocks(spec))``, remembered on the spec (which is
    immutable; like its ``codes``): the refined iteration reads them at every evaluation
    of ``T``. Read-only use only (the kernels and the solvers index them)."""
    memo = spec.__dict__.get("_estimator_layout")
    if memo is None:
        memo = spec.__dict__["_estimator_layout"] = (block_starts(spec),
                                                     duplicate_blocks(spec))
    return memo


def _limits(data: RegressionData, factor: float) -> np.ndarray:
    return factor * np.maximum(data.target_abs_max, 1.0)


def compute_moments(
    data: RegressionData,
    spec: ModelSpec,
    theta: np.ndarray | None = None,
    *,
    active: np.ndarray | None = None,
    out: Moments | None = None,
    limit_factor: float = 1e3,
    limits: np.ndarray | None = None,
    mode: int | None = None,
) -> Moments:
    """Accumulate LS moments (``theta is None``) or IV moments with instruments
    simulated from the auxiliary model ``theta`` (shape ``(G, P)``); ``mode``
    :data:`~vesselid.identify.kernels.MODE_LAGGED` gives basic-IV moments with
    delayed-measurement instruments."""
    codes = spec.codes
    n_par = codes.n_params
    mom = out or _empty_moments(data.n_segments, n_par, spec.n_states)
    if mode is None:
        mode = kernels.MODE_LS if theta is None else kernels.MODE_SIMULATED
    th = np.zeros((data.n_groups, n_par)) if theta is None else np.ascontiguousarray(theta, float)
    act = np.ones(data.n_groups, dtype=np.bool_) if active is None else active
    lim = _limits(data, limit_factor) if limits is None else limits
    blocks, dup = _layout(spec)
    kernels.moments(
        data.regsig, data.target, data.u, data.starts, data.group, th, act, int(mode),
        codes.factors, codes.equation, blocks, dup, lim,
        mom.zphi, mom.zy, mom.z, mom.phi, mom.y, mom.count, mom.status,
    )
    return mom


def _bound_moments(data: RegressionData, spec: ModelSpec, mom: Moments,
                   limits: np.ndarray) -> Callable[[np.ndarray, np.ndarray], bool] | None:
    """:func:`compute_moments` with simulated instruments into ``mom`` for the refined
    iteration, its specialised kernel looked up once: ``fn(theta, active)`` runs the same
    kernel on the same arrays (False where it cannot; then :func:`compute_moments`). None
    on the numpy path or without a specialised kernel of this structure."""
    from vesselid.identify.backend import numpy_active

    if numpy_active():
        return None
    codes = spec.codes
    blocks = _layout(spec)[0]
    fast = kernels.specialised_moments(data.regsig.shape[1], data.u.shape[1], codes.factors,
                                       codes.equation, blocks)
    if fast is None:
        return None
    # what kernels.moments decides for these arrays
    parallel = (data.starts.shape[0] > 2
                and data.target.shape[0] >= kernels.PARALLEL_MIN_SAMPLES)
    arrays = (data.regsig, data.target, data.u, data.starts, data.group)
    sums = (mom.zphi, mom.zy, mom.z, mom.phi, mom.y, mom.count, mom.status)

    def run(theta: np.ndarray, active: np.ndarray) -> bool:
        return fast(parallel, *arrays, np.ascontiguousarray(theta, float), active, True,
                    limits, *sums)

    return run


def moments_from_matrices(
    data: RegressionData, spec: ModelSpec, z_mat: np.ndarray, phi_mat: np.ndarray
) -> Moments:
    """Moments from explicit instrument and regressor matrices (rows aligned with data).

    Row ``k`` holds ζ(k) / φ(k) for the equation predicting ``y(k)``; the first row
    of every segment is ignored.
    """
    n_par = spec.n_params
    mom = _empty_moments(data.n_segments, n_par, spec.n_states)
    eq = spec.codes.equation
    for s in range(data.n_segments):
        sl = slice(int(data.starts[s]) + 1, int(data.starts[s + 1]))
        z, phi, y = z_mat[sl], phi_mat[sl], data.target[sl]
        y_eq = y[:, eq]
        same = eq[:, None] == eq[None, :]
        mom.zphi[s] = (z.T @ phi) * same
        mom.zy[s] = (z * y_eq).sum(axis=0)
        mom.z[s] = z.sum(axis=0)
        mom.phi[s] = phi.sum(axis=0)
        mom.y[s] = y.sum(axis=0)
        mom.count[s] = z.shape[0]
    return mom


def _segment_equations(mom: Moments, spec: ModelSpec, zero_mean: bool):
    """Per-segment ``A_s θ = b_s`` (block-diagonal A), centred if ``zero_mean``."""
    a = mom.zphi.copy()
    b = mom.zy.copy()
    if zero_mean and a.shape[0] == 1:  # one segment: the same products and quotients
        n = max(int(mom.count[0]), 1)
        eq = spec.codes.equation
        same = eq[:, None] == eq[None, :]
        a[0] -= np.multiply.outer(mom.z[0], mom.phi[0]) / n * same
        b[0] -= mom.z[0] * mom.y[0, eq] / n
    elif zero_mean:
        n = np.maximum(mom.count, 1)[:, None]
        eq = spec.codes.equation
        same = eq[:, None] == eq[None, :]
        a -= np.einsum("sp,sq->spq", mom.z, mom.phi) / n[:, :, None] * same
        b -= mom.z * mom.y[:, eq] / n
    return a, b


def solve_moments(
    mom: Moments,
    data: RegressionData,
    spec: ModelSpec,
    *,
    zero_mean: bool = False,
    combine: str = "pooled",
    active: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve the (multi-experiment) IV/LS equations for every group.

    Returns
    -------
    theta : ndarray (G, P)
        Estimates; rows of failed groups are NaN (callers must check ``ok``).
    ok : ndarray (G,) bool
        False where an equation block is singular.
    """
    if combine not in COMBINE_MODES:
        raise IdentificationError(f"combine must be one of {COMBINE_MODES}, got {combine!r}")
    n_groups = data.n_groups
    act = np.ones(n_groups, dtype=bool) if active is None else active
    a_seg, b_seg = _segment_equations(mom, spec, zero_mean)
    blocks = _layout(spec)[0]
    if n_groups == 1 and a_seg.shape[0] == 1 and act[0]:
        # one group of one segment (a fit): its equations as they are, block by block,
        # without the gathering of the general path (the refined iteration solves here
        # at every evaluation of T)
        theta = np.empty((1, spec.n_params))
        good = True
        for i in range(spec.n_states):
            sl = slice(int(blocks[i]), int(blocks[i + 1]))
            th_i, ok_i = _batched_solve(a_seg[:, sl, sl], b_seg[:, sl])
            theta[:, sl] = th_i
            good = good and bool(ok_i[0])
        return theta, np.array([good])
    theta = np.full((n_groups, spec.n_params), np.nan)
    ok = np.ones(n_groups, dtype=bool)
    seg_counts = np.bincount(data.group, minlength=n_groups)
    single = np.all(seg_counts == 1)
    every = bool(act.all())  # every group solved: no gathered copies, slices for rows
    rows = slice(None) if every else act
    for i in range(spec.n_states):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        a_i = a_seg[:, sl, sl]
        b_i = b_seg[:, sl]
        if single or combine == "pooled":
            if single and n_groups == 1:  # one segment: its equations as they are
                a_g, b_g = a_i, b_i
            elif single:
                order = np.argsort(data.group, kind="stable")
                a_g, b_g = a_i[order], b_i[order]
            else:
                a_g = np.zeros((n_groups, *a_i.shape[1:]))
                b_g = np.zeros((n_groups, b_i.shape[1]))
                np.add.at(a_g, data.group, a_i)
                np.add.at(b_g, data.group, b_i)
            th_i, ok_i = _batched_solve(a_g[rows], b_g[rows])
        else:
            nrm = np.maximum(mom.count, 1)[:, None]
            a_n = a_i / nrm[:, :, None]
            b_n = b_i / nrm
            th_i = np.full((int(act.sum()), a_i.shape[1]), np.nan)
            ok_i = np.ones(th_i.shape[0], dtype=bool)
            for j, g in enumerate(np.flatnonzero(act)):
                segs = np.flatnonzero(data.group == g)
                big_a = a_n[segs].reshape(-1, a_i.shape[2])
                big_b = b_n[segs].reshape(-1)
                if not (np.all(np.isfinite(big_a)) and np.all(np.isfinite(big_b))):
                    ok_i[j] = False
                    continue
                # equilibrate rows (one weight per instrument, linalg.stacked_row_weights)
                # and columns: neither the estimate nor the rank decision depends on units
                n_k = a_i.shape[1]
                r, c = linalg.equilibrate(big_a[None], groups=np.tile(np.arange(n_k),
                                                                      segs.size))
                r, c = r[0], c[0]
                sol, _, rank, _ = np.linalg.lstsq(big_a * r[:, None] * c[None, :], big_b * r,
                                                  rcond=None)
                sol = sol * c
                if rank < a_i.shape[2] or not np.all(np.isfinite(sol)):
                    ok_i[j] = False
                else:
                    th_i[j] = sol
        theta[rows, sl] = th_i
        ok[np.flatnonzero(act)[~ok_i]] = False
    ok &= act
    return theta, ok


def _batched_solve(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve a stack of square systems; singular or non-finite ones are flagged
    (:func:`vesselid.identify.linalg.solve`: column-scaled, equilibrated rank check)."""
    return linalg.solve(a, b)


def least_squares(data: RegressionData, spec: ModelSpec, *, combine: str = "pooled"):
    """LS estimate (16) per group. Returns ``(theta (G, P), ok (G,))``.

    Remembered on ``data`` (per ``spec`` and ``combine``; fresh copies are returned): the
    LS row, the LS start of both refined-IV rows and of ``auto`` in a Monte Carlo chunk
    are one computation on the same arrays (RegressionData is immutable).
    """
    memo = getattr(data, "__dict__", {}).setdefault("_least_squares", {})
    key = (id(spec), combine)
    hit = memo.get(key)
    if hit is None or hit[0] is not spec:
        mom = compute_moments(data, spec)
        hit = memo[key] = (spec, *solve_moments(mom, data, spec, combine=combine))
    return hit[1].copy(), hit[2].copy()


@dataclass
class IterationResult:
    """Outcome of the refined-IV iteration for every group."""

    theta: np.ndarray
    theta_aux: np.ndarray
    converged: np.ndarray
    iterations: np.ndarray
    reason: np.ndarray
    residual: np.ndarray
    oscillation: np.ndarray
    history: list[np.ndarray] = field(default_factory=list)
    start: np.ndarray | None = None
    #: estimator-specific per-group results (instrument set used, J/C statistics, ...)
    info: dict = field(default_factory=dict)

    @property
    def ok(self) -> np.ndarray:
        return np.all(np.isfinite(self.theta), axis=1)


def refined_iv(
    data: RegressionData,
    spec: ModelSpec,
    theta_start: np.ndarray,
    *,
    zero_mean: bool = False,
    combine: str = "pooled",
    max_iter: int = 100,
    tol: float = 1e-9,
    min_step: float = 1.0 / 64,
    limit_factor: float = 1e3,
    keep_history: bool = False,
    groups: np.ndarray | None = None,
    moment_source: Callable | None = None,
) -> IterationResult:
    """Refined instrumental variables: iterate ``θ ← θ + α (T(θ) − θ)``.

    ``T(θ)`` is the IV estimate (4)/(6) with instruments simulated from the
    auxiliary model with parameters ``θ``. The iteration starts from
    ``theta_start`` (the LS estimate in the paper) and stops when the relative
    fixed-point residual ``‖T(θ) − θ‖ / ‖θ‖ < tol``.

    Safeguards (period-2 cycles and overflowing auxiliary simulations were seen
    while prototyping):

    * step control: the step ``α`` starts at 1 and is halved whenever the
      fixed-point residual grows (this damps period-2 oscillations, whose
      iteration-map eigenvalue is near −1) or the auxiliary model of the
      candidate diverges (the candidate is then rejected);
    * the iteration stops when ``α`` falls below ``min_step`` with a diverging
      auxiliary model, after ``max_iter`` evaluations of ``T``, or when it has
      *stalled*: the best residual is below ``STALL_TOL`` and has not improved for
      ``STALL_PATIENCE`` evaluations. A stall is what an auxiliary simulation that is
      sensitive to θ looks like — e.g. a vessel model whose sway–yaw motion is locally
      unstable during full-ahead thruster manoeuvres amplifies a 1e-12 change of θ over
      thousands of samples, so ``T`` jumps at the 1e-5 level and the residual wanders
      there instead of shrinking.
      The iteration is reported as not converged, with that reason;
    * the returned estimate is ``T(θ_best)``, the IV estimate whose instruments
      come from the iterate with the smallest fixed-point residual — a genuine
      IV estimate even when the iteration did not converge.

    ``moment_source(theta, active, out, limits)``, when given, fills the moments ``out``
    instead of :func:`compute_moments` on ``data`` (which then only needs the attributes
    the solvers read): :mod:`vesselid.identify.streaming` sums them over streamed experiments.

    Returns
    -------
    IterationResult
        ``theta`` (G, P) estimates (NaN only where no instrument could be formed —
        the LS auxiliary model itself diverged or the system was singular;
        ``reason`` says which), ``converged``, ``iterations``, ``reason``,
        ``residual``, ``oscillation`` (a sign reversal of successive steps
        with a growing residual was seen).
    """
    n_groups, n_par = data.n_groups, spec.n_params
    limits = _limits(data, limit_factor)
    mom = _empty_moments(data.n_segments, n_par, spec.n_states)

    direct = _bound_moments(data, spec, mom, limits) if moment_source is None else None

    def evaluate(theta: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if moment_source is None:
            # a few finite parameters (a fit) need no cleaned copy
            finite = theta.size <= 64 and all(math.isfinite(x) for x in theta.flat)
            th = theta if finite else np.nan_to_num(theta)
            if direct is None or not direct(th, active):
                compute_moments(data, spec, th, active=active, out=mom, limits=limits)
        else:  # moments summed elsewhere (streamed experiments, a Dask cluster)
            moment_source(theta, active, mom, limits)
        if n_groups == 1:  # every segment is group 0's
            diverged = np.array([bool(np.any(mom.status != kernels.AUX_OK))])
        else:
            diverged = np.zeros(n_groups, dtype=bool)
            np.logical_or.at(diverged, data.group, mom.status != kernels.AUX_OK)
        t_theta, ok = solve_moments(mom, data, spec, zero_mean=zero_mean, combine=combine,
                                    active=active & ~diverged)
        return t_theta, ok & active & ~diverged

    theta = np.array(theta_start, dtype=float, copy=True)
    if n_groups == 1:  # a fit: the same steps on Python floats
        return _refined_one(evaluate,
                            _one_group_map(evaluate, direct, data, spec, mom, limits,
                                           zero_mean),
                            theta, groups, keep_history, max_iter, tol, min_step)
    start_ok = np.all(np.isfinite(theta), axis=1)
    if groups is not None:
        start_ok &= groups
    reason = np.full(n_groups, STOP_MAX_ITER, dtype=object)
    reason[~start_ok] = STOP_SINGULAR
    t_theta, ok = evaluate(theta, start_ok)
    failed = start_ok & ~ok
    reason[failed] = STOP_START_DIVERGED
    active = ok.copy()
    iterations = np.where(active, 1, 0)
    residual = np.full(n_groups, np.inf)
    residual[active] = _rel(t_theta[active] - theta[active], theta[active])
    best_res = residual.copy()
    best_aux = theta.copy()
    best_t = t_theta.copy()
    since_best = np.zeros(n_groups, dtype=np.int64)
    step = np.ones(n_groups)
    oscillation = np.zeros(n_groups, dtype=bool)
    converged = np.zeros(n_groups, dtype=bool)
    prev_dir = np.where(active[:, None], t_theta - theta, 0.0)
    history = [best_t.copy()] if keep_history else []

    for _ in range(max_iter - 1):
        done = active & (residual < tol)
        converged |= done
        reason[done] = STOP_CONVERGED
        active &= ~done
        stalled = active & (since_best >= STALL_PATIENCE) & (best_res < STALL_TOL)
        reason[stalled] = STOP_STALLED
        active &= ~stalled
        if not active.any():
            break
        cand = theta + step[:, None] * np.where(active[:, None], t_theta - theta, 0.0)
        t_cand, ok_c = evaluate(cand, active)
        iterations += active
        bad = active & ~ok_c
        # reject diverging candidates: shorten the step and retry from the same θ
        step[bad] *= 0.5
        give_up = bad & (step < min_step)
        reason[give_up] = STOP_DIVERGED
        active &= ~give_up
        good = active & ok_c
        res_c = np.full(n_groups, np.inf)
        res_c[good] = _rel(t_cand[good] - cand[good], cand[good])
        direction = t_cand - cand
        grew = good & (res_c > residual)
        if grew.any():  # a sign reversal of successive steps with a growing residual
            reversed_ = grew & (np.einsum("gp,gp->g", np.nan_to_num(direction), prev_dir) < 0)
            oscillation |= reversed_
        step[grew] = np.maximum(step[grew] * 0.5, min_step)
        theta[good] = cand[good]
        t_theta[good] = t_cand[good]
        residual[good] = res_c[good]
        prev_dir[good] = direction[good]
        better = good & (res_c < best_res)
        since_best += active
        since_best[better] = 0
        best_res[better] = res_c[better]
        best_aux[better] = cand[better]
        best_t[better] = t_cand[better]
        if keep_history:
            history.append(np.where(good[:, None], t_cand, np.nan))
    done = active & (residual < tol)
    converged |= done
    reason[done] = STOP_CONVERGED
    est = best_t.copy()
    info: dict = {}
    n_avg = _STALL_AVERAGE.get()
    stalled = reason == STOP_STALLED
    if n_avg and stalled.any():
        info["stall_average"] = _average_stall(evaluate, stalled, best_aux, best_t, n_avg,
                                               iterations, est, best_aux)
    est[failed | ~start_ok] = np.nan
    return IterationResult(
        theta=est,
        theta_aux=best_aux,
        converged=converged,
        iterations=iterations,
        reason=reason,
        residual=best_res,
        oscillation=oscillation,
        history=history,
        info=info,
    )


def _refined_one(evaluate: Callable, one: Callable[[list], list | None], theta: np.ndarray,
                 groups: np.ndarray | None, keep_history: bool, max_iter: int, tol: float,
                 min_step: float) -> IterationResult:
    """:func:`refined_iv` of one group (``theta`` (1, P), the start): its start,
    :func:`_iterate_one` and its result, with the flags, counters and residuals as Python
    scalars and ``T`` on Python floats (``one``, :func:`_one_group_map`); the batched
    path's tests and arithmetic, so the same numbers. ``evaluate``: the batched ``T``
    (a kept history's start, the stall averaging)."""
    start_ok = (all(math.isfinite(x) for x in theta.flat)
                and (groups is None or bool(groups[0])))
    reason = STOP_MAX_ITER if start_ok else STOP_SINGULAR
    if start_ok and not keep_history:  # (a failed start's T: NaN, shown by no history)
        t_list = one(theta[0].tolist())
        ok = t_list is not None
        t_theta = np.array([t_list]) if ok else np.full_like(theta, np.nan)
    else:
        t_theta, ok_arr = evaluate(theta, np.array([start_ok]))
        ok = bool(ok_arr[0])
    failed = start_ok and not ok
    if failed:
        reason = STOP_START_DIVERGED
    active = ok
    th, t_th = theta[0].tolist(), t_theta[0].tolist()
    residual = math.inf
    prev_dir = [0.0] * len(th)
    if active:
        prev_dir = [t - x for t, x in zip(t_th, th, strict=True)]
        residual = _rel_list(prev_dir, th)
    history = [t_theta.copy()] if keep_history else []
    (active, residual, best_res, best_aux, best_t, reason, iterations, oscillation,
     converged) = _iterate_one(one, th, t_th, prev_dir, active, residual, residual, theta,
                               t_theta, reason, 1 if active else 0,
                               history if keep_history else None, max_iter, tol, min_step)
    if active and residual < tol:
        converged, reason = True, STOP_CONVERGED
    est = best_t.copy()
    iters = np.array([iterations])
    info: dict = {}
    n_avg = _STALL_AVERAGE.get()
    if n_avg and reason == STOP_STALLED:
        info["stall_average"] = _average_stall(evaluate, np.array([True]), best_aux, best_t,
                                               n_avg, iters, est, best_aux)
    if failed or not start_ok:
        est[:] = np.nan
    return IterationResult(
        theta=est,
        theta_aux=best_aux,
        converged=np.array([converged]),
        iterations=iters,
        reason=np.array([reason], dtype=object),
        residual=np.array([best_res]),
        oscillation=np.array([oscillation]),
        history=history,
        info=info,
    )


def _one_group_map(evaluate: Callable, direct: Callable | None, data: RegressionData,
                   spec: ModelSpec, mom: Moments, limits: np.ndarray,
                   zero_mean: bool) -> Callable[[list], list | None]:
    """``T`` of a one-group ``data`` on Python floats for :func:`_iterate_one`:
    ``fn(theta)`` takes the ``P`` parameters as a list and returns ``T(θ)`` as a list, or
    None where ``evaluate`` flags the group (a diverged auxiliary model, a singular block).

    One experiment with the specialised kernel (every fit of one log): the kernel's sums
    into ``mom``, then the equations of :func:`solve_moments`'s one-group path — the
    centring of :func:`_segment_equations` and the block solves of
    :func:`vesselid.identify.linalg.solve` (:func:`~vesselid.identify.linalg.solve_rows`)
    — as the same IEEE operations in the same order on Python floats: the same bits,
    without the arrays, masks and copies of the batched path (the iteration evaluates
    ``T`` up to ``max_iter`` times). Elsewhere (several experiments, the numpy path, a
    non-finite θ) it is ``evaluate`` itself."""
    mask = np.ones(1, dtype=bool)

    def generic(theta: list) -> list | None:
        t_theta, ok = evaluate(np.array([theta], dtype=float), mask)
        return t_theta[0].tolist() if ok[0] else None

    if direct is None or data.n_segments != 1:
        return generic
    n_par = spec.n_params
    eq = spec.codes.equation.tolist()
    same = [[1.0 if ei == ej else 0.0 for ej in eq] for ei in eq]  # (a bool array's 1, 0)
    blocks = _layout(spec)[0].tolist()
    spans = [(int(lo), int(hi)) for lo, hi in pairwise(blocks)]
    buf = np.empty((1, n_par))
    zphi, zy, z, phi, y, count, status = (mom.zphi[0], mom.zy[0], mom.z[0], mom.phi[0],
                                          mom.y[0], mom.count, mom.status)
    isfinite, aux_ok, solve_rows = math.isfinite, kernels.AUX_OK, linalg.solve_rows
    rng = range(n_par)

    def one(theta: list) -> list | None:
        if not all(isfinite(x) for x in theta):
            return generic(theta)
        buf[0] = theta
        if not direct(buf, mask):
            compute_moments(data, spec, buf, active=mask, out=mom, limits=limits)
        if status[0] != aux_ok:
            return None
        a = zphi.tolist()
        b = zy.tolist()
        if zero_mean:  # _segment_equations of one segment
            n = max(int(count[0]), 1)
            zs, ps, ys = z.tolist(), phi.tolist(), y.tolist()
            a = [[a[i][j] - zs[i] * ps[j] / n * same[i][j] for j in rng] for i in rng]
            b = [b[i] - zs[i] * ys[eq[i]] / n for i in rng]
        if len(spans) == 1:
            return solve_rows(a, b)
        out: list = []
        for lo, hi in spans:
            x = solve_rows([row[lo:hi] for row in a[lo:hi]], b[lo:hi])
            if x is None:
                return None
            out += x
        return out

    return one


def _iterate_one(evaluate: Callable[[list], list | None], theta: list, t_theta: list,
                 prev_dir: list, active: bool, residual: float, best_res: float,
                 best_aux: np.ndarray, best_t: np.ndarray, reason: str, iterations: int,
                 history: list | None, max_iter: int, tol: float, min_step: float) -> tuple:
    """The iteration of :func:`refined_iv` for one group: the same steps, tests and
    arithmetic, on the parameters as lists of Python floats (``evaluate``:
    :func:`_one_group_map`) and with the per-group flags, counters, step and residuals as
    Python scalars instead of masked length-1 arrays (a fit evaluates ``T`` some twenty
    times, up to ``max_iter``, and the array handling cost more than the evaluations).
    The elementwise operations are numpy's (IEEE, in the same order), the norms those of
    :func:`_rel`, so every iterate has the bits of the batched path's.

    Returns ``(active, residual, best_res, best_aux, best_t, reason, iterations,
    oscillation, converged)`` after the loop (``best_aux``, ``best_t``: ``(1, P)``
    arrays)."""
    inf = math.inf
    step, since_best, oscillation, converged = 1.0, 0, False, False
    best = None
    n_par = len(theta)
    for _ in range(max_iter - 1):
        if active and residual < tol:
            converged, reason, active = True, STOP_CONVERGED, False
        if active and since_best >= STALL_PATIENCE and best_res < STALL_TOL:
            reason, active = STOP_STALLED, False
        if not active:
            break
        cand = [x + step * (t - x) for x, t in zip(theta, t_theta, strict=True)]
        t_cand = evaluate(cand)
        iterations += 1
        ok = t_cand is not None
        if not ok:  # reject a diverging candidate: shorten the step, retry from θ
            step *= 0.5
            if step < min_step:
                reason, active = STOP_DIVERGED, False
        good = active and ok
        res_c = inf
        if good:
            direction = [t - c for t, c in zip(t_cand, cand, strict=True)]
            res_c = _rel_list(direction, cand)
            if res_c > residual:  # a sign reversal with a growing residual
                if np.einsum("gp,gp->g", np.nan_to_num(np.array([direction])),
                             np.array([prev_dir]))[0] < 0:
                    oscillation = True
                step = max(step * 0.5, min_step)
            theta, t_theta, residual, prev_dir = cand, t_cand, res_c, direction
        if active:
            since_best += 1
        if good and res_c < best_res:
            since_best, best_res, best = 0, res_c, (cand, t_cand)
        if history is not None:
            history.append(np.array([t_cand], dtype=float) if good
                           else np.full((1, n_par), np.nan))
    if best is not None:
        best_aux, best_t = np.array([best[0]]), np.array([best[1]])
    return (active, residual, best_res, best_aux.copy(), best_t.copy(), reason, iterations,
            oscillation, converged)


def _average_stall(evaluate: Callable, stalled: np.ndarray, theta: np.ndarray,
                   t_theta: np.ndarray, n_avg: int,
                   iterations: np.ndarray, est: np.ndarray, aux: np.ndarray) -> dict:
    """``n_avg`` undamped steps ``θ ← T(θ)`` from the best iterate of each stalled group;
    the means of the points and of their ``T`` replace the estimate and the auxiliary
    model in place (:func:`stall_averaging`). Returns per group ``evaluations``,
    ``mean_step`` (mean of ``T(θ) − θ`` over the window: the averaged fixed-point
    residual) and ``sd_of_mean`` (the standard error of the mean ``T``, with the AR(1)
    inflation for successive values: how well the window locates the fixed point), NaN
    where an evaluation failed (the group then keeps its best iterate)."""
    th = theta.copy()
    t_th = t_theta.copy()
    seq_t = np.zeros((n_avg, *th.shape))
    seq_x = np.zeros((n_avg, *th.shape))
    alive = stalled.copy()
    for m in range(n_avg):
        cand = np.where(alive[:, None], t_th, th)  # undamped: θ ← T(θ)
        t_c, ok_c = evaluate(cand, alive)
        iterations += alive
        alive &= ok_c
        seq_t[m], seq_x[m] = np.nan_to_num(t_c), cand
        th[alive], t_th[alive] = cand[alive], t_c[alive]
    n = float(n_avg)
    mean_t, mean_x = seq_t.mean(axis=0), seq_x.mean(axis=0)
    dev = seq_t - mean_t
    var = np.sum(dev**2, axis=0) / max(n - 1.0, 1.0)
    # successive T values are correlated (the iteration carries θ): inflate the variance
    # of their mean by (1 + ρ₁)/(1 − ρ₁), ρ₁ their lag-1 autocorrelation (AR(1) rule)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.sum(dev[1:] * dev[:-1], axis=0) / np.sum(dev**2, axis=0)
    rho = np.clip(np.nan_to_num(rho), 0.0, 0.95)
    sd_mean = np.sqrt(var / n * (1.0 + rho) / (1.0 - rho))
    est[alive], aux[alive] = mean_t[alive], mean_x[alive]
    out_step = np.where(alive[:, None], mean_t - mean_x, np.nan)
    out_sd = np.where(alive[:, None], sd_mean, np.nan)
    return {"groups": alive, "evaluations": n_avg, "mean_step": out_step,
            "sd_of_mean": out_sd}


def _rel(diff: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``‖diff‖ / max(‖ref‖, 1e-300)`` along the last axis: ``np.linalg.norm(·, axis=-1)``'s
    own formula for real arrays (``sqrt(add.reduce(x·x))``, the same bits) without its
    argument handling (the refined iteration calls this at every step)."""
    def norm(x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return np.sqrt(np.add.reduce(x * x, axis=-1))

    return norm(diff) / np.maximum(norm(ref), 1e-300)


def _norm_list(x: list) -> float:
    """``np.linalg.norm`` of one row of Python floats, as :func:`_rel` computes it: numpy's
    ``add.reduce`` of fewer than 8 terms adds them in order (pairwise sums above)."""
    if len(x) >= 8:
        v = np.array(x, dtype=float)
        return float(np.sqrt(np.add.reduce(v * v)))
    acc = 0.0
    for v in x:
        acc += v * v
    return math.sqrt(acc)


def _rel_list(diff: list, ref: list) -> float:
    """:func:`_rel` of one row of Python floats (``np.maximum`` keeps a NaN norm)."""
    den = _norm_list(ref)
    if not den >= 1e-300 and den == den:
        den = 1e-300
    return _norm_list(diff) / den


METHODS = ("ls", "iv", "iv-zero-mean")


def estimate(
    data: RegressionData,
    spec: ModelSpec,
    method: str,
    *,
    combine: str = "pooled",
    theta_start: np.ndarray | None = None,
    **iteration_options,
) -> IterationResult:
    """Estimate every group with ``method`` (``ls``, ``iv``, ``iv-zero-mean``).

    IV methods start the refined iteration from the LS estimate unless
    ``theta_start`` is given.
    """
    if method not in METHODS:
        raise IdentificationError(f"unknown method {method!r}; choose from {METHODS}")
    theta_ls, ok = least_squares(data, spec, combine=combine)
    if method == "ls":
        n_groups = data.n_groups
        return IterationResult(
            theta=theta_ls,
            theta_aux=theta_ls,
            converged=ok.copy(),
            iterations=np.zeros(n_groups, dtype=np.int64),
            reason=np.where(ok, "closed form", STOP_SINGULAR).astype(object),
            residual=np.zeros(n_groups),
            oscillation=np.zeros(n_groups, dtype=bool),
        )
    zero_mean = method == "iv-zero-mean"
    if theta_start is not None:
        start = np.array(np.broadcast_to(np.asarray(theta_start, dtype=float), theta_ls.shape))
        res = refined_iv(data, spec, start, zero_mean=zero_mean, combine=combine,
                         **iteration_options)
        res.start = np.full(data.n_groups, "given", dtype=object)
        return res
    res = refined_iv(data, spec, theta_ls, zero_mean=zero_mean, combine=combine,
                     **iteration_options)
    res.start = np.full(data.n_groups, "ls", dtype=object)
    failed = res.reason == STOP_START_DIVERGED
    if failed.any():
        # The LS model's simulation diverges: start from basic IV with delayed
        # measurements as instruments instead (no simulation needed).
        mom = compute_moments(data, spec, mode=kernels.MODE_LAGGED)
        theta_lag, ok_lag = solve_moments(mom, data, spec, zero_mean=zero_mean, combine=combine)
        retry = failed & ok_lag
        if retry.any():
            res2 = refined_iv(data, spec, np.where(retry[:, None], theta_lag, theta_ls),
                              zero_mean=zero_mean, combine=combine, groups=retry,
                              **iteration_options)
            for name in ("theta", "theta_aux", "converged", "iterations", "reason", "residual",
                         "oscillation"):
                getattr(res, name)[retry] = getattr(res2, name)[retry]
            res.start[retry] = "lagged-iv"
            if res2.history:
                res.history = res2.history if not res.history else [
                    np.where(retry[:, None], h2, h1)
                    for h1, h2 in zip(res.history, res2.history, strict=False)]
    return res
