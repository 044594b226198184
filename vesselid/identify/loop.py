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

import itertools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vesselid.errors import ControlError, IdentificationError
from vesselid.identify.backend import kernels
from vesselid.identify.covariance import column_means
from vesselid.identify.data import RegressionData, block_starts
from vesselid.identify.estimators import estimate
from vesselid.model.spec import ModelSpec

__all__ = ["ClosedLoopSignals", "ControllerFit", "FeedbackTest", "closed_loop_instruments",
           "closed_loop_note", "closed_loop_route", "closed_loop_signals",
           "estimate_controller", "feedback_check", "feedback_test", "feedback_test_data",
           "undeclared_closed_loop_route"]

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
    return _signal_arrays(log, spec, pid, reference, dither, method)


def _signal_arrays(log: Any, spec: ModelSpec, pid: Any, reference: Mapping[str, str],
                   dither: Mapping[str, str], method: str) -> ClosedLoopSignals:
    """The reference and dither columns named by ``reference`` (state -> column) and
    ``dither`` (input -> column), rows in the regression data's order."""
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
    """Bartlett-kernel long-run covariance of the rows of ``s`` (already centred); a long
    series by the block-wise Bartlett sums (the same quantity rounded differently)."""
    n = s.shape[0]
    if n > _large_rows() and lags > 0:
        from vesselid.identify.covariance import bartlett_long_run

        return bartlett_long_run(s, lags) / n
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
    from scipy.special import chdtrc  # = scipy.stats.chi2.sf; scipy.stats costs ~1 s to import

    from vesselid.identify.gmm import hac_lags

    scale = np.sqrt(np.mean(data.target**2, axis=0))
    tiny = [float(np.sqrt(np.mean(d.resid**2))) <= 1e-9 * max(float(scale[i]), 1e-300)
            for i, d in enumerate(designs)]
    if all(tiny):
        raise IdentificationError("the fit leaves only rounding-level residuals (noise-free "
                                  "data): no equation error to test")
    u = data.u
    # centred inputs per experiment
    uc = u.copy()
    for s in range(data.n_segments):
        sl = data.segment(s)
        uc[sl] -= column_means(u[sl])
    if data.n_segments == 1 and rows_of(data) > _large_rows():
        # a long one-experiment log: the rows and lags as slices (no index arrays)
        s = _one_experiment_scores(designs, uc, lags)
    else:
        s = _scores(data, designs, uc, lags)
    del uc
    n_eff = s.shape[0]
    mean = column_means(s)
    s -= mean  # centred in place (s is this function's own copy)
    cov = _newey_west(s, hac_lags(n_eff))
    scale = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr = cov / np.outer(scale, scale)
    w, vecs = np.linalg.eigh(corr)
    good = w > 1e-10 * max(w.max(), 1e-300)
    t = vecs[:, good].T @ (mean / scale)
    stat = float(n_eff * np.sum(t**2 / w[good]))
    df = int(good.sum())
    pvalue = float(chdtrc(df, stat)) if df > 0 else float("nan")
    return FeedbackTest(statistic=stat, df=df, pvalue=pvalue, lags=lags, alpha=alpha)


def _inverse_moments(d: Any, n_rows: int) -> np.ndarray:
    """``A⁻¹``, ``A = mean ζ(k) φ(k)ᵀ`` of one design (the pseudo-inverse where singular)."""
    if d.z.shape[0] != n_rows:
        raise IdentificationError("feedback test: the designs do not cover every equation "
                                  "row")
    a = d.z.T @ d.phi / n_rows
    try:
        return np.linalg.inv(a)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(a)


def _one_experiment_scores(designs: list, uc: np.ndarray, lags: int) -> np.ndarray:
    """The scores of :func:`_scores` on one experiment's rows ``1 … T−1`` (the designs'
    rows), each lag's written straight into its columns: the kept rows are the leading
    ``T − lags`` of every design, and row ``k`` of lag ``τ`` reads ``ũ(k + 1 + τ)``."""
    n_rows = uc.shape[0] - 1
    n_kept = n_rows - (lags - 1)
    m = uc.shape[1]
    s = np.empty((n_kept, len(designs) * lags * m))
    col = 0
    for d in designs:
        a_inv = _inverse_moments(d, n_rows)
        phi_kept, z_kept, e_kept = d.phi[:n_kept], d.z[:n_kept], d.resid[:n_kept, None]
        for tau in range(lags):
            u_tau = uc[1 + tau:1 + tau + n_kept]
            out = s[:, col:col + m]
            out[...] = u_tau
            out -= z_kept @ ((u_tau.T @ phi_kept / n_kept) @ a_inv).T
            out *= e_kept
            col += m
    return s


