"""``vesselid/Manoeuvring3DOF-v0``: surge/sway/yaw manoeuvring of CyberShip II.

The plant is :mod:`vesselid.plant.vessels`: the Skjetne, Smogeli & Fossen (2004) CyberShip II
model discretised with explicit Euler into the second-order modulus regression of
:func:`vesselid.plant.vessels.cybership2_spec`, driven through the spec's term codes and θ0 by
the compiled kernels of :mod:`vesselid.plant.vessels` (the same code as
:func:`vesselid.plant.vessels.simulate_cybership2`), with an earth-fixed ocean current rotated
into the body frame (the paper's non-additive ``v = −ν_c``), Blendermann (1994) wind with
gusts, optional unmodelled forces, and a switchable sensor suite.

:class:`Manoeuvring3DOFEnv` is the single environment; :class:`Manoeuvring3DOFVectorEnv`
steps ``num_envs`` vessels with one parallel compiled kernel (next-step autoreset), for
``gym.make_vec(..., vectorization_mode="vector_entry_point")``.

Both implement the recorder contract of :mod:`vesselid.envs.recorder` (``model_spec``,
``dt``, ``log_row``, ``log_inputs``, ``log_metadata``).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, SupportsFloat

import gymnasium as gym
import numba
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from vesselid.envs._render import FigureRenderer, check_render_mode, warn_no_render_mode
from vesselid.envs._settings import document, merged, triple
from vesselid.envs._validate import check_action, require_reset
from vesselid.errors import VesselidError
from vesselid.model.spec import ModelSpec
from vesselid.plant.catalogue import vessel_module
from vesselid.plant.vessels import (
    LAYOUT,
    VesselBatch,
    VesselDisturbances,
    VesselModel,
    VesselSensors,
    log_columns,
    wrap,
)
from vesselid.plant.vessels.kernel import STATUS_OK

__all__ = ["Manoeuvring3DOFEnv", "Manoeuvring3DOFVectorEnv", "reward"]

_ANGLE_CHANNELS = {"psi", "wind_angle"}
_THREE = (3,)
SINGLE_BLOCK = 1024  # disturbance rows drawn at once by a single env
VECTOR_BLOCK_SAMPLES = 1 << 16  # rows x envs drawn at once by a vector env


def reward(u: np.ndarray, psi: np.ndarray, a: np.ndarray, u_ref: float, psi_ref: float,
           weights: Sequence[float]) -> np.ndarray:
    """``−(w_u (u − u_ref)² + w_ψ wrap(ψ − ψ_ref)² + w_a ‖a‖²)`` per vessel.

    ``u``, ``psi`` true surge speed and heading after the step, ``a`` ``(B, 3)`` clipped
    actions.
    """
    w_u, w_psi, w_a = weights
    du = u - u_ref
    dpsi = wrap(psi - psi_ref)
    asq = a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1] + a[:, 2] * a[:, 2]
    return -(w_u * du * du + w_psi * dpsi * dpsi + w_a * asq)


#: Settings of both environments and their defaults (see ``## Arguments``).
DEFAULTS: dict[str, Any] = {
    "vessel": "cybership2",
    "dt": 0.1,
    "current_speed": 0.05,
    "current_direction": None,
    "current_variation": 0.005,
    "current_time_constant": 120.0,
    "wind_speed": 1.0,
    "wind_direction": None,
    "wind_gust": 0.2,
    "force_noise": 0.0,
    "sensors": None,
    "cubic_surge": False,
    "force_max": None,
    "u_ref": 0.3,
    "psi_ref": 0.0,
    "reward_weights": (10.0, 1.0, 0.01),
    "initial_speed": (0.0, 0.4),
    "velocity_limit": None,
}


class _Core:
    """A :class:`~vesselid.plant.vessels.VesselBatch` of ``B`` vessels plus the environment's
    action scaling, references and reward (shared by both envs)."""

    def __init__(
        self,
        n: int,
        *,
        parallel: bool,
        vessel: str,
        dt: float,
        current_speed: float,
        current_direction: float | None,
        current_variation: float,
        current_time_constant: float,
        wind_speed: float,
        wind_direction: float | None,
        wind_gust: float,
        force_noise: Sequence[float] | float,
        sensors: VesselSensors | Mapping[str, Any] | None,
        cubic_surge: bool,
        force_max: Sequence[float] | None,
        u_ref: float,
        psi_ref: float,
        reward_weights: Sequence[float],
        initial_speed: Sequence[float],
        velocity_limit: float | None,
        block: int,
    ) -> None:
        hull = vessel_module(str(vessel)).HULL
        fmax = triple("force_max", hull.force_max if force_max is None else force_max)
        if min(fmax) <= 0:
            raise VesselidError(f"force_max must be positive, got {force_max!r}")
        rw = triple("reward_weights", reward_weights)
        for name, val in (("current_speed", current_speed), ("current_variation",
                          current_variation), ("wind_speed", wind_speed),
                          ("wind_gust", wind_gust)):
            if not (math.isfinite(float(val)) and float(val) >= 0):
                raise VesselidError(f"{name} must be a non-negative number, got {val!r}")
        vlim = float(hull.velocity_limit if velocity_limit is None else velocity_limit)
        if not (math.isfinite(vlim) and vlim > 0):
            raise VesselidError(f"velocity_limit must be positive, got {velocity_limit!r}")
        lo, hi = (float(x) for x in initial_speed)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise VesselidError(f"initial_speed must be a range (low, high), got {initial_speed}")
        dist = VesselDisturbances(
            current_speed=float(current_speed),
            current_direction=0.0 if current_direction is None else float(current_direction),
            current_speed_std=float(current_variation),
            current_direction_std=float(current_variation) / max(float(current_speed), 0.05)
            if current_variation > 0 else 0.0,
            current_time_constant=float(current_time_constant),
            wind_speed=float(wind_speed),
            wind_direction=0.0 if wind_direction is None else float(wind_direction),
            gust_std=float(wind_gust),
            wind_direction_std=0.1 if wind_gust > 0 else 0.0,
            force_noise_std=triple("force_noise", force_noise),
            cubic_surge=bool(cubic_surge),
        )
        self.model = VesselModel(hull=hull, dt=dt, disturbances=dist,
                                 sensors=VesselSensors() if sensors is None else sensors,
                                 limit=vlim)
        self.force_max = np.asarray(fmax)
        self.i_status = LAYOUT.slice("status").start
        self.u_ref, self.psi_ref, self.reward_weights = float(u_ref), float(psi_ref), rw
        self.reward_par = np.array([*fmax, self.u_ref, self.psi_ref, *rw], dtype=np.float64)
        self.velocity_limit = vlim
        self.random_current_direction = current_direction is None
        self.random_wind_direction = wind_direction is None
        self.initial_speed = (lo, hi)
        self.n = int(n)
        self.batch = VesselBatch(self.model, self.n, block=block, parallel=parallel,
                                 n_chunks=max(1, min(self.n // 128, numba.get_num_threads())))
        self.channels = self.model.sensors.channels
        self.n_obs = len(self.channels)
        self.no_skip = np.zeros(self.n, dtype=np.bool_)
        self.rewards = np.zeros(self.n)

    @property
    def obs(self) -> np.ndarray:
        return self.batch.obs

    @property
    def rng(self) -> np.random.Generator | None:
        return self.batch.rng

    # -- spaces -----------------------------------------------------------------
    def spaces(self) -> tuple[spaces.Box, spaces.Box]:
        action = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        d = self.model.disturbances
        vel = 2.0 * self.velocity_limit
        wind = 2.0 * (d.wind_speed + 3.0 * d.gust_std + self.velocity_limit)
        high = np.array([np.pi if c in _ANGLE_CHANNELS else wind if c == "wind_speed" else vel
                         for c in self.channels], dtype=np.float32)
        return action, spaces.Box(-high, high, dtype=np.float32)

    # -- reset --------------------------------------------------------------------
    def _initial(self, rng: np.random.Generator, idx: np.ndarray,
                 options: Mapping[str, Any] | None) -> None:
        k = idx.size
        opts = dict(options or {})
        unknown = sorted(set(opts) - {"nu", "eta", "current_direction", "wind_direction"})
        if unknown:
            raise VesselidError(f"unknown reset options {unknown}; allowed: nu, eta, "
                                "current_direction, wind_direction")
        lo, hi = self.initial_speed
        nu = np.column_stack([rng.uniform(lo, hi, k), rng.uniform(-0.02, 0.02, k),
                              rng.uniform(-0.02, 0.02, k)])
        eta = np.column_stack([np.zeros(k), np.zeros(k), rng.uniform(-np.pi, np.pi, k)])
        d = self.model.disturbances
        cdir = rng.uniform(-np.pi, np.pi, k) if self.random_current_direction \
            else np.full(k, d.current_direction)
        wdir = rng.uniform(-np.pi, np.pi, k) if self.random_wind_direction \
            else np.full(k, d.wind_direction)
        if "nu" in opts:
            nu = np.broadcast_to(np.asarray(opts["nu"], dtype=float), (k, 3))
        if "eta" in opts:
            eta = np.broadcast_to(np.asarray(opts["eta"], dtype=float), (k, 3))
        if "current_direction" in opts:
            cdir = np.broadcast_to(np.asarray(opts["current_direction"], dtype=float), (k,))
        if "wind_direction" in opts:
            wdir = np.broadcast_to(np.asarray(opts["wind_direction"], dtype=float), (k,))
        for name, arr in (("nu", nu), ("eta", eta), ("current_direction", cdir),
                          ("wind_direction", wdir)):
            if not np.all(np.isfinite(arr)):
                raise VesselidError(f"reset option {name} must be finite")
        self.batch.set_state(idx, nu, eta, cdir, wdir)

    def reset_all(self, rng: np.random.Generator, options: Mapping[str, Any] | None) -> None:
        self._initial(rng, np.arange(self.n), options)
        self.batch.start(rng)

    # -- step ---------------------------------------------------------------------
    def step(self, actions: Any, skip: np.ndarray) -> None:
        """Scale the actions to forces, step the plant, compute the rewards."""
        a = np.empty((self.n, 3))
        a[:] = actions
        np.clip(a, -1.0, 1.0, out=a)
        self.batch.step(a * self.force_max, skip)
        nu, eta = self.batch.block_of("nu"), self.batch.block_of("eta")
        self.rewards = reward(nu[:, 0], eta[:, 2], a, self.u_ref, self.psi_ref,
                              self.reward_weights)
        self.rewards[skip] = 0.0

    def step_single(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """The single environment's ``(obs, reward, terminated, truncated, info)`` for
        ``action``: :meth:`step` for one vessel from Python floats, the same operations
        in one compiled call (:meth:`VesselBatch.step_one`), so bit-identical."""
        # an ndarray of the action space's shape holding finite floats (what agents pass)
        # is read directly (``x - x`` is 0 for finite x, NaN otherwise); anything else
        # goes through the full check, which also words the refusal
        try:
            a0, a1, a2 = action.tolist()
        except (AttributeError, TypeError, ValueError):
            a0 = a1 = a2 = None
        batch = self.batch
        if not (a0.__class__ is a1.__class__ is a2.__class__ is float
                and (a0 - a0) + (a1 - a1) + (a2 - a2) == 0.0):
            require_reset(batch.rng is not None)
            a0, a1, a2 = check_action(action, _THREE).tolist()
        if batch.rng is None:
            require_reset(False)
        reward = batch.step_one(a0, a1, a2, self.reward_par)
        return (batch.obs0.copy(), reward, batch.st.item(0, self.i_status) != STATUS_OK, False,
                batch.info_one())

    @property
    def terminated(self) -> np.ndarray:
        return self.batch.diverged

    def info(self, row: int | None = None) -> dict[str, np.ndarray]:
        return self.batch.info(row)

    def tau(self, actions: Any) -> np.ndarray:
        a = np.clip(np.asarray(actions, dtype=np.float64), -1.0, 1.0)
        return a * self.force_max

    def metadata(self) -> dict[str, Any]:
        return {
            **{"system": self.model.hull.name}, **self.model.describe(),
            "random_current_direction": self.random_current_direction,
            "random_wind_direction": self.random_wind_direction,
            "force_max": self.force_max.tolist(),
            "u_ref": self.u_ref,
            "psi_ref": self.psi_ref,
            "reward_weights": list(self.reward_weights),
        }


def _log_row(info: Mapping[str, Any], enabled: Sequence[str]) -> dict[str, Any]:
    """Trial-log columns from an info dict (single or batched): :func:`log_columns`."""
    row = log_columns(lambda key, i: np.asarray(info[key])[..., i], enabled, inputs=False)
    if np.ndim(row["true_u"]) == 0:
        row = {k: float(v) for k, v in row.items()}
    return row


# ---------------------------------------------------------------------------- rendering


class _Plot(FigureRenderer):
    """Trajectory in the north-east plane with a heading arrow, and velocity time series."""

    def __init__(self, mode: str, fps: int, length: float) -> None:
        super().__init__(mode, fps, (8.0, 4.0), 80)
        self.length = length
        self.ax_ne, self.ax_v = self.fig.subplots(1, 2)
        (self.l_traj,) = self.ax_ne.plot([], [], lw=1.0)
        self.arrow = None
        self.ax_ne.set_xlabel("east (m)")
        self.ax_ne.set_ylabel("north (m)")
        self.ax_ne.set_aspect("equal", adjustable="box")
        self.l_u = self.ax_v.plot([], [], label="u")[0]
        self.l_v = self.ax_v.plot([], [], label="v")[0]
        self.l_r = self.ax_v.plot([], [], label="r")[0]
        self.ax_v.set_xlabel("time (s)")
        self.ax_v.legend(loc="upper left", fontsize="small")
        self.fig.tight_layout()

    def draw(self, hist: np.ndarray) -> np.ndarray | None:
        """``hist`` columns: t, north, east, psi, u, v, r."""
        t, n, e, psi, u, v, r = hist.T
        self.l_traj.set_data(e, n)
        if self.arrow is not None:
            self.arrow.remove()
        size = 2.0 * self.length
        self.arrow = self.ax_ne.arrow(e[-1], n[-1], size * math.sin(psi[-1]),
                                      size * math.cos(psi[-1]), width=0.15 * size,
                                      length_includes_head=True, color="C3")
        self.ax_ne.set_xlim(e.min() - 2 * size, e.max() + 2 * size)
        self.ax_ne.set_ylim(n.min() - 2 * size, n.max() + 2 * size)
        self.l_u.set_data(t, u)
        self.l_v.set_data(t, v)
        self.l_r.set_data(t, r)
        self.ax_v.relim()
        self.ax_v.autoscale_view()
        self.ax_v.set_xlim(t[0], max(t[-1], t[0] + 1e-3))
        return self.present()


_DOC_ARGS = """
    - ``render_mode``: ``None``, ``"human"`` (matplotlib window; off-screen Agg figure on
      headless machines) or ``"rgb_array"`` (the vector env renders sub-env 0).
    - ``dt``: sample time of the Euler discretisation (0.1 s).
    - ``current_speed``: mean earth-frame current speed (0.05 m/s, model scale).
    - ``current_direction``: going-to direction of the current (rad from north towards
      east); ``None`` (default) draws it uniformly per episode from ``np_random``.
    - ``current_variation``: std of the bounded Gauss–Markov variation of the current speed
      (m/s; the direction varies by ``current_variation / max(current_speed, 0.05)`` rad),
      time constant ``current_time_constant`` (120 s), bound 3 std.
    - ``wind_speed``: mean true wind speed (1.0 m/s model scale ≈ 8 m/s full scale).
    - ``wind_direction``: going-to direction of the wind; ``None`` draws it per episode.
    - ``wind_gust``: std of the coloured (Gauss–Markov, 5 s) gusts of the wind speed; with
      gusts the wind direction also varies (0.1 rad, 30 s).
    - ``force_noise``: std of unmodelled Gauss–Markov forces ``[X, Y, N]`` (0).
    - ``sensors``: :class:`vesselid.plant.vessels.VesselSensors` or a mapping of its fields
      (noise std per sensor, ``None`` switches a sensor off). Default: all six sensors.
    - ``cubic_surge``: add the published cubic surge damping ``X_uuu u_r³`` (then the
      identification spec is misspecified).
    - ``vessel``: catalogue vessel (:func:`vesselid.plant.catalogue.vessel_names`;
      ``"cybership2"``).
    - ``force_max``: physical ``[X, Y, N]`` at action ±1; default the vessel's actuator
      limits (``Hull.force_max``; CyberShip II: 2 N, 1.5 N, 1 N m).
    - ``u_ref``, ``psi_ref``: reference surge speed (0.3 m/s) and heading (0 rad).
    - ``reward_weights``: ``(w_u, w_ψ, w_a)`` of the reward (``(10, 1, 0.01)``).
    - ``initial_speed``: range of the uniform initial surge speed (``(0.0, 0.4)`` m/s).
    - ``velocity_limit``: the episode terminates when a component of ν exceeds it
      (default the vessel's; CyberShip II: 5 m/s,
      unreachable with its forces); velocity channels are bounded by
      ±2·velocity_limit, the apparent wind speed by ±2·(wind_speed + 3·wind_gust +
      velocity_limit), angles by ±π.
    - ``render_window``: number of recent samples plotted (600).
