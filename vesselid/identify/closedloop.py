"""Identification in closed loop: the closed-loop refined IV and the feedback test.

Closed-loop refined IV (``--method cl-iv``)
------------------------------------------
Under feedback the logged input carries the noise (``u(k)`` reacts to ``y(k) = x(k) +
e(k)``), so instruments simulated from it (the paper's auxiliary model, Lemma 3.1) violate
A6. Following the refined IV for closed loops of Gilson & Van den Hof (2005), the
instruments are built from the *external* signals only: the closed loop itself is
simulated noise-free with the current estimate θ̂ and the known controller, driven by
the reference ``r`` and the dither ``d`` alone,

    x̂(k+1) = Φᵀ([x̂(k); û(k)]) θ̂,   û(k) = C(r(k) − x̂(k)) + d(k),

and the instruments are the model's own (modulus) regressors of that simulation,
``ζ(k) = φ(x̂(k−1), û(k−1))``, centred per experiment (A7). They depend on ``r`` and ``d``
only, which are independent of the disturbances ``v``, ``w``, ``e``: (5b) holds term by
term exactly as in the proof of Lemma 3.1 (the input now appears only among the
regressors, whose noise the zero-mean instruments average out under A10), and (5a) holds
as long as the reference and dither excite the loop. The estimate is iterated to the
fixed point ``θ = T(θ)`` with the step control of :func:`~vesselid.identify.estimators.
refined_iv`, from least squares. Covariance: the package's ``cov_type`` (default HAC) on
the final instruments, regressors and residuals.

The log names its controller and external signals in ``metadata["closed_loop"]``
(:func:`vesselid.closedloop.closed_loop_metadata`, written by
:func:`vesselid.closedloop.simulate_closed_loop` and the environment recorder).

Feedback test
-------------
:func:`feedback_test` asks whether the input is correlated with past output errors: in
open loop (A4) ``u(k+τ)`` is independent of the equation error ``ε(k)`` for ``τ ≥ 0``; a
controller makes ``u(k)`` react to ``e(k)``. The statistic is the Wald test of the
moments ``E{ũ_j(k+τ) ε_i(k)} = 0`` (``ũ`` centred per experiment; ``τ = 0 … lags−1``; every
input ``j`` and state equation ``i``) on the residuals of the open-loop consistent
IV_E{ζ}=0 fit, with the estimation effect removed from the score (the residuals are
estimated: ``s(k) = (ũ(k+τ) − M A⁻¹ ζ(k)) ε̂(k)``, ``M = mean ũ(k+τ) φ(k)ᵀ``,
``A = mean ζ(k) φ(k)ᵀ``) and a Newey–West long-run covariance: χ² with
``n · m · lags`` degrees of freedom under open loop.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from vesselid.errors import ControlError, IdentificationError
from vesselid.identify.backend import kernels
from vesselid.identify.base import Estimator, equation_rows, square_designs
from vesselid.identify.data import RegressionData
from vesselid.identify.estimators import (
    STOP_START_DIVERGED,
    IterationResult,
    Moments,
    compute_moments,
    least_squares,
    moments_from_matrices,
    refined_iv,
    solve_moments,
)
from vesselid.model import ModelSpec

__all__ = ["ClosedLoopIV", "ClosedLoopSignals", "FeedbackTest", "closed_loop_signals",
           "feedback_test", "feedback_test_data"]

#: Significance level of the open-loop warning and of ``auto``'s switch to ``cl-iv``.
FEEDBACK_ALPHA = 0.01
#: Lags ``τ = 0 … FEEDBACK_LAGS − 1`` of the feedback test.
FEEDBACK_LAGS = 3
#: Refined-IV evaluations of the test's reference IV_E{ζ}=0 fit (its best iterate is used;
#: the test needs a consistent estimate, not the fixed point to the last digit).
REFERENCE_MAX_ITER = 20


@dataclass(frozen=True)
class ClosedLoopSignals:
    """The external signals of a closed-loop log, rows aligned with the regression data:
    ``reference`` (T, m) — the reference of each input's controlled state (0 for open-loop
    inputs) — ``dither`` (T, m) and the ``controller``."""

    reference: np.ndarray
    dither: np.ndarray
    controller: Any


def _log_order(log: Any, spec: ModelSpec) -> np.ndarray | None:
    parts = log._validate(spec)
    order = np.concatenate([pos for _, pos in parts])
    if order.size == len(log.data) and np.array_equal(order, np.arange(order.size)):
        return None
    return order


def closed_loop_signals(log: Any, spec: ModelSpec | None = None, *,
                        method: str = "cl-iv") -> ClosedLoopSignals:
    """Read the controller, reference and dither a closed-loop log names in its metadata.

    Raises
    ------
    IdentificationError
        One-line reasons: no ``metadata["closed_loop"]``, a missing reference column, a
        controller that cannot be simulated, non-finite external signals.
    """
    from vesselid.closedloop import PID, closed_loop_info
    from vesselid.logs import TrialLog

    if not isinstance(log, TrialLog):
        log = TrialLog(log)
    spec = spec or log.spec
    if spec is None:
        raise IdentificationError("no model spec given and the log carries none")
    info = closed_loop_info(log)
    if info is None:
        raise IdentificationError(
            f"method {method!r} needs a closed-loop log: metadata['closed_loop'] naming the "
            "controller and the reference/dither columns (vesselid.closedloop."
            "simulate_closed_loop or TrialRecorder.closed_loop write it); this log has none")
    ctrl = info.get("controller")
    if ctrl is None:
        raise IdentificationError(
            f"method {method!r} simulates the loop and needs the controller in "
            "metadata['closed_loop']['controller'] (a PID); the log does not describe it")
    try:
        pid = ctrl if isinstance(ctrl, PID) else PID.from_dict(ctrl)
        pid.arrays(spec)
    except ControlError as exc:
        raise IdentificationError(f"method {method!r}: {exc}") from None
    reference = dict(info.get("reference") or {})
    dither = dict(info.get("dither") or {})
    cols = set(log.data.columns)
    for state in dict.fromkeys(pid.loops.values()):
        col = reference.get(state)
        if col is None or col not in cols:
            what = "names no reference column" if col is None else f"names {col!r}, absent"
            raise IdentificationError(
                f"method {method!r} needs the reference of the controlled state {state!r}: "
                f"metadata['closed_loop']['reference'] {what} in the log")
    for inp, col in dither.items():
        if col not in cols:
            raise IdentificationError(
                f"method {method!r}: the dither column {col!r} of input {inp!r} is not in the "
                "log")
    order = _log_order(log, spec)

    def column(name: str) -> np.ndarray:
        x = log.data[name].to_numpy(float)
        x = x if order is None else x[order]
        if not np.all(np.isfinite(x)):
            raise IdentificationError(f"method {method!r}: column {name!r} holds NaN or inf")
        return x

    n_rows = len(log.data) if order is None else order.size
    ref = np.zeros((n_rows, spec.n_inputs))
    dith = np.zeros((n_rows, spec.n_inputs))
    for j, inp in enumerate(spec.inputs):
        if inp in pid.loops:
            ref[:, j] = column(reference[pid.loops[inp]])
        if inp in dither:
            dith[:, j] = column(dither[inp])
    return ClosedLoopSignals(reference=np.ascontiguousarray(ref),
                             dither=np.ascontiguousarray(dith), controller=pid)


def closed_loop_instruments(data: RegressionData, spec: ModelSpec, theta: np.ndarray,
                            signals: ClosedLoopSignals, limits: np.ndarray | None = None
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Instruments ``ζ(k) = φ(x̂(k−1), û(k−1))`` of the noise-free closed loop with
    parameters ``theta``, driven by the reference and dither (rows as
    :func:`~vesselid.identify.kernels.regressor_matrix`), and the per-segment status (0 ok,
    1 the simulated loop diverged)."""
    from vesselid.closedloop import closed_loop_states

    n_seg = data.n_segments
    xs = np.empty_like(data.target)
    us = np.empty_like(data.u)
    status = np.zeros(n_seg, dtype=np.int64)
    lim = (1e3 * np.maximum(data.target_abs_max, 1.0) if limits is None
           else np.asarray(limits, dtype=float))
    for s in range(n_seg):
        sl = data.segment(s)
        x, u, st = closed_loop_states(
            spec, signals.controller, signals.reference[sl], dither=signals.dither[sl],
            theta=theta, x0=data.target[sl.start], limit=lim[s], raise_on_divergence=False)
        xs[sl], us[sl] = x, u
        status[s] = st[0]
    z = kernels.regressor_matrix(np.nan_to_num(xs), np.nan_to_num(us), data.starts,
                                 spec.codes.factors)
    return z, status


