"""Simulation of system (1a)–(1b), batched over runs and compiled with numba.

``x(k+1) = Φᵀ([x(k) + v(k); u(k)]) θ0 + w(k)`` — the disturbance ``v`` (e.g. an
ocean current) enters *inside* the nonlinearity, ``w`` is additive. Measurements
``y = x + e`` are added by the caller (see :mod:`vesselid.plant.systems`).

The recursion is sequential in time, so it runs in a compiled kernel that loops
over samples; runs are split across threads (:func:`vesselid.core.threads.run_ranges`, one
serial ``nogil`` kernel for small and large batches); no Python code runs per sample.
"""

from __future__ import annotations

import numpy as np

from vesselid.core.threads import run_ranges
from vesselid.errors import SimulationDivergedError, SimulationError
from vesselid.model.regressors import advance, kernel
from vesselid.model.spec import ModelSpec

__all__ = ["DEFAULT_DIVERGENCE_LIMIT", "simulate_states", "step_states"]

#: States whose magnitude exceeds this are treated as diverged.
DEFAULT_DIVERGENCE_LIMIT = 1e8

STATUS_OK = 0
STATUS_NONFINITE = 1
STATUS_LIMIT = 2


@kernel(inline="always")
def _simulate_run(r, x0, u, v, w, fac, eq, theta, limit, x_out, status, fail_at):
    n_samples, n = x_out.shape[1], x_out.shape[2]
    m = u.shape[2]
    n_par = fac.shape[0]
    th = theta[r] if theta.shape[0] > 1 else theta[0]
    s = np.empty(n + m)
    f = np.empty(2 * (n + m) + 1)
    phi = np.empty(n_par)
    nxt = np.empty(n)
    for i in range(n):
        x_out[r, 0, i] = x0[r, i]
    status[r] = STATUS_OK
    fail_at[r] = -1
    for k in range(n_samples - 1):
        for i in range(n):
            s[i] = x_out[r, k, i] + v[r, k, i]
        for j in range(m):
            s[n + j] = u[r, k, j]
        for i in range(n):
            nxt[i] = w[r, k, i]
        advance(fac, eq, th, s, f, phi, nxt)
        bad = STATUS_OK
        for i in range(n):
            xi = nxt[i]
            x_out[r, k + 1, i] = xi
            if not np.isfinite(xi):
                bad = STATUS_NONFINITE
            elif abs(xi) > limit:
                bad = STATUS_LIMIT
        if bad != STATUS_OK:
            status[r] = bad
            fail_at[r] = k + 1
            for kk in range(k + 2, n_samples):
                for i in range(n):
                    x_out[r, kk, i] = np.nan
            break


@kernel(nogil=True)
def _simulate_runs(lo, hi, x0, u, v, w, fac, eq, theta, limit, x_out, status, fail_at):
    for r in range(lo, hi):
        _simulate_run(r, x0, u, v, w, fac, eq, theta, limit, x_out, status, fail_at)


#: Below this many samples in total the serial kernel is used.
PARALLEL_MIN_SAMPLES = 200_000


@kernel()
def step_states(fac, eq, theta, x, v, u, w, out):
    """One compiled step ``out = Φᵀ([x + v; u]) θ + w`` for a batch of systems.

    ``fac, eq`` are the factor layout of ``ModelSpec.codes`` (``factors``,
    ``equation``); ``x, v, w, out`` have shape ``(B, n)``, ``u`` ``(B, m)``, ``theta``
    ``(P,)``.
    """
    n_b, n = x.shape
    m = u.shape[1]
    s = np.empty(n + m)
    f = np.empty(2 * (n + m) + 1)
    phi = np.empty(fac.shape[0])
    for b in range(n_b):
        for i in range(n):
            s[i] = x[b, i] + v[b, i]
            out[b, i] = w[b, i]
        for j in range(m):
            s[n + j] = u[b, j]
        advance(fac, eq, theta, s, f, phi, out[b])


def _as_batch(name: str, arr, n_runs: int, n_samples: int, width: int) -> np.ndarray:
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or a.shape[1:] != (n_samples, width) or a.shape[0] not in (1, n_runs):
        raise SimulationError(
            f"{name} must have shape (runs, samples, {width}) or (samples, {width}); got "
            f"{np.shape(arr)} for {n_runs} runs of {n_samples} samples"
        )
    if a.shape[0] != n_runs:
        a = np.broadcast_to(a, (n_runs, n_samples, width))
    return _writable(a)


