"""``vesselid/Heave-v0``: heave velocity control of an underwater vehicle (paper §6).

The plant is the :class:`~vesselid.plant.systems.System` of :func:`vesselid.plant.systems.heave`:
``w_a(k+1) = a0 w_r(k) + n0 w_r(k)|w_r(k)| + f0 τ(k) + ξ(k)``, ``w_r = w_a − w_c``,
θ0 = [0.99, −0.1, 1], ``y1 = w_a + e1``, optionally ``y2 = w_c + e2``. Spec, θ0,
coupling sign and (white Gaussian) disturbances come from that system, and the step is
its own one-step kernel (:func:`vesselid.plant.simulate.step_states`); the environment adds
action scaling, the reference, the reward and episodes. :class:`HeaveEnv` is the shared
core with ``n = 1``; :class:`HeaveVectorEnv` steps ``n`` (next-step autoreset).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from vesselid.envs._render import HeavePlot, check_render_mode, warn_no_render_mode
from vesselid.envs._settings import document, finite, merged, pair
from vesselid.envs._validate import check_action, require_reset
from vesselid.errors import VesselidError
from vesselid.model.spec import ModelSpec
from vesselid.plant.simulate import step_states
from vesselid.plant.systems import System, heave, truth_columns

__all__ = ["HeaveEnv", "HeaveVectorEnv"]

_ONE = (1,)
#: Noise drawn at once: time instants (single env), env-instants (vector env).
SINGLE_BLOCK, VECTOR_BLOCK_ELEMENTS = 1024, 1 << 16
# Per instant and env: 4 standard normals (current, ξ, e1, e2; scaled by the system's
# Gaussian disturbances) and 3 uniforms (reference level and hold, initial velocity).
_NZ, _NU = 4, 3
#: Observation rows of the single environment allocated at once (a power of two dividing
#: SINGLE_BLOCK): a kept observation keeps its 64 rows alive (about 1 kB).
_ROWS = 64


#: Numeric settings and their validation.
_NUMBERS: dict[str, dict[str, bool]] = {
    "current_mean": {}, "current_std": {"nonneg": True}, "xi_std": {"nonneg": True},
    "sensor_std": {"nonneg": True}, "current_sensor_std": {"nonneg": True},
    "action_cost": {"nonneg": True}, "velocity_limit": {"positive": True}}


class _HeaveConfig:
    """Validated settings and the plant (a :class:`System`) shared by both environments."""

    def __init__(self, *, reference: float | str, reference_range: tuple[float, float],
                 reference_hold: tuple[int, int], thrust_range: tuple[float, float],
                 initial_velocity: tuple[float, float], current_sensor: bool | None,
                 xi_mean: float | None, **numbers: Any) -> None:
        v = {k: finite(k, numbers[k], **kw) for k, kw in _NUMBERS.items()}
        cm, xm = v["current_mean"], None if xi_mean is None else finite("xi_mean", xi_mean)
        sensor = (cm != 0.0) if current_sensor is None else bool(current_sensor)
        self.thrust_range = pair("thrust_range", thrust_range)
        self.velocity_limit, self.cost = v["velocity_limit"], v["action_cost"]
        self.w0 = pair("initial_velocity", initial_velocity, strict=False)
        self.random_reference = isinstance(reference, str)
        if self.random_reference:
            if reference != "random":
                raise VesselidError(f"reference must be a number or 'random', got {reference!r}")
            self.ref = pair("reference_range", reference_range, strict=False)
            hold = pair("reference_hold", reference_hold, strict=False)
            if hold[0] < 1 or hold[0] != int(hold[0]) or hold[1] != int(hold[1]):
                raise VesselidError(
                    f"reference_hold must be whole numbers of steps >= 1, got {reference_hold!r}")
            self.hold = hold
        else:
            self.ref = (finite("reference", reference),) * 2
            self.hold = (1.0, 1.0)
        if max(map(abs, (*self.ref, *self.w0))) >= self.velocity_limit:
            raise VesselidError(f"reference and initial velocity must lie inside "
                                f"velocity_limit={self.velocity_limit}")
        # the plant: the catalogue heave system with the environment's noise levels
        system = heave(current_mean=cm, current_sensor=sensor, xi_mean=xm, stds={
            k: v[f"{k}_std"] for k in ("current", "xi", "sensor", "current_sensor")})
        self.system: System = system
        self.model_spec: ModelSpec = system.identification_spec()
        self.sensor = sensor
        self.sensor_column = system.sensor_name("w")
        spec = system.spec
        self.layout = (spec.codes.factors, spec.codes.equation, spec.theta0_vector())
        self.sign = float(system.sign("w"))
        # (mean, std) of the system's white Gaussian current and ξ, std of e1 and e2
        self.q = (system.current["w"].mean, system.current["w"].std)
        self.xi = (system.process_noise["w"].mean, system.process_noise["w"].std)
        self.e1, self.e2 = system.sensor_noise["w"].std, v["current_sensor_std"]
        given = {**v, "xi_mean": self.xi[0], "current_sensor": sensor, "reference": reference,
                 "thrust_range": list(self.thrust_range), "reference_range": list(self.ref),
                 "reference_hold": [int(h) for h in self.hold], "initial_velocity": list(self.w0)}
        self.settings: dict[str, Any] = {k: given[k] for k in DEFAULTS}

    def spaces(self) -> tuple[spaces.Box, spaces.Box]:
        high = np.full(3 if self.sensor else 2, 2.0 * self.velocity_limit, dtype=np.float32)
        return (spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32),
                spaces.Box(-high, high, dtype=np.float32))

    def thrust(self, a: np.ndarray) -> np.ndarray:
        """Physical thrust of normalised actions (clipped to [−1, 1])."""
        lo, hi = self.thrust_range
        return lo + (np.clip(a, -1.0, 1.0) + 1.0) * 0.5 * (hi - lo)

    def metadata(self) -> dict[str, Any]:
        described = self.system.describe()
        described.pop("inputs", None)  # the input comes from the agent
        described.pop("x0", None)
        return {"settings": dict(self.settings), "system": described}


class _Core:
    """State of ``n`` heave environments; the single environment is ``n = 1``."""

    def __init__(self, cfg: _HeaveConfig, n: int, block: int, max_steps: int = 0) -> None:
        self.cfg, self.n, self.block, self.max_steps = cfg, n, block, max_steps
        self.s = {k: np.zeros(n) for k in ("w_a", "w_c", "xi", "y1", "y2", "w_ref", "hold")}
        self.steps = np.zeros(n, dtype=np.int64)
        self.prev_done = np.zeros(n, dtype=np.bool_)
        self.tau = np.full(n, np.nan)
        self.rng: np.random.Generator | None = None
        self.k = block

    def _draw(self) -> tuple[np.ndarray, np.ndarray]:
        if self.k >= self.block:
            self.z = self.rng.standard_normal((self.block, self.n, _NZ))
            self.u = self.rng.random((self.block, self.n, _NU))
            self.k = 0
        self.k += 1
        return self.z[self.k - 1], self.u[self.k - 1]

    def _sense(self, m: Any, z: np.ndarray) -> None:
        c, s = self.cfg, self.s
        s["w_c"][m] = c.q[0] + c.q[1] * z[m, 0]
        s["xi"][m] = c.xi[0] + c.xi[1] * z[m, 1]
        s["y1"][m] = s["w_a"][m] + c.e1 * z[m, 2]
        s["y2"][m] = s["w_c"][m] + c.e2 * z[m, 3]

    def _new_reference(self, m: Any, u: np.ndarray) -> None:
        (lo, hi), (h_lo, h_hi) = self.cfg.ref, self.cfg.hold
        if self.cfg.random_reference:
            self.s["w_ref"][m] = lo + (hi - lo) * u[m, 0]
            self.s["hold"][m] = h_lo + np.floor(u[m, 1] * (h_hi - h_lo + 1.0))
        else:
            self.s["w_ref"][m] = lo
            self.s["hold"][m] = np.inf

    def _start(self, m: Any, z: np.ndarray, u: np.ndarray) -> None:
        lo, hi = self.cfg.w0
        self.s["w_a"][m] = lo + (hi - lo) * u[m, 2]
        self._new_reference(m, u)
        self._sense(m, z)
        self.steps[m] = 0

    def reset(self, rng: np.random.Generator, w0: Any = None) -> None:
        self.rng, self.k = rng, self.block
        z, u = self._draw()
        self._start(slice(None), z, u)
        self.prev_done[:] = False
        self.tau[:] = np.nan
        if w0 is not None:
            w0 = np.broadcast_to(np.asarray(w0, dtype=np.float64), (self.n,))
            if not np.all(np.isfinite(w0)):
                raise VesselidError("options['w0'] must be finite")
            self.s["y1"] += w0 - self.s["w_a"]
            self.s["w_a"][:] = w0

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One sample for every environment; returns reward, terminated, truncated."""
        cfg, s = self.cfg, self.s
        z, u = self._draw()
        go = ~self.prev_done
        rew, term, trunc = np.zeros(self.n), np.zeros(self.n, bool), np.zeros(self.n, bool)
        tau = cfg.thrust(np.asarray(actions, dtype=np.float64).reshape(self.n)[go])
        nxt = np.empty((tau.size, 1))
        step_states(*cfg.layout, s["w_a"][go, None], cfg.sign * s["w_c"][go, None],
                    tau.reshape(-1, 1), s["xi"][go, None], nxt)
        nxt = nxt[:, 0]
        err = nxt - s["w_ref"][go]
        rew[go] = -(err * err) - cfg.cost * tau * tau
        s["w_a"][go] = nxt
        s["hold"][go] -= 1.0
        self._new_reference(go & (s["hold"] <= 0.0), u)
        self._sense(go, z)
        term[go] = ~(np.abs(nxt) <= cfg.velocity_limit)  # also true for NaN
        self.steps[go] += 1
        trunc[go] = (self.max_steps > 0) & (self.steps[go] >= self.max_steps)
        self.tau[go] = tau
        if self.prev_done.any():  # next-step autoreset
            self._start(self.prev_done, z, u)
            self.tau[self.prev_done] = np.nan
        self.prev_done = term | trunc
        return rew, term, trunc

    def obs(self) -> np.ndarray:
        cols = ("y1", "y2", "w_ref") if self.cfg.sensor else ("y1", "w_ref")
        return np.column_stack([self.s[c] for c in cols]).astype(np.float32)

    def info(self) -> dict[str, np.ndarray]:
        keys = ("w_a", "w_r", "w_c", "xi", "y1", "y2", "w_ref")
        s = dict(self.s, w_r=self.s["w_a"] - self.s["w_c"])
        return {k: s[k].copy() for k in keys if k != "y2" or self.cfg.sensor}