"""


# --------------------------------------------------------------------------- single env
class _ManoeuvringBase:
    """Rendering and the recorder contract shared by both environments (sub-env 0 is
    rendered)."""

    metadata: ClassVar[dict[str, Any]]
    _core: _Core
    render_mode: str | None

    def _attach(self, render_mode: str | None, render_window: int) -> None:
        self.render_mode = check_render_mode(render_mode, self.metadata["render_modes"])
        #: Identification structure of the recorded data (recorder contract).
        self.model_spec: ModelSpec = self._core.model.spec
        #: Sample time (s).
        self.dt: float = self._core.model.dt
        self._hist: deque | None = deque(maxlen=int(render_window)) if render_mode else None
        self._plot: _Plot | None = None

    def _append(self, step: int) -> None:
        b = self._core.batch
        self._hist.append((step * self.dt, *b.block_of("eta")[0], *b.block_of("nu")[0]))

    def _frame(self) -> np.ndarray | None:
        if self.render_mode is None:
            warn_no_render_mode("vesselid/Manoeuvring3DOF-v0")
            return None
        if self._plot is None:
            self._plot = _Plot(self.render_mode, self.metadata["render_fps"],
                               self._core.model.hull.length)
        if not self._hist:
            self._record()
        return self._plot.draw(np.asarray(self._hist))

    def close_extras(self, **kwargs: Any) -> None:
        if self._plot is not None:
            self._plot.close()
            self._plot = None

    def log_row(self, info: dict[str, Any]) -> dict[str, Any]:
        """Trial-log columns at the time of ``info`` (recorder contract; floats, or arrays
        ``(num_envs,)``): :func:`vesselid.plant.vessels.log_columns` without the inputs."""
        return _log_row(info, self._core.model.sensors.enabled)

    def log_inputs(self, action: Any) -> dict[str, Any]:
        """Physical inputs ``{"X", "Y", "N"}`` applied for ``action``."""
        n = self._core.n
        tau = self._core.tau(np.asarray(action, dtype=np.float64).reshape(n, 3))
        cols = {c: tau[:, j] for j, c in enumerate(("X", "Y", "N"))}
        return {c: float(v[0]) for c, v in cols.items()} if isinstance(
            self, Manoeuvring3DOFEnv) else cols

    def log_metadata(self) -> dict[str, Any]:
        """Disturbance and sensor settings (JSON-serialisable), for log metadata."""
        return self._core.metadata()


class Manoeuvring3DOFEnv(_ManoeuvringBase, gym.Env[np.ndarray, np.ndarray]):
    """Surge/sway/yaw manoeuvring of CyberShip II in current and wind.

    ## Description

    CyberShip II (Skjetne, Smogeli & Fossen 2004), a 1:70 supply-ship model, moves in
    the horizontal plane. Its velocity relative to water obeys
    ``M ν̇_r + C(ν_r)ν_r + D(ν_r)ν_r = τ + τ_wind`` with linear and modulus damping,
    discretised by explicit Euler at ``dt`` into the second-order modulus regression of
    :func:`vesselid.plant.vessels.cybership2_spec` (paper Definition 2.1). In the paper's
    notation ``x(k+1) = Φᵀ([x(k) + v(k); τ(k)])θ0 + w(k)`` with ``x = ν`` the absolute
    velocity, ``v = −ν_c`` the body-frame current (non-additive) and ``w`` the change of
    the body-frame current plus wind and unmodelled forces. Position and heading follow
    ``η(k+1) = η(k) + dt R(ψ)ν``. The current is fixed in the earth frame (constant plus a
    bounded Gauss–Markov variation) and rotated into the body frame; wind loads follow
    Blendermann (1994) with the relative wind speed squared and angle.

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: normalised generalised forces; ``τ = clip(a, −1, 1) ·
    force_max`` gives ``[X, Y, N]`` in N, N, N m.

    ## Observation Space

    ``Box(float32)`` concatenating the enabled sensor readings, in this order (default:
    all): GNSS velocity ``[u, v]`` (absolute, body frame), Doppler speed log
    ``[u_r, v_r]`` (velocity through water — the aggregated state of the paper's
    Remark 4.3), current meter ``[u_c, v_c]``, anemometer ``[V_rw, γ_rw]`` (apparent wind
    speed and angle, 0 = from ahead), gyro ``r``, heading ``ψ``. Angles are wrapped to
    ``[−π, π)`` (bounds ±π); see ``velocity_limit`` for the other bounds. Sensor noise is Gaussian
    clipped at 3 std (bounded, paper A2).

    ## Rewards

    ``−(w_u (u − u_ref)² + w_ψ wrap(ψ − ψ_ref)² + w_a ‖a‖²)`` from the true state after the
    step: track a surge speed over ground and a heading with a small action penalty.

    ## Starting State

    ``u ~ U(initial_speed)``, ``v, r ~ U(−0.02, 0.02)``, position at the origin, heading
    ``U(−π, π)``; random current/wind directions when not given. ``reset(options=...)``
    accepts ``nu``, ``eta``, ``current_direction`` and ``wind_direction``.

    ## Episode End

    Termination if a velocity component exceeds ``velocity_limit`` or becomes non-finite
    (unreachable with the default bounded forces). Truncation at ``max_episode_steps``
    (2000 in the registration).

    ## Info

    Same keys after ``reset`` and ``step``: ``nu`` (true ν), ``nu_r`` (ν − ν_c), ``eta``,
    ``current`` (body-frame ``[u_c, v_c, 0]``; the paper's ``v = −current``), ``wind``
    (true apparent wind ``[V_rw, γ_rw]``), ``wind_force`` (``τ_wind``), ``tau`` (applied
    forces; zero after reset) and one key per enabled sensor (``gnss``, ``speed_log``,
    ``current_meter``, ``anemometer``, ``gyro``, ``heading``).

    ## Arguments

    {arguments}

    All randomness (initial state, directions, current, gusts, noise — pre-drawn in
    blocks) comes from ``self.np_random``.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"],
                                          "render_fps": 10}

    def __init__(self, render_mode: str | None = None, *, render_window: int = 600,
                 **settings: Any) -> None:
        self._core = _Core(1, parallel=False, block=SINGLE_BLOCK, **merged(settings, DEFAULTS))
        self.action_space, self.observation_space = self._core.spaces()
        self._attach(render_mode, render_window)
        self._skip = self._core.no_skip
        self._t = 0
        # nothing to record (and step not overridden): a step is the core's single step
        if self._hist is None and type(self).step is Manoeuvring3DOFEnv.step:
            self.step = self._core.step_single  # type: ignore[method-assign]

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._core.reset_all(self.np_random, options)
        self._t = 0
        if self._hist is not None:
            self._hist.clear()
            self._record()
        if self.render_mode == "human":
            self.render()
        return self._core.obs[0].copy(), self._core.info(0)

    def step(
        self, action: Any
    ) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        """Apply the normalised forces ``action`` for one sample.

        Without a render mode the instance's ``step`` is the core's single step
        (``_Core.step_single``) itself; this method adds the rendering."""
        out = self._core.step_single(action)
        self._t += 1
        if self._hist is not None:
            self._record()
            if self.render_mode == "human":
                self.render()
        return out

    def _record(self) -> None:
        self._append(self._t)

    def render(self) -> np.ndarray | None:
        return self._frame()

    def close(self) -> None:
        self.close_extras()


