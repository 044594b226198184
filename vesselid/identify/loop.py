"""Closed-loop logs' external signals and the feedback test (no estimator classes).

* :func:`closed_loop_signals` reads the controller, reference and dither a closed-loop log
  names in ``metadata["closed_loop"]``; :func:`closed_loop_instruments` simulates the
  noise-free closed loop from them (the instruments of ``cl-iv``,
  :mod:`vesselid.identify.closedloop`).
* :func:`feedback_test` asks whether the input is correlated with past output errors: in
  open loop (A4) ``u(k+τ)`` is independent of the equation error ``ε(k)`` for ``τ ≥ 0``; a
  controller makes ``u(k)`` react to ``e(k)``. The statistic is the Wald test of the
  moments ``E{ũ_j(k+τ) ε_i(k)} = 0`` (``ũ`` centred per experiment; ``τ = 0 … lags−1``;
  every input ``j`` and state equation ``i``) on the residuals of the open-loop consistent
  IV_E{ζ}=0 fit, with the estimation effect removed from the score (the residuals are
  estimated: ``s(k) = (ũ(k+τ) − M A⁻¹ ζ(k)) ε̂(k)``, ``M = mean ũ(k+τ) φ(k)ᵀ``,
  ``A = mean ζ(k) φ(k)ᵀ``) and a Newey–West long-run covariance: χ² with
  ``n · m · lags`` degrees of freedom under open loop.
* :func:`feedback_check` is what ``Estimator.fit`` runs for every open-loop estimator.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vesselid.errors import ControlError, IdentificationError
from vesselid.identify.backend import kernels
from vesselid.identify.data import RegressionData, block_starts
from vesselid.identify.estimators import estimate
from vesselid.model.spec import ModelSpec

__all__ = ["ClosedLoopSignals", "FeedbackTest", "closed_loop_instruments",
           "closed_loop_route", "closed_loop_signals", "feedback_check", "feedback_test",
           "feedback_test_data"]

#: Significance level of the open-loop warning.
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
    from vesselid.data.logs import TrialLog
    from vesselid.plant.closedloop import PID, closed_loop_info

    if not isinstance(log, TrialLog):
        log = TrialLog(log)
    spec = spec or log.spec
    if spec is None:
        raise IdentificationError("no model spec given and the log carries none")
    info = closed_loop_info(log)
    if info is None:
        raise IdentificationError(
            f"method {method!r} needs a closed-loop log: metadata['closed_loop'] naming the "
            "controller and the reference/dither columns (vesselid.plant.closedloop."
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
    from vesselid.plant.closedloop import closed_loop_states

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

    scale = np.sqrt(np.mean(data.target**2, axis=0))
    tiny = [float(np.sqrt(np.mean(d.resid**2))) <= 1e-9 * max(float(scale[i]), 1e-300)
            for i, d in enumerate(designs)]
    if all(tiny):
        raise IdentificationError("the fit leaves only rounding-level residuals (noise-free "
                                  "data): no equation error to test")
    rows = np.flatnonzero(_equation_rows(data))
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


@dataclass
class _Design:
    z: np.ndarray
    phi: np.ndarray
    resid: np.ndarray


def _equation_rows(data: RegressionData) -> np.ndarray:
    rows = np.ones(int(data.starts[-1]), dtype=bool)
    rows[data.starts[:-1]] = False
    return rows


def reference_designs(data: RegressionData, spec: ModelSpec, it: Any = None) -> list[_Design]:
    """Instruments (centred per experiment), regressors and residuals of the open-loop
    IV_E{ζ}=0 fit (the paper's simulated instruments), per state equation; ``it`` an
    IV_E{ζ}=0 result of ``data`` already at hand (the first step of ``auto``, GMM, SRIV
    and PEM), else it is estimated."""
    if it is None or not np.all(np.isfinite(it.theta[0])):
        it = estimate(data, spec, "iv-zero-mean", max_iter=REFERENCE_MAX_ITER)
    theta = it.theta[0]
    if not np.all(np.isfinite(theta)):
        raise IdentificationError(f"the reference IV fit failed ({it.reason[0]})")
    codes = spec.codes
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, codes.factors)
    z, _ = kernels.instrument_matrix(data.target, data.u, data.starts, it.theta_aux[0],
                                     codes.factors, codes.equation, spec.n_states)
    rows = _equation_rows(data)
    zc = z.copy()
    for s in range(data.n_segments):
        sl = slice(int(data.starts[s]) + 1, int(data.starts[s + 1]))
        zc[sl] -= zc[sl].mean(axis=0)
    blocks = block_starts(spec)
    out = []
    for i in range(spec.n_states):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        out.append(_Design(z=zc[rows, sl], phi=phi[rows, sl],
                           resid=data.target[rows, i] - phi[rows, sl] @ theta[sl]))
    return out


def feedback_test(log: Any, spec: ModelSpec | None = None, *, lags: int = FEEDBACK_LAGS,
                  alpha: float = FEEDBACK_ALPHA) -> FeedbackTest:
    """Does the log look closed loop? (module docstring).

    Fits IV_E{ζ}=0 (consistent in open loop) and tests whether the inputs are correlated
    with its past equation errors. ``rejects`` is True when open loop is rejected at
    ``alpha``.
    """
    from vesselid.identify.data import from_log

    data, spec = from_log(log, spec, sensor_noise=False)
    return feedback_test_data(data, spec, reference_designs(data, spec), lags=lags,
                              alpha=alpha)


def _declares_closed_loop(log: Any) -> bool:
    """Whether the log's metadata names a closed loop (read without importing the
    compiled closed-loop simulation, :func:`vesselid.plant.closedloop.closed_loop_info`)."""
    meta = getattr(log, "metadata", None) or {}
    return isinstance(meta.get("closed_loop"), Mapping)


def feedback_check(name: str, log: Any, data: RegressionData, spec: ModelSpec,
                   designs: list | None = None, reference: Any = None
                   ) -> tuple[dict[str, Any], str | None]:
    """The closed-loop check of an open-loop estimator's fit: ``(diagnostics, warning)``.

    Declared closed loop (``metadata["closed_loop"]``) always warns; otherwise the feedback
    test runs on ``designs`` (the fit's own, when it is IV_E{ζ}=0) or on the IV_E{ζ}=0
    fit ``reference`` (an IterationResult of ``data``; estimated when None), and warns
    when it rejects.
    """
    declared = _declares_closed_loop(log)
    out: dict[str, Any] = {"declared_closed_loop": declared}
    test = None
    try:
        test = feedback_test_data(data, spec, designs if designs is not None
                                  else reference_designs(data, spec, reference))
        out.update(test.to_dict())
    except (IdentificationError, np.linalg.LinAlgError, ValueError) as exc:
        out["not_computed"] = str(exc)
    msg = None
    if declared or (test is not None and test.rejects):
        why = ("the log's metadata says it was recorded in closed loop" if declared else
               f"the inputs are correlated with past output errors (feedback test p = "
               f"{test.pvalue:.2g})")
        msg = (f"{name}: {why}; open-loop estimators are biased under feedback — use "
               "method 'cl-iv' (needs the reference/dither columns and the controller in "
               "metadata['closed_loop'])")
    return out, msg


def closed_loop_route(log: Any, spec: ModelSpec | None) -> ClosedLoopSignals | None:
    """The external signals when ``log`` declares closed loop *and* names a simulable
    controller and its reference (``auto`` then uses ``cl-iv``), else None."""
    if not _declares_closed_loop(log):
        return None
    try:
        return closed_loop_signals(log, spec or getattr(log, "spec", None))
    except IdentificationError:
        return None