#: Source of :meth:`_ScalarCore.step`, formatted by :func:`_compile_step`: ``{plant}``
#: becomes ``ξ + Σ θ_p F_a F_b`` written out in term order (the sums of the compiled
#: :func:`vesselid.model.regressors.advance`) with ``F = [s, τ, |s|, |τ|, 1]``, ``s = w_a +
#: sign·w_c`` (``{s}``), and the other fields the environment's constants as literals.
_SCALAR_STEP = """
def step(self, action):
    # an ndarray of the action space's shape holding a finite float (what agents pass)
    # is read directly (``a - a`` is NaN for ±inf and NaN); anything else goes through
    # the full check, which also words the refusal
    try:
        (a,) = action.tolist()
    except (AttributeError, TypeError, ValueError):
        a = None
    if a.__class__ is not float or not a - a == 0.0:
        a = self.checked(action)
    k = self.k
    if k >= {block}:
        self._draw()  # raises ResetNeeded before the first reset
        k = 0
    else:
        self.k = k + 1
        if not k & {mask}:
            self._new_rows(k)
    if self.prev_done:  # stepped past the end without reset: next-step autoreset
        return self._autoreset(k)
    tau = {lo!r} + ((-1.0 if a < -1.0 else 1.0 if a > 1.0 else a) + 1.0) * 0.5 * {span!r}
    s = {s}
    nxt = {plant}
    err = nxt - self.w_ref
    self.w_a = nxt
    self.hold = hold = self.hold - 1.0
    if hold <= 0.0:
        self._new_reference(self.u[k].tolist(), k)
    self.w_c = w_c = self.wc[k]
    self.xi = xi = self.xis[k]
    self.y1 = y1 = nxt + self.e1z[k]
    self.y2 = y2 = self.y2s[k]
    self.tau_now = tau
    self.prev_done = term = not (abs(nxt) <= {limit!r})  # also true for NaN
    o = self.rows[k & {mask}]  # y2 and w_ref are in place (_new_rows, _new_reference)
    o[0] = y1
    return o, -(err * err) - {cost!r} * tau * tau, term, False, {info}
"""


