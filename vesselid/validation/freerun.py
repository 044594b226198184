"""Simulating an identified model on a measured experiment: free run, k-step prediction and
zig-zags steered by the simulated heading.

:func:`vesselid.plant.simulate.simulate_states` simulates ``x(k+1) = Φᵀ([x; u]) θ`` with inputs
given in advance. A manoeuvring model with ``[derived]`` inputs (:mod:`vesselid.model.derived`:
``u²δ``, ``(u² + v²)δ``) needs those inputs recomputed at every step from the *simulated*
states, and a zig-zag simulated as the manoeuvre it is needs the rudder reversed when the
simulated heading reaches the switching angle. :class:`Plant` compiles a spec and θ into
the arrays of one compiled kernel (numba, no Python per sample) that does both:

* every sample: the spec's signal vector ``s = [x; u]`` from the simulated states and the
  measured inputs; measured columns an expression reads are the simulated state (or, for a
  derived state ``x_d = a·col + c``, ``(x_d − c)/a``) when they are states, else the log's
  column; then the derived inputs ``Σ c_m Π factors``; then ``x(k+1) = Φᵀ(s) θ``;
* zig-zag mode: from the execute sample on, the rudder input moves toward ``±δ₀`` at the
  measured rudder rate and reverses when the heading change (integrated from the simulated
  yaw rate, trapezoidal rule) reaches ``±ψ_s``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vesselid.errors import SimulationError
from vesselid.model.regressors import fill_factors, kernel, one_step, regressors
from vesselid.model.spec import ModelSpec

__all__ = ["Plant", "ZigZagLogic"]

DIVERGENCE_LIMIT = 1e8


@kernel(inline="always")
def _step(x, urow, rawrow, inv_state, inv_a, inv_c, d_slot, mono_d, mono_coef, mono_fac,
          fac, eq, theta, s, env, fenv, f, phi, nxt):
    """Fill ``s`` from the state ``x`` and the inputs, compute the derived inputs, and the
    next state into ``nxt``."""
    n = x.shape[0]
    m = urow.shape[0]
    n_s = n + m
    n_env = env.shape[0]
    for i in range(n):
        env[i] = x[i]
    for j in range(m):
        env[n + j] = urow[j]
    for j in range(n_env - n_s):
        st = inv_state[j]
        if st >= 0:
            env[n_s + j] = (x[st] - inv_c[j]) / inv_a[j]
        else:
            env[n_s + j] = rawrow[j]
    fill_factors(env, fenv)
    for d in range(d_slot.shape[0]):
        env[d_slot[d]] = 0.0
    for p in range(mono_d.shape[0]):
        v = mono_coef[p]
        for q in range(mono_fac.shape[1]):
            v *= fenv[mono_fac[p, q]]
        env[d_slot[mono_d[p]]] += v
    for i in range(n_s):
        s[i] = env[i]
    fill_factors(s, f)
    regressors(fac, f, phi)
    for i in range(n):
        nxt[i] = 0.0
    one_step(eq, theta, phi, nxt)


@kernel(inline="always")
def _scratch(n, m, n_raw, n_phi):
    """The scratch buffers of :func:`_step` for ``n`` states, ``m`` inputs, ``n_raw``
    measured columns and ``n_phi`` regressors: ``s, env, fenv, f, phi, nxt``."""
    n_env = n + m + n_raw
    return (np.empty(n + m), np.empty(n_env), np.empty(2 * n_env + 1),
            np.empty(2 * (n + m) + 1), np.empty(n_phi), np.empty(n))


@kernel(nogil=True)
def _simulate(x0, u, raw, inv_state, inv_a, inv_c, d_slot, mono_d, mono_coef, mono_fac,
              fac, eq, theta, limit, zz_on, zz_k, zz_idx, zz_delta0, zz_psi_s, zz_rate,
              zz_gain, zz_first, r_idx, dt, x_out, u_out):
    """Free run (``zz_on = 0``) or zig-zag run from ``x0``; returns the first diverged
    sample (or -1)."""
    n_samples, n = x_out.shape
    m = u.shape[1]
    s, env, fenv, f, phi, nxt = _scratch(n, m, raw.shape[1], fac.shape[0])
    urow = np.empty(m)
    x = x0.copy()
    psi = 0.0
    target = zz_first * zz_delta0
    rudder = 0.0
    for k in range(n_samples):
        for i in range(n):
            x_out[k, i] = x[i]
        for j in range(m):
            urow[j] = u[k, j]
        if zz_on == 1:
            if k == zz_k:
                rudder = u[k, zz_idx]
                psi = 0.0
            if k > zz_k:
                sgn = 1.0 if target > 0 else -1.0
                if sgn * zz_gain * psi >= zz_psi_s:
                    target = -target
                step = target - rudder
                lim = zz_rate * dt
                if step > lim:
                    step = lim
                elif step < -lim:
                    step = -lim
                rudder += step
            if k >= zz_k:
                urow[zz_idx] = rudder
        _step(x, urow, raw[k], inv_state, inv_a, inv_c, d_slot, mono_d, mono_coef, mono_fac,
              fac, eq, theta, s, env, fenv, f, phi, nxt)
        for j in range(m):
            u_out[k, j] = s[n + j]
        if k == n_samples - 1:
            break
        bad = False
        for i in range(n):
            if not np.isfinite(nxt[i]) or abs(nxt[i]) > limit:
                bad = True
        if bad:
            for kk in range(k + 1, n_samples):
                for i in range(n):
                    x_out[kk, i] = np.nan
            return k + 1
        if zz_on == 1 and k >= zz_k and r_idx >= 0:
            psi += 0.5 * dt * (x[r_idx] + nxt[r_idx])
        for i in range(n):
            x[i] = nxt[i]
    return -1


@kernel(nogil=True)
def _k_step(y, u, raw, horizon, inv_state, inv_a, inv_c, d_slot, mono_d, mono_coef, mono_fac,
            fac, eq, theta, out):
    """``out[k + horizon]``: the ``horizon``-step prediction from the measured ``y[k]``."""
    n_samples, n = y.shape
    s, env, fenv, f, phi, nxt = _scratch(n, u.shape[1], raw.shape[1], fac.shape[0])
    x = np.empty(n)
    for k in range(n_samples):
        for i in range(n):
            out[k, i] = np.nan
    for k0 in range(n_samples - horizon):
        for i in range(n):
            x[i] = y[k0, i]
        ok = True
        for j in range(horizon):
            _step(x, u[k0 + j], raw[k0 + j], inv_state, inv_a, inv_c, d_slot, mono_d,
                  mono_coef, mono_fac, fac, eq, theta, s, env, fenv, f, phi, nxt)
            for i in range(n):
                x[i] = nxt[i]
                if not np.isfinite(x[i]) or abs(x[i]) > 1e8:
                    ok = False
            if not ok:
                break
        if ok:
            for i in range(n):
                out[k0 + horizon, i] = x[i]


@dataclass(frozen=True)
class ZigZagLogic:
    """Rudder logic of a zig-zag simulated on the model (angles in the log's unit, rad).

    Parameters
    ----------
    execute : int
        Sample of the first rudder execute (the rudder follows the log before it).
    rudder : str
        Rudder input column.
    delta0 : float
        Rudder amplitude ``δ₀`` (> 0).
    psi_switch : float
        Heading change ``ψ_s`` (> 0) at which the rudder reverses.
    rate : float
        Rudder rate (per second, > 0).
    gain_sign : float
        ``+1`` if a positive rudder turns the heading positive, else ``-1``.
    first_sign : float
        Sign of the first rudder deflection.
    """

    execute: int
    rudder: str
    delta0: float
    psi_switch: float
    rate: float
    gain_sign: float
    first_sign: float


class Plant:
    """An identified model ready for simulation on measured experiments.

    Parameters
    ----------
    spec : ModelSpec
        The structure, with ``[derived]`` signals if any.
    theta : array-like, optional
        Parameters in ``spec.param_index`` order; default the spec's θ0.
    """

    def __init__(self, spec: ModelSpec, theta: np.ndarray | None = None) -> None:
        th = spec.theta0_vector() if theta is None else np.asarray(theta, dtype=float)
        if th.shape != (spec.n_params,) or not np.all(np.isfinite(th)):
            raise SimulationError(f"theta must hold {spec.n_params} finite values")
        self.spec = spec
        self.theta = np.ascontiguousarray(th)
        signals = list(spec.signals)
        raw_cols: list[str] = []
        inv_state: list[int] = []
        inv_a: list[float] = []
        inv_c: list[float] = []
        state_source: dict[str, tuple[int, float, float]] = {}
        for i, name in enumerate(spec.states):
            d = spec.derived.get(name)
            if d is not None:
                col, a, c = d.affine()  # type: ignore[misc]
                state_source[col] = (i, a, c)
        for d in spec.derived.values():
            for col in d.uses:
                if col in signals or col in raw_cols:
                    continue
                raw_cols.append(col)
                if col in state_source:
                    i, a, c = state_source[col]
                    inv_state.append(i)
                    inv_a.append(a)
                    inv_c.append(c)
                else:
                    inv_state.append(-1)
                    inv_a.append(1.0)
                    inv_c.append(0.0)
        #: measured columns read from the log besides the spec's states and inputs
        self.raw_columns = tuple(c for c, st in zip(raw_cols, inv_state, strict=True) if st < 0)
        self.source_of = {spec.states[i]: (col, a, c) for col, (i, a, c) in state_source.items()}
        env = signals + raw_cols
        n_env = len(env)
        d_inputs = [nm for nm in spec.inputs if nm in spec.derived]
        mono_d, mono_coef, mono_rows = [], [], []
        for k, nm in enumerate(d_inputs):
            for mono, coef in spec.derived[nm].terms:
                mono_d.append(k)
                mono_coef.append(coef)
                mono_rows.append([env.index(c) + n_env * int(a) for c, a in mono])
        width = max((len(r) for r in mono_rows), default=1) or 1
        mono_fac = np.full((len(mono_rows), width), 2 * n_env, dtype=np.int64)
        for p, r in enumerate(mono_rows):
            mono_fac[p, :len(r)] = r
        self._env_raw = raw_cols
        self._inv = (np.asarray(inv_state, dtype=np.int64).reshape(-1),
                     np.asarray(inv_a, dtype=float).reshape(-1),
                     np.asarray(inv_c, dtype=float).reshape(-1))
        self._derived = (np.asarray([signals.index(nm) for nm in d_inputs], dtype=np.int64),
                         np.asarray(mono_d, dtype=np.int64),
                         np.asarray(mono_coef, dtype=float), mono_fac)
        codes = spec.codes
        self._codes = (codes.factors, codes.equation)

    # ------------------------------------------------------------------ arrays
    def arrays(self, frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(y, u, raw)`` of one experiment (a DataFrame with the measured columns);
        derived columns are computed from the measured ones."""
        from vesselid.model.derived import add_derived

        frame = add_derived(frame, self.spec)
        y = np.ascontiguousarray(frame[list(self.spec.states)].to_numpy(dtype=float))
        u = np.ascontiguousarray(frame[list(self.spec.inputs)].to_numpy(dtype=float)
                                 if self.spec.inputs else np.zeros((len(frame), 0)))
        raw = np.zeros((len(frame), len(self._env_raw)))
        for j, c in enumerate(self._env_raw):
            if self._inv[0][j] < 0:
                raw[:, j] = frame[c].to_numpy(dtype=float)
        return y, u, np.ascontiguousarray(raw)

    def simulate(self, frame, x0: np.ndarray | None = None, zigzag: ZigZagLogic | None = None,
                 dt: float | None = None) -> tuple[np.ndarray, np.ndarray, int]:
        """Free run (or zig-zag run) over one experiment.

        Returns
        -------
        x : ndarray (N, n)
            Simulated states (NaN from a diverged sample on).
        u : ndarray (N, m)
            The inputs used (derived inputs from the simulated states; the rudder of the
            zig-zag logic).
        diverged_at : int
            First diverged sample, or -1.
        """
        y, u, raw = self.arrays(frame)
        x0 = y[0] if x0 is None else np.asarray(x0, dtype=float)
        n = self.spec.n_states
        x_out = np.empty((y.shape[0], n))
        u_out = np.empty_like(u)
        if zigzag is not None:
            if dt is None:
                raise SimulationError("a zig-zag simulation needs dt")
            if "r" not in self.spec.states:
                raise SimulationError("a zig-zag simulation needs the yaw rate state 'r'")
            zz = (1, int(zigzag.execute), self.spec.inputs.index(zigzag.rudder),
                  float(zigzag.delta0), float(zigzag.psi_switch), float(zigzag.rate),
                  float(zigzag.gain_sign), float(zigzag.first_sign),
                  self.spec.states.index("r"), float(dt))
        else:
            zz = (0, 0, 0, 0.0, 0.0, 0.0, 1.0, 1.0, -1, float(dt or 1.0))
        bad = _simulate(np.ascontiguousarray(x0, dtype=float), u, raw, *self._inv,
                        *self._derived, *self._codes, self.theta, DIVERGENCE_LIMIT, *zz,
                        x_out, u_out)
        return x_out, u_out, int(bad)

    def k_step(self, frame, horizon: int) -> np.ndarray:
        """``horizon``-step-ahead predictions ``ŷ(k | k − horizon)`` (NaN for the first
        ``horizon`` samples)."""
        y, u, raw = self.arrays(frame)
        out = np.empty_like(y)
        _k_step(y, u, raw, int(horizon), *self._inv, *self._derived, *self._codes,
                self.theta, out)
        return out
