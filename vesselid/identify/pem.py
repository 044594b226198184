"""Prediction-error (quasi-maximum-likelihood) estimator with the disturbances as states.

The instrumental-variable estimators of the paper are consistent when the current ``v``
is white (Lemma 3.1) and lose most of their precision when it is coloured: a slowly
varying current inside the modulus leaves no instrument built from the input alone
exactly valid (``scripts/estimator_study.py``). This estimator models the disturbance
instead. For one state equation of Definition 2.1 it runs the Gaussian filter of
:mod:`vesselid.identify._pemkernels` on the state ``[x, v, c]`` — ``v`` a Gauss–Markov
current inside the modulus, ``c`` Gauss–Markov sensor noise, plus white process noise
``w`` (mean ``μ_w``) and white sensor noise ``e`` — and minimises the negative
log-likelihood of its innovations ``ε(k)`` with variances ``S(k)``,

    V(ψ) = Σ_k ½ (log S(k) + ε(k)² / S(k)),

by Fisher scoring (exact sensitivities of ``ε`` and ``S`` from the filter's tangent
recursion, in the same compiled pass as the filter), started from the consistent
IV_{E{ζ}=0} estimate.

Two disturbance models are fitted and the one with the higher likelihood is reported:

* ``current``: Gauss–Markov ``v`` (ρ_v, σ_v), no coloured sensor noise (σ_c = 0);
* ``sensor``: white ``v`` inside the modulus (ρ_v = 0), Gauss–Markov ``c`` (ρ_c, σ_c).

Both contain the white disturbances of the paper's §6. Fitting both (rather than one
model with both processes) matters: with ``v`` and ``c`` free together the likelihood
has ridges along which a coloured current is traded for coloured sensor noise, and the
scoring stalled or chose the wrong one in 72 % of Gauss–Markov-current runs; fitted
apart, the current model won every such run by 48–1890 log-likelihood units and the
sensor model 99 % of the Gauss–Markov-sensor-noise runs. Vuong's (1989) test of the two
non-nested models (with Schwarz's correction) is reported. Where two cores are usable the
sensor model is fitted on a second thread while the current model and what follows from it
run on the first (:func:`_candidates`; the same numbers as in turn). The sensor model loses
on the coloured-current logs that take this estimator, and its Hessian there exceeds its
Fisher information: once near its optimum and clearly behind the current model, its
scoring takes secant steps (:func:`_scoring`); where it wins after all it is continued with
plain scoring from there, so every reported estimate is plain Fisher scoring's.

With ``joint=True`` (``auto``'s choice) a third model is fitted from the better of the
two: ``joint``, a Gauss–Markov current *and* Gauss–Markov sensor noise at once (every
parameter free), which nests both. Started from a converged single-process fit it does
not stall on the ridges: on a Gauss–Markov current plus Gauss–Markov sensor noise the
current model's bias on the damping was 15 Monte Carlo sd while the joint model's was
within 0.3 sd, and under a single Gauss–Markov current it loses ~13 % in median error on
the damping (``scripts/robustness_study.py``). The likelihood-ratio statistic of the
joint model against the better single-process model is reported.

With ``boundary="unbounded"``, where the current model is the better single-process
model and the joint model gains little over it (likelihood ratio ≤ :data:`LOCAL_LR`),
the joint model is reported as ``joint-local`` instead: the sensor-noise variance
estimated without its bound at zero, one scoring step from the current model
(:func:`_local_joint`). Under a single Gauss–Markov current the bounded joint fit keeps
a small spurious sensor-noise process in most runs, and that one-sided choice biases
``n`` by 0.4 Monte Carlo sd; the unbounded step is symmetric about θ0 there and stays
the efficient joint estimate when a weak sensor-noise process is present. On a telegraph
current (outside every model) it is biased twice as much as the bounded fit. No
likelihood-ratio pre-test between the joint and the current model removes the bound's
bias without biasing the two-process case (the sensor-noise process there is too weak
to be established in a fifth of the runs, and the current model alone is biased by 2–3
Monte Carlo sd), so ``boundary="auto"`` (``auto``'s default) asks the current instead:
a kurtosis test of the smoothed one-step residuals of the current-model fit
(:func:`vesselid.identify.current_shape.smoothed_current_test`) separates a bimodal,
switching current from a Gaussian one; the bounded fit is reported where it rejects,
with the spread between the bounded and the unbounded fit added to its covariance
(:func:`_with_spread`), the unbounded one elsewhere (``scripts/pem_boundary_study.py``,
``scripts/robustness_study.py``).

The covariance is the inverse Fisher information of the chosen model (the θ block); with
a correct model it is efficient. The quasi-ML sandwich ``F⁻¹ Ŝ F⁻¹`` (``Ŝ`` the Bartlett
HAC long-run variance of the per-sample scores) is computed beside it (``cov_sandwich``):
it stays valid when the disturbances are not the modelled Gaussian processes, but its HAC
estimate is biased downward at 10⁴ samples (Gauss–Markov sensor noise with random pulses:
SE / Monte Carlo sd 0.90 against the inverse Fisher's 0.93). ``cov_conservative``,
``F⁻¹ + (sandwich − F⁻¹)₊``, lies above both in the Loewner order; ``auto`` reports it
(:func:`conservative_covariance`).

Single state, no disturbance sensor (``[aggregate]``), pooled experiments (one set of
noise parameters, the filter restarted at every experiment).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from concurrent.futures import wait
from functools import partial
from typing import Any, ClassVar

import numpy as np

from vesselid.errors import IdentificationError
from vesselid.identify.base import Estimator, square_designs
from vesselid.identify.current_shape import smoothed_current_test
from vesselid.identify.data import RegressionData
from vesselid.identify.estimators import IterationResult, estimate
from vesselid.model.spec import ModelSpec

__all__ = ["BOUNDARIES", "COVARIANCES", "DISTURBANCE_MODELS", "JOINT", "JOINT_LOCAL",
           "OneStateLikelihood", "PredictionError", "assumption_text", "fit_groups",
           "load_kernels", "supports"]

#: The disturbance models fitted (see module docstring).
DISTURBANCE_MODELS = ("current", "sensor")
#: Both processes at once, fitted from the better single-process model (``joint=True``).
JOINT = "joint"
#: Scoring steps of the joint model (from a converged fit it converges in 5–20 where a
#: second process is present; without one it can wander along the ridge σ → 0, and the
#: single-process fit is kept then).
JOINT_ITER = 40
#: Covariances of the likelihood estimate: inverse Fisher information, quasi-ML sandwich,
#: and the smallest covariance above both in the Loewner order (``conservative``).
COVARIANCES = ("fisher", "sandwich", "conservative")
#: The key of each covariance in :func:`fit_groups`'s output.
COVARIANCE_KEYS = {"fisher": "cov", "sandwich": "cov_sandwich",
                   "conservative": "cov_conservative"}

CONVERGED = "converged"
NO_DESCENT = "line search found no descent"
MAX_ITER = "maximum iterations reached"
BAD_START = "IV_E{ζ}=0 start not finite"
EXACT = "exact fit (noise-free log)"

#: One-step residuals of the start below this fraction of max |y|: a noise-free log, on
#: which the likelihood is unbounded (σ → 0) and the consistent start is exact.
EXACT_FIT = 1e-12

#: Stop when the squared Newton decrement ``gᵀF⁻¹g`` — the squared length of the next
#: step in standard errors — falls below this: the last step moves no parameter by more
#: than 0.01 standard errors (measured against 1e-8: ≤ 0.01 SE, 30–45 % fewer steps).
SCORING_TOL = 1e-4


def supports(spec: ModelSpec, data: RegressionData | None = None) -> bool:
    """Whether the estimator applies: one state, no disturbance sensor in the regressors
    (``[aggregate]``), and (``data``) a log that was not low-pass filtered (the filter is
    not part of the model)."""
    if spec.n_states != 1 or spec.aggregate:
        return False
    return data is None or not data.lowpassed


def _layout(n_par: int) -> dict[str, int]:
    names = ("mu_w", "rho_v", "sigma_v", "rho_c", "sigma_c", "sigma_w", "sigma_e")
    return {k: n_par + i for i, k in enumerate(names)}


def _start(theta: np.ndarray, y: np.ndarray, u: np.ndarray, starts: np.ndarray,
           fac: np.ndarray, model: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Starting row ψ₀ and free mask of ``model`` from the IV estimate ``theta``, and
    the standard deviation of the start's one-step residuals."""
    from vesselid.model.regressors import evaluate

    n_par = theta.size
    ix = _layout(n_par)
    sig = np.concatenate([y[:, None], u], axis=1)
    pred = evaluate(fac, sig[:-1]) @ theta
    res = y[1:] - pred
    keep = np.ones(res.size, dtype=bool)
    keep[starts[1:-1] - 1] = False  # no residual across an experiment boundary
    res = res[keep]
    scale = float(np.std(res)) if res.size > 1 else 0.0
    log_s = math.log(scale / 2.0) if scale > 0 and np.isfinite(scale) else 0.0
    psi = np.empty(n_par + 7)
    psi[:n_par] = theta
    psi[ix["mu_w"]] = float(np.mean(res)) if res.size else 0.0
    psi[[ix["sigma_v"], ix["sigma_c"], ix["sigma_w"], ix["sigma_e"]]] = log_s
    free = np.ones(psi.size, dtype=bool)
    if model == "current":
        psi[ix["rho_v"]] = math.atanh(0.8)
        psi[ix["rho_c"]] = 0.0
        psi[ix["sigma_c"]] = -np.inf
        free[[ix["rho_c"], ix["sigma_c"]]] = False
    else:
        psi[ix["rho_v"]] = 0.0
        psi[ix["rho_c"]] = math.atanh(0.8)
        free[ix["rho_v"]] = False
    return psi, free, scale


