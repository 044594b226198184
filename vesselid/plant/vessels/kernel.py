"""The generic vessel kernel: one compiled Euler step for every hull, with the sea around it.

``ν(k+1) = Φᵀ([ν(k) − ν_c(k); τ(k)]) θ0 + w(k)`` with
``w(k) = ν_c(k+1) + dt M⁻¹ (τ_wind(k) + τ_noise(k) [+ cubic damping])``: the
hydrodynamics are evaluated only through the hull spec's factor layout and θ0 (one
physics, :mod:`vesselid.model.regressors`), the current is earth-fixed and rotated into the
body frame with the heading (the paper's non-additive ``v = −ν_c``), the wind load is
Blendermann's (:func:`vesselid.plant.vessels.wind.wind_load`), and the sensors read the state
with noise. Kinematics ``η(k+1) = η(k) + dt R(ψ(k)) ν(k)``, ``η = [north, east, ψ]``.

Users: :func:`simulate_vessel` (offline trials, one :class:`VesselSimulation`) and
:class:`VesselBatch` (``B`` vessels stepped one sample at a time, for the environments).
Inputs are physical forces ``τ``; action scaling, references and rewards belong to the
environments.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit, prange

from vesselid.core import seeds
from vesselid.core.filters import ar1_filter
from vesselid.errors import SimulationDivergedError, VesselidError
from vesselid.model.regressors import advance, kernel
from vesselid.model.spec import ModelSpec
from vesselid.plant.disturbances import gauss_markov_rows
from vesselid.plant.plant import heading
from vesselid.plant.result import SimulationResult
from vesselid.plant.simulate import DEFAULT_DIVERGENCE_LIMIT, simulate_states
from vesselid.plant.vessels.environment import (
    N_SENSOR_CHANNELS,
    SENSOR_CHANNELS,
    SENSOR_GROUPS,
    VesselDisturbances,
    VesselSensors,
    coerce,
)
from vesselid.plant.vessels.hull import Hull
from vesselid.plant.vessels.wind import N_WIND_PAR, blendermann_wind_force, wind_load

__all__ = [
    "LAYOUT",
    "StateLayout",
    "VesselBatch",
    "VesselModel",
    "VesselSimulation",
    "log_columns",
    "simulate_vessel",
]

DEFAULT_DT = 0.1
_N_SENS = N_SENSOR_CHANNELS


# ----------------------------------------------------------------------------- layout
@dataclass(frozen=True)
class StateLayout:
    """Named blocks of a vessel's state row (``st[..., start:start + width]``).

    The kernels address the row through the module constants below (compile-time
    integers); Python code (results, environment info) uses this object.
    """

    blocks: tuple[tuple[str, int, int], ...]

    def slice(self, name: str) -> slice:
        for key, start, width in self.blocks:
            if key == name:
                return slice(start, start + width)
        raise KeyError(name)

    def sensor_slices(self, sensors: VesselSensors) -> list[tuple[str, slice]]:
        """``(group, slice)`` of every enabled sensor group."""
        out, i = [], S_SENS
        for g, chans in SENSOR_GROUPS.items():
            if g in sensors.enabled:
                out.append((g, slice(i, i + len(chans))))
            i += len(chans)
        return out


# Packed parameters ``par``.
P_DT = 0
P_MINV = 1  # 9 entries: dt M⁻¹ row-major
P_WINDP = 10  # N_WIND_PAR entries: BlendermannWind.parameters()
P_CUBIC = P_WINDP + N_WIND_PAR  # 3 entries: X_uuu, Y_vvv, N_rrr (0: off)
P_LIMIT = P_CUBIC + 3
P_WIND = P_LIMIT + 1  # 1.0: compute wind loads
N_PAR = P_WIND + 1

# Disturbance rows ``dist[b, k]``: zero-mean variations and noise at time k.
D_VC = 0  # current speed variation
D_BC = 1  # current direction variation
D_VW = 2  # wind speed gust
D_BW = 3  # wind direction variation
D_F = 4  # 3 unmodelled forces
D_E = 7  # sensor noise, _N_SENS channels
N_DIST = D_E + _N_SENS
N_GM = 7  # GM channels (the first seven)

# State row ``st[b]`` (batch) or ``st[r, k]`` (rollout).
S_NU = 0  # ν (3)
S_NUR = 3  # ν_r = ν − ν_c (3)
S_ETA = 6  # η = [north, east, ψ] (3)
S_CUR = 9  # body-frame current [u_c, v_c, 0] (3)
S_WIND = 12  # apparent wind [V_rw, γ_rw] (2)
S_WF = 14  # wind force [X, Y, N] (3)
S_TAU = 17  # applied τ (3)
S_SENS = 20  # sensor readings (_N_SENS)
S_INFO = S_SENS + _N_SENS
S_W = S_INFO  # the paper's w(k) (3)
S_STAT = S_W + 3  # divergence status
S_ENV = S_STAT + 1  # means [V_c, β_c, V_w, β_w] (4)
S_ACT = S_ENV + 4  # input τ (3)
N_ST = S_ACT + 3

#: The state-row layout.
LAYOUT = StateLayout((
    ("nu", S_NU, 3), ("nu_r", S_NUR, 3), ("eta", S_ETA, 3), ("current", S_CUR, 3),
    ("wind", S_WIND, 2), ("wind_force", S_WF, 3), ("tau", S_TAU, 3),
    ("sensors", S_SENS, _N_SENS), ("w", S_W, 3), ("status", S_STAT, 1),
    ("env_means", S_ENV, 4), ("input", S_ACT, 3),
))
#: Info blocks the environments expose.
INFO_BLOCKS = ("nu", "nu_r", "eta", "current", "wind", "wind_force", "tau")

STATUS_OK, STATUS_NONFINITE, STATUS_LIMIT = 0, 1, 2


@njit(cache=True, inline="always")
def wrap(a):
    """Angle wrapped to ``[−π, π)``."""
    return a - 2.0 * np.pi * np.floor((a + np.pi) / (2.0 * np.pi))


@njit(cache=True, inline="always")
def _observe(st, i, dist, b, j, par):
    """Current, wind and sensor readings of state row ``st[i]`` with noise ``dist[b, j]``."""
    u = st[i, S_NU]
    v = st[i, S_NU + 1]
    r = st[i, S_NU + 2]
    psi = st[i, S_ETA + 2]
    vc = st[i, S_ENV] + dist[b, j, D_VC]
    dc = st[i, S_ENV + 1] + dist[b, j, D_BC] - psi
    uc = vc * math.cos(dc)
    vcb = vc * math.sin(dc)
    vw = st[i, S_ENV + 2] + dist[b, j, D_VW]
    if vw < 0.0:
        vw = 0.0
    dw = st[i, S_ENV + 3] + dist[b, j, D_BW] - psi
    urw = u - vw * math.cos(dw)
    vrw = v - vw * math.sin(dw)
    v2 = urw * urw + vrw * vrw
    gam = -math.atan2(vrw, urw)
    xw = 0.0
    yw = 0.0
    nw = 0.0
    if v2 > 0.0 and par[P_WIND] > 0.0:
        xw, yw, nw = wind_load(gam, v2, par, P_WINDP)
    vr = math.sqrt(v2)
    st[i, S_CUR] = uc
    st[i, S_CUR + 1] = vcb
    st[i, S_CUR + 2] = 0.0
    st[i, S_NUR] = u - uc
    st[i, S_NUR + 1] = v - vcb
    st[i, S_NUR + 2] = r
    st[i, S_WIND] = vr
    st[i, S_WIND + 1] = gam
    st[i, S_WF] = xw
    st[i, S_WF + 1] = yw
    st[i, S_WF + 2] = nw
    e = D_E
    o = S_SENS
    st[i, o] = u + dist[b, j, e]
    st[i, o + 1] = v + dist[b, j, e + 1]
    st[i, o + 2] = (u - uc) + dist[b, j, e + 2]
    st[i, o + 3] = (v - vcb) + dist[b, j, e + 3]
    st[i, o + 4] = uc + dist[b, j, e + 4]
    st[i, o + 5] = vcb + dist[b, j, e + 5]
    st[i, o + 6] = vr + dist[b, j, e + 6]
    st[i, o + 7] = wrap(gam + dist[b, j, e + 7])
    st[i, o + 8] = r + dist[b, j, e + 8]
    st[i, o + 9] = wrap(psi + dist[b, j, e + 9])



@njit(cache=True, inline="always")
def _advance(st, i, i1, dist, b, j, codes, eq, theta, par, s):
    """One Euler step ``st[i] → st[i1]`` (``i1`` may equal ``i``) with disturbance rows
    ``dist[b, j]`` (time k) and ``dist[b, j + 1]`` (time k+1); input ``τ = st[i, S_ACT:]``.

    ``ν(k+1) = Φᵀ([ν(k) − ν_c(k); τ(k)]) θ0 + w(k)`` with
    ``w(k) = ν_c(k+1) + dt M⁻¹ (τ_wind + τ_noise [+ cubic damping])``. Needs ``_observe``
    of row ``i`` first (current and wind at time k). ``s`` is a work buffer of length
    ``19 + P``: signals ``[x + v; τ]``, factor vector, regressors. Returns the status.
    """
    dt = par[P_DT]
    u = st[i, S_NU]
    v = st[i, S_NU + 1]
    r = st[i, S_NU + 2]
    n0 = st[i, S_ETA]
    e0 = st[i, S_ETA + 1]
    psi = st[i, S_ETA + 2]
    # regressor signals [x + v; τ] with v = −ν_c
    s[0] = u - st[i, S_CUR]
    s[1] = v - st[i, S_CUR + 1]
    s[2] = r
    for q in range(3):
        s[3 + q] = st[i, S_ACT + q]
    # additive forces: wind + unmodelled noise (+ cubic damping)
    fx = st[i, S_WF] + dist[b, j, D_F]
    fy = st[i, S_WF + 1] + dist[b, j, D_F + 1]
    fn = st[i, S_WF + 2] + dist[b, j, D_F + 2]
    if par[P_CUBIC] != 0.0:
        fx += par[P_CUBIC] * s[0] * s[0] * s[0]
    if par[P_CUBIC + 1] != 0.0:
        fy += par[P_CUBIC + 1] * s[1] * s[1] * s[1]
    if par[P_CUBIC + 2] != 0.0:
        fn += par[P_CUBIC + 2] * s[2] * s[2] * s[2]
    # body-frame current at k+1 (heading after the step)
    psi1 = psi + dt * r
    vc1 = st[i, S_ENV] + dist[b, j + 1, D_VC]
    dc1 = st[i, S_ENV + 1] + dist[b, j + 1, D_BC] - psi1
    m = P_MINV
    w0 = vc1 * math.cos(dc1) + (par[m] * fx + par[m + 1] * fy + par[m + 2] * fn)
    w1 = vc1 * math.sin(dc1) + (par[m + 3] * fx + par[m + 4] * fy + par[m + 5] * fn)
    w2 = 0.0 + (par[m + 6] * fx + par[m + 7] * fy + par[m + 8] * fn)
    st[i, S_W] = w0
    st[i, S_W + 1] = w1
    st[i, S_W + 2] = w2
    for q in range(3):
        st[i, S_TAU + q] = s[3 + q]
    st[i1, S_NU] = w0
    st[i1, S_NU + 1] = w1
    st[i1, S_NU + 2] = w2
    advance(codes, eq, theta, s[:6], s[6:19], s[19:], st[i1, S_NU:S_NU + 3])
    c = math.cos(psi)
    sn = math.sin(psi)
    st[i1, S_ETA] = n0 + dt * (c * u - sn * v)
    st[i1, S_ETA + 1] = e0 + dt * (sn * u + c * v)
    st[i1, S_ETA + 2] = psi1
    status = STATUS_OK
    for q in range(3):
        x = st[i1, S_NU + q]
        if not math.isfinite(x):
            status = STATUS_NONFINITE
        elif abs(x) > par[P_LIMIT]:
            status = STATUS_LIMIT
    st[i1, S_STAT] = status
    return status

@kernel(parallel=True)
def _rollout_kernel(st, dist, codes, eq, theta, par, fail_at):
    """Roll out ``R`` vessels for ``N`` samples (parallel over vessels).

    ``st`` ``(R, N, N_ST)`` holds the initial ν, η in row 0, and the means and inputs in
    every row; everything else is written.
    """
    n_runs, n_samples = st.shape[0], st.shape[1]
    for b in prange(n_runs):
        s = np.empty(19 + theta.shape[0])
        x = st[b]
        fail_at[b] = -1
        _observe(x, 0, dist, b, 0, par)
        for k in range(n_samples - 1):
            status = _advance(x, k, k + 1, dist, b, k, codes, eq, theta, par, s)
            if status != STATUS_OK:
                fail_at[b] = k + 1
                for kk in range(k + 1, n_samples):
                    for q in range(S_INFO):
                        x[kk, q] = np.nan
                break
            _observe(x, k + 1, dist, b, k + 1, par)
        for q in range(3):
            x[n_samples - 1, S_W + q] = 0.0


@kernel()
def _env_chunk(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip, lo, hi, s):
    for b in range(lo, hi):
        if skip[b]:
            st[b, S_STAT] = 0.0
            for q in range(3):
                st[b, S_W + q] = 0.0
                st[b, S_TAU + q] = 0.0
        else:
            _advance(st, b, b, dist, b, j, codes, eq, theta, par, s)
        _observe(st, b, dist, b, j + 1, par)
        for q in range(obs_idx.shape[0]):
            obs[b, q] = st[b, S_SENS + obs_idx[q]]


@kernel()
def _env_step_serial(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip):
    """Advance a batch of vessels one step in place (serial; for single envs).

    Vessels with ``skip`` set are only observed (next-step autoreset).
    """
    s = np.empty(19 + theta.shape[0])
    _env_chunk(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip, 0, st.shape[0], s)


@kernel()
def _env_step_one(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip, a0, a1, a2, rpar):
    """One step of vessel 0 of a batch of one from normalised actions (the single
    environment): clip to ±1, scale by ``force_max = rpar[:3]``, step, and return the
    reward ``−(w_u (u − u_ref)² + w_ψ wrap(ψ − ψ_ref)² + w_a ‖a‖²)`` with ``rpar[3:8] =
    [u_ref, ψ_ref, w_u, w_ψ, w_a]`` (the operations of the environments' ``reward``)."""
    a0 = min(max(a0, -1.0), 1.0)
    a1 = min(max(a1, -1.0), 1.0)
    a2 = min(max(a2, -1.0), 1.0)
    st[0, S_ACT] = a0 * rpar[0]
    st[0, S_ACT + 1] = a1 * rpar[1]
    st[0, S_ACT + 2] = a2 * rpar[2]
    s = np.empty(19 + theta.shape[0])
    _env_chunk(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip, 0, 1, s)
    du = st[0, S_NU] - rpar[3]
    d = st[0, S_ETA + 2] - rpar[4]
    dpsi = d - 2.0 * np.pi * np.floor((d + np.pi) / (2.0 * np.pi))
    asq = a0 * a0 + a1 * a1 + a2 * a2
    return -(rpar[5] * du * du + rpar[6] * dpsi * dpsi + rpar[7] * asq)


@kernel(parallel=True)
def _env_step_parallel(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip, n_chunks):
    """Advance a batch of vessels one step in place, in ``n_chunks`` parallel chunks."""
    n_b = st.shape[0]
    for c in prange(n_chunks):
        s = np.empty(19 + theta.shape[0])
        _env_chunk(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip,
                   c * n_b // n_chunks, (c + 1) * n_b // n_chunks, s)


@njit(cache=True)
def _env_observe(st, dist, j, par, obs_idx, obs, mask):
    """Sensor readings at buffer row ``j`` for the vessels in ``mask`` (after a reset)."""
    for b in range(st.shape[0]):
        if mask[b]:
            _observe(st, b, dist, b, j, par)
            for q in range(obs_idx.shape[0]):
                obs[b, q] = st[b, S_SENS + obs_idx[q]]




# ------------------------------------------------------------------------ vessel model
@dataclass
class VesselModel:
    """A hull in a sea: the vessel plant (:class:`vesselid.plant.plant.Plant`).

    Builds the physics spec (:meth:`Hull.spec`), θ0, the term codes and the packed
    parameter vector of the compiled kernels, and draws the disturbance rows. Every vessel
    user goes through it: :meth:`simulate` (:func:`simulate_vessel`: offline and sea
    trials), :class:`VesselBatch` (the environments), :meth:`run` (manoeuvre switching
    instants, the trial planner's nominal path) and :meth:`disturbed_paths` (the trial
    planner's instrument–regressor cross moment).
    """

    hull: Hull
    dt: float = DEFAULT_DT
    disturbances: VesselDisturbances = field(default_factory=VesselDisturbances)
    sensors: VesselSensors = field(default_factory=VesselSensors)
    limit: float = DEFAULT_DIVERGENCE_LIMIT

    def __post_init__(self) -> None:
        self.dt = float(self.dt)
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise VesselidError(f"dt must be a positive number, got {self.dt}")
        self.disturbances = coerce(VesselDisturbances, self.disturbances, "disturbances")
        self.sensors = coerce(VesselSensors, self.sensors, "sensors")
        self.spec: ModelSpec = self.hull.spec(self.dt)
        self.codes = np.ascontiguousarray(self.spec.codes.factors)
        self.eq = np.ascontiguousarray(self.spec.codes.equation)
        self.theta = np.ascontiguousarray(self.spec.theta0_vector())
        d = self.disturbances
        self.wind_model = d.wind_model or self.hull.wind
        par = np.zeros(N_PAR)
        par[P_DT] = self.dt
        par[P_MINV:P_MINV + 9] = (self.dt * self.hull.mass_matrix_inverse()).ravel()
        par[P_WINDP:P_WINDP + N_WIND_PAR] = self.wind_model.parameters()
        if d.cubic_surge:
            par[P_CUBIC:P_CUBIC + 3] = self.hull.cubic
        par[P_LIMIT] = float(self.limit)
        par[P_WIND] = 1.0 if d.wind_on else 0.0
        self.par = par
        self.processes = d.processes(self.dt)
        self._gm = [(i, gm.pole, gm.std_, gm.bound_) for i, gm in enumerate(self.processes)
                    if not gm.is_zero]
        self.sensor_std = self.sensors.std_vector()
        self._noisy = np.flatnonzero(self.sensor_std > 0)
        self.obs_idx = self.sensors.channel_index()

    def env_means(self, n: int) -> np.ndarray:
        """``(n, 4)`` per-vessel means ``[V_c, β_c, V_w, β_w]``."""
        d = self.disturbances
        return np.tile([d.current_speed, d.current_direction, d.wind_speed,
                        d.wind_direction], (n, 1)).astype(float)

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable settings (log metadata)."""
        return {"name": self.hull.name, "dt": self.dt,
                "coefficients": dict(self.hull.parameters),
                "disturbances": self.disturbances.to_dict(), "sensors": self.sensors.to_dict()}

    # -- the plant (simulations, noise-free runs, disturbed paths, wind loads) --
    def simulate(
        self,
        inputs: np.ndarray,
        *,
        n_runs: int | None = None,
        seed: int | np.random.SeedSequence | None = None,
        run_seeds: Sequence[np.random.SeedSequence] | None = None,
        nu0: np.ndarray | None = None,
        eta0: np.ndarray | None = None,
        current_direction: np.ndarray | float | None = None,
        wind_direction: np.ndarray | float | None = None,
    ) -> VesselSimulation:
        """Trials of this plant with its disturbances and sensors (:func:`simulate_vessel`,
        whose parameters these are)."""
        return _simulate(self, inputs, n_runs, seed, run_seeds, nu0, eta0,
                         current_direction, wind_direction)

    # -- noise-free runs, disturbed paths, wind loads ----------------------------
    @property
    def dt_minv(self) -> np.ndarray:
        """``dt M⁻¹``: how a body-frame force ``[X, Y, N]`` enters the velocity in a step."""
        return self.dt * self.hull.mass_matrix_inverse()

    @property
    def force_max(self) -> tuple[float, float, float]:
        """Actuator limits ``|X|, |Y|, |N|`` of the hull."""
        return self.hull.force_max

    def run(self, inputs: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """Noise-free states ``x(0..n)`` ``(n + 1, 3)`` for forces ``(n, 3)`` from ``x0``
        (default at rest): the spec's θ0 in calm water (no current, wind or noise)."""
        tau = np.asarray(inputs, dtype=float)
        return simulate_states(self.spec, np.vstack([tau, tau[-1:]]), x0=x0, limit=self.limit)

    def wind_load(self, states: np.ndarray, psi: np.ndarray, speed: float,
                  direction: np.ndarray | float) -> np.ndarray:
        """Blendermann load ``(n, 3)`` of a true wind (``speed``, going-to ``direction``,
        earth frame) on the vessel moving with ``states`` ``[u, v, r]`` at heading ``psi``:
        :meth:`apparent_wind_load` of ``[u, v] − V_w [cos, sin](β_w − ψ)``."""
        d = direction - psi
        urw = states[:, 0] - speed * np.cos(d)
        vrw = states[:, 1] - speed * np.sin(d)
        return self.apparent_wind_load(urw, vrw)

    def apparent_wind_load(self, urw: np.ndarray, vrw: np.ndarray) -> np.ndarray:
        """Blendermann load ``(n, 3)`` of the body-frame air velocity ``[u_rw, v_rw] = ν −
        ν_w`` (angle ``γ_rw = −atan2(v_rw, u_rw)``, 0: wind from ahead) with the plant's
        wind model (:func:`~vesselid.plant.vessels.wind.blendermann_wind_force`)."""
        return blendermann_wind_force(-np.arctan2(vrw, urw), np.hypot(urw, vrw),
                                      self.wind_model)

    def wind_linearisation(self, states: np.ndarray, psi: np.ndarray,
                           step: float = 1e-4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The mean wind's load along ``states``/``psi`` and its derivatives with respect
        to the wind speed and direction (forward differences of ``step``): the gains
        through which gusts and direction changes act near that path."""
        d = self.disturbances
        base = self.wind_load(states, psi, d.wind_speed, d.wind_direction)
        g_speed = (self.wind_load(states, psi, d.wind_speed + step, d.wind_direction)
                   - base) / step
        g_dir = (self.wind_load(states, psi, d.wind_speed, d.wind_direction + step)
                 - base) / step
        return base, g_speed, g_dir

    def disturbed_paths(self, inputs: np.ndarray, x0: np.ndarray | None = None, *,
                        paths: int, seed: int,
                        nominal: np.ndarray | None = None) -> np.ndarray:
        """States ``(paths, n + 1, 3)`` driven by ``inputs`` plus random realisations of
        the process disturbances (no sensor noise), from ``default_rng(seed)``.

        Per path, in this order: the unmodelled forces (the three Gauss–Markov processes
        of :class:`VesselDisturbances`, one block, :func:`gauss_markov_rows`), the wind
        gusts and then the direction changes (each a Gauss–Markov process through the
        gain of the Blendermann load along the noise-free path, :meth:`wind_linearisation`;
        drawn when its std is positive and the plant computes wind loads), then the force
        of every plug-in component (:class:`DisturbanceComponent`, in order). The
        processes are taken Gaussian and unbounded (the linearisation the trial planner's
        covariance uses); their sum enters with the inputs. The states are the velocity
        through the water; current variations are not drawn. Every path starts from
        ``x0`` (default at rest). ``nominal``: the noise-free states :meth:`run` gives for
        these inputs and ``x0``, when the caller has them (else they are simulated).
        """
        tau = np.asarray(inputs, dtype=float)
        n = tau.shape[0]
        x_init = np.zeros(3) if x0 is None else np.asarray(x0, dtype=float)
        d = self.disturbances
        rng = np.random.default_rng(seed)
        gains = []
        if d.wind_on:
            xs = (self.run(tau, x_init) if nominal is None else nominal)[:-1]
            _, g_speed, g_dir = self.wind_linearisation(xs, heading(xs, self.dt))
            for g, std, tc in ((g_speed, d.gust_std, d.gust_time_constant),
                               (g_dir, d.wind_direction_std, d.wind_direction_time_constant)):
                if std > 0:
                    gains.append((g, np.array([float(std)]), math.exp(-self.dt / tc)))
        fn = np.asarray(d.force_noise_std, dtype=float)
        a_f = math.exp(-self.dt / d.force_noise_time_constant)
        out = np.empty((int(paths), n + 1, 3))
        for j in range(int(paths)):
            w = gauss_markov_rows(rng, fn, a_f, n).T
            for g, std, pole in gains:
                w = w + g * gauss_markov_rows(rng, std, pole, n).T
            for comp in d.components:
                drawn = comp.draw(rng, n, self.dt)
                if drawn.force is not None:
                    w = w + np.asarray(drawn.force, dtype=float).reshape(n, 3)
            out[j] = self.run(tau + w, x_init)
        return out

    # -- disturbance draws ---------------------------------------------------
    def draw_run(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """All disturbance rows of one run, ``(n, N_DIST)``, in a fixed draw order.

        GM variations with :meth:`GaussMarkov.sample`, then the sensor noise (Gaussian
        clipped at ``clip`` std), then the plug-in components in order.
        """
        out = np.zeros((n, N_DIST))
        for i, gm in enumerate(self.processes):
            if not gm.is_zero:
                out[:, i] = gm.sample(rng, n)
        z = rng.standard_normal((n, _N_SENS))
        clip = self.sensors.clip
        np.clip(z, -clip, clip, out=z)
        out[:, D_E:] = z * self.sensor_std
        for comp in self.disturbances.components:
            drawn = comp.draw(rng, n, self.dt)
            if drawn.force is not None:
                out[:, D_F:D_F + 3] += np.asarray(drawn.force, dtype=float).reshape(n, 3)
            for ch, val in drawn.sensors.items():
                if ch not in SENSOR_CHANNELS:
                    raise VesselidError(f"component {comp.name!r}: unknown sensor channel "
                                        f"{ch!r}; known: {list(SENSOR_CHANNELS)}")
                out[:, D_E + SENSOR_CHANNELS.index(ch)] += np.asarray(val, dtype=float)
        return out

    def start_block(self, rng: np.random.Generator, buf: np.ndarray,
                    latent: np.ndarray) -> None:
        """Fill a ``(B, K+1, N_DIST)`` block buffer from a stationary start.

        ``latent`` ``(B, N_GM)`` keeps the unsaturated GM states between blocks.
        """
        n_b = buf.shape[0]
        buf[:, 0, :] = 0.0
        latent[:] = 0.0
        for i, _a, std, bound in self._gm:
            g = std * rng.standard_normal(n_b)
            latent[:, i] = g
            buf[:, 0, i] = bound * np.tanh(g / bound) if math.isfinite(bound) else g
        self._sensor_noise(rng, buf[:, 0:1, :])
        buf[:, 1:, :] = 0.0
        self.continue_block(rng, buf, latent, first=True)

    def continue_block(self, rng: np.random.Generator, buf: np.ndarray, latent: np.ndarray,
                       *, first: bool = False) -> None:
        """Draw rows ``1..K`` continuing every GM process from row 0 (row K → row 0 first).

        Same recursion and saturation as :meth:`GaussMarkov.sample`
        (``g(k) = a g(k−1) + ε(k)``, bounded processes ``b·tanh(g/b)``), so the block-wise
        draws of the environments form one stationary process. One normal draw per block
        covers the GM innovations and the sensor noise.
        """
        if not first:
            buf[:, 0, :] = buf[:, -1, :]
        n_b, k1 = buf.shape[0], buf.shape[1] - 1
        n_gm, idx = len(self._gm), self._noisy
        if n_gm + idx.size == 0:
            return
        z = rng.standard_normal((n_gm + idx.size, n_b, k1))
        for c, (i, a, std, bound) in enumerate(self._gm):
            innov = z[c]
            innov *= std * math.sqrt(1.0 - a * a)
            g = ar1_filter(innov, a, a * latent[:, i])
            latent[:, i] = g[:, -1]
            if math.isfinite(bound):
                g *= 1.0 / bound
                np.tanh(g, out=g)
                g *= bound
            buf[:, 1:, i] = g
        if idx.size:
            e = z[n_gm:]
            clip = self.sensors.clip
            np.clip(e, -clip, clip, out=e)
            e *= self.sensor_std[idx][:, None, None]
            for c, i in enumerate(idx):
                buf[:, 1:, D_E + i] = e[c]

    def _sensor_noise(self, rng: np.random.Generator, view: np.ndarray) -> None:
        idx = self._noisy
        view[..., D_E:] = 0.0
        if idx.size == 0:
            return
        z = rng.standard_normal((*view.shape[:-1], idx.size))
        clip = self.sensors.clip
        np.clip(z, -clip, clip, out=z)
        z *= self.sensor_std[idx]
        view[..., D_E + idx] = z


# --------------------------------------------------------------------- batch simulator
@dataclass
class VesselSimulation(SimulationResult):
    """Result of :func:`simulate_vessel`; arrays have shape ``(runs, samples, ·)``.

    Properties: ``nu`` true absolute velocity ``[u, v, r]`` (the paper's ``x``), ``nu_r``
    velocity relative to water (the aggregated state ``x + v``), ``nu_c`` body-frame
    current ``[u_c, v_c, 0]``, ``v = −nu_c`` and ``w`` the paper's disturbances of (1a)
    (``w[:, -1]`` is zero, unused), ``eta = [north, east, ψ]`` (ψ not wrapped), ``tau``
    applied forces, ``wind`` apparent wind ``[V_rw, γ_rw]``, ``tau_wind`` its force,
    ``sensors`` readings of all channels (:data:`SENSOR_CHANNELS`).
    """

    model: VesselModel
    state: np.ndarray
    seed: int | None = None
    spawn_keys: list | None = None

    def _cols(self, start: int, n: int) -> np.ndarray:
        return self.state[..., start:start + n]

    nu = property(lambda self: self._cols(S_NU, 3), doc="True absolute velocity ν.")
    nu_r = property(lambda self: self._cols(S_NUR, 3), doc="ν_r = ν − ν_c.")
    nu_c = property(lambda self: self._cols(S_CUR, 3), doc="Body-frame current [u_c, v_c, 0].")
    eta = property(lambda self: self._cols(S_ETA, 3), doc="η = [north, east, ψ].")
    tau = property(lambda self: self._cols(S_ACT, 3), doc="Applied forces [X, Y, N].")
    wind = property(lambda self: self._cols(S_WIND, 2), doc="Apparent wind [V_rw, γ_rw].")
    tau_wind = property(lambda self: self._cols(S_WF, 3), doc="Wind force [X, Y, N].")
    sensors = property(lambda self: self._cols(S_SENS, _N_SENS), doc="Sensor readings.")
    w = property(lambda self: self._cols(S_W, 3), doc="The paper's additive w(k).")
    env_means = property(lambda self: self.state[:, 0, S_ENV:S_ENV + 4],
                         doc="Per-run means [V_c, β_c, V_w, β_w].")

    @property
    def v(self) -> np.ndarray:
        """The paper's non-additive disturbance ``v(k) = −ν_c(k)``."""
        return -self.nu_c

    @property
    def spec(self) -> ModelSpec:
        return self.model.spec

    def _lead(self) -> np.ndarray:
        return self.state

    def _dt(self) -> float:
        return self.model.dt

    def columns(self) -> dict[str, np.ndarray]:
        """:func:`log_columns` of the run arrays: measured ``u, v`` (GNSS), ``r`` (gyro),
        inputs ``X, Y, N``, ``psi``, speed log ``u_log, v_log, r_log``, current meter
        ``u_c, v_c``, anemometer ``wind_speed, wind_angle`` (enabled sensors only) and
        ground truth ``true_*``."""
        arrays = {"nu": self.nu, "nu_r": self.nu_r, "current": self.nu_c, "eta": self.eta,
                  "tau": self.tau}

        def get(block: str, i: int) -> np.ndarray:
            if block in arrays:
                return arrays[block][:, :, i].ravel()
            return self.sensors[:, :, SENSOR_CHANNELS.index(SENSOR_GROUPS[block][i])].ravel()

        return log_columns(get, self.model.sensors.enabled)

    def to_log(self, *, aggregate: str | None = None):
        """A :class:`~vesselid.data.logs.TrialLog` with metadata (spec, θ0, seeds, settings).

        Parameters
        ----------
        aggregate : {None, "current_meter"}
            ``"current_meter"`` attaches the aggregate relations ``u - u_c``, ``v - v_c``
            (paper eq. (9)) to the spec in the metadata. The speed-log columns
            ``u_log, v_log, r_log`` measure the aggregated state directly (Remark 4.3).
        """
        spec = self.spec
        if aggregate == "current_meter":
            spec = spec.with_aggregate({"u": "u - u_c", "v": "v - v_c"})
        elif aggregate is not None:
            raise VesselidError(f"unknown aggregate option {aggregate!r}")
        return self._trial_log(spec, {**self.model.describe(),
                                      "env_means": np.asarray(self.env_means).tolist()})


def log_columns(get: Callable[[str, int], Any], enabled: Sequence[str], *,
                inputs: bool = True) -> dict[str, Any]:
    """The trial-log columns of a vessel: the one schema of simulations and environments.

    ``get(block, i)`` returns component ``i`` of a :data:`LAYOUT` block (``nu``, ``nu_r``,
    ``current``, ``eta``, ``tau``) or of an enabled sensor group (:data:`SENSOR_GROUPS`);
    ``enabled`` lists the enabled groups; ``inputs`` adds ``X, Y, N``.
    """
    row: dict[str, Any] = {}
    if "gnss" in enabled:
        row["u"], row["v"] = get("gnss", 0), get("gnss", 1)
    if "gyro" in enabled:
        row["r"] = get("gyro", 0)
    if inputs:
        row["X"], row["Y"], row["N"] = get("tau", 0), get("tau", 1), get("tau", 2)
    if "heading" in enabled:
        row["psi"] = get("heading", 0)
    if "speed_log" in enabled:
        row["u_log"], row["v_log"] = get("speed_log", 0), get("speed_log", 1)
        if "gyro" in enabled:
            row["r_log"] = get("gyro", 0)
    if "current_meter" in enabled:
        row["u_c"], row["v_c"] = get("current_meter", 0), get("current_meter", 1)
    if "anemometer" in enabled:
        row["wind_speed"], row["wind_angle"] = get("anemometer", 0), get("anemometer", 1)
    for i, c in enumerate(("u", "v", "r")):
        row[f"true_{c}"] = get("nu", i)
    row["true_u_r"], row["true_v_r"] = get("nu_r", 0), get("nu_r", 1)
    row["true_u_c"], row["true_v_c"] = get("current", 0), get("current", 1)
    for i, c in enumerate(("north", "east", "psi")):
        row[f"true_{c}"] = get("eta", i)
    return row


def simulate_vessel(
    hull: Hull,
    inputs: np.ndarray,
    *,
    n_runs: int | None = None,
    seed: int | np.random.SeedSequence | None = None,
    run_seeds: Sequence[np.random.SeedSequence] | None = None,
    dt: float = DEFAULT_DT,
    disturbances: VesselDisturbances | Mapping[str, Any] | None = None,
    sensors: VesselSensors | Mapping[str, Any] | None = None,
    nu0: np.ndarray | None = None,
    eta0: np.ndarray | None = None,
    current_direction: np.ndarray | float | None = None,
    wind_direction: np.ndarray | float | None = None,
    limit: float = DEFAULT_DIVERGENCE_LIMIT,
) -> VesselSimulation:
    """Simulate trials of a hull with current, wind, force noise and sensors.

    Runs the compiled batch kernel (parallel over runs). Run ``r`` draws all its
    disturbances from ``default_rng(SeedSequence(seed).spawn(R)[r])`` in a fixed order
    (:meth:`VesselModel.draw_run`), so results are deterministic and any run can be
    regenerated alone.

    Parameters
    ----------
    hull : Hull
        The vessel.
    inputs : ndarray, shape (R, N, 3) or (N, 3)
        Generalised forces ``τ = [X, Y, N]`` (N, N, N m) per run and sample.
    n_runs : int, optional
        Number of runs when ``inputs`` is ``(N, 3)`` (the same input for all runs).
    seed, run_seeds
        Root seed, or explicit per-run seed sequences.
    dt : float
        Sample time (s).
    disturbances, sensors : settings or mapping, optional
        Defaults: no current, wind or force noise; default sensors.
    nu0 : ndarray, shape (3,) or (R, 3), optional
        Initial absolute velocity; default: at rest in the water (``ν(0) = ν_c(0)``).
    eta0 : ndarray, shape (3,) or (R, 3), optional
        Initial ``[north, east, ψ]``; default zeros.
    current_direction, wind_direction : float or ndarray (R,), optional
        Per-run mean directions overriding the settings.
    limit : float
        Divergence limit on ``|ν|``.

    Returns
    -------
    VesselSimulation

    Raises
    ------
    SimulationDivergedError
        If a run becomes non-finite or exceeds ``limit``.
    """
    model = VesselModel(hull=hull, dt=dt, disturbances=disturbances, sensors=sensors,
                        limit=limit)
    return model.simulate(inputs, n_runs=n_runs, seed=seed, run_seeds=run_seeds, nu0=nu0,
                          eta0=eta0, current_direction=current_direction,
                          wind_direction=wind_direction)


def _simulate(
    model: VesselModel,
    inputs: np.ndarray,
    n_runs: int | None,
    seed: int | np.random.SeedSequence | None,
    run_seeds: Sequence[np.random.SeedSequence] | None,
    nu0: np.ndarray | None,
    eta0: np.ndarray | None,
    current_direction: np.ndarray | float | None,
    wind_direction: np.ndarray | float | None,
) -> VesselSimulation:
    """The body of :meth:`VesselModel.simulate`."""
    hull, limit = model.hull, model.limit
    tau = np.asarray(inputs, dtype=np.float64)
    if tau.ndim == 2:
        tau = tau[None]
    if tau.ndim != 3 or tau.shape[2] != 3:
        raise VesselidError(f"inputs must have shape (R, N, 3) or (N, 3), got {np.shape(inputs)}")
    if run_seeds is not None:
        n_r = len(run_seeds)
    elif n_runs is not None:
        n_r = int(n_runs)
    else:
        n_r = tau.shape[0]
    if n_r < 1:
        raise VesselidError(f"need at least one run, got {n_r}")
    if tau.shape[0] not in (1, n_r):
        raise VesselidError(f"inputs hold {tau.shape[0]} runs but {n_r} runs were asked for")
    n_k = tau.shape[1]
    if n_k < 2:
        raise VesselidError(f"need at least 2 samples, got {n_k}")
    if not np.all(np.isfinite(tau)):
        raise VesselidError("inputs hold non-finite values")
    tau = np.ascontiguousarray(np.broadcast_to(tau, (n_r, n_k, 3)))
    if run_seeds is None:
        run_seeds = seeds.run_seeds(seed, n_r)
    dist = np.empty((n_r, n_k, N_DIST))
    for r, ss in enumerate(run_seeds):
        dist[r] = model.draw_run(np.random.default_rng(ss), n_k)
    envp = model.env_means(n_r)
    if current_direction is not None:
        envp[:, 1] = np.broadcast_to(np.asarray(current_direction, dtype=float), n_r)
    if wind_direction is not None:
        envp[:, 3] = np.broadcast_to(np.asarray(wind_direction, dtype=float), n_r)
    eta0_arr = np.zeros((n_r, 3)) if eta0 is None else np.asarray(eta0, dtype=float)
    eta0_arr = np.broadcast_to(np.atleast_2d(eta0_arr), (n_r, 3))
    if nu0 is None:
        vc = envp[:, 0] + dist[:, 0, D_VC]
        dc = envp[:, 1] + dist[:, 0, D_BC] - eta0_arr[:, 2]
        nu0_arr = np.column_stack([vc * np.cos(dc), vc * np.sin(dc), np.zeros(n_r)])
    else:
        nu0_arr = np.asarray(nu0, dtype=float)
    nu0_arr = np.broadcast_to(np.atleast_2d(nu0_arr), (n_r, 3))
    if not (np.all(np.isfinite(nu0_arr)) and np.all(np.isfinite(eta0_arr))):
        raise VesselidError("nu0 and eta0 must be finite")
    st = np.zeros((n_r, n_k, N_ST))
    st[:, 0, S_NU:S_NU + 3] = nu0_arr
    st[:, 0, S_ETA:S_ETA + 3] = eta0_arr
    st[:, :, S_ENV:S_ENV + 4] = envp[:, None, :]
    st[:, :, S_ACT:S_ACT + 3] = tau
    fail_at = np.empty(n_r, dtype=np.int64)
    _rollout_kernel(st, dist, model.codes, model.eq, model.theta, model.par, fail_at)
    if np.any(fail_at >= 0):
        bad = np.flatnonzero(fail_at >= 0)
        r = int(bad[0])
        raise SimulationDivergedError(
            f"{hull.name} simulation diverged in {bad.size} of {n_r} run(s): run {r} became "
            f"non-finite or exceeded |ν| > {limit:g} at sample {int(fail_at[r])}; reduce the "
            f"input forces or dt"
        )
    seed_int = None if seed is None or isinstance(seed, np.random.SeedSequence) else int(seed)
    return VesselSimulation(model=model, state=st, seed=seed_int,
                                spawn_keys=[list(ss.spawn_key) for ss in run_seeds])




# -------------------------------------------------------------------- stepped batches
class VesselBatch:
    """``B`` vessels stepped one sample at a time (the environments' plant).

    Disturbances are pre-drawn in blocks of ``block`` samples per vessel from the
    generator given to :meth:`start` (stationary Gauss–Markov processes continue across
    blocks). Plug-in disturbance components are not supported here (they are drawn per
    run by :func:`simulate_vessel`).

    Attributes
    ----------
    st : ndarray (B, N_ST)
        State rows (:data:`LAYOUT`).
    obs : ndarray (B, n_channels), float32
        Readings of the enabled sensor channels after the last step/observe.
    """

    def __init__(self, model: VesselModel, n: int, *, block: int, parallel: bool = False,
                 n_chunks: int = 1) -> None:
        if model.disturbances.components:
            raise VesselidError("plug-in disturbance components are only simulated by "
                                "simulate_vessel, not by the stepped environments")
        self.model = model
        self.n = int(n)
        self.block = int(block)
        self.parallel = bool(parallel)
        self.n_chunks = int(n_chunks)
        self.channels = model.sensors.channels
        self.st = np.zeros((self.n, N_ST))
        self.dist = np.zeros((self.n, self.block + 1, N_DIST))
        self.latent = np.zeros((self.n, N_GM))
        self.obs = np.zeros((self.n, len(self.channels)), dtype=np.float32)
        self._views()
        self.j = 0
        self.rng: np.random.Generator | None = None
        self.no_skip = np.zeros(self.n, dtype=np.bool_)
        self.info_slices = ([(k, LAYOUT.slice(k)) for k in INFO_BLOCKS]
                            + LAYOUT.sensor_slices(model.sensors))

    def _views(self) -> None:
        """Views of vessel 0 (the single environment's): its readings and info block."""
        self.obs0 = self.obs[0]
        self.info0 = self.st[0, :S_INFO]

    def __getstate__(self) -> dict[str, Any]:  # a copy's views must view its own arrays
        return {k: v for k, v in self.__dict__.items() if k not in ("obs0", "info0")}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._views()

    def set_state(self, idx: np.ndarray, nu: np.ndarray, eta: np.ndarray,
                  current_direction: np.ndarray, wind_direction: np.ndarray) -> None:
        """Initial ``ν``, ``η`` and mean directions of the vessels ``idx``."""
        d = self.model.disturbances
        st = self.st
        st[idx] = 0.0
        st[idx, S_NU:S_NU + 3] = nu
        st[idx, S_ETA:S_ETA + 3] = eta
        st[idx, S_ENV] = d.current_speed
        st[idx, S_ENV + 1] = current_direction
        st[idx, S_ENV + 2] = d.wind_speed
        st[idx, S_ENV + 3] = wind_direction

    def start(self, rng: np.random.Generator) -> None:
        """Draw the first disturbance block from ``rng`` and observe every vessel."""
        m = self.model
        self.rng = rng
        m.start_block(rng, self.dist, self.latent)
        self.j = 0
        _env_observe(self.st, self.dist, 0, m.par, m.obs_idx, self.obs,
                     np.ones(self.n, dtype=np.bool_))

    def step(self, tau: np.ndarray, skip: np.ndarray) -> None:
        """Apply forces ``τ`` ``(B, 3)`` for one sample; vessels in ``skip`` are only
        observed (next-step autoreset)."""
        if self.j >= self.block:
            self.model.continue_block(self.rng, self.dist, self.latent)
            self.j = 0
        m = self.model
        self.st[:, S_ACT:S_ACT + 3] = tau
        if self.parallel:
            _env_step_parallel(self.st, self.dist, self.j, m.codes, m.eq, m.theta, m.par,
                               m.obs_idx, self.obs, skip, self.n_chunks)
        else:
            _env_step_serial(self.st, self.dist, self.j, m.codes, m.eq, m.theta, m.par,
                             m.obs_idx, self.obs, skip)
        self.j += 1

    def step_one(self, a0: float, a1: float, a2: float, rpar: np.ndarray) -> float:
        """:meth:`step` for a batch of one vessel (``B = 1``, not skipped) from the
        normalised actions as floats, with the clipping, force scaling and reward of the
        environments in the same compiled call (:func:`_env_step_one`; ``rpar``:
        ``force_max``, ``u_ref``, ``ψ_ref`` and the reward weights); returns the reward."""
        if self.j >= self.block:
            self.model.continue_block(self.rng, self.dist, self.latent)
            self.j = 0
        m = self.model
        r = _env_step_one(self.st, self.dist, self.j, m.codes, m.eq, m.theta, m.par,
                          m.obs_idx, self.obs, self.no_skip, a0, a1, a2, rpar)
        self.j += 1
        return r

    def info_one(self) -> dict[str, np.ndarray]:
        """:meth:`info` of vessel 0 of a batch of one: the fresh copy is taken now, its
        views are made when the dict is first read (:class:`LazyInfo`)."""
        return LazyInfo(self.info0.copy(), self.info_slices)

    def block_of(self, name: str) -> np.ndarray:
        """View of a named block of every vessel's state row (:data:`LAYOUT`)."""
        return self.st[:, LAYOUT.slice(name)]

    @property
    def diverged(self) -> np.ndarray:
        """Vessels whose last step diverged (non-finite or beyond the limit)."""
        return self.st[:, S_STAT] != STATUS_OK

    def info(self, row: int | None = None) -> dict[str, np.ndarray]:
        """Info dict (views into one fresh copy); ``row`` selects a single vessel."""
        buf = self.st[row if row is not None else slice(None), :S_INFO].copy()
        return {k: buf[..., sl] for k, sl in self.info_slices}


def _filled(method: str) -> Callable[..., Any]:
    """``dict.<method>`` run after :meth:`LazyInfo._fill`."""
    base = getattr(dict, method)

    def wrapper(self: LazyInfo, *args: Any, **kwargs: Any) -> Any:
        if self._buf is not None:
            self._fill()
        return base(self, *args, **kwargs)

    wrapper.__name__ = wrapper.__qualname__ = method
    wrapper.__doc__ = base.__doc__
    return wrapper


class LazyInfo(dict):
    """The info dict of a single environment's step: views into one fresh copy of the
    vessel's info block, made when the dict is first read.

    The copy is taken at the step (the values are that step's); building a dozen array
    views costs more than the step itself, and most callers never read ``info``. Every
    dict operation fills the dict first, so it behaves as the plain dict of those views;
    a copy, ``dict(info)`` or a pickled/unpickled one is a plain dict.
    """

    __slots__ = ("_buf", "_slices")

    def __init__(self, buf: np.ndarray, slices: Sequence[tuple[str, slice]]) -> None:
        # (dict.__new__ made the empty dict; dict.__init__ without arguments adds nothing)
        self._buf: np.ndarray | None = buf
        self._slices = slices

    def _fill(self) -> None:
        buf, self._buf = self._buf, None
        if buf is not None:
            view = buf.__getitem__
            for k, sl in self._slices:
                dict.__setitem__(self, k, view(sl))

    def copy(self) -> dict[str, Any]:
        return dict(self.items())

    def __reduce__(self) -> tuple[Any, ...]:
        return dict, (dict(self.items()),)

    def __reduce_ex__(self, protocol: Any) -> tuple[Any, ...]:
        return self.__reduce__()

    for _m in ("__getitem__", "__setitem__", "__delitem__", "__iter__", "__reversed__",
               "__len__", "__contains__", "__repr__", "__eq__", "__ne__", "__or__",
               "__ror__", "__ior__", "__sizeof__", "keys", "values", "items", "get", "pop",
               "popitem", "setdefault", "update", "clear"):
        locals()[_m] = _filled(_m)
    del _m
