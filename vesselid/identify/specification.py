"""Specification tests over arrays: instrument strength, over-identification, endogeneity,
residual whiteness and residual–input correlation.

Everything works on plain arrays (instruments ``z``, regressors ``phi``, target ``y``,
residuals, inputs, experiment boundaries ``starts``), one state equation at a time
unless said otherwise, with the package's conventions: rows are all experiments
concatenated, no statistic mixes samples of two experiments, and with zero-mean
instruments (A7) every experiment has its own constant (``zero_mean=True``).
Autocorrelation-robust versions use the covariance estimators of
:mod:`vesselid.identify.covariance` (``cov_type`` / ``cov_config``).

* :func:`first_stage` — partial F of each endogenous regressor and the Cragg–Donald
  minimum-eigenvalue statistic (Stock–Yogo style weak-instrument screen).
* :func:`hansen_j`, :func:`difference_in_j` — Hansen's J of an over-identified set
  (two-step efficient GMM) and the C statistic of a subset of instruments.
* :func:`endogeneity_test` — Durbin–Wu–Hausman test of LS against IV in the
  regression (control-function) form, robust with the chosen covariance, with a plain
  sentence ("LS is biased on this log: p = …").
* :func:`ljung_box` — residual whiteness per equation (statsmodels'
  ``acorr_ljungbox`` per experiment, Q statistics and degrees of freedom summed).
* :func:`residual_correlations` — residual autocorrelation and residual–input
  cross-correlation with confidence bands (the data of ``plot_residuals``).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vesselid.identify import covariance as _covariance
from vesselid.identify.covariance import (
    DEFAULT_COV_TYPE,
    CovarianceError,
    column_means,
    get_covariance_estimator,
)

__all__ = [
    "ResidualCorrelation",
    "TestResult",
    "difference_in_j",
    "endogeneity_test",
    "equation_diagnostics",
    "exogenous_columns",
    "first_stage",
    "hansen_j",
    "ljung_box",
    "residual_correlations",
    "summary_lines",
]


@dataclass
class TestResult:
    """A test statistic with its null distribution (after linearmodels' ``WaldTestStatistic``).

    Attributes
    ----------
    name : str
    stat : float
    df : int
        Degrees of freedom of the χ² (or numerator of the F) distribution.
    pvalue : float
    distribution : str
        ``"chi2"`` or ``"F"``.
    null : str
        The null hypothesis in words.
    sentence : str
        One plain sentence for ``summary()``.
    extra : dict
        Anything else (e.g. per-regressor values).
    """

    name: str
    stat: float
    df: int
    pvalue: float
    distribution: str = "chi2"
    null: str = ""
    sentence: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "stat": _finite(self.stat), "df": int(self.df),
                "pvalue": _finite(self.pvalue), "distribution": self.distribution,
                "null": self.null, "sentence": self.sentence}

    def __str__(self) -> str:
        return (f"{self.name}: {self.stat:.4g} ({self.distribution}({self.df})), "
                f"{_p(self.pvalue)}")


def _chi2_sf(x: float, df: float) -> float:
    """χ² survival function (= ``scipy.stats.chi2.sf``; scipy.special keeps imports light)."""
    from vesselid.identify._special import chi2_sf

    return float(chi2_sf(x, df)) if df > 0 else float("nan")  # scipy.stats: nan for df = 0


def _norm_ppf(q: float) -> float:
    """Standard normal quantile (= ``scipy.stats.norm.ppf``)."""
    from vesselid.identify._special import norm_ppf

    return norm_ppf(q)


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _p(p: float) -> str:
    """``"p = 0.034"`` / ``"p < 0.0001"``."""
    return "p = nan" if not np.isfinite(p) else ("p < 0.0001" if p < 1e-4 else f"p = {p:.2g}")


#: Rows per block of :func:`_minus_fit` and of :func:`_lstsq`'s refinement on long logs:
#: a block and its products stay in the core's cache (a residual block of ``1 << 16``
#: rows × 6 columns took ~5x longer per row than one of ``1 << 13``).
BLOCK_ROWS = 1 << 13


#: Largest condition number of the equilibrated Gram matrix for which :func:`_lstsq`
#: solves long logs from the normal equations (beyond: ``np.linalg.lstsq``).
GRAM_COND = 1e10


def _lstsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The least-squares coefficients ``np.linalg.lstsq(a, b, rcond=None)[0]``.

    Above :data:`~vesselid.identify.covariance.LARGE_ROWS` rows: the normal equations
    of the column-equilibrated ``a`` (``aᵀa`` and ``aᵀb`` in one pass each, no copy of
    ``a``) with two steps of iterative refinement on the residual ``b − a x`` (formed
    :data:`BLOCK_ROWS` rows at a time): for a Gram matrix of condition number ``κ² <``
    :data:`GRAM_COND` each step multiplies the error by ``~κ² ε``, so the solution has
    the accuracy of the whole-array SVD (the same coefficients rounded differently,
    ~1e-13 relative). A worse-conditioned or rank-deficient ``a`` takes ``lstsq``."""
    n, k = a.shape
    if n <= _covariance.LARGE_ROWS or k == 0:
        return np.linalg.lstsq(a, b, rcond=None)[0]
    rhs = b.reshape(n, -1)
    gram = a.T @ a
    scale = np.sqrt(np.diag(gram))
    if not (np.all(np.isfinite(gram)) and np.all(scale > 0)):
        return np.linalg.lstsq(a, b, rcond=None)[0]
    g_s = gram / np.outer(scale, scale)
    if not np.linalg.cond(g_s) < GRAM_COND:
        return np.linalg.lstsq(a, b, rcond=None)[0]
    chol = np.linalg.cholesky(g_s)

    def solve(v: np.ndarray) -> np.ndarray:  # gram⁻¹ v through the equilibrated factor
        w = np.linalg.solve(chol, v / scale[:, None])
        return np.linalg.solve(chol.T, w) / scale[:, None]

    x = solve(a.T @ rhs)
    for _ in range(2):
        atr = np.zeros_like(x)
        for t0 in range(0, n, BLOCK_ROWS):
            blk = slice(t0, min(t0 + BLOCK_ROWS, n))
            atr += a[blk].T @ (rhs[blk] - a[blk] @ x)
        x = x + solve(atr)
    return x.reshape((k, *b.shape[1:]))


def _minus_fit(a: np.ndarray, b: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """``a − b·coef`` in ``a``'s own buffer (the caller's copy), block by block on long
    logs (no ``(n, m)`` product array)."""
    n = a.shape[0]
    if n <= _covariance.LARGE_ROWS:
        fit = b @ coef
        return np.subtract(a, fit, out=fit)  # a − b·coef in the product's buffer
    for t0 in range(0, n, BLOCK_ROWS):
        blk = slice(t0, min(t0 + BLOCK_ROWS, n))
        a[blk] -= b[blk] @ coef
    return a


def _segs(starts: np.ndarray | None, t_len: int, skip_first: bool) -> list[slice]:
    starts = np.array([0, t_len]) if starts is None else np.asarray(starts, dtype=np.int64)
    off = 1 if skip_first else 0
    return [slice(int(starts[s]) + off, int(starts[s + 1])) for s in range(starts.size - 1)]


def _demean(x: np.ndarray, segs: list[slice], in_place: bool = False) -> np.ndarray:
    """``x`` centred per segment (rows outside ``segs`` zero); ``in_place``: in ``x``'s
    own buffer (float64 ``x`` whose segments cover every row; the same numbers)."""
    if len(segs) == 1 and segs[0].start == 0 and segs[0].stop == x.shape[0]:
        # one experiment, every row: the same numbers, one pass
        return np.subtract(x, column_means(x), out=x if in_place else None)
    if in_place:
        for s in segs:
            x[s] -= column_means(x[s])
        return x
    out = np.zeros_like(x, dtype=float)
    for s in segs:
        out[s] = x[s] - column_means(x[s])
    return out


def _rows(x: np.ndarray, segs: list[slice]) -> np.ndarray:
    return np.concatenate([x[s] for s in segs])


def _compact_starts(segs: list[slice]) -> np.ndarray:
    return np.concatenate([[0], np.cumsum([s.stop - s.start for s in segs])]).astype(np.int64)


def exogenous_columns(z: np.ndarray, phi: np.ndarray, *, rtol: float = 1e-10) -> np.ndarray:
    """Regressor columns that are also instrument columns (known inputs: exogenous)."""
    z = np.asarray(z, dtype=float)
    phi = np.asarray(phi, dtype=float)
    out = np.zeros(phi.shape[1], dtype=bool)
    if phi.shape[1] == 0:
        return out
    head = min(64, phi.shape[0])
    # every pair's screen over the first rows in one reduction (maxima are exact: the
    # values of the column-by-column screen); the scales column by column (a contiguous
    # reduction each: faster than one strided reduction over the rows)
    screen = np.max(np.abs(z[:head, :, None] - phi[:head, None, :]), axis=0)
    for j in range(phi.shape[1]):
        scale = np.max(np.abs(phi[:, j])) or 1.0
        cand = np.flatnonzero(screen[:, j] <= rtol * scale)
        out[j] = any(np.max(np.abs(z[:, k] - phi[:, j])) <= rtol * scale for k in cand)
    return out


# ----------------------------------------------------------------- instrument strength
def first_stage(
    z: np.ndarray,
    phi: np.ndarray,
    starts: np.ndarray | None = None,
    *,
    zero_mean: bool = True,
    skip_first: bool = True,
    names: list[str] | None = None,
) -> dict[str, Any]:
    """First-stage strength of the instruments of one equation.

    The regressors that are instruments themselves (inputs) are exogenous and are
    partialled out together with the per-experiment constants (``zero_mean``). For
    every remaining (endogenous) regressor the partial F statistic of its
    regression on the excluded instruments is reported, and the Cragg–Donald
    minimum eigenvalue statistic of them jointly (homoskedastic form; compare it
    with Stock–Yogo critical values, ≈ 10 and up for strong instruments). Both use
    ``σ̂² = SSR/N`` (the Wald form, as linearmodels' first-stage ``f.stat``).

    Returns
    -------
    dict
        ``partial_f`` {name: F}, ``partial_r2`` {name: R²}, ``cragg_donald`` (float),
        ``endogenous`` (names), ``df`` (numerator, denominator).
    """
    prep = _prepare(z, phi, None, starts, zero_mean, skip_first)
    return _first_stage(prep, names)


def _first_stage(prep: _Prepared, names: list[str] | None,
                 exo: np.ndarray | None = None) -> dict[str, Any]:
    """:func:`first_stage` on prepared rows (``exo``: :func:`exogenous_columns` of them)."""
    zz, pp = prep.z, prep.phi
    names = names or [f"x{j}" for j in range(pp.shape[1])]
    exo = exogenous_columns(zz, pp) if exo is None else exo
    excl = ~exogenous_columns(pp, zz)  # instrument columns that are not regressors
    endo = np.flatnonzero(~exo)
    n = zz.shape[0]
    k_ex = int(excl.sum())
    k_total = k_ex + int(exo.sum()) + (len(prep.segs) if prep.zero_mean else 0)
    if n > _covariance.LARGE_ROWS and endo.size and k_ex:  # sums over blocks of rows
        return _first_stage_blocks(zz, pp, excl, exo, names,
                                   _first_stage_base(names, endo, k_ex, n - k_total))
    w = pp[:, exo]

    def resid_on(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if b.shape[1] == 0:
            return a
        return _minus_fit(a, b, _lstsq(b, a))  # a: a gathered copy, ours

    x_t = resid_on(pp[:, endo], w)
    z_t = resid_on(zz[:, excl], w)
    out: dict[str, Any] = {"partial_f": {}, "partial_r2": {},
                           "endogenous": [names[j] for j in endo], "df": (k_ex, n - k_total)}
    if endo.size == 0 or k_ex == 0:
        out["cragg_donald"] = float("inf") if endo.size == 0 else 0.0
        return out
    coef = _lstsq(z_t, x_t)
    ssrs, sses, vv, ff = _fit_cross_products(z_t, x_t, coef)
    return _first_stage_stats(out, endo, names, ssrs, sses, vv, ff, k_ex, n)


def _first_stage_base(names: list[str], endo: np.ndarray, k_ex: int, df_den: int) -> dict[str, Any]:
    """The first stage's result before its statistics (:func:`_first_stage`)."""
    return {"partial_f": {}, "partial_r2": {}, "endogenous": [names[j] for j in endo],
            "df": (k_ex, df_den)}


def _first_stage_stats(out: dict[str, Any], endo: np.ndarray, names: list[str],
                       ssrs: np.ndarray, sses: np.ndarray, vv: np.ndarray, ff: np.ndarray,
                       k_ex: int, n: int) -> dict[str, Any]:
    """Partial F, partial R² and Cragg–Donald of :func:`_first_stage` from the sums of
    its fit and residual."""
    for i, j in enumerate(endo):
        ssr = float(ssrs[i])
        sse = float(sses[i])
        r2 = sse / (sse + ssr) if sse + ssr > 0 else float("nan")
        f = (sse / k_ex) / (ssr / n) if ssr > 0 else float("inf")
        out["partial_f"][names[j]] = float(f)
        out["partial_r2"][names[j]] = float(r2)
    s_vv = vv / n
    try:
        l_inv = np.linalg.inv(np.linalg.cholesky(s_vv))
        g = l_inv @ ff @ l_inv.T / k_ex
        out["cragg_donald"] = float(np.min(np.linalg.eigvalsh(0.5 * (g + g.T))))
    except np.linalg.LinAlgError:
        out["cragg_donald"] = float("inf")
    return out


def _endogeneity_rows(z: np.ndarray, phi: np.ndarray, y: np.ndarray, endo: np.ndarray,
                      cov_type: str, cov_config: Mapping[str, Any]
                      ) -> tuple[np.ndarray, np.ndarray] | None:
    """The augmented regression of :func:`_endogeneity` on one long experiment without
    its ``[φ, v̂]`` array: each block of rows formed where a sum needs it (the least
    squares of :func:`_lstsq_blocks`, the covariance of
    :func:`~vesselid.identify.covariance.ls_covariance_of_rows`; the same sums rounded
    differently). ``(β, Cov β)``, or None where the covariance has no block form."""
    est = get_covariance_estimator(cov_type, **cov_config)
    n, p = phi.shape
    q = p + endo.size
    if not (isinstance(est, _covariance.KernelCovariance) and est.sums_in_blocks()):
        return None
    coef = _lstsq_blocks(lambda b: z[b], lambda b: phi[b][:, endo], n)

    def x_of(a: int, b: int) -> np.ndarray:  # the rows of [φ, v̂]
        out = np.empty((b - a, q))
        out[:, :p] = phi[a:b]
        out[:, p:] = phi[a:b][:, endo]
        out[:, p:] -= z[a:b] @ coef
        return out

    beta = _lstsq_blocks(lambda b: x_of(b.start, b.stop), lambda b: y[b][:, None], n)[:, 0]
    resid = np.empty(n)
    for t0 in range(0, n, BLOCK_ROWS):
        t1 = min(t0 + BLOCK_ROWS, n)
        resid[t0:t1] = y[t0:t1] - x_of(t0, t1) @ beta
    cov = _covariance.ls_covariance_of_rows(est, x_of, n, q, resid)
    return None if cov is None else (beta, cov)


def _first_stage_blocks(zz: np.ndarray, pp: np.ndarray, excl: np.ndarray, exo: np.ndarray,
                        names: list[str], out: dict[str, Any]) -> dict[str, Any]:
    """:func:`_first_stage` of a long log without the partialled-out copies of the
    excluded instruments and endogenous regressors: every row of ``z̃ = z_excl − w c_z``
    and ``x̃ = x_endo − w c_x`` is formed inside a block of :data:`BLOCK_ROWS` rows where a
    sum needs it (:func:`_lstsq_blocks`; the same sums rounded differently)."""
    excl_i, exo_i, endo = np.flatnonzero(excl), np.flatnonzero(exo), np.flatnonzero(~exo)
    n = zz.shape[0]
    if exo_i.size:
        c_z = _lstsq_blocks(lambda b: pp[b][:, exo_i], lambda b: zz[b][:, excl_i], n)
        c_x = _lstsq_blocks(lambda b: pp[b][:, exo_i], lambda b: pp[b][:, endo], n)

        def z_t(b: slice) -> np.ndarray:
            return zz[b][:, excl_i] - pp[b][:, exo_i] @ c_z

        def x_t(b: slice) -> np.ndarray:
            return pp[b][:, endo] - pp[b][:, exo_i] @ c_x
    else:
        def z_t(b: slice) -> np.ndarray:
            return zz[b][:, excl_i]

        def x_t(b: slice) -> np.ndarray:
            return pp[b][:, endo]
    coef = _lstsq_blocks(z_t, x_t, n)
    m = endo.size
    vv, ff = np.zeros((m, m)), np.zeros((m, m))
    for t0 in range(0, n, BLOCK_ROWS):
        blk = slice(t0, min(t0 + BLOCK_ROWS, n))
        f = z_t(blk) @ coef
        v = x_t(blk) - f
        vv += v.T @ v
        ff += f.T @ f
    return _first_stage_stats(out, endo, names, np.diag(vv).copy(), np.diag(ff).copy(), vv,
                              ff, int(excl_i.size), n)


def _lstsq_blocks(a_of: Any, b_of: Any, n: int) -> np.ndarray:
    """:func:`_lstsq` of a long ``a`` and ``b`` given by their rows: ``a_of(rows)``,
    ``b_of(rows)`` return the rows of a slice (2-d); the normal equations and their two
    refinement steps summed over blocks of :data:`BLOCK_ROWS` rows. Where the Gram matrix
    is too ill-conditioned for them, the arrays are formed whole and ``lstsq`` solves."""
    blocks = [slice(t0, min(t0 + BLOCK_ROWS, n)) for t0 in range(0, n, BLOCK_ROWS)]
    gram, atb = 0.0, 0.0
    for blk in blocks:
        a, b = a_of(blk), b_of(blk)
        gram = gram + a.T @ a
        atb = atb + a.T @ b
    scale = np.sqrt(np.diag(gram))
    g_s = gram / np.outer(scale, scale) if np.all(scale > 0) else None
    if (g_s is None or not np.all(np.isfinite(gram))
            or not np.linalg.cond(g_s) < GRAM_COND):
        whole = slice(0, n)
        return np.linalg.lstsq(a_of(whole), b_of(whole), rcond=None)[0]
    chol = np.linalg.cholesky(g_s)

    def solve(v: np.ndarray) -> np.ndarray:  # gram⁻¹ v through the equilibrated factor
        w = np.linalg.solve(chol, v / scale[:, None])
        return np.linalg.solve(chol.T, w) / scale[:, None]

    x = solve(atb)
    for _ in range(2):
        atr = np.zeros_like(x)
        for blk in blocks:
            a = a_of(blk)
            atr += a.T @ (b_of(blk) - a @ x)
        x = x + solve(atr)
    return x


def _fit_cross_products(z: np.ndarray, x: np.ndarray, coef: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The first stage's sums of the fit ``f = z·coef`` and its residual ``v = x − f``:
    ``(Σ v², Σ f²)`` per column and ``(vᵀv, fᵀf)``. Above
    :data:`~vesselid.identify.covariance.LARGE_ROWS` rows summed over blocks of
    :data:`BLOCK_ROWS` rows (no ``(n, m)`` fit or residual arrays; the same sums rounded
    differently); shorter logs: whole-array products (the column sums as the columns'
    own dot products)."""
    n = z.shape[0]
    if n > _covariance.LARGE_ROWS:
        m = x.shape[1]
        vv, ff = np.zeros((m, m)), np.zeros((m, m))
        for t0 in range(0, n, BLOCK_ROWS):
            blk = slice(t0, min(t0 + BLOCK_ROWS, n))
            f = z[blk] @ coef
            v = x[blk] - f
            vv += v.T @ v
            ff += f.T @ f
        return np.diag(vv).copy(), np.diag(ff).copy(), vv, ff
    fitted = z @ coef
    v = x - fitted
    ssr = np.array([v[:, i] @ v[:, i] for i in range(x.shape[1])])
    sse = np.array([fitted[:, i] @ fitted[:, i] for i in range(x.shape[1])])
    return ssr, sse, v.T @ v, fitted.T @ fitted


# ----------------------------------------------------------------- over-identification
def _gmm_sums(z, phi, y, segs):
    """``A = Σ z φᵀ`` and ``b = Σ z y`` over the experiments (formed once per J test)."""
    return sum(z[s].T @ phi[s] for s in segs), sum(z[s].T @ y[s] for s in segs)


def _gmm(sums, weight):
    """``θ = (AᵀWA)⁻¹ AᵀW b`` from :func:`_gmm_sums`."""
    a, b = sums
    m = a.T @ weight @ a
    theta = np.linalg.solve(m, a.T @ weight @ b)
    return theta


def hansen_j(z: np.ndarray, phi: np.ndarray, y: np.ndarray, starts: np.ndarray | None = None,
             *, zero_mean: bool = True, skip_first: bool = True,
             cov_type: str = DEFAULT_COV_TYPE, long_run: np.ndarray | None = None,
             **cov_config: Any) -> TestResult:
    """Hansen's J test of the over-identifying restrictions of one equation.

    Two-step efficient GMM: 2SLS first, the long-run covariance ``S`` of its scores
    (``cov_type``, within experiments), then ``θ = argmin ḡᵀ S⁻¹ ḡ`` and
    ``J = ḡ(θ)ᵀ S⁻¹ ḡ(θ) ~ χ²(K − P)`` with ``ḡ = Σ z (y − φᵀθ)``. Pass ``long_run``
    to reuse an ``S`` (the difference-in-J test does). With ``zero_mean`` the
    instruments, regressors and target are centred per experiment first.

    Raises
    ------
    CovarianceError
        Fewer instruments than regressors.
    """
    prep = _prepare(z, phi, y, starts, zero_mean, skip_first)
    return _hansen_j(prep, cov_type, cov_config, long_run)


def _hansen_j(prep: _Prepared, cov_type: str, cov_config: Mapping[str, Any],
              long_run: np.ndarray | None = None) -> TestResult:
    """:func:`hansen_j` on prepared rows."""
    z, phi, y, segs = prep.z, prep.phi, prep.y, prep.segs
    k, p = z.shape[1], phi.shape[1]
    if k < p:
        raise CovarianceError(
            f"J test needs at least as many instruments ({k}) as regressors ({p})")
    sums = _gmm_sums(z, phi, y, segs)
    if long_run is None:
        w0 = np.linalg.pinv(sum(z[s].T @ z[s] for s in segs))
        th0 = _gmm(sums, w0)
        est = get_covariance_estimator(cov_type, **cov_config)
        long_run, _ = est.long_run(z, y - phi @ th0, _starts_of(segs), skip_first=False)
    s_inv = np.linalg.pinv(long_run)
    theta = _gmm(sums, s_inv)
    gbar = sum(z[s].T @ (y[s] - phi[s] @ theta) for s in segs)
    j = float(gbar @ s_inv @ gbar)
    df = k - p
    pval = float(_chi2_sf(j, df)) if df > 0 else float("nan")
    verdict = "rejected" if pval < 0.05 else "not rejected"
    sentence = ("the instruments are just-identified: no over-identification test" if df == 0
                else f"over-identifying restrictions {verdict}: J = {j:.3g}, {_p(pval)}")
    return TestResult("Hansen J", j, df, pval, "chi2",
                      "all instruments are uncorrelated with the equation error", sentence,
                      {"theta": theta, "long_run": long_run})


def difference_in_j(z: np.ndarray, phi: np.ndarray, y: np.ndarray, tested: np.ndarray,
                    starts: np.ndarray | None = None, *, zero_mean: bool = True,
                    skip_first: bool = True, cov_type: str = DEFAULT_COV_TYPE,
                    **cov_config: Any) -> TestResult:
    """Difference-in-J (C) test of the instrument columns ``tested`` (bool mask or indices).

    ``C = J(all) − J(all but tested)``, both with the long-run covariance of the full
    set (its sub-block for the smaller set; Hayashi 2000, §3.6), so ``C ≥ 0``;
    ``C ~ χ²(#tested)`` under the null that the tested instruments are valid given
    that the others are.
    """
    z = np.asarray(z, dtype=float)
    mask = np.zeros(z.shape[1], dtype=bool)
    mask[np.asarray(tested)] = True
    full = hansen_j(z, phi, y, starts, zero_mean=zero_mean, skip_first=skip_first,
                    cov_type=cov_type, **cov_config)
    s_full = full.extra["long_run"]
    keep = ~mask
    sub = hansen_j(z[:, keep], phi, y, starts, zero_mean=zero_mean, skip_first=skip_first,
                   long_run=s_full[np.ix_(keep, keep)])
    c = max(full.stat - sub.stat, 0.0)
    df = int(mask.sum())
    pval = float(_chi2_sf(c, df))
    sentence = (f"the tested instruments are {'rejected' if pval < 0.05 else 'not rejected'}: "
                f"C = {c:.3g}, {_p(pval)}")
    return TestResult("difference-in-J (C)", c, df, pval, "chi2",
                      "the tested instruments are uncorrelated with the equation error", sentence,
                      {"j_full": full.stat, "j_subset": sub.stat})


@dataclass
class _Prepared:
    """The rows one equation's tests use: experiments' usable rows concatenated (``segs``
    index them), centred per experiment with ``zero_mean``; ``y`` None for first stages."""

    z: np.ndarray
    phi: np.ndarray
    y: np.ndarray | None
    segs: list[slice]
    zero_mean: bool


def _prepare(z: Any, phi: Any, y: Any, starts: np.ndarray | None, zero_mean: bool,
             skip_first: bool, overwrite: bool = False) -> _Prepared:
    z = np.asarray(z, dtype=float)
    phi = np.asarray(phi, dtype=float)
    segs = _segs(starts, phi.shape[0], skip_first)
    arrays = [z, phi] if y is None else [z, phi, np.asarray(y, dtype=float).reshape(-1)]
    cs = _compact_starts(segs)
    inner = [slice(int(cs[i]), int(cs[i + 1])) for i in range(len(segs))]
    arrays = [_prepared_rows(a, segs, inner, zero_mean, overwrite) for a in arrays]
    return _Prepared(arrays[0], arrays[1], arrays[2] if y is not None else None, inner,
                     zero_mean)


def _prepared_rows(a: np.ndarray, segs: list[slice], inner: list[slice],
                   zero_mean: bool, overwrite: bool = False) -> np.ndarray:
    """One array's usable rows, concatenated (``inner`` index them), centred per
    experiment with ``zero_mean`` (each array on its own: the numbers do not depend on
    which others are prepared with it). ``overwrite``: the caller's float64 array may be
    centred in its own buffer (it needs it no more)."""
    # one experiment: its rows are a view (centring below copies unless the caller
    # hands the array over); the rows of several are a fresh copy, centred in place
    rows = np.ascontiguousarray(a[segs[0]]) if len(segs) == 1 else _rows(a, segs)
    own = (overwrite and a.dtype == np.float64) or not np.may_share_memory(rows, a)
    return _demean(rows, inner, in_place=own) if zero_mean else rows


def _with_target(prep: _Prepared, y: Any, starts: np.ndarray | None,
                 skip_first: bool) -> _Prepared:
    """``prep`` (instruments and regressors prepared already) with the target ``y``:
    :func:`_prepare` of the same arrays and ``y``, without preparing them again."""
    y = np.asarray(y, dtype=float).reshape(-1)
    segs = _segs(starts, y.shape[0], skip_first)
    return _Prepared(prep.z, prep.phi, _prepared_rows(y, segs, prep.segs, prep.zero_mean),
                     prep.segs, prep.zero_mean)


def _starts_of(segs: list[slice]) -> np.ndarray:
    return np.array([segs[0].start] + [s.stop for s in segs], dtype=np.int64)


# ----------------------------------------------------------------- endogeneity
def endogeneity_test(z: np.ndarray, phi: np.ndarray, y: np.ndarray,
                     starts: np.ndarray | None = None, *, zero_mean: bool = True,
                     skip_first: bool = True, cov_type: str = DEFAULT_COV_TYPE,
                     level: float = 0.05, **cov_config: Any) -> TestResult:
    """Durbin–Wu–Hausman test of LS against IV for one equation (regression form).

    The endogenous regressors (those that are not instruments) are regressed on the
    instruments; their first-stage residuals ``v̂`` are added to the LS regression
    ``y = φᵀθ + v̂ᵀδ + ε`` and ``δ = 0`` is tested with a Wald statistic using the
    covariance ``cov_type`` (default HAC, so autocorrelated equation errors do not
    fake a rejection). Under the null LS and IV estimate the same θ; a rejection means
    LS is biased on this log. With ``cov_type="unadjusted"`` the statistic is
    linearmodels' ``wu_hausman`` times its numerator degrees of freedom.
    """
    prep = _prepare(z, phi, y, starts, zero_mean, skip_first)
    return _endogeneity(prep, cov_type, cov_config, level)


def _endogeneity(prep: _Prepared, cov_type: str, cov_config: Mapping[str, Any],
                 level: float = 0.05, exo: np.ndarray | None = None,
                 memo: dict[str, Any] | None = None) -> TestResult:
    """:func:`endogeneity_test` on prepared rows (``exo``: :func:`exogenous_columns`;
    ``memo``: keeps the regressors augmented with the first-stage residuals, which do not
    depend on ``y``, for another target with the same instruments and regressors)."""
    z, phi, y, segs = prep.z, prep.phi, prep.y, prep.segs
    exo = exogenous_columns(z, phi) if exo is None else exo
    endo = np.flatnonzero(~exo)
    if endo.size == 0:
        return TestResult("Durbin-Wu-Hausman", 0.0, 0, 1.0, "chi2", "LS is consistent",
                          "no endogenous regressor: LS and IV coincide")
    x = None if memo is None else memo.get("x")
    rows = None
    if x is None and memo is None and z.shape[0] > _covariance.LARGE_ROWS and len(segs) == 1:
        rows = _endogeneity_rows(z, phi, y, endo, cov_type, cov_config)
    if rows is not None:
        beta, cov = rows
    elif x is None:
        coef = _lstsq(z, phi[:, endo])
        if z.shape[0] > _covariance.LARGE_ROWS:  # [φ, v] filled in place: no separate v
            x = np.empty((phi.shape[0], phi.shape[1] + endo.size))
            x[:, :phi.shape[1]] = phi
            x[:, phi.shape[1]:] = phi[:, endo]
            _minus_fit(x[:, phi.shape[1]:], z, coef)
        else:
            v = phi[:, endo] - z @ coef
            x = np.hstack([phi, v])
        if memo is not None:
            memo["x"] = x
    if rows is None:
        beta = _lstsq(x, y)
        est = get_covariance_estimator(cov_type, **cov_config)
        # a long log's augmented regressors, kept for no other target, are handed over
        hand_over = ({"overwrite": True} if memo is None
                     and x.shape[0] > _covariance.LARGE_ROWS
                     and type(est).estimate is _covariance.CovarianceEstimator.estimate
                     else {})
        cov = est.estimate(x, x, y - x @ beta, _starts_of(segs), skip_first=False,
                           zero_mean=False, **hand_over).cov
    d = beta[phi.shape[1]:]
    v_d = cov[phi.shape[1]:, phi.shape[1]:]
    try:
        stat = float(d @ np.linalg.solve(v_d, d))
    except np.linalg.LinAlgError:
        stat = float("nan")
    df = int(endo.size)
    pval = float(_chi2_sf(stat, df)) if np.isfinite(stat) else float("nan")
    if not np.isfinite(pval):
        sentence = "endogeneity test not available"
    elif pval < level:
        sentence = f"LS is biased on this log: {_p(pval)}"
    else:
        sentence = f"no evidence that LS is biased: {_p(pval)}"
    return TestResult("Durbin-Wu-Hausman", stat, df, pval, "chi2",
                      "LS is consistent (the regressors are exogenous)", sentence,
                      {"cov_type": cov_type})


# ----------------------------------------------------------------- residual checks
def ljung_box(
    resid: np.ndarray,
    starts: np.ndarray | None = None,
    *,
    lags: int = 20,
    skip_first: bool = True,
    names: list[str] | None = None,
) -> dict[str, TestResult]:
    """Ljung–Box whiteness test of the residual of every equation.

    ``Q = n(n+2) Σ_{k≤m} r_k²/(n−k)`` per experiment (``lags`` capped at a fifth of
    the experiment; equal to statsmodels' ``acorr_ljungbox``, checked in the tests,
    computed here without importing statsmodels), the independent experiments' Q
    statistics and degrees of freedom summed. The one-step equation error of (3) is
    autocorrelated by construction
    (sensor noise enters ``y(k)`` and ``φ(k+1)``), so a rejection is expected with
    noisy sensors; it says why the covariance must be HAC, not that the model is wrong.
    """
    resid = np.asarray(resid, dtype=float)
    if resid.ndim == 1:
        resid = resid[:, None]
    segs = _segs(starts, resid.shape[0], skip_first)
    names = names or [f"e{i}" for i in range(resid.shape[1])]
    out = {}
    for i, name in enumerate(names):
        q, df = 0.0, 0
        for s in segs:
            x = resid[s, i]
            m = int(min(lags, max(1, x.size // 5)))
            if x.size < 3 or np.std(x) == 0:
                continue
            q += _ljung_box_q(x - x.mean(), m)
            df += m
        pval = float(_chi2_sf(q, df)) if df else float("nan")
        sentence = (f"residual of {name} is {'not ' if pval < 0.05 else ''}white "
                    f"(Ljung-Box Q = {q:.4g}, {df} lags, {_p(pval)})")
        out[name] = TestResult("Ljung-Box", q, df, pval, "chi2", "the residual is white",
                               sentence)
    return out


def _ljung_box_q(x: np.ndarray, m: int) -> float:
    n = x.size
    den = float(x @ x)
    if den == 0:
        return 0.0
    r = np.array([x[k:] @ x[: n - k] for k in range(1, m + 1)]) / den
    return float(n * (n + 2) * np.sum(r**2 / (n - np.arange(1, m + 1))))


@dataclass
class ResidualCorrelation:
    """Residual autocorrelation and residual–input cross-correlation (MATLAB ``resid``).

    Attributes
    ----------
    lags : ndarray (L+1,)
        ``0 … max_lag`` for the autocorrelation.
    acf : ndarray (n_out, L+1)
        Autocorrelation of each equation's residual (pooled over experiments).
    cross_lags : ndarray (2L+1,)
        ``−max_lag … max_lag``; positive lag τ: input leads the residual,
        ``corr(ε(k), u(k − τ))``.
    ccf : ndarray (n_out, n_in, 2L+1)
    band : float
        Half-width of the confidence band under whiteness/independence,
        ``z_{1−α/2}/√N``.
    level : float
    outputs, inputs : list of str
    n : int
        Samples used.
    """

    lags: np.ndarray
    acf: np.ndarray
    cross_lags: np.ndarray
    ccf: np.ndarray
    band: float
    level: float
    outputs: list[str]
    inputs: list[str]
    n: int

    def outside(self) -> dict[str, Any]:
        """Share of lags (≥ 1 for the acf) whose correlation is outside the band."""
        return {"acf": {o: float(np.mean(np.abs(self.acf[i, 1:]) > self.band))
                        for i, o in enumerate(self.outputs)},
                "ccf": {f"{o}~{u}": float(np.mean(np.abs(self.ccf[i, j]) > self.band))
                        for i, o in enumerate(self.outputs) for j, u in enumerate(self.inputs)}}

    def to_dict(self) -> dict[str, Any]:
        return {"lags": self.lags.tolist(), "acf": self.acf.tolist(),
                "cross_lags": self.cross_lags.tolist(), "ccf": self.ccf.tolist(),
                "band": float(self.band), "level": float(self.level),
                "outputs": list(self.outputs), "inputs": list(self.inputs), "n": int(self.n)}


def residual_correlations(
    resid: np.ndarray,
    u: np.ndarray,
    starts: np.ndarray | None = None,
    *,
    max_lag: int = 25,
    level: float = 0.99,
    skip_first: bool = True,
    outputs: list[str] | None = None,
    inputs: list[str] | None = None,
) -> ResidualCorrelation:
    """Residual autocorrelation and residual–input cross-correlation with bands.

    Correlations are computed within experiments (each series centred per
    experiment) and pooled: ``r(τ) = Σ_E Σ_k a(k) b(k−τ) / sqrt(Σ a² Σ b²)``. The band
    ``±z/√N`` (default 99 %, as MATLAB's ``resid``) is the approximate null
    distribution for a white residual independent of the input.
    """
    resid = np.asarray(resid, dtype=float)
    u = np.asarray(u, dtype=float)
    if resid.ndim == 1:
        resid = resid[:, None]
    if u.ndim == 1:
        u = u[:, None]
    segs = _segs(starts, resid.shape[0], skip_first)
    max_lag = int(max(1, min(max_lag, min(s.stop - s.start for s in segs) - 1)))
    e = _demean(resid, segs)
    uu = _demean(u, segs)
    n_o, n_i = e.shape[1], uu.shape[1]
    acf = np.zeros((n_o, max_lag + 1))
    ccf = np.zeros((n_o, n_i, 2 * max_lag + 1))
    ee = np.zeros(n_o)
    u2 = np.zeros(n_i)
    n = 0
    for s in segs:
        a, b = e[s], uu[s]
        m = a.shape[0]
        n += m
        ee += np.sum(a**2, axis=0)
        u2 += np.sum(b**2, axis=0)
        nfft = 1 << int(np.ceil(np.log2(m + max_lag + 1)))
        fa = np.fft.rfft(a, nfft, axis=0)
        fb = np.fft.rfft(b, nfft, axis=0)
        # Σ_k a(k) x(k − τ) for τ ≥ 0 at index τ, τ < 0 at nfft + τ
        auto = np.fft.irfft(fa * np.conj(fa), nfft, axis=0)
        acf += auto[: max_lag + 1].T
        cross = np.fft.irfft(fa[:, :, None] * np.conj(fb[:, None, :]), nfft, axis=0)
        idx = np.r_[nfft - max_lag: nfft, 0: max_lag + 1]
        ccf += np.moveaxis(cross[idx], 0, -1)  # τ ≥ 0: ε(k) with u(k − τ)
    with np.errstate(divide="ignore", invalid="ignore"):
        acf = acf / ee[:, None]
        ccf = ccf / np.sqrt(ee[:, None, None] * u2[None, :, None])
    acf = np.nan_to_num(acf)
    ccf = np.nan_to_num(ccf)
    band = float(_norm_ppf(0.5 + level / 2) / np.sqrt(max(n, 1)))
    return ResidualCorrelation(
        lags=np.arange(max_lag + 1), acf=acf, cross_lags=np.arange(-max_lag, max_lag + 1),
        ccf=ccf, band=band, level=level,
        outputs=outputs or [f"e{i}" for i in range(n_o)],
        inputs=inputs or [f"u{j}" for j in range(n_i)], n=n,
    )


# ----------------------------------------------------------------- one call per equation
def equation_diagnostics(
    z: np.ndarray,
    phi: np.ndarray,
    y: np.ndarray,
    starts: np.ndarray | None = None,
    *,
    zero_mean: bool = True,
    skip_first: bool = True,
    names: list[str] | None = None,
    cov_type: str = DEFAULT_COV_TYPE,
    shared: dict[str, Any] | None = None,
    overwrite: bool = False,
    **cov_config: Any,
) -> dict[str, Any]:
    """Instrument strength, endogeneity (and J when over-identified) of one equation.

    ``z`` are the instruments the estimator used (K ≥ P columns), ``phi`` the
    regressors, ``y`` the target of the equation. Returns a JSON-ready dict:
    ``first_stage`` (:func:`first_stage`), ``endogeneity`` and, for ``K > P``,
    ``hansen_j`` (:meth:`TestResult.to_dict`). A test that cannot be computed
    (singular matrices) is reported with ``None`` values and a reason, never raised.

    ``shared`` (a dict the caller passes for every equation of one model, empty at
    first): an equation whose instruments, regressors, experiments, options and names
    equal the previous equation's (the sway and yaw equations of a model whose two
    equations have the same terms) reuses its prepared rows, exogenous columns, first
    stage and the first-stage residuals of the endogeneity regression — the same
    numbers, computed once.

    ``overwrite``: the caller hands ``z``, ``phi`` and ``y`` over (float64 arrays it needs
    no more): they are centred in their own buffers instead of copies (the same numbers;
    on a long log each copy is as large as the instruments).
    """
    errors = (np.linalg.LinAlgError, ValueError)
    key = (zero_mean, skip_first, None if names is None else tuple(names),
           None if starts is None else np.asarray(starts).tobytes(), cov_type)
    prev = None if shared is None else shared.get("previous")
    if prev is not None and not (prev["key"] == key and _same(prev["z"], z)
                                 and _same(prev["phi"], phi)):
        prev = None
    try:  # the three tests share the prepared rows and the exogenous columns
        if prev is not None:
            prep = _with_target(prev["prep"], y, starts, skip_first)
            exo = prev["exo"]
        else:
            prep = _prepare(z, phi, y, starts, zero_mean, skip_first, overwrite)
            exo = exogenous_columns(prep.z, prep.phi)
    except errors:  # let each test report its own reason
        return _equation_diagnostics_apart(z, phi, y, starts, zero_mean, skip_first, names,
                                           cov_type, cov_config)
    if shared is not None and prev is None:
        prev = shared["previous"] = {"key": key, "z": z, "phi": phi, "prep": prep, "exo": exo,
                                     "memo": {}}
    memo = None if prev is None else prev["memo"]

    def first() -> dict[str, Any]:
        if memo is None:
            return _first_stage(prep, names, exo)
        if "first_stage" not in memo:
            memo["first_stage"] = _first_stage(prep, names, exo)
        return copy.deepcopy(memo["first_stage"])

    tests = {"first_stage": first,
             "endogeneity": lambda: _endogeneity(prep, cov_type, cov_config, exo=exo,
                                                 memo=memo),
             "hansen_j": lambda: _hansen_j(prep, cov_type, cov_config)}
    return _run_tests(tests, np.shape(z)[1] > np.shape(phi)[1])


def _same(a: Any, b: Any) -> bool:
    """The same array (object, or shape and values)."""
    if a is b:
        return True
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and bool(np.array_equal(a, b))


def _equation_diagnostics_apart(z, phi, y, starts, zero_mean, skip_first, names, cov_type,
                                cov_config) -> dict[str, Any]:
    opts = {"zero_mean": zero_mean, "skip_first": skip_first}
    tests = {"first_stage": lambda: first_stage(z, phi, starts, names=names, **opts),
             "endogeneity": lambda: endogeneity_test(z, phi, y, starts, cov_type=cov_type,
                                                     **opts, **cov_config),
             "hansen_j": lambda: hansen_j(z, phi, y, starts, cov_type=cov_type, **opts,
                                          **cov_config)}
    return _run_tests(tests, np.shape(z)[1] > np.shape(phi)[1])


def _run_tests(tests: dict[str, Any], over_identified: bool) -> dict[str, Any]:
    """Run the tests of :func:`equation_diagnostics`; a failure is a reason, not a raise."""
    out: dict[str, Any] = {}
    for key, fn in tests.items():
        if key == "hansen_j" and not over_identified:
            continue
        try:
            res = fn()
        except (np.linalg.LinAlgError, ValueError) as exc:
            reason = str(exc).splitlines()[0]
            out[key] = ({"error": reason} if key == "first_stage" else
                        {"stat": None, "pvalue": None,
                         "sentence": f"{key} not available: {reason}"})
            continue
        out[key] = ({k: (v if not isinstance(v, float) else _finite(v)) for k, v in res.items()}
                    if key == "first_stage" else res.to_dict())
    return out


def summary_lines(per_equation: dict[str, dict[str, Any]]) -> list[str]:
    """Plain lines for ``summary()`` from ``{state: equation_diagnostics(...)}``."""
    lines = []
    for s, d in per_equation.items():
        fs = d.get("first_stage", {})
        cd = fs.get("cragg_donald")
        pf = fs.get("partial_f", {})
        if pf:
            weakest = min(pf, key=lambda k: pf[k] if pf[k] is not None else -1)
            lines.append(f"instruments {s}: Cragg-Donald {_fmt(cd)}, weakest partial F "
                         f"{_fmt(pf[weakest])} ({weakest})")
        endo = d.get("endogeneity")
        if endo:
            lines.append(f"endogeneity {s}: {endo.get('sentence', '')}")
        j = d.get("hansen_j")
        if j:
            lines.append(f"over-identification {s}: {j.get('sentence', '')}")
    return lines


def _fmt(x: Any) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.3g}"
