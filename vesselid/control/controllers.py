"""Model-based control of CyberShip II from an identified θ: the "control experiment".

:class:`FeedbackLinearizingController` inverts the identified discrete-time second-order
modulus model (the sea-trial spec of :func:`vesselid.studies.seatrial.seatrial_spec`, velocity
through water ``ν_r`` as state) for the surge force ``X`` and the yaw moment ``N``:

* surge — choose ``X`` so that the model's one-step prediction of the surge speed reaches
  ``u_r(k) + (dt/T_u)(u_ref − u(k)) + k_iu ∫(u_ref − u)``;
* heading — an outer PI law gives the yaw-rate reference
  ``r_ref = sat(K_ψ wrap(ψ_ref − ψ) + K_iψ ∫ wrap(ψ_ref − ψ), ±r_max)``, and ``N`` is chosen
  so that the model predicts ``r(k+1) = r(k) + (dt/T_r)(r_ref − r(k))``;
* ``Y = 0`` (no sway force is used, as with a conventional rudder/propeller ship).

Solving the model's input terms for τ: with ``φ`` the regressors of the measured state,
``u(k+1) = θ_u,X X + Σ_{j≠X} θ_u,j φ_j`` gives ``X = (u_des − Σ_{j≠X} θ_u,j φ_j) / θ_u,X``
and the same for ``N`` in the ``r`` equation (paper Definition 2.1: the input terms are
linear). Forces are saturated to the environment's limits and normalised to actions.

Measurements used (the environment's sensors, not privileged truth): the Doppler speed log
``[u_r, v_r]`` (regressors), the gyro ``r``, the heading sensor ``ψ`` and the GNSS surge
speed ``u`` (the tracked speed over ground).

:func:`run_control_experiment` runs one controller per θ in ``vesselid/Manoeuvring3DOF-v0``
with current and wind (identical disturbance realisations for all controllers) and
reports RMS tracking errors.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.errors import ControlError
from vesselid.model.spec import ModelSpec

__all__ = [
    "AdaptiveFeedbackLinearizingController",
    "ControlError",
    "ControlExperiment",
    "FeedbackLinearizingController",
    "default_reference",
    "run_control_experiment",
]


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def default_reference(t: float) -> tuple[float, float]:
    """Reference ``(u_ref [m/s], ψ_ref [rad])``: speed steps 0.3/0.45/0.25 m/s, heading
    steps 0/45°/−30°/0."""
    u_ref = 0.3 if t < 60.0 else (0.45 if t < 120.0 else 0.25)
    if t < 20.0:
        psi = 0.0
    elif t < 80.0:
        psi = math.radians(45.0)
    elif t < 140.0:
        psi = math.radians(-30.0)
    else:
        psi = 0.0
    return u_ref, psi


@dataclass
class FeedbackLinearizingController:
    """Feedback linearisation of surge speed and heading from an identified model.

    Parameters
    ----------
    spec : ModelSpec
        Model structure with states ``u, v, r`` and inputs ``X, Y, N`` (e.g.
        :func:`vesselid.studies.seatrial.seatrial_spec`); its regressors use the velocity through
        water.
    theta : array-like
        Parameter vector in ``spec`` order (θ0 or an estimate).
    force_max : (float, float, float), optional
        Force limits of the actuators (N, N, N m); actions are ``τ / force_max``. Default
        the limits of the catalogue vessel named by ``spec.name``.
    t_u, t_r : float
        Desired closed-loop time constants of surge speed and yaw rate (s).
    k_psi, ki_psi, r_max : float
        Heading PI gains (1/s, 1/s²) and the yaw-rate reference limit (rad/s).
    ki_u : float
        Integral gain on the surge-speed error (1/s), rejects wind and model bias.
    reference : callable t -> (u_ref, ψ_ref)
        Reference (default :func:`default_reference`).
    """

    spec: ModelSpec
    theta: Any
    force_max: Sequence[float] | None = None
    t_u: float = 5.0
    t_r: float = 1.0
    k_psi: float = 0.4
    ki_psi: float = 0.01
    r_max: float = 0.25
    ki_u: float = 0.02
    reference: Callable[[float], tuple[float, float]] = default_reference
    _state: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        spec = self.spec
        if list(spec.states) != ["u", "v", "r"] or list(spec.inputs) != ["X", "Y", "N"]:
            raise ControlError("the controller needs states [u, v, r] and inputs [X, Y, N]")
        theta = np.asarray(self.theta, dtype=float).ravel()
        if theta.shape != (spec.n_params,) or not np.all(np.isfinite(theta)):
            raise ControlError(f"theta must be {spec.n_params} finite values")
        self.theta = theta
        self.dt = float(spec.dt or 0.1)
        codes = spec.codes
        self._codes = codes
        names = [str(t) for _, t in spec.param_index]
        eq = codes.equation
        self._gain = {}
        for state, inp in (("u", "X"), ("r", "N"), ("r", "Y"), ("u", "Y"), ("u", "N")):
            i = spec.states.index(state)
            idx = [p for p in range(spec.n_params) if eq[p] == i and names[p] == inp]
            self._gain[(state, inp)] = theta[idx[0]] if idx else 0.0
        if abs(self._gain[("u", "X")]) < 1e-12 or abs(self._gain[("r", "N")]) < 1e-12:
            raise ControlError("the model has no (or a zero) X → u or N → r input gain")
        self._input_cols = np.array([names[p] in ("X", "Y", "N") for p in range(spec.n_params)])
        self._eq = eq
        if self.force_max is None:
            from vesselid.plant.catalogue import vessel_module

            self.force_max = vessel_module(spec.name).HULL.force_max
        self.fmax = np.asarray(self.force_max, dtype=float)
        self.reset()

    def reset(self) -> None:
        """Clear the integrators and the clock."""
        self._state = {"iu": 0.0, "ipsi": 0.0, "k": 0}

    def _bias(self) -> np.ndarray:
        """Constant added to the model's free response (zero here; the adaptive
        controller's estimated offsets)."""
        return np.zeros(3)

    def _free_response(self, nu_r: np.ndarray) -> np.ndarray:
        """Model prediction of ``ν_r(k+1)`` with zero input, per state."""
        from vesselid.model.regressors import predict

        free_theta = np.where(self._input_cols, 0.0, self.theta)
        return predict(self._codes, free_theta, np.concatenate([nu_r, np.zeros(3)]))

    def forces(self, u: float, nu_r: Sequence[float], psi: float, t: float) -> np.ndarray:
        """Forces ``[X, Y, N]`` for the measured surge speed over ground ``u``, velocity
        through water ``ν_r = [u_r, v_r, r]`` and heading ``ψ`` at time ``t``."""
        st = self._state
        dt = self.dt
        u_ref, psi_ref = self.reference(t)
        e_u = u_ref - u
        e_psi = _wrap(psi_ref - psi)
        nu_r = np.asarray(nu_r, dtype=float)
        r_ref = self.k_psi * e_psi + self.ki_psi * st["ipsi"]
        r_ref = min(max(r_ref, -self.r_max), self.r_max)
        u_des = nu_r[0] + dt / self.t_u * e_u + self.ki_u * dt * st["iu"]
        r_des = nu_r[2] + dt / self.t_r * (r_ref - nu_r[2])
        free = self._free_response(nu_r) + self._bias()
        x = (u_des - free[0]) / self._gain[("u", "X")]
        n = (r_des - free[2]) / self._gain[("r", "N")]
        tau = np.clip(np.array([x, 0.0, n]), -self.fmax, self.fmax)
        # conditional integration (anti-windup): integrate only when not saturated
        if abs(tau[0]) < self.fmax[0]:
            st["iu"] += e_u / self.t_u
        if abs(tau[2]) < self.fmax[2] and abs(r_ref) < self.r_max:
            st["ipsi"] += e_psi * dt
        st["k"] += 1
        return tau

    def __call__(self, info: Mapping[str, Any], t: float | None = None) -> np.ndarray:
        """Normalised action from an environment ``info`` dict (sensor keys ``gnss``,
        ``speed_log``, ``gyro``, ``heading``)."""
        try:
            u = float(np.asarray(info["gnss"])[0])
            u_r, v_r = (float(x) for x in np.asarray(info["speed_log"])[:2])
            r = float(np.asarray(info["gyro"])[0])
            psi = float(np.asarray(info["heading"])[0])
        except KeyError as exc:
            raise ControlError(f"the controller needs the sensor {exc} in info") from exc
        tt = self._state["k"] * self.dt if t is None else float(t)
        return (self.forces(u, [u_r, v_r, r], psi, tt) / self.fmax).astype(np.float32)


