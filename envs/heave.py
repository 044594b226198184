"""``vesselid/Heave-v0``: heave velocity control of an underwater vehicle (paper §6).

The plant is the heave system of :func:`vesselid.systems.heave`,

``w_a(k+1) = a0 w_r(k) + n0 w_r(k)|w_r(k)| + f0 τ(k) + ξ(k)``,  ``w_r = w_a − w_c``,

with θ0 = [a0, n0, f0] = [0.99, −0.1, 1], measured by ``y1 = w_a + e1`` and, optionally,
a current meter ``y2 = w_c + e2``. The one-step map is evaluated by a compiled kernel from
the system's factor layout and θ0 (:func:`vesselid.regressors.advance`), the same encoding the
simulator and the estimators use; nothing here re-implements the model by hand.

:class:`HeaveEnv` is the single environment, :class:`HeaveVectorEnv` the batched one
(``gym.make_vec(..., vectorization_mode="vector_entry_point")``): one compiled kernel
steps all sub-environments, with next-step autoreset.

Both implement the recorder contract of :mod:`vesselid.envs.recorder`
(``model_spec``, ``log_row``, ``log_inputs``, ``log_metadata``).
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from typing import Any, ClassVar, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numba import njit

from vesselid.disturbances import Gaussian
from vesselid.envs._render import FigureRenderer
from vesselid.errors import VesselidError
from vesselid.model import ModelSpec
from vesselid.regressors import advance, kernel
from vesselid.systems import System, heave

__all__ = ["HeaveEnv", "HeaveVectorEnv"]

# --------------------------------------------------------------------------- layout
# Parameter vector ``par`` (float64) shared by the kernels.
_SIGN = 0  # coupling sign of the current: v = sign * w_c (−1: w_r = w_a − w_c)
_CM = 1  # current mean
_CS = 2  # current std
_XM = 3  # ξ mean
_XS = 4  # ξ std
_E1 = 5  # velocity sensor noise std
_E2 = 6  # current sensor noise std
_TLO = 7  # thrust at action −1
_THI = 8  # thrust at action +1
_COST = 9  # action cost on τ²
_VLIM = 10  # |w_a| above this terminates
_RMODE = 11  # 0: constant reference, 1: random piecewise-constant
_RLO = 12  # constant reference value, or lower level of the random schedule
_RHI = 13  # upper level of the random schedule
_HMIN = 14  # shortest hold of a reference level (steps)
_HMAX = 15  # longest hold
_W0LO = 16  # initial velocity range
_W0HI = 17
_NPAR = 18

# Per-environment state ``st[row, env]`` (float64).
_WA = 0  # true absolute velocity w_a(k)
_WC = 1  # current w_c(k) (acts in the step k -> k+1)
_XI = 2  # process disturbance ξ(k) (enters w_a(k+1))
_Y1 = 3  # velocity measurement y1(k)
_Y2 = 4  # current-meter reading y2(k)
_REF = 5  # reference w_ref(k)
_HOLD = 6  # steps the reference stays at its level (counting the current one)
_NST = 7

# Pre-drawn randomness per environment and time instant: 4 standard normals (current,
# ξ, e1, e2) and 3 uniforms (reference level, reference hold, initial velocity).
_NZ = 4
_NU = 3

#: Time instants of noise drawn at once by the single environment.
SINGLE_BLOCK = 1024
#: Target number of env-instants of noise per block in the vector environment.
VECTOR_BLOCK_ELEMENTS = 1 << 16


# --------------------------------------------------------------------------- kernels
@njit(cache=True, inline="always")
def _thrust(par, a):
    """Physical thrust of a normalised action (clipped to [−1, 1])."""
    if a < -1.0:
        a = -1.0
    elif a > 1.0:
        a = 1.0
    return par[_TLO] + (a + 1.0) * 0.5 * (par[_THI] - par[_TLO])


@njit(cache=True)
def _thrust_array(par, a, out):
    for i in range(a.shape[0]):
        out[i] = _thrust(par, a[i])


@njit(cache=True, inline="always")
def _sense(par, st, i, z):
    """Disturbances and sensor readings of the current time instant."""
    wc = par[_CM] + par[_CS] * z[0]
    st[_WC, i] = wc
    st[_XI, i] = par[_XM] + par[_XS] * z[1]
    st[_Y1, i] = st[_WA, i] + par[_E1] * z[2]
    st[_Y2, i] = wc + par[_E2] * z[3]


@njit(cache=True, inline="always")
def _new_reference(par, st, i, u_level, u_hold):
    if par[_RMODE] > 0.5:
        st[_REF, i] = par[_RLO] + (par[_RHI] - par[_RLO]) * u_level
        st[_HOLD, i] = par[_HMIN] + np.floor(u_hold * (par[_HMAX] - par[_HMIN] + 1.0))
    else:
        st[_REF, i] = par[_RLO]
        st[_HOLD, i] = np.inf


@njit(cache=True, inline="always")
def _start(par, st, i, z, u):
    """Initial state, reference and first readings of environment ``i``."""
    st[_WA, i] = par[_W0LO] + (par[_W0HI] - par[_W0LO]) * u[2]
    _new_reference(par, st, i, u[0], u[1])
    _sense(par, st, i, z)


@njit(cache=True, inline="always")
def _advance(codes, eq, theta, par, sig, st, i, a, z, u):
    """One transition of environment ``i``; returns (τ, reward, terminated).

    ``w_a(k+1) = Φᵀ([w_a(k) + sign·w_c(k); τ(k)]) θ0 + ξ(k)`` with the system's factor
    layout ``codes, eq``; ``sig`` is a work buffer of length ``8 + P``.
    """
    tau = _thrust(par, a)
    sig[0] = st[_WA, i] + par[_SIGN] * st[_WC, i]
    sig[1] = tau
    out = sig[7:8]
    out[0] = st[_XI, i]
    advance(codes, eq, theta, sig[:2], sig[2:7], sig[8:], out)
    nxt = out[0]
    err = nxt - st[_REF, i]
    reward = -(err * err) - par[_COST] * tau * tau
    st[_WA, i] = nxt
    st[_HOLD, i] -= 1.0
    if st[_HOLD, i] <= 0.0:
        _new_reference(par, st, i, u[0], u[1])
    _sense(par, st, i, z)
    terminated = not (abs(nxt) <= par[_VLIM])  # also true for NaN
    return tau, reward, terminated


@njit(cache=True)
def _single_reset(par, st, z, u):
    _start(par, st, 0, z, u)


@kernel()
def _single_step(codes, eq, theta, par, sig, st, z, u, a):
    tau, reward, terminated = _advance(codes, eq, theta, par, sig, st, 0, a, z, u)
    return (tau, reward, terminated, st[_WA, 0], st[_WC, 0], st[_XI, 0], st[_Y1, 0],
            st[_Y2, 0], st[_REF, 0])


@njit(cache=True, inline="always")
def _write_obs(st, i, obs, sensor):
    obs[i, 0] = st[_Y1, i]
    if sensor:
        obs[i, 1] = st[_Y2, i]
        obs[i, 2] = st[_REF, i]
    else:
        obs[i, 1] = st[_REF, i]


@njit(cache=True)
def _vector_reset(par, st, steps, prev_done, z, u, obs, sensor):
    for i in range(st.shape[1]):
        _start(par, st, i, z[i], u[i])
        steps[i] = 0
        prev_done[i] = False
        _write_obs(st, i, obs, sensor)


@kernel()
def _vector_step(codes, eq, theta, par, sig, st, steps, prev_done, a, z, u, max_steps, obs, rew,
                 term, trunc, tau, sensor):
    """Step every sub-environment; those done at the previous step are reset instead."""
    for i in range(st.shape[1]):
        if prev_done[i]:
            _start(par, st, i, z[i], u[i])
            steps[i] = 0
            rew[i] = 0.0
            term[i] = False
            trunc[i] = False
            tau[i] = np.nan
        else:
            t_i, r_i, d_i = _advance(codes, eq, theta, par, sig, st, i, a[i], z[i], u[i])
            steps[i] += 1
            rew[i] = r_i
            term[i] = d_i
            trunc[i] = max_steps > 0 and steps[i] >= max_steps
            tau[i] = t_i
        prev_done[i] = term[i] or trunc[i]
        _write_obs(st, i, obs, sensor)


# ------------------------------------------------------------------------ settings
def _pair(name: str, value: Any, *, strict: bool = True) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise VesselidError(f"{name} must be a pair (low, high), got {value!r}") from exc
    if not (math.isfinite(lo) and math.isfinite(hi)) or (hi <= lo if strict else hi < lo):
        raise VesselidError(f"{name} must be finite with low < high, got {value!r}")
    return lo, hi


def _finite(name: str, value: Any, *, nonneg: bool = False, positive: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise VesselidError(f"{name} must be a number, got {value!r}") from exc
    if not math.isfinite(v) or (nonneg and v < 0) or (positive and v <= 0):
        what = "positive" if positive else "non-negative" if nonneg else "finite"
        raise VesselidError(f"{name} must be {what}, got {value!r}")
    return v


class _HeaveConfig:
    """Validated settings shared by :class:`HeaveEnv` and :class:`HeaveVectorEnv`."""

    def __init__(
        self,
        *,
        current_mean: float,
        current_std: float,
        xi_mean: float | None,
        xi_std: float,
        sensor_std: float,
        current_sensor: bool | None,
        current_sensor_std: float,
        thrust_range: tuple[float, float],
        reference: float | str,
        reference_range: tuple[float, float],
        reference_hold: tuple[int, int],
        action_cost: float,
        initial_velocity: tuple[float, float],
        velocity_limit: float,
    ) -> None:
        cm = _finite("current_mean", current_mean)
        cs = _finite("current_std", current_std, nonneg=True)
        xm = cm - 0.05 if xi_mean is None else _finite("xi_mean", xi_mean)
        xs = _finite("xi_std", xi_std, nonneg=True)
        e1 = _finite("sensor_std", sensor_std, nonneg=True)
        e2 = _finite("current_sensor_std", current_sensor_std, nonneg=True)
        sensor = (cm != 0.0) if current_sensor is None else bool(current_sensor)
        t_lo, t_hi = _pair("thrust_range", thrust_range)
        vlim = _finite("velocity_limit", velocity_limit, positive=True)
        w0_lo, w0_hi = _pair("initial_velocity", initial_velocity, strict=False)
        cost = _finite("action_cost", action_cost, nonneg=True)
        if isinstance(reference, str):
            if reference != "random":
                raise VesselidError(
                    f"reference must be a number or 'random', got {reference!r}"
                )
            r_lo, r_hi = _pair("reference_range", reference_range, strict=False)
            h_lo, h_hi = _pair("reference_hold", reference_hold, strict=False)
            if h_lo < 1 or h_lo != int(h_lo) or h_hi != int(h_hi):
                raise VesselidError(
                    f"reference_hold must be whole numbers of steps >= 1, got {reference_hold!r}"
                )
            mode = 1.0
        else:
            r_lo = r_hi = _finite("reference", reference)
            h_lo = h_hi = 1.0
            mode = 0.0
        if max(abs(r_lo), abs(r_hi), abs(w0_lo), abs(w0_hi)) >= vlim:
            raise VesselidError(
                f"reference and initial velocity must lie inside velocity_limit={vlim}"
            )

        system = heave(current_mean=cm, current_sensor=sensor, xi_mean=xm)
        system = dataclasses.replace(
            system,
            current={"w": Gaussian(cm, cs)},
            process_noise={"w": Gaussian(xm, xs)},
            sensor_noise={"w": Gaussian(0.0, e1)},
            current_sensor_noise={"w": Gaussian(0.0, e2)} if sensor else {},
        )
        spec = system.spec
        if spec.signals != ("w", "tau") or spec.n_params != spec.codes.n_params:
            raise VesselidError("the heave system must have signals ['w', 'tau']")  # guard
        self.system: System = system
        self.model_spec: ModelSpec = system.identification_spec()
        self.sensor = sensor
        self.sensor_column = system.sensor_name("w")
        self.codes = np.ascontiguousarray(spec.codes.factors)
        self.eq = np.ascontiguousarray(spec.codes.equation)
        self.theta = np.ascontiguousarray(spec.theta0_vector())
        self.velocity_limit = vlim
        self.reference = reference
        par = np.zeros(_NPAR)
        par[_SIGN] = float(system.sign("w"))
        par[_CM], par[_CS], par[_XM], par[_XS] = cm, cs, xm, xs
        par[_E1], par[_E2] = e1, e2
        par[_TLO], par[_THI] = t_lo, t_hi
        par[_COST], par[_VLIM] = cost, vlim
        par[_RMODE], par[_RLO], par[_RHI], par[_HMIN], par[_HMAX] = mode, r_lo, r_hi, h_lo, h_hi
        par[_W0LO], par[_W0HI] = w0_lo, w0_hi
        self.par = par
        self.settings: dict[str, Any] = {
            "current_mean": cm, "current_std": cs, "xi_mean": xm, "xi_std": xs,
            "sensor_std": e1, "current_sensor": sensor, "current_sensor_std": e2,
            "thrust_range": [t_lo, t_hi], "reference": reference,
            "reference_range": [r_lo, r_hi], "reference_hold": [int(h_lo), int(h_hi)],
            "action_cost": cost, "initial_velocity": [w0_lo, w0_hi], "velocity_limit": vlim,
        }

    @property
    def n_obs(self) -> int:
        return 3 if self.sensor else 2

    def spaces(self) -> tuple[spaces.Box, spaces.Box]:
        high = np.full(self.n_obs, 2.0 * self.velocity_limit, dtype=np.float32)
        action = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        return action, spaces.Box(-high, high, dtype=np.float32)

    def metadata(self) -> dict[str, Any]:
        described = self.system.describe()
        described.pop("inputs", None)  # the input comes from the agent
        described.pop("x0", None)
        return {"settings": dict(self.settings), "system": described}


def _initial_velocity(options: dict[str, Any] | None) -> float | None:
    if not options or "w0" not in options:
        return None
    return _finite("options['w0']", options["w0"])


# ----------------------------------------------------------------------- rendering
class _Plot(FigureRenderer):
    """Matplotlib plot of the recent window: velocity vs reference, thrust, current."""

    def __init__(self, mode: str, sensor: bool, fps: int) -> None:
        super().__init__(mode, fps, (6.4, 4.8), 100)
        self.sensor = sensor
        ax_v, ax_t, ax_c = self.fig.subplots(3, 1, sharex=True)
        (self.l_w,) = ax_v.plot([], [], label="w_a (true)")
        (self.l_y,) = ax_v.plot([], [], ".", ms=2, label="y1 (measured)")
        (self.l_r,) = ax_v.plot([], [], "--", label="w_ref")
        ax_v.set_ylabel("heave velocity")
        ax_v.legend(loc="upper left", fontsize="small")
        (self.l_tau,) = ax_t.step([], [], where="post")
        ax_t.set_ylabel("thrust τ")
        (self.l_c,) = ax_c.plot([], [], label="w_c (true)")
        (self.l_y2,) = ax_c.plot([], [], ".", ms=2, label="y2 (meter)")
        ax_c.set_ylabel("current")
        ax_c.set_xlabel("step")
        if sensor:
            ax_c.legend(loc="upper left", fontsize="small")
        self.axes = (ax_v, ax_t, ax_c)
        self.fig.tight_layout()

    def draw(self, hist: np.ndarray, title: str = "") -> np.ndarray | None:
        """``hist`` columns: k, w_a, y1, ref, tau, w_c, y2."""
        k, wa, y1, ref, tau, wc, y2 = hist.T
        self.l_w.set_data(k, wa)
        self.l_y.set_data(k, y1)
        self.l_r.set_data(k, ref)
        self.l_tau.set_data(k, tau)
        self.l_c.set_data(k, wc)
        self.l_y2.set_data(k, y2 if self.sensor else np.full_like(y2, np.nan))
        for ax in self.axes:
            ax.relim()
            ax.autoscale_view()
        if k.size:
            self.axes[0].set_xlim(k[0], max(k[-1], k[0] + 1))
        self.axes[0].set_title(title, fontsize="small")
        return self.present()




_DOC_ARGS = """
    - ``render_mode``: ``None``, ``"human"`` (matplotlib window; falls back to an
      off-screen Agg figure on headless machines) or ``"rgb_array"`` (the vector
      environment supports ``"rgb_array"`` only).
    - ``current_mean``, ``current_std``: the current ``w_c ~ N(current_mean, current_std²)``
      (paper: w̄c = 0 or 0.1, variance 0.01, so std 0.1).
    - ``xi_mean``, ``xi_std``: process disturbance ``ξ ~ N(xi_mean, xi_std²)``; ``xi_mean``
      defaults to ``current_mean − 0.05`` (§6).
    - ``sensor_std``: std of the velocity sensor noise ``e1`` (0.1).
    - ``current_sensor``: add the current meter ``y2 = w_c + e2`` to the observation;
      default on iff ``current_mean != 0`` (as :func:`vesselid.systems.heave`).
    - ``current_sensor_std``: std of ``e2`` (0.1).
    - ``thrust_range``: physical thrust at actions −1 and +1 (``(0.0, 0.5)``).
    - ``reference``: a constant reference velocity, or ``"random"`` (default): levels
      uniform on ``reference_range`` (``(0.5, 1.5)``), each held for a whole number of
      steps uniform on ``reference_hold`` (``(50, 200)``), all drawn from ``np_random``.
    - ``action_cost``: weight of the thrust penalty ``action_cost · τ²`` (0.1).
    - ``initial_velocity``: range of the uniform initial heave velocity (``(0.0, 1.5)``).
    - ``velocity_limit``: the episode terminates when ``|w_a|`` exceeds it (10); the
      observation bounds are ``±2·velocity_limit``.
    - ``render_window``: number of recent samples plotted (200).