def _scores(data: RegressionData, designs: list, uc: np.ndarray, lags: int) -> np.ndarray:
    """The rows ``s(k)`` of the feedback test's moments, every design and lag in its
    columns, on the equation rows that have every lag inside their experiment."""
    rows = np.flatnonzero(_equation_rows(data))
    n_rows = rows.size
    seg_of_row = np.searchsorted(data.starts, rows, side="right") - 1
    u = uc
    keep = np.ones(n_rows, dtype=bool)
    for tau in range(lags):
        idx = rows + tau
        ok = idx < data.starts[seg_of_row + 1]
        keep &= ok
    # the scores of every design and lag, written into their columns of one array
    n_kept = int(keep.sum())
    s = np.empty((n_kept, len(designs) * lags * u.shape[1]))
    col = 0
    for d in designs:
        a_inv = _inverse_moments(d, n_rows)
        # the kept rows as views where they are the leading ones (one experiment)
        lead = bool(keep[:n_kept].all())
        kept = slice(0, n_kept) if lead else keep
        phi_kept = d.phi[:n_kept] if d.phi.flags.c_contiguous and lead else d.phi[keep]
        for tau in range(lags):
            idx = np.minimum(rows + tau, u.shape[0] - 1)
            mmat = uc[idx[kept]].T @ phi_kept / n_kept  # (m, P)
            adj = uc[idx]  # (n_rows, m), this lag's own copy: adjusted in place
            adj -= d.z @ (mmat @ a_inv).T
            adj *= d.resid[:, None]
            s[:, col:col + adj.shape[1]] = adj[kept]  # the kept rows only
            col += adj.shape[1]
            del adj, idx
        del phi_kept
    return s


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
    long = data.n_segments == 1 and spec.n_states == 1 and rows_of(data) > _large_rows()
    if data.n_groups == 1 and not long:  # computed (and kept) by the mean-current test
        from vesselid.identify.validity import reference_matrices

        phi, z, _ = reference_matrices(data, spec, it.theta_aux[0])
    else:  # (a long log: none kept; the instruments computed here into a buffer this
        # function owns, the regressors the fit's own rows where it kept them, read only)
        from vesselid.identify.eiv import uncorrected_regressor_matrix

        codes = spec.codes
        phi = uncorrected_regressor_matrix(data, spec)
        z, xhat = kernels.instrument_matrix(data.target, data.u, data.starts, it.theta_aux[0],
                                            codes.factors, codes.equation, spec.n_states)
        del xhat
    rows = _equation_rows(data)
    # centred per experiment: in its own buffer when computed here, else (the matrices
    # the mean-current test kept, read-only) in a copy
    zc = z if z.flags.writeable else z.copy()
    for s in range(data.n_segments):
        sl = slice(int(data.starts[s]) + 1, int(data.starts[s + 1]))
        zc[sl] -= column_means(zc[sl])
    if long:
        # a long one-experiment log: every row but the first, as views (no gathered copies)
        rows = slice(1, None)
    blocks = block_starts(spec)
    out = []
    for i in range(spec.n_states):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        out.append(_Design(z=zc[rows, sl], phi=phi[rows, sl],
                           resid=data.target[rows, i] - phi[rows, sl] @ theta[sl]))
    return out


def rows_of(data: RegressionData) -> int:
    """The number of rows of ``data`` (every experiment's samples)."""
    return int(data.starts[-1])


def _large_rows() -> int:
    from vesselid.identify.covariance import LARGE_ROWS

    return LARGE_ROWS


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