@dataclass
class AdaptiveFeedbackLinearizingController(FeedbackLinearizingController):
    """:class:`FeedbackLinearizingController` whose model is updated online by recursive IV.

    The parameters a changing vessel moves most — the input gains ``θ_u,X`` and
    ``θ_r,N`` (actuator efficiency, mass and inertia with load) — and a constant offset per
    equation (current, wind, model bias) are estimated at every sample from the equation
    errors of the surge and yaw equations with the rest of the model fixed:
    ``u_r(k+1) − f_u(ν_r(k)) = θ_u,X X(k) + c_u`` (``f_u`` the model's free response),
    likewise for ``r`` with ``N``. The recursion is
    :class:`vesselid.identify.recursive.RecursiveEstimator` (recursive IV with forgetting,
    delayed-input instruments ``[X(k − delay), 1]``: in the loop ``X(k)`` reacts to the
    sensor noise at ``k``, which the equation error contains, while the delayed input does
    not). The control law uses the latest gains (bounded to ``gain_bounds`` times the
    initial ones) and subtracts the estimated offsets. The parameters below come besides
    those of :class:`FeedbackLinearizingController`.

    Parameters
    ----------
    forgetting : float
        λ of the recursion (memory ``1/(1 − λ)`` samples).
    delay : int
        Delay of the input instruments (samples).
    warmup : int
        Samples before the first update is used.
    gain_bounds : (float, float)
        Limits of the adapted gains relative to the initial ones.
    """

    forgetting: float = 0.995
    delay: int = 2
    warmup: int = 100
    gain_bounds: tuple[float, float] = (0.25, 4.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        from vesselid.identify.recursive import RecursiveEstimator, check_forgetting

        self.forgetting = check_forgetting(self.forgetting)
        lo, hi = self.gain_bounds
        if not (0 < lo < 1 < hi):
            raise ControlError(f"gain_bounds need 0 < low < 1 < high, got {self.gain_bounds}")
        self._g0 = (self._gain[("u", "X")], self._gain[("r", "N")])
        aux = ModelSpec(name="adaptive", states=["u", "r"], inputs=["X", "N"],
                        equations={"u": ["X"], "r": ["N"]}, dt=self.dt)
        self._rec = RecursiveEstimator(aux, "iv", forgetting=self.forgetting,
                                       instruments="delayed", delay=int(self.delay),
                                       warmup=int(self.warmup))
        self._prev: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.trace: list[tuple[float, float, float, float]] = []

    def reset(self) -> None:
        super().reset()
        if hasattr(self, "_rec"):
            self._prev = None
            self._rec.new_experiment()

    def _bias(self) -> np.ndarray:
        if not hasattr(self, "_rec") or not self._rec.ready:
            return np.zeros(3)
        c = self._rec.intercepts
        return np.array([c[0], 0.0, c[1]])

    def forces(self, u: float, nu_r: Sequence[float], psi: float, t: float) -> np.ndarray:
        nu = np.asarray(nu_r, dtype=float)
        if self._prev is not None:
            nu_p, free_p, tau_p = self._prev
            target = np.array([nu[0] - free_p[0], nu[2] - free_p[2]])
            self._rec.update([nu_p[0], nu_p[2]], [tau_p[0], tau_p[2]], target)
            if self._rec.ready:
                th = self._rec.theta
                lo, hi = self.gain_bounds
                for k, (key, g0) in enumerate(zip((("u", "X"), ("r", "N")), self._g0,
                                                  strict=True)):
                    if np.isfinite(th[k]):
                        self._gain[key] = float(np.clip(th[k] / g0, lo, hi) * g0)
        tau = super().forces(u, nu, psi, t)
        self._prev = (nu, self._free_response(nu), tau)
        self.trace.append((float(t), self._gain[("u", "X")], self._gain[("r", "N")],
                           float(self._bias()[0])))
        return tau


@dataclass
class ControlExperiment:
    """Result of :func:`run_control_experiment`.

    Attributes
    ----------
    table : DataFrame
        Per controller: RMS surge-speed error (m/s), RMS heading error (deg), mean ``|X|``,
        mean ``|N|`` (after ``settle`` seconds).
    traces : dict name -> DataFrame
        Time series ``t, u, u_ref, psi, psi_ref, X, N, r`` (true states; the forces
        applied at ``t``).
    """

    table: pd.DataFrame
    traces: dict[str, pd.DataFrame]

    def plot(self, path: str | Path | None = None, *, dpi: int = 80):
        """Time series of ``u`` and ``ψ`` versus the reference for every controller."""
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(2, 1, figsize=(8.0, 5.0), sharex=True)
        first = next(iter(self.traces.values()))
        axes[0].plot(first["t"], first["u_ref"], "k--", lw=1.0, label="reference")
        axes[1].plot(first["t"], np.degrees(first["psi_ref"]), "k--", lw=1.0)
        for name, tr in self.traces.items():
            axes[0].plot(tr["t"], tr["u"], lw=0.9, label=name)
            axes[1].plot(tr["t"], np.degrees(tr["psi"]), lw=0.9)
        axes[0].set_ylabel("surge speed u (m/s)")
        axes[1].set_ylabel("heading ψ (deg)")
        axes[1].set_xlabel("time (s)")
        axes[0].legend(loc="upper right", fontsize="small", ncol=4)
        axes[0].set_title("Feedback linearisation from θ: Manoeuvring3DOF-v0 with current and wind",
                          fontsize="medium")
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=dpi)
            plt.close(fig)
        return fig