# --------------------------------------------------------------------------- vector env
class Manoeuvring3DOFVectorEnv(_ManoeuvringBase, VectorEnv):
    """``num_envs`` CyberShip II vessels stepped by one parallel compiled kernel.

    Same dynamics, spaces, rewards and info keys as :class:`Manoeuvring3DOFEnv` (info
    values batched along the first axis). Next-step autoreset: the step after an episode
    ends resets that sub-env (its action is ignored, reward 0, not done). Truncation after
    ``max_episode_steps`` steps (passed by ``gym.make_vec`` from the registration).
    Disturbance processes run on continuously across autoresets (they are stationary);
    directions and the initial state are redrawn.

    ## Arguments

    - ``num_envs``: number of vessels.
    - ``max_episode_steps``: truncation length (2000).
    - ``parallel``: step the vessels in parallel numba threads; default: only with at least
      four threads and 256 vessels (OpenMP thread pools collapse on small or oversubscribed
      machines, where the serial kernel is faster).
    {arguments}
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["rgb_array"],
        "render_fps": 10,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(self, num_envs: int = 1, max_episode_steps: int = 2000,
                 render_mode: str | None = None, *, render_window: int = 600,
                 parallel: bool | None = None, **settings: Any) -> None:
        if int(num_envs) < 1:
            raise VesselidError(f"num_envs must be >= 1, got {num_envs}")
        if int(max_episode_steps) < 1:
            raise VesselidError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        self.num_envs = int(num_envs)
        self.max_episode_steps = int(max_episode_steps)
        block = max(16, VECTOR_BLOCK_SAMPLES // self.num_envs)
        if parallel is None:
            parallel = numba.get_num_threads() >= 4 and self.num_envs >= 256
        self._core = _Core(self.num_envs, parallel=bool(parallel), block=block,
                           **merged(settings, DEFAULTS))
        self.single_action_space, self.single_observation_space = self._core.spaces()
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._attach(render_mode, render_window)
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._prev_done = np.zeros(self.num_envs, dtype=np.bool_)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._core.reset_all(self.np_random, options)
        self._steps[:] = 0
        self._prev_done[:] = False
        if self._hist is not None:
            self._hist.clear()
            self._record()
        return self._core.obs.copy(), self._core.info()

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        core = self._core
        require_reset(core.rng is not None)
        actions = check_action(actions, self.action_space.shape, name="actions")
        skip = self._prev_done
        if skip.any():
            core._initial(core.rng, np.flatnonzero(skip), None)
        core.step(actions, skip)
        self._steps += 1
        self._steps[skip] = 0
        terminated = core.terminated.copy()
        truncated = self._steps >= self.max_episode_steps
        terminated[skip] = False
        truncated[skip] = False
        self._prev_done = terminated | truncated
        if self._hist is not None:
            if skip[0]:
                self._hist.clear()
            self._record()
        return core.obs.copy(), core.rewards.copy(), terminated, truncated, core.info()

    def _record(self) -> None:
        self._append(self._steps[0])

    def render(self) -> np.ndarray | None:
        """RGB frame of sub-environment 0."""
        return self._frame()


document(_DOC_ARGS, Manoeuvring3DOFEnv, Manoeuvring3DOFVectorEnv)
