"""Explicit-matrix IV/GMM, batched over parameter groups: instrument sets, noise-model
prefiltering, two-step GMM with a HAC weight, Hansen's J.

The paper's estimators (:mod:`vesselid.identify.estimators`) accumulate moments in
one fused kernel pass. The estimators here need the instrument and regressor
*rows* (to prefilter them with a noise model, to form a HAC weight, to stack
several instrument sets), so they build them explicitly, still for all groups
(Monte Carlo runs) at once and with compiled per-experiment helpers
(:mod:`vesselid.identify._ivkernels`).

Instrument sets (per state equation ``i`` with regressors ``φ_i``):

* ``simulated`` — ``ζ(k) = Φ([x̂(k−1); u(k−1)])`` from the auxiliary model (§6).
  Functions of the input only: valid whatever the colour of the disturbances.
* ``lagged`` — the measured regressors delayed one and two samples (state taken at
  ``k−2`` and ``k−3``) for every term that involves a state, plus the input-only
  terms themselves (exogenous). Efficient when every disturbance is white, badly
  biased when one is coloured (the delayed state then correlates with the equation
  error).
* ``combined`` — both (over-identified).

Every set is used with per-experiment constants (zero-mean instruments, A7): all
rows are centred per experiment, which is algebraically 2SLS/GMM with an
experiment-specific constant among the regressors and the instruments.

Estimation per group and equation: ``A = Σ z φᵀ``, ``b = Σ z y``; 2SLS
``θ₁ = (AᵀM⁻¹A)⁻¹AᵀM⁻¹b`` with ``M = Σ z zᵀ``; two-step GMM ``θ₂`` with ``W = Ŝ⁻¹``,
``Ŝ`` the Bartlett (Newey–West) long-run variance of ``z ε(θ₁)`` summed over
experiments (never across a boundary). Hansen's ``J = ḡᵀŜ⁻¹ḡ`` with
``ḡ = Σ z ε(θ₂)`` is χ²(K − P) under valid instruments; the difference-in-J (C)
statistic of a subset is ``J(all) − J(without the subset)``.

The weight ``Ŝ(θ₁)⁻¹`` is itself estimated, which makes the textbook two-step
covariance optimistic in finite samples; on request (the checked ``fit`` path) the
derivative ``D = ∂θ₂/∂θ₁`` through the weight (:func:`weight_jacobian`,
:func:`hac_sums_derivative`: same kernel, bandwidth, per-experiment lags and
centring) is kept for Windmeijer's (2005) corrected covariance
(:meth:`vesselid.identify.covariance.CovarianceEstimator.estimate`).
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from vesselid.identify import covariance as _covariance
from vesselid.identify import linalg
from vesselid.identify._fastkernels import specialised_combined
from vesselid.identify.backend import ivk, kernels, numpy_active
from vesselid.identify.covariance import moving_sums
from vesselid.identify.data import RegressionData, block_starts
from vesselid.model.spec import ModelSpec

__all__ = [
    "COLOUR_WINDOW",
    "INSTRUMENT_SETS",
    "WHITENED_COLOUR_ORDER",
    "WHITENED_COLOUR_SPAN",
    "GMMSolution",
    "ar_coefficients",
    "colour_test",
    "combined_solution",
    "hac_lags",
    "hac_sums",
    "hac_sums_derivative",
    "instrument_blocks",
    "lagged_regressors",
    "noise_instruments",
    "noise_model",
    "simulated_instruments",
    "solve_equations",
    "state_terms",
    "weight_jacobian",
    "whitened_colour_window",
    "yule_walker",
]

INSTRUMENT_SETS = ("simulated", "lagged", "combined")

#: Delays of the measured state in the lagged instruments (regressors lagged 1 and 2).
LAGS = (2, 3)


def state_terms(spec: ModelSpec) -> np.ndarray:
    """Boolean mask over θ: True for terms that involve a state (endogenous)."""
    n, m = spec.n_states, len(spec.inputs)
    fac = spec.codes.factors

    def is_state(idx: int) -> bool:
        return idx < n or n + m <= idx < 2 * n + m

    return np.array([is_state(int(f0)) or is_state(int(f1)) for f0, f1 in fac])


def hac_lags(n: int) -> int:
    """Newey–West (1994) rule-of-thumb Bartlett bandwidth ``⌊4 (n/100)^{2/9}⌋``."""
    return int(max(1, np.floor(4.0 * (max(n, 1) / 100.0) ** (2.0 / 9.0))))


def lagged_regressors(data: RegressionData, spec: ModelSpec, lag: int) -> np.ndarray:
    """``Φ([ỹ(k−lag); u(k−1)])`` for every row (NaN where ``k − lag`` is before the
    experiment start). ``lag = 1`` gives the regressors themselves."""
    shifted = np.full_like(data.regsig, np.nan)
    d = lag - 1
    for s in range(data.n_segments):
        a, b = int(data.starts[s]), int(data.starts[s + 1])
        if b - a > d:
            shifted[a + d:b] = data.regsig[a:b - d]
    return kernels.regressor_matrix(np.ascontiguousarray(shifted), data.u, data.starts,
                                    spec.codes.factors)


#: Delays (first, last) of the estimated regressor noise averaged into the colour-test
#: instrument: samples 1..32 before the regressors (``scripts/estimator_study.py``:
#: the most powerful of the windows 1..8, 1..16, 1..32, 1..64 and of three windows
#: 1–2, 3–8, 9–32 against Gauss–Markov sensor noise, size kept on white noise).
COLOUR_WINDOW = (1, 32)

#: AR order of the whitened colour test (:func:`colour_test` with ``noise_order``;
#: ``InstrumentalGMM("auto", colour_order=...)``) and the number of noise lags it
#: averages, from ``order + 1``:
#: ``scripts/colour_study.py`` compared orders 1–3 and spans 8–24 (AR(2), lags 3–18: the
#: most powerful against Gauss–Markov sensor noise at its level on white noise).
WHITENED_COLOUR_ORDER = 2
WHITENED_COLOUR_SPAN = 16


def whitened_colour_window(order: int) -> tuple[int, int]:
    """Noise lags of the colour test whitened by an AR(``order``) prefilter: the first
    ``order + 1`` (the prefiltered error ``Ĉ(q)ε(k)`` reaches back to ``ε(k − order)``,
    whose MA(1) part remembers the noise at ``k − order``), :data:`WHITENED_COLOUR_SPAN`
    of them."""
    return (int(order) + 1, int(order) + WHITENED_COLOUR_SPAN)


def noise_instruments(data: RegressionData, spec: ModelSpec, phi: np.ndarray,
                      z_sim: np.ndarray, window: tuple[int, int] = COLOUR_WINDOW
                      ) -> np.ndarray:
    """Past estimated regressor noise ``η(k) = φ(k) − ζ(k)`` (measured minus simulated
    regressors, state terms only), averaged over the rows ``k − window[1] … k − window[0]``
    of the same experiment; NaN where the window reaches the experiment's first row.

    ``η`` is the sensor noise (and the current's response) seen through each regressor,
    without the signal that the measured regressors carry, so its past is a sensitive
    probe of whether the equation error ``ε(k)`` remembers the noise: with white
    disturbances ``E{η(k − j) ε(k)} = 0`` for ``j ≥ 1`` (the same argument that makes the
    delayed measurements valid instruments); with coloured ones it is not. Returns
    ``(T, n_endogenous)``.
    """
    lo, hi = int(window[0]), int(window[1])
    if not 1 <= lo <= hi:
        raise ValueError(f"window must satisfy 1 <= first <= last, got {window!r}")
    cols = np.flatnonzero(state_terms(spec)).astype(np.int64)
    # one compiled pass (bit-identical to the numpy formulation: running sum of
    # η = nan_to_num(φ − ζ) over all rows, window differences; rows whose window leaves
    # the experiment or meets a diverged simulation are NaN)
    return ivk.noise_window(np.ascontiguousarray(phi, dtype=float),
                            np.ascontiguousarray(z_sim, dtype=float), cols,
                            np.asarray(data.starts, dtype=np.int64), lo, hi)


def colour_test(data: RegressionData, spec: ModelSpec, phi: np.ndarray,
                z_sim: np.ndarray | list[np.ndarray], window: tuple[int, int] | None = None,
                *, theta: np.ndarray | None = None, noise_order: int = 0
                ) -> tuple[np.ndarray, np.ndarray]:
    """Test of white disturbances aimed at the delayed instruments' validity.

    Per equation: two-step HAC GMM with the simulated instruments ``ζ`` (valid whatever
    the colour, Lemma 3.1; just identified) plus the past estimated noise of the
    equation's state terms (:func:`noise_instruments`); Hansen's J (= the difference-in-J
    statistic of the added columns) is χ²(number of state terms) when those moments
    hold — the condition under which the delayed measurements are valid instruments.

    With ``noise_order = p > 0`` (the whitened test) the moments are whitened first: an
    AR(p) noise model ``Ĉ(q)`` of the equation error of (3) at ``theta`` (the
    IV_{E{ζ}=0} estimate, (4) with (A7)) is fitted by Yule–Walker per group
    (:func:`ar_coefficients`) and target, regressors and instruments are prefiltered
    with it as in SRIV (refined IV with a noise model); the noise window then starts at
    lag ``p + 1`` (:func:`whitened_colour_window`): with white disturbances the error is
    an MA(1) (sensor noise at ``k`` and ``k + 1``), so ``Ĉ(q)ε(k)`` involves the noise
    back to ``k − p`` only and ``E{η(k − j) Ĉ(q)ε(k)} = 0`` for ``j > p``. Under
    coloured sensor noise the prefilter removes most of the error's own persistence,
    whose long-run variance otherwise drowns the correlation the test looks for
    (``scripts/colour_study.py`` measures size and power with and without it).

    Parameters
    ----------
    data, spec : RegressionData, ModelSpec
        The regression data (one or many groups) and the model.
    phi : ndarray (T, P)
        Regressors (:func:`vesselid.identify.kernels.regressor_matrix`).
    z_sim : ndarray (T, P), or a list holding it
        Instruments simulated from ``theta`` (:func:`simulated_instruments`). A one-item
        list hands them over: they are taken out of it and freed once copied into the
        equations' instrument blocks (on a long log they are as large as a block).
    window : (int, int), optional
        Noise lags averaged (:func:`noise_instruments`); default :data:`COLOUR_WINDOW`,
        or :func:`whitened_colour_window` with ``noise_order``. Must start after
        ``noise_order``.
    theta : ndarray (G, P), optional
        Estimate whose residual the noise model is fitted to (needed with
        ``noise_order``).
    noise_order : int
        AR order of the whitening prefilter (0: none, the unfiltered test).

    Returns
    -------
    stat : ndarray (G, n)
        Hansen's J of the noise moments per group and equation.
    df : ndarray (n,)
        Its degrees of freedom (the equation's number of state terms).
    """
    order = int(noise_order)
    if window is None:
        window = whitened_colour_window(order) if order else COLOUR_WINDOW
    if order < 0 or int(window[0]) <= order:
        raise ValueError(f"the noise window {window!r} must start after the AR order {order}")
    if order and theta is None:
        raise ValueError("a whitened colour test (noise_order > 0) needs theta")
    blocks = block_starts(spec)
    endo = state_terms(spec)
    if isinstance(z_sim, list):  # handed over: this frame holds the only reference
        z_sim = z_sim.pop()
    eta = noise_instruments(data, spec, phi, z_sim, window)
    col_of = np.cumsum(endo) - 1
    z_blocks = []
    for i in range(spec.n_states):
        cols = np.arange(int(blocks[i]), int(blocks[i + 1]))
        e_cols = col_of[cols[endo[cols]]]
        z_blocks.append((_gather_columns([(z_sim, cols), (eta, e_cols)]), e_cols.size))
    # gathered into the blocks, which solve_equations frees one by one
    del eta, z_sim
    ar = noise_model(data, spec, phi, np.asarray(theta, dtype=float), order) if order else None
    sol = solve_equations(data, spec, phi, z_blocks, weight="hac", ar=ar, release=True)
    return sol.c, sol.c_df


def simulated_instruments(data: RegressionData, spec: ModelSpec, theta: np.ndarray,
                          limit_factor: float = 1e3) -> tuple[np.ndarray, np.ndarray]:
    """Instruments simulated from ``theta`` (G, P) per group; ``(z (T, P), ok (G,))``."""
    codes = spec.codes
    limit = limit_factor * np.maximum(data.target_abs_max, 1.0)
    z, seg_ok = ivk.simulated_regressors(
        data.target, data.u, data.starts, data.group,
        np.ascontiguousarray(np.nan_to_num(theta), dtype=float), codes.factors,
        codes.equation, limit)
    ok = np.ones(data.n_groups, dtype=bool)
    np.logical_and.at(ok, data.group, seg_ok)
    ok &= np.all(np.isfinite(theta), axis=1)
    return z, ok


def instrument_blocks(spec: ModelSpec, kind: str, phi: np.ndarray, z_sim: np.ndarray | None,
                      lagged: list[np.ndarray] | None) -> list[tuple[np.ndarray, int]]:
    """Instrument matrix of every equation for instrument set ``kind``.

    Returns a list ``[(Z_i (T, K_i), n_lagged_i)]``; the last ``n_lagged_i`` columns
    are the lagged (measured-state) instruments.
    """
    blocks = block_starts(spec)
    endo = state_terms(spec)
    out = []
    for i in range(spec.n_states):
        cols = np.arange(int(blocks[i]), int(blocks[i + 1]))
        d_cols = cols[endo[cols]]
        lag_cols = [(lg, d_cols) for lg in (lagged or [])]
        n_lag = len(lag_cols) * d_cols.size
        if kind == "simulated":
            out.append((z_sim[:, cols], 0))
        elif kind == "lagged":
            x_cols = cols[~endo[cols]]
            out.append((_gather_columns([(phi, x_cols), *lag_cols]), n_lag))
        elif kind == "combined":
            out.append((_gather_columns([(z_sim, cols), *lag_cols]), n_lag))
        else:  # pragma: no cover - validated by callers
            raise ValueError(kind)
    return out


def _gather_columns(parts: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """``np.column_stack([a[:, cols] for a, cols in parts])`` (the same values, C order)
    copied column by column into one array: a few strided copies instead of the fancy
    indexed pieces and their concatenation (~7x faster for 10⁴ × 7)."""
    rows = parts[0][0].shape[0]
    out = np.empty((rows, sum(len(cols) for _, cols in parts)),
                   dtype=np.result_type(*(a.dtype for a, _ in parts)))
    pos = 0
    for a, cols in parts:
        for c in np.asarray(cols).tolist():
            out[:, pos] = a[:, c]
            pos += 1
    return out


def ar_coefficients(data: RegressionData, resid: np.ndarray, valid: np.ndarray,
                    order: int) -> np.ndarray:
    """Yule–Walker AR(``order``) noise model ``C(q) = 1 + c₁q⁻¹ + …`` of ``resid`` per
    group, pooled over the group's experiments. Returns ``(G, order + 1)``; always
    minimum phase (Yule–Walker), so the prefilter ``C(q)`` is well defined."""
    acv, cnt = ivk.autocov(np.nan_to_num(resid), data.starts, valid, int(order))
    g_acv = np.zeros((data.n_groups, order + 1))
    g_cnt = np.zeros(data.n_groups)
    np.add.at(g_acv, data.group, acv)
    np.add.at(g_cnt, data.group, cnt)
    return yule_walker(g_acv / np.maximum(g_cnt, 1)[:, None])


def yule_walker(r: np.ndarray) -> np.ndarray:
    """AR noise models ``C(q) = 1 + c₁q⁻¹ + … + c_pq⁻ᵖ`` from autocovariances ``r``
    ``(G, p + 1)`` (lags 0..p; any common scale) by the Yule–Walker equations; ``C = 1``
    where the Toeplitz system is singular. Returns ``(G, p + 1)``."""
    r = np.asarray(r, dtype=float)
    order = r.shape[1] - 1
    idx = np.abs(np.subtract.outer(np.arange(order), np.arange(order)))
    coef, ok = linalg.solve(r[:, idx], r[:, 1:])
    out = np.zeros_like(r)
    out[:, 0] = 1.0
    out[ok, 1:] = -coef[ok]
    return out


@dataclass
class GMMSolution:
    """Estimates of one instrument set for every group.

    ``theta`` (G, P), ``ok`` (G,), per equation ``j`` (G, n) Hansen's J, ``df`` (n,)
    its degrees of freedom, ``c`` (G, n) the difference-in-J statistic of the
    lagged subset and ``c_df`` (n,). ``designs`` (one group only, on request):
    per equation ``(z, phi, y, valid, weight)`` after prefiltering and centring;
    ``jacobians`` (with ``designs``): per equation the derivative ``∂θ₂/∂θ₁`` (P_i, P_i)
    of the two-step estimate with respect to the first-step estimate through the
    estimated HAC weight (:func:`weight_jacobian`; Windmeijer 2005), None where the
    equation has no estimated weight (just identified, or 2SLS). ``colour`` (G, n),
    ``colour_df`` (n,), ``colour_ok`` (G,): the colour test fused into
    :func:`combined_solution` on request (:func:`colour_test`'s statistic where
    ``colour_ok``; elsewhere not computed), else None.
    """

    theta: np.ndarray
    ok: np.ndarray
    j: np.ndarray
    df: np.ndarray
    c: np.ndarray
    c_df: np.ndarray
    designs: list | None = None
    jacobians: list | None = None
    colour: np.ndarray | None = None
    colour_df: np.ndarray | None = None
    colour_ok: np.ndarray | None = None


def hac_sums(z: np.ndarray, e: np.ndarray, starts: np.ndarray, valid: np.ndarray,
             lags: int) -> np.ndarray:
    """Bartlett (Newey–West) long-run variance of the sum of ``g(k) = z(k) e(k)`` per
    experiment: ``Γ0 + Σ_{l=1}^{L} (1 − l/(L+1)) (Γl + Γlᵀ)``, ``Γl = Σ_k g(k) g(k−l)ᵀ``,
    ``g`` demeaned per experiment, invalid rows as zeros (time alignment kept).

    Computed exactly through moving sums: with ``h(t) = Σ_{j=0}^{L} g(t − j)`` over the
    zero-padded series, ``Σ_t h hᵀ = Σ_l (L + 1 − |l|) Γl``, so one ``K × K`` product
    replaces ``L + 1`` of them. Returns ``(S, K, K)``.
    """
    k_cols = z.shape[1]
    out = np.zeros((starts.size - 1, k_cols, k_cols))
    for s, a, b, v, cnt in _valid_experiments(starts, valid):
        lag = int(min(lags, b - a - 1))
        if b - a > _covariance.LARGE_ROWS:  # the same sums in blocks: no K × n scores
            # (the blocks zero the invalid rows' scores themselves: e as it is)
            out[s] = _bartlett_scores_in_blocks(z[a:b], e[a:b], v, cnt, lag,
                                                _covariance.BLOCK_ROWS)
            continue
        g = _scores_of(z, e, a, b, v, cnt)
        h = moving_sums(g, lag)
        out[s] = (h @ h.T) / (lag + 1.0)
    return out


def _bartlett_scores_in_blocks(z: np.ndarray, ev: np.ndarray, v: np.ndarray, cnt: int,
                               lag: int, rows: int) -> np.ndarray:
    """:func:`hac_sums` of one long experiment (rows of ``z``, residuals ``ev``; the
    scores of the invalid rows ``~v`` are zeroed, whatever ``ev`` holds there) with the
    scores formed ``rows`` rows at a time: their mean
    over the valid rows, then :func:`vesselid.identify.covariance.bartlett_block_sums`
    of the demeaned scores (invalid rows zero). Memory ``O(rows · K)`` instead of the
    ``K × n`` scores; the same sums rounded differently (~1e-14 relative)."""
    n, k_cols = z.shape
    spans = [(a, min(a + rows, n)) for a in range(0, n, rows)]
    # the blocks holding an invalid row (the others need no mask: the same numbers)
    masked = {a for a, b in spans if not v[a:b].all()}

    def raw(a: int, b: int) -> np.ndarray:
        g = z[a:b] * ev[a:b, None]
        if a in masked:
            g[~v[a:b]] = 0.0
        return g

    def demeaned(a: int, b: int) -> np.ndarray:
        g = raw(a, b)
        g -= g_mean
        if a in masked:
            g[~v[a:b]] = 0.0
        return g

    g_mean = sum(raw(a, b).sum(axis=0) for a, b in spans) / cnt
    mean = sum(demeaned(a, b).sum(axis=0) for a, b in spans) / n
    return _covariance.bartlett_block_sums(demeaned, n, k_cols, mean, lag, rows)


def _scores_of(z: np.ndarray, e: np.ndarray, a: int, b: int, v: np.ndarray,
               cnt: int) -> np.ndarray:
    """The scores ``z(k) e(k)`` of rows ``a … b − 1`` demeaned over the valid rows ``v``,
    invalid rows zero, as ``(K, n)`` (time along contiguous rows)."""
    ev = np.where(v, e[a:b], 0.0)
    g = np.empty((z.shape[1], b - a))
    np.multiply(z[a:b].T, ev, out=g)
    g -= (g.sum(axis=1) / cnt)[:, None]
    g[:, ~v] = 0.0
    return g


def _valid_experiments(starts: np.ndarray, valid: np.ndarray,
                       ) -> Iterator[tuple[int, int, int, np.ndarray, int]]:
    """``(s, a, b, valid rows, their count)`` of every experiment ``s`` (rows ``a … b − 1``)
    with a valid row."""
    for s in range(starts.size - 1):
        a, b = int(starts[s]), int(starts[s + 1])
        v = valid[a:b]
        cnt = int(v.sum())
        if cnt:
            yield s, a, b, v, cnt


def hac_sums_derivative(z: np.ndarray, phi: np.ndarray, e: np.ndarray, starts: np.ndarray,
                        valid: np.ndarray, lags: int, u: np.ndarray) -> np.ndarray:
    """Derivative of :func:`hac_sums` (summed over the experiments) with respect to θ,
    where ``e = y − φθ``, applied to a vector: ``(∂S/∂θ_j) u`` for every ``j``, shape
    ``(K, P)`` (what :func:`weight_jacobian` needs, at a fraction of the full ``P × K × K``).

    The same Bartlett weights, bandwidth, per-experiment demeaning and zeroed invalid
    rows as :func:`hac_sums`. With ``g(k) = z(k) e(k)`` demeaned per experiment,
    ``S = Σ_k g(k) (T g)(k)ᵀ/(L+1)``, ``T`` the triangular filter
    ``(T x)(k) = Σ_{|l|≤L} (L + 1 − |l|) x(k − l)`` within the experiment (the moving sums
    applied twice; symmetric). With ``q_j(k) = ∂g(k)/∂θ_j = −(z(k) φ_j(k) − mean_E z φ_j)``,
    ``(L+1) (∂S/∂θ_j) u = Σ_k q_j(k) (T uᵀg)(k) + Σ_k g(k) (T uᵀq_j)(k)``: the filter runs
    on ``1 + P`` scalar series only (so it never forms ``g`` itself, unlike
    :func:`hac_sums`' :func:`_scores_of`).
    """
    k_cols, p_cols = z.shape[1], phi.shape[1]
    u = np.asarray(u, dtype=float)
    out = np.zeros((k_cols, p_cols))
    for _, a, b, v, cnt in _valid_experiments(starts, valid):
        n = b - a
        # g = z e − mean_E(z e) on the valid rows is never formed: only uᵀg and gᵀ(·)
        # every row valid (and the layout np.where would give): the rows themselves
        every = (bool(v.all()) and z.dtype == np.float64 and z.flags.c_contiguous
                 and e.dtype == np.float64 and e.flags.c_contiguous)
        bad = np.flatnonzero(~v)
        # a long experiment whose few invalid rows hold finite instruments: the
        # instruments themselves (no zeroed N × K copy), the invalid rows' share taken
        # out of the sums below (ev and, after zu, the filtered series are zero there)
        in_place = (not every and n > _covariance.LARGE_ROWS
                    and bool(np.isfinite(z[a:b][bad]).all()))
        zv = (z[a:b] if every or in_place else np.where(v[:, None], z[a:b], 0.0))
        ev = e[a:b] if every else np.where(v, e[a:b], 0.0)
        ph = phi[a:b]
        if in_place:
            g_mean = zv.T @ ev / cnt
            mean = (zv.T @ ph - zv[bad].T @ ph[bad]) / cnt
        else:
            g_mean = zv.T @ ev / cnt  # (K,)
            mean = zv.T @ ph / cnt  # (K, P): mean of z φ_j
        lag = int(min(lags, n - 1))
        if n > _covariance.LARGE_ROWS:  # the filtered series and their sums in blocks
            t_gu_sum, t_qu_sum, zph, zeq = _filtered_sums_blocks(zv, ph, ev, v, u, g_mean,
                                                                 mean, lag)
            xu = mean * t_gu_sum - zph  # Σ q_j (T uᵀg)
            xtu = zeq - np.outer(g_mean, t_qu_sum)  # Σ g (T uᵀq_j)
            out += (xu + xtu) / (lag + 1.0)
            continue
        zu = zv @ u
        series = np.empty((1 + p_cols, n))
        series[0] = zu * ev - g_mean @ u  # uᵀ g
        series[1:] = (u @ mean)[:, None] - zu * ph.T  # uᵀ q_j
        series[:, ~v] = 0.0
        once = moving_sums(series, lag)
        del series
        tf = moving_sums(once, lag)[:, lag:lag + n]
        del once
        tf[:, ~v] = 0.0
        t_gu, t_qu = tf[0], tf[1:]
        zph, zeq = zv.T @ (ph * t_gu[:, None]), zv.T @ (ev[:, None] * t_qu.T)
        xu = mean * t_gu.sum() - zph  # Σ q_j (T uᵀg)
        xtu = zeq - np.outer(g_mean, t_qu.sum(axis=1))  # Σ g (T uᵀq_j)
        out += (xu + xtu) / (lag + 1.0)
    return out


def _filtered_sums_blocks(zv: np.ndarray, ph: np.ndarray, ev: np.ndarray, v: np.ndarray,
                          u: np.ndarray, g_mean: np.ndarray, mean: np.ndarray, lag: int
                          ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """The sums :func:`hac_sums_derivative` needs of one long experiment's filtered
    series — ``Σ T uᵀg``, ``Σ T uᵀq_j``, ``zvᵀ (ph · T uᵀg)`` and ``zvᵀ (ev · (T uᵀq)ᵀ)``
    — formed over blocks of output rows: the triangular filter ``T`` of row ``k`` reads
    the series on rows ``k − L … k + L`` only, so each block's series is formed (and
    filtered twice by :func:`moving_sums`) on its rows widened by ``L`` on each side
    (zero outside the experiment, as the whole-series filter pads). Memory
    ``O(BLOCK_ROWS + L)`` instead of three ``(1 + P) × n`` series; rounded differently."""
    n, p_cols = ph.shape
    k_cols = zv.shape[1]
    step = _covariance.BLOCK_ROWS * 2
    um = u @ mean  # (P,)
    gu = g_mean @ u
    t_gu_sum, t_qu_sum = 0.0, np.zeros(p_cols)
    zph, zeq = np.zeros((k_cols, p_cols)), np.zeros((k_cols, p_cols))
    for a in range(0, n, step):
        b = min(a + step, n)
        lo, hi = max(a - lag, 0), min(b + lag, n)
        zu = zv[lo:hi] @ u
        series = np.empty((1 + p_cols, hi - lo))
        series[0] = zu * ev[lo:hi] - gu  # uᵀ g
        series[1:] = um[:, None] - zu * ph[lo:hi].T  # uᵀ q_j
        series[:, ~v[lo:hi]] = 0.0
        tf = moving_sums(moving_sums(series, lag), lag)[:, lag + a - lo:lag + b - lo]
        tf[:, ~v[a:b]] = 0.0
        t_gu, t_qu = tf[0], tf[1:]
        t_gu_sum += t_gu.sum()
        t_qu_sum += t_qu.sum(axis=1)
        zph += zv[a:b].T @ (ph[a:b] * t_gu[:, None])
        zeq += zv[a:b].T @ (ev[a:b, None] * t_qu.T)
    return t_gu_sum, t_qu_sum, zph, zeq


def weight_jacobian(a: np.ndarray, w: np.ndarray, gbar: np.ndarray, ds_u: np.ndarray
                    ) -> np.ndarray:
    """``D = ∂θ₂/∂θ₁`` of the two-step GMM estimate through its weight (Windmeijer 2005).

    ``θ₂ = (AᵀW A)⁻¹ AᵀW b`` with ``W = S(θ₁)⁻¹``; since ``AᵀW ḡ₂ = 0`` at
    ``ḡ₂ = b − Aθ₂``, ``∂θ₂/∂θ₁_j = −(AᵀWA)⁻¹ AᵀW (∂S/∂θ_j) W ḡ₂`` (exact, not only to
    first order). ``a`` (K, P), ``w`` (K, K), ``gbar`` (K,); ``ds_u`` (K, P) the columns
    ``(∂S/∂θ_j) W ḡ₂`` at ``θ₁`` (:func:`hac_sums_derivative` with ``u = W ḡ₂``).
    Returns ``(P, P)``, column ``j`` the derivative with respect to ``θ₁_j``.
    """
    aw = a.T @ w
    return -np.linalg.solve(aw @ a, aw @ ds_u)


def _group_sum(data: RegressionData, x: np.ndarray) -> np.ndarray:
    out = np.zeros((data.n_groups, *x.shape[1:]))
    np.add.at(out, data.group, x)
    return out


def noise_model(data: RegressionData, spec: ModelSpec, phi: np.ndarray, theta: np.ndarray,
                order: int) -> np.ndarray:
    """AR(``order``) noise model of the equation error of (3) at ``theta``, per group and
    equation (:func:`ar_coefficients` of the residual ``y(k) − φᵀ(k)θ_g``; a non-finite
    ``θ`` counts as zero, non-finite residual rows are left out): the prefilter of SRIV
    and of the whitened colour test, shape ``(G, n, order + 1)``."""
    th = _per_row(np.nan_to_num(theta), data)
    eq = spec.codes.equation
    prod = phi * th
    ar = np.zeros((data.n_groups, spec.n_states, order + 1))
    for i in range(spec.n_states):
        resid = data.target[:, i] - prod[:, eq == i].sum(axis=1)
        ar[:, i] = ar_coefficients(data, resid, np.isfinite(resid), order)
    return ar


def _row_groups(data: RegressionData) -> np.ndarray:
    return np.repeat(data.group, np.diff(data.starts))


def _per_row(x: np.ndarray, data: RegressionData) -> np.ndarray:
    """``x[_row_groups(data)]`` (each row's group's row of ``x``, (T, …)): the same array,
    built by repeating each segment's row over its rows (a gather per segment, not per row:
    ~3x faster for one group of 10⁴ rows)."""
    return np.repeat(x[data.group], np.diff(data.starts), axis=0)


def _rows_of(theta: np.ndarray, data: RegressionData, shape: tuple[int, int]) -> np.ndarray:
    """Each row's group's ``theta`` as a ``shape`` array: :func:`_per_row`, or for one
    group on a long log its row broadcast (no ``(T, P)`` copy; the same products)."""
    if data.n_groups == 1 and shape[0] > _covariance.LARGE_ROWS:
        return np.broadcast_to(theta[0], shape)
    return _per_row(theta, data)


#: Rows per block of the GMM residuals written over the centred target.
_RESIDUAL_ROWS = 1 << 16


def solve_equations(
    data: RegressionData,
    spec: ModelSpec,
    phi: np.ndarray | list[np.ndarray],
    z_blocks: list[tuple[np.ndarray, int]],
    *,
    weight: str = "hac",
    ar: np.ndarray | None = None,
    lags: int | None = None,
    keep_designs: bool = False,
    keep_jacobians: bool | None = None,
    release: bool = False,
) -> GMMSolution:
    """IV / 2SLS / two-step GMM of every equation and group (see module docstring).

    Parameters
    ----------
    phi : ndarray (T, P), or a list holding it
        Regressors (:func:`vesselid.identify.kernels.regressor_matrix`). A one-item list
        hands them over: they are taken out of it and freed once the last equation's rows
        are centred.
    z_blocks : list of (ndarray (T, K_i), int)
        Instruments per equation and the number of trailing lagged columns.
    weight : {"hac", "2sls"}
        Over-identified equations: two-step GMM with a Bartlett HAC weight, or 2SLS.
    ar : ndarray (G, n, p + 1), optional
        Noise-model prefilter ``C(q)`` per group and equation (SRIV); applied to
        target, regressors and instruments per experiment before centring.
    lags : int, optional
        HAC bandwidth (default :func:`hac_lags` of the median experiment length).
    keep_designs : bool
        Keep group 0's final rows (``designs``; one group only).
    keep_jacobians : bool, optional
        With ``designs``, also Windmeijer's ``∂θ₂/∂θ₁`` of each two-step HAC equation
        (``jacobians``); default ``keep_designs``.
    release : bool
        The caller hands ``z_blocks`` over: each equation's entry is set to None once its
        rows are centred (the instruments are then freed with the list's reference; on
        a long log they are as large as the centred rows).
    """
    blocks = block_starts(spec)
    handed = isinstance(phi, list)
    if handed:  # this frame holds the only reference
        phi = phi.pop()
    n_groups = data.n_groups
    theta = np.full((n_groups, spec.n_params), np.nan)
    ok = np.ones(n_groups, dtype=bool)
    j_stat = np.zeros((n_groups, spec.n_states))
    c_stat = np.zeros((n_groups, spec.n_states))
    df = np.zeros(spec.n_states, dtype=int)
    c_df = np.zeros(spec.n_states, dtype=int)
    bw = hac_lags(int(np.median(np.diff(data.starts)))) if lags is None else int(lags)
    designs = [] if keep_designs else None
    keep_jacobians = keep_designs if keep_jacobians is None else keep_jacobians
    jacobians = [] if keep_designs else None
    for i in range(spec.n_states):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        z, n_lag = z_blocks[i]
        p_i = sl.stop - sl.start
        k_i = z.shape[1]
        # rows with every column finite; equilibrate every column exactly (powers of two,
        # undone below): the weights and Hansen's J are fourth-order sums (Σ (zε)²) that
        # over/underflow for signals of 1e±50 in raw units; filtering and centring
        # commute with the scaling
        zc = np.ascontiguousarray(z, dtype=float)
        valid, cmax = ivk.design_scan(zc, phi, sl.start, sl.stop, data.target, i)
        col = linalg.pow2_scale(cmax)
        if ar is None and release and _centres_in_place(zc):
            # a long log's handed-over instruments centred in their own buffer (no second
            # T × K array); the regressors and target as below (the same numbers)
            zz = _centre_in_place(zc, valid, col[:k_i], data.starts)
            if handed and i == spec.n_states - 1 and _own_rows(phi, sl):
                # and the handed-over regressors, every column this equation's, in theirs
                _, _, yy = ivk.design_centre(zc[:, :0], phi, sl.stop, sl.stop, data.target,
                                             i, valid, col[k_i + p_i:], data.starts)
                pp = _centre_in_place(phi, valid, col[k_i:k_i + p_i], data.starts)
            else:
                _, pp, yy = ivk.design_centre(zc[:, :0], phi, sl.start, sl.stop, data.target,
                                              i, valid, col[k_i:], data.starts)
        elif ar is None:  # masked, scaled and centred in two compiled passes (bit-identical)
            zz, pp, yy = ivk.design_centre(zc, phi, sl.start, sl.stop, data.target, i,
                                           valid, col, data.starts)
        elif not numpy_active():  # prefiltered and centred in one compiled pass (same bits)
            zz, pp, yy, valid = ivk.design_ar_centre(
                zc, phi, sl.start, sl.stop, data.target, i, valid, col, data.starts,
                np.ascontiguousarray(ar[:, i]), data.group)
        else:
            stack = np.column_stack([z, phi[:, sl], data.target[:, i]])
            stack = np.where(valid[:, None], stack, 0.0) * col
            stack, valid = ivk.ar_filter(stack, data.starts, valid,
                                         np.ascontiguousarray(ar[data.group, i]))
            stack = ivk.center(stack, data.starts, valid)
            zz = np.ascontiguousarray(stack[:, :k_i])
            pp = np.ascontiguousarray(stack[:, k_i:k_i + p_i])
            yy = np.ascontiguousarray(stack[:, -1])
            del stack
        if release:
            z_blocks[i] = None  # type: ignore[call-overload]
        del z, zc
        if handed and i == spec.n_states - 1:
            del phi  # every equation's rows are centred
        a_s, b_s, m_s, _ = ivk.cross_sums(zz, pp, yy, data.starts, valid)
        a, b, m = _group_sum(data, a_s), _group_sum(data, b_s), _group_sum(data, m_s)
        w = None
        if k_i > p_i:
            w, ok_w = linalg.inv_sym(m)
            ok &= ok_w
            w = np.nan_to_num(w)
        th, ok_i = linalg.gmm_solve(a, b, w)
        s_mat = None
        jac = None
        if k_i > p_i:
            th_rows = _rows_of(np.nan_to_num(th), data, pp.shape)
            if designs is None:
                # e = yy − Σ_p pp θ written over yy (read no more), a block of rows at a
                # time (the same numbers row by row); the centred regressors freed after
                e = yy
                for lo in range(0, e.size, _RESIDUAL_ROWS):
                    hi = lo + _RESIDUAL_ROWS
                    e[lo:hi] -= np.einsum("tp,tp->t", pp[lo:hi], th_rows[lo:hi])
                del pp, yy
            else:  # (the difference written over the product: the same numbers)
                e = np.einsum("tp,tp->t", pp, th_rows)
                np.subtract(yy, e, out=e)
            del th_rows
            s_mat = _group_sum(data, hac_sums(zz, e, data.starts, valid, bw))
            s_inv, ok_s = linalg.inv_sym(s_mat)
            if weight == "hac":
                th2, ok_2 = linalg.gmm_solve(a, b, np.nan_to_num(s_inv))
                th, ok_i = th2, ok_i & ok_2 & ok_s
                w = s_inv
            gbar = b - np.einsum("gkp,gp->gk", a, np.nan_to_num(th))
            if weight == "hac" and keep_jacobians and designs is not None and n_groups == 1 \
                    and ok_i[0]:
                # Windmeijer (2005): how θ₂ moves with θ₁ through W = S(θ₁)⁻¹, in the
                # units of the data (θ = θ_scaled · c_p / c_y)
                ds_u = hac_sums_derivative(zz, pp, e, data.starts, valid, bw,
                                           s_inv[0] @ gbar[0])
                c_p = col[k_i:k_i + p_i]
                jac = weight_jacobian(a[0], s_inv[0], gbar[0], ds_u) * c_p[:, None] / c_p[None, :]
            j_stat[:, i] = np.einsum("gk,gkl,gl->g", gbar, np.nan_to_num(s_inv), gbar)
            df[i] = k_i - p_i
            if n_lag:
                k_r = k_i - n_lag
                if k_r > p_i:  # restricted set over-identified: J(all) − J(restricted)
                    sr_inv, _ = linalg.inv_sym(s_mat[:, :k_r, :k_r])
                    th_r, _ = linalg.gmm_solve(a[:, :k_r], b[:, :k_r], np.nan_to_num(sr_inv))
                    g_r = b[:, :k_r] - np.einsum("gkp,gp->gk", a[:, :k_r], np.nan_to_num(th_r))
                    j_r = np.einsum("gk,gkl,gl->g", g_r, np.nan_to_num(sr_inv), g_r)
                else:
                    j_r = 0.0
                c_stat[:, i] = j_stat[:, i] - j_r
                c_df[i] = n_lag
        c_z, c_p, c_y = col[:k_i], col[k_i:k_i + p_i], col[-1]
        theta[:, sl] = th * c_p / c_y  # back to the units of the data
        ok &= ok_i
        if designs is not None:
            rows = _as_slice(valid)  # the valid rows (a slice when they are one block)
            # back to the units of the data in the rows' own buffers (zz, pp and yy are
            # this step's: a view of one block is divided in place, no second copy)
            zd, pd_, yd = zz[rows], pp[rows], yy[rows]
            zd /= c_z
            pd_ /= c_p
            yd /= c_y
            designs.append((zd, pd_, yd, valid,
                            None if w is None else np.asarray(w)[0] * np.outer(c_z, c_z)))
            jacobians.append(jac)
    theta[~ok] = np.nan
    return GMMSolution(theta=theta, ok=ok, j=j_stat, df=df, c=c_stat, c_df=c_df,
                       designs=designs, jacobians=jacobians)


def _centres_in_place(z: np.ndarray) -> bool:
    """Instruments :func:`solve_equations` may centre in their own buffer when the
    caller hands them over: a long log's (above
    :data:`~vesselid.identify.covariance.LARGE_ROWS` rows) float64, C-ordered, writeable
    array of at least two columns that owns its memory (not a view of another array)."""
    return (z.shape[0] > _covariance.LARGE_ROWS and z.ndim == 2 and z.shape[1] >= 2
            and z.dtype == np.float64 and z.flags.c_contiguous and z.flags.owndata
            and z.flags.writeable)


def _own_rows(phi: np.ndarray, sl: slice) -> bool:
    """Handed-over regressors :func:`solve_equations` may centre in their own buffer:
    every column is the equation's (``sl``), :func:`_centres_in_place` holds, and no
    other reference to the array exists (the handing-over frame's list gave its one
    up; rows kept elsewhere, e.g. the fit's remembered ones, are never written)."""
    return (sl.start == 0 and sl.stop == phi.shape[1] and _centres_in_place(phi)
            and _sole_reference(phi))


def _sole_reference(a: np.ndarray) -> bool:
    """Whether the caller's one name is the only reference to ``a``: its count against
    that of an array only this function names (the same calls; the interpreter's own
    counting conventions cancel)."""
    fresh = np.empty(0)
    return _references(a) <= _references(fresh) + 1  # (+1: the caller's name of ``a``)


def _references(a: object) -> int:
    return sys.getrefcount(a)


def _centre_in_place(z: np.ndarray, valid: np.ndarray, col: np.ndarray,
                     starts: np.ndarray) -> np.ndarray:
    """``z`` masked (invalid rows 0), scaled by ``col`` and centred per segment over its
    valid rows, in place: the instruments of ``design_centre`` (the same numbers — each
    product is the same, a C-ordered ``(T, K ≥ 2)`` column sum adds the rows in order, as
    the kernel does, and the zeroed invalid rows add nothing)."""
    z *= col
    bad = ~valid
    if bad.any():
        z[bad] = 0.0
    for s in range(starts.size - 1):
        a, b = int(starts[s]), int(starts[s + 1])
        cnt = int(np.count_nonzero(valid[a:b]))
        if cnt:
            z[a:b] -= z[a:b].sum(axis=0) / cnt
    return z


def _as_slice(mask: np.ndarray) -> slice | np.ndarray:
    """The rows of a boolean ``mask`` as a slice when they form one block (one experiment
    whose first rows are invalid), else the mask itself: the same rows, no gather."""
    idx = np.flatnonzero(mask)
    if idx.size and int(idx[-1]) - int(idx[0]) + 1 == idx.size:
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return mask


def _combined_layout(spec: ModelSpec):
    """Column layout of the combined set, grouped by equation: per equation its
    simulated columns, then its delayed-2 and delayed-3 state columns."""
    blocks = block_starts(spec)
    endo = state_terms(spec)
    ztype, zpar, zeq, bounds, n_lag = [], [], [], [0], []
    for i in range(spec.n_states):
        cols = list(range(int(blocks[i]), int(blocks[i + 1])))
        d_cols = [c for c in cols if endo[c]]
        for t, group in ((0, cols), *((lag, d_cols) for lag in LAGS)):
            ztype += [t] * len(group)
            zpar += group
            zeq += [i] * len(group)
        bounds.append(len(ztype))
        n_lag.append(len(d_cols) * len(LAGS))
    as_int = [np.asarray(x, dtype=np.int64) for x in (ztype, zpar, zeq, bounds)]
    return (*as_int, n_lag)


def _colour_layout(spec: ModelSpec):
    """Column layout of the colour test (:func:`colour_test`), grouped by equation: per
    equation its simulated columns (kind 0), then the noise window of its state terms
    (kind 1). Returns ``(kind, par, eq, bounds)``."""
    blocks = block_starts(spec)
    endo = state_terms(spec)
    kind, par, eq, bounds = [], [], [], [0]
    for i in range(spec.n_states):
        cols = list(range(int(blocks[i]), int(blocks[i + 1])))
        d_cols = [c for c in cols if endo[c]]
        kind += [0] * len(cols) + [1] * len(d_cols)
        par += cols + d_cols
        eq += [i] * (len(cols) + len(d_cols))
        bounds.append(len(kind))
    return tuple(np.asarray(x, dtype=np.int64) for x in (kind, par, eq, bounds))


def combined_solution(data: RegressionData, spec: ModelSpec, theta: np.ndarray, *,
                      lags: int | None = None, limit_factor: float = 1e3,
                      colour: tuple[int, int] | None = None
                      ) -> tuple[GMMSolution, np.ndarray]:
    """Two-step HAC GMM with the ``combined`` set for every group in two fused compiled
    passes (no row matrices): the Monte Carlo fast path of :func:`solve_equations`
    with ``instrument_blocks(spec, "combined", …)`` (same estimates to rounding).

    ``colour`` (a window, e.g. :data:`COLOUR_WINDOW`): also the colour test of the
    instruments simulated from ``theta`` in the same two passes (the generated kernel
    only; :func:`colour_test`'s statistic to rounding: the sums are accumulated in
    another order, the design is not column-scaled), into ``solution.colour``,
    ``colour_df`` and ``colour_ok``; ``colour_ok`` is False for groups it could not
    compute (``theta`` not finite, non-finite sums), and ``colour`` None when the
    generated kernel is not available — the caller runs :func:`colour_test` there.
    The combined estimates do not depend on ``colour`` (bit for bit).

    Returns ``(solution, aux_ok)``; ``aux_ok`` is False where the auxiliary model of
    ``theta`` diverged.
    """
    codes = spec.codes
    ztype, zpar, zeq, bounds, n_lag = _combined_layout(spec)
    ckind, cpar, ceq, cbounds = _colour_layout(spec)
    n_seg, k_tot, n_par, n = data.n_segments, ztype.size, spec.n_params, spec.n_states
    limit = limit_factor * np.maximum(data.target_abs_max, 1.0)
    bw = hac_lags(int(np.median(np.diff(data.starts)))) if lags is None else int(lags)
    th = np.ascontiguousarray(np.nan_to_num(theta), dtype=float)
    active = np.all(np.isfinite(theta), axis=1)
    s_a = np.zeros((n_seg, k_tot, n_par))
    s_b = np.zeros((n_seg, k_tot))
    s_m = np.zeros((n_seg, k_tot, k_tot))
    s_z = np.zeros((n_seg, k_tot))
    s_phi = np.zeros((n_seg, n_par))
    s_y = np.zeros((n_seg, n))
    count = np.zeros(n_seg, dtype=np.int64)
    status = np.zeros(n_seg, dtype=np.int64)
    s_hac = np.zeros((n_seg, k_tot, k_tot))
    dummy = np.zeros((1, 1))
    args = (data.regsig, data.target, data.u, data.starts, data.group, th, active,
            codes.factors, codes.equation, ztype, zpar, zeq, limit)
    special = specialised_combined(n, spec.n_inputs, codes.factors, codes.equation, ztype,
                                   zpar, zeq, ckind, cpar, ceq)

    parallel = n_seg > 1 and data.target.shape[0] >= ivk.PARALLEL_MIN_SAMPLES
    k_c = ckind.size
    fused = bool(colour is not None and special is not None)
    lo, hi = (int(colour[0]), int(colour[1])) if fused else (1, 1)
    if fused and not 1 <= lo <= hi:
        raise ValueError(f"window must satisfy 1 <= first <= last, got {colour!r}")
    c_out = [np.zeros((n_seg, k_c, n_par)), np.zeros((n_seg, k_c)),
             np.zeros((n_seg, k_c, k_c)), np.zeros((n_seg, k_c)), np.zeros((n_seg, n_par)),
             np.zeros((n_seg, n)), np.zeros(n_seg, dtype=np.int64),
             np.zeros((n_seg, k_c, k_c)), np.zeros((n_seg, k_c + n_par + n))
             ] if fused else [dummy[None], dummy, dummy[None], dummy, dummy, dummy,
                              count[:1] * 0, dummy[None], dummy]

    # the second pass reads its colour inputs unconditionally: full-shape zeros
    c_zero = (np.zeros((data.n_groups, n_par)), np.zeros((n_seg, k_c)),
              np.zeros((n_seg, n_par)), np.zeros((n_seg, n)), np.zeros((n_seg, k_c)))

    def run(*rest, c_in=c_zero) -> bool:
        # the generated kernel when it loads (True), else the generic one (False)
        if special is not None and special(parallel, *args, *rest, fused, (lo, hi), c_in,
                                           tuple(c_out)):
            return True
        ivk.combined_moments(*args, *rest)
        return False

    fused &= run(False, th, dummy, dummy, dummy, dummy, bw, s_a, s_b, s_m, s_z, s_phi, s_y,
                 count, status, s_hac)
    aux_ok = active.copy()
    np.logical_and.at(aux_ok, data.group, status == 0)
    cnt, (mz, mphi, my), (a_c, b_c, _), (a_g, b_g, m_g) = _centred_sums(
        data, codes.equation, zeq, s_a, s_b, s_m, s_z, s_phi, s_y, count)
    blocks = block_starts(spec)
    theta1 = np.full((data.n_groups, n_par), np.nan)
    ok = aux_ok.copy()
    for i in range(n):
        zs, ps = slice(int(bounds[i]), int(bounds[i + 1])), slice(int(blocks[i]),
                                                                     int(blocks[i + 1]))
        w, ok_w = linalg.inv_sym(m_g[:, zs, zs])
        t1, ok_1 = linalg.gmm_solve(a_g[:, zs, ps], b_g[:, zs], np.nan_to_num(w))
        theta1[:, ps] = t1
        ok &= ok_w & ok_1
    # mean score per segment, ḡ = (1/n) Σ (z − z̄)(y − ȳ − (φ − φ̄)ᵀθ₁)
    t1s = np.nan_to_num(theta1)[data.group]
    g_seg = (b_c - np.einsum("skp,sp->sk", a_c, t1s)) / cnt[:, None]
    c_in = _colour_first_step(data, spec, c_out, cbounds) if fused else None
    fused &= run(True, np.ascontiguousarray(np.nan_to_num(theta1)), mz, mphi, my,
                 np.ascontiguousarray(g_seg), bw, s_a * 0, s_b * 0, s_m * 0, s_z * 0,
                 s_phi * 0, s_y * 0, count * 0, status * 0, s_hac,
                 **({} if c_in is None else {"c_in": c_in[0]}))
    s_g = _group_sum(data, s_hac)
    theta2 = np.full_like(theta1, np.nan)
    j_stat = np.zeros((data.n_groups, n))
    c_stat = np.zeros((data.n_groups, n))
    df = np.zeros(n, dtype=int)
    c_df = np.zeros(n, dtype=int)
    for i in range(n):
        zs, ps = slice(int(bounds[i]), int(bounds[i + 1])), slice(int(blocks[i]),
                                                                     int(blocks[i + 1]))
        theta2[:, ps], ok_2, j_stat[:, i] = _second_step(a_g, b_g, s_g, zs, ps)
        ok &= ok_2
        df[i] = (zs.stop - zs.start) - (ps.stop - ps.start)
        c_stat[:, i] = j_stat[:, i]  # the simulated subset alone is just identified
        c_df[i] = n_lag[i]
    theta2[~ok] = np.nan
    sol = GMMSolution(theta=theta2, ok=ok, j=j_stat, df=df, c=c_stat, c_df=c_df)
    if fused and c_in is not None:
        sol.colour, sol.colour_df, sol.colour_ok = _colour_second_step(
            data, spec, c_out, cbounds, c_in[1], active)
    return sol, aux_ok


def _centred_sums(data: RegressionData, equation: np.ndarray, zeq: np.ndarray,
                  s_a: np.ndarray, s_b: np.ndarray, s_m: np.ndarray, s_z: np.ndarray,
                  s_phi: np.ndarray, s_y: np.ndarray, count: np.ndarray) -> tuple:
    """Per-segment raw sums of a fused pass (``Σ zφᵀ``, ``Σ zy``, ``Σ zzᵀ``, ``Σ z``,
    ``Σ φ``, ``Σ y``, row count) → ``(counts, (z̄, φ̄, ȳ), (A, b, M) centred per segment,
    (A, b, M) summed per group)``; instrument ``c`` belongs to equation ``zeq[c]``, parameter
    ``p`` to ``equation[p]``."""
    cnt = np.maximum(count, 1).astype(float)
    mz, mphi, my = s_z / cnt[:, None], s_phi / cnt[:, None], s_y / cnt[:, None]
    same = zeq[:, None] == equation[None, :]
    a_c = s_a - np.einsum("sk,sp->skp", s_z, mphi) * same
    b_c = s_b - s_z * my[:, zeq]
    m_c = s_m - np.einsum("sk,sl->skl", s_z, mz)
    a_g, b_g, m_g = _group_sum(data, a_c), _group_sum(data, b_c), _group_sum(data, m_c)
    return cnt, (mz, mphi, my), (a_c, b_c, m_c), (a_g, b_g, m_g)


def _second_step(a_g: np.ndarray, b_g: np.ndarray, s_g: np.ndarray, zs: slice, ps: slice
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two-step GMM of one equation (instrument columns ``zs``, parameters ``ps``) per
    group with the HAC weight ``S⁻¹`` of the group score sums ``s_g``:
    ``(θ₂, ok, Hansen's J)``."""
    s_inv, ok_s = linalg.inv_sym(s_g[:, zs, zs])
    a_i, b_i = a_g[:, zs, ps], b_g[:, zs]
    t2, ok_2 = linalg.gmm_solve(a_i, b_i, np.nan_to_num(s_inv))
    gbar = b_i - np.einsum("gkp,gp->gk", a_i, np.nan_to_num(t2))
    j = np.einsum("gk,gkl,gl->g", gbar, np.nan_to_num(s_inv), gbar)
    return t2, ok_s & ok_2, j


def _mirror(x: np.ndarray) -> np.ndarray:
    """Fill the lower triangles of a stack of matrices from the upper ones (in place)."""
    lower = np.tril_indices(x.shape[1], -1)
    x[:, lower[0], lower[1]] = x[:, lower[1], lower[0]]
    return x


def _colour_first_step(data: RegressionData, spec: ModelSpec, c_out: list,
                       cbounds: np.ndarray) -> tuple[tuple, tuple]:
    """First step of the fused colour test from the first pass's raw sums ``c_out``:
    centred sums per experiment, the 2SLS estimate per group and equation, and the
    second pass's inputs ``(θ₁, z̄, φ̄, ȳ, ḡ)``; also the centred ``(A, b, M)`` per group."""
    c_a, c_b, c_m, c_z, c_phi, c_y, c_count, _, c_ref = c_out
    _mirror(c_m)
    codes = spec.codes
    _, _, ceq, _ = _colour_layout(spec)
    blocks = block_starts(spec)
    # sums of differences from reference values (the centred sums do not depend on them)
    cnt, (mz, mphi, my), (a_c, b_c, _), (a_g, b_g, m_g) = _centred_sums(
        data, codes.equation, ceq, c_a, c_b, c_m, c_z, c_phi, c_y, c_count)
    theta1 = np.full((data.n_groups, spec.n_params), np.nan)
    for i in range(spec.n_states):
        zs = slice(int(cbounds[i]), int(cbounds[i + 1]))
        ps = slice(int(blocks[i]), int(blocks[i + 1]))
        w, _ = linalg.inv_sym(m_g[:, zs, zs])
        theta1[:, ps], _ = linalg.gmm_solve(a_g[:, zs, ps], b_g[:, zs], np.nan_to_num(w))
    t1 = np.ascontiguousarray(np.nan_to_num(theta1))
    g_seg = (b_c - np.einsum("skp,sp->sk", a_c, t1[data.group])) / cnt[:, None]
    k_c, n_par = c_z.shape[1], c_phi.shape[1]
    means = (c_ref[:, :k_c] + mz, c_ref[:, k_c:k_c + n_par] + mphi, c_ref[:, k_c + n_par:] + my)
    return (t1, *means, np.ascontiguousarray(g_seg)), (a_g, b_g, m_g)


def _colour_second_step(data: RegressionData, spec: ModelSpec, c_out: list,
                        cbounds: np.ndarray, sums: tuple, active: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two-step GMM and Hansen's J per group and equation of the fused colour test
    (:func:`solve_equations`' HAC branch on the group sums); ``(stat, df, ok)``."""
    a_g, b_g, m_g = sums
    s_g = _group_sum(data, _mirror(c_out[7]))
    blocks = block_starts(spec)
    n = spec.n_states
    stat = np.zeros((data.n_groups, n))
    df = np.zeros(n, dtype=int)
    for i in range(n):
        zs = slice(int(cbounds[i]), int(cbounds[i + 1]))
        ps = slice(int(blocks[i]), int(blocks[i + 1]))
        if zs.stop - zs.start == ps.stop - ps.start:
            continue  # no state term: just identified, nothing to test
        stat[:, i] = _second_step(a_g, b_g, s_g, zs, ps)[2]
        df[i] = (zs.stop - zs.start) - (ps.stop - ps.start)
    finite = np.ones(data.n_groups, dtype=bool)
    for arr in (*c_out[:6], *c_out[7:]):
        seg_ok = np.all(np.isfinite(arr.reshape(arr.shape[0], -1)), axis=1)
        np.logical_and.at(finite, data.group, seg_ok)
    finite &= np.all(np.isfinite(a_g), axis=(1, 2)) & np.all(np.isfinite(m_g), axis=(1, 2))
    return stat, df, finite & active