"""


# ------------------------------------------------------------------------ single env
class HeaveEnv(gym.Env[np.ndarray, np.ndarray]):
    """Heave velocity tracking for an underwater vehicle (Ljungberg & Enqvist, §6).

    ## Description

    The vehicle's absolute heave velocity ``w_a`` obeys the second-order modulus model
    of paper eq. (15), restructured with unit sampling time:

    ``w_a(k+1) = a0 w_r(k) + n0 w_r(k)|w_r(k)| + f0 τ(k) + ξ(k)``,  ``w_r = w_a − w_c``,

    θ0 = [a0, n0, f0] = [0.99, −0.1, 1]. The water current ``w_c`` enters *inside* the
    nonlinearity (a non-additive disturbance) and ``ξ`` (current plus the unmodelled
    gravity/buoyancy discrepancy) is additive. The velocity is measured with noise,
    ``y1 = w_a + e1``; optionally a current meter reads ``y2 = w_c + e2``. All noises are
    Gaussian and white; defaults are the paper's §6 values (variance 0.01, w̄c = 0,
    mean of ξ w̄c − 0.05). The dynamics are evaluated from the term codes and θ0 of
    :func:`vesselid.systems.heave` by a compiled kernel.

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: normalised thrust, clipped to [−1, 1] and mapped
    linearly to the physical thrust ``τ`` on ``thrust_range`` (default [0, 0.5]).

    ## Observation Space

    ``Box(-2·velocity_limit, 2·velocity_limit, (2,) or (3,), float32)``:

    | Num | Observation                                   |
    |-----|-----------------------------------------------|
    | 0   | velocity measurement ``y1 = w_a + e1``        |
    | 1   | current-meter reading ``y2 = w_c + e2`` (only with ``current_sensor``) |
    | -1  | reference velocity ``w_ref``                  |

    ## Rewards

    ``r(k) = −(w_a(k+1) − w_ref(k))² − action_cost · τ(k)²``: tracking error of the *true*
    velocity after the step against the reference shown with the observation the action
    was chosen from, plus a thrust penalty.

    ## Starting State

    ``w_a(0)`` uniform on ``initial_velocity`` (or ``options={"w0": value}`` in
    ``reset``); the reference starts a new level.

    ## Episode End

    Termination when ``|w_a|`` exceeds ``velocity_limit`` or becomes non-finite.
    Truncation after ``max_episode_steps`` (1000 in the registration).

    ## Info

    The same keys in ``reset`` and ``step``, values at the time of the observation:
    ``w_a`` (true velocity), ``w_r`` (relative velocity ``w_a − w_c``), ``w_c`` (current
    acting in the coming step), ``xi`` (process disturbance entering the coming step),
    ``y1`` (velocity reading), ``y2`` (current-meter reading, only with
    ``current_sensor``), ``w_ref`` (reference). Thus ``w_a(k+1)`` follows from ``info(k)``
    and ``τ(k)`` exactly.

    ## Arguments
    {arguments}

    ## Recording

    :attr:`model_spec`, :meth:`log_row`, :meth:`log_inputs` and :meth:`log_metadata`
    implement the contract of :mod:`vesselid.envs.recorder`.

    ## Version History

    * v0: Initial version.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"],
                                          "render_fps": 30}

    def __init__(
        self,
        render_mode: str | None = None,
        *,
        current_mean: float = 0.0,
        current_std: float = 0.1,
        xi_mean: float | None = None,
        xi_std: float = 0.1,
        sensor_std: float = 0.1,
        current_sensor: bool | None = None,
        current_sensor_std: float = 0.1,
        thrust_range: tuple[float, float] = (0.0, 0.5),
        reference: float | str = "random",
        reference_range: tuple[float, float] = (0.5, 1.5),
        reference_hold: tuple[int, int] = (50, 200),
        action_cost: float = 0.1,
        initial_velocity: tuple[float, float] = (0.0, 1.5),
        velocity_limit: float = 10.0,
        render_window: int = 200,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise VesselidError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        cfg = _HeaveConfig(
            current_mean=current_mean, current_std=current_std, xi_mean=xi_mean,
            xi_std=xi_std, sensor_std=sensor_std, current_sensor=current_sensor,
            current_sensor_std=current_sensor_std, thrust_range=thrust_range,
            reference=reference, reference_range=reference_range,
            reference_hold=reference_hold, action_cost=action_cost,
            initial_velocity=initial_velocity, velocity_limit=velocity_limit,
        )
        self._cfg = cfg
        self.render_mode = render_mode
        self.action_space, self.observation_space = cfg.spaces()
        #: Identification structure of the recorded data (recorder contract).
        self.model_spec: ModelSpec = cfg.model_spec
        #: Sample time.
        self.dt: float = float(cfg.model_spec.dt or 1.0)
        self.current_sensor: bool = cfg.sensor
        self._codes, self._eq, self._theta, self._par = cfg.codes, cfg.eq, cfg.theta, cfg.par
        self._sig = np.zeros(8 + cfg.theta.shape[0])
        self._st = np.zeros((_NST, 1))
        self._z = np.zeros((SINGLE_BLOCK, _NZ))
        self._u = np.zeros((SINGLE_BLOCK, _NU))
        self._k = SINGLE_BLOCK
        self._t = 0
        self._window = int(render_window)
        self._hist: deque | None = deque(maxlen=self._window) if render_mode else None
        self._plot: _Plot | None = None

    # ---------------------------------------------------------------- randomness
    def _refill(self) -> None:
        rng = self.np_random
        self._z = rng.standard_normal((SINGLE_BLOCK, _NZ))
        self._u = rng.random((SINGLE_BLOCK, _NU))
        self._k = 0

    # --------------------------------------------------------------------- API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, float]]:
        """Start an episode; ``options={"w0": value}`` sets the initial true velocity."""
        super().reset(seed=seed)
        w0 = _initial_velocity(options)
        self._refill()
        st = self._st
        _single_reset(self._par, st, self._z[0], self._u[0])
        if w0 is not None:
            st[_Y1, 0] += w0 - st[_WA, 0]
            st[_WA, 0] = w0
        self._k = 1
        self._t = 0
        w_a, w_c, xi, y1, y2, ref = (float(st[r, 0]) for r in (_WA, _WC, _XI, _Y1, _Y2, _REF))
        if self._hist is not None:
            self._hist.clear()
            self._hist.append([0.0, w_a, y1, ref, np.nan, w_c, y2])
        obs, info = self._out(w_a, w_c, xi, y1, y2, ref)
        if self.render_mode == "human":
            self.render()
        return obs, info

    def _out(self, w_a, w_c, xi, y1, y2, ref):
        if self.current_sensor:
            obs = np.array((y1, y2, ref), dtype=np.float32)
            info = {"w_a": w_a, "w_r": w_a - w_c, "w_c": w_c, "xi": xi, "y1": y1, "y2": y2,
                    "w_ref": ref}
        else:
            obs = np.array((y1, ref), dtype=np.float32)
            info = {"w_a": w_a, "w_r": w_a - w_c, "w_c": w_c, "xi": xi, "y1": y1,
                    "w_ref": ref}
        return obs, info

    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, float]]:
        """Apply the normalised thrust ``action`` for one sample."""
        k = self._k
        if k >= SINGLE_BLOCK:
            self._refill()
            k = 0
        try:
            a = float(action[0])
        except (TypeError, IndexError):
            a = float(action)
        tau, reward, terminated, w_a, w_c, xi, y1, y2, ref = _single_step(
            self._codes, self._eq, self._theta, self._par, self._sig, self._st, self._z[k],
            self._u[k], a
        )
        self._k = k + 1
        self._t += 1
        if self.current_sensor:
            obs = np.array((y1, y2, ref), dtype=np.float32)
            info = {"w_a": w_a, "w_r": w_a - w_c, "w_c": w_c, "xi": xi, "y1": y1, "y2": y2,
                    "w_ref": ref}
        else:
            obs = np.array((y1, ref), dtype=np.float32)
            info = {"w_a": w_a, "w_r": w_a - w_c, "w_c": w_c, "xi": xi, "y1": y1,
                    "w_ref": ref}
        if self._hist is not None:
            self._hist[-1][4] = tau
            self._hist.append([float(self._t), w_a, y1, ref, np.nan, w_c, y2])
            if self.render_mode == "human":
                self.render()
        return obs, reward, terminated, False, info

    def render(self) -> np.ndarray | None:
        """Plot the recent window (``rgb_array``: an ``(H, W, 3)`` uint8 image)."""
        if self.render_mode is None:
            gym.logger.warn(
                "You are calling render method without specifying any render mode, e.g. "
                'gym.make("vesselid/Heave-v0", render_mode="rgb_array")'
            )
            return None
        if self._plot is None:
            self._plot = _Plot(self.render_mode, self.current_sensor,
                               self.metadata["render_fps"])
        hist = np.array(self._hist, dtype=float).reshape(-1, 7) if self._hist else np.zeros((0, 7))
        return self._plot.draw(hist, f"Heave-v0, step {self._t}")

    def close(self) -> None:
        if self._plot is not None:
            self._plot.close()
            self._plot = None

    # --------------------------------------------------------- recorder contract
    def thrust(self, action: Any) -> float:
        """Physical thrust τ applied for a normalised action."""
        try:
            a = float(np.asarray(action, dtype=np.float64).reshape(-1)[0])
        except (TypeError, ValueError, IndexError) as exc:
            raise VesselidError(f"action must hold one number, got {action!r}") from exc
        out = np.empty(1)
        _thrust_array(self._par, np.array([a]), out)
        return float(out[0])

    def log_row(self, info: dict[str, Any]) -> dict[str, float]:
        """Trial-log columns at the time of ``info`` (recorder contract).

        ``w`` = y1, ``w_c`` = y2 (with the current meter), ``w_ref``, and ground truth
        ``true_w``, ``true_current_w``, ``true_process_w``.
        """
        row = {"w": info["y1"]}
        if self.current_sensor:
            row[self._cfg.sensor_column] = info["y2"]
        row["w_ref"] = info["w_ref"]
        row["true_w"] = info["w_a"]
        row["true_current_w"] = info["w_c"]
        row["true_process_w"] = info["xi"]
        return row

    def log_inputs(self, action: Any) -> dict[str, float]:
        """Physical inputs applied for ``action`` (recorder contract): ``{"tau": τ}``."""
        return {"tau": self.thrust(action)}

    def log_metadata(self) -> dict[str, Any]:
        """Disturbance and sensor settings (JSON-serialisable), for log metadata."""
        return self._cfg.metadata()