def run_control_experiment(
    thetas: Mapping[str, Any],
    spec: ModelSpec | None = None,
    *,
    steps: int = 1800,
    seed: int = 0,
    settle: float = 10.0,
    current_speed: float = 0.05,
    current_direction: float = math.radians(30.0),
    wind_speed: float = 1.0,
    wind_direction: float = math.radians(-60.0),
    wind_gust: float = 0.1,
    reference: Callable[[float], tuple[float, float]] = default_reference,
    controller_options: Mapping[str, Any] | None = None,
    env_options: Mapping[str, Any] | None = None,
    initial_speed: float = 0.3,
) -> ControlExperiment:
    """Run the feedback-linearising controller for each θ in ``Manoeuvring3DOF-v0``.

    Every controller sees the same disturbance realisation (same env seed, fixed current
    and wind directions, same initial state ``ν = [0.3, 0, 0]``, ``η = 0``).

    Parameters
    ----------
    thetas : mapping name -> θ
        Parameter vectors in ``spec`` order, e.g. ``{"θ0": ..., "LS": ..., "IV": ...}``.
    spec : ModelSpec, optional
        Default :func:`vesselid.studies.seatrial.seatrial_spec` (relative predictor).
    steps : int
        Episode length in samples.
    seed : int
        Environment seed.
    settle : float
        Seconds excluded from the RMS (initial transient).
    current_speed, current_direction, wind_speed, wind_direction, wind_gust : float
        Environment disturbances (m/s, rad).
    reference : callable
        ``t -> (u_ref, ψ_ref)``.
    controller_options, env_options : mapping, optional
        Extra arguments of :class:`FeedbackLinearizingController` and of the environment.
    initial_speed : float
        Surge speed at the start (m/s).

    The vessel is the catalogue vessel named by ``spec.name``.

    Returns
    -------
    ControlExperiment
    """
    import gymnasium as gym

    import vesselid.envs  # noqa: F401  (registers the environments)
    from vesselid.studies.seatrial import seatrial_spec

    spec = spec or seatrial_spec()
    rows, traces = [], {}
    for name, theta in thetas.items():
        ctrl = FeedbackLinearizingController(spec, theta, reference=reference,
                                             **dict(controller_options or {}))
        env = gym.make("vesselid/Manoeuvring3DOF-v0", max_episode_steps=steps + 1,
                       vessel=spec.name, dt=ctrl.dt, current_speed=current_speed,
                       current_direction=current_direction, wind_speed=wind_speed,
                       wind_direction=wind_direction, wind_gust=wind_gust,
                       force_max=tuple(ctrl.fmax), **dict(env_options or {}))
        _, info = env.reset(seed=seed, options={"nu": [initial_speed, 0.0, 0.0],
                                                "eta": [0.0, 0.0, 0.0]})
        rec = np.zeros((steps, 8))
        diverged = False
        for k in range(steps):
            t = k * ctrl.dt
            u_ref, psi_ref = reference(t)
            a = ctrl(info, t)
            rec[k] = (t, info["nu"][0], u_ref, info["eta"][2], psi_ref,
                      a[0] * ctrl.fmax[0], a[2] * ctrl.fmax[2], info["nu"][2])
            _, _, term, _trunc, info = env.step(a)
            if term:
                diverged = True
                rec = rec[:k + 1]
                break
        env.close()
        tr = pd.DataFrame(rec, columns=["t", "u", "u_ref", "psi", "psi_ref", "X", "N", "r"])
        traces[name] = tr
        m = tr["t"] >= settle
        e_psi = np.angle(np.exp(1j * (tr["psi"][m] - tr["psi_ref"][m])))
        rows.append({
            "controller": name,
            "rms_u (m/s)": float(np.sqrt(np.mean((tr["u"][m] - tr["u_ref"][m]) ** 2))),
            "rms_psi (deg)": float(np.degrees(np.sqrt(np.mean(e_psi**2)))),
            "mean |X| (N)": float(np.mean(np.abs(tr["X"][m]))),
            "mean |N| (N m)": float(np.mean(np.abs(tr["N"][m]))),
            "saturated %": float(100 * np.mean((np.abs(tr["X"][m]) >= ctrl.fmax[0] - 1e-9)
                                               | (np.abs(tr["N"][m]) >= ctrl.fmax[2] - 1e-9))),
            "diverged": diverged,
        })
    table = pd.DataFrame(rows).set_index("controller")
    return ControlExperiment(table=table, traces=traces)