def _writable(a: np.ndarray) -> np.ndarray:
    """C-contiguous and writable: read-only arrays would compile a second specialisation
    of the kernel (numba types them apart), so they are copied."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.flags.writeable else a.copy()


def simulate_states(
    spec: ModelSpec,
    u: np.ndarray,
    *,
    theta: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    v: np.ndarray | None = None,
    w: np.ndarray | None = None,
    limit: float = DEFAULT_DIVERGENCE_LIMIT,
    raise_on_divergence: bool = True,
) -> np.ndarray:
    """Simulate the true states of (1a) for one or many runs.

    Parameters
    ----------
    spec : ModelSpec
        Model structure (and θ0 unless ``theta`` is given).
    u : ndarray, shape (N, m) or (R, N, m)
        Known inputs.
    theta : ndarray, shape (P,) or (R, P), optional
        Parameters (one vector, or one per run); default θ0 of ``spec``.
    x0 : ndarray, shape (n,) or (R, n), optional
        Initial states; default zeros.
    v, w : ndarray, shape (N, n) or (R, N, n), optional
        Disturbance inside the nonlinearity and additive process disturbance.
    limit : float
        States with magnitude above ``limit`` count as diverged.
    raise_on_divergence : bool
        Raise :class:`SimulationDivergedError` if any run diverges (default). If
        False, diverged runs are NaN from the failing sample on.

    Returns
    -------
    ndarray, shape (N, n) or (R, N, n)
        The states ``x(0) ... x(N-1)``; batch shape follows ``u``.
    """
    u_arr = np.asarray(u, dtype=np.float64)
    single = u_arr.ndim == 2
    if u_arr.ndim not in (2, 3) or u_arr.shape[-1] != spec.n_inputs:
        raise SimulationError(f"u must have shape (N, {spec.n_inputs}) or (R, N, {spec.n_inputs})")
    n_runs = 1 if single else u_arr.shape[0]
    n_samples, n = u_arr.shape[-2], spec.n_states
    if n_samples < 1:
        raise SimulationError("need at least one sample")
    th = spec.theta0_vector() if theta is None else np.asarray(theta, dtype=np.float64)
    th = np.atleast_2d(th)
    if th.shape[1] != spec.n_params or th.shape[0] not in (1, n_runs):
        raise SimulationError(f"theta must have {spec.n_params} entries per run, got {th.shape}")
    if not np.all(np.isfinite(th)):
        raise SimulationError("theta holds non-finite values")
    x0_arr = np.zeros((n_runs, n)) if x0 is None else np.asarray(x0, dtype=np.float64)
    x0_arr = np.array(np.broadcast_to(np.atleast_2d(x0_arr), (n_runs, n)), order="C")
    zeros = np.zeros((1, n_samples, n))
    u_b = _as_batch("u", u_arr, n_runs, n_samples, spec.n_inputs)
    v_b = _as_batch("v", zeros if v is None else v, n_runs, n_samples, n)
    w_b = _as_batch("w", zeros if w is None else w, n_runs, n_samples, n)
    x = np.empty((n_runs, n_samples, n))
    status = np.empty(n_runs, dtype=np.int64)
    fail_at = np.empty(n_runs, dtype=np.int64)
    codes = spec.codes
    parallel = n_runs > 1 and n_runs * n_samples >= PARALLEL_MIN_SAMPLES
    run_ranges(_simulate_runs, n_runs,
               (x0_arr, u_b, v_b, w_b, codes.factors, codes.equation, _writable(th),
                float(limit), x, status, fail_at), parallel=parallel)
    if raise_on_divergence and np.any(status != STATUS_OK):
        bad = np.flatnonzero(status != STATUS_OK)
        r = int(bad[0])
        why = "became non-finite" if status[r] == STATUS_NONFINITE else f"exceeded |x| > {limit:g}"
        raise SimulationDivergedError(
            f"simulation of {spec.name!r} diverged in {bad.size} of {n_runs} run(s): run {r} "
            f"{why} at sample {int(fail_at[r])}; check θ and the input amplitude"
        )
    return x[0] if single else x