# ------------------------------------------------------------------------ vector env
class HeaveVectorEnv(VectorEnv):
    """``num_envs`` copies of :class:`HeaveEnv` stepped by one compiled kernel.

    Same dynamics, spaces (batched), rewards and info keys as :class:`HeaveEnv`; info
    values are arrays of shape ``(num_envs,)`` with the usual ``"_<key>"`` masks.
    Episodes truncate after ``max_episode_steps`` and reset on the next step
    (``AutoresetMode.NEXT_STEP``: the action of a sub-environment that was done at the
    previous step is ignored, its reward is 0 and it returns its first observation).
    All randomness comes from one generator, ``self.np_random``, seeded by ``reset(seed=...)``.

    ## Arguments

    - ``num_envs``: number of sub-environments.
    - ``max_episode_steps``: truncation length (0 or None: never truncate).
    {arguments}"""

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["rgb_array"],
        "render_fps": 30,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        max_episode_steps: int | None = 1000,
        render_mode: str | None = None,
        *,
        current_mean: float = 0.0,
        current_std: float = 0.1,
        xi_mean: float | None = None,
        xi_std: float = 0.1,
        sensor_std: float = 0.1,
        current_sensor: bool | None = None,
        current_sensor_std: float = 0.1,
        thrust_range: tuple[float, float] = (0.0, 0.5),
        reference: float | str = "random",
        reference_range: tuple[float, float] = (0.5, 1.5),
        reference_hold: tuple[int, int] = (50, 200),
        action_cost: float = 0.1,
        initial_velocity: tuple[float, float] = (0.0, 1.5),
        velocity_limit: float = 10.0,
        render_window: int = 200,
    ) -> None:
        num_envs = int(num_envs)
        if num_envs < 1:
            raise VesselidError(f"num_envs must be at least 1, got {num_envs}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise VesselidError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        cfg = _HeaveConfig(
            current_mean=current_mean, current_std=current_std, xi_mean=xi_mean,
            xi_std=xi_std, sensor_std=sensor_std, current_sensor=current_sensor,
            current_sensor_std=current_sensor_std, thrust_range=thrust_range,
            reference=reference, reference_range=reference_range,
            reference_hold=reference_hold, action_cost=action_cost,
            initial_velocity=initial_velocity, velocity_limit=velocity_limit,
        )
        self._cfg = cfg
        self.num_envs = num_envs
        self.max_episode_steps = int(max_episode_steps or 0)
        self.render_mode = render_mode
        self.single_action_space, self.single_observation_space = cfg.spaces()
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        #: Identification structure of the recorded data (recorder contract).
        self.model_spec: ModelSpec = cfg.model_spec
        #: Sample time.
        self.dt: float = float(cfg.model_spec.dt or 1.0)
        self.current_sensor: bool = cfg.sensor
        self._codes, self._eq, self._theta, self._par = cfg.codes, cfg.eq, cfg.theta, cfg.par
        self._sig = np.zeros(8 + cfg.theta.shape[0])
        self._st = np.zeros((_NST, num_envs))
        self._steps = np.zeros(num_envs, dtype=np.int64)
        self._prev_done = np.zeros(num_envs, dtype=np.bool_)
        self._block = max(1, VECTOR_BLOCK_ELEMENTS // num_envs)
        self._z = np.zeros((self._block, num_envs, _NZ))
        self._u = np.zeros((self._block, num_envs, _NU))
        self._k = self._block
        self._tau = np.full(num_envs, np.nan)
        self._mask = np.ones(num_envs, dtype=np.bool_)
        self._mask.flags.writeable = False
        self._window = int(render_window)
        self._hist: np.ndarray | None = None
        self._hist_len = 0
        self._plot: _Plot | None = None
        self._t = 0

    def _refill(self) -> None:
        rng = self.np_random
        self._z = rng.standard_normal((self._block, self.num_envs, _NZ))
        self._u = rng.random((self._block, self.num_envs, _NU))
        self._k = 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Reset every sub-environment; ``options={"w0": value or array}`` sets ``w_a(0)``."""
        super().reset(seed=seed)
        self._refill()
        obs = np.empty((self.num_envs, self._cfg.n_obs), dtype=np.float32)
        st = self._st
        _vector_reset(self._par, st, self._steps, self._prev_done, self._z[0], self._u[0], obs,
                      self.current_sensor)
        if options and "w0" in options:
            w0 = np.broadcast_to(np.asarray(options["w0"], dtype=np.float64), (self.num_envs,))
            if not np.all(np.isfinite(w0)):
                raise VesselidError("options['w0'] must be finite")
            st[_Y1] += w0 - st[_WA]
            st[_WA] = w0
            obs[:, 0] = st[_Y1]
        self._k = 1
        self._t = 0
        self._tau[:] = np.nan
        if self.render_mode is not None:
            self._hist = np.full((self._window, 7, self.num_envs), np.nan)
            self._hist_len = 0
            self._record_hist()
        return obs, self._make_info()

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Step all sub-environments with normalised thrusts of shape ``(num_envs, 1)``."""
        n = self.num_envs
        a = np.asarray(actions, dtype=np.float64).reshape(n)
        if self._k >= self._block:
            self._refill()
        k = self._k
        obs = np.empty((n, self._cfg.n_obs), dtype=np.float32)
        rew = np.empty(n)
        term = np.empty(n, dtype=np.bool_)
        trunc = np.empty(n, dtype=np.bool_)
        if self.render_mode is not None:
            self._hist[(self._hist_len - 1) % self._window, 4] = _applied(a, self._par,
                                                                         self._prev_done)
        _vector_step(self._codes, self._eq, self._theta, self._par, self._sig, self._st,
                     self._steps, self._prev_done, a, self._z[k], self._u[k],
                     self.max_episode_steps, obs, rew, term, trunc, self._tau, self.current_sensor)
        self._k = k + 1
        self._t += 1
        if self.render_mode is not None:
            self._record_hist()
        return obs, rew, term, trunc, self._make_info()

    def _make_info(self) -> dict[str, np.ndarray]:
        st = self._st
        m = self._mask
        info = {"w_a": st[_WA].copy(), "_w_a": m, "w_r": st[_WA] - st[_WC], "_w_r": m,
                "w_c": st[_WC].copy(), "_w_c": m, "xi": st[_XI].copy(), "_xi": m,
                "y1": st[_Y1].copy(), "_y1": m}
        if self.current_sensor:
            info["y2"] = st[_Y2].copy()
            info["_y2"] = m
        info["w_ref"] = st[_REF].copy()
        info["_w_ref"] = m
        return info

    # ---------------------------------------------------------------- rendering
    def _record_hist(self) -> None:
        st = self._st
        row = self._hist_len % self._window
        h = self._hist[row]
        h[0] = self._t
        h[1], h[2], h[3] = st[_WA], st[_Y1], st[_REF]
        h[4] = np.nan
        h[5], h[6] = st[_WC], st[_Y2]
        self._hist_len += 1

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One ``(H, W, 3)`` uint8 frame per sub-environment (slow for many envs)."""
        if self.render_mode is None:
            gym.logger.warn(
                "You are calling render method without specifying any render mode, e.g. "
                'gym.make_vec("vesselid/Heave-v0", render_mode="rgb_array")'
            )
            return None
        if self._hist is None:
            raise VesselidError("call reset() before render()")
        if self._plot is None:
            self._plot = _Plot("rgb_array", self.current_sensor, self.metadata["render_fps"])
        n = min(self._hist_len, self._window)
        order = (np.arange(self._hist_len - n, self._hist_len)) % self._window
        hist = self._hist[order]  # (n, 7, num_envs)
        frames = []
        for i in range(self.num_envs):
            h = np.ascontiguousarray(hist[:, :, i])
            frames.append(self._plot.draw(h, f"Heave-v0 env {i}, step {self._t}"))
        return tuple(frames)

    def close_extras(self, **kwargs: Any) -> None:
        if self._plot is not None:
            self._plot.close()
            self._plot = None

    # --------------------------------------------------------- recorder contract
    def thrust(self, actions: Any) -> np.ndarray:
        """Physical thrusts applied for normalised actions of shape ``(num_envs, 1)``."""
        a = np.ascontiguousarray(np.asarray(actions, dtype=np.float64).reshape(self.num_envs))
        out = np.empty(self.num_envs)
        _thrust_array(self._par, a, out)
        return out

    def log_row(self, info: dict[str, Any]) -> dict[str, np.ndarray]:
        """Trial-log columns at the time of ``info``, arrays of shape ``(num_envs,)``."""
        row = {"w": np.asarray(info["y1"], dtype=np.float64)}
        if self.current_sensor:
            row[self._cfg.sensor_column] = np.asarray(info["y2"], dtype=np.float64)
        row["w_ref"] = np.asarray(info["w_ref"], dtype=np.float64)
        row["true_w"] = np.asarray(info["w_a"], dtype=np.float64)
        row["true_current_w"] = np.asarray(info["w_c"], dtype=np.float64)
        row["true_process_w"] = np.asarray(info["xi"], dtype=np.float64)
        return row

    def log_inputs(self, actions: Any) -> dict[str, np.ndarray]:
        """Physical inputs applied for ``actions``: ``{"tau": array (num_envs,)}``."""
        return {"tau": self.thrust(actions)}

    def log_metadata(self) -> dict[str, Any]:
        """Disturbance and sensor settings (JSON-serialisable), for log metadata."""
        return self._cfg.metadata()


HeaveEnv.__doc__ = (HeaveEnv.__doc__ or "").replace("{arguments}", _DOC_ARGS.strip())
HeaveVectorEnv.__doc__ = (HeaveVectorEnv.__doc__ or "").replace(
    "{arguments}", _DOC_ARGS.strip()
)


def _applied(a: np.ndarray, par: np.ndarray, prev_done: np.ndarray) -> np.ndarray:
    out = np.empty(a.shape[0])
    _thrust_array(par, np.ascontiguousarray(a), out)
    out[prev_done] = np.nan
    return out