def closed_loop_note(feedback: Mapping[str, Any] | None) -> str | None:
    """The sentence that leads ``choice_reason`` when ``auto`` (or its fallback chain)
    returns an open-loop estimate of a log that declares closed loop or on which the
    feedback test rejects open loop (``feedback``: ``diagnostics["feedback"]``); None
    otherwise."""
    if not feedback or not (feedback.get("rejects") or feedback.get("declared_closed_loop")):
        return None
    if feedback.get("declared_closed_loop"):
        why = "the log declares closed loop but no simulable controller and reference"
    else:
        why = (f"the feedback test rejects open loop (p = {feedback['pvalue']:.2g}: the "
               "inputs react to past output errors), the log declares no loop and no PID "
               "law on a logged reference <state>_ref explains its inputs")
    return (f"CLOSED LOOP — {why}; this open-loop estimate is biased under feedback. Log "
            "the reference (<state>_ref) and declare the controller "
            "(metadata['closed_loop']) to identify with 'cl-iv'.")


def closed_loop_route(log: Any, spec: ModelSpec | None) -> ClosedLoopSignals | None:
    """The external signals when ``log`` declares closed loop *and* names a simulable
    controller and its reference (``auto`` then uses ``cl-iv``), else None."""
    if not _declares_closed_loop(log):
        return None
    try:
        return closed_loop_signals(log, spec or getattr(log, "spec", None))
    except IdentificationError:
        return None



# ------------------------------------------------- undeclared loops: the controller
#: Share of an input's variation (R², over its unsaturated rows) a PID law fitted to the
#: log must explain before ``auto`` treats the input as controlled by that law. The
#: instruments ``cl-iv`` simulates from the reference through *any* law stay independent
#: of the disturbances; the law decides only how strong they are, and an input that is
#: mostly its own external excitation is a better instrument as logged.
CONTROLLER_MIN_R2 = 0.5
#: An input that holds its extreme value exactly on at least this many rows is taken as
#: saturated there (a continuous signal does not repeat a value exactly).
SATURATION_ROWS = 2


@dataclass(frozen=True)
class ControllerFit:
    """A PID law recovered from a log that does not declare its controller
    (:func:`estimate_controller`): the ``controller``, the R² of each controlled input's
    law, the reference columns (state -> column) and the external-signal columns (input
    -> column: logged dithers, and the logged input itself for inputs no law explains —
    an open-loop input is external)."""

    controller: Any
    r2: dict[str, float]
    reference: dict[str, str]
    dither: dict[str, str]

    def sentence(self) -> str:
        loops = ", ".join(f"{j} -> {s} (R² {self.r2[j]:.3f})"
                          for j, s in self.controller.loops.items())
        return f"PID law fitted to the log: {loops}"

    def to_dict(self) -> dict[str, Any]:
        return {"controller": self.controller.to_dict(), "r2": dict(self.r2),
                "reference": dict(self.reference), "dither": dict(self.dither)}


def _pid_regressors(err: np.ndarray, u: np.ndarray, starts: np.ndarray, dt: float,
                    lo: float, hi: float) -> np.ndarray:
    """``[1, e(k), I(k), (e(k) − e(k−1))/dt]`` of :class:`~vesselid.plant.closedloop.PID` per
    experiment, with its conditional integration (``I`` integrates ``e`` only while the
    output is inside its limits)."""
    x = np.zeros((err.size, 4))
    x[:, 0] = 1.0
    x[:, 1] = err
    inside = (u > lo) & (u < hi)
    for a, b in itertools.pairwise(starts):
        e = err[a:b]
        inc = np.where(inside[a:b], dt * e, 0.0)
        x[a:b, 2] = np.concatenate([[0.0], np.cumsum(inc)[:-1]])
        x[a + 1:b, 3] = np.diff(e) / dt
    return x