def _compile_step(cfg: _HeaveConfig, block: int) -> Any:
    """:data:`_SCALAR_STEP` for one plant (factor layout and θ of a one-state system) and
    the environment's constants (``repr`` of a float reads back as the same float)."""
    fac, _, theta = cfg.layout

    def product(i: int, j: int) -> str:  # a factor 1.0 is left out (x · 1.0 is x, exactly)
        names = [n for n in (("s", "tau", "abs(s)", "abs(tau)", "1.0")[f] for f in (i, j))
                 if n != "1.0"]
        return " * ".join(names) or "1.0"

    plant = "self.xi" + "".join(  # and so is 1.0 · x
        f" + {product(int(i), int(j))}" if float(t) == 1.0
        else f" + {float(t)!r} * ({product(int(i), int(j))})"
        for (i, j), t in zip(fac, theta, strict=True))
    s = {1.0: "self.w_a + self.w_c", -1.0: "self.w_a - self.w_c"}.get(  # exact: a + -b is a - b
        cfg.sign, f"self.w_a + {cfg.sign!r} * self.w_c")
    y2 = ' "y2": y2,' if cfg.sensor else ""
    info = ('{"w_a": nxt, "w_r": nxt - w_c, "w_c": w_c, "xi": xi, "y1": y1,' + y2
            + ' "w_ref": self.w_ref}')
    lo, hi = cfg.thrust_range
    source = _SCALAR_STEP.format(block=int(block), mask=_ROWS - 1, lo=lo, span=hi - lo, s=s,
                                 plant=plant, limit=cfg.velocity_limit, cost=cfg.cost,
                                 info=info)
    scope: dict[str, Any] = {}
    exec(compile(source, "<heave scalar step>", "exec"), scope)
    return scope["step"]


