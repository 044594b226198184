"""Simulated plants and the catalogue of systems from the paper.

A :class:`System` is a :class:`~vesselid.model.spec.ModelSpec` with true θ0 plus how the
world disturbs it: a physical current ``q`` per state entering inside the
nonlinearity as ``v = sign · q`` (for the heave vehicle ``w_r = w_a − w_c``, so
``v = −w_c``), an additive process disturbance ``w``, sensor noise ``e`` on the
state measurement ``y = x + e`` (1b), and optionally a disturbance sensor
``y₂ = q + e₂`` (paper §4, A12) whose column name and sign come from the spec's
aggregate relation.

Catalogue: :func:`heave` (paper §6, Tables 1–2) and :func:`siso_example` (paper §5).
Vessels live in :mod:`vesselid.plant.vessels`; every entry is listed in
:mod:`vesselid.plant.catalogue`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vesselid.core import seeds
from vesselid.errors import VesselidError
from vesselid.model.spec import ModelSpec
from vesselid.plant.disturbances import Gaussian, Process, Uniform, Zero
from vesselid.plant.result import SimulationResult
from vesselid.plant.signals import AlternatingPulses, InputSignal, RandomPulses, StaticOffset
from vesselid.plant.simulate import DEFAULT_DIVERGENCE_LIMIT, simulate_states

__all__ = ["Simulation", "System", "heave", "siso_example", "truth_columns"]

SeedLike = int | np.random.SeedSequence | None


def truth_columns(state: str) -> tuple[str, str, str]:
    """Trial-log ground-truth columns of a state of a :class:`System`: the true state, the
    physical current and the process disturbance (``true_w, true_current_w,
    true_process_w``); the one naming rule of simulations and the heave environment."""
    return f"true_{state}", f"true_current_{state}", f"true_process_{state}"


@dataclass(frozen=True)
class System:
    """A simulated plant (:class:`vesselid.plant.plant.Plant`): model structure with θ0,
    disturbances, sensors and input design.

    Parameters
    ----------
    spec : ModelSpec
        Structure with ``theta0``. Its aggregate relations name the disturbance
        sensors and their signs (``"w - w_c"``: sensor ``w_c``, ``v = −w_c``).
    inputs : mapping input -> InputSignal or sequence of InputSignal
        Input design for each input. A sequence gives one design per experiment,
        cycled: experiment ``i`` (the spawn index of its seed) uses design
        ``i mod len``, e.g. steady turns to starboard and to port.
    current : mapping state -> Process
        Physical disturbance ``q`` per state (``v = sign · q``); absent = zero.
    current_sign : mapping state -> int
        Sign of the coupling; default from the aggregate relation, else +1.
    process_noise : mapping state -> Process
        Additive process disturbance ``w`` (1a).
    sensor_noise : mapping state -> Process
        Measurement noise ``e`` (1b).
    current_sensor_noise : mapping state -> Process
        Noise ``e₂`` of the disturbance sensor ``y₂ = q + e₂``; a state listed here
        gets a sensor column (named by the aggregate relation, else ``<state>_c``).
    x0 : mapping state -> float
        Initial state.
    model : ModelSpec, optional
        The structure identified from this system's logs, when it differs from the
        simulated one (e.g. merged collinear terms); default ``spec``.
    """

    spec: ModelSpec
    inputs: Mapping[str, InputSignal | Sequence[InputSignal]]
    current: Mapping[str, Process] = field(default_factory=dict)
    current_sign: Mapping[str, int] = field(default_factory=dict)
    process_noise: Mapping[str, Process] = field(default_factory=dict)
    sensor_noise: Mapping[str, Process] = field(default_factory=dict)
    current_sensor_noise: Mapping[str, Process] = field(default_factory=dict)
    x0: Mapping[str, float] = field(default_factory=dict)
    description: str = ""
    model: ModelSpec | None = None

    def __post_init__(self) -> None:
        spec = self.spec
        if spec.theta0 is None:
            raise VesselidError(f"system {spec.name!r} needs a spec with theta0")
        missing = [u for u in spec.inputs if u not in self.inputs]
        if missing:
            raise VesselidError(f"system {spec.name!r} has no input design for {missing}")
        for label, mapping in (
            ("current", self.current),
            ("current_sign", self.current_sign),
            ("process_noise", self.process_noise),
            ("sensor_noise", self.sensor_noise),
            ("current_sensor_noise", self.current_sensor_noise),
            ("x0", self.x0),
        ):
            unknown = sorted(set(mapping) - set(spec.states))
            if unknown:
                raise VesselidError(f"{label} given for unknown states {unknown}")
        for s, sign in self.current_sign.items():
            if sign not in (1, -1):
                raise VesselidError(f"current_sign of {s!r} must be +1 or -1, got {sign}")

    # ------------------------------------------------------------------ helpers
    def sign(self, state: str) -> int:
        """Coupling sign ``v = sign · q`` of a state's current."""
        if state in self.current_sign:
            return int(self.current_sign[state])
        if state in self.spec.aggregate and self.spec.aggregate[state].sign != 0:
            return int(self.spec.aggregate[state].sign)
        return 1

    def sensor_name(self, state: str) -> str:
        """Column name of a state's disturbance sensor."""
        if state in self.spec.aggregate:
            return self.spec.aggregate[state].sensor
        return f"{state}_c"

    @property
    def sensor_states(self) -> tuple[str, ...]:
        return tuple(s for s in self.spec.states if s in self.current_sensor_noise)

    def identification_spec(self, *, aggregate: bool | None = None) -> ModelSpec:
        """The model spec a user identifies with.

        With ``aggregate=True`` the regressors use ``state ± sensor`` (paper (9)); with
        ``False`` the plain predictor (3). Default: aggregate iff the system has
        disturbance sensors.
        """
        use = bool(self.sensor_states) if aggregate is None else aggregate
        structure = self.model or self.spec
        if not use:
            return structure.with_aggregate(None)
        if not self.sensor_states:
            raise VesselidError(f"system {self.spec.name!r} has no disturbance sensor to aggregate")
        rel = {
            s: f"{s} {'+' if self.sign(s) > 0 else '-'} {self.sensor_name(s)}"
            for s in self.sensor_states
        }
        return structure.with_aggregate(rel)

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable settings (for log metadata)."""
        return {
            "name": self.spec.name,
            "description": self.description,
            "inputs": {k: ([d.to_dict() for d in v] if isinstance(v, Sequence) else v.to_dict())
                       for k, v in self.inputs.items()},
            "current": {k: v.to_dict() for k, v in self.current.items()},
            "current_sign": {s: self.sign(s) for s in self.spec.states},
            "process_noise": {k: v.to_dict() for k, v in self.process_noise.items()},
            "sensor_noise": {k: v.to_dict() for k, v in self.sensor_noise.items()},
            "current_sensor_noise": {k: v.to_dict() for k, v in self.current_sensor_noise.items()},
            "x0": {k: float(v) for k, v in self.x0.items()},
        }

    # --------------------------------------------------------------- simulation
    def input_design(self, name: str, experiment: int) -> InputSignal:
        """The input design of ``name`` used in experiment number ``experiment``."""
        design = self.inputs[name]
        if isinstance(design, Sequence):
            return design[experiment % len(design)]
        return design

    def _draw(self, rng: np.random.Generator, n: int, experiment: int = 0) -> dict[str, np.ndarray]:
        """Draw one run's signals; the order of draws is fixed (determinism)."""
        spec = self.spec
        zero = Zero()
        u = np.column_stack([self.input_design(name, experiment).sample(rng, n)
                             for name in spec.inputs]) if spec.inputs else np.zeros((n, 0))
        q = np.column_stack([self.current.get(s, zero).sample(rng, n) for s in spec.states])
        w = np.column_stack([self.process_noise.get(s, zero).sample(rng, n) for s in spec.states])
        e = np.column_stack([self.sensor_noise.get(s, zero).sample(rng, n) for s in spec.states])
        e2 = [self.current_sensor_noise[s].sample(rng, n) for s in self.sensor_states]
        e2_arr = np.column_stack(e2) if e2 else np.zeros((n, 0))
        return {"u": u, "q": q, "w": w, "e": e, "e2": e2_arr}

    def _draw_into(
        self, rng: np.random.Generator, n: int, experiment: int, out: dict[str, np.ndarray],
        r: int,
    ) -> None:
        """Draw run ``r``'s signals straight into the batch buffers ``out``.

        Same draw order as :meth:`_draw` (inputs, currents, process noise, sensor
        noise, disturbance-sensor noise; states in spec order), so a run's data
        depend only on its own generator. Gaussian noise is drawn as standard
        normals into the buffer and scaled in place (no temporaries).
        """
        spec = self.spec
        for j, name in enumerate(spec.inputs):
            out["u"][r, :, j] = self.input_design(name, experiment).sample(rng, n)
        self._draw_states_into(rng, out, r, ("q", "w", "e"))
        for j, s in enumerate(self.sensor_states):
            _fill(self.current_sensor_noise[s], rng, out["e2"][r, :, j])

    def _draw_states_into(self, rng: np.random.Generator, out: dict[str, np.ndarray], r: int,
                          keys: Sequence[str]) -> None:
        """Draw run ``r``'s state-wise disturbances ``keys`` (of ``q``, ``w``, ``e``, in
        that order; states in spec order) into ``out[key][r]``."""
        procs = {"q": self.current, "w": self.process_noise, "e": self.sensor_noise}
        for key in keys:
            for i, s in enumerate(self.spec.states):
                proc = procs[key].get(s)
                if proc is not None:
                    _fill(proc, rng, out[key][r, :, i])

    def _draw_batch(
        self, run_seeds: Sequence[np.random.SeedSequence], n: int
    ) -> dict[str, np.ndarray]:
        """All runs' signals as ``(R, N, ·)`` arrays, drawn in threads (numpy's
        generators release the GIL); run ``r`` uses only ``default_rng(run_seeds[r])``."""
        n_runs, n_st = len(run_seeds), self.spec.n_states
        out = {
            "u": np.zeros((n_runs, n, self.spec.n_inputs)),
            "q": np.zeros((n_runs, n, n_st)),
            "w": np.zeros((n_runs, n, n_st)),
            "e": np.zeros((n_runs, n, n_st)),
            "e2": np.zeros((n_runs, n, len(self.sensor_states))),
        }

        def work(first: int, last: int) -> None:
            for r in range(first, last):
                ss = run_seeds[r]
                self._draw_into(np.random.default_rng(ss), n,
                                int(ss.spawn_key[-1]) if ss.spawn_key else 0, out, r)

        from vesselid.core.threads import n_threads, serial

        workers = min(n_threads(), n_runs)
        if workers > 1 and n_runs * n >= 100_000 and not serial():
            bounds = np.linspace(0, n_runs, workers + 1).astype(int)
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(work, bounds[:-1], bounds[1:]))
        else:
            work(0, n_runs)
        return out

    def simulate(
        self,
        n_samples: int,
        n_runs: int = 1,
        seed: SeedLike = None,
        *,
        run_seeds: Sequence[np.random.SeedSequence] | None = None,
        limit: float = DEFAULT_DIVERGENCE_LIMIT,
    ) -> Simulation:
        """Simulate ``n_runs`` independent runs of ``n_samples`` samples.

        Run ``r`` draws all its signals from ``default_rng(SeedSequence(seed).spawn(n_runs)[r])``,
        so any subset of runs can be regenerated on its own (Monte Carlo chunks,
        Dask workers) and gives bit-identical data.

        Raises
        ------
        SimulationDivergedError
            If a state diverges (unstable θ0 or too large an input).
        """
        n_samples = int(n_samples)
        if n_samples < 2:
            raise VesselidError(f"need at least 2 samples, got {n_samples}")
        if run_seeds is None:
            if int(n_runs) < 1:
                raise VesselidError(f"need at least one run, got {n_runs}")
            run_seeds = seeds.run_seeds(seed, n_runs)
        stack = self._draw_batch(run_seeds, n_samples)
        signs = np.array([self.sign(s) for s in self.spec.states], dtype=float)
        v = stack["q"] * signs
        x0 = self._x0(None)
        x = simulate_states(self.spec, stack["u"], x0=x0, v=v, w=stack["w"], limit=limit)
        y = stack["e"]  # y = e + x in the sensor-noise buffer (not kept): no new array
        y += x
        idx = [self.spec.states.index(s) for s in self.sensor_states]
        y2 = stack["q"][:, :, idx] + stack["e2"]
        return Simulation(
            system=self, x=x, y=y, u=stack["u"], q=stack["q"], w=stack["w"], y2=y2,
            seed=None if seed is None or isinstance(seed, np.random.SeedSequence) else int(seed),
            entropy=[ss.entropy if isinstance(ss.entropy, int) else None for ss in run_seeds][:1],
            spawn_keys=[list(ss.spawn_key) for ss in run_seeds],
        )

    def run(self, inputs: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """Noise-free states ``x(0..n)`` ``(n + 1, n_states)`` for inputs ``(n, n_inputs)``
        from ``x0`` (default the system's ``x0``): θ0 without current or noise."""
        u = np.asarray(inputs, dtype=float)
        return simulate_states(self.spec, np.vstack([u, u[-1:]]), x0=self._x0(x0))

    def disturbed_paths(self, inputs: np.ndarray, x0: np.ndarray | None = None, *,
                        paths: int, seed: int) -> np.ndarray:
        """States ``(paths, n + 1, n_states)`` under random realisations of the process
        disturbances (current ``q``, entering as ``v = sign · q``, then process noise
        ``w``; no sensor noise), drawn from one ``default_rng(seed)``, path after path.

        A path draws as :meth:`simulate` draws a run after its inputs, so with an input
        design that draws nothing (:class:`~vesselid.plant.signals.ConstantInput`) the
        first path's ``x(0..n−1)`` is run 0 of ``simulate(n, run_seeds=[SeedSequence(seed)])``.
        """
        u = np.asarray(inputs, dtype=float)
        n, n_st, m = u.shape[0], self.spec.n_states, int(paths)
        rng = np.random.default_rng(seed)
        out = {"q": np.zeros((m, n + 1, n_st)), "w": np.zeros((m, n + 1, n_st))}
        view = {k: v[:, :n] for k, v in out.items()}
        for r in range(m):
            self._draw_states_into(rng, view, r, ("q", "w"))
        signs = np.array([self.sign(s) for s in self.spec.states], dtype=float)
        u_pad = np.broadcast_to(np.vstack([u, u[-1:]]), (m, n + 1, u.shape[1]))
        return simulate_states(self.spec, u_pad, x0=self._x0(x0), v=out["q"] * signs,
                               w=out["w"])

    def _x0(self, x0: np.ndarray | None) -> np.ndarray:
        if x0 is not None:
            return np.asarray(x0, dtype=float)
        return np.array([float(self.x0.get(s, 0.0)) for s in self.spec.states])


@dataclass
class Simulation(SimulationResult):
    """Arrays of a batch simulation, shapes ``(runs, samples, ·)``.

    ``x`` true states, ``y`` state measurements (1b), ``u`` inputs, ``q`` physical
    currents, ``w`` process disturbances, ``y2`` disturbance-sensor readings.
    """

    system: System
    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    q: np.ndarray
    w: np.ndarray
    y2: np.ndarray
    seed: int | None = None
    entropy: list | None = None
    spawn_keys: list | None = None

    def _lead(self) -> np.ndarray:
        return self.x

    def _dt(self) -> float:
        return self.system.spec.dt or 1.0

    def columns(self) -> dict[str, np.ndarray]:
        """Measured states, inputs, disturbance sensors, then ground truth ``true_*``."""
        sysm = self.system
        spec = sysm.spec
        cols: dict[str, np.ndarray] = {}
        for i, s in enumerate(spec.states):
            cols[s] = self.y[:, :, i].ravel()
        for j, name in enumerate(spec.inputs):
            cols[name] = self.u[:, :, j].ravel()
        for j, s in enumerate(sysm.sensor_states):
            cols[sysm.sensor_name(s)] = self.y2[:, :, j].ravel()
        for i, s in enumerate(spec.states):
            cols[truth_columns(s)[0]] = self.x[:, :, i].ravel()
        for i, s in enumerate(spec.states):
            _, current, process = truth_columns(s)
            if s in sysm.current and not sysm.current[s].is_zero:
                cols[current] = self.q[:, :, i].ravel()
            if s in sysm.process_noise and not sysm.process_noise[s].is_zero:
                cols[process] = self.w[:, :, i].ravel()
        return cols

    def to_log(self, *, aggregate: bool | None = None):
        """A :class:`~vesselid.data.logs.TrialLog` with metadata (spec, θ0, seeds, settings)."""
        return self._trial_log(self.system.identification_spec(aggregate=aggregate),
                               self.system.describe())


def _fill(proc: Process, rng: np.random.Generator, out: np.ndarray) -> None:
    """``out[:] = proc.sample(rng, len(out))``, in place for Gaussian noise."""
    if isinstance(proc, Gaussian) and proc.std > 0 and out.flags.c_contiguous:
        rng.standard_normal(out=out)
        out *= proc.std
        out += proc.mean
    elif not isinstance(proc, Zero):
        out[:] = proc.sample(rng, out.shape[0])


# --------------------------------------------------------------------- catalogue
HEAVE_THETA0 = {"w": [0.99, -0.1, 1.0]}


def heave(
    *,
    current_mean: float = 0.0,
    current_sensor: bool | None = None,
    xi_mean: float | None = None,
    variance: float = 0.01,
    pulse_low: float = 0.1,
    pulse_high: float = 0.3,
    pulse_min_width: int | None = None,
    pulse_max_width: int | None = None,
    pulse_design: str = "random",
    x0: float = 1.3,
    stds: Mapping[str, float] | None = None,
) -> System:
    """Heave motion of an underwater vehicle, paper §6 (eq. (15) restructured).

    ``w_a(k+1) = a0 w_r(k) + n0 w_r(k)|w_r(k)| + f0 τ(k) + ξ(k)``,
    ``w_r = w_a − w_c``, ``y1 = w_a + e1``, θ0 = [a0, n0, f0] = [0.99, −0.1, 1].

    Parameters
    ----------
    current_mean : float
        Mean current w̄c; ``w_c ~ N(w̄c, variance)``.
    current_sensor : bool, optional
        Add the current meter ``y2 = w_c + e2``, ``e2 ~ N(0, variance)`` (Table 2);
        default: on iff ``current_mean != 0``.
    xi_mean : float, optional
        Mean of ξ. Default ``w̄c − 0.05``, §6 read literally (ξ = w_c + ξ̃). With it
        Table 2's published rows are reproduced when the relative measurement ỹ is
        also the regression target; ``−0.05`` drives w_r through zero with these
        pulses (evidence in :mod:`vesselid.studies.reproduce`).
    variance : float
        Variance of the Gaussian noises (0.01 in the paper).
    pulse_low, pulse_high, pulse_min_width, pulse_max_width
        Pulse input with amplitudes 0.1–0.3 as in §6; the widths are not given in
        the paper. Default widths: 10–100 samples for ``"random"``, 1–20 for
        ``"alternating"``.
    pulse_design : {"random", "alternating"}
        ``"random"`` (default): levels uniform on ``[pulse_low, pulse_high]``
        (:class:`~vesselid.plant.signals.RandomPulses`). ``"alternating"``: the input
        switches between ``pulse_low`` and ``pulse_high``
        (:class:`~vesselid.plant.signals.AlternatingPulses`); with widths 1–20 it
        reproduces the published LS rows and all spreads of Tables 1–2 (the
        design :mod:`vesselid.studies.reproduce` uses; evidence in its docstring).
    x0 : float
        Initial heave velocity (inside the range the pulses drive it to).
    stds : mapping, optional
        Standard deviations that differ from ``sqrt(variance)``, by source: ``"current"``
        (w_c), ``"xi"`` (ξ), ``"sensor"`` (e1), ``"current_sensor"`` (e2) (the heave
        environment's settings ``<source>_std``).
    """
    if current_sensor is None:
        current_sensor = current_mean != 0.0
    xi = current_mean - 0.05 if xi_mean is None else xi_mean
    design: InputSignal
    if pulse_design == "random":
        design = RandomPulses(pulse_low, pulse_high,
                              10 if pulse_min_width is None else pulse_min_width,
                              100 if pulse_max_width is None else pulse_max_width)
    elif pulse_design == "alternating":
        design = AlternatingPulses(pulse_low, pulse_high,
                                   1 if pulse_min_width is None else pulse_min_width,
                                   20 if pulse_max_width is None else pulse_max_width)
    else:
        raise VesselidError(
            f"pulse_design must be 'random' or 'alternating', got {pulse_design!r}")
    std = float(np.sqrt(variance))
    sd = {k: std for k in ("current", "xi", "sensor", "current_sensor")}
    if set(stds or {}) - set(sd):
        raise VesselidError(f"stds: unknown sources {sorted(set(stds) - set(sd))}; "
                            f"known {list(sd)}")
    sd |= dict(stds or {})
    spec = ModelSpec(
        name="heave",
        states=["w"],
        inputs=["tau"],
        equations={"w": ["w", "w*|w|", "tau"]},
        theta0=HEAVE_THETA0,
        aggregate={"w": "w - w_c"},
        dt=1.0,
    )
    return System(
        spec=spec,
        inputs={"tau": design},
        current={"w": Gaussian(current_mean, sd["current"])},
        current_sign={"w": -1},
        process_noise={"w": Gaussian(xi, sd["xi"])},
        sensor_noise={"w": Gaussian(0.0, sd["sensor"])},
        current_sensor_noise={"w": Gaussian(0.0, sd["current_sensor"])} if current_sensor else {},
        x0={"w": x0},
        description="Heave of an underwater vehicle, Ljungberg & Enqvist §6",
    )


def siso_example(
    *,
    n0: float = -0.1,
    f0: float = 1.0,
    v_mean: float = 0.0,
    v_half_width: float = 0.1,
    e1_half_width: float = 0.1,
    e2_half_width: float = 0.1,
    w_half_width: float = 0.05,
    u_mean: float = 1.0,
    u_half_width: float = 0.3,
    current_sensor: bool | None = None,
    x0: float = 0.9,
) -> System:
    """The SISO example of paper §5.

    ``x(k+1) = n0 (x+v)|x+v| + f0 u + w``, ``y1 = x + e1`` with uniform ``v``,
    ``e1``, ``e2`` and a static-offset input ``u = ū + ũ``. The paper gives no
    numbers; with these bounded defaults (uniform ``w`` too) every sample satisfies
    ``x ≥ −0.1·1.5² + 0.7 − 0.05 = 0.425 > |v̄| + η_v + η_e1 + η_e2 = 0.4`` for
    ``v̄ = 0.1`` (A15). ``y2 = v + e2`` when ``current_sensor``.
    """
    if current_sensor is None:
        current_sensor = v_mean != 0.0
    spec = ModelSpec(
        name="siso_example",
        states=["x"],
        inputs=["u"],
        equations={"x": ["x*|x|", "u"]},
        theta0={"x": [n0, f0]},
        aggregate={"x": "x + v"},
        dt=1.0,
    )
    return System(
        spec=spec,
        inputs={"u": StaticOffset(u_mean, Uniform(0.0, u_half_width))},
        current={"x": Uniform(v_mean, v_half_width)},
        current_sign={"x": 1},
        process_noise={"x": Uniform(0.0, w_half_width)},
        sensor_noise={"x": Uniform(0.0, e1_half_width)},
        current_sensor_noise={"x": Uniform(0.0, e2_half_width)} if current_sensor else {},
        x0={"x": x0},
        description="SISO example, Ljungberg & Enqvist §5",
    )

