"""Online (recursive) least squares and instrumental variables with a forgetting factor.

The recursions solve, at every sample ``k``, the exponentially weighted estimating
equations of the batch estimators

* RLS: ``(Σ_i λ^{k-i} φ(i) φ(i)ᵀ) θ = Σ_i λ^{k-i} φ(i) y(i)`` (paper (16) with forgetting);
* RIV: ``(Σ_i λ^{k-i} ζ(i) φ(i)ᵀ) θ = Σ_i λ^{k-i} ζ(i) y(i)`` (paper (4) with forgetting),

one state equation at a time, with the matrix-inversion-lemma update (Ljung & Söderström
1983, Young 2011 §6)::

    g = P ζ / (λ + φᵀ P ζ),   θ ← θ + g (y − φᵀ θ),   P ← (P − g φᵀ P) / λ

— O(p²) operations per sample and equation (``p`` its parameters), in one compiled
kernel with no Python per sample.

Instruments of RIV:

* ``instruments="delayed"`` (default): the regressors delayed by ``delay`` samples,
  ``ζ(k) = φ(k − delay)`` — valid when the equation errors are white (independent
  disturbances ``v``, ``w``, ``e``; not under a coloured current) and, in closed loop, only
  with ``delay`` beyond the loop's memory of the noise; at ``λ = 1`` the recursion equals the
  batch IV with the same instruments (``identify(..., instruments=Z)``) to rounding;
* ``instruments="auxiliary"``: the paper's simulated instruments
  ``ζ(k) = φ(x̂(k), u(k))`` from the noise-free auxiliary model
  ``x̂(k+1) = Φᵀ([x̂(k); u(k)]) θ_aux`` driven by the known input (Lemma 3.1), computed
  sample by sample for a given auxiliary model ``θ_aux`` (a batch estimate, or an earlier
  recursive estimate installed with :meth:`RecursiveEstimator.set_auxiliary` between
  manoeuvres). With ``θ_aux`` the batch IV_E{ζ}=0's own auxiliary model the recursion at
  ``λ = 1`` equals the batch estimate to rounding. The auxiliary parameters are not
  replaced sample by sample by the running estimate: that couples the instruments to the
  noise through the estimate and, from a poor early estimate, loses the instruments.

With ``intercept=True`` (the RIV default) a constant is appended to both instruments and
regressors: the estimate of θ then equals the zero-mean-instrument IV (A7, the paper's
IV_E{ζ}=0) exactly — the constant absorbs the instruments' mean.

Initialisation is exact, not a large ``P(0)``: the first ``warmup`` samples (``warmup ≥``
the equation's unknowns) accumulate the weighted estimating equations, which are solved
once; the recursion continues from their inverse. So at ``λ = 1`` RLS equals batch LS and
RIV the batch IV with the same instruments, to rounding.

Rows follow the trial-log alignment: row ``k`` holds ``y(k)`` and ``u(k)``; a sample of the
recursion is the pair ``(y(k), u(k)) → y(k+1)``. Experiments restart the auxiliary
simulation at their first measurement; the estimate carries on across them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from vesselid.errors import IdentificationError
from vesselid.identify._ivkernels import gauss_jordan
from vesselid.model.regressors import advance, fill_factors, kernel, regressors
from vesselid.model.spec import ModelSpec

__all__ = ["RecursiveEstimator", "RecursiveResult", "check_forgetting", "recursive_estimate"]

MODE_LS = 0
MODE_IV = 1
INSTR_AUX = 0
INSTR_DELAYED = 1

#: phases of an equation's recursion
_PH_LS_WARM, _PH_IV_WARM, _PH_RUN = 0, 1, 2


def check_forgetting(forgetting: Any) -> float:
    """The forgetting factor λ as a float in (0, 1]; one-line reason otherwise."""
    try:
        lam = float(forgetting)
    except (TypeError, ValueError):
        raise IdentificationError(
            f"forgetting must be a number in (0, 1], got {forgetting!r}") from None
    if not (math.isfinite(lam) and 0.0 < lam <= 1.0):
        raise IdentificationError(f"forgetting must be in (0, 1], got {forgetting!r}")
    return lam


# ----------------------------------------------------------------------------- kernels
@kernel(inline="always")
def _solve_small(a, b, q, out):
    """Gauss–Jordan inverse of ``a[:q, :q]`` into ``out`` (partial pivoting,
    :func:`~vesselid.identify._ivkernels.gauss_jordan`); False when (numerically) singular:
    a pivot not above ``1e-13`` times the largest entry. ``b`` is scratch of shape ≥
    (q, 2q)."""
    scale = 0.0
    for i in range(q):
        for j in range(q):
            b[i, j] = a[i, j]
            b[i, q + j] = 1.0 if i == j else 0.0
            if abs(a[i, j]) > scale:
                scale = abs(a[i, j])
    if not scale > 0.0:
        return False
    if not gauss_jordan(b, q, 1e-13 * scale, True):
        return False
    for i in range(q):
        for j in range(q):
            out[i, j] = b[i, q + j]
    return True


@kernel(nogil=True)
def _recursive_run(regsig, u, target, starts, fac, eq, blocks, lam, mode, instr, delay,
                   intercept, warmup, limit, theta, cint, pmat, rmat, rvec, count, phase,
                   xhat, zbuf, scratch, hist, hist_every, hist_pos, used, restart, nzs,
                   theta_aux):
    """Run the recursion over rows ``starts[s] .. starts[s+1]-1`` of every segment.

    State (updated in place, so a stream can be fed in pieces): ``theta`` (P,), ``cint``
    (n,) intercepts, ``pmat`` (n, q, q) the inverses, ``rmat``/``rvec`` the warm-up sums,
    ``count`` (n,) samples in the current phase, ``phase`` (n,), ``xhat`` (n,) the
    auxiliary state, ``zbuf`` (delay+1, P) the delayed regressors ring, ``used`` (n,)
    samples used. ``hist`` (H, P) receives θ every ``hist_every`` samples. ``restart``
    1: each segment restarts the auxiliary state and the delay ring (``nzs[0]`` counts
    its entries); 0: the first segment continues them (a stream fed sample by sample).
    """
    n = regsig.shape[1]
    m = u.shape[1]
    n_par = fac.shape[0]
    n_sig = n + m
    s = np.empty(n_sig)
    f = np.empty(2 * n_sig + 1)
    phi = np.empty(n_par)
    zeta = np.empty(n_par)
    qmax = pmat.shape[1]
    ph = np.empty(qmax)
    ze = np.empty(qmax)
    pz = np.empty(qmax)
    php = np.empty(qmax)
    th = np.empty(qmax)
    nxt = np.empty(n)
    n_hist = hist.shape[0]
    for seg in range(starts.shape[0] - 1):
        a = starts[seg]
        b = starts[seg + 1]
        if restart == 1 or seg > 0:
            for i in range(n):
                xhat[i] = target[a, i]
            nzs[0] = 0
        for k in range(a, b - 1):
            for i in range(n):
                s[i] = regsig[k, i]
            for j in range(m):
                s[n + j] = u[k, j]
            fill_factors(s, f)
            regressors(fac, f, phi)
            have_z = True
            if mode == MODE_IV and instr == INSTR_AUX:
                for i in range(n):
                    s[i] = xhat[i]
                fill_factors(s, f)
                regressors(fac, f, zeta)
            elif mode == MODE_IV:
                slot = nzs[0] % (delay + 1)
                for p in range(n_par):
                    zbuf[slot, p] = phi[p]
                nzs[0] += 1
                if nzs[0] <= delay:
                    have_z = False
                else:
                    old = nzs[0] % (delay + 1)
                    for p in range(n_par):
                        zeta[p] = zbuf[old, p]
            for i in range(n):
                lo = blocks[i]
                p_i = blocks[i + 1] - lo
                q = p_i + intercept
                y = target[k + 1, i]
                for p in range(p_i):
                    ph[p] = phi[lo + p]
                if intercept == 1:
                    ph[p_i] = 1.0
                ls_now = mode == MODE_LS or phase[i] == _PH_LS_WARM
                if ls_now:
                    for p in range(q):
                        ze[p] = ph[p]
                else:
                    if not have_z:
                        continue
                    for p in range(p_i):
                        ze[p] = zeta[lo + p]
                    if intercept == 1:
                        ze[p_i] = 1.0
                used[i] += 1
                if phase[i] != _PH_RUN:
                    for r in range(q):
                        rvec[i, r] = lam * rvec[i, r] + ze[r] * y
                        for c in range(q):
                            rmat[i, r, c] = lam * rmat[i, r, c] + ze[r] * ph[c]
                    count[i] += 1
                    if count[i] >= warmup and count[i] >= q:
                        if _solve_small(rmat[i], scratch, q, pmat[i]):
                            for r in range(q):
                                acc = 0.0
                                for c in range(q):
                                    acc += pmat[i, r, c] * rvec[i, c]
                                th[r] = acc
                            for p in range(p_i):
                                theta[lo + p] = th[p]
                            if intercept == 1:
                                cint[i] = th[p_i]
                            if mode == MODE_IV and phase[i] == _PH_LS_WARM:
                                phase[i] = _PH_IV_WARM  # IV sums from the LS start
                                count[i] = 0
                                for r in range(q):
                                    rvec[i, r] = 0.0
                                    for c in range(q):
                                        rmat[i, r, c] = 0.0
                            else:
                                phase[i] = _PH_RUN
                    continue
                # recursive update (matrix-inversion lemma)
                for p in range(p_i):
                    th[p] = theta[lo + p]
                if intercept == 1:
                    th[p_i] = cint[i]
                den = lam
                err = y
                for r in range(q):
                    acc = 0.0
                    acc2 = 0.0
                    for c in range(q):
                        acc += pmat[i, r, c] * ze[c]
                        acc2 += ph[c] * pmat[i, c, r]
                    pz[r] = acc
                    php[r] = acc2
                    err -= ph[r] * th[r]
                for r in range(q):
                    den += ph[r] * pz[r]
                if not (abs(den) > 0.0 and math.isfinite(den)):
                    continue
                for r in range(q):
                    g = pz[r] / den
                    th[r] += g * err
                    for c in range(q):
                        pmat[i, r, c] = (pmat[i, r, c] - g * php[c]) / lam
                for p in range(p_i):
                    theta[lo + p] = th[p]
                if intercept == 1:
                    cint[i] = th[p_i]
            if mode == MODE_IV and instr == INSTR_AUX:
                # auxiliary model: the noise-free simulation with the latest estimate
                for i in range(n):
                    s[i] = xhat[i]
                    nxt[i] = 0.0
                for j in range(m):
                    s[n + j] = u[k, j]
                advance(fac, eq, theta_aux, s, f, phi, nxt)
                for i in range(n):
                    if math.isfinite(nxt[i]) and abs(nxt[i]) <= limit[i]:
                        xhat[i] = nxt[i]
                    # else: a diverging auxiliary step is not taken (the state is held:
                    # restarting at a measurement would put its noise into ζ)
            if n_hist > 0:
                hist_pos[1] += 1
                if hist_pos[1] % hist_every == 0 and hist_pos[0] < n_hist:
                    for p in range(n_par):
                        hist[hist_pos[0], p] = theta[p]
                    hist_pos[0] += 1


# ---------------------------------------------------------------------------- objects
@dataclass
class RecursiveResult:
    """Result of :func:`recursive_estimate`.

    Attributes
    ----------
    params : Series
        Final estimate θ̂ (spec parameter order).
    history : DataFrame or None
        θ̂ after every ``history_every``-th sample (index: sample number of the
        recursion, i.e. equations used so far).
    ready : bool
        Every equation finished its warm-up (before that θ̂ is NaN).
    method, forgetting, instruments : str, float, str
        The settings.
    """

    params: Any
    history: Any
    ready: bool
    method: str
    forgetting: float
    instruments: str


class RecursiveEstimator:
    """Recursive LS / IV with forgetting, fed sample by sample or with whole arrays.

    Parameters
    ----------
    spec : ModelSpec
        Model structure (its regressors use ``regsig``; an aggregate relation's sensor
        signal is the caller's to add).
    method : {"iv", "ls"}
        Recursive IV (auxiliary-model or delayed instruments) or recursive LS.
    forgetting : float
        λ in (0, 1]; the effective memory is ``1 / (1 − λ)`` samples.
    instruments : {"delayed", "auxiliary"}
        RIV instruments (module docstring).
    delay : int
        Delay of the ``"delayed"`` instruments (samples, ≥ 1).
    theta_aux : array-like, optional
        The auxiliary model of the ``"auxiliary"`` instruments (required for them).
    intercept : bool, optional
        Append a constant to regressors and instruments (default: True for IV — the
        zero-mean instruments of IV_E{ζ}=0 — False for LS, which then equals batch LS).
    warmup : int, optional
        Samples of each exact initialisation phase (default ``max(10 q, 50)`` for the
        largest equation's ``q`` unknowns).
    limit : float
        The auxiliary state restarts at the measurement when it leaves ``±limit``
        (default 1e3 times the largest measured magnitude seen at the first call).

    Examples
    --------
    Inside an environment loop (row ``k``: measurement ``y(k)``, input ``u(k)``)::

        est = RecursiveEstimator(spec, forgetting=0.999)
        for k in range(n - 1):
            est.update(y[k], u[k], y[k + 1])
        est.theta
    """

    def __init__(self, spec: ModelSpec, method: str = "iv", *, forgetting: float = 1.0,
                 instruments: str = "delayed", delay: int = 1,
                 intercept: bool | None = None, warmup: int | None = None,
                 theta_aux: Any | None = None, limit: float | None = None) -> None:
        if method not in ("iv", "ls"):
            raise IdentificationError(f"method must be 'iv' or 'ls', got {method!r}")
        if instruments not in ("auxiliary", "delayed"):
            raise IdentificationError(
                f"instruments must be 'auxiliary' or 'delayed', got {instruments!r}")
        if not (isinstance(delay, int | np.integer) and delay >= 1):
            raise IdentificationError(f"delay must be a positive integer, got {delay!r}")
        from vesselid.identify.data import block_starts

        self.spec = spec
        self.method = method
        self.forgetting = check_forgetting(forgetting)
        self.instruments = instruments
        self.delay = int(delay)
        self.intercept = (method == "iv") if intercept is None else bool(intercept)
        codes = spec.codes
        self._fac, self._eq = codes.factors, codes.equation
        self._blocks = block_starts(spec)
        n, n_par = spec.n_states, spec.n_params
        qmax = int(np.max(np.diff(self._blocks))) + int(self.intercept)
        if warmup is None:
            warmup = max(10 * qmax, 50)
        if not (isinstance(warmup, int | np.integer) and warmup >= 1):
            raise IdentificationError(f"warmup must be a positive integer, got {warmup!r}")
        self.warmup = int(warmup)
        self._theta = np.full(n_par, np.nan)
        self._cint = np.zeros(n)
        self._pmat = np.zeros((n, qmax, qmax))
        self._rmat = np.zeros((n, qmax, qmax))
        self._rvec = np.zeros((n, qmax))
        self._count = np.zeros(n, dtype=np.int64)
        self._phase = np.zeros(n, dtype=np.int64)
        self._used = np.zeros(n, dtype=np.int64)
        self._xhat = np.zeros(n)
        self._zbuf = np.zeros((self.delay + 1, n_par))
        self._scratch = np.zeros((qmax, 2 * qmax))
        self._limit = None if limit is None else np.full(n, float(limit))
        self._last: np.ndarray | None = None  # last (regsig, u) for update()
        self._aux_started = False
        self._nzs = np.zeros(1, dtype=np.int64)
        self._theta_aux = np.zeros(n_par)
        if method == "iv" and instruments == "auxiliary":
            if theta_aux is None:
                raise IdentificationError(
                    "instruments='auxiliary' needs theta_aux (the auxiliary model, e.g. a "
                    "batch IV estimate's params or an earlier recursive estimate)")
            self.set_auxiliary(theta_aux)
        if method == "iv":
            self._phase[:] = _PH_IV_WARM
        # one-sample buffers of update()
        self._one = (np.zeros((2, n)), np.zeros((2, spec.n_inputs)), np.zeros((2, n)))
        self._starts1 = np.array([0, 2], dtype=np.int64)
        self._nohist = np.zeros((0, n_par))
        self._hp = np.zeros(2, dtype=np.int64)

    # ------------------------------------------------------------------ state
    @property
    def theta(self) -> np.ndarray:
        """Current estimate (NaN in an equation still warming up)."""
        out = self._theta.copy()
        for i in range(self.spec.n_states):
            if self._phase[i] != _PH_RUN:
                out[self._blocks[i]:self._blocks[i + 1]] = np.nan
        return out

    @property
    def intercepts(self) -> np.ndarray:
        """The estimated constant of each equation (``intercept=True``; else zeros; NaN in
        an equation still warming up)."""
        return np.where(self._phase == _PH_RUN, self._cint, np.nan)

    @property
    def ready(self) -> bool:
        """Every equation has finished its warm-up."""
        return bool(np.all(self._phase == _PH_RUN))

    @property
    def n_updates(self) -> int:
        """Samples used so far (the least of the equations)."""
        return int(self._used.min())

    def covariance(self, sigma2: Any) -> np.ndarray:
        """``σ² P`` per equation block — the covariance of the estimate for white equation
        errors of variance ``sigma2`` (per state) at ``λ = 1``; with forgetting it is the
        usual approximate scale of the tracking error."""
        sig = np.broadcast_to(np.asarray(sigma2, dtype=float), (self.spec.n_states,))
        cov = np.full((self.spec.n_params,) * 2, np.nan)
        for i in range(self.spec.n_states):
            lo, hi = int(self._blocks[i]), int(self._blocks[i + 1])
            p = hi - lo
            cov[lo:hi, lo:hi] = sig[i] * self._pmat[i, :p, :p]
        return cov

    def set_auxiliary(self, theta_aux: Any) -> None:
        """Replace the auxiliary model of the ``"auxiliary"`` instruments (e.g. by the
        latest estimate, between manoeuvres); its simulation state carries on."""
        th = np.asarray(self.spec.vector_from(theta_aux), dtype=float)
        if not np.all(np.isfinite(th)):
            raise IdentificationError("theta_aux must be finite")
        self._theta_aux[:] = th

    def _ensure_limit(self, target: np.ndarray) -> None:
        if self._limit is None:
            scale = np.nanmax(np.abs(target), axis=0) if target.size else np.ones(1)
            self._limit = 1e3 * np.maximum(np.broadcast_to(scale, (self.spec.n_states,)), 1.0)

    def _run(self, regsig, u, target, starts, hist, every, hp, restart=1) -> None:
        self._ensure_limit(target)
        _recursive_run(regsig, u, target, starts, self._fac, self._eq, self._blocks,
                       self.forgetting, MODE_IV if self.method == "iv" else MODE_LS,
                       INSTR_AUX if self.instruments == "auxiliary" else INSTR_DELAYED,
                       self.delay, int(self.intercept), self.warmup, self._limit,
                       self._theta, self._cint, self._pmat, self._rmat, self._rvec,
                       self._count, self._phase, self._xhat, self._zbuf, self._scratch,
                       hist, max(int(every), 1), hp, self._used, int(restart), self._nzs,
                       self._theta_aux)

    # ---------------------------------------------------------------- streaming
    def update(self, x: Any, u: Any, y: Any) -> np.ndarray:
        """One sample: regressor signals ``x = y(k)`` (states, or the aggregated signal),
        input ``u(k)`` and the next measurement ``y(k+1)``; returns θ̂ (a copy).

        Consecutive calls are consecutive samples: the auxiliary model of RIV continues
        from its last state (call :meth:`new_experiment` between experiments).
        """
        rs, uu, tg = self._one
        rs[0] = np.asarray(x, dtype=float).ravel()
        uu[0] = np.asarray(u, dtype=float).ravel()
        tg[1] = np.asarray(y, dtype=float).ravel()
        tg[0] = rs[0]
        if not (np.all(np.isfinite(rs[0])) and np.all(np.isfinite(uu[0]))
                and np.all(np.isfinite(tg[1]))):
            raise IdentificationError("update: x, u and y must be finite")
        self._run(rs, uu, tg, self._starts1, self._nohist, 1, self._hp,
                  restart=0 if self._aux_started else 1)
        self._aux_started = True
        return self.theta

    def new_experiment(self) -> None:
        """The next :meth:`update` starts a new experiment (the auxiliary model restarts
        at its measurement)."""
        self._aux_started = False

    def run(self, regsig: Any, u: Any, target: Any | None = None, *,
            starts: Any | None = None, history_every: int = 0,
            continues: bool = False) -> np.ndarray | None:
        """Feed whole arrays (one compiled pass): rows ``k`` of ``regsig`` (N, n) and
        ``u`` (N, m), targets ``target`` (default ``regsig``), experiments split at
        ``starts`` (default one). Returns the θ̂ history (rows every ``history_every``
        samples) when asked, else None. Calls continue the estimate (streamed logs); with
        ``continues=True`` the first rows continue the previous call's experiment (its
        auxiliary simulation) — a log streamed in chunks."""
        rs = np.ascontiguousarray(regsig, dtype=float)
        uu = np.ascontiguousarray(u, dtype=float)
        tg = rs if target is None else np.ascontiguousarray(target, dtype=float)
        if rs.ndim == 1:
            rs, tg = rs[:, None], (tg[:, None] if tg.ndim == 1 else tg)
        if uu.ndim == 1:
            uu = uu[:, None]
        n, m = self.spec.n_states, self.spec.n_inputs
        if rs.shape[1:] != (n,) or tg.shape != rs.shape or uu.shape != (rs.shape[0], m):
            raise IdentificationError(
                f"run: need regsig/target of shape (N, {n}) and u of shape (N, {m}); got "
                f"{rs.shape}, {tg.shape}, {uu.shape}")
        if not (np.all(np.isfinite(rs)) and np.all(np.isfinite(uu))
                and np.all(np.isfinite(tg))):
            raise IdentificationError("run: the signals hold NaN or inf")
        st = (np.array([0, rs.shape[0]], dtype=np.int64) if starts is None
              else np.ascontiguousarray(starts, dtype=np.int64))
        every = int(history_every)
        hist = (np.full(((rs.shape[0] // every) + 1, self.spec.n_params), np.nan)
                if every > 0 else self._nohist)
        hp = np.zeros(2, dtype=np.int64)
        self._run(rs, uu, tg, st, hist, every, hp,
                  restart=0 if (continues and self._aux_started) else 1)
        self._aux_started = True
        return hist[: int(hp[0])] if every > 0 else None


def recursive_estimate(log: Any, spec: ModelSpec | None = None, method: str = "iv", *,
                       forgetting: float = 1.0, history_every: int = 0,
                       **options: Any) -> RecursiveResult:
    """Run :class:`RecursiveEstimator` over a whole trial log (one compiled pass).

    Parameters
    ----------
    log : TrialLog or DataFrame
        As for :func:`vesselid.identify.identify` (validated the same way).
    spec : ModelSpec, optional
        Default the log's spec.
    method : {"iv", "ls"}
    forgetting : float
        λ in (0, 1].
    history_every : int
        Keep θ̂ every this many samples (0: only the final estimate).
    **options
        Further :class:`RecursiveEstimator` options.

    Returns
    -------
    RecursiveResult
    """
    import pandas as pd

    from vesselid.identify.data import from_log

    lam = check_forgetting(forgetting)
    data, spec = from_log(log, spec, sensor_noise=False)
    est = RecursiveEstimator(spec, method, forgetting=lam, **options)
    hist = est.run(data.regsig, data.u, data.target, starts=data.starts,
                   history_every=history_every)
    index = spec.param_index
    history = None
    if hist is not None:
        history = pd.DataFrame(hist, columns=index,
                               index=pd.RangeIndex(1, hist.shape[0] + 1) * int(history_every))
        history.index.name = "sample"
    return RecursiveResult(params=pd.Series(est.theta, index=index, name="estimate"),
                           history=history, ready=est.ready, method=method,
                           forgetting=lam, instruments=est.instruments)
