"""Maximum-likelihood estimator with a switching (telegraph) current inside the modulus.

The Gauss–Markov current of :mod:`vesselid.identify.pem` describes a current whose
increments are small and Gaussian. A tidal-step current is not: it sits at one of two
levels ``±c`` and jumps between them at random times (a two-state Markov chain,
switching probability ``p`` a sample). Its autocorrelation is that of a Gauss–Markov
current (``(1 − 2p)^k``), but ``v²`` is constant and the filter's Gaussian approximation
of ``E[h(x + v)]`` through the modulus term is then wrong, which biases ``a`` and ``n``
by several standard errors (``scripts/robustness_study.py``, telegraph design).

Here the current level is a hidden Markov state: for one state equation of Definition
2.1 the interacting-multiple-model filter of :mod:`vesselid.identify._switchkernels`
keeps one Gaussian of the state per current level, propagates each through ``h`` with
its exact Gaussian mean and variance, mixes them by the chain's transition
probabilities and updates them with the measurement (white process noise ``w`` with
mean ``μ_w`` and std ``σ_w``, white sensor noise ``e`` with std ``σ_e``). The estimate
maximises the log-likelihood ``Σ_k log p(y(k) | y(<k))`` of that filter over
``ψ = [θ, μ_w, log c, logit 2p, log σ_w, log σ_e]``, from the consistent IV_{E{ζ}=0}
estimate, by BHHH steps (the outer product of finite-difference per-sample scores)
with a backtracking line search until the squared decrement falls below :data:`TOL`,
then confirmed (or finished) by Newton steps on the finite-difference Hessian ``H``
(stop: squared Newton decrement ``gᵀH⁻¹g`` below :data:`TOL`, the step at most 0.01
standard errors).

Covariances (θ block): ``fisher`` is the inverse observed information ``H⁻¹``;
``sandwich`` is ``H⁻¹ Ŝ H⁻¹`` with ``Ŝ`` the Bartlett HAC long-run variance of the
per-sample scores (valid when the filter's likelihood is only an approximation: the
filter's Gaussian mixture is not the exact conditional density);
``conservative`` (the default) lies above both
(:func:`vesselid.identify.pem.conservative_covariance`).

``auto`` fits this model only where the current looks switching (the kurtosis test
of the smoothed current of its Gauss–Markov fit,
:func:`vesselid.identify.current_shape.smoothed_current_test`) and reports it only
where Vuong's test of the two non-nested likelihoods prefers it
(:func:`vuong_switching`; :mod:`vesselid.identify.efficient`).

Single state, no disturbance sensor (``[aggregate]``), pooled experiments (the filter
restarted at every experiment).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from vesselid.errors import IdentificationError
from vesselid.identify.data import RegressionData
from vesselid.identify.estimators import IterationResult
from vesselid.identify.pem import COVARIANCE_KEYS, COVARIANCES, OneStateLikelihood
from vesselid.model.spec import ModelSpec

__all__ = ["COVARIANCES", "COVARIANCE_KEYS", "SwitchingCurrent", "compare_with_gaussian",
           "fit_groups", "vuong_switching"]

NOISE_NAMES = ("mu_w", "c", "p", "sigma_w", "sigma_e")

CONVERGED = "converged"
NO_DESCENT = "line search found no descent"
MAX_ITER = "maximum iterations reached"
BAD_START = "IV_E{ζ}=0 start not finite"
EXACT = "exact fit (noise-free log)"
HESSIAN = "Hessian not positive definite at the optimum"

#: Stop when the squared Newton decrement ``gᵀH⁻¹g`` falls below this (the last step
#: moves no parameter by more than 0.01 standard errors).
TOL = 1e-4
#: One-step residuals of the start below this fraction of max |y|: a noise-free log.
EXACT_FIT = 1e-12
#: Finite-difference steps (in units of the scaled parameters): scores, Hessian.
H_SCORE = 1e-5
H_HESS = 1e-4
#: Start of the switching probability (``p``) and of the level relative to the
#: residual scale (``c``).
P_START = 0.05


def supports(spec: ModelSpec, data: RegressionData | None = None) -> bool:
    """One state, no disturbance sensor, an unfiltered log (as :func:`pem.supports`)."""
    from vesselid.identify.pem import supports as pem_supports

    return pem_supports(spec, data)


class _Log:
    """One group's scaled log and the filter's calls on it."""

    def __init__(self, y: np.ndarray, u: np.ndarray, starts: np.ndarray,
                 fac: np.ndarray) -> None:
        from vesselid.identify._pemkernels import term_kinds

        self.y = np.ascontiguousarray(y, dtype=np.float64)
        self.u = np.ascontiguousarray(u, dtype=np.float64)
        self.starts = np.ascontiguousarray(starts, dtype=np.int64)
        self.terms = term_kinds(fac, 1 + self.u.shape[1])
        self.p_init = np.array([max(float(np.var(self.y[a:b])), 1e-300) if b > a else 1.0
                                for a, b in zip(self.starts[:-1], self.starts[1:],
                                                strict=True)])
        self.count = self.y.size - (self.starts.size - 1)

    def _run(self, rows: np.ndarray, per_sample: bool) -> tuple[np.ndarray, np.ndarray]:
        from vesselid.identify._switchkernels import switching_filter

        rows = np.ascontiguousarray(np.atleast_2d(rows), dtype=np.float64)
        ll = np.zeros((rows.shape[0], self.y.size if per_sample else 0))
        total = np.empty(rows.shape[0])
        switching_filter(rows, self.y, self.u, self.starts, self.p_init, *self.terms,
                         ll, total)
        return total, ll

    def nll(self, rows: np.ndarray) -> np.ndarray:
        """Negative log-likelihood of each row (``inf`` where not finite)."""
        tot = -self._run(rows, False)[0]
        return np.where(np.isfinite(tot), tot, np.inf)

    def terms_of(self, psi: np.ndarray) -> np.ndarray:
        """Per-sample log-likelihoods (T,) of the row ``psi``."""
        return self._run(psi, True)[1][0]

    def scores(self, psi: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, float]:
        """Central finite-difference per-sample scores of the log-likelihood (T, d)
        with respect to ``psi[idx]`` and the negative log-likelihood at ``psi``."""
        d = idx.size
        rows = np.repeat(psi[None, :], 2 * d + 1, axis=0)
        for j, i in enumerate(idx):
            rows[2 * j, i] += H_SCORE
            rows[2 * j + 1, i] -= H_SCORE
        total, ll = self._run(rows, True)
        sc = (ll[0:2 * d:2] - ll[1:2 * d:2]).T / (2.0 * H_SCORE)
        return sc, float(-total[-1])

    def hessian(self, psi: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Central finite-difference Hessian of the negative log-likelihood (d, d)."""
        d = idx.size
        h = H_HESS
        pairs = [(i, j) for i in range(d) for j in range(i, d)]
        rows = np.repeat(psi[None, :], 4 * len(pairs) + 1, axis=0)
        for q, (i, j) in enumerate(pairs):
            for r, (si, sj) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
                rows[4 * q + r, idx[i]] += si * h
                rows[4 * q + r, idx[j]] += sj * h
        f = -self._run(rows, False)[0]
        out = np.empty((d, d))
        for q, (i, j) in enumerate(pairs):
            v = (f[4 * q] - f[4 * q + 1] - f[4 * q + 2] + f[4 * q + 3]) / (4.0 * h * h)
            out[i, j] = out[j, i] = v
        return out