class _ScalarCore:
    """One heave environment on Python floats: the operations of :class:`_Core` with
    ``n = 1``, in the same order and from the same draws, so bit-identical to it.

    The single environment steps one sample per call, where numpy's per-call overhead
    on arrays of one element would dominate. Its :meth:`step` is generated per
    environment (:func:`_compile_step`): action check, plant, reward, observation and
    info in one function, the plant's one-step map ``Φᵀ(s)θ + ξ`` evaluated from the
    system's factor layout in term order (as the compiled
    :func:`vesselid.model.regressors.advance`). What depends on the noise alone (current,
    ξ, sensor noise, the current meter) is computed for a whole block of draws at once
    with numpy's elementwise operations, the same IEEE operations as the scalar ones.
    The observations are the rows of float32 arrays of :data:`_ROWS` rows with the
    current meter and the reference filled in ahead (a view costs less than a new
    array); each row is returned by one step and never written again.
    """

    n = 1

    def __init__(self, cfg: _HeaveConfig, block: int) -> None:
        self.cfg, self.block = cfg, block
        fac, eq, _ = cfg.layout
        if block % _ROWS:  # pragma: no cover
            raise VesselidError(f"the noise block must be a multiple of {_ROWS} instants")
        if fac.shape[0] and (int(eq.max()) != 0 or int(fac.max()) > 4):  # pragma: no cover
            raise VesselidError("the scalar heave core needs one state and one input")
        self.step = _compile_step(cfg, block).__get__(self)
        self.n_obs = 3 if cfg.sensor else 2
        self.w_a = self.w_c = self.xi = self.y1 = self.y2 = self.w_ref = self.hold = 0.0
        self.prev_done = False
        self.tau_now = math.nan
        self.rng: np.random.Generator | None = None
        self.buffer = np.zeros(self.n_obs, dtype=np.float32)
        self.k = block
        # per instant of the noise block: current, ξ, e1 and the current meter reading
        # (lists of floats: cheaper to index than arrays), the uniforms, the observations
        self.wc: list[float] = []
        self.xis: list[float] = []
        self.e1z: list[float] = []
        self.y2s: list[float] = []
        self.u = np.zeros((0, _NU))
        self.y2a = np.zeros(0)
        self.rows = np.zeros((0, self.n_obs), dtype=np.float32)

    # the plotting and recorder helpers read the state as arrays of one element
    @property
    def s(self) -> dict[str, np.ndarray]:
        return {k: np.array([getattr(self, k)]) for k in
                ("w_a", "w_c", "xi", "y1", "y2", "w_ref", "hold")}

    @property
    def tau(self) -> np.ndarray:
        return np.array([self.tau_now])

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, float]]:
        """One sample with the normalised ``action``: the single environment's ``(obs,
        reward, terminated, truncated, info)``. Replaced per instance by the step
        compiled from :data:`_SCALAR_STEP`."""
        raise NotImplementedError  # pragma: no cover - bound in __init__

    def __getstate__(self) -> dict[str, Any]:  # the generated step is made again
        return {k: v for k, v in self.__dict__.items() if k != "step"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.step = _compile_step(self.cfg, self.block).__get__(self)

    def checked(self, action: Any) -> float:
        """The action as a float, or the clear error of :func:`check_action` (after
        :func:`require_reset`, as every environment)."""
        require_reset(self.rng is not None)
        return float(check_action(action, _ONE)[0])

    def _draw(self) -> None:
        """The next noise block, drawn as :class:`_Core` draws it for ``n = 1``; the
        step uses its instant 0."""
        require_reset(self.rng is not None)
        c, n = self.cfg, self.block
        z = self.rng.standard_normal((n, 1, _NZ)).reshape(n, _NZ)
        self.u = self.rng.random((n, 1, _NU)).reshape(n, _NU)
        w_c = c.q[0] + c.q[1] * z[:, 0]  # the operations of _Core._sense, elementwise
        y2 = w_c + c.e2 * z[:, 3]
        self.wc, self.y2s = w_c.tolist(), y2.tolist()
        self.xis = (c.xi[0] + c.xi[1] * z[:, 1]).tolist()
        self.e1z = (c.e1 * z[:, 2]).tolist()
        self.y2a = y2
        self.k = 1
        self._new_rows(0)

    def _new_rows(self, k: int) -> None:
        """The observation rows of instants ``k`` to ``k + _ROWS − 1`` of the block."""
        self.rows = rows = np.empty((_ROWS, self.n_obs), dtype=np.float32)
        if self.cfg.sensor:
            rows[:, 1] = self.y2a[k:k + _ROWS]
        rows[:, -1] = self.w_ref

    def _new_reference(self, u: list[float], k: int) -> None:
        """A new reference level and hold from the uniforms ``u`` of instant ``k``."""
        (lo, hi), (h_lo, h_hi) = self.cfg.ref, self.cfg.hold
        if self.cfg.random_reference:
            self.w_ref = lo + (hi - lo) * u[0]
            self.hold = h_lo + float(math.floor(u[1] * (h_hi - h_lo + 1.0)))
        else:
            self.w_ref = lo
            self.hold = math.inf
        self.rows[k & (_ROWS - 1):, -1] = self.w_ref  # the observations from instant k on

    def _start(self, k: int) -> None:
        """A new episode from the draws of instant ``k``."""
        lo, hi = self.cfg.w0
        u = self.u[k].tolist()
        self.w_a = lo + (hi - lo) * u[2]
        self._new_reference(u, k)
        self.w_c, self.xi = self.wc[k], self.xis[k]
        self.y1 = self.w_a + self.e1z[k]
        self.y2 = self.y2s[k]

    def _autoreset(self, k: int) -> tuple[np.ndarray, float, bool, bool, dict[str, float]]:
        self._start(k)
        self.tau_now = math.nan
        self.prev_done = False
        return self.obs(), 0.0, False, False, self.info()

    def reset(self, rng: np.random.Generator, w0: float | None = None) -> None:
        self.rng = rng
        self._draw()
        self._start(0)
        self.prev_done = False
        self.tau_now = math.nan
        if w0 is not None:
            self.y1 += w0 - self.w_a
            self.w_a = w0

    def obs(self) -> np.ndarray:
        o = self.buffer
        o[0] = self.y1
        if self.cfg.sensor:
            o[1] = self.y2
        o[-1] = self.w_ref
        return o.copy()

    def info(self) -> dict[str, float]:
        if self.cfg.sensor:
            return {"w_a": self.w_a, "w_r": self.w_a - self.w_c, "w_c": self.w_c,
                    "xi": self.xi, "y1": self.y1, "y2": self.y2, "w_ref": self.w_ref}
        return {"w_a": self.w_a, "w_r": self.w_a - self.w_c, "w_c": self.w_c,
                "xi": self.xi, "y1": self.y1, "w_ref": self.w_ref}


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
      default on iff ``current_mean != 0`` (as :func:`vesselid.plant.systems.heave`).
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

#: Settings of both environments and their defaults (see ``## Arguments``).
DEFAULTS: dict[str, Any] = {
    "current_mean": 0.0, "current_std": 0.1, "xi_mean": None, "xi_std": 0.1,
    "sensor_std": 0.1, "current_sensor": None, "current_sensor_std": 0.1,
    "thrust_range": (0.0, 0.5), "reference": "random", "reference_range": (0.5, 1.5),
    "reference_hold": (50, 200), "action_cost": 0.1, "initial_velocity": (0.0, 1.5),
    "velocity_limit": 10.0,
}


class _HeaveBase:
    """Construction, rendering and the recorder contract shared by both environments."""

    metadata: ClassVar[dict[str, Any]]

    def _setup(self, n: int, block: int, max_steps: int, render_mode: str | None,
               render_window: int, settings: dict[str, Any]) -> None:
        self.render_mode = check_render_mode(render_mode, self.metadata["render_modes"])
        self._cfg = _HeaveConfig(**merged(settings, DEFAULTS))
        self._core: Any = (_ScalarCore(self._cfg, block) if isinstance(self, HeaveEnv)
                           else _Core(self._cfg, n, block, max_steps))
        #: Identification structure of the recorded data (recorder contract).
        self.model_spec: ModelSpec = self._cfg.model_spec
        #: Sample time.
        self.dt: float = float(self._cfg.model_spec.dt or 1.0)
        self.current_sensor: bool = self._cfg.sensor
        self._t = 0
        self._plot = HeavePlot(render_mode, self._cfg.sensor, self.metadata["render_fps"],
                               render_window, n) if render_mode else None

    def _restart(self) -> None:
        self._t = 0
        if self._plot is not None:
            self._plot.clear()
        self._record()

    def _record(self, tau: np.ndarray | None = None) -> None:
        if self._plot is not None:
            s = self._core.s
            self._plot.record(self._t, s["w_a"], s["y1"], s["w_ref"], s["w_c"], s["y2"], tau)

    def _frames(self) -> list[np.ndarray | None] | None:
        if self._plot is None:
            warn_no_render_mode("vesselid/Heave-v0")
            return None
        if not self._plot.length:
            raise VesselidError("call reset() before render()")
        return self._plot.frames(f"Heave-v0, step {self._t}")

    def close_extras(self, **kwargs: Any) -> None:
        if self._plot is not None:
            self._plot.close()

    def thrust(self, actions: Any) -> Any:
        """Physical thrust τ applied for normalised action(s)."""
        try:
            tau = self._cfg.thrust(np.asarray(actions, dtype=np.float64).reshape(self._core.n))
        except (TypeError, ValueError) as exc:
            raise VesselidError(f"action must hold {self._core.n} number(s)") from exc
        return float(tau[0]) if isinstance(self, HeaveEnv) else tau

    def log_row(self, info: dict[str, Any]) -> dict[str, Any]:
        """Trial-log columns at the time of ``info`` (recorder contract): ``w`` = y1,
        the current meter (if any), ``w_ref`` and ground truth ``true_*``."""
        row = {"w": info["y1"]} | ({self._cfg.sensor_column: info["y2"]} if self.current_sensor
                                   else {})
        truth = dict(zip(truth_columns("w"), (info["w_a"], info["w_c"], info["xi"]), strict=True))
        return row | {"w_ref": info["w_ref"]} | truth

    def log_inputs(self, action: Any) -> dict[str, Any]:
        """Physical inputs applied for ``action`` (recorder contract): ``{"tau": τ}``."""
        return {"tau": self.thrust(action)}

    def log_metadata(self) -> dict[str, Any]:
        """Disturbance and sensor settings (JSON-serialisable), for log metadata."""
        return self._cfg.metadata()


class HeaveEnv(_HeaveBase, gym.Env[np.ndarray, np.ndarray]):
    """Heave velocity tracking for an underwater vehicle (Ljungberg & Enqvist, §6).

    ## Description

    The absolute heave velocity ``w_a`` follows paper eq. (15) (module docstring): the
    current ``w_c`` enters *inside* the nonlinearity, ``ξ`` is additive; ``y1 = w_a + e1``
    and optionally a current meter ``y2 = w_c + e2``. White Gaussian noises; defaults are
    the paper's §6 values (variance 0.01, w̄c = 0, mean of ξ w̄c − 0.05).

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: normalised thrust, clipped to [−1, 1] and mapped
    linearly to the physical thrust ``τ`` on ``thrust_range`` (default [0, 0.5]).

    ## Observation Space

    ``Box(±2·velocity_limit, (2,) or (3,), float32)``: ``y1``, ``y2`` (only with
    ``current_sensor``) and the reference ``w_ref``. Every observation is an array of
    its own that the environment never writes again; those of ``step`` are rows of
    blocks of 64 (a view costs less than a new array), so one kept observation keeps
    its block (about 1 kB) alive.

    ## Rewards

    ``r(k) = −(w_a(k+1) − w_ref(k))² − action_cost · τ(k)²``: tracking error of the *true*
    velocity after the step against the reference observed with the action, plus a
    thrust penalty.

    ## Starting State and Episode End

    ``w_a(0)`` uniform on ``initial_velocity`` (or ``reset(options={"w0": value})``); the
    reference starts a new level. Termination when ``|w_a|`` exceeds ``velocity_limit`` or
    is non-finite; truncation after ``max_episode_steps`` (1000 in the registration).

    ## Info

    Same keys after ``reset`` and ``step``, at the time of the observation: ``w_a``,
    ``w_r = w_a − w_c``, ``w_c`` and ``xi`` (acting in the coming step), ``y1``, ``y2``
    (with ``current_sensor``), ``w_ref``; ``w_a(k+1)`` follows from ``info(k)`` and ``τ(k)``.

    ## Arguments

    {arguments}

    :attr:`model_spec`, :meth:`log_row`, :meth:`log_inputs` and :meth:`log_metadata`
    implement the recorder contract of :mod:`vesselid.envs.recorder`.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"],
                                          "render_fps": 30}

    def __init__(self, render_mode: str | None = None, *, render_window: int = 200,
                 **settings: Any) -> None:
        self._setup(1, SINGLE_BLOCK, 0, render_mode, render_window, settings)
        self.action_space, self.observation_space = self._cfg.spaces()
        self._bind_step()

    def _bind_step(self) -> None:
        # nothing to record (and step not overridden): a step is the core's compiled step
        if self._plot is None and type(self).step is HeaveEnv.step:
            self.step = self._core.step  # type: ignore[method-assign]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, float]]:
        """Start an episode; ``options={"w0": value}`` sets the initial true velocity."""
        super().reset(seed=seed)
        w0 = None if not options or "w0" not in options else finite("options['w0']",
                                                                     options["w0"])
        self._core.reset(self.np_random, w0)
        self._restart()
        if self.render_mode == "human":
            self.render()
        return self._core.obs(), self._core.info()

    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "step"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._bind_step()

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, float]]:
        """Apply the normalised thrust ``action`` for one sample.

        Without a render mode the instance's ``step`` is the core's generated step
        (:class:`_ScalarCore`) itself; this method adds the rendering."""
        out = self._core.step(action)
        self._t += 1
        if self._plot is not None:
            self._record(self._core.tau)
            if self.render_mode == "human":
                self.render()
        return out

    def render(self) -> np.ndarray | None:
        """Plot the recent window (``rgb_array``: an ``(H, W, 3)`` uint8 image)."""
        frames = self._frames()
        return None if frames is None else frames[0]

    close = _HeaveBase.close_extras


class HeaveVectorEnv(_HeaveBase, VectorEnv):
    """``num_envs`` copies of :class:`HeaveEnv` on one core (batched spaces and info with
    ``"_<key>"`` masks). Next-step autoreset: the step after an episode ends resets that
    sub-env (action ignored, reward 0). One generator, ``self.np_random``.

    ## Arguments

    - ``num_envs``: number of sub-environments.
    - ``max_episode_steps``: truncation length (0 or None: never truncate).
    {arguments}"""

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": ["rgb_array"], "render_fps": 30,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = 1000,
                 render_mode: str | None = None, *, render_window: int = 200,
                 **settings: Any) -> None:
        num_envs = int(num_envs)
        if num_envs < 1:
            raise VesselidError(f"num_envs must be at least 1, got {num_envs}")
        self.num_envs = num_envs
        self.max_episode_steps = int(max_episode_steps or 0)
        self._setup(num_envs, max(1, VECTOR_BLOCK_ELEMENTS // num_envs),
                    self.max_episode_steps, render_mode, render_window, settings)
        self.single_action_space, self.single_observation_space = self._cfg.spaces()
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._mask = np.ones(num_envs, dtype=np.bool_)
        self._mask.flags.writeable = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Reset every sub-environment; ``options={"w0": value or array}`` sets ``w_a(0)``."""
        super().reset(seed=seed)
        self._core.reset(self.np_random, (options or {}).get("w0"))
        self._restart()
        return self._core.obs(), self._info()

    def _info(self) -> dict[str, np.ndarray]:
        info = self._core.info()
        return info | {f"_{k}": self._mask for k in info}

    def step(self, actions: Any
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Step all sub-environments with normalised thrusts of shape ``(num_envs, 1)``."""
        require_reset(self._core.rng is not None)
        rew, term, trunc = self._core.step(check_action(actions, self.action_space.shape,
                                                        name="actions"))
        self._t += 1
        self._record(self._core.tau)
        return self._core.obs(), rew, term, trunc, self._info()

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One ``(H, W, 3)`` uint8 frame per sub-environment (slow for many envs)."""
        frames = self._frames()
        return None if frames is None else tuple(frames)


document(_DOC_ARGS, HeaveEnv, HeaveVectorEnv)
