"""Diagnostics that name causes: parameter stability and a current's mean.

Both tests run on the fit path of ``auto`` (one log) and are reported with the result
(``diagnostics["parameter_stability"]``, ``diagnostics["mean_current"]``).

* :func:`parameter_stability` — a split-sample (Chow-type) test: the IV_{E{ζ}=0}
  estimate (4) of the first and of the second half of every experiment, and the Wald
  statistic of their difference with the two halves' HAC covariances,
  ``W = dᵀ (V₁ + V₂)⁻¹ d ~ χ²(P)`` under constant parameters. A drifting parameter makes
  the equation error remember its past like a coloured disturbance does; ``auto``'s
  colour test then rejects, and the choice sentence must not blame colour.
* :func:`mean_current` — a current with mean ``v̄`` inside the modulus and no
  disturbance sensor. Expanding the modulus about the measured state,
  ``(w − v̄)|w − v̄| = w|w| − 2 v̄ |w| + v̄² sign(w)`` (``|w| ≥ |v̄|``), so the equation
  error carries ``−2 n v̄ |w|``: the data identify the coefficient ``b = −2 n v̄`` of
  ``|w|`` (hence ``v̄ = −b / (2n)``), and the offset becomes ``μ_w − a v̄ − …`` — the
  process-noise mean and the current's mean can no longer be read from it alone. The
  test adds ``|w|`` to the equation with the simulated ``|x̂|`` as its instrument (the
  other instruments simulated as usual; everything centred per experiment) and tests
  ``b = 0`` with a Bartlett HAC covariance. Where the motion keeps one sign ``|w| = ±w``
  and only ``a ∓ 2 n v̄`` is identified; the test then has no power and says so through
  its wide interval.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from vesselid.identify import covariance as _covariance
from vesselid.identify.backend import kernels
from vesselid.identify.covariance import bartlett_long_run, column_means
from vesselid.identify.data import RegressionData
from vesselid.identify.gmm import hac_lags
from vesselid.model.spec import ModelSpec

__all__ = ["MEAN_CURRENT_ALPHA", "STABILITY_ALPHA", "mean_current", "parameter_stability"]

#: Level of the split-sample stability test.
STABILITY_ALPHA = 0.01
#: Level of the mean-current (``|w|`` term) test.
MEAN_CURRENT_ALPHA = 0.01
#: Fewest samples per half-experiment for the stability test.
MIN_HALF = 100


def _solve_iv(z: np.ndarray, phi: np.ndarray, y: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """``θ = (ZᵀΦ)⁻¹ Zᵀy`` and ``(ZᵀΦ)⁻¹``; None when singular."""
    a = z.T @ phi
    try:
        return np.linalg.solve(a, z.T @ y), np.linalg.inv(a)
    except np.linalg.LinAlgError:
        return None


def _hac_iv(z: np.ndarray, phi: np.ndarray, y: np.ndarray, seg: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray] | None:
    """Just-identified IV ``θ = (ZᵀΦ)⁻¹ Zᵀy`` on centred rows and its Bartlett HAC
    sandwich covariance (lags not across segments ``seg``)."""
    solved = _solve_iv(z, phi, y)
    if solved is None:
        return None
    theta, a_inv = solved
    resid = y - phi @ theta
    m = np.empty_like(z, dtype=float)
    for j in range(z.shape[1]):  # z * resid[:, None], column by column (the same products)
        np.multiply(z[:, j], resid, out=m[:, j])
    s = m.T @ m
    bw = hac_lags(m.shape[0])
    one = seg.size == 0 or seg[0] == seg[-1]  # one segment (sorted): every pair counts
    if one and m.shape[0] > _covariance.LARGE_ROWS:  # a long log: the same sum in blocks
        s = bartlett_long_run(m, bw)
        return theta, a_inv @ s @ a_inv.T
    for lag in range(1, bw + 1):
        if one:
            c = m[lag:].T @ m[:-lag]
        else:
            same = (seg[lag:] == seg[:-lag]).astype(float)[:, None]
            c = (m[lag:] * same).T @ m[:-lag]
        s += (1.0 - lag / (bw + 1.0)) * (c + c.T)
    return theta, a_inv @ s @ a_inv.T


def _with_column(arr: np.ndarray) -> np.ndarray:
    """A new C-ordered ``(T, K + 1)`` float array: ``arr`` (T, K) and a last column of NaN
    (what ``np.column_stack`` of ``arr`` and a NaN column gives)."""
    out = np.empty((arr.shape[0], arr.shape[1] + 1))
    out[:, :-1] = arr
    out[:, -1] = np.nan
    return out


def _centre_columns(rows: np.ndarray) -> None:
    """``rows -= column_means(rows)`` in place, one column at a time: the same
    subtractions, without numpy's row-by-row broadcast over a few columns."""
    mean = column_means(rows).tolist()
    for j, mu in enumerate(mean):
        col = rows[:, j]
        col -= mu


