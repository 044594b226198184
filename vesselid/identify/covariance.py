"""Covariance estimators for the LS / IV estimates of (4), (6) and (10), as a registry.

After linearmodels' ``iv/covariance.py``: ``fit(cov_type=..., **cov_config)`` looks up
a class in :data:`COVARIANCE_ESTIMATORS`, builds it from ``cov_config`` (validated
there) and calls :meth:`CovarianceEstimator.estimate` with plain arrays. Nothing here
needs a trial log or a results object, so a trial planner can predict the covariance
of a design from simulated instruments and residuals.

The estimators and their sandwich
---------------------------------
Every estimator of the package solves, per state equation ``i`` and experiment
``E``, moment equations ``Σ_k z(k) [y_i(k) − φᵀ(k) θ_i] = 0`` (LS: ``z = φ``; IV:
the instruments ζ; zero-mean IV: ζ centred per experiment, A7), combined over the
experiments in one of two ways (``combine``):

* ``"pooled"``: ``(Σ_E A_E) θ = Σ_E b_E`` with ``A_E = Σ_k z φᵀ``;
* ``"stacked"``: (6)/(10) in the least-squares sense, ``min_θ Σ_E ‖(b_E − A_E θ)/N_E‖²``.

Both are ``H θ̂ = Σ_E G_E b_E`` with ``G_E = I`` (pooled) or ``A_Eᵀ / N_E²`` (stacked)
and ``H = Σ_E G_E A_E``. With the scores ``g(k) = z(k) ε(k)`` (one column per
parameter, ``ε`` the residual of that parameter's equation),

``θ̂ − θ0 ≈ H⁻¹ Σ_E G_E Σ_k g_E(k)``  and  ``Cov θ̂ = H⁻¹ (Σ_E G_E S_E G_Eᵀ) H⁻ᵀ``,

where ``S_E`` is the long-run covariance of the scores *within* experiment ``E``
(experiments are independent; no lag ever crosses an experiment boundary). The
estimators differ only in ``S_E``:

* ``unadjusted`` — white, homoskedastic equation errors: ``S_E = Σ_k z zᵀ ⊙ Σ_ε``
  with the residual (co)variance ``Σ_ε`` pooled over the experiments;
* ``hac`` — kernel-weighted (heteroskedasticity and autocorrelation consistent)
  ``S_E = Σ_j w_j Γ_E(j)``, Bartlett / Parzen / quadratic-spectral kernels, fixed or
  automatic bandwidth (Andrews 1991 AR(1) plug-in, Newey & West 1994), optionally
  pre-whitened with a VAR(1) (Andrews & Monahan 1992);
* ``cluster`` — one cluster per experiment, ``S_E = (Σ_k g)(Σ_k g)ᵀ`` (needs many
  experiments).

The joint covariance of all equations is returned (cross-equation blocks from the
cross-products of the scores), not only the per-equation blocks.

Zero-mean instruments equal adding one constant per experiment to the regressors
and the instruments (the instruments are then the centred ζ, the residual loses its
per-experiment mean), so with ``zero_mean=True`` the scores use the residual
centred per experiment: ``unadjusted`` then equals linearmodels
``IV2SLS(y, experiment dummies, Φ, ζ).fit(cov_type="unadjusted")`` and ``hac`` with
one experiment ``cov_type="kernel"`` (tests check both to 1e-10).

Why the default is HAC
----------------------
The equation error of (3) is autocorrelated by construction: the sensor noise ``e``
enters ``y(k)`` and, through the regressors, ``φ(k+1)`` (an MA(1) with a negative
lag-1 correlation around ``−(a + 2n|x|)``), and slowly varying currents are
coloured. A white-noise formula overstates the standard errors on the paper's
white designs and understates them under coloured currents; the calibration study
(``scripts/calibration.py``) measures it.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, ClassVar

import numpy as np

from vesselid.errors import CovarianceError
from vesselid.identify.defaults import DEFAULT_COV_TYPE
from vesselid.identify.movingsums import moving_sums

__all__ = [
    "BANDWIDTH_RULES",
    "COVARIANCE_ESTIMATORS",
    "DEFAULT_COV_TYPE",
    "KERNELS",
    "ClusterCovariance",
    "CovarianceError",
    "CovarianceEstimator",
    "CovarianceResult",
    "KernelCovariance",
    "UnadjustedCovariance",
    "automatic_bandwidth",
    "bartlett_long_run",
    "column_means",
    "get_covariance_estimator",
    "iv_covariance",
    "kernel_weights",
    "long_run_covariance",
    "moving_sums",
    "sandwich_from_sums",
    "scores",
]



#: Kernels of the HAC estimator (linearmodels' names and bandwidth convention).
#: Experiments longer than this many rows take the bounded-memory paths: the Bartlett
#: long-run covariance accumulated over blocks of :data:`BLOCK_ROWS` rows
#: (:func:`bartlett_long_run`) and the LS-form scores without a second copy of the
#: equilibrated regressors (:func:`_scores`). They agree with the whole-array forms to
#: rounding (~1e-14 relative); logs up to this length keep the whole-array numbers.
LARGE_ROWS = 1 << 17
#: Rows per block of the bounded-memory Bartlett sums (a block and its running sums stay
#: in the core's cache: measured fastest at 4-8k rows, slower than the whole-array kernel
#: from 16k rows up).
BLOCK_ROWS = 1 << 13

KERNELS = ("bartlett", "parzen", "qs")
_KERNEL_ALIASES = {
    "bartlett": "bartlett", "newey-west": "bartlett",
    "parzen": "parzen", "gallant": "parzen",
    "qs": "qs", "quadratic-spectral": "qs", "andrews": "qs",
}
_KERNEL_LABELS = {"bartlett": "Bartlett", "parzen": "Parzen", "qs": "quadratic-spectral"}

#: Automatic bandwidth rules.
BANDWIDTH_RULES = ("andrews", "newey-west")

# --------------------------------------------------------------------------- kernels
def kernel_weights(kernel: str, bandwidth: float, n_lags: int) -> np.ndarray:
    """Kernel weights ``w_0 … w_{n_lags}`` (``w_0 = 1``).

    The bandwidth follows linearmodels / Newey–West: Bartlett ``w_j = 1 − j/(⌊b⌋+1)``
    (``⌊b⌋`` lags with non-zero weight, as statsmodels' ``weights_bartlett(⌊b⌋)``),
    Parzen on ``x = j/(⌊b⌋+1)``, quadratic-spectral ``w_j = 3/z² (sin z / z − cos z)``,
    ``z = 6π (j/b)/5`` (Andrews 1991, eq. (2.7), real ``b``, every lag); ``b = 0``
    keeps lag 0 only.
    """
    kernel = _kernel_name(kernel)
    b = float(bandwidth)
    if not (b >= 0 and math.isfinite(b)):
        raise CovarianceError(f"bandwidth must be finite and non-negative, got {bandwidth}")
    j = np.arange(int(n_lags) + 1, dtype=float)
    if kernel == "bartlett":
        w = np.clip(1.0 - j / (math.floor(b) + 1.0), 0.0, None)
    elif kernel == "parzen":
        x = j / (math.floor(b) + 1.0)
        w = np.where(x <= 0.5, 1 - 6 * x**2 + 6 * x**3, np.where(x <= 1, 2 * (1 - x) ** 3, 0.0))
    else:
        w = np.zeros_like(j)
        w[0] = 1.0
        if b > 0:
            z = 6 * np.pi * j[1:] / b / 5
            w[1:] = 3.0 / z**2 * (np.sin(z) / z - np.cos(z))
    return w


def _kernel_name(kernel: str) -> str:
    key = str(kernel).lower()
    if key not in _KERNEL_ALIASES:
        raise CovarianceError(f"unknown kernel {kernel!r}; choose from {list(KERNELS)}")
    return _KERNEL_ALIASES[key]


def _segments(starts: np.ndarray, skip_first: bool) -> list[slice]:
    off = 1 if skip_first else 0
    return [slice(int(starts[s]) + off, int(starts[s + 1])) for s in range(starts.size - 1)]


def automatic_bandwidth(
    g: np.ndarray,
    starts: np.ndarray | None = None,
    *,
    kernel: str = "bartlett",
    rule: str = "andrews",
    skip_first: bool = False,
) -> float:
    """Automatic bandwidth for :func:`long_run_covariance` of the series ``g`` (T, q).

    ``rule="andrews"``: Andrews (1991, §6) with an AR(1) plug-in for every column,
    each column weighted by ``1/σ_a⁴`` (scale free), autocorrelations estimated
    within experiments and pooled, ``|ρ| ≤ 0.97``; the optimal ``S_T`` for the total
    sample size is converted to the Newey–West bandwidth convention of
    :func:`kernel_weights` (``b = S_T − 1`` for Bartlett and Parzen, ``b = S_T`` for QS).

    ``rule="newey-west"``: the nonparametric rule of Newey & West (1994) on the sum
    of the standardised columns (experiments pooled); on one column and one
    experiment it is linearmodels' ``kernel_optimal_bandwidth`` (rounded up).

    The result never exceeds the shortest experiment minus one.
    """
    kernel = _kernel_name(kernel)
    g = np.asarray(g, dtype=float)
    if g.ndim == 1:
        g = g[:, None]
    starts = np.array([0, g.shape[0]]) if starts is None else np.asarray(starts)
    segs = _segments(starts, skip_first)
    lengths = np.array([s.stop - s.start for s in segs])
    t_total = int(lengths.sum())
    cap = float(max(int(lengths.min()) - 1, 0))
    if rule == "andrews":
        num = np.zeros(g.shape[1])
        den = np.zeros(g.shape[1])
        for s in segs:
            x = g[s]
            num += np.einsum("ta,ta->a", x[1:], x[:-1])
            den += np.einsum("ta,ta->a", x[:-1], x[:-1])
        ok = den > 0
        if not ok.any():
            return 0.0
        rho = np.clip(num[ok] / den[ok], -0.97, 0.97)
        if kernel == "bartlett":
            a = np.sum(4 * rho**2 / ((1 - rho) ** 6 * (1 + rho) ** 2)) / np.sum(1 / (1 - rho) ** 4)
            s_t = 1.1447 * (a * t_total) ** (1 / 3)
        else:
            a = np.sum(4 * rho**2 / (1 - rho) ** 8) / np.sum(1 / (1 - rho) ** 4)
            s_t = (2.6614 if kernel == "parzen" else 1.3221) * (a * t_total) ** (1 / 5)
        b = s_t if kernel == "qs" else max(s_t - 1.0, 0.0)
        return float(min(b, cap))
    if rule == "newey-west":
        return float(min(_newey_west_bandwidth(g, segs, kernel, t_total), cap))
    raise CovarianceError(f"unknown bandwidth rule {rule!r}; choose from {list(BANDWIDTH_RULES)}")


def _newey_west_bandwidth(g: np.ndarray, segs: list[slice], kernel: str, t_total: int) -> float:
    scale = np.sqrt(column_means(_compact(g, segs), square=True))
    scale[scale == 0] = 1.0
    x = [_row_sums(g[s], scale) for s in segs] if g.shape[1] > 1 else [g[s, 0] for s in segs]
    return _newey_west_from_sums(x, kernel, t_total)


def _newey_west_from_sums(x: list[np.ndarray], kernel: str, t_total: int) -> float:
    """:func:`_newey_west_bandwidth` from the standardised columns' sums ``x`` of every
    experiment."""
    # Newey & West (1994): pilot lags n, exponent q, constant c per kernel
    q, c, n_exp = {"bartlett": (1, 1.1447, 2 / 9), "parzen": (2, 2.6614, 4 / 25),
                   "qs": (2, 1.3221, 2 / 25)}[kernel]
    n = math.ceil(4 * (t_total / 100) ** n_exp)
    sig = np.zeros(n + 1)
    for xs in x:
        for j in range(min(n, xs.size - 1) + 1):
            sig[j] += xs[j:] @ xs[: xs.size - j]
    sig /= t_total
    s0 = sig[0] + 2 * sig[1:].sum()
    sq = 2 * np.sum(np.arange(1, n + 1) ** q * sig[1:])
    if s0 == 0:
        return 0.0
    gamma = c * ((sq / s0) ** 2) ** (1 / (2 * q + 1))
    return float(math.ceil(gamma * t_total ** (1 / (2 * q + 1))))


def column_means(x: np.ndarray, *, square: bool = False) -> np.ndarray:
    """``x.mean(axis=0)`` (``square``: ``np.mean(x ** 2, axis=0)``), bit-identical: numpy
    adds the rows of a C-contiguous ``(T, K ≥ 2)`` array one after another, which the
    compiled :func:`vesselid.identify._ivkernels.column_sums` does without the per-row
    call overhead (or the squared copy) when the compiled kernels are loaded."""
    kernel = _loaded_kernel("column_sums")
    if (kernel is not None and x.ndim == 2 and x.shape[1] >= 2 and x.shape[0] > 0
            and x.dtype == np.float64 and x.flags.c_contiguous):
        return kernel(x, square) / x.shape[0]
    return np.mean(x**2, axis=0) if square else x.mean(axis=0)


def _row_sums(g: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """``np.sum(g / scale, axis=1)``, bit-identical: numpy adds fewer than 8 terms of a
    row in order from 0, so with few columns the row sums are accumulated one column at
    a time (a few vector passes instead of one short reduction per row)."""
    if g.shape[1] >= 8:
        return np.sum(g / scale, axis=1)
    acc = np.zeros(g.shape[0])
    for j in range(g.shape[1]):
        acc += g[:, j] / scale[j]
    return acc


def long_run_covariance(
    g: np.ndarray,
    weights: np.ndarray,
) -> np.ndarray:
    """``Σ_j w_|j| Γ(j)`` of one experiment's scores ``g`` (T, q), summed (not averaged).

    ``Γ(j) = Σ_k g(k) g(k−j)ᵀ``; computed as ``gᵀ (K g)`` with ``K`` the Toeplitz
    kernel matrix applied by (FFT) convolution, so every lag up to ``len(weights) − 1``
    is included exactly at ``O(q T log T)`` cost.
    """
    g = np.asarray(g, dtype=float)
    n_lags = min(len(weights) - 1, g.shape[0] - 1)
    w = np.asarray(weights[: n_lags + 1], dtype=float)
    if n_lags == 0:
        return w[0] * g.T @ g
    if n_lags <= 64:  # a few lag products beat the FFT
        out = w[0] * (g.T @ g)
        for j in range(1, n_lags + 1):
            if w[j] != 0:
                gj = g[j:].T @ g[:-j]
                out += w[j] * (gj + gj.T)
        return out
    sym = np.concatenate([w[:0:-1], w])[:, None]
    from scipy.signal import fftconvolve  # only the HAC kernels need it

    kg = fftconvolve(g, sym, mode="same", axes=0)
    out = g.T @ kg
    return 0.5 * (out + out.T)


def _loaded_kernel(name: str) -> Any:
    """The compiled kernel ``name`` (:mod:`vesselid.identify._ivkernels`, bit-identical to
    the numpy lines it replaces) when that module is loaded already and the estimation is
    not on the numpy path (:mod:`vesselid.identify.backend`); never imports numba."""
    from vesselid.identify.backend import loaded_kernel

    return loaded_kernel(name)


def bartlett_long_run(g: np.ndarray, lags: int) -> np.ndarray:
    """Bartlett long-run covariance ``Σ_{|l|≤L} (1 − |l|/(L+1)) Γ(l)`` of one experiment's
    scores ``g`` (T, q), summed: :func:`long_run_covariance` with
    ``kernel_weights("bartlett", L, …)`` in one ``q × q`` product instead of ``L + 1``.

    With the moving sums ``h(t) = Σ_{i=0}^{L} g(t − i)`` of the zero-padded series,
    ``Σ_t h hᵀ = Σ_l (L + 1 − |l|) Γ(l)`` (as :func:`vesselid.identify.gmm.hac_sums`).
    The moving sums are differences of a running sum of ``g`` minus its mean (the mean's
    share is added back as rank-one terms), so their rounding error does not grow with
    ``T``; the result equals the lag-by-lag sum to ~1e-15 relative.
    """
    g = np.asarray(g, dtype=float)
    n = g.shape[0]
    lags = int(lags)
    if lags == 0 or n < 2:
        return g.T @ g
    if n > LARGE_ROWS and g.shape[1] > 0:
        return _bartlett_blocks(g, lags, BLOCK_ROWS)
    kernel = _loaded_kernel("centred_moving_sums")
    if kernel is not None and g.flags.c_contiguous and g.shape[1] > 0:
        # the column means as numpy's pairwise sums of each (strided) column, the same
        # numbers as the row means of gᵀ; the moving sums of g − mean without its copy
        mean = np.array([g[:, i].mean() for i in range(g.shape[1])])
        h = kernel(g, mean, lags)
    else:
        gt = g.T.copy()  # time along contiguous rows
        mean = gt.mean(axis=1)
        gt -= mean[:, None]
        h = moving_sums(gt, lags)  # moving sums of g − mean
        del gt
    count, count_sq = _window_sizes(n, lags)
    # the moving sums of g are h + count·meanᵀ: add the mean's share as rank-one terms
    v = h @ count
    out = h @ h.T + np.outer(v, mean) + np.outer(mean, v) + count_sq * np.outer(mean, mean)
    return out / (lags + 1.0)


def _bartlett_blocks(g: np.ndarray, lags: int, rows: int) -> np.ndarray:
    """:func:`bartlett_long_run` accumulated over blocks of ``rows`` rows: the moving
    sums ``h(t) = c(min(t, n − 1)) − c(t − L − 1)`` of the centred running sum
    ``c(t) = Σ_{k≤t} (g(k) − ḡ)`` (``c`` of a negative index is 0) are formed one block
    at a time, carrying the last ``L + 1`` running sums, and ``Σ_t h hᵀ`` and
    ``Σ_t count(t) h(t)`` are summed per block: memory ``O((rows + L) q)`` instead of
    the ``(n + L) × q`` moving sums and the window sizes. The same quantity as the
    whole-array form, rounded differently (~1e-14 relative)."""
    n, q = g.shape
    mean = np.array([g[:, i].mean() for i in range(q)])
    return bartlett_block_sums(lambda a, b: g[a:b], n, q, mean, lags, rows)


def bartlett_block_sums(block: Callable[[int, int], np.ndarray], n: int, q: int,
                        mean: np.ndarray, lags: int, rows: int) -> np.ndarray:
    """:func:`_bartlett_blocks` of scores that are never held whole: ``block(a, b)``
    returns rows ``a … b − 1`` of the ``(n, q)`` scores (a fresh or read-only array) and
    ``mean`` is their column mean. Memory ``O((rows + L) q)`` whatever ``n``."""
    hh = np.zeros((q, q))
    v = np.zeros(q)
    count_sq = 0.0
    # buf holds c(t0 − L − 1 … t1 − 1): the carried L + 1 running sums, then the block's
    # (no concatenated copy); h is formed in its own buffer
    buf = np.zeros((rows + lags + 1, q))
    h_buf = np.empty((rows, q))
    carry = np.zeros(q)  # c(t0 − 1)
    full = None  # the window sizes of a whole block once every window is full (t ≥ L)
    for t0 in range(0, n, rows):
        t1 = min(t0 + rows, n)
        m = t1 - t0
        c = buf[lags + 1:lags + 1 + m]
        np.subtract(block(t0, t1), mean, out=c)
        np.cumsum(c, axis=0, out=c)
        c += carry
        carry = c[-1].copy()
        h = np.subtract(buf[lags + 1:lags + 1 + m], buf[:m], out=h_buf[:m])
        if t0 >= lags and m == rows:
            if full is None:
                full = (np.full(rows, lags + 1.0),)
                full += (float(full[0] @ full[0]),)
            count, count_sq_block = full
        else:
            t = np.arange(t0, t1, dtype=float)
            count = t - np.maximum(t - lags, 0.0) + 1.0
            count_sq_block = float(count @ count)
        hh += h.T @ h
        v += h.T @ count
        count_sq += count_sq_block
        buf[:lags + 1] = buf[m:m + lags + 1]  # c(t1 − L − 1 … t1 − 1) for the next block
    prev = buf[:lags + 1]
    # the tail t = n … n + L − 1: h(t) = c(n − 1) − c(t − L − 1)
    h = carry - prev[:lags]
    t = np.arange(n, n + lags, dtype=float)
    count = (n - 1.0) - np.maximum(t - lags, 0.0) + 1.0
    hh += h.T @ h
    v += h.T @ count
    count_sq += float(count @ count)
    out = hh + np.outer(v, mean) + np.outer(mean, v) + count_sq * np.outer(mean, mean)
    return out / (lags + 1.0)


@functools.lru_cache(maxsize=2)
def _window_sizes(n: int, lags: int) -> tuple[np.ndarray, float]:
    """The moving-sum window sizes of :func:`bartlett_long_run` (``t = 0 … n + lags − 1``)
    and their sum of squares, per ``(n, lags)`` (a fit's three HAC estimates share them);
    read-only."""
    t = np.arange(n + lags)
    count = (np.minimum(t, n - 1) - np.maximum(t - lags, 0) + 1).astype(float)
    count.flags.writeable = False
    return count, count @ count


# --------------------------------------------------------------------------- scores
def scores(
    z: np.ndarray,
    resid: np.ndarray,
    starts: np.ndarray,
    equation: np.ndarray,
    *,
    zero_mean: bool = False,
    skip_first: bool = True,
) -> np.ndarray:
    """Scores ``g(k) = z(k) ε_eq(k)`` (T, P); with ``zero_mean`` the residual is centred
    per experiment (the constant that zero-mean instruments absorb). Skipped rows are 0."""
    resid = np.asarray(resid, dtype=float)
    if resid.ndim == 1:
        resid = resid[:, None]
    segs = _segments(np.asarray(starts), skip_first)
    eps = _residual(resid, segs, zero_mean)
    out = np.zeros(np.shape(z))
    for s in segs:
        out[s] = z[s] * eps[s][:, np.asarray(equation)]
    return out


def _residual(resid: np.ndarray, segs: list[slice], zero_mean: bool) -> np.ndarray:
    if len(segs) == 1 and segs[0].start == 0 and segs[0].stop == resid.shape[0]:
        # one experiment, every row (the fit path): the same numbers in one pass
        return resid - resid.mean(axis=0) if zero_mean else resid.copy()
    eps = np.zeros_like(resid)
    for s in segs:
        eps[s] = resid[s] - resid[s].mean(axis=0) if zero_mean else resid[s]
    return eps


# --------------------------------------------------------------------------- results
@dataclass
class CovarianceResult:
    """Covariance of the estimates and how it was computed.

    Attributes
    ----------
    cov : ndarray (P, P)
        Joint covariance of all parameters (all equations).
    cov_type : str
        Registry name (``"unadjusted"``, ``"hac"``, ``"cluster"``).
    config : dict
        Estimator settings as used (kernel, bandwidth, rule, prewhiten …).
    label : str
        One line for ``summary()``.
    long_run : ndarray (K, K)
        ``Σ_E S_E``, the summed long-run covariance of the scores ``z ε`` (for J tests
        and optimal GMM weights).
    condition : ndarray (n_eq,)
        Condition number of each equation's column-equilibrated ``Σ_E A_E`` (computed
        when first read: the fit path never needs it).
    """

    cov: np.ndarray
    cov_type: str
    config: dict[str, Any] = field(default_factory=dict)
    label: str = ""
    long_run: np.ndarray | None = None
    moment_matrix: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(
        default=None, repr=False, compare=False)

    @property
    def std_errors(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))

    @cached_property
    def condition(self) -> np.ndarray | None:
        if self.moment_matrix is None:
            return None
        a_sum, z_equation, equation = self.moment_matrix
        n_eq = int(equation.max()) + 1 if equation.size else 0
        return np.array([_condition(a_sum[np.ix_(z_equation == i, equation == i)])
                         for i in range(n_eq)])


@dataclass
class _Scores:
    """Column-equilibrated instruments and regressors of one call, with the scores.

    ``z``/``phi`` are divided by ``z_scale``/``phi_scale`` (unit-norm columns over the
    rows used), ``eps`` the residual (centred per experiment with ``zero_mean``) and
    ``g = z ε`` the scores, one column per instrument, zero outside the rows used.
    """

    z: np.ndarray
    phi: np.ndarray
    z_scale: np.ndarray
    phi_scale: np.ndarray
    eps: np.ndarray
    g: np.ndarray
    segs: list[slice]
    equation: np.ndarray
    z_equation: np.ndarray


# --------------------------------------------------------------------------- estimators
class CovarianceEstimator:
    """Base class: the IV sandwich of (4)/(6)/(10); subclasses supply ``S_E``.

    Subclasses set :attr:`name` (and :attr:`description`, the ``summary()`` line of an
    estimator without options) and implement :meth:`meat` (the sum over experiments
    of ``G_E S_E G_Eᵀ`` is formed here). ``__init__`` takes the ``cov_config``
    keywords and validates them; the base class takes none.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    #: Add Windmeijer's (2005) finite-sample correction to two-step GMM estimates whose
    #: design carries ``weight_jacobian`` (``cov_config`` ``windmeijer=False`` turns it off).
    windmeijer: bool = True
    #: With the Windmeijer correction, or a just-identified design that asks for it
    #: (``fixed_b_square``), and a Bartlett kernel: scale each standard error by
    #: the fixed-b critical value at its effective bandwidth ratio over 1.96
    #: (:mod:`vesselid.identify.fixedb`; ``cov_config`` ``fixed_b=False`` turns it off).
    fixed_b: bool = True
    #: Whether :meth:`meat` reads the instruments ``z`` (else it gets None, and the
    #: equilibrated copies of ``z`` and ``φ`` are released before it runs: a long log's
    #: HAC meat then holds only the scores).
    meat_uses_z: ClassVar[bool] = True

    def __init__(self, **config: Any) -> None:
        if config:
            raise CovarianceError(f"cov_type {self.name!r} takes no options, got {sorted(config)}")

    def config(self) -> dict[str, Any]:
        return {}

    def label(self, config: Mapping[str, Any]) -> str:
        return self.description or self.name

    def meat(
        self, g: np.ndarray, z: np.ndarray, eps: np.ndarray, segs: list[slice],
        equation: np.ndarray,
    ) -> tuple[list[np.ndarray], dict[str, Any]]:
        """Per-experiment long-run score covariances ``S_E`` (summed, not averaged)."""
        raise NotImplementedError

    def estimate(
        self,
        z: np.ndarray,
        phi: np.ndarray,
        resid: np.ndarray,
        starts: np.ndarray | None = None,
        equation: np.ndarray | None = None,
        *,
        z_equation: np.ndarray | None = None,
        weight: np.ndarray | None = None,
        zero_mean: bool = False,
        combine: str = "pooled",
        skip_first: bool = True,
        weight_jacobian: np.ndarray | None = None,
        overwrite: bool = False,
        fixed_b_square: bool = False,
    ) -> CovarianceResult:
        """Covariance of the estimates from instruments, regressors and residuals.

        Parameters
        ----------
        z : ndarray (T, K)
            Instruments (LS: the regressors), ``K ≥ P``, rows of all experiments
            concatenated. With ``zero_mean``, ``z`` must already be centred per
            experiment (as the estimator used it).
        phi : ndarray (T, P)
            Regressors, one column per parameter.
        resid : ndarray (T, n) or (T,)
            Residual ``y_i(k) − φ_iᵀ(k) θ̂_i`` of every equation.
        starts : ndarray (S+1,), optional
            Experiment boundaries into the rows (default: one experiment).
        equation : ndarray (P,), optional
            Equation (column of ``resid``) of each parameter (default all 0).
        z_equation : ndarray (K,), optional
            Equation of each instrument column (default ``equation`` when ``K == P``,
            else all 0).
        weight : ndarray (K, K), optional
            GMM weight ``W`` of an over-identified estimate ``θ̂ = argmin ḡᵀ W ḡ``:
            the covariance is ``(AᵀWA)⁻¹ AᵀW S W A (AᵀWA)⁻¹`` (``A = Σ zφᵀ``,
            ``S`` the summed long-run covariance of ``z ε``). Default: identity when
            ``K == P`` (IV), else the 2SLS weight ``(Σ zzᵀ)⁻¹`` (within equations).
        zero_mean : bool
            The instruments were centred per experiment (IV_E{ζ}=0): the scores
            use the residual centred per experiment.
        combine : {"pooled", "stacked"}
            How the estimator combined experiments (module docstring).
        skip_first : bool
            Ignore the first row of every experiment (the package's convention: the
            one-step predictor has no regressors there). ``False`` when the caller
            already dropped those rows.
        weight_jacobian : ndarray (P, P), optional
            Two-step GMM with the weight ``W = Ŝ(θ₁)⁻¹`` estimated from the 2SLS first
            step ``θ₁``: ``D = ∂θ₂/∂θ₁`` through that weight
            (:func:`vesselid.identify.gmm.weight_jacobian`). With :attr:`windmeijer`
            the covariance is Windmeijer's (2005) finite-sample corrected
            ``L S Lᵀ``, ``L = C + D C₁``, where ``C = (AᵀWA)⁻¹AᵀW`` and
            ``C₁ = (AᵀW₁A)⁻¹AᵀW₁`` (``W₁ = (Σ zzᵀ)⁻¹``) map the moments to the two-step
            and first-step estimates (``θ₂ − θ0 ≈ C ḡ + D (θ₁ − θ0)``); with
            ``S = W⁻¹`` it is Windmeijer's ``V + DV + VDᵀ + D V₁ Dᵀ``. Pooled only.
            With :attr:`fixed_b` and a Bartlett kernel (not pre-whitened) each standard
            error is then scaled by ``q(b_p)/1.96``, the fixed-b 95 % critical value at the
            parameter's effective bandwidth ratio (:mod:`vesselid.identify.fixedb`), so
            that ``±1.96 SE`` is the fixed-b interval (``config``: ``effective_b``,
            ``critical_value``).
        fixed_b_square : bool
            Apply the same fixed-b scaling to a pooled just-identified estimate
            (``K == P``, no ``weight``; influence ``A⁻¹``) — the refined IV of
            :class:`vesselid.identify.efficient.InstrumentalGMM` (SRIV) asks for it.
        overwrite : bool
            The caller hands ``z`` over (a float64 array it needs no more): it is
            equilibrated in its own buffer instead of a copy (the same numbers; on a long
            log the copy is as large as the instruments).

        Returns
        -------
        CovarianceResult
            ``cov`` is the covariance of θ̂ itself (sums, not means, inside).

        Raises
        ------
        CovarianceError
            Inconsistent shapes, NaN/inf in the rows used, experiments with fewer
            than two rows.
        """
        if combine not in ("pooled", "stacked"):
            raise CovarianceError(f"combine must be 'pooled' or 'stacked', got {combine!r}")
        if np.shape(z)[0] > LARGE_ROWS:  # one long experiment: every sum in blocks
            blocks = self._estimate_in_blocks(z, phi, resid, starts, equation, z_equation,
                                              weight, zero_mean, combine, skip_first,
                                              weight_jacobian, fixed_b_square)
            if blocks is not None:
                return blocks
        # a long log whose meat needs the scores only: they are formed in the
        # equilibrated instruments' buffer once the sums below have read it (the same
        # products, no second N × K array)
        late = not self.meat_uses_z and np.shape(z)[0] > LARGE_ROWS
        sc = _scores(z, phi, resid, starts, equation, z_equation, zero_mean, skip_first,
                     form_g=not late, overwrite=overwrite)
        z, phi, segs, equation, z_equation = sc.z, sc.phi, sc.segs, sc.equation, sc.z_equation
        n_par, n_ins = phi.shape[1], z.shape[1]
        same = z_equation[:, None] == equation[None, :]
        same_z = z_equation[:, None] == z_equation[None, :]
        a_list = [(z[s].T @ phi[s]) * same for s in segs]
        a_sum = sum(a_list)
        if weight is None:
            if n_ins == n_par:
                # identity in the original units is diag(z_scale²) in the scaled ones; it
                # cancels from the pooled sandwich, so only the stacked form needs it
                stacked = combine == "stacked" and len(segs) > 1
                w_mat = np.diag(sc.z_scale**2) if stacked else np.eye(n_ins)
            else:
                w_mat = _block_inverse(sum(z[s].T @ z[s] for s in segs) * same_z, z_equation)
        else:
            w_mat = np.asarray(weight, dtype=float)
            if w_mat.shape != (n_ins, n_ins) or not np.all(np.isfinite(w_mat)):
                raise CovarianceError(f"weight must be a finite ({n_ins}, {n_ins}) matrix")
            w_mat = w_mat * np.outer(sc.z_scale, sc.z_scale)
        windmeijer = weight_jacobian is not None and self.windmeijer
        w_first = (_block_inverse(sum(z[s].T @ z[s] for s in segs) * same_z, z_equation)
                   if windmeijer and weight is not None and n_ins != n_par else None)
        fixed_b = None
        square_b = self._fixed_b_square(fixed_b_square, weight, n_ins, n_par, combine)
        infl = self._fixed_b_influence(square_b, windmeijer, w_first, weight_jacobian,
                                       a_sum, w_mat, sc.phi_scale, combine)
        if infl is not None:  # before the meat, which may form the scores in z's buffer
            rows = _fixed_b_rows(z, phi, segs, equation, z_equation, zero_mean, infl)
            if rows is not None:
                zl, phi_c = rows

                def fixed_b(cov: np.ndarray, lags: int) -> np.ndarray:
                    from vesselid.identify.fixedb import effective_b

                    return effective_b(zl, phi_c, cov, equation, lags, segs)
        if not self.meat_uses_z:  # the scores carry all the meat needs
            if late:
                every_row = sum(s.stop - s.start for s in segs) == z.shape[0]
                sc.g = _products(z, sc.eps, segs, z_equation, every_row, in_place=True)
            sc.z = sc.phi = z = phi = None
        s_list, used = self.meat(sc.g, z, sc.eps, segs, z_equation)
        n_list = [s.stop - s.start for s in segs]
        return self._sandwich(a_list, a_sum, s_list, n_list, w_mat, w_first, used,
                              weight=weight, weight_jacobian=weight_jacobian,
                              combine=combine, z_scale=sc.z_scale, phi_scale=sc.phi_scale,
                              z_equation=z_equation, equation=equation, fixed_b=fixed_b,
                              square_b=square_b)

    def _fixed_b_kernel(self, combine: str) -> bool:
        """Whether this estimator's intervals may take the fixed-b critical value
        (:attr:`fixed_b`, and :meth:`fixed_b_applies`)."""
        return self.fixed_b and self.fixed_b_applies(combine)

    def fixed_b_applies(self, combine: str) -> bool:
        """Whether the fixed-b critical values are defined for this covariance: a
        Bartlett kernel not pre-whitened, a pooled estimate (whether they are used is
        :attr:`fixed_b`)."""
        return (combine == "pooled" and getattr(self, "kernel", None) == "bartlett"
                and not getattr(self, "prewhiten", False))

    def _fixed_b_square(self, fixed_b_square: bool, weight: Any, n_ins: int, n_par: int,
                        combine: str) -> bool:
        """Whether a just-identified estimate takes the fixed-b scaling."""
        return (fixed_b_square and n_ins == n_par and weight is None
                and self._fixed_b_kernel(combine))

    def _fixed_b_influence(self, square_b: bool, windmeijer: bool, w_first: Any,
                           weight_jacobian: Any, a_sum: np.ndarray, w_mat: np.ndarray,
                           phi_scale: np.ndarray, combine: str) -> np.ndarray | None:
        """The influence matrix (equilibrated units) of an estimate whose intervals take
        the fixed-b critical value: ``C + D C₁`` of a two-step GMM estimate with
        Windmeijer's correction, ``A⁻¹`` of a just-identified one (``square_b``); None
        where the scaling does not apply."""
        n_par = a_sum.shape[1]
        if square_b:
            try:
                return np.linalg.inv(a_sum)
            except np.linalg.LinAlgError:
                return None
        if not (windmeijer and w_first is not None and self._fixed_b_kernel(combine)):
            return None
        d_s = np.asarray(weight_jacobian, dtype=float)
        if d_s.shape != (n_par, n_par) or not np.all(np.isfinite(d_s)):
            return None
        return _influence(a_sum, w_mat, w_first, d_s * np.outer(phi_scale, 1.0 / phi_scale))

    def _sandwich(self, a_list: list[np.ndarray], a_sum: np.ndarray, s_list: list[np.ndarray],
                  n_list: list[int], w_mat: np.ndarray, w_first: np.ndarray | None,
                  used: dict[str, Any], *, weight: np.ndarray | None,
                  weight_jacobian: np.ndarray | None, combine: str, z_scale: np.ndarray,
                  phi_scale: np.ndarray, z_equation: np.ndarray, equation: np.ndarray,
                  fixed_b: Callable[[np.ndarray, int], np.ndarray] | None = None,
                  square_b: bool = False) -> CovarianceResult:
        """The sandwich of :meth:`estimate` from its sums in the equilibrated units:
        ``a_list`` (``Σ_E zφᵀ``), the meat ``s_list`` (``S_E``), the rows ``n_list``, the
        weight ``w_mat`` (and ``w_first``, the first step's, for Windmeijer);
        ``fixed_b(cov, lags)``: the effective bandwidth ratios
        (:func:`vesselid.identify.fixedb.effective_b`) where the standard errors take the
        fixed-b critical value."""
        n_ins, n_par = a_sum.shape
        windmeijer = weight_jacobian is not None and self.windmeijer
        n_segs = len(s_list)
        if weight_jacobian is not None:
            used["windmeijer"] = bool(self.windmeijer)
        if windmeijer:
            d_mat = np.asarray(weight_jacobian, dtype=float)
            if weight is None or n_ins == n_par:
                raise CovarianceError("weight_jacobian needs the weight of an over-identified "
                                      "two-step GMM estimate")
            if combine == "stacked" and n_segs > 1:
                raise CovarianceError("weight_jacobian (Windmeijer) is for pooled estimates")
            if d_mat.shape != (n_par, n_par) or not np.all(np.isfinite(d_mat)):
                raise CovarianceError(f"weight_jacobian must be a finite ({n_par}, {n_par}) "
                                      "matrix")
            # θ_s = D_φ θ: the Jacobian in the equilibrated units
            d_mat = d_mat * np.outer(phi_scale, 1.0 / phi_scale)
            cov = _windmeijer_sandwich(a_sum, s_list, w_mat, w_first, d_mat)
        elif n_ins == n_par and weight is None and (combine == "pooled" or n_segs == 1):
            cov = sandwich_from_sums(a_list, s_list, n_list)
        elif combine == "stacked" and _is_positive_diagonal(w_mat):
            cov = sandwich_from_sums(a_list, s_list, n_list, row_weight=np.diag(w_mat))
        else:
            cov = _general_sandwich(a_list, a_sum, s_list, w_mat, n_list, combine)
        if windmeijer or square_b:
            used["fixed_b"] = bool(self.fixed_b and fixed_b is not None)
        if fixed_b is not None and np.all(np.isfinite(cov)) and "bandwidth" in used:
            from vesselid.identify.fixedb import critical_scaling

            b_eff = fixed_b(cov, math.floor(used["bandwidth"]))
            crit, scale = critical_scaling(b_eff)
            cov = cov * np.outer(scale, scale)
            used["effective_b"] = [float(x) for x in b_eff]
            used["critical_value"] = [float(x) for x in crit]
        if np.all(np.isfinite(cov)):
            cov = cov / np.outer(phi_scale, phi_scale)
        config = {**self.config(), **used}
        label = self.label(config)
        if config.get("windmeijer"):
            label += "; Windmeijer (2005) correction for the estimated two-step GMM weight"
        if config.get("fixed_b") and "critical_value" in config:
            label += ("; standard errors scaled to the fixed-b (Kiefer-Vogelsang 2005) 95 % "
                      "critical value at the effective bandwidth ratio")
        return CovarianceResult(cov=cov, cov_type=self.name, config=config,
                                label=label,
                                long_run=sum(s_list) * np.outer(z_scale, z_scale),
                                moment_matrix=(a_sum, z_equation, equation))

    def _estimate_in_blocks(self, z: Any, phi: Any, resid: Any, starts: np.ndarray | None,
                            equation: np.ndarray | None, z_equation: np.ndarray | None,
                            weight: np.ndarray | None, zero_mean: bool, combine: str,
                            skip_first: bool, weight_jacobian: np.ndarray | None,
                            fixed_b_square: bool = False) -> CovarianceResult | None:
        """:meth:`estimate` of one long experiment whose meat is built from the
        scores alone, every sum over :data:`BLOCK_ROWS` rows at a time (no equilibrated
        ``(T, K)`` copy, no ``(T, K)`` scores); None where that does not apply (the
        caller takes the whole-array path). Sums rounded differently (~1e-14
        relative)."""
        same = phi is z  # LS / the endogeneity regression: instruments = regressors
        if phi is None or np.ndim(phi) != 2 or np.ndim(z) != 2:
            return None
        z = np.asarray(z, dtype=float)
        phi = z if same else np.asarray(phi, dtype=float)
        t_len, n_ins = z.shape
        n_par = phi.shape[1]
        if (phi.shape[0] != t_len or n_ins < n_par
                or (equation is not None and np.any(np.asarray(equation) != 0))
                or not (starts is None or (len(starts) == 2 and int(starts[0]) == 0
                                          and int(starts[-1]) == t_len))
                or not all(np.isfinite(phi[:, j]).all() for j in range(n_par))):
            return None
        if weight is not None:
            weight = np.asarray(weight, dtype=float)
            if weight.shape != (n_ins, n_ins) or not np.all(np.isfinite(weight)):
                return None  # (the whole-array path says why)
        got = self._scaled_long_run_blocks(z, resid, starts, z_equation, zero_mean,
                                           skip_first)
        if got is None:
            return None
        s_u, z_scale, used = got
        phi_scale = z_scale if same else _column_scale(phi, None)
        two_sls = weight is None and n_ins != n_par
        windmeijer = weight_jacobian is not None and self.windmeijer
        need_zz = two_sls or (windmeijer and weight is not None and n_ins != n_par)
        a_sum = np.zeros((n_ins, n_par))
        zz = np.zeros((n_ins, n_ins))
        for a in range(0, t_len, BLOCK_ROWS):
            zb = z[a:a + BLOCK_ROWS] / z_scale
            a_sum += zb.T @ (zb if same else phi[a:a + BLOCK_ROWS] / phi_scale)
            if need_zz:
                zz += zb.T @ zb
        eq = np.zeros(n_ins, dtype=np.int64)
        if weight is None:
            w_mat = np.eye(n_ins) if n_ins == n_par else _block_inverse(zz, eq)
        else:
            w_mat = weight * np.outer(z_scale, z_scale)
        w_first = _block_inverse(zz, eq) if need_zz and not two_sls else None
        square_b = self._fixed_b_square(fixed_b_square, weight, n_ins, n_par, combine)
        infl = self._fixed_b_influence(square_b, windmeijer, w_first, weight_jacobian,
                                       a_sum, w_mat, phi_scale, combine)
        fixed_b = None
        if infl is not None and np.all(np.isfinite(infl)):
            seg = _segments(np.array([0, t_len]), skip_first)[0]

            def fixed_b(cov: np.ndarray, lags: int) -> np.ndarray:
                return _effective_b_in_blocks(z, None if same else phi, z_scale, phi_scale,
                                              infl, zero_mean, seg, cov, lags)

        return self._sandwich([a_sum], a_sum, [s_u], [t_len], w_mat, w_first, used,
                              weight=weight, weight_jacobian=weight_jacobian,
                              combine=combine, z_scale=z_scale, phi_scale=phi_scale,
                              z_equation=eq, equation=np.zeros(n_par, dtype=np.int64),
                              fixed_b=fixed_b, square_b=square_b)

    def _scaled_long_run_blocks(self, z: Any, resid: Any, starts: np.ndarray | None,
                                z_equation: np.ndarray | None, zero_mean: bool,
                                skip_first: bool
                                ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]] | None:
        """The block-wise long run of :meth:`_long_run_in_blocks` in the equilibrated
        units, with the column scales: ``(S, scale, settings)``; None where it does not
        apply."""
        return None

    def long_run(
        self,
        z: np.ndarray,
        resid: np.ndarray,
        starts: np.ndarray | None = None,
        *,
        z_equation: np.ndarray | None = None,
        zero_mean: bool = False,
        skip_first: bool = True,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """``Σ_E S_E`` of the scores ``z ε`` in the units of ``z``, and the settings used.

        The ``long_run`` of :meth:`estimate` (the same numbers) without the sandwich:
        what a J test or an optimal GMM weight needs. Arguments as :meth:`estimate`
        (``z_equation`` default: all instruments in equation 0).
        """
        if np.shape(z)[0] > LARGE_ROWS:
            blocks = self._long_run_in_blocks(z, resid, starts, z_equation, zero_mean,
                                              skip_first)
            if blocks is not None:
                return blocks
        sc = _scores(z, None, resid, starts, None, z_equation, zero_mean, skip_first,
                     keep_z=self.meat_uses_z)  # else the scores carry all the meat needs
        s_list, used = self.meat(sc.g, sc.z, sc.eps, sc.segs, sc.z_equation)
        return sum(s_list) * np.outer(sc.z_scale, sc.z_scale), {**self.config(), **used}

    def _long_run_in_blocks(self, z: Any, resid: Any, starts: np.ndarray | None,
                            z_equation: np.ndarray | None, zero_mean: bool,
                            skip_first: bool) -> tuple[np.ndarray, dict[str, Any]] | None:
        """:meth:`long_run` of one long experiment whose meat is built from the scores
        alone, with the scores formed :data:`BLOCK_ROWS` rows at a time (no equilibrated
        ``(T, K)`` copy, no ``(T, K)`` scores); None where that does not apply (the
        caller takes the whole-array path). The same rows of scores; sums rounded
        differently (~1e-14 relative)."""
        return None

    def cov(self, z: np.ndarray, phi: np.ndarray, resid: np.ndarray,
            starts: np.ndarray | None = None, **options: Any) -> np.ndarray:
        """Shortcut: ``estimate(...).cov``."""
        return self.estimate(z, phi, resid, starts, **options).cov


def _scores(z: np.ndarray, phi: np.ndarray | None, resid: np.ndarray,
            starts: np.ndarray | None, equation: np.ndarray | None,
            z_equation: np.ndarray | None, zero_mean: bool, skip_first: bool,
            keep_z: bool = True, form_g: bool = True, overwrite: bool = False) -> _Scores:
    """Validate the arrays of :meth:`CovarianceEstimator.estimate` and form the scores
    (``phi=None``: instruments only, as :meth:`CovarianceEstimator.long_run`); without
    ``keep_z`` the scores are formed in the equilibrated instruments' buffer (the same
    products) and ``z`` is None; without ``form_g`` the scores are left to the caller
    (``g`` None: :func:`_products` once ``z`` has served every other sum); ``overwrite``:
    ``z`` (the caller's, handed over) is equilibrated in its own buffer."""
    same = phi is z  # LS / the endogeneity regression: instruments = regressors
    z = np.asarray(z, dtype=float)
    resid = np.asarray(resid, dtype=float)
    if resid.ndim == 1:
        resid = resid[:, None]
    if z.ndim != 2:
        raise CovarianceError("z and phi must be 2-d arrays (rows × columns)")
    t_len = z.shape[0]
    phi = (np.zeros((t_len, 0)) if phi is None else z if same
           else np.asarray(phi, dtype=float))
    if phi.ndim != 2:
        raise CovarianceError("z and phi must be 2-d arrays (rows × columns)")
    n_par = phi.shape[1]
    n_ins = z.shape[1]
    if phi.shape[0] != t_len or resid.shape[0] != t_len or n_ins < n_par:
        raise CovarianceError(f"z {z.shape}, phi {phi.shape} and resid {resid.shape} "
                              "must have the same rows and z at least phi's columns")
    starts = np.array([0, t_len]) if starts is None else np.asarray(starts, dtype=np.int64)
    if starts[0] != 0 or starts[-1] != t_len or np.any(np.diff(starts) < 0):
        raise CovarianceError("starts must rise from 0 to the number of rows")
    equation = (np.zeros(n_par, dtype=np.int64) if equation is None
                else np.asarray(equation, dtype=np.int64))
    if z_equation is None:
        z_equation = equation if n_ins == n_par else np.zeros(n_ins, dtype=np.int64)
    z_equation = np.asarray(z_equation, dtype=np.int64)
    if (equation.shape != (n_par,) or z_equation.shape != (n_ins,)
            or max(equation.max(initial=0), z_equation.max(initial=0)) >= resid.shape[1]):
        raise CovarianceError("equation / z_equation must give a residual column for every "
                              "regressor / instrument column")
    segs = _segments(starts, skip_first)
    if any(s.stop - s.start < 2 for s in segs):
        raise CovarianceError("every experiment needs at least two usable rows")
    rows = np.zeros(t_len, dtype=bool)
    for s in segs:
        rows[s] = True
    every_row = bool(rows.all())  # the fit path drops the first rows itself: no copies
    for name, arr in (("z", z), ("phi", phi), ("resid", resid)):
        if (name != "phi" or not same) and not np.all(np.isfinite(arr if every_row
                                                                  else arr[rows])):
            raise CovarianceError(f"{name} holds NaN or inf in the rows used")
    # Equilibrate: unit-norm instrument and regressor columns (over the rows used), so
    # that badly scaled signals (forces in N next to velocities in m/s, or every signal
    # times 1e±6) lose no precision in the sandwich below. The estimator is equivariant:
    # θ_s = D_φ θ, ḡ_s = D_z⁻¹ ḡ, W_s = D_z W D_z, so Cov θ̂ = D_φ⁻¹ Cov θ̂_s D_φ⁻¹.
    z_scale = _column_scale(z, None if every_row else rows)
    phi_scale = z_scale if same else _column_scale(phi, None if every_row else rows)
    z = (np.divide(z, z_scale, out=z) if overwrite and z.flags.writeable
         else z / z_scale)
    # the same numbers either way; a copy all the same (a product of one buffer with
    # itself would take BLAS's symmetric rank-k path, rounded differently)
    # (above LARGE_ROWS rows the one buffer serves both: no second N × P copy, the
    # products rounded by the symmetric path)
    phi = ((z if t_len > LARGE_ROWS and keep_z else z.copy()) if same
           else phi / phi_scale)
    eps = _residual(resid, segs, zero_mean)
    # (in the equilibrated copy's buffer when the caller needs no z: same products)
    g = _products(z, eps, segs, z_equation, every_row, in_place=not keep_z) if form_g else None
    if not keep_z:
        z = phi = None
    return _Scores(z=z, phi=phi, z_scale=z_scale, phi_scale=phi_scale, eps=eps, g=g,
                   segs=segs, equation=equation, z_equation=z_equation)


def _products(z: np.ndarray, eps: np.ndarray, segs: list[slice], z_equation: np.ndarray,
              every_row: bool, in_place: bool) -> np.ndarray:
    """The scores ``g = z ε`` of :func:`_scores` (zero outside ``segs``); ``in_place``:
    in ``z``'s buffer (the equilibrated copy, which the caller needs no more)."""
    one = eps.shape[1] == 1  # every instrument in equation 0: broadcast, no column copies
    if every_row and len(segs) == 1:  # the products themselves, without a zeroed copy
        return np.multiply(z, eps if one else eps[:, z_equation], out=z if in_place else None)
    if in_place:
        rows = np.zeros(z.shape[0], dtype=bool)
        for s in segs:
            rows[s] = True
            z[s] *= eps[s] if one else eps[s][:, z_equation]
        z[~rows] = 0.0
        return z
    g = np.zeros(z.shape)
    for s in segs:
        g[s] = z[s] * (eps[s] if one else eps[s][:, z_equation])
    return g


def sandwich_from_sums(a_list: list[np.ndarray], s_list: list[np.ndarray], n_list: list[int],
                       *, row_weight: np.ndarray | None = None) -> np.ndarray:
    """Covariance of a just-identified IV estimate from per-experiment sums.

    ``a_list`` holds ``A_E = Σ_k z φᵀ`` and ``s_list`` the long-run score covariances
    ``S_E`` of every experiment, both on column-equilibrated instruments and regressors
    (the covariance comes back in those units). Without ``row_weight``: the pooled
    ``A_Σ⁻¹ (Σ_E S_E) A_Σ⁻ᵀ`` (``H⁻¹ A_Σᵀ = A_Σ⁻¹``, so the condition number of ``A_Σ``
    enters once, not squared as in ``H = A_ΣᵀA_Σ``). With the diagonal ``row_weight`` of
    the stacked form (6)/(10): :func:`_stacked_qr_sandwich`. Used by
    :meth:`CovarianceEstimator.estimate` and by the streamed identification, which
    gathers the same sums one experiment at a time. A singular or non-finite result is
    an all-``inf`` matrix.
    """
    k = a_list[0].shape[1]
    try:
        if row_weight is None:
            a_inv = np.linalg.inv(sum(a_list))
            cov = a_inv @ sum(s_list) @ a_inv.T
        else:
            cov = _stacked_qr_sandwich(a_list, s_list, row_weight, n_list)
        cov = 0.5 * (cov + cov.T)
    except np.linalg.LinAlgError:
        return np.full((k, k), np.inf)
    return cov if np.all(np.isfinite(cov)) else np.full((k, k), np.inf)


def _general_sandwich(a_list: list[np.ndarray], a_sum: np.ndarray, s_list: list[np.ndarray],
                      w_mat: np.ndarray, n_list: list[int], combine: str) -> np.ndarray:
    """``H⁻¹ (Σ_E G_E S_E G_Eᵀ) H⁻ᵀ`` with ``G_E = AᵀW`` (pooled) or ``A_EᵀW / N_E²``
    (stacked) and ``H = Σ_E G_E A_E`` (module docstring); all-``inf`` when singular."""
    if combine == "pooled" or len(a_list) == 1:
        g_list = [a_sum.T @ w_mat] * len(a_list)
    else:
        g_list = [a.T @ w_mat / n**2 for a, n in zip(a_list, n_list, strict=True)]
    h = sum(gm @ a for gm, a in zip(g_list, a_list, strict=True))
    middle = sum(gm @ s_e @ gm.T for gm, s_e in zip(g_list, s_list, strict=True))
    k = h.shape[0]
    try:
        h_inv = np.linalg.inv(h)
    except np.linalg.LinAlgError:
        return np.full((k, k), np.inf)
    cov = h_inv @ middle @ h_inv.T
    cov = 0.5 * (cov + cov.T)
    return cov if np.all(np.isfinite(cov)) else np.full((k, k), np.inf)


def _influence(a_sum: np.ndarray, w_mat: np.ndarray, w_first: np.ndarray,
               d_mat: np.ndarray) -> np.ndarray | None:
    """``L = C + D C₁`` of :func:`_windmeijer_sandwich` (``θ̂ − θ0 ≈ L Σ g``); None
    when singular."""
    try:
        aw = a_sum.T @ w_mat
        aw1 = a_sum.T @ w_first
        return np.linalg.solve(aw @ a_sum, aw) + d_mat @ np.linalg.solve(aw1 @ a_sum, aw1)
    except np.linalg.LinAlgError:
        return None


def _effective_b_in_blocks(z: np.ndarray, phi: np.ndarray | None, z_scale: np.ndarray,
                           phi_scale: np.ndarray, infl: np.ndarray, zero_mean: bool,
                           seg: slice, cov: np.ndarray, lags: int) -> np.ndarray:
    """:func:`vesselid.identify.fixedb.effective_b` of one experiment (rows ``seg``, one
    equation) with every row formed block by block from the caller's instruments and
    regressors (``phi`` None: the instruments), in the equilibrated units: the same
    ratios as :func:`_fixed_b_rows` and ``effective_b`` on the whole arrays, to
    rounding."""
    from vesselid.identify.fixedb import influence_directions

    def regressors(a: int, b: int) -> np.ndarray:
        return (z[a:b] / z_scale) if phi is None else (phi[a:b] / phi_scale)

    n_rows = seg.stop - seg.start
    mean = None
    if zero_mean:
        mean = sum(regressors(a, min(a + BLOCK_ROWS, seg.stop)).sum(axis=0)
                   for a in range(seg.start, seg.stop, BLOCK_ROWS)) / n_rows
    u, ok = influence_directions(cov)

    def scores(a: int, b: int) -> np.ndarray:
        a, b = a + seg.start, b + seg.start
        pb = regressors(a, b)
        if mean is not None:
            pb = pb - mean
        return ((z[a:b] / z_scale) @ infl.T) * (pb @ u)

    n_par = cov.shape[0]
    # the Bartlett sums of the scores s(k) themselves (moving sums of s − 0)
    b_eff = np.diag(bartlett_block_sums(scores, n_rows, n_par, np.zeros(n_par), lags,
                                        BLOCK_ROWS)).copy()
    return np.where(ok & np.isfinite(b_eff), b_eff, 0.0)


def _fixed_b_rows(z: np.ndarray, phi: np.ndarray, segs: list[slice], equation: np.ndarray,
                  z_equation: np.ndarray, zero_mean: bool, infl: np.ndarray | None
                  ) -> tuple[list[np.ndarray] | np.ndarray, np.ndarray] | None:
    """The rows :func:`vesselid.identify.fixedb.effective_b` needs: the instruments
    projected on the influence rows (one (T, P) array when every parameter's influence
    row stays within its own equation's instruments, as for estimates per equation;
    else one per equation), and the regressors centred per experiment where the
    residuals are (``zero_mean``); zero outside the rows used."""
    if infl is None or not np.all(np.isfinite(infl)):
        return None
    n_eq = int(max(equation.max(initial=0), z_equation.max(initial=0))) + 1
    own = equation[:, None] == z_equation[None, :]
    phi_c = np.zeros_like(phi)
    if not np.any(infl[~own]):
        zl = np.zeros((z.shape[0], phi.shape[1]))
        for s in segs:
            for e in range(n_eq):
                cols, pars = z_equation == e, equation == e
                if cols.any() and pars.any():
                    zl[s, pars] = z[s][:, cols] @ infl[np.ix_(pars, cols)].T
            phi_c[s] = phi[s] - phi[s].mean(axis=0) if zero_mean else phi[s]
        return zl, phi_c
    zls = [np.zeros((z.shape[0], phi.shape[1])) for _ in range(n_eq)]
    for s in segs:
        for e in range(n_eq):
            cols = z_equation == e
            if cols.any():
                zls[e][s] = z[s][:, cols] @ infl[:, cols].T
        phi_c[s] = phi[s] - phi[s].mean(axis=0) if zero_mean else phi[s]
    return zls, phi_c


def _windmeijer_sandwich(a_sum: np.ndarray, s_list: list[np.ndarray], w_mat: np.ndarray,
                         w_first: np.ndarray, d_mat: np.ndarray) -> np.ndarray:
    """Windmeijer (2005) corrected covariance of a pooled two-step GMM estimate:
    ``L (Σ_E S_E) Lᵀ`` with ``L = C + D C₁``, ``C = (AᵀWA)⁻¹AᵀW``,
    ``C₁ = (AᵀW₁A)⁻¹AᵀW₁`` (see :meth:`CovarianceEstimator.estimate`); all-``inf`` when
    singular."""
    k = a_sum.shape[1]
    infl = _influence(a_sum, w_mat, w_first, d_mat)
    if infl is None:
        return np.full((k, k), np.inf)
    cov = infl @ sum(s_list) @ infl.T
    cov = 0.5 * (cov + cov.T)
    return cov if np.all(np.isfinite(cov)) else np.full((k, k), np.inf)


def _is_positive_diagonal(w: np.ndarray) -> bool:
    return bool(np.all(np.diag(w) > 0) and np.count_nonzero(w - np.diag(np.diag(w))) == 0)


def _stacked_qr_sandwich(a_list: list[np.ndarray], s_list: list[np.ndarray],
                         w_diag: np.ndarray, n_list: list[int]) -> np.ndarray:
    """``H⁻¹ (Σ_E G_E S_E G_Eᵀ) H⁻ᵀ`` of the stacked form without forming ``H``.

    With ``B = [W^½ A_E / N_E]_E = QR`` (reduced QR), ``H = BᵀB = RᵀR`` and
    ``H⁻¹ G_E = R⁻¹ Q_Eᵀ W^½ / N_E``, so the covariance is ``R⁻¹ (Σ_E C_E S_E C_Eᵀ) R⁻ᵀ``
    with ``C_E = Q_Eᵀ W^½ / N_E``: the condition number of ``B`` enters once, not squared.
    """
    root = np.sqrt(w_diag)
    b = np.vstack([root[:, None] * a / n for a, n in zip(a_list, n_list, strict=True)])
    q, r = np.linalg.qr(b)
    k = root.size
    middle = np.zeros((r.shape[0], r.shape[0]))
    for e, (s_e, n) in enumerate(zip(s_list, n_list, strict=True)):
        c = q[e * k:(e + 1) * k].T * root[None, :] / n
        middle += c @ s_e @ c.T
    x = np.linalg.solve(r, middle)
    return np.linalg.solve(r, x.T)


def _column_scale(x: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
    """Euclidean norm of every column over ``rows`` (None: all; 1 for an all-zero column)."""
    xr = x if rows is None else x[rows]
    scale = np.sqrt(np.einsum("tk,tk->k", xr, xr))
    return np.where((scale > 0) & np.isfinite(scale), scale, 1.0)


def _block_inverse(m: np.ndarray, eq: np.ndarray) -> np.ndarray:
    out = np.zeros_like(m)
    for i in np.unique(eq):
        idx = np.flatnonzero(eq == i)
        out[np.ix_(idx, idx)] = np.linalg.pinv(m[np.ix_(idx, idx)])
    return out


def _condition(a: np.ndarray) -> float:
    from vesselid.identify.diagnostics import condition_number

    return condition_number(a)


class UnadjustedCovariance(CovarianceEstimator):
    """White, homoskedastic equation errors: ``S_E = Σ_k z(k) z(k)ᵀ ⊙ Σ_ε``.

    ``Σ_ε`` is the residual (co)variance over all experiments (centred per
    experiment when ``zero_mean``), divided by the number of rows (no degrees-of-
    freedom correction, as linearmodels' ``debiased=False``).
    """

    name = "unadjusted"
    description = "unadjusted (white, homoskedastic equation error)"

    def meat(self, g, z, eps, segs, equation):
        n_rows = sum(s.stop - s.start for s in segs)
        sig = sum(eps[s].T @ eps[s] for s in segs) / n_rows
        sig_p = sig[np.ix_(equation, equation)]  # equation of each instrument column
        return [(z[s].T @ z[s]) * sig_p for s in segs], {}


class KernelCovariance(CovarianceEstimator):
    """HAC: kernel-weighted long-run covariance of the scores within each experiment.

    Parameters (``cov_config``)
    ---------------------------
    kernel : {"bartlett", "parzen", "qs"}
        Kernel (aliases ``"newey-west"``, ``"gallant"``, ``"quadratic-spectral"``,
        ``"andrews"`` as in linearmodels).
    bandwidth : float or {"newey-west", "andrews"}
        Fixed bandwidth (:func:`kernel_weights` convention) or an automatic rule
        (default ``"newey-west"``: the Andrews AR(1) plug-in misses the slow part of
        scores that mix the white MA(1) sensor-noise error with a coloured current,
        see docs/guide/uncertainty.md)
        (:func:`automatic_bandwidth`), computed from the scores of all experiments
        (after pre-whitening if on).
    prewhiten : bool
        Fit a VAR(1) ``g(k) = B g(k−1) + u(k)`` within experiments, apply the kernel
        to ``u`` and recolour with ``(I − B)⁻¹`` (Andrews & Monahan 1992; the
        eigenvalues of ``B`` are shrunk to at most 0.97).
    """

    name = "hac"

    meat_uses_z: ClassVar[bool] = False
    def __init__(self, kernel: str = "bartlett", bandwidth: float | str = "newey-west",
                 prewhiten: bool = False) -> None:
        self.kernel = _kernel_name(kernel)
        if isinstance(bandwidth, str):
            if bandwidth not in BANDWIDTH_RULES:
                raise CovarianceError(f"bandwidth must be a number or one of "
                                      f"{list(BANDWIDTH_RULES)}, got {bandwidth!r}")
        else:
            try:
                value = float(bandwidth)
            except (TypeError, ValueError):
                raise CovarianceError(f"bandwidth must be a number or one of "
                                      f"{list(BANDWIDTH_RULES)}, got {bandwidth!r}") from None
            if not (value >= 0 and math.isfinite(value)):
                raise CovarianceError(f"bandwidth must be finite and non-negative, got {value}")
            bandwidth = value
        self.bandwidth = bandwidth
        if not isinstance(prewhiten, bool | np.bool_):
            raise CovarianceError(f"prewhiten must be True or False, got {prewhiten!r}")
        self.prewhiten = bool(prewhiten)

    def config(self) -> dict[str, Any]:
        return {"kernel": self.kernel, "prewhiten": self.prewhiten,
                "bandwidth_rule": self.bandwidth if isinstance(self.bandwidth, str) else "fixed"}

    def label(self, config: Mapping[str, Any]) -> str:
        rule = config.get("bandwidth_rule")
        how = {"andrews": "Andrews (1991) AR(1) rule", "newey-west": "Newey-West (1994) rule",
               "fixed": "fixed"}.get(str(rule), str(rule))
        pw = ", VAR(1) pre-whitened" if config.get("prewhiten") else ""
        return (f"HAC ({_KERNEL_LABELS[self.kernel]} kernel, bandwidth "
                f"{config.get('bandwidth', float('nan')):.3g} by {how}{pw}, within experiments)")

    def _long_run_in_blocks(self, z, resid, starts, z_equation, zero_mean, skip_first):
        got = self._scaled_long_run_blocks(z, resid, starts, z_equation, zero_mean,
                                           skip_first)
        if got is None:
            return None
        s_u, z_scale, used = got
        return s_u * np.outer(z_scale, z_scale), used

    def sums_in_blocks(self) -> bool:
        """Whether the block-wise long run applies: the Bartlett kernel with a
        Newey-West or fixed lag, not pre-whitened."""
        return not (self.kernel != "bartlett" or self.prewhiten
                    or (isinstance(self.bandwidth, str) and self.bandwidth != "newey-west"))

    def _scaled_long_run_blocks(self, z, resid, starts, z_equation, zero_mean, skip_first):
        if not self.sums_in_blocks():
            return None  # the blocks cover the Bartlett kernel with a Newey-West/fixed lag
        z = np.asarray(z, dtype=float)
        resid = np.asarray(resid, dtype=float)
        resid = resid[:, None] if resid.ndim == 1 else resid
        t_len = z.shape[0]
        if (z.ndim != 2 or resid.shape != (t_len, 1) or skip_first
                or not (starts is None or len(starts) == 2)
                or (z_equation is not None and np.any(np.asarray(z_equation) != 0))):
            return None  # one experiment, every row, one equation: else the general path
        if t_len < 2 or not (np.all(np.isfinite(z)) and np.all(np.isfinite(resid))):
            return None  # (the general path says why)
        segs = [slice(0, t_len)]
        z_scale = _column_scale(z, None)
        # (raw residuals are read in place: the same numbers as _residual's copy)
        eps = _residual(resid, segs, zero_mean)[:, 0] if zero_mean else resid[:, 0]
        return self._bartlett_of_rows(lambda a, b: z[a:b], t_len, z.shape[1], z_scale, eps)

    def _bartlett_of_rows(self, rows_of: Callable[[int, int], np.ndarray], t_len: int,
                          q: int, z_scale: np.ndarray, eps: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]] | None:
        """The block-wise long run of the scores ``(z / z_scale) ε`` whose instrument
        rows ``a … b − 1`` are ``rows_of(a, b)`` (:meth:`_scaled_long_run_blocks`)."""
        spans = [(a, min(a + BLOCK_ROWS, t_len)) for a in range(0, t_len, BLOCK_ROWS)]

        def block(a: int, b: int) -> np.ndarray:  # the rows a … b − 1 of g = (z / s) ε
            return np.multiply(rows_of(a, b) / z_scale, eps[a:b, None])

        used: dict[str, Any] = {}
        total = None  # the scores' column sums, from the bandwidth's pass where it has one
        if isinstance(self.bandwidth, str):  # Newey-West (1994) on the scores' blocks
            sq, total = 0, 0
            for a, b in spans:
                g = block(a, b)
                sq = sq + np.einsum("tk,tk->k", g, g)
                total = total + g.sum(axis=0)
            scale = np.sqrt(sq / t_len)
            scale[scale == 0] = 1.0
            x = np.empty(t_len)  # the scaled row sums, block by block
            for a, b in spans:
                x[a:b] = _row_sums(block(a, b), scale) if q > 1 else block(a, b)[:, 0]
            bw = float(min(_newey_west_from_sums([x], self.kernel, t_len),
                           float(max(t_len - 1, 0))))
        else:
            bw = float(self.bandwidth)
        used["bandwidth"] = bw
        lags = math.floor(bw)
        if min(lags + 1, t_len - 1) <= 1:
            return None  # a bandwidth below one lag: the general path
        if total is None:
            total = sum(block(a, b).sum(axis=0) for a, b in spans)
        mean = total / t_len
        s_u = bartlett_block_sums(block, t_len, q, mean, lags, BLOCK_ROWS)
        return s_u, z_scale, {**self.config(), **used}

    def meat(self, g, z, eps, segs, equation):
        q = g.shape[1]
        recolour = np.eye(q)
        series = g
        used: dict[str, Any] = {}
        if self.prewhiten:
            series, recolour, b_mat = _prewhiten(g, segs)
            used["var1_spectral_radius"] = float(np.max(np.abs(np.linalg.eigvals(b_mat))))
        if isinstance(self.bandwidth, str):
            bw = automatic_bandwidth(_compact(series, segs), _compact_starts(segs),
                                     kernel=self.kernel, rule=self.bandwidth)
        else:
            bw = float(self.bandwidth)
        used["bandwidth"] = bw
        longest = max(s.stop - s.start for s in segs)
        n_lags = (longest - 1 if self.kernel == "qs" else min(math.floor(bw) + 1, longest - 1))
        w = kernel_weights(self.kernel, bw, n_lags)
        out = []
        for s in segs:
            if self.kernel == "bartlett" and n_lags > 1:
                s_u = bartlett_long_run(series[s], math.floor(bw))
            else:
                s_u = long_run_covariance(series[s], w)
            out.append(s_u if not self.prewhiten else recolour @ s_u @ recolour.T)
        return out, used


def ls_covariance_of_rows(est: CovarianceEstimator, rows_of: Callable[[int, int], np.ndarray],
                          t_len: int, q: int, resid: np.ndarray) -> np.ndarray | None:
    """The covariance ``est.estimate(x, x, resid, skip_first=False)`` of least squares
    on one long experiment whose regressor rows ``a … b − 1`` are ``rows_of(a, b)``
    (never formed whole): the equilibration, the sandwich's sums and the Bartlett meat
    over blocks of :data:`BLOCK_ROWS` rows. None where that does not apply (another
    kernel or estimator, non-finite rows, a bandwidth below one lag)."""
    if not (isinstance(est, KernelCovariance) and est.sums_in_blocks()) or t_len < 2:
        return None
    spans = [(a, min(a + BLOCK_ROWS, t_len)) for a in range(0, t_len, BLOCK_ROWS)]
    sq = np.zeros(q)
    for a, b in spans:
        x = rows_of(a, b)
        if not np.all(np.isfinite(x)):
            return None
        sq += np.einsum("tk,tk->k", x, x)
    scale = np.sqrt(sq)
    scale = np.where((scale > 0) & np.isfinite(scale), scale, 1.0)
    eps = np.asarray(resid, dtype=float).reshape(-1)
    if eps.shape != (t_len,) or not np.all(np.isfinite(eps)):
        return None
    got = est._bartlett_of_rows(rows_of, t_len, q, scale, eps)
    if got is None:
        return None
    s_u, _, used = got
    a_sum = np.zeros((q, q))
    for a, b in spans:
        xb = rows_of(a, b) / scale
        a_sum += xb.T @ xb
    eq = np.zeros(q, dtype=np.int64)
    return est._sandwich([a_sum], a_sum, [s_u], [t_len], np.eye(q), None, used, weight=None,
                         weight_jacobian=None, combine="pooled", z_scale=scale,
                         phi_scale=scale, z_equation=eq, equation=eq).cov


def _compact(x: np.ndarray, segs: list[slice]) -> np.ndarray:
    """The rows of ``segs`` concatenated (``x`` itself when they are all of its rows)."""
    if segs[0].start == 0 and segs[-1].stop == x.shape[0] and all(
            a.stop == b.start for a, b in itertools.pairwise(segs)):
        return x
    return np.concatenate([x[s] for s in segs])


def _compact_starts(segs: list[slice]) -> np.ndarray:
    return np.concatenate([[0], np.cumsum([s.stop - s.start for s in segs])])


def _prewhiten(g: np.ndarray, segs: list[slice]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """VAR(1) pre-whitening within experiments; returns (u, (I − B)⁻¹, B)."""
    q = g.shape[1]
    xx = np.zeros((q, q))
    xy = np.zeros((q, q))
    for s in segs:
        x = g[s]
        xx += x[:-1].T @ x[:-1]
        xy += x[:-1].T @ x[1:]
    b_t, *_ = np.linalg.lstsq(xx, xy, rcond=None)
    b_mat = b_t.T
    # shrink to a spectral norm ≤ 0.97 (Andrews & Monahan's adjustment, via the SVD)
    u_, sv, vt = np.linalg.svd(b_mat)
    if sv.max() > 0.97:
        b_mat = u_ @ np.diag(np.minimum(sv, 0.97)) @ vt
    out = np.zeros_like(g)
    for s in segs:
        x = g[s]
        out[s.start] = x[0]
        out[s.start + 1 : s.stop] = x[1:] - x[:-1] @ b_mat.T
    recolour = np.linalg.inv(np.eye(q) - b_mat)
    return out, recolour, b_mat


class ClusterCovariance(CovarianceEstimator):
    """One cluster per experiment: ``S_E = (Σ_k g_E)(Σ_k g_E)ᵀ``.

    Robust to any dependence within an experiment, but it needs many experiments
    (its ``S`` has rank at most the number of experiments); no small-sample
    correction.
    """

    name = "cluster"
    description = "clustered by experiment"

    meat_uses_z: ClassVar[bool] = False

    def meat(self, g, z, eps, segs, equation):
        if len(segs) < 2:
            raise CovarianceError("cov_type 'cluster' needs at least two experiments")
        out = []
        for s in segs:
            tot = g[s].sum(axis=0)
            out.append(np.outer(tot, tot))
        return out, {"clusters": len(segs)}


#: Covariance estimators by name (``cov_type``).
COVARIANCE_ESTIMATORS: dict[str, type[CovarianceEstimator]] = {
    "unadjusted": UnadjustedCovariance,
    "hac": KernelCovariance,
    "cluster": ClusterCovariance,
}


def get_covariance_estimator(cov_type: str = DEFAULT_COV_TYPE, **cov_config: Any
                             ) -> CovarianceEstimator:
    """The estimator registered as ``cov_type``, built (and validated) from ``cov_config``.

    Raises
    ------
    CovarianceError
        Unknown ``cov_type`` or invalid options (a ``ValueError``).
    """
    if cov_type not in COVARIANCE_ESTIMATORS:
        raise CovarianceError(f"unknown cov_type {cov_type!r}; choose from "
                              f"{list(COVARIANCE_ESTIMATORS)}")
    cov_config = dict(cov_config)
    windmeijer = cov_config.pop("windmeijer", True)
    if not isinstance(windmeijer, bool | np.bool_):
        raise CovarianceError(f"windmeijer must be True or False, got {windmeijer!r}")
    fixed_b = cov_config.pop("fixed_b", True)
    if not isinstance(fixed_b, bool | np.bool_):
        raise CovarianceError(f"fixed_b must be True or False, got {fixed_b!r}")
    try:
        est = COVARIANCE_ESTIMATORS[cov_type](**cov_config)
    except TypeError as exc:
        raise CovarianceError(f"invalid options for cov_type {cov_type!r}: {exc}") from None
    est.windmeijer = bool(windmeijer)
    est.fixed_b = bool(fixed_b)
    return est


def iv_covariance(z: np.ndarray, phi: np.ndarray, resid: np.ndarray,
                  starts: np.ndarray | None = None, equation: np.ndarray | None = None, *,
                  cov_type: str = DEFAULT_COV_TYPE, z_equation: np.ndarray | None = None,
                  weight: np.ndarray | None = None, zero_mean: bool = False,
                  combine: str = "pooled", skip_first: bool = True,
                  weight_jacobian: np.ndarray | None = None,
                  **cov_config: Any) -> CovarianceResult:
    """One call: :func:`get_covariance_estimator` then
    :meth:`CovarianceEstimator.estimate` (see there for the arguments)."""
    est = get_covariance_estimator(cov_type, **cov_config)
    return est.estimate(z, phi, resid, starts, equation, z_equation=z_equation, weight=weight,
                        zero_mean=zero_mean, combine=combine, skip_first=skip_first,
                        weight_jacobian=weight_jacobian)
