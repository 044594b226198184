"""Plants in closed loop: a PID controller, compiled closed-loop simulation, closed-loop logs.

Under feedback the input ``u(k)`` depends on the measurement ``y(k) = x(k) + e(k)`` and so
on the disturbances: assumption A4 of the paper (open loop) fails, least squares is biased
for a second reason and the paper's instruments, simulated from the logged input, are
correlated with the noise. Closed-loop consistent estimation
(:class:`vesselid.identify.closedloop.ClosedLoopIV`) needs the *external* signals — the
reference ``r`` and any excitation (dither) ``d`` added to the controller's output — and the
controller, so that the loop can be simulated noise-free from ``r`` and ``d`` alone.

This module provides

* :class:`PID` — a discrete PID per input channel (``u_j`` controls one measured state),
  with saturation, conditional-integration anti-windup and an additive dither; it
  serialises to log metadata, runs compiled in simulations and as a policy in environment
  loops (:meth:`PID.policy`);
* :func:`closed_loop_states` — the compiled closed-loop simulation of a
  :class:`~vesselid.model.spec.ModelSpec` plant (one kernel over runs and samples);
* :func:`simulate_closed_loop` — a catalogue :class:`~vesselid.plant.systems.System` under a PID
  with a reference and a dither, as a :class:`ClosedLoopSimulation` whose trial log has the
  reference columns ``<state>_ref`` and the dither columns ``<input>_dither`` named in
  ``metadata["closed_loop"]`` (:func:`closed_loop_metadata`).

The control law at row ``k`` (trial-log alignment: the input applied at ``k`` from the
measurement at ``k``), for an input ``j`` that controls state ``i``::

    e(k) = r(k) − y_i(k)
    u_j(k) = sat(u0_j + K_p e(k) + K_i I(k) + K_d (e(k) − e(k−1)) / dt + d_j(k))
    I(k+1) = I(k) + dt e(k)      (only while the output is not saturated)

with ``e(−1) = e(0)``; an input without a controlled state is ``sat(u0_j + d_j(k))``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vesselid.core import seeds
from vesselid.errors import ControlError, SimulationDivergedError, VesselidError
from vesselid.model.regressors import advance, kernel
from vesselid.model.spec import ModelSpec
from vesselid.plant.systems import Simulation, System

__all__ = [
    "DESIGNS",
    "PID",
    "ClosedLoopDesign",
    "ClosedLoopSimulation",
    "closed_loop_info",
    "closed_loop_metadata",
    "closed_loop_states",
    "simulate_closed_loop",
]

STATUS_OK = 0
STATUS_DIVERGED = 1


@dataclass(frozen=True)
class PID:
    """Discrete PID controllers, one per controlled input (module docstring).

    Parameters
    ----------
    loops : mapping input -> state
        The measured state each input controls (inputs not listed are open loop:
        ``u0 + dither``).
    kp, ki, kd : mapping input -> float
        Proportional, integral (per second) and derivative (seconds) gains; missing: 0.
    offset : mapping input -> float
        Constant feed-forward ``u0`` per input; missing: 0.
    limits : mapping input -> (low, high)
        Saturation of each input; missing: none.
    dt : float
        Sample time (s) of the integral and derivative.
    """

    loops: Mapping[str, str]
    kp: Mapping[str, float] = field(default_factory=dict)
    ki: Mapping[str, float] = field(default_factory=dict)
    kd: Mapping[str, float] = field(default_factory=dict)
    offset: Mapping[str, float] = field(default_factory=dict)
    limits: Mapping[str, Sequence[float]] = field(default_factory=dict)
    dt: float = 1.0

    def __post_init__(self) -> None:
        if not self.loops:
            raise ControlError("a PID needs at least one loop (input -> state)")
        for name, gains in (("kp", self.kp), ("ki", self.ki), ("kd", self.kd),
                            ("offset", self.offset)):
            for key, val in gains.items():
                if not math.isfinite(float(val)):
                    raise ControlError(f"PID {name}[{key!r}] must be finite, got {val!r}")
        for key, lim in self.limits.items():
            lo, hi = (float(v) for v in lim)
            if not (lo < hi) or math.isnan(lo) or math.isnan(hi):
                raise ControlError(f"PID limits[{key!r}] need low < high, got {lim!r}")
        if not (math.isfinite(float(self.dt)) and self.dt > 0):
            raise ControlError(f"PID dt must be positive, got {self.dt!r}")

    # ------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (``kind: "pid"``), stored in log metadata."""
        return {"kind": "pid", "loops": dict(self.loops),
                "kp": {k: float(v) for k, v in self.kp.items()},
                "ki": {k: float(v) for k, v in self.ki.items()},
                "kd": {k: float(v) for k, v in self.kd.items()},
                "offset": {k: float(v) for k, v in self.offset.items()},
                "limits": {k: [float(v) for v in lim] for k, lim in self.limits.items()},
                "dt": float(self.dt)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> PID:
        """Rebuild from :meth:`to_dict`; a one-line :class:`ControlError` otherwise."""
        if not isinstance(d, Mapping) or d.get("kind") != "pid":
            kind = d.get("kind") if isinstance(d, Mapping) else type(d).__name__
            raise ControlError(f"the controller in the log is {kind!r}, not a PID")
        try:
            return cls(loops=dict(d["loops"]), kp=dict(d.get("kp", {})),
                       ki=dict(d.get("ki", {})), kd=dict(d.get("kd", {})),
                       offset=dict(d.get("offset", {})),
                       limits={k: tuple(v) for k, v in d.get("limits", {}).items()},
                       dt=float(d.get("dt", 1.0)))
        except (KeyError, TypeError, ValueError) as exc:
            raise ControlError(f"malformed PID description in the log: {exc}") from None

    # -------------------------------------------------------------- compiled form
    def arrays(self, spec: ModelSpec) -> tuple[np.ndarray, ...]:
        """``(state index per input (−1: open loop), kp, ki, kd, u0, low, high)`` in
        ``spec.inputs`` order."""
        unknown = [j for j in self.loops if j not in spec.inputs]
        bad = [s for s in self.loops.values() if s not in spec.states]
        if unknown or bad:
            raise ControlError(f"PID loops {dict(self.loops)} do not match the model's inputs "
                               f"{list(spec.inputs)} and states {list(spec.states)}")
        m = spec.n_inputs
        cs = np.array([spec.states.index(self.loops[j]) if j in self.loops else -1
                       for j in spec.inputs], dtype=np.int64)

        def vec(mp: Mapping[str, float]) -> np.ndarray:
            return np.array([float(mp.get(j, 0.0)) for j in spec.inputs])

        lo = np.full(m, -np.inf)
        hi = np.full(m, np.inf)
        for j, name in enumerate(spec.inputs):
            if name in self.limits:
                lo[j], hi[j] = (float(v) for v in self.limits[name])
        return cs, vec(self.kp), vec(self.ki), vec(self.kd), vec(self.offset), lo, hi

    def policy(self, spec: ModelSpec) -> PIDPolicy:
        """A stateful per-sample controller for environment loops (:class:`PIDPolicy`)."""
        return PIDPolicy(self, spec)


class PIDPolicy:
    """:class:`PID` evaluated one sample at a time (environment loops, Python).

    ``policy(y, r, d)`` with the measured states ``y`` (n,), the references of the inputs'
    controlled states ``r`` (m,; ignored for open-loop inputs) and the dither ``d`` (m,)
    returns the inputs ``u`` (m,) — the same arithmetic as the compiled simulation.
    """

    def __init__(self, pid: PID, spec: ModelSpec) -> None:
        self.pid = pid
        self.spec = spec
        self._cs, self._kp, self._ki, self._kd, self._u0, self._lo, self._hi = pid.arrays(spec)
        self.reset()

    def reset(self) -> None:
        """Clear the integrators and the derivative memory."""
        m = self.spec.n_inputs
        self._integ = np.zeros(m)
        self._eprev = np.zeros(m)
        self._first = True

    def __call__(self, y: Any, r: Any, d: Any | None = None) -> np.ndarray:
        y = np.asarray(y, dtype=float).ravel()
        r = np.broadcast_to(np.asarray(r, dtype=float).ravel(), (self.spec.n_inputs,))
        d = np.zeros(self.spec.n_inputs) if d is None else np.asarray(d, dtype=float).ravel()
        u = np.empty(self.spec.n_inputs)
        dt = self.pid.dt
        for j in range(u.size):
            u[j], self._integ[j], self._eprev[j] = _pid_law(
                int(self._cs[j]), y, r[j], d[j], self._kp[j], self._ki[j], self._kd[j],
                self._u0[j], self._lo[j], self._hi[j], dt, self._integ[j], self._eprev[j],
                self._first)
        self._first = False
        return u


def _pid_law(cs, y, r, d, kp, ki, kd, u0, lo, hi, dt, integ, eprev, first):
    """One channel of the law (module docstring); returns ``(u, I(k+1), e(k))``."""
    if cs < 0:
        return min(max(u0 + d, lo), hi), integ, eprev
    err = r - y[cs]
    de = 0.0 if first else (err - eprev) / dt
    raw = u0 + kp * err + ki * integ + kd * de + d
    u = min(max(raw, lo), hi)
    if lo < raw < hi:
        integ = integ + dt * err
    return u, integ, err


@kernel(nogil=True)
def _closed_loop_runs(fac, eq, theta, x0, v, w, e, ref, dith, cs, kp, ki, kd, u0, lo, hi,
                      dt, limit, x_out, u_out, status):
    n_runs, n_samples, n = x_out.shape
    m = u_out.shape[2]
    n_par = fac.shape[0]
    s = np.empty(n + m)
    f = np.empty(2 * (n + m) + 1)
    phi = np.empty(n_par)
    nxt = np.empty(n)
    integ = np.empty(m)
    eprev = np.empty(m)
    for r in range(n_runs):
        th = theta[r] if theta.shape[0] > 1 else theta[0]
        status[r] = STATUS_OK
        for i in range(n):
            x_out[r, 0, i] = x0[r, i]
        for j in range(m):
            integ[j] = 0.0
            eprev[j] = 0.0
        for k in range(n_samples):
            for j in range(m):
                c = cs[j]
                if c < 0:
                    uj = u0[j] + dith[r, k, j]
                    uj = min(max(uj, lo[j]), hi[j])
                else:
                    err = ref[r, k, j] - (x_out[r, k, c] + e[r, k, c])
                    de = 0.0 if k == 0 else (err - eprev[j]) / dt
                    raw = u0[j] + kp[j] * err + ki[j] * integ[j] + kd[j] * de + dith[r, k, j]
                    uj = min(max(raw, lo[j]), hi[j])
                    if lo[j] < raw < hi[j]:
                        integ[j] += dt * err
                    eprev[j] = err
                u_out[r, k, j] = uj
            if k == n_samples - 1:
                break
            for i in range(n):
                s[i] = x_out[r, k, i] + v[r, k, i]
                nxt[i] = w[r, k, i]
            for j in range(m):
                s[n + j] = u_out[r, k, j]
            advance(fac, eq, th, s, f, phi, nxt)
            bad = False
            for i in range(n):
                x_out[r, k + 1, i] = nxt[i]
                if not (math.isfinite(nxt[i]) and abs(nxt[i]) <= limit[i]):
                    bad = True
            if bad:
                status[r] = STATUS_DIVERGED
                for kk in range(k + 1, n_samples):
                    for i in range(n):
                        x_out[r, kk, i] = np.nan
                    for j in range(m):
                        u_out[r, kk, j] = np.nan
                break


def _batch(a: Any, n_runs: int, n_samples: int, width: int, name: str) -> np.ndarray:
    arr = np.zeros((1, n_samples, width)) if a is None else np.asarray(a, dtype=float)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (n_samples, width) or arr.shape[0] not in (1, n_runs):
        raise VesselidError(f"{name} must have shape (runs, {n_samples}, {width}) or "
                            f"({n_samples}, {width}); got {np.shape(a)}")
    return np.ascontiguousarray(np.broadcast_to(arr, (n_runs, n_samples, width)))


def closed_loop_states(spec: ModelSpec, controller: PID, reference: Any, *,
                       dither: Any = None, theta: Any = None, x0: Any = None, v: Any = None,
                       w: Any = None, e: Any = None, limit: Any = 1e8,
                       raise_on_divergence: bool = True
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulate (1a) under ``controller``: ``x(k+1) = Φᵀ([x + v; u])θ + w``, ``u(k)`` the
    PID of ``y(k) = x(k) + e(k)`` and the reference, plus the dither.

    Parameters
    ----------
    spec : ModelSpec
        Plant structure (θ0 unless ``theta``).
    controller : PID
    reference : array (N, m) or (R, N, m)
        Reference of each *input's* controlled state (columns in ``spec.inputs`` order;
        ignored for open-loop inputs).
    dither : array (N, m) or (R, N, m), optional
        External excitation added to each input before saturation.
    theta : array (P,) or (R, P), optional
    x0 : array (n,) or (R, n), optional
    v, w, e : arrays (N, n) or (R, N, n), optional
        Disturbance inside the nonlinearity, additive process disturbance, sensor noise.
    limit : float or array (n,)
        Divergence bound of each state.
    raise_on_divergence : bool

    Returns
    -------
    x, u, status
        States (R, N, n), inputs (R, N, m) and per-run status (0 ok, 1 diverged; diverged
        runs are NaN from the failing sample); a leading run axis only if some argument
        had one.
    """
    ref_arr = np.asarray(reference, dtype=float)
    n_runs = max(np.asarray(a).shape[0] if a is not None and np.ndim(a) == 3 else 1
                 for a in (ref_arr, dither, v, w, e))
    single = all(a is None or np.ndim(a) < 3 for a in (ref_arr, dither, v, w, e))
    n_samples = ref_arr.shape[-2]
    n, m = spec.n_states, spec.n_inputs
    th = np.atleast_2d(spec.theta0_vector() if theta is None
                       else np.asarray(theta, dtype=float))
    x0_arr = np.ascontiguousarray(np.broadcast_to(
        np.atleast_2d(np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)),
        (n_runs, n)))
    lim = np.broadcast_to(np.asarray(limit, dtype=float), (n,)).copy()
    cs, kp, ki, kd, u0, lo, hi = controller.arrays(spec)
    x = np.empty((n_runs, n_samples, n))
    u = np.empty((n_runs, n_samples, m))
    status = np.empty(n_runs, dtype=np.int64)
    codes = spec.codes
    _closed_loop_runs(codes.factors, codes.equation, np.ascontiguousarray(th), x0_arr,
                      _batch(v, n_runs, n_samples, n, "v"), _batch(w, n_runs, n_samples, n, "w"),
                      _batch(e, n_runs, n_samples, n, "e"),
                      _batch(ref_arr, n_runs, n_samples, m, "reference"),
                      _batch(dither, n_runs, n_samples, m, "dither"),
                      cs, kp, ki, kd, u0, lo, hi, float(controller.dt), lim, x, u, status)
    if raise_on_divergence and np.any(status != STATUS_OK):
        bad = np.flatnonzero(status != STATUS_OK)
        raise SimulationDivergedError(
            f"closed-loop simulation of {spec.name!r} diverged in {bad.size} of {n_runs} "
            "run(s); check θ, the controller gains and the reference")
    if single:
        return x[0], u[0], status
    return x, u, status


# ---------------------------------------------------------------------- logs
def closed_loop_metadata(controller: PID | Mapping[str, Any] | None,
                         reference: Mapping[str, str], dither: Mapping[str, str]
                         ) -> dict[str, Any]:
    """``metadata["closed_loop"]``: the controller (a :meth:`PID.to_dict`, another
    description, or None when unknown) and the log columns of the reference
    (state -> column) and of the dither (input -> column)."""
    ctrl = controller.to_dict() if isinstance(controller, PID) else (
        dict(controller) if isinstance(controller, Mapping) else None)
    return {"controller": ctrl, "reference": dict(reference), "dither": dict(dither)}


def closed_loop_info(log: Any) -> dict[str, Any] | None:
    """The log's ``metadata["closed_loop"]`` (None: not declared closed loop)."""
    meta = getattr(log, "metadata", None) or {}
    info = meta.get("closed_loop")
    return dict(info) if isinstance(info, Mapping) else None


@dataclass
class ClosedLoopSimulation(Simulation):
    """A :class:`~vesselid.plant.systems.Simulation` recorded in closed loop: also the references
    ``r`` (R, N, n_ref) of ``ref_states`` and the dither ``d`` (R, N, m)."""

    r: np.ndarray | None = None
    d: np.ndarray | None = None
    ref_states: tuple[str, ...] = ()
    controller: PID | None = None

    def columns(self) -> dict[str, np.ndarray]:
        cols = super().columns()
        extra = {f"{s}_ref": self.r[:, :, i].ravel() for i, s in enumerate(self.ref_states)}
        extra |= {f"{j}_dither": self.d[:, :, k].ravel()
                  for k, j in enumerate(self.system.spec.inputs)}
        # the external signals right after the inputs (before sensors and truth)
        spec = self.system.spec
        first = [*spec.states, *spec.inputs]
        out = {c: cols[c] for c in first}
        out |= extra
        out |= {c: v for c, v in cols.items() if c not in out}
        return out

    def to_log(self, *, aggregate: bool | None = None):
        log = super().to_log(aggregate=aggregate)
        std = _white_sensor_noise(self.system)
        if std and "sensor_noise_std" not in log.metadata:
            log.metadata["sensor_noise_std"] = std
        log.metadata["closed_loop"] = closed_loop_metadata(
            self.controller, {s: f"{s}_ref" for s in self.ref_states},
            {j: f"{j}_dither" for j in self.system.spec.inputs})
        return log


def _white_sensor_noise(system: System) -> dict[str, float]:
    """``{state: σ}`` of a system whose state sensors carry zero-mean white Gaussian noise
    (the log's ``metadata["sensor_noise_std"]``: the closed-loop estimator's
    errors-in-variables correction); empty when any sensor noise is of another kind."""
    from vesselid.plant.disturbances import Gaussian

    out = {}
    for state, proc in system.sensor_noise.items():
        if type(proc) is not Gaussian or proc.mean_ != 0.0:
            return {}
        if proc.std_ > 0:
            out[state] = float(proc.std_)
    return out


def _per_experiment(design: Any, experiment: int) -> Any:
    if isinstance(design, Sequence) and not isinstance(design, str):
        return design[experiment % len(design)]
    return design


def simulate_closed_loop(system: System, controller: PID, reference: Mapping[str, Any], *,
                         dither: Mapping[str, Any] | None = None, n_samples: int = 1000,
                         n_runs: int = 1, seed: Any = None) -> ClosedLoopSimulation:
    """Simulate a catalogue system under a PID, with a reference and a dither.

    The system's disturbances, sensor noise and initial state are drawn exactly as by
    :meth:`System.simulate` (same seeds, same draws); its open-loop input design is not
    used — the controller decides the input. The reference and the dither of run ``r``
    come from a generator of their own, spawned from the run's seed.

    Parameters
    ----------
    system : System
    controller : PID
        ``controller.loops`` names the inputs that are controlled and their states.
    reference : mapping state -> InputSignal or float, or a sequence of them
        Reference of every controlled state (a signal drawn per run, or a constant); a
        sequence gives one design per experiment, cycled by the run's spawn index (as
        :class:`~vesselid.plant.systems.System` input designs), e.g. turns to both sides.
    dither : mapping input -> Process or InputSignal (or a sequence), optional
        External excitation per input (e.g. ``Gaussian(0, 0.02)``); missing: none.
    n_samples, n_runs, seed
        As :meth:`System.simulate`.

    Returns
    -------
    ClosedLoopSimulation
        ``to_log()`` adds the columns ``<state>_ref`` and ``<input>_dither`` and
        ``metadata["closed_loop"]``.
    """
    spec = system.spec
    n_samples = int(n_samples)
    if n_samples < 2:
        raise VesselidError(f"need at least 2 samples, got {n_samples}")
    ref_states = tuple(dict.fromkeys(controller.loops.values()))
    missing = [s for s in ref_states if s not in reference]
    if missing:
        raise ControlError(f"no reference given for the controlled state(s) {missing}")
    unknown = [j for j in (dither or {}) if j not in spec.inputs]
    if unknown:
        raise ControlError(f"dither given for unknown inputs {unknown}")
    run_seeds = seeds.run_seeds(seed, n_runs)
    stack = system._draw_batch(run_seeds, n_samples)
    r_arr = np.zeros((n_runs, n_samples, len(ref_states)))
    d_arr = np.zeros((n_runs, n_samples, spec.n_inputs))
    for r, ss in enumerate(run_seeds):
        rng = np.random.default_rng(seeds.child(ss, 0x434C))
        exp = int(ss.spawn_key[-1]) if ss.spawn_key else 0
        for i, s in enumerate(ref_states):
            sig = _per_experiment(reference[s], exp)
            r_arr[r, :, i] = (sig.sample(rng, n_samples) if hasattr(sig, "sample")
                              else float(sig))
        for j, name in enumerate(spec.inputs):
            if dither and name in dither:
                d_arr[r, :, j] = _per_experiment(dither[name], exp).sample(rng, n_samples)
    ref_in = np.zeros((n_runs, n_samples, spec.n_inputs))
    for j, name in enumerate(spec.inputs):
        if name in controller.loops:
            ref_in[:, :, j] = r_arr[:, :, ref_states.index(controller.loops[name])]
    signs = np.array([system.sign(s) for s in spec.states], dtype=float)
    v = stack["q"] * signs
    x0 = np.array([float(system.x0.get(s, 0.0)) for s in spec.states])
    x, u, _ = closed_loop_states(spec, controller, ref_in, dither=d_arr, x0=x0, v=v,
                                 w=stack["w"], e=stack["e"])
    y = stack["e"] + x
    idx = [spec.states.index(s) for s in system.sensor_states]
    y2 = stack["q"][:, :, idx] + stack["e2"]
    return ClosedLoopSimulation(
        system=system, x=x, y=y, u=u, q=stack["q"], w=stack["w"], y2=y2,
        seed=None if seed is None or isinstance(seed, np.random.SeedSequence) else int(seed),
        entropy=[ss.entropy if isinstance(ss.entropy, int) else None for ss in run_seeds][:1],
        spawn_keys=[list(ss.spawn_key) for ss in run_seeds],
        r=r_arr, d=d_arr, ref_states=ref_states, controller=controller)


# ------------------------------------------------------------------- trial designs
@dataclass(frozen=True)
class ClosedLoopDesign:
    """A closed-loop trial: the plant, the controller, the reference and dither designs, the
    identified structure and the trial size (experiments of ``samples`` samples)."""

    name: str
    system: System
    spec: ModelSpec
    controller: PID
    reference: Mapping[str, Any]
    dither: Mapping[str, Any]
    samples: int
    experiments: int

    def simulate(self, *, samples: int | None = None, experiments: int | None = None,
                 seed: Any = None) -> ClosedLoopSimulation:
        """:func:`simulate_closed_loop` of this design."""
        return simulate_closed_loop(self.system, self.controller, self.reference,
                                    dither=self.dither, n_samples=samples or self.samples,
                                    n_runs=experiments or self.experiments, seed=seed)


def heave_pi_design(*, kp: float = 0.3, ki: float = 0.05, kd: float = 0.0,
                    offset: float = 0.2, reference: tuple[float, float] = (1.0, 2.0),
                    hold: tuple[int, int] = (50, 200), dither_std: float = 0.05,
                    samples: int = 5000, experiments: int = 1) -> ClosedLoopDesign:
    """The heave system (paper §6 noise) under a PI(D) loop on the heave velocity with a
    random-step reference (levels uniform on ``reference``, held ``hold`` samples) and a
    white Gaussian dither on the thrust."""
    from vesselid.plant.disturbances import Gaussian
    from vesselid.plant.signals import RandomPulses
    from vesselid.plant.systems import heave

    system = heave()
    return ClosedLoopDesign(
        name="heave", system=system, spec=system.identification_spec(aggregate=False),
        controller=PID(loops={"tau": "w"}, kp={"tau": kp}, ki={"tau": ki}, kd={"tau": kd},
                       offset={"tau": offset}, dt=system.spec.dt or 1.0),
        reference={"w": RandomPulses(*reference, *hold)},
        dither={"tau": Gaussian(0.0, dither_std)}, samples=samples, experiments=experiments)


def cybership2_velocity_design(*, samples: int = 3000, experiments: int = 4,
                               dither_std: tuple[float, float, float] = (0.3, 0.3, 0.03)
                               ) -> ClosedLoopDesign:
    """CyberShip II (catalogue system: Gauss–Markov process noise, sensor noise) under three
    PI velocity loops ``X → u``, ``Y → v``, ``N → r`` — a dynamic-positioning-like velocity
    controller — with random-step references (``u`` on [0.5, 1] m/s; ``v`` and ``r`` on
    ±[0.05, 0.15], the four sign combinations cycled over the experiments so that every
    modulus term is identifiable; levels held 5–30 s) and white dithers on the forces."""
    from vesselid.plant.catalogue import get_system
    from vesselid.plant.disturbances import Gaussian
    from vesselid.plant.signals import RandomPulses

    system = get_system("cybership2")
    hold = (50, 300)
    pos, neg = RandomPulses(0.05, 0.15, *hold), RandomPulses(-0.15, -0.05, *hold)
    return ClosedLoopDesign(
        name="3dof", system=system, spec=system.spec.with_aggregate(None),
        controller=PID(loops={"X": "u", "Y": "v", "N": "r"},
                       kp={"X": 30.0, "Y": 30.0, "N": 3.0}, ki={"X": 6.0, "Y": 6.0, "N": 0.6},
                       offset={"X": 1.4}, dt=system.spec.dt),
        reference={"u": RandomPulses(0.5, 1.0, *hold), "v": [pos, pos, neg, neg],
                   "r": [pos, neg, pos, neg]},
        dither={k: Gaussian(0.0, sd) for k, sd in zip("XYN", dither_std, strict=True)},
        samples=samples, experiments=experiments)


#: Closed-loop trial designs by name.
DESIGNS = {"heave": heave_pi_design, "3dof": cybership2_velocity_design}