_SHARED = "_validity_matrices"


def reference_matrices(data: RegressionData, spec: ModelSpec, theta_aux: np.ndarray, *,
                       keep: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The regressor matrix and the instruments (with the simulated states) simulated from
    ``theta_aux`` on every row of a one-group ``data``: ``(phi, z, xhat)``, read-only.

    ``keep``: remember them on ``data`` for the next call with the same ``spec`` and
    ``theta_aux``, which takes them (the mean-current test computes them, the feedback
    test's reference designs, :func:`vesselid.identify.loop.reference_designs`, reuse
    them: the same kernels on the same arrays, computed once)."""
    theta_aux = np.ascontiguousarray(theta_aux, dtype=float)
    key = (id(spec), theta_aux.tobytes())
    memo = getattr(data, "__dict__", {}).pop(_SHARED, None)
    if memo is not None and memo[0] == key:
        return memo[1]
    codes = spec.codes
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, codes.factors)
    z, xhat = kernels.instrument_matrix(data.target, data.u, data.starts, theta_aux,
                                        codes.factors, codes.equation, spec.n_states)
    for arr in (phi, z, xhat):
        arr.flags.writeable = False
    if keep and hasattr(data, "__dict__"):
        data.__dict__[_SHARED] = (key, (phi, z, xhat))
    return phi, z, xhat


def _rows(data: RegressionData, spec: ModelSpec, theta_aux: np.ndarray, extra: bool):
    """Centred regressors, instruments and targets of group 0 (one state), with the
    ``|w|`` column and its simulated instrument appended when ``extra`` (on a one-group
    ``data``: its matrices then kept for the feedback test, :func:`reference_matrices`)."""
    codes = spec.codes
    sl, starts = data.group_rows(0)
    if extra and data.n_groups == 1:  # new arrays below: the kept ones stay unchanged
        # (a long log keeps none: held to the feedback test, they would raise the peak
        # memory of every step in between; the feedback test computes them again)
        long = data.target.shape[0] > _covariance.LARGE_ROWS
        phi, z, xhat = reference_matrices(data, spec, theta_aux, keep=not long)
    else:
        phi = kernels.regressor_matrix(data.regsig[sl], data.u[sl], starts, codes.factors)
        z, xhat = kernels.instrument_matrix(data.target[sl], data.u[sl], starts, theta_aux,
                                            codes.factors, codes.equation, spec.n_states)
    y = data.target[sl, 0].astype(float)
    if extra:  # [phi, |w(k-1)|] and [z, |x̂(k-1)|] (NaN in each experiment's first row)
        phi, z = _with_column(phi), _with_column(z)
        for s in range(starts.size - 1):
            a, b = int(starts[s]), int(starts[s + 1])
            np.abs(data.regsig[sl][a:b - 1, 0], out=phi[a + 1:b, -1])
            np.abs(xhat[a:b - 1, 0], out=z[a + 1:b, -1])
    keep = np.ones(y.size, dtype=bool)
    for arr in (phi, z):  # column by column: the same mask as a row-wise all()
        for j in range(arr.shape[1]):
            keep &= np.isfinite(arr[:, j])
    seg = np.repeat(np.arange(starts.size - 1), np.diff(starts))
    for s in range(starts.size - 1):  # a constant per experiment: centre
        a = int(starts[s])
        kept = np.flatnonzero(keep[a:int(starts[s + 1])])
        if kept.size and kept[-1] - kept[0] + 1 == kept.size:  # one run of rows: in place
            r = slice(a + int(kept[0]), a + int(kept[-1]) + 1)
            for arr in (phi, z):
                _centre_columns(arr[r])
            rows = y[r]
            rows -= rows.mean(axis=0)
            continue
        r = keep & (seg == s)
        for arr in (phi, z):
            arr[r] -= column_means(arr[r])
        y[r] -= y[r].mean()
    kept = np.flatnonzero(keep)
    if kept.size and kept[-1] - kept[0] + 1 == kept.size:  # one run of rows: views
        r = slice(int(kept[0]), int(kept[-1]) + 1)
        return phi[r], z[r], y[r], seg[r]
    return phi[keep], z[keep], y[keep], seg[keep]


def _one_long_experiment(data: RegressionData) -> bool:
    """Whether ``data`` is one group of one experiment longer than
    :data:`~vesselid.identify.covariance.LARGE_ROWS` rows (the bounded-memory forms of
    the mean-current test)."""
    return (data.n_groups == 1 and data.starts.size == 2
            and int(data.starts[-1]) > _covariance.LARGE_ROWS)


def _long_rows(data: RegressionData, spec: ModelSpec, theta_aux: np.ndarray,
               extra: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_rows` with ``extra`` of one long experiment (:func:`_one_long_experiment`):
    the same numbers, each matrix formed once in its final ``(T, P + 1)`` buffer (the
    ``|w|`` column and its instrument written in place; nothing kept for the feedback
    test). ``seg`` is empty: every row belongs to the one experiment."""
    codes = spec.codes
    n = int(data.starts[-1])

    def widened(x: np.ndarray, last: np.ndarray) -> np.ndarray:
        out = np.empty((n, x.shape[1] + 1))
        out[:, :-1] = x
        out[0, -1] = np.nan
        np.abs(last[:-1], out=out[1:, -1])
        return out

    # the instruments first (their simulation's states freed once read), then the
    # regressors (the fit's own rows where it kept them: copied, not formed again)
    z, xhat = kernels.instrument_matrix(data.target, data.u, data.starts, theta_aux,
                                        codes.factors, codes.equation, spec.n_states)
    z = widened(z, xhat[:, 0])
    del xhat
    from vesselid.identify.eiv import uncorrected_regressor_matrix

    phi = widened(uncorrected_regressor_matrix(data, spec), data.regsig[:, 0])
    y = data.target[:, 0].astype(float)
    keep = np.ones(n, dtype=bool)
    for arr in (phi, z):  # column by column: the same mask as a row-wise all()
        for j in range(arr.shape[1]):
            keep &= np.isfinite(arr[:, j])
    seg = np.zeros(0, dtype=np.int64)
    kept = np.flatnonzero(keep)
    if kept.size and kept[-1] - kept[0] + 1 == kept.size:  # one run of rows: in place
        r = slice(int(kept[0]), int(kept[-1]) + 1)
        for arr in (phi, z):
            rows = arr[r]
            rows -= column_means(rows)
        rows = y[r]
        rows -= rows.mean(axis=0)
        return phi[r], z[r], y[r], seg
    for arr in (phi, z):
        arr[keep] -= column_means(arr[keep])
    y[keep] -= y[keep].mean()
    return phi[keep], z[keep], y[keep], seg


def _hac_iv_blocks(z: np.ndarray, phi: np.ndarray, y: np.ndarray, seg: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`_hac_iv` of one experiment with its scores ``z (y − Φθ)`` formed one block
    of :data:`~vesselid.identify.covariance.BLOCK_ROWS` rows at a time (the Bartlett sums
    of :func:`~vesselid.identify.covariance.bartlett_block_sums`): the same quantity
    rounded differently, memory ``O(BLOCK_ROWS)`` beyond the rows."""
    solved = _solve_iv(z, phi, y)
    if solved is None:
        return None
    theta, a_inv = solved
    n, q = z.shape
    rows = int(_covariance.BLOCK_ROWS)

    def block(i: int, j: int) -> np.ndarray:
        return z[i:j] * (y[i:j] - phi[i:j] @ theta)[:, None]

    bw = hac_lags(n)
    total, s = np.zeros(q), np.zeros((q, q))
    for i in range(0, n, rows):
        m = block(i, min(i + rows, n))
        total += m.sum(axis=0)
        if bw == 0:
            s += m.T @ m
    if bw > 0:
        s = _covariance.bartlett_block_sums(block, n, q, total / n, bw, rows)
    return theta, a_inv @ s @ a_inv.T


def _chi2_sf(x: float, df: int) -> float:
    from vesselid.identify._special import chi2_sf

    return float(chi2_sf(np.array([max(x, 0.0)]), df)[0])


def mean_current(data: RegressionData, spec: ModelSpec, theta_aux: np.ndarray,
                 alpha: float = MEAN_CURRENT_ALPHA) -> dict[str, Any] | None:
    """Test for a current with non-zero mean inside the modulus (module docstring).

    ``theta_aux``: the consistent estimate the instruments are simulated from (P,).
    ``None`` where the test does not apply: several states, a disturbance sensor (its
    mean is then measured), or no ``w*|w|`` term of the state.
    """
    if spec.n_states != 1 or spec.aggregate or data.n_groups != 1:
        return None
    state = spec.states[0]
    names = [str(t) for t in spec.equations[state]]
    key = f"{state}*|{state}|"
    if key not in names or state not in names:
        return None
    long = _one_long_experiment(data)  # (bounded memory: _long_rows, _hac_iv_blocks)
    phi, z, y, seg = (_long_rows if long else _rows)(data, spec,
                                                     np.asarray(theta_aux, dtype=float),
                                                     extra=True)
    if y.size < 4 * phi.shape[1]:
        return None
    fit = (_hac_iv_blocks if long else _hac_iv)(z, phi, y, seg)
    if fit is None:
        return None
    theta, cov = fit
    p = phi.shape[1] - 1
    i_n = names.index(key)
    b, se_b = float(theta[p]), float(math.sqrt(max(cov[p, p], 0.0)))
    n_hat = float(theta[i_n])
    if not (np.isfinite(b) and se_b > 0 and n_hat != 0):
        return None
    zstat = b / se_b
    pval = math.erfc(abs(zstat) / math.sqrt(2.0))
    vbar = -b / (2.0 * n_hat)
    grad = np.zeros(p + 1)  # delta method for v̄ = −b / (2n)
    grad[p] = -1.0 / (2.0 * n_hat)
    grad[i_n] = b / (2.0 * n_hat ** 2)
    se_v = float(math.sqrt(max(grad @ cov @ grad, 0.0)))
    warned = pval < alpha
    sentence = (
        f"the equation error carries a |{state}| term (coefficient {b:.3g} ± {se_b:.2g}, "
        f"p = {pval:.2g}): a current with non-zero mean acts inside the modulus and no "
        f"sensor measures it; the data identify that coefficient, −2·n·v̄, so the "
        f"current's mean is v̄ = {vbar:.3g} ± {se_v:.2g} (95 % interval "
        f"{vbar - 1.96 * se_v:.3g} … {vbar + 1.96 * se_v:.3g}), and the offset then mixes "
        f"the process-noise mean with −a·v̄: read neither from it alone"
        if warned else
        f"no sign of a current with non-zero mean inside the modulus (|{state}| term "
        f"{b:.3g} ± {se_b:.2g}, p = {pval:.2g})")
    return {"statistic": zstat, "pvalue": pval, "level": alpha, "warned": bool(warned),
            "abs_coefficient": b, "abs_coefficient_se": se_b,
            "identified": f"coefficient of |{state}| = -2*n*v_mean",
            "estimate": vbar, "std_error": se_v, "sentence": sentence}


def _halves(data: RegressionData) -> RegressionData | None:
    """Group 0's rows rearranged as two groups: the first half of every experiment,
    then the second half."""
    sl, starts = data.group_rows(0)
    firsts, seconds = [], []
    for s in range(starts.size - 1):
        a, b = sl.start + int(starts[s]), sl.start + int(starts[s + 1])
        mid = (a + b) // 2
        if mid - a < MIN_HALF or b - mid < MIN_HALF:
            return None
        firsts.append(slice(a, mid))
        seconds.append(slice(mid, b))
    pieces = firsts + seconds
    lengths = [p.stop - p.start for p in pieces]

    def take(arr):
        if arr is None:
            return None
        if len(firsts) == 1 and sl == slice(0, arr.shape[0]):
            return arr  # one experiment: its halves in order are its rows (no copy)
        return np.ascontiguousarray(np.concatenate([arr[p] for p in pieces]))

    n_exp = len(firsts)
    return replace(data, target=take(data.target), regsig=take(data.regsig),
                   u=take(data.u), sensor=take(data.sensor),
                   starts=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
                   group=np.repeat([0, 1], n_exp).astype(np.int64), n_groups=2,
                   experiment_ids=tuple(range(2 * n_exp)))


def parameter_stability(data: RegressionData, spec: ModelSpec,
                        alpha: float = STABILITY_ALPHA,
                        theta_start: np.ndarray | None = None) -> dict[str, Any] | None:
    """Split-sample (Chow-type) test of constant parameters (module docstring).

    One state equation. ``None`` where the test does not apply: several states, an
    experiment too short to halve (:data:`MIN_HALF` samples a half), an estimate that is
    not finite. ``theta_start``: the whole log's estimate, a start of both halves'
    refined iterations that saves most of their steps.
    """
    from vesselid.identify.estimators import estimate, refined_iv

    if data.n_groups != 1 or spec.n_states != 1:
        return None
    halves = _halves(data)
    if halves is None:
        return None
    if theta_start is None:
        it = estimate(halves, spec, "iv-zero-mean", combine="pooled")
        theta, theta_aux = it.theta, it.theta_aux
        subs = [_group(halves, g) for g in (0, 1)]
    else:  # what ``estimate`` runs from a given start, without its unused LS estimate
        # each half on its own: the groups' iterations are independent (per-group steps,
        # residuals and stopping), and one group's takes the scalar path of the refined
        # iteration instead of masked two-group arrays at every step (the same numbers;
        # a half that stops early does not carry the other's)
        start = np.asarray(theta_start, dtype=float).reshape(1, spec.n_params)
        subs = [_group(halves, g) for g in (0, 1)]
        its = [refined_iv(sub, spec, start.copy(), zero_mean=True, combine="pooled")
               for sub in subs]
        theta = np.vstack([i.theta for i in its])
        theta_aux = np.vstack([i.theta_aux for i in its])
    if not np.all(np.isfinite(theta)):
        return None
    n_par = spec.n_params
    covs = []
    for g in (0, 1):
        phi, z, y, seg = _rows(subs[g], spec, theta_aux[g], extra=False)
        fit = _hac_iv(z, phi, y, seg)
        if fit is None:
            return None
        covs.append(fit[1])
    d = theta[1] - theta[0]
    v = covs[0] + covs[1]
    try:
        stat = float(d @ np.linalg.solve(v, d))
    except np.linalg.LinAlgError:
        return None
    pval = _chi2_sf(stat, n_par)
    se = np.sqrt(np.clip(np.diag(v), 0, None))
    zs = d / np.where(se > 0, se, np.nan)
    names = [f"{e}: {t}" for e, t in spec.param_index]
    worst = int(np.nanargmax(np.abs(zs)))
    rejected = pval < alpha
    sentence = (
        f"the parameters differ between the first and second half of the log (split-"
        f"sample Wald {stat:.3g}, {n_par} df, p = {pval:.2g}; largest change "
        f"{names[worst]} {d[worst]:+.3g}, {zs[worst]:+.2g} SE): the model drifts, and a "
        f"drifting parameter also makes the equation error look coloured"
        if rejected else
        f"no sign of drifting parameters (split-sample Wald {stat:.3g}, {n_par} df, "
        f"p = {pval:.2g})")
    return {"statistic": stat, "df": n_par, "pvalue": pval, "level": alpha,
            "rejected": bool(rejected),
            "first_half": dict(zip(names, map(float, theta[0]), strict=True)),
            "second_half": dict(zip(names, map(float, theta[1]), strict=True)),
            "sentence": sentence}


def _group(data: RegressionData, g: int) -> RegressionData:
    sl, starts = data.group_rows(g)
    segs = np.flatnonzero(data.group == g)

    def cut(arr):
        return None if arr is None else arr[sl]

    return replace(data, target=cut(data.target), regsig=cut(data.regsig), u=cut(data.u),
                   sensor=cut(data.sensor), starts=starts.astype(np.int64),
                   group=np.zeros(segs.size, dtype=np.int64), n_groups=1,
                   experiment_ids=tuple(range(segs.size)))