def _start(theta: np.ndarray, log: _Log, fac: np.ndarray) -> tuple[np.ndarray, float]:
    """Start row from the (scaled) IV estimate and the start's residual std."""
    from vesselid.model.regressors import evaluate

    n_par = theta.size
    sig = np.concatenate([log.y[:, None], log.u], axis=1)
    res = log.y[1:] - evaluate(fac, sig[:-1]) @ theta
    keep = np.ones(res.size, dtype=bool)
    keep[log.starts[1:-1] - 1] = False
    res = res[keep]
    scale = float(np.std(res)) if res.size > 1 else 0.0
    psi = np.empty(n_par + 5)
    psi[:n_par] = theta
    psi[n_par] = float(np.mean(res)) if res.size else 0.0
    base = math.log(scale / 2.0) if scale > 0 and np.isfinite(scale) else 0.0
    psi[n_par + 1] = base
    psi[n_par + 2] = math.log(P_START / (0.5 - P_START))
    psi[n_par + 3] = base
    psi[n_par + 4] = base
    return psi, scale


def _maximise(log: _Log, psi0: np.ndarray, max_iter: int, tol: float) -> dict[str, Any]:
    """BHHH with backtracking from ``psi0``, then Newton on the Hessian (module
    docstring). Returns ``psi``, ``nll``, ``hessian``, ``scores``, ``iterations``,
    ``converged``, ``reason``."""
    idx = np.arange(psi0.size)
    psi = psi0.copy()
    f0 = float(log.nll(psi)[0])
    if not np.isfinite(f0):
        return {"psi": psi, "nll": f0, "converged": False, "reason": BAD_START,
                "iterations": 0, "hessian": None, "scores": None}
    reason = MAX_ITER
    it = 0
    newton = False
    hess = None
    while it < max_iter:
        it += 1
        sc, f0 = log.scores(psi, idx)
        g = -sc.sum(axis=0)  # gradient of the negative log-likelihood
        if newton:
            hess = log.hessian(psi, idx)
            curv = hess
        else:
            curv = sc.T @ sc
        try:
            lam, vec = np.linalg.eigh(0.5 * (curv + curv.T))
        except np.linalg.LinAlgError:
            reason = NO_DESCENT
            break
        if not np.all(np.isfinite(lam)) or lam[-1] <= 0:
            reason = NO_DESCENT
            break
        if lam[0] <= 1e-10 * lam[-1]:
            if newton:  # the Hessian is not positive definite: stop at the BHHH optimum
                reason = HESSIAN
                break
            lam = np.maximum(lam, 1e-10 * lam[-1])
        step = -(vec @ ((vec.T @ g) / lam))
        dec = float(-(g @ step))
        if dec < tol:
            if newton:
                reason = CONVERGED
                break
            newton = True  # BHHH has converged: confirm (or finish) with Newton steps
            it -= 1
            continue
        alpha, moved = 1.0, False
        for _ in range(30):
            trial = psi + alpha * step
            f1 = float(log.nll(trial)[0])
            if np.isfinite(f1) and f1 <= f0 - 1e-4 * alpha * dec:
                psi, moved = trial, True
                break
            alpha *= 0.5
        if not moved:
            reason = CONVERGED if dec < 100 * tol else NO_DESCENT
            break
        hess = None
    sc, f0 = log.scores(psi, idx)
    if hess is None:
        hess = log.hessian(psi, idx)
    ok = reason == CONVERGED
    if ok and not np.all(np.linalg.eigvalsh(0.5 * (hess + hess.T)) > 0):
        ok, reason = False, HESSIAN
    return {"psi": psi, "nll": f0, "converged": ok, "reason": reason, "iterations": it,
            "hessian": hess, "scores": sc}