def estimate_controller(log: Any, spec: ModelSpec, *, min_r2: float = CONTROLLER_MIN_R2
                        ) -> ControllerFit | None:
    """Recover a PID law from a log with reference columns but no declared controller.

    For every input ``j`` and every state ``s`` with a reference column ``<s>_ref``, the
    law ``u_j(k) − d_j(k) = u0 + Kp e(k) + Ki I(k) + Kd (e(k) − e(k−1))/dt`` (``e = r −
    y_s``, ``I`` the conditionally integrated error, ``d_j`` the logged dither
    ``<j>_dither`` or zero) is fitted by least squares over the rows where the input is
    not at a saturation limit (an extreme value it holds exactly on at least
    :data:`SATURATION_ROWS` rows). The regressors at row ``k`` depend on the
    measurements up to ``k`` and so on the dither only up to ``k − 1``: with a white
    dither the fit is consistent, with the dither logged it is exact. An input is
    controlled by the state whose law explains the most of its variation, provided
    R² ≥ ``min_r2``; the other inputs are taken as external signals. None when no
    reference column exists or no input meets ``min_r2``.
    """
    from vesselid.plant.closedloop import PID

    cols = set(log.data.columns)
    ref_cols = {s: f"{s}_ref" for s in spec.states if f"{s}_ref" in cols}
    if not ref_cols:
        return None
    dither_cols = {j: f"{j}_dither" for j in spec.inputs if f"{j}_dither" in cols}
    order = _log_order(log, spec)

    def column(name: str) -> np.ndarray:
        x = log.data[name].to_numpy(float)
        return x if order is None else x[order]

    if "experiment" in cols:
        exp = column("experiment")
        starts = np.concatenate([[0], np.flatnonzero(np.diff(exp) != 0) + 1, [exp.size]])
    else:
        starts = np.array([0, len(log.data)])
    dt = float(spec.dt or 1.0)
    loops, kp, ki, kd, offset, limits, r2 = {}, {}, {}, {}, {}, {}, {}
    for j in spec.inputs:
        u = column(j)
        target = u - (column(dither_cols[j]) if j in dither_cols else 0.0)
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(target))):
            continue
        lo, hi = -np.inf, np.inf
        for ext in (u.min(), u.max()):
            if np.count_nonzero(u == ext) >= SATURATION_ROWS and u.min() < u.max():
                lo, hi = (ext, hi) if ext == u.min() else (lo, ext)
        free = (u > lo) & (u < hi)
        best = None
        for s, col in ref_cols.items():
            r, y = column(col), column(s)
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(y))):
                continue
            x = _pid_regressors(r - y, u, starts, dt, lo, hi)[free]
            t = target[free]
            if t.size <= x.shape[1] or np.ptp(t) == 0:
                continue
            coef, *_ = np.linalg.lstsq(x, t, rcond=None)
            fit = 1.0 - float(np.sum((t - x @ coef) ** 2) / np.sum((t - t.mean()) ** 2))
            if best is None or fit > best[0]:
                best = (fit, s, coef)
        if best is not None and best[0] >= min_r2:
            fit, s, coef = best
            loops[j], r2[j] = s, fit
            offset[j], kp[j], ki[j], kd[j] = (float(c) for c in coef)
            if np.isfinite(lo) or np.isfinite(hi):
                limits[j] = (float(lo) if np.isfinite(lo) else -1e300,
                             float(hi) if np.isfinite(hi) else 1e300)
    if not loops:
        return None
    pid = PID(loops=loops, kp=kp, ki=ki, kd=kd, offset=offset, limits=limits, dt=dt)
    external = {j: dither_cols.get(j, j) if j in loops else j for j in spec.inputs}
    external = {j: c for j, c in external.items() if j not in loops or j in dither_cols}
    return ControllerFit(controller=pid, r2=r2,
                         reference={s: ref_cols[s] for s in dict.fromkeys(loops.values())},
                         dither=external)


def undeclared_closed_loop_route(log: Any, spec: ModelSpec | None
                                 ) -> tuple[ClosedLoopSignals, dict[str, Any]] | None:
    """``auto``'s route for a log that does not declare its loop but logs a reference:
    when the feedback test rejects open loop and a PID law explains the inputs
    (:func:`estimate_controller`), the external signals for ``cl-iv`` and what was
    found (feedback test, fitted controller); else None."""
    from vesselid.data.logs import TrialLog

    if _declares_closed_loop(log):
        return None
    log = log if isinstance(log, TrialLog) else TrialLog(log)
    spec = spec or log.spec
    if spec is None or not any(f"{s}_ref" in log.data.columns for s in spec.states):
        return None
    try:
        test = feedback_test(log, spec)
    except (IdentificationError, np.linalg.LinAlgError, ValueError):
        return None
    if not test.rejects:
        return None
    fit = estimate_controller(log, spec)
    if fit is None:
        return None
    try:
        signals = _signal_arrays(log, spec, fit.controller, fit.reference, fit.dither,
                                 "cl-iv")
    except IdentificationError:
        return None
    return signals, {"feedback": test.to_dict(), **fit.to_dict(),
                     "sentence": fit.sentence()}