#: Below this many row-samples a pass of several filter rows runs in the calling thread:
#: ten rows of a 10⁴-sample log take a few milliseconds, less than waking the pool's
#: threads and handing them the GIL back costs (each row is filtered on its own, so the
#: split never changes a number).
PARALLEL_MIN_ROW_SAMPLES = 1_000_000


class _Filter:
    """The filter of one group's log (arrays kept contiguous for the compiled kernel)."""

    def __init__(self, y: np.ndarray, u: np.ndarray, starts: np.ndarray, fac: np.ndarray,
                 parallel: bool) -> None:
        self.y = np.ascontiguousarray(y, dtype=np.float64)
        self.u = np.ascontiguousarray(u, dtype=np.float64)
        self.starts = np.ascontiguousarray(starts, dtype=np.int64)
        from vesselid.identify._pemkernels import term_kinds

        self.terms = term_kinds(fac, 1 + self.u.shape[1])
        self.p_init = np.array([max(float(np.var(self.y[a:b])), 1e-300) if b > a else 1.0
                                for a, b in zip(self.starts[:-1], self.starts[1:],
                                                strict=True)])
        self.parallel = parallel
        self.n = self.y.size
        # innovation samples: all but the first of each experiment
        self.count = self.n - (self.starts.size - 1)

    def run(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Innovations and their variances (R, T) of the parameter rows (R, P + 7)."""
        return self._filter(rows)

    def nll_rows(self, rows: np.ndarray, *, idle: bool = False) -> np.ndarray:
        """The negative log-likelihood ``V(ψ) = Σ ½ (log S + ε²/S)`` of each parameter
        row (R,): each row filtered as by :meth:`run` and summed as ``np.sum`` of its
        terms, in the thread that filtered it. ``idle``: in a Monte Carlo worker, the
        rows may also run on the cores the other workers leave idle
        (:func:`vesselid.core.threads.run_ranges`)."""
        out = np.empty(np.shape(rows)[0])

        def each(lo: int, hi: int, eps: np.ndarray, var: np.ndarray) -> None:
            for j in range(lo, hi):
                out[j] = np.sum(_nll_terms(eps[j], var[j]))

        self._filter(rows, idle=idle, each=each)
        return out

    def _filter(self, rows: np.ndarray, *, idle: bool = False,
                each: Callable[[int, int, np.ndarray, np.ndarray], None] | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`run`'s innovations and variances, the rows split over threads by
        :func:`vesselid.core.threads.run_ranges`; ``each(lo, hi, eps, var)`` runs after
        each block of rows ``[lo, hi)`` in the thread that filtered it."""
        from vesselid.core.threads import run_ranges
        from vesselid.identify._pemkernels import gaussian_filter

        rows = np.ascontiguousarray(rows, dtype=np.float64)
        n_rows = rows.shape[0]
        eps = np.empty((n_rows, self.n))
        var = np.empty((n_rows, self.n))
        kernel = gaussian_filter
        if each is not None:
            def kernel(lo: int, hi: int, *args: Any) -> None:
                gaussian_filter(lo, hi, *args)
                each(lo, hi, eps, var)

        run_ranges(kernel, n_rows,
                   (rows, self.y, self.u, self.starts, self.p_init, *self.terms, eps, var),
                   parallel=(self.parallel and n_rows > 1
                             and n_rows * self.n >= PARALLEL_MIN_ROW_SAMPLES),
                   idle=idle and self.parallel)
        return eps, var

    def tangent(self, psi: np.ndarray, idx: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                           np.ndarray, float]:
        """Innovations ``ε``, variances ``S`` (T,) of the row ``psi``, their exact
        derivatives with respect to ``psi[idx]`` (d, T), and the negative
        log-likelihood's gradient (d,), Fisher information (d, d) and value, in one
        compiled pass."""
        from vesselid.identify._pemkernels import gaussian_filter_tangent

        psi = np.ascontiguousarray(psi, dtype=np.float64)
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        eps = np.empty(self.n)
        var = np.empty(self.n)
        deps = np.empty((self.n, idx.size))
        dvar = np.empty((self.n, idx.size))
        grad = np.empty(idx.size)
        fisher = np.empty((idx.size, idx.size))
        nll = np.empty(1)
        gaussian_filter_tangent(psi, idx, self.y, self.u, self.starts, self.p_init,
                                *self.terms, eps, var, deps, dvar, grad, fisher, nll)
        return eps, var, deps.T, dvar.T, grad, fisher, float(nll[0])


def load_kernels() -> None:
    """Load (or compile, on first use) the kernels with the signatures every fit calls
    them with: the filter, its tangent pass, the scores' HAC sums and the selection
    quadrature (:mod:`vesselid.studies.precompile` compiles the same filter kernels)."""
    fac = np.array([[0, 4], [0, 2], [1, 4]], dtype=np.int64)  # heave: x, x|x|, u
    filt = _Filter(np.zeros(4), np.zeros((4, 1)), np.array([0, 4]), fac, parallel=False)
    filt.run(np.zeros((1, fac.shape[0] + 7)))
    _, _, je, js, *_ = filt.tangent(np.zeros(fac.shape[0] + 7),
                                    np.arange(fac.shape[0] + 7))
    _score_hac(je, js, np.zeros(4), np.ones(4), filt.starts)
    _selection_weights(np.eye(2))


def _nll_terms(eps: np.ndarray, var: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return 0.5 * (np.log(var) + eps * eps / var)


#: Below this squared Newton decrement (the predicted decrease × 2, in the Fisher
#: metric) the scoring is near its optimum and corrects its curvature by secant
#: updates (:func:`_secant_update`).
TAIL_DEC = 10.0


def _secant_update(extra: np.ndarray, s: np.ndarray, y: np.ndarray,
                   fisher: np.ndarray) -> np.ndarray:
    """Symmetric rank-one update of the curvature beyond the Fisher information: the
    Hessian of ``V`` is ``F + A`` with ``A`` the terms the expected information drops
    (non-zero where the disturbance model is not the log's); after a step ``s`` with
    gradient change ``y``, ``A`` is corrected so that ``(F + A) s = y`` (the structured
    secant condition of Dennis, Gay & Welsch's adaptive nonlinear least squares).
    Skipped where the correction is ill-defined."""
    r = y - fisher @ s - extra @ s
    den = float(r @ s)
    if not (np.isfinite(den) and abs(den) > 1e-8 * float(np.linalg.norm(r))
            * float(np.linalg.norm(s))):
        return extra
    return extra + np.outer(r, r) / den


def _curvature_step(curv: np.ndarray, grad: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Newton step ``−B⁺g`` and its slope ``−gᵀδ`` for a positive semi-definite
    curvature ``B`` (pseudo-inverse with the Fisher step's cut-off; ``None`` where ``B``
    has a negative eigenvalue: the Fisher step is taken)."""
    lam, vec = np.linalg.eigh(0.5 * (curv + curv.T))
    top = float(np.max(np.abs(lam))) if lam.size else 0.0
    cut = 1e-12 * top
    if not (top > 0 and np.all(np.isfinite(lam))) or np.any(lam < -cut):
        return None
    inv = np.where(lam > cut, 1.0 / np.where(lam > cut, lam, 1.0), 0.0)
    delta = -vec @ (inv * (vec.T @ grad))
    slope = float(-grad @ delta)
    if not (np.all(np.isfinite(delta)) and slope > 0):
        return None
    return delta, slope


def _loses(f0: float, dec: float, rival: float | None) -> bool:
    """Whether a fit at ``f0`` predicting a decrease of ``dec / 2`` loses to a rival
    fit at ``rival`` (negative log-likelihoods) by a margin of another ``dec / 2``."""
    return rival is not None and np.isfinite(rival) and rival < f0 - dec


def _scoring(filt: _Filter, psi0: np.ndarray, free: np.ndarray, max_iter: int, tol: float,
             secant: Callable[[], float | None] | None = None,
             abandon: Callable[[], bool] | None = None) -> dict[str, Any] | None:
    """Fisher scoring of ``V(ψ)`` over the free entries of ψ (module docstring).

    ``secant``: the negative log-likelihood of a rival model's fit (``None``: none).
    Once the squared Newton decrement is below :data:`TAIL_DEC` and the rival is the
    better fit by more than twice the decrease this fit still predicts (so this one
    loses), the steps use the Fisher information plus a secant estimate of the
    curvature it misses
    (:func:`_secant_update`, :func:`_curvature_step`). A single-process model fitted to
    a log whose disturbance it does not describe has a Hessian well above its Fisher
    information along some directions (measured: 1.4–1.5 times along ρ_c of the
    sensor-noise model on a Gauss–Markov current), and the scoring steps then overshoot
    and alternate about the optimum for a dozen steps; the secant step converges in a
    few. The stopping rule is the same either way (the Fisher-metric decrement), and so
    is every step before the tail. ``abandon``: asked before every step; ``None`` is
    returned once it says so (a fit computed ahead that is no longer wanted)."""
    psi = psi0.copy()
    idx = np.flatnonzero(free)
    d = idx.size
    search = _LineSearch(filt)
    reason, converged, it = MAX_ITER, False, 0
    fisher = np.full((d, d), np.nan)
    eps0 = var0 = je = js = None
    extra: np.ndarray | None = None  # the tail's secant correction of the curvature
    tail: tuple[np.ndarray, int] | None = None
    ahead = None  # the tangent pass of an accepted trial point
    full = False  # whether the last step was the full one
    last: tuple[np.ndarray, np.ndarray] = (psi[idx], np.zeros(d))
    for it in range(1, max_iter + 1):
        if abandon is not None and abandon():
            return None
        # the filter at ψ with its exact sensitivities (the accepted trial of the line
        # search was filtered without them — the same innovations, recomputed here —
        # unless it was filtered with them)
        eps0, var0, je, js, grad, fisher, f0 = (ahead if ahead is not None
                                                else filt.tangent(psi, idx))
        ahead = None
        if not np.isfinite(f0):
            reason = "likelihood not finite"
            break
        if not (np.all(np.isfinite(grad)) and np.all(np.isfinite(fisher))):
            reason = "sensitivities not finite"
            break
        # pseudo-inverse: a disturbance at its boundary (σ → 0) leaves its ρ unidentified
        delta = -np.linalg.pinv(fisher, rcond=1e-12, hermitian=True) @ grad
        dec = float(-grad @ delta)  # Newton decrement²: the predicted decrease × 2
        if dec < tol:
            reason, converged = CONVERGED, True
            break
        slope = dec
        if extra is not None:
            extra = _secant_update(extra, psi[idx] - last[0], grad - last[1], fisher)
            step = _curvature_step(fisher + extra, grad)
            if step is not None:
                delta, slope = step
        elif secant is not None and dec < TAIL_DEC and _loses(f0, dec, secant()):
            extra = np.zeros((d, d))
            tail = (psi.copy(), it - 1)  # the plain scoring's state here: the same
        if extra is not None:
            last = (psi[idx].copy(), grad.copy())
        found = search.step(psi, idx, delta, f0, slope, full)
        if found is None:
            reason = NO_DESCENT
            break
        psi, alpha, ahead = found
        full = alpha == 1.0
    cov = np.zeros((psi.size, psi.size))
    parts = None
    if np.all(np.isfinite(fisher)):
        finv = np.linalg.pinv(fisher, rcond=1e-12, hermitian=True)
        cov[np.ix_(idx, idx)] = finv
        parts = (je, js, eps0, var0, filt.starts, finv, idx)
    else:
        cov[:] = np.nan
    terms = _nll_terms(eps0, var0) if eps0 is not None else None
    fit = {"psi": psi, "cov": cov, "cov_sandwich": None, "sandwich_parts": parts,
           "converged": converged, "iterations": it, "reason": reason,
           "nll_terms": terms, "free": int(d), "tail": tail}
    if d * filt.n > DEFER_MAX:  # the sensitivities are large: the sandwich now
        _sandwich(fit)
    return fit


#: Halvings of the step before the line search gives up (its smallest step is
#: ``2**-(LINE_STEPS - 1)``, the last above 10⁻⁴).
LINE_STEPS = 14
#: Trial points filtered together once the expected ones all failed.
LINE_STEPS_MORE = 2


class _LineSearch:
    """Backtracking (Armijo) line search of :func:`_scoring`: the steps ``α = 1, ½, ¼, …``
    (at most :data:`LINE_STEPS`) are tried in turn and the first with
    ``V(ψ + α δ) ≤ V(ψ) − 10⁻⁴ α · slope`` is taken.

    The trial points are filtered several at a time, as rows of one filter call
    (:meth:`_Filter.nll_rows`: the rows advance together, so a row costs about two thirds
    of one filtered alone, and rows may run on threads that would otherwise idle, each
    summing its rows' likelihoods): as many as the likely step needs (the step the last
    search took, or the larger of the last two where the steps alternate), then
    :data:`LINE_STEPS_MORE` at a time; the rows past the accepted step are work thrown
    away. Each row is filtered on its own and the steps are judged in the same order, so
    the step taken (and every number after it) is the one-at-a-time search's."""

    def __init__(self, filt: _Filter) -> None:
        self.filt = filt
        self.taken = (0, 0, 0)  # the last three steps taken (halvings), latest first

    def step(self, psi: np.ndarray, idx: np.ndarray, delta: np.ndarray, f0: float,
             slope: float, full: bool) -> tuple[np.ndarray, float, Any] | None:
        """``(ψ + α δ, α, tangent pass or None)`` of the accepted step, ``None`` where no
        step descends. ``full``: the last step was the full one, so this one likely is
        too and its trial point is filtered with its sensitivities (which the next
        scoring step needs; the innovations are the filter's, bit for bit). Elsewhere
        the tangent pass at the likely step is computed meanwhile on an idle core where
        there is one (:func:`vesselid.core.threads.ahead`) and handed on where that step
        is taken (the same pass the next scoring step would compute)."""
        from vesselid.core import threads

        k = 0
        if full:
            trial = psi.copy()
            trial[idx] += delta
            ahead = self.filt.tangent(trial, idx)
            if self._descends(float(np.sum(_nll_terms(ahead[0], ahead[1]))), f0, 1.0,
                              slope):
                self.taken = (0, *self.taken[:2])
                return trial, 1.0, ahead
            k = 1
        # the steps settle or alternate: the likely step is the last one taken, or the
        # one before where they alternate (then the trial points cover both)
        t1, t2, t3 = self.taken
        alternate = t1 != t2 and t3 == t1
        likely = t2 if alternate else t1
        count = min(max((max(t1, t2) if alternate else t1) + 1 - k, 1), LINE_STEPS - k)
        while k < LINE_STEPS:
            alphas = 0.5 ** np.arange(k, k + count, dtype=float)
            trials = np.repeat(psi[None], count, axis=0)
            trials[:, idx] += alphas[:, None] * delta
            # on an idle core: the tangent pass at the likely step, which the next scoring
            # step then needs not compute
            guess = likely - k
            job = (threads.ahead(partial(self.filt.tangent, trials[guess].copy(), idx))
                   if self.filt.parallel and 0 <= guess < count else None)
            values = self.filt.nll_rows(trials, idle=True)
            for i in range(count):
                if self._descends(float(values[i]), f0, float(alphas[i]), slope):
                    self.taken = (k + i, t1, t2)
                    return (trials[i].copy(), float(alphas[i]),
                            threads.collect(job) if job is not None and i == guess
                            else None)
            k += count
            count = min(LINE_STEPS_MORE, LINE_STEPS - k)  # more halvings than expected
        return None

    @staticmethod
    def _descends(f1: float, f0: float, alpha: float, slope: float) -> bool:
        """Armijo's condition on the trial value ``f1``."""
        return bool(np.isfinite(f1) and f1 <= f0 - 1e-4 * alpha * slope)


#: Largest ``d × T`` for which a fit keeps its sensitivities and computes its quasi-ML
#: sandwich only when it is reported (:func:`_sandwich`; most fits of
#: :func:`fit_groups` are candidates that are not).
DEFER_MAX = 200_000


def _sandwich(fit: dict[str, Any]) -> np.ndarray:
    """The quasi-ML sandwich ``F⁻¹ Ŝ F⁻¹`` of a :func:`_scoring` fit (ψ-sized; NaN where
    the Fisher information or the scores are not finite), computed on first use."""
    if fit["cov_sandwich"] is None:
        parts = fit.pop("sandwich_parts", None)
        n = fit["psi"].size
        sand = np.full((n, n), np.nan)
        if parts is not None:
            je, js, eps0, var0, starts, finv, idx = parts
            sand[:] = 0.0
            meat = _score_hac(je, js, eps0, var0, starts)
            sand[np.ix_(idx, idx)] = finv @ meat @ finv if meat is not None else np.nan
        fit["cov_sandwich"] = sand
    return fit["cov_sandwich"]


def _score_hac(je: np.ndarray | None, js: np.ndarray | None, eps: np.ndarray,
               var: np.ndarray, starts: np.ndarray) -> np.ndarray | None:
    """Bartlett HAC long-run variance of the per-sample scores
    ``s(k) = ∂ε/∂ψ ε/S + ½ ∂S/∂ψ (1/S − ε²/S²)`` (the meat of the quasi-ML sandwich;
    Newey–West bandwidth, lags not across experiment boundaries)."""
    from vesselid.identify._pemkernels import quasi_scores

    if je is None or js is None:
        return None
    sc = np.empty((eps.size, je.shape[0]))  # (T, d), 0 where not finite
    quasi_scores(np.ascontiguousarray(je), np.ascontiguousarray(js), eps, var, sc)
    out = scores_long_run(sc, starts)
    return out if np.all(np.isfinite(out)) else None


def group_units(data: RegressionData, rows: np.ndarray, fac: np.ndarray
                ) -> tuple[float, np.ndarray, np.ndarray]:
    """The units a likelihood fit of the group ``rows`` works in: the state's ``cx`` and
    the inputs' ``cu`` (:func:`_unit`), and ``tscale`` (P,) with ``θ' = θ · tscale`` the
    parameters of the scaled log. In units of each signal's spread the fit's finite
    differences and start values are the same whatever units the log is in (results
    scale exactly)."""
    cx = _unit(data.target[rows, 0])
    cu = np.array([_unit(data.u[rows, q]) for q in range(data.u.shape[1])])
    fscale = np.concatenate([[cx], cu, [cx], cu, [1.0]])  # F = [x, u, |x|, |u|, 1]
    return cx, cu, fscale[fac[:, 0]] * fscale[fac[:, 1]] / cx


def scores_long_run(sc: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Bartlett HAC long-run variance ``Σ_lag w_lag Σ_k s(k) s(k−lag)ᵀ`` (both signs of
    the lag) of per-sample scores ``sc`` (T, d): Newey–West bandwidth, lags not across
    experiment boundaries (``starts``)."""
    from vesselid.identify._pemkernels import bartlett_lagged
    from vesselid.identify.gmm import hac_lags

    # Σ_lag w_lag Σ_k s(k) s(k−lag)ᵀ = Σ_k s(k) f(k)ᵀ with f(k) = Σ_lag w_lag s(k−lag)
    # (Bartlett weights, pairs within one experiment): one product instead of one a lag
    lagged = np.empty_like(sc)
    bartlett_lagged(sc, np.ascontiguousarray(starts, dtype=np.int64),
                    hac_lags(int(sc.shape[0])), lagged)
    c = sc.T @ lagged
    return sc.T @ sc + (c + c.T)


def _unit(x: np.ndarray) -> float:
    """A signal's unit for the scoring: its standard deviation (its largest magnitude
    when constant, 1 when zero or not finite)."""
    sd = float(np.std(x))
    if np.isfinite(sd) and sd > 0:
        return sd
    top = float(np.max(np.abs(x))) if x.size else 0.0
    return top if np.isfinite(top) and top > 0 else 1.0


def _vuong(a: dict[str, Any], b: dict[str, Any], count: int) -> float:
    """Vuong's z of model ``a`` against ``b`` (positive: ``a`` fits better), with
    Schwarz's correction for the number of free parameters."""
    if a["nll_terms"] is None or b["nll_terms"] is None:
        return float("nan")
    diff = b["nll_terms"] - a["nll_terms"]  # per-sample log-likelihood of a minus b
    lr = float(np.sum(diff)) - 0.5 * (a["free"] - b["free"]) * math.log(max(count, 2))
    sd = float(np.std(diff[np.isfinite(diff)]))
    if not (sd > 0 and np.isfinite(lr)):
        return 0.0 if lr == 0 else float(np.sign(lr)) * float("inf")
    return lr / (math.sqrt(count) * sd)


def _with_spread(f: dict[str, Any], other: dict[str, Any], n_par: int) -> dict[str, Any]:
    """``f`` with ``ddᵀ`` added to its covariances' θ block, ``d`` the difference of its
    θ and ``other``'s: the spread of two fits of a misspecified model that the
    likelihood cannot choose between (a bimodal current; module docstring)."""
    d = f["psi"][:n_par] - other["psi"][:n_par]
    if not np.all(np.isfinite(d)):
        return f
    out = dict(f)
    out["cov_sandwich"] = _sandwich(f)
    out.pop("sandwich_parts", None)
    for key in ("cov", "cov_sandwich"):
        c = out[key].copy()
        c[:n_par, :n_par] += np.outer(d, d)
        out[key] = c
    return out


def _residuals(psi: np.ndarray, y: np.ndarray, u: np.ndarray, starts: np.ndarray,
               fac: np.ndarray, n_par: int) -> list[np.ndarray]:
    """One-step residuals ``y(k+1) − θᵀφ(k)`` of the row ``psi``, one array per
    experiment (none across an experiment boundary)."""
    from vesselid.model.regressors import evaluate

    sig = np.concatenate([y[:, None], u], axis=1)
    res = y[1:] - evaluate(fac, sig[:-1]) @ psi[:n_par]
    return [res[a:b - 1] for a, b in itertools.pairwise(starts) if b - a > 1]


def _joint_start(best: dict[str, Any], model: str, n_par: int, scale: float) -> np.ndarray:
    """Start of the joint model from a converged single-process fit: the other process
    switched on (ρ = 0.8, σ a quarter of the start's residual std)."""
    ix = _layout(n_par)
    psi = best["psi"].copy()
    log_s = math.log(scale / 4.0) if scale > 0 and np.isfinite(scale) else 0.0
    if model == "current":
        psi[ix["rho_c"]] = math.atanh(0.8)
        psi[ix["sigma_c"]] = log_s
    else:
        psi[ix["rho_v"]] = math.atanh(0.8)
    return psi


#: Stationary correlations ρ_c of the sensor-noise process at which the unbounded
#: one-step estimate of the joint model is computed (:func:`_local_joint`): the one with
#: the largest ``|z|`` of the sensor-noise variance is kept.
LOCAL_RHO_GRID = (0.3, 0.6, 0.8, 0.9, 0.95, 0.98)
#: Twice the log-likelihood gain of the fitted joint model over the current model above
#: which the joint fit itself is reported (its sensor-noise process is then far from
#: the boundary σ_c = 0, where the one-step expansion of :func:`_local_joint` is not
#: needed and no longer accurate).
LOCAL_LR = 10.0
#: The joint model estimated without the bound σ_c² ≥ 0 (:func:`_local_joint`).
JOINT_LOCAL = "joint-local"
#: How the joint model treats the sensor-noise variance's bound at zero
#: (:func:`fit_groups`'s ``boundary``): ``auto`` is ``unbounded`` unless the smoothed
#: current looks bimodal (:func:`vesselid.identify.current_shape.smoothed_current_test`),
#: then ``bounded`` (module docstring; ``auto``'s default).
BOUNDARIES = ("auto", "bounded", "unbounded")
#: Normal draws of the quadrature of the selection term of :func:`_local_joint`'s
#: covariance (a fixed set, the same for every log: a numerical integral, not a random
#: result).
SELECTION_DRAWS = 20_000
_NORMALS: dict[int, np.ndarray] = {}


def _normals(k: int) -> np.ndarray:
    """The fixed standard normal draws (SELECTION_DRAWS, k) of the selection quadrature."""
    if k not in _NORMALS:
        _NORMALS[k] = np.random.default_rng(20_240_601).standard_normal((SELECTION_DRAWS, k))
    return _NORMALS[k]


def _selection_weights(corr: np.ndarray) -> np.ndarray:
    """``w_j = E[Z_J² 1{J = j}]`` for ``Z ~ N(0, corr)`` and ``J = argmax_j |Z_j|``: the
    variance the choice of the largest ``|z|`` over the grid adds (``Σ_j w_j ≥ 1``; one grid
    point: 1)."""
    from vesselid.identify._pemkernels import selection_sums

    lam, vec = np.linalg.eigh(0.5 * (corr + corr.T))
    root = vec * np.sqrt(np.maximum(lam, 0.0))
    z = _normals(corr.shape[0]) @ root.T
    sums = np.empty(corr.shape[0])
    selection_sums(np.ascontiguousarray(z), sums)  # the argmax of |z| and its bincount
    return sums / z.shape[0]


def _local_joint(filt: _Filter, single: dict[str, Any], n_par: int,
                 grid: tuple[float, ...] | None = None) -> dict[str, Any] | None:
    """The joint model's estimate without the bound σ_c² ≥ 0: one Fisher-scoring step
    from the converged current-model fit ``single`` in its free parameters and the
    stationary variance ``q`` of Gauss–Markov sensor noise (correlation ρ_c fixed), the
    derivatives in ``q`` taken at ``q = 0`` (forward differences; the likelihood is smooth
    in ``q`` through zero; the free parameters' derivatives exact, from the filter's
    tangent recursion). At each ρ_c of ``grid`` the step's ``q`` gets a z-value (the
    efficient score of ``q``, standardised); the ρ_c with the largest ``|z|`` is kept.

    Why: under a single Gauss–Markov current the true ``q`` is zero, on the boundary of
    the joint model. The bounded maximum-likelihood estimate keeps only ``q̂ > 0`` (a
    spurious sensor-noise process in about 70 % of runs) and shifts θ with it: a bias of
    about 0.4 Monte Carlo sd on ``n`` (``scripts/robustness_study.py``). The unbounded
    step ``θ̂ = θ̂_S + b_j z_j`` is, to first order, symmetric about θ0 when ``q = 0``
    (``z`` and ``−z`` are equally likely and pick the same ρ_c), and it is the joint
    model's efficient estimate when ``q`` is small but positive.

    Covariance: ``F_S⁻¹ + Σ_j w_j b_j b_jᵀ`` — the current model's inverse Fisher
    information (θ̂_S is asymptotically independent of the efficient scores of ``q``) plus
    the variance of the step, ``E[b_J b_Jᵀ Z_J²]`` for ``Z ~ N(0, R)`` (``R`` the
    correlation of the efficient scores over the grid, ``J`` the largest ``|Z_j|``),
    integrated by :func:`_selection_weights`; with one grid point it is the joint model's
    inverse Fisher information at that ρ_c. The sandwich is the fixed-ρ_c sandwich plus
    the same selection term. Returns a fit dict like :func:`_scoring`'s (``nll_terms`` of
    the single fit), or ``None`` where a derivative is not finite."""
    grid = LOCAL_RHO_GRID if grid is None else grid
    ix = _layout(n_par)
    psi0 = single["psi"]
    free = np.isfinite(psi0)
    free[[ix["rho_c"], ix["sigma_c"]]] = False
    idx = np.flatnonzero(free)
    d = idx.size
    rows = np.repeat(psi0[None], 1 + len(grid), axis=0)
    parts = single.get("sandwich_parts")
    if single["converged"] and parts is not None and np.array_equal(parts[6], idx):
        # the converged fit's last tangent pass was at ψ₀ in these directions: its
        # sensitivities and innovations are those of the passes below
        je_s, js_s, eps0, var0 = parts[0], parts[1], parts[2][None], parts[3][None]
    else:
        _, _, je_s, js_s, *_ = filt.tangent(psi0, idx)  # exact, in the free parameters
        eps0, var0 = filt.run(rows[:1])
    if not (np.all(np.isfinite(eps0)) and np.all(np.isfinite(var0))):
        return None
    h = 1e-6 * float(np.mean(var0[0]))  # the sensor-noise variance of the q-rows
    rows[1:, ix["rho_c"]] = np.arctanh(np.asarray(grid, dtype=float))
    rows[1:, ix["sigma_c"]] = 0.5 * math.log(h)
    eq, vq = filt.run(rows[1:])
    e0, v0 = eps0[0], var0[0]
    je = np.vstack([je_s, (eq - e0) / h])
    js = np.vstack([js_s, (vq - v0) / h])
    inv_s = 1.0 / v0
    grad = je @ (e0 * inv_s) + 0.5 * (js @ (inv_s - e0 * e0 * inv_s * inv_s))
    fisher = (je * inv_s) @ je.T + 0.5 * ((js * (inv_s * inv_s)) @ js.T)
    if not (np.all(np.isfinite(grad)) and np.all(np.isfinite(fisher))):
        return None
    f_inv = np.linalg.pinv(fisher[:d, :d], rcond=1e-12, hermitian=True)
    cross = fisher[:d, d:]                                   # (d, J)
    c = fisher[d:, d:] - cross.T @ f_inv @ cross             # efficient information of q
    info_q = np.diag(c).copy()
    if not np.all(info_q > 0):
        return None
    g_eff = grad[d:] - cross.T @ (f_inv @ grad[:d])
    z = -g_eff / np.sqrt(info_q)
    b = -(f_inv @ cross) / np.sqrt(info_q)                   # θ-step per unit z (d, J)
    j = int(np.argmax(np.abs(z)))
    psi = psi0.copy()
    psi[idx] += -f_inv @ grad[:d] + b[:, j] * z[j]
    q = float(z[j] / math.sqrt(info_q[j]))
    psi[ix["rho_c"]] = math.atanh(grid[j])
    psi[ix["sigma_c"]] = 0.5 * math.log(q) if q > 0 else -np.inf
    w = _selection_weights(c / np.sqrt(np.outer(info_q, info_q)))
    select = (b * w) @ b.T
    cov = np.zeros((psi.size, psi.size))
    sand = np.full((psi.size, psi.size), np.nan)
    cov[np.ix_(idx, idx)] = f_inv + select
    keep = np.r_[np.arange(d), d + j]
    meat = _score_hac(je[keep], js[keep], e0, v0, filt.starts)
    if meat is not None:
        a_inv = np.linalg.pinv(fisher[np.ix_(keep, keep)], rcond=1e-12, hermitian=True)
        fixed = (a_inv @ meat @ a_inv)[:d, :d]
        sand[:] = 0.0
        sand[np.ix_(idx, idx)] = fixed + select - np.outer(b[:, j], b[:, j])
    return {"psi": psi, "cov": cov, "cov_sandwich": sand, "converged": True,
            "iterations": 1, "reason": CONVERGED, "nll_terms": single["nll_terms"],
            "free": d + 2, "q": q, "q_z": float(z[j]), "rho_c": float(grid[j])}


def fit_groups(data: RegressionData, spec: ModelSpec, theta_start: np.ndarray, *,
               max_iter: int = 100, tol: float = SCORING_TOL,
               models: tuple[str, ...] = DISTURBANCE_MODELS,
               parallel: bool = True, joint: bool = False,
               details: bool = False, boundary: str = "bounded") -> dict[str, np.ndarray]:
    """Fit every group of ``data`` from the rows of ``theta_start`` (G, P), each with
    every disturbance model; keep the model with the higher likelihood. ``joint``: then
    fit both processes at once from the better model and report that (module docstring)
    where its scoring converged.

    Returns a dict of per-group arrays: ``theta`` (G, P; NaN where not finite),
    ``cov`` (G, P, P; inverse Fisher), ``cov_sandwich`` (G, P, P; quasi-ML sandwich),
    ``cov_conservative`` (G, P, P; :func:`conservative_covariance`),
    ``psi`` (G, P + 7), ``model`` (G,), ``converged``, ``iterations``, ``reason``,
    ``loglik`` (G, len(models)), ``vuong`` (G,; z of ``models[0]`` against
    ``models[1]``), ``lr_joint`` (G,; twice the joint model's log-likelihood gain over the
    better single-process model, NaN without ``joint``), ``local_z`` (G,; the z of the
    unbounded sensor-noise variance step, :func:`_local_joint`, where computed),
    ``shape_z`` / ``shape_bimodal`` (G,; the kurtosis test of the smoothed current,
    :func:`vesselid.identify.current_shape.smoothed_current_test`, where computed) and
    ``boundary`` (G,; the bound applied: ``bounded`` or ``unbounded``).

    ``boundary`` (with ``joint``): ``"bounded"`` reports the joint fit with σ_c ≥ 0;
    ``"unbounded"`` reports :data:`JOINT_LOCAL` instead where the current model is the
    better single process and the joint fit's likelihood ratio is at most
    :data:`LOCAL_LR` (module docstring); ``"auto"`` is ``"unbounded"`` unless the
    smoothed current looks bimodal, then ``"bounded"`` with the spread between the two
    fits added to the covariance. The unbounded step and the shape test are computed
    for ``details`` either way.
    """
    if boundary not in BOUNDARIES:
        raise IdentificationError(
            f"boundary must be one of {list(BOUNDARIES)}, got {boundary!r}")
    codes = spec.codes
    fac = codes.factors
    n_par = spec.n_params
    n_groups = data.n_groups
    out: dict[str, np.ndarray] = {
        "theta": np.full((n_groups, n_par), np.nan),
        "cov": np.full((n_groups, n_par, n_par), np.nan),
        "psi": np.full((n_groups, n_par + 7), np.nan),
        "model": np.full(n_groups, "", dtype=object),
        "converged": np.zeros(n_groups, dtype=bool),
        "iterations": np.zeros(n_groups, dtype=np.int64),
        "reason": np.full(n_groups, BAD_START, dtype=object),
        "loglik": np.full((n_groups, len(models)), np.nan),
        "vuong": np.full(n_groups, np.nan),
        "cov_sandwich": np.full((n_groups, n_par, n_par), np.nan),
        "cov_conservative": np.full((n_groups, n_par, n_par), np.nan),
        "lr_joint": np.full(n_groups, np.nan),
        "local_z": np.full(n_groups, np.nan),
        "shape_z": np.full(n_groups, np.nan),
        "shape_bimodal": np.zeros(n_groups, dtype=bool),
        "boundary": np.full(n_groups, "", dtype=object),
    }
    if details:  # every candidate's fit (studies of the model choice)
        for prefix in ("single_", "joint_", "local_"):
            out[prefix + "theta"] = np.full((n_groups, n_par), np.nan)
            out[prefix + "psi"] = np.full((n_groups, n_par + 7), np.nan)
            out[prefix + "cov"] = np.full((n_groups, n_par, n_par), np.nan)
            out[prefix + "cov_sandwich"] = np.full((n_groups, n_par, n_par), np.nan)
            out[prefix + "cov_conservative"] = np.full((n_groups, n_par, n_par), np.nan)
        out["joint_converged"] = np.zeros(n_groups, dtype=bool)
    for g in range(n_groups):
        th0 = np.asarray(theta_start[g], dtype=float)
        if not np.all(np.isfinite(th0)):
            continue
        rows, starts = data.group_rows(g)
        cx, cu, tscale = group_units(data, rows, fac)
        y = data.target[rows, 0] / cx
        u = data.u[rows] / cu
        filt = _Filter(y, u, starts, fac, parallel)
        firsts = []
        for m in models:
            psi0, free, scale = _start(th0 * tscale, y, u, starts, fac, m)
            if not scale > EXACT_FIT * max(float(np.max(np.abs(y))), 1e-300):
                break  # noise-free: the likelihood has no maximum, the start is exact
            firsts.append((psi0, free))
        if not firsts:
            out["theta"][g] = th0
            out["cov"][g] = 0.0
            out["cov_sandwich"][g] = 0.0
            out["cov_conservative"][g] = 0.0
            out["model"][g] = "none"
            out["converged"][g] = True
            out["reason"][g] = EXACT
            continue
        stage_args = (filt, n_par, scale, max_iter, tol, boundary, details, fac)
        fits, early = _candidates(filt, firsts, models, max_iter, tol,
                                  stage_args if joint else None)
        ll = _logliks(fits, filt.count, cx)
        best = int(np.argmax(ll))
        if fits[best]["tail"] is not None:
            # the other models' fits take secant steps in their tail (they lose on the
            # logs this estimator is chosen for, and only their likelihood is reported);
            # a winner is the plain scoring's fit, reported as it always was: continued
            # from where the secant steps began (the plain scoring's path up to there)
            psi_t, done = fits[best]["tail"]
            plain = _scoring(filt, psi_t, firsts[best][1], max_iter - done, tol)
            plain["iterations"] += done
            fits[best] = plain
            ll = _logliks(fits, filt.count, cx)
            best = int(np.argmax(ll))
        f = fits[best]
        out["loglik"][g] = ll
        if len(fits) == 2:
            out["vuong"][g] = _vuong(fits[0], fits[1], filt.count)
        out["model"][g] = models[best]
        iterations = sum(x["iterations"] for x in fits)
        fj = None
        if joint and np.isfinite(ll[best]) and f["converged"]:
            stage = (early if early is not None and best == 0 else
                     _joint_stage(f, models[best], *stage_args))
            fj, local, bound = stage["joint"], stage["local"], stage["bound"]
            iterations += stage["iterations"]
            if stage["shape"] is not None:
                out["shape_z"][g] = stage["shape"]["z"]
                out["shape_bimodal"][g] = stage["shape"]["bimodal"]
            out["boundary"][g] = bound
            if fj["nll_terms"] is not None:
                gain = float(np.sum(f["nll_terms"]) - np.sum(fj["nll_terms"]))
                out["lr_joint"][g] = 2.0 * gain
                if (fj["converged"] and np.isfinite(gain) and gain >= 0
                        and (local is None or bound == "bounded"
                             or 2.0 * gain > LOCAL_LR)):
                    f = fj
                    out["model"][g] = JOINT
            if local is not None and bound == "unbounded" and out["model"][g] != JOINT:
                f = local
                out["model"][g] = JOINT_LOCAL
            elif local is not None and boundary == "auto" and bound == "bounded":
                f = _with_spread(f, local, n_par)
            if local is not None:
                out["local_z"][g] = local["q_z"]
                if "local_theta" in out:
                    _store(out, "local_", g, local, tscale, cx, n_par)
        out["converged"][g] = f["converged"]
        out["iterations"][g] = iterations
        out["reason"][g] = f["reason"]
        if np.isfinite(ll[best]):
            _store(out, "", g, f, tscale, cx, n_par)
            if "single_theta" in out:
                _store(out, "single_", g, fits[best], tscale, cx, n_par)
                if fj is not None:
                    _store(out, "joint_", g, fj, tscale, cx, n_par)
                    out["joint_converged"][g] = fj["converged"]
    return out


def _logliks(fits: list[dict[str, Any]], count: int, cx: float) -> np.ndarray:
    """Each fit's log-likelihood in the log's units (``-inf`` where not finite)."""
    ll = np.array([-np.sum(f["nll_terms"]) if f["nll_terms"] is not None else -np.inf
                   for f in fits]) - count * math.log(cx)
    return np.where(np.isfinite(ll), ll, -np.inf)


def _candidates(filt: _Filter, firsts: list[tuple[np.ndarray, np.ndarray]],
                models: tuple[str, ...], max_iter: int, tol: float,
                stage_args: tuple | None) -> tuple[list[dict[str, Any]], dict | None]:
    """The scoring fit of every disturbance model from its start ``firsts[i]``, and
    (``stage_args``: the joint model is wanted) the joint stage of the first model
    (:func:`_joint_stage`) where it may be the better one, or ``None``.

    Where the calling thread may use a second thread (:func:`vesselid.core.threads.
    background`), the other models are fitted there while this thread fits the first
    and runs its joint stage ahead: the first model (``current``) wins on the
    coloured-current logs that take this estimator, and its stage needs no other fit.
    Each fit runs the same code on the same numbers in whichever thread, so the results
    are those of the serial order; only a stage computed for a model that loses is
    work thrown away. The other models' scoring takes secant steps in its tail where
    the first model's fit is the better one by a margin (:func:`_scoring`; it waits for
    that fit, so the choice is the same whatever the threads); :func:`fit_groups`
    continues one that wins after all without them."""
    from concurrent.futures import Future

    from vesselid.core.threads import background

    done: Future = Future()  # the first model's negative log-likelihood

    def rival() -> float | None:
        return done.result()

    def rest() -> list[dict[str, Any]]:
        return [_scoring(filt, psi0, free, max_iter, tol, secant=rival)
                for psi0, free in firsts[1:]]

    def settle(fit: dict[str, Any]) -> None:
        terms = fit["nll_terms"]
        done.set_result(float(np.sum(terms)) if terms is not None else None)

    job = background(rest) if filt.parallel and len(firsts) > 1 else None
    if job is None:
        first = _scoring(filt, *firsts[0], max_iter, tol)
        settle(first)
        return [first, *rest()], None
    try:
        first = _scoring(filt, *firsts[0], max_iter, tol)
        settle(first)
        early = None
        if stage_args is not None and first["converged"] and (
                first["nll_terms"] is not None and np.isfinite(np.sum(first["nll_terms"]))):
            mine = float(np.sum(first["nll_terms"]))

            def beaten() -> bool:  # another model already fits better: stop the stage
                return job.done() and job.exception() is None and any(
                    o["nll_terms"] is not None and float(np.sum(o["nll_terms"])) < mine
                    for o in job.result())

            early = _joint_stage(first, models[0], *stage_args, abandon=beaten)
    except BaseException as exc:
        if not done.done():
            done.set_exception(exc)
        wait([job])  # never leave while the other fits still run
        raise
    return [first, *job.result()], early


def _joint_stage(f: dict[str, Any], model: str, filt: _Filter, n_par: int, scale: float,
                 max_iter: int, tol: float, boundary: str, details: bool,
                 fac: np.ndarray, abandon: Callable[[], bool] | None = None
                 ) -> dict[str, Any] | None:
    """What :func:`fit_groups` computes from the better single-process fit ``f`` (of
    ``model``): the joint model's scoring (continued where it is still climbing past
    :data:`JOINT_ITER` steps), the shape test of the smoothed current and the
    unbounded one-step estimate (:func:`_local_joint`) where they apply, and the bound
    applied. Reads ``f`` only. ``None`` where ``abandon`` says so (:func:`_scoring`)."""
    fj = _scoring(filt, _joint_start(f, model, n_par, scale),
                  np.ones(n_par + 7, dtype=bool), min(max_iter, JOINT_ITER), tol,
                  abandon=abandon)
    if fj is None:
        return None
    iterations = fj["iterations"]
    if (fj["reason"] == MAX_ITER and fj["nll_terms"] is not None
            and np.sum(fj["nll_terms"]) < np.sum(f["nll_terms"])
            and max_iter > JOINT_ITER):
        # already a better fit than the single process yet still climbing: a
        # second process is there, so let the scoring finish
        more = _scoring(filt, fj["psi"], np.ones(n_par + 7, dtype=bool),
                        max_iter - JOINT_ITER, tol, abandon=abandon)
        if more is None:
            return None
        iterations += more["iterations"]
        if more["nll_terms"] is not None:
            fj = more
    bound, shape = boundary, None
    if model == "current" and (boundary == "auto" or details):
        shape = smoothed_current_test(
            _residuals(f["psi"], filt.y, filt.u, filt.starts, fac, n_par),
            math.tanh(float(f["psi"][_layout(n_par)["rho_v"]])))
        if boundary == "auto":
            bound = "bounded" if shape["bimodal"] else "unbounded"
    local = (_local_joint(filt, f, n_par)
             if model == "current" and (bound == "unbounded" or details
                                        or boundary == "auto")
             else None)
    return {"joint": fj, "iterations": iterations, "shape": shape, "bound": bound,
            "local": local}


def _store(out: dict[str, np.ndarray], prefix: str, g: int, f: dict[str, Any],
           tscale: np.ndarray, cx: float, n_par: int) -> None:
    """Group ``g``'s fit ``f`` back in the log's units into ``out[prefix + key]``."""
    if not np.all(np.isfinite(f["psi"][:n_par])):
        return
    psi = f["psi"].copy()
    psi[:n_par] /= tscale
    ix = _layout(n_par)
    psi[ix["mu_w"]] *= cx
    for key in ("sigma_v", "sigma_c", "sigma_w", "sigma_e"):
        psi[ix[key]] += math.log(cx)
    out[prefix + "theta"][g] = psi[:n_par]
    out[prefix + "psi"][g] = psi
    out[prefix + "cov"][g] = f["cov"][:n_par, :n_par] / np.outer(tscale, tscale)
    sand = _sandwich(f) if "sandwich_parts" in f else f["cov_sandwich"]
    out[prefix + "cov_sandwich"][g] = sand[:n_par, :n_par] / np.outer(tscale, tscale)
    out[prefix + "cov_conservative"][g] = (
        conservative_covariance(f["cov"][:n_par, :n_par], sand[:n_par, :n_par])
        / np.outer(tscale, tscale))


def conservative_covariance(fisher: np.ndarray, sandwich: np.ndarray) -> np.ndarray:
    """``F⁻¹ + (Σ_S − F⁻¹)₊``: the inverse Fisher information plus the positive part
    (eigenvalues clipped at zero) of the sandwich's excess over it. It lies above both in
    the Loewner order, so every linear combination's variance is at least the larger of
    the two. The inverse Fisher information is efficient but valid only for the
    modelled Gaussian processes; the sandwich is valid beyond them but its HAC estimate
    of the long-run score variance is biased downward at 10⁴ samples (measured:
    ``scripts/robustness_study.py``, ``docs/guide/choosing-an-estimator.md``). NaN where
    either is not finite."""
    if not (np.all(np.isfinite(fisher)) and np.all(np.isfinite(sandwich))):
        return np.full_like(fisher, np.nan)
    diff = 0.5 * ((sandwich - fisher) + (sandwich - fisher).T)
    lam, vec = np.linalg.eigh(diff)
    return fisher + (vec * np.maximum(lam, 0.0)) @ vec.T


class OneStateLikelihood(Estimator):
    """The frame of a likelihood estimator of one state equation without a disturbance
    sensor (:func:`supports`), started from IV_{E{ζ}=0}: the fit of every group by
    :meth:`fit_groups_from` (a dict of per-group arrays with ``theta``, ``converged``,
    ``iterations``, ``reason`` and the covariances of :data:`COVARIANCE_KEYS`, kept in the
    result's ``info`` under :attr:`info_prefix`), its own covariance as reported
    (``covariance``) and the measured regressors as the diagnostics' design."""

    uses_instruments: ClassVar[bool] = False
    multi_experiment: ClassVar[tuple[str, ...]] = ("pooled",)
    reports_convergence: ClassVar[bool] = True
    #: The prefix of the fit's arrays in the result's ``info``.
    info_prefix: ClassVar[str] = ""
    covariance: str

    def fit_groups_from(self, data: RegressionData, spec: ModelSpec,
                        theta_start: np.ndarray) -> dict[str, np.ndarray]:
        """Every group of ``data`` fitted from the rows of ``theta_start`` (G, P)."""
        raise NotImplementedError

    def covariance_label(self) -> tuple[str, str]:
        """``(cov_type, label)`` of the reported covariance."""
        raise NotImplementedError

    def _check_spec(self, spec: ModelSpec) -> None:
        if not supports(spec):
            has = ([f"{spec.n_states} state equations"] if spec.n_states != 1 else []) + (
                ["an [aggregate] relation (a disturbance sensor)"] if spec.aggregate else [])
            raise IdentificationError(
                f"method {self.name!r} models one state equation without a disturbance "
                f"sensor; this spec has {' and '.join(has)} — use 'auto' or 'iv-zero-mean'")

    def _check_data(self, data: RegressionData) -> None:
        """One-line reasons for a log the model does not describe (none here)."""

    def estimate_parameters(self, data: RegressionData, spec: ModelSpec, *,
                            combine: str = "pooled", theta_start: np.ndarray | None = None,
                            max_iter: int = 100, tol: float = 1e-9,
                            keep_history: bool = False,
                            base: IterationResult | None = None) -> IterationResult:
        """Every group from its IV_{E{ζ}=0} estimate (``base`` if given)."""
        self._validate(spec)
        self._check_data(data)
        if base is None:
            base = estimate(data, spec, "iv-zero-mean", combine="pooled",
                            theta_start=theta_start, max_iter=max_iter, tol=tol)
        res = self.fit_groups_from(data, spec, base.theta)
        theta = res.pop("theta")
        n = data.n_groups
        reason = np.where(np.isfinite(base.theta).all(axis=1), res["reason"], base.reason)
        prefix = self.info_prefix
        return IterationResult(
            theta=theta, theta_aux=theta.copy(), converged=res["converged"].copy(),
            iterations=res["iterations"].copy(), reason=reason.astype(object),
            residual=np.zeros(n), oscillation=np.zeros(n, dtype=bool), start=base.start,
            info={"base": base, **{f"{prefix}{k}": v for k, v in res.items()}},
            history=[theta.copy()] if keep_history else [],
        )

    def equation_designs(self, data, spec, it, phi, combine):
        # the measured regressors and one-step residuals (diagnostics only: the
        # covariance is the likelihood's own, :meth:`own_covariance`)
        return square_designs(data, spec, phi, phi, it.theta[0], zero_mean=False,
                              combine=combine)

    def own_covariance(self, it: IterationResult) -> np.ndarray | None:
        return it.info[self.info_prefix + COVARIANCE_KEYS[self.covariance]][0]

    def own_covariance_label(self, it: IterationResult) -> tuple[str, str]:
        return self.covariance_label()


class PredictionError(OneStateLikelihood):
    """Prediction-error / quasi-ML estimator with the current or the sensor noise as a
    Gauss–Markov filter state (module docstring).

    Parameters
    ----------
    scoring_iter : int
        Fisher-scoring steps per disturbance model.
    scoring_tol : float
        Stop when the squared Newton decrement ``gᵀ F⁻¹ g`` (twice the predicted decrease
        of the negative log-likelihood; the squared step in standard errors) falls below
        it (:data:`SCORING_TOL`).
    joint : bool
        Also fit both processes at once from the better single-process model and report
        it where it converges (:func:`fit_groups`; ``auto`` does).
    covariance : {"fisher", "sandwich", "conservative"}
        The reported covariance: the inverse Fisher information (efficient when the
        disturbance model is right), the quasi-ML sandwich (valid beyond it) or the
        smallest covariance above both (:func:`conservative_covariance`).
    """

    name: ClassVar[str] = "pem"
    label: ClassVar[str] = ("prediction error (quasi-ML), Gauss–Markov current or sensor "
                            "noise as filter states")
    short: ClassVar[str] = "PEM"
    plot_label: ClassVar[str] = "PEM"
    info_prefix: ClassVar[str] = "pem_"

    def __init__(self, scoring_iter: int = 100, scoring_tol: float = SCORING_TOL,
                 joint: bool = False, covariance: str = "fisher") -> None:
        super().__init__(scoring_iter=scoring_iter, scoring_tol=scoring_tol, joint=joint,
                         covariance=covariance)
        self.scoring_iter = scoring_iter
        self.scoring_tol = scoring_tol
        self.joint = joint
        self.covariance = covariance

    def _validate(self, spec: ModelSpec) -> None:
        if not (isinstance(self.scoring_iter, int | np.integer) and self.scoring_iter >= 1):
            raise IdentificationError(
                f"scoring_iter must be a positive integer, got {self.scoring_iter!r}")
        if not (isinstance(self.scoring_tol, float | int | np.floating | np.integer)
                and np.isfinite(self.scoring_tol) and self.scoring_tol > 0):
            raise IdentificationError(
                f"scoring_tol must be a positive number, got {self.scoring_tol!r}")
        check_pem_options(self.joint, self.covariance)
        self._check_spec(spec)

    def check_covariance(self, cov_type: str | None) -> None:
        if cov_type is not None:
            raise IdentificationError(
                "method 'pem' reports the inverse Fisher information of its likelihood; "
                f"cov_type {cov_type!r} applies to the instrumental-variable estimators")

    def fit_groups_from(self, data: RegressionData, spec: ModelSpec,
                        theta_start: np.ndarray) -> dict[str, np.ndarray]:
        return fit_groups(data, spec, theta_start, max_iter=int(self.scoring_iter),
                          tol=float(self.scoring_tol), joint=bool(self.joint))

    def covariance_label(self) -> tuple[str, str]:
        return covariance_label(self.covariance)

    def describe(self, it: IterationResult) -> dict[str, Any]:
        out = describe_fit(it.info, 0, it.theta.shape[1])
        out["assumption"] = assumption_text(str(it.info["pem_model"][0]))
        return out


def covariance_label(kind: str) -> tuple[str, str]:
    """``(cov_type, label)`` of the likelihood estimate's covariance ``kind``."""
    if kind == "sandwich":
        return "sandwich", ("quasi-ML sandwich F⁻¹ S F⁻¹ (HAC scores; valid when the "
                            "disturbances are not the modelled Gaussian processes)")
    if kind == "conservative":
        return "conservative", ("the larger of the inverse Fisher information and the "
                                "quasi-ML sandwich (F⁻¹ + (sandwich − F⁻¹)₊, HAC scores)")
    return "fisher", "inverse Fisher information (quasi-ML)"


def check_pem_options(joint: Any, covariance: Any) -> None:
    """One-line reasons for bad ``joint`` / ``covariance`` options."""
    if not isinstance(joint, bool | np.bool_):
        raise IdentificationError(f"joint must be True or False, got {joint!r}")
    if covariance not in COVARIANCES:
        raise IdentificationError(
            f"covariance must be one of {list(COVARIANCES)}, got {covariance!r}")


def assumption_text(model: str) -> str:
    """The disturbance model the estimate rests on, in one sentence."""
    what = {"current": "a Gauss–Markov current inside the modulus and white sensor noise",
            "sensor": "a white current inside the modulus and Gauss–Markov sensor noise",
            JOINT: "a Gauss–Markov current inside the modulus and Gauss–Markov sensor "
                   "noise",
            JOINT_LOCAL: "a Gauss–Markov current inside the modulus and Gauss–Markov "
                         "sensor noise (possibly absent)",
            }.get(model)
    if what is None:
        return "none: the log is noise-free and the estimate is exact"
    return ("this estimate assumes the disturbances are " + what + " (zero-mean "
            "Gaussian processes); on other disturbances it can be biased — compare "
            "'auto' and 'iv-zero-mean'")


def describe_fit(info: dict[str, Any], g: int, n_par: int) -> dict[str, Any]:
    """The disturbance model of group ``g`` in words and numbers (JSON-ready)."""
    psi = info["pem_psi"][g]
    model = str(info["pem_model"][g])
    if model == "none":
        return {"disturbance_model": "none",
                "noise_model": "none: the log is noise-free (exact fit of the IV start)"}
    ix = _layout(n_par)

    def num(key: str) -> float:
        v = float(psi[ix[key]])
        if key.startswith("rho"):
            return math.tanh(v)
        if key.startswith("sigma"):
            return math.exp(v) if np.isfinite(v) else 0.0
        return v

    est = {k: num(k) for k in ix}
    if model == "current":
        txt = (f"Gauss–Markov current inside the modulus (ρ_v = {est['rho_v']:.3g}, "
               f"σ_v = {est['sigma_v']:.3g}), white sensor noise σ_e = {est['sigma_e']:.3g}")
    elif model == JOINT_LOCAL:
        zq = info.get("pem_local_z")
        zq = float(zq[g]) if zq is not None else float("nan")
        txt = (f"Gauss–Markov current inside the modulus (ρ_v = {est['rho_v']:.3g}, "
               f"σ_v = {est['sigma_v']:.3g}) and Gauss–Markov sensor noise whose variance "
               f"is estimated without its bound at zero (ρ_c = {est['rho_c']:.3g}, "
               f"σ_c = {est['sigma_c']:.3g}, variance z = {zq:+.2f}: one scoring step "
               f"from the current model) plus white σ_e = {est['sigma_e']:.3g}")
    elif model == JOINT:
        txt = (f"Gauss–Markov current inside the modulus (ρ_v = {est['rho_v']:.3g}, "
               f"σ_v = {est['sigma_v']:.3g}) and Gauss–Markov sensor noise "
               f"(ρ_c = {est['rho_c']:.3g}, σ_c = {est['sigma_c']:.3g}) plus white "
               f"σ_e = {est['sigma_e']:.3g}")
    else:
        txt = (f"white current inside the modulus (σ_v = {est['sigma_v']:.3g}), "
               f"Gauss–Markov sensor noise (ρ_c = {est['rho_c']:.3g}, "
               f"σ_c = {est['sigma_c']:.3g}) plus white σ_e = {est['sigma_e']:.3g}")
    txt += f"; process noise σ_w = {est['sigma_w']:.3g}, mean μ_w = {est['mu_w']:.3g}"
    z = float(info["pem_vuong"][g])
    p = math.erfc(abs(z) / math.sqrt(2.0)) if np.isfinite(z) else float("nan")
    ll = info["pem_loglik"][g]
    out = {
        "disturbance_model": model,
        "noise_model": txt,
        "noise_parameters": est,
        "log_likelihood": {m: float(v) for m, v in zip(DISTURBANCE_MODELS, ll, strict=False)},
        "model_choice": (f"{model} model: log-likelihood {float(np.max(ll)):.6g} against "
                         f"{float(np.min(ll)):.6g}; Vuong z (current vs sensor noise) = "
                         f"{z:.3g}, p = {p:.3g}"),
    }
    zs = info.get("pem_shape_z")
    if zs is not None and np.isfinite(zs[g]):
        from vesselid.identify.current_shape import SHAPE_ALPHA

        bound = info.get("pem_boundary")
        out["current_shape"] = {
            "kurtosis_z": float(zs[g]), "level": SHAPE_ALPHA,
            "sensor_noise_bound": str(bound[g]) if bound is not None else "",
            "test": ("excess kurtosis of the smoothed one-step residuals of the current "
                     "model (negative: a bimodal, switching current)")}
    lr = info.get("pem_lr_joint")
    if lr is not None and np.isfinite(lr[g]):
        out["model_choice"] = (
            f"{model} model: both processes at once fitted from the better single-process "
            f"model; likelihood-ratio statistic {float(lr[g]):.3g} against it ("
            + out["model_choice"] + ")")
    return out