class ClosedLoopIV(Estimator):
    """Closed-loop refined IV (module docstring): instruments from the reference and dither
    through the simulated closed loop, zero-mean per experiment, HAC intervals.

    Needs a log with ``metadata["closed_loop"]`` (controller, reference, dither).
    """

    name: ClassVar[str] = "cl-iv"
    label: ClassVar[str] = ("closed-loop refined IV (instruments: reference and dither "
                            "through the simulated closed loop)")
    short: ClassVar[str] = "CL-IV"
    plot_label: ClassVar[str] = "closed-loop IV"
    multi_experiment: ClassVar[tuple[str, ...]] = ("pooled", "stacked")
    open_loop: ClassVar[bool] = False

    def __init__(self) -> None:
        super().__init__()
        self._signals: ClosedLoopSignals | None = None

    def with_signals(self, signals: ClosedLoopSignals) -> ClosedLoopIV:
        """A copy bound to one log's external signals."""
        est = copy.copy(self)
        est._signals = signals
        return est

    def fit(self, log: Any, spec: ModelSpec | None = None, **options: Any):
        if self._signals is not None:
            return Estimator.fit(self, log, spec, **options)
        if options.get("instruments") is not None:
            raise IdentificationError("method 'cl-iv' builds its own instruments from the "
                                      "reference and dither")
        from vesselid.logs import TrialLog

        log = log if isinstance(log, TrialLog) else TrialLog(log)
        signals = closed_loop_signals(log, spec or log.spec)
        return Estimator.fit(self.with_signals(signals), log, spec, **options)

    def _require(self) -> ClosedLoopSignals:
        if self._signals is None:
            raise IdentificationError("method 'cl-iv' needs the log's closed-loop signals "
                                      "(call fit / identify with the log)")
        return self._signals

    def estimate_parameters(self, data: RegressionData, spec: ModelSpec, *,
                            combine: str = "pooled", theta_start: np.ndarray | None = None,
                            max_iter: int = 100, tol: float = 1e-9,
                            keep_history: bool = False) -> IterationResult:
        signals = self._require()
        if data.n_groups != 1:
            raise IdentificationError("method 'cl-iv' estimates one parameter group at a time")
        phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)

        def source(theta: np.ndarray, active: np.ndarray, out: Moments, limits) -> None:
            z, status = closed_loop_instruments(data, spec, np.nan_to_num(theta[0]), signals,
                                                limits)
            z = np.where(np.isfinite(z), z, 0.0)
            mom = moments_from_matrices(data, spec, z, phi)
            for name in ("zphi", "zy", "z", "phi", "y", "count"):
                getattr(out, name)[...] = getattr(mom, name)
            out.status[...] = np.where(status == 0, kernels.AUX_OK, kernels.AUX_OK + 1)

        opts = dict(zero_mean=True, combine=combine, max_iter=max_iter, tol=tol,
                    keep_history=keep_history, moment_source=source)
        theta_ls, _ = least_squares(data, spec, combine=combine)
        start = (theta_ls if theta_start is None else
                 np.array(np.broadcast_to(np.asarray(theta_start, float), theta_ls.shape)))
        res = refined_iv(data, spec, start, **opts)
        res.start = np.array(["given" if theta_start is not None else "ls"], dtype=object)
        if theta_start is None and res.reason[0] == STOP_START_DIVERGED:
            # the LS model's closed loop diverges: start from basic IV with delayed
            # measurements (no simulation)
            mom = compute_moments(data, spec, mode=kernels.MODE_LAGGED)
            theta_lag, ok_lag = solve_moments(mom, data, spec, zero_mean=True, combine=combine)
            if ok_lag[0]:
                res = refined_iv(data, spec, theta_lag, **opts)
                res.start = np.array(["lagged-iv"], dtype=object)
        return res

    def equation_designs(self, data, spec, it, phi, combine):
        z, _ = closed_loop_instruments(data, spec, it.theta_aux[0], self._require())
        z = np.where(np.isfinite(z), z, 0.0)
        return square_designs(data, spec, z, phi, it.theta[0], zero_mean=True,
                              combine=combine)

    def describe(self, it: IterationResult) -> dict[str, Any]:
        sig = self._signals
        return {"instruments": "simulated closed loop driven by the reference and dither, "
                               "zero-mean per experiment",
                "controller": None if sig is None else sig.controller.to_dict()}