def _covariances(fit: dict[str, Any], starts: np.ndarray) -> tuple[np.ndarray, ...]:
    """``H⁻¹``, the sandwich ``H⁻¹ Ŝ H⁻¹`` (Bartlett HAC of the scores) and the
    conservative covariance of the full row (scaled units)."""
    from vesselid.identify.pem import conservative_covariance, scores_long_run

    hess, sc = fit["hessian"], fit["scores"]
    d = fit["psi"].size
    nan = np.full((d, d), np.nan)
    if hess is None or sc is None or not np.all(np.isfinite(hess)):
        return nan, nan, nan
    try:
        hinv = np.linalg.inv(0.5 * (hess + hess.T))
    except np.linalg.LinAlgError:
        return nan, nan, nan
    sc = np.ascontiguousarray(np.where(np.isfinite(sc), sc, 0.0))
    sand = hinv @ scores_long_run(sc, starts) @ hinv
    sand = 0.5 * (sand + sand.T)
    return hinv, sand, conservative_covariance(hinv, sand)


def fit_groups(data: RegressionData, spec: ModelSpec, theta_start: np.ndarray, *,
               max_iter: int = 100, tol: float = TOL,
               groups: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Fit the switching-current model to every group of ``data`` (or the ``groups``
    mask's: the others keep NaN arrays and an empty ``reason``) from the rows of
    ``theta_start`` (G, P).

    Returns per-group arrays: ``theta`` (G, P), ``cov``/``cov_sandwich``/
    ``cov_conservative`` (G, P, P), ``noise`` (G, 5: μ_w, c, p, σ_w, σ_e in the log's
    units), ``psi`` (G, P + 5; scaled units), ``loglik`` (G,), ``converged``,
    ``iterations``, ``reason``, ``model`` (``switching`` or ``none`` on a noise-free
    log) and ``terms`` (a list: each group's per-sample log-likelihoods in the log's
    units, for the comparison with another model, :func:`vuong_switching`).
    """
    from vesselid.identify.pem import group_units

    fac = spec.codes.factors
    n_par = spec.n_params
    n = data.n_groups
    out: dict[str, Any] = {
        "theta": np.full((n, n_par), np.nan),
        "cov": np.full((n, n_par, n_par), np.nan),
        "cov_sandwich": np.full((n, n_par, n_par), np.nan),
        "cov_conservative": np.full((n, n_par, n_par), np.nan),
        "noise": np.full((n, 5), np.nan),
        "psi": np.full((n, n_par + 5), np.nan),
        "loglik": np.full(n, np.nan),
        "converged": np.zeros(n, dtype=bool),
        "iterations": np.zeros(n, dtype=np.int64),
        "reason": np.full(n, BAD_START, dtype=object),
        "model": np.full(n, "", dtype=object),
        "terms": [None] * n,
    }
    for g in range(n):
        if groups is not None and not groups[g]:
            out["reason"][g] = ""  # not asked for
            continue
        th0 = np.asarray(theta_start[g], dtype=float)
        if not np.all(np.isfinite(th0)):
            continue
        rows, starts = data.group_rows(g)
        cx, cu, tscale = group_units(data, rows, fac)
        log = _Log(data.target[rows, 0] / cx, data.u[rows] / cu, starts, fac)
        psi0, scale = _start(th0 * tscale, log, fac)
        if not scale > EXACT_FIT * max(float(np.max(np.abs(log.y))), 1e-300):
            out["theta"][g] = th0
            for key in COVARIANCE_KEYS.values():
                out[key][g] = 0.0
            out["model"][g] = "none"
            out["converged"][g] = True
            out["reason"][g] = EXACT
            continue
        fit = _maximise(log, psi0, max_iter, tol)
        psi = fit["psi"]
        out["psi"][g] = psi
        out["iterations"][g] = fit["iterations"]
        out["reason"][g] = fit["reason"]
        out["converged"][g] = fit["converged"]
        out["model"][g] = "switching"
        if not np.isfinite(fit["nll"]):
            continue
        out["loglik"][g] = -fit["nll"] - log.count * math.log(cx)
        terms = log.terms_of(psi)
        first = np.zeros(terms.size, dtype=bool)
        first[starts[:-1]] = True
        out["terms"][g] = np.where(first, np.nan, terms - math.log(cx))
        out["theta"][g] = psi[:n_par] / tscale
        for key, cov in zip(COVARIANCE_KEYS.values(), _covariances(fit, starts),
                            strict=True):
            out[key][g] = cov[:n_par, :n_par] / np.outer(tscale, tscale)
        out["noise"][g] = [psi[n_par] * cx, math.exp(psi[n_par + 1]) * cx,
                           0.5 / (1.0 + math.exp(-psi[n_par + 2])),
                           math.exp(psi[n_par + 3]) * cx, math.exp(psi[n_par + 4]) * cx]
    return out


def vuong_switching(terms_a: np.ndarray, terms_b: np.ndarray, free_a: int,
                    free_b: int) -> float:
    """Vuong's (1989) z of model ``a`` against the non-nested model ``b`` from their
    per-sample log-likelihoods on the same samples (NaN entries skipped), with Schwarz's
    correction ``½ (free_a − free_b) log T``: positive where ``a`` fits better;
    asymptotically standard normal where both fit equally well."""
    diff = np.asarray(terms_a, dtype=float) - np.asarray(terms_b, dtype=float)
    diff = diff[np.isfinite(diff)]
    t = diff.size
    if t < 2:
        return float("nan")
    lr = float(np.sum(diff)) - 0.5 * (free_a - free_b) * math.log(t)
    sd = float(np.std(diff))
    if not sd > 0:
        return 0.0 if lr == 0 else math.copysign(math.inf, lr)
    return lr / (math.sqrt(t) * sd)


#: One-sided level of Vuong's test of the switching model against the Gauss–Markov
#: model that ``auto`` reports it instead of (:func:`compare_with_gaussian`).
VUONG_ALPHA = 0.05
#: The Gauss–Markov models of :mod:`vesselid.identify.pem` with a current state, and
#: their free noise parameters (beside θ).
GAUSSIAN_FREE = {"current": 5, "joint": 7, "joint-local": 7}
#: Free noise parameters of the switching model (μ_w, c, p, σ_w, σ_e).
SWITCHING_FREE = 5


def gaussian_terms(data: RegressionData, g: int, psi: np.ndarray,
                   fac: np.ndarray, n_par: int) -> np.ndarray | None:
    """Per-sample log-likelihoods ``−½ (log 2π + log S + ε²/S)`` (T,; NaN at each
    experiment's first sample) of group ``g`` under the Gaussian filter of
    :mod:`vesselid.identify.pem` at its row ``psi`` (the log's units), or None."""
    from vesselid.identify.pem import _Filter

    if not np.all(np.isfinite(psi[:n_par])):
        return None
    rows, starts = data.group_rows(g)
    filt = _Filter(data.target[rows, 0], data.u[rows], starts, fac, parallel=False)
    eps, var = filt.run(psi[None, :])
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = -0.5 * (math.log(2.0 * math.pi) + np.log(var[0]) + eps[0] ** 2 / var[0])
    first = np.zeros(terms.size, dtype=bool)
    first[starts[:-1]] = True
    return np.where(first, np.nan, terms)


def compare_with_gaussian(data: RegressionData, spec: ModelSpec, theta_start: np.ndarray,
                          pem_res: dict[str, np.ndarray], candidates: np.ndarray, *,
                          alpha: float | None = None) -> dict[str, Any]:
    """Fit the switching model to the ``candidates`` groups and test it against their
    Gauss–Markov fit ``pem_res`` (:func:`vesselid.identify.pem.fit_groups`) by Vuong's
    test (:func:`vuong_switching`). ``taken`` (G,): the switching model converged and
    fits better at one-sided level ``alpha`` (z above the normal quantile).

    Returns the switching fit's arrays (:func:`fit_groups`, for every group; NaN where
    not fitted) with ``vuong`` (G,; z of the switching model against the Gauss–Markov
    one) and ``taken``. ``alpha``: :data:`VUONG_ALPHA` unless given."""
    from vesselid.identify._special import norm_ppf

    candidates = np.asarray(candidates, dtype=bool)
    out = fit_groups(data, spec, theta_start, groups=candidates)
    out["vuong"] = np.full(data.n_groups, np.nan)
    out["taken"] = np.zeros(data.n_groups, dtype=bool)
    crit = float(norm_ppf(1.0 - (VUONG_ALPHA if alpha is None else alpha)))
    n_par = spec.n_params
    for g in np.flatnonzero(candidates):
        terms = out["terms"][g]
        model = str(pem_res["model"][g])
        if terms is None or model not in GAUSSIAN_FREE:
            continue
        other = gaussian_terms(data, int(g), pem_res["psi"][g], spec.codes.factors, n_par)
        if other is None:
            continue
        z = vuong_switching(terms, other, n_par + SWITCHING_FREE,
                            n_par + GAUSSIAN_FREE[model])
        out["vuong"][g] = z
        out["taken"][g] = bool(out["converged"][g] and np.isfinite(z) and z > crit
                               and np.all(np.isfinite(out["cov_conservative"][g])))
    return out


def covariance_label(kind: str) -> tuple[str, str]:
    """``(cov_type, label)`` of the covariance ``kind``."""
    if kind == "sandwich":
        return "sandwich", ("quasi-ML sandwich H⁻¹ S H⁻¹ of the switching-current "
                            "likelihood (HAC scores)")
    if kind == "conservative":
        return "conservative", ("the larger of the inverse observed information and the "
                                "quasi-ML sandwich (H⁻¹ + (sandwich − H⁻¹)₊, HAC scores)")
    return "fisher", "inverse observed information of the switching-current likelihood"


def noise_text(noise: np.ndarray) -> str:
    """The fitted disturbance model in words."""
    mw, c, p, sw, se = (float(x) for x in noise)
    return (f"telegraph current ±{c:.3g} inside the modulus switching w.p. {p:.3g} a "
            f"sample (mean dwell {1.0 / max(p, 1e-300):.3g} samples), process noise "
            f"σ_w = {sw:.3g} with mean μ_w = {mw:.3g}, white sensor noise σ_e = {se:.3g}")


ASSUMPTION = ("this estimate assumes the current inside the modulus switches between two "
              "levels ±c as a Markov chain and the process and sensor noise are white "
              "Gaussian; on a Gaussian coloured current it can be biased — compare 'auto' "
              "and 'pem'")


class SwitchingCurrent(OneStateLikelihood):
    """Maximum likelihood with a two-level Markov-switching current inside the modulus
    (interacting-multiple-model filter; module docstring).

    Parameters
    ----------
    max_iter : int
        BHHH and Newton steps.
    tol : float
        Stop when the squared Newton decrement falls below it (:data:`TOL`).
    covariance : {"fisher", "sandwich", "conservative"}
        The reported covariance: inverse observed information, the quasi-ML sandwich,
        or the smallest covariance above both (default).
    """

    name: ClassVar[str] = "pem-switching"
    label: ClassVar[str] = ("maximum likelihood, two-level Markov-switching (telegraph) "
                            "current inside the modulus (IMM filter)")
    short: ClassVar[str] = "PEM switching"
    plot_label: ClassVar[str] = "PEM (switching)"
    info_prefix: ClassVar[str] = "sw_"

    def __init__(self, max_iter: int = 100, tol: float = TOL,
                 covariance: str = "conservative") -> None:
        super().__init__(max_iter=max_iter, tol=tol, covariance=covariance)
        self.max_iter = max_iter
        self.tol = tol
        self.covariance = covariance

    def _validate(self, spec: ModelSpec) -> None:
        if not (isinstance(self.max_iter, int | np.integer) and not isinstance(
                self.max_iter, bool) and self.max_iter >= 1):
            raise IdentificationError(
                f"max_iter must be a positive integer, got {self.max_iter!r}")
        if not (isinstance(self.tol, float | int | np.floating | np.integer)
                and not isinstance(self.tol, bool) and np.isfinite(self.tol)
                and self.tol > 0):
            raise IdentificationError(f"tol must be a positive number, got {self.tol!r}")
        if self.covariance not in COVARIANCES:
            raise IdentificationError(
                f"covariance must be one of {list(COVARIANCES)}, got {self.covariance!r}")
        self._check_spec(spec)

    def check_covariance(self, cov_type: str | None) -> None:
        if cov_type is not None:
            raise IdentificationError(
                "method 'pem-switching' reports its likelihood's own covariance; "
                f"cov_type {cov_type!r} applies to the instrumental-variable estimators")

    def _check_data(self, data: RegressionData) -> None:
        if data.lowpassed:
            raise IdentificationError(
                "method 'pem-switching' needs an unfiltered log (the low-pass filter is "
                "not part of its model) — use 'auto'")

    def fit_groups_from(self, data: RegressionData, spec: ModelSpec,
                        theta_start: np.ndarray) -> dict[str, np.ndarray]:
        return fit_groups(data, spec, theta_start, max_iter=int(self.max_iter),
                          tol=float(self.tol))

    def covariance_label(self) -> tuple[str, str]:
        return covariance_label(self.covariance)

    def describe(self, it: IterationResult) -> dict[str, Any]:
        return describe_fit(it.info, 0, prefix="sw_")


def describe_fit(info: dict[str, Any], g: int, prefix: str) -> dict[str, Any]:
    """The fitted switching-current model of group ``g`` (JSON-ready)."""
    model = str(info[prefix + "model"][g])
    if model == "none":
        return {"disturbance_model": "none",
                "noise_model": "none: the log is noise-free (exact fit of the IV start)"}
    noise = info[prefix + "noise"][g]
    return {"disturbance_model": "switching",
            "noise_model": noise_text(noise),
            "noise_parameters": {k: float(v) for k, v in zip(NOISE_NAMES, noise,
                                                               strict=True)},
            "log_likelihood": {"switching": float(info[prefix + "loglik"][g])},
            "assumption": ASSUMPTION}


def describe_auto(info: dict[str, Any], g: int) -> dict[str, Any]:
    """``auto``'s report of group ``g`` where it took the switching model: the model,
    and the Gauss–Markov model it was preferred to (JSON-ready)."""
    noise = info["pem_switch_noise"][g]
    gauss = str(info["pem_gaussian_model"][g])
    z = float(info["pem_switch_vuong"][g])
    p = 0.5 * math.erfc(z / math.sqrt(2.0)) if np.isfinite(z) else float("nan")
    return {"disturbance_model": "switching",
            "noise_model": noise_text(noise),
            "noise_parameters": {k: float(v) for k, v in zip(NOISE_NAMES, noise,
                                                               strict=True)},
            "log_likelihood": {"switching": float(info["pem_switch_loglik"][g])},
            "model_choice": (f"switching current against the Gauss–Markov {gauss} model: "
                             f"Vuong z = {z:.3g} (one-sided p = {p:.3g}, level "
                             f"{VUONG_ALPHA:g})"),
            "current_shape": {"kurtosis_z": float(info["pem_shape_z"][g]),
                              "test": "excess kurtosis of the smoothed one-step residuals "
                                      "of the Gauss–Markov current model (negative: a "
                                      "bimodal, switching current)"},
            "assumption": ASSUMPTION}