# ------------------------------------------------------------------- feedback test
@dataclass(frozen=True)
class FeedbackTest:
    """Result of :func:`feedback_test`: Wald ``statistic``, degrees of freedom ``df``,
    ``pvalue``, ``lags``, and whether it ``rejects`` open loop at ``alpha``."""

    statistic: float
    df: int
    pvalue: float
    lags: int
    alpha: float

    @property
    def rejects(self) -> bool:
        return bool(self.pvalue < self.alpha)

    def to_dict(self) -> dict[str, Any]:
        return {"statistic": self.statistic, "df": self.df, "pvalue": self.pvalue,
                "lags": self.lags, "alpha": self.alpha, "rejects": self.rejects}


def _newey_west(s: np.ndarray, lags: int) -> np.ndarray:
    """Bartlett-kernel long-run covariance of the rows of ``s`` (already centred)."""
    n = s.shape[0]
    cov = s.T @ s / n
    for ell in range(1, lags + 1):
        g = s[ell:].T @ s[:-ell] / n
        cov += (1.0 - ell / (lags + 1.0)) * (g + g.T)
    return cov


def feedback_test_data(data: RegressionData, spec: ModelSpec, designs: list, *,
                       lags: int = FEEDBACK_LAGS, alpha: float = FEEDBACK_ALPHA
                       ) -> FeedbackTest:
    """The feedback test on the equation designs of an open-loop consistent fit (rows:
    every equation row of ``data``; ``designs[i].z``, ``.phi``, ``.resid``)."""
    from scipy.stats import chi2

    from vesselid.identify.gmm import hac_lags

    rows = np.flatnonzero(equation_rows(data))
    n_rows = rows.size
    seg_of_row = np.searchsorted(data.starts, rows, side="right") - 1
    u = data.u
    # centred inputs per experiment
    uc = u.copy()
    for s in range(data.n_segments):
        sl = data.segment(s)
        uc[sl] -= u[sl].mean(axis=0)
    scores = []
    keep = np.ones(n_rows, dtype=bool)
    for tau in range(lags):
        idx = rows + tau
        ok = idx < data.starts[seg_of_row + 1]
        keep &= ok
    for d in designs:
        if d.z.shape[0] != n_rows:
            raise IdentificationError("feedback test: the designs do not cover every equation "
                                      "row")
        a = d.z.T @ d.phi / n_rows
        try:
            a_inv = np.linalg.inv(a)
        except np.linalg.LinAlgError:
            a_inv = np.linalg.pinv(a)
        for tau in range(lags):
            idx = np.minimum(rows + tau, u.shape[0] - 1)
            ut = uc[idx]  # (n_rows, m)
            mmat = ut[keep].T @ d.phi[keep] / keep.sum()  # (m, P)
            adj = ut - d.z @ (mmat @ a_inv).T
            scores.append(adj * d.resid[:, None])
    s = np.concatenate(scores, axis=1)[keep]
    n_eff = s.shape[0]
    mean = s.mean(axis=0)
    cov = _newey_west(s - mean, hac_lags(n_eff))
    scale = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr = cov / np.outer(scale, scale)
    w, vecs = np.linalg.eigh(corr)
    good = w > 1e-10 * max(w.max(), 1e-300)
    t = vecs[:, good].T @ (mean / scale)
    stat = float(n_eff * np.sum(t**2 / w[good]))
    df = int(good.sum())
    return FeedbackTest(statistic=stat, df=df, pvalue=float(chi2.sf(stat, df)), lags=lags,
                        alpha=alpha)


def feedback_test(log: Any, spec: ModelSpec | None = None, *, lags: int = FEEDBACK_LAGS,
                  alpha: float = FEEDBACK_ALPHA) -> FeedbackTest:
    """Does the log look closed loop? (module docstring).

    Fits IV_E{ζ}=0 (consistent in open loop) and tests whether the inputs are correlated
    with its past equation errors. ``rejects`` is True when open loop is rejected at
    ``alpha``.
    """
    from vesselid.identify.data import from_log
    from vesselid.identify.methods import RefinedIV

    data, spec = from_log(log, spec, sensor_noise=False)
    est = RefinedIV(zero_mean=True)
    it = est.estimate_parameters(data, spec, max_iter=REFERENCE_MAX_ITER)
    if not np.all(np.isfinite(it.theta[0])):
        raise IdentificationError(f"feedback test: the reference fit failed ({it.reason[0]})")
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    designs = est.equation_designs(data, spec, it, phi, "pooled")
    return feedback_test_data(data, spec, designs, lags=lags, alpha=alpha)


def feedback_check(estimator: Estimator, log: Any, data: RegressionData, spec: ModelSpec,
                   it: IterationResult, designs: list, phi: np.ndarray
                   ) -> tuple[dict[str, Any], str | None]:
    """The closed-loop check of an open-loop estimator's fit: ``(diagnostics, warning)``.

    Declared closed loop (``metadata["closed_loop"]``) always warns; otherwise the feedback
    test runs on the fit's own designs when the estimator is IV_E{ζ}=0, else on a reference
    IV_E{ζ}=0 fit, and warns when it rejects.
    """
    from vesselid.closedloop import closed_loop_info
    from vesselid.identify.methods import RefinedIV

    declared = closed_loop_info(log) is not None
    out: dict[str, Any] = {"declared_closed_loop": declared}
    try:
        if isinstance(estimator, RefinedIV) and estimator.zero_mean and \
                it.reason[0] != "user-supplied instruments (no iteration)":
            ref_designs = designs
        else:
            ref = RefinedIV(zero_mean=True)
            it_ref = ref.estimate_parameters(data, spec, max_iter=REFERENCE_MAX_ITER)
            if not np.all(np.isfinite(it_ref.theta[0])):
                raise IdentificationError(str(it_ref.reason[0]))
            ref_designs = ref.equation_designs(data, spec, it_ref, phi, "pooled")
        test = feedback_test_data(data, spec, ref_designs)
        out.update(test.to_dict())
    except (IdentificationError, np.linalg.LinAlgError, ValueError) as exc:
        out["not_computed"] = str(exc)
        test = None
    msg = None
    if declared or (test is not None and test.rejects):
        why = ("the log's metadata says it was recorded in closed loop" if declared else
               f"the inputs are correlated with past output errors (feedback test p = "
               f"{test.pvalue:.2g})")
        msg = (f"{estimator.name}: {why}; open-loop estimators are biased under feedback — "
               "use method 'cl-iv' (needs the reference/dither columns and the controller in "
               "metadata['closed_loop'])")
    return out, msg


def closed_loop_route(log: Any, spec: ModelSpec | None) -> ClosedLoopSignals | None:
    """The external signals when ``log`` declares closed loop *and* names a simulable
    controller and its reference (``auto`` then uses ``cl-iv``), else None."""
    from vesselid.closedloop import closed_loop_info

    if closed_loop_info(log) is None:
        return None
    try:
        return closed_loop_signals(log, spec or getattr(log, "spec", None))
    except IdentificationError:
        return None

