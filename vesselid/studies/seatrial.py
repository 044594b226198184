"""Sea-trial pipeline for CyberShip II: experiment design, consistent identification, CLI.

The surge/sway/yaw vessel of :mod:`vesselid.plant.vessels` is identified from a *multi-experiment*
sea trial (paper eq. (6)/(10), ``N_E`` experiments):

1. :func:`design_sea_trial` — one static operating point per experiment (a steady turn
   to starboard or to port at a given thrust/sway-force/yaw-moment level) plus random
   pulses of moderate amplitude for excitation. The static offsets keep ``u > 0`` and
   ``v``, ``r`` of one sign in every experiment, away from zero by a margin (A10/A15);
   turns to both sides at several levels make the experiments jointly informative (A8).
   The margins are checked on a noise-free simulation (:func:`vesselid.identify.diagnostics.
   design_margins`).
2. :func:`simulate_sea_trial` — the batch simulator (:func:`vesselid.plant.vessels.
   simulate_cybership2`, the same compiled physics as ``vesselid/Manoeuvring3DOF-v0``)
   with current, wind, gusts and unmodelled forces, and a trial log whose metadata holds
   the identification spec (θ0 and the aggregate relation), ready for ``vesselid identify``.
3. :func:`run_pipeline` — simulate + identify with LS, IV and IV with zero-mean
   instruments, plus free-run validation on a held-out experiment.

Identification structure
------------------------
In every steady turn of this vessel ``v`` and ``r`` have opposite signs (checked over the
whole force envelope, see docs/guide/sea-trials.md), so ``v·|r| = −r·|v|`` on all such data and only
the combination is identifiable. The spec used here folds ``v·|r|`` into ``r·|v|``
(:meth:`ModelSpec.merge_terms`; θ0 of ``r·|v|`` becomes ``θ_r|v| − θ_v|r|``); the plant
keeps the full physics.

Current: the GNSS measures the absolute velocity ``x = ν`` and the hydrodynamics act on
``ν_r = x + v`` with ``v = −ν_c`` (non-additive). With ``aggregate="speed_log"`` the
regressors use the Doppler log (velocity through water, the aggregated state of
Remark 4.3) and the target stays the GNSS velocity, i.e. the predictor (9) with the
residual ``w(k) = ν_c(k+1) + dt M⁻¹ τ_wind + …``; ``"current_meter"`` forms
``ỹ = y₁ − y₂`` from a current meter (eq. (9) literally); ``None`` uses the GNSS
velocity itself in the regressors (predictor (3), biased by the current).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from vesselid.errors import SeaTrialError
from vesselid.model.spec import ModelSpec

__all__ = [
    "AGGREGATES",
    "DEFAULT_LEVELS",
    "DESIGNS",
    "WIND_INPUTS",
    "SeaTrialDesign",
    "SeaTrialResult",
    "design_sea_trial",
    "free_run_nrmse",
    "markdown_table",
    "normalized_errors",
    "planned_sea_trial_design",
    "run_pipeline",
    "seatrial_spec",
    "simulate_sea_trial",
]

#: Aggregate options: name -> aggregate relations of the spec (paper eq. (9), Remark 4.3).
AGGREGATES: dict[str, dict[str, str] | None] = {
    "relative": None,
    "speed_log": {"u": "u_log", "v": "v_log"},
    "current_meter": {"u": "u - u_c", "v": "v - v_c"},
    "none": None,
}

#: Operating points ``(X [N], Y [N], N [N m], side)``; ``side`` +1 = starboard turn
#: (``r > 0``, ``v < 0``), −1 = port (``Y`` and ``N`` mirrored). The vessel has no
#: straight-running equilibrium to speak of — in every steady turn ``v·r < 0`` — so the
#: experiments are steady turns to both sides with the sway force of either sign (different
#: ``v/r`` ratios). With the default pulses (±0.45 N, ±0.5 N, ±0.1 N m) the nominal design
#: keeps ``u ≥ 0.092`` m/s, ``|v| ≥ 0.13`` m/s and ``|r| ≥ 0.072`` rad/s even over 10⁶
#: samples per experiment (seeds 0, 1), within the hull's force limits (``FORCE_MAX``).
DEFAULT_LEVELS: tuple[tuple[float, float, float, int], ...] = (
    (1.55, 0.0, 0.22, +1),
    (1.55, 0.0, 0.22, -1),
    (1.55, 0.3, 0.25, +1),
    (1.55, 0.3, 0.25, -1),
    (1.55, -0.3, 0.20, +1),
    (1.55, -0.3, 0.20, -1),
    (1.55, 0.15, 0.23, +1),
    (1.55, -0.15, 0.21, -1),
)

#: Input designs by name: ``"planned"`` (default) — standard manoeuvres chosen by the trial
#: planner (:func:`vesselid.studies.planner.plan_trial`), identified with the full structure
#: (``v·|r|`` and ``r·|v|`` apart: zig-zags separate them); ``"static-offset"`` — the
#: original steady turns with random pulses (:func:`design_sea_trial`), identified with
#: the merged structure.
DESIGNS = ("planned", "static-offset")

#: Default perturbation amplitudes ``(X, Y, N)`` of the random pulses. Large relative
#: perturbations are needed: only the variation *within* an experiment informs the
#: zero-mean-instrument estimator (the instruments are centred per experiment, A7).
DEFAULT_PERTURBATION = (0.45, 0.5, 0.1)



# --------------------------------------------------------------------------------- spec
def seatrial_spec(dt: float = 0.1, aggregate: str | None = "relative",
                  structure: str = "merged", *, vessel: str = "cybership2") -> ModelSpec:
    """The identification spec of the sea trial.

    :func:`vesselid.plant.vessels.cybership2_spec` — with ``structure="merged"`` (the
    static-offset design) ``v·|r|`` folded into ``r·|v|`` (``v·|r| = −r·|v|`` in every
    steady turn); ``"full"`` keeps both (the planned manoeuvres separate them) — and the
    aggregate relation of ``aggregate`` (:data:`AGGREGATES`).

    Parameters
    ----------
    dt : float
        Sample time (s).
    aggregate : {"relative", "speed_log", "current_meter", "none", None}
        Signals of ``u`` and ``v`` (``r`` is not affected by an irrotational current):
        ``"relative"`` — the log's ``u, v`` columns hold the speed log (velocity through
        water) as target *and* regressors, so the current does not enter the equations;
        ``"speed_log"`` — GNSS target, speed-log regressors (Remark 4.3 with (10));
        ``"current_meter"`` — GNSS target, regressors ``GNSS − current meter`` (eq. (9));
        ``"none"`` — GNSS everywhere (predictor (3)).
    structure : {"merged", "full"}
        ``"merged"``: the vessel data module's ``TRIAL_MERGES`` (terms collinear in steady
        turns) are folded; ``"full"``: no merges.
    vessel : str
        Catalogue vessel.

    Returns
    -------
    ModelSpec
    """
    from vesselid.plant.catalogue import vessel_module

    key = aggregate_key(aggregate)
    module = vessel_module(vessel)
    merges = {"merged": getattr(module, "TRIAL_MERGES", ()), "full": ()}
    if structure not in merges:
        raise SeaTrialError(f"unknown structure {structure!r}; choose 'merged' or 'full'")
    spec = module.HULL.spec(dt)
    for keep, drop, factor in merges[structure]:
        spec = spec.merge_terms(keep, drop, factor)
    rel = AGGREGATES[key]
    return spec.with_aggregate(rel) if rel else spec


def aggregate_key(aggregate: str | None) -> str:
    key = "none" if aggregate is None else str(aggregate).replace("-", "_")
    if key not in AGGREGATES:
        raise SeaTrialError(f"unknown aggregate {aggregate!r}; choose from {sorted(AGGREGATES)}")
    return key


# ------------------------------------------------------------------------------- design
@dataclass
class SeaTrialDesign:
    """A multi-experiment sea-trial design (result of :func:`design_sea_trial`).

    Attributes
    ----------
    inputs : ndarray (N_E, N, 3)
        Generalised forces ``[X, Y, N]`` per experiment and sample.
    table : DataFrame
        One row per experiment: side, offsets, perturbation amplitudes and the nominal
        (noise-free, no current) steady state ``u, v, r`` and its minima ``|·|``.
    margins : DataFrame
        :func:`vesselid.identify.diagnostics.design_margins` of the nominal velocity through water
        with the margins ``eta``; ``ok`` is False where a state comes within ``η`` of zero.
    eta : dict
        The margins used.
    warmup : int
        Samples of constant offset simulated (and discarded) before each experiment.
    dt : float
        Sample time (s).
    nominal : ndarray (N_E, N, 3)
        Noise-free velocity through water ``ν_r`` of the design.
    vessel : str
        Catalogue vessel the design is for.
    """

    inputs: np.ndarray
    table: pd.DataFrame
    margins: pd.DataFrame
    eta: dict[str, float]
    warmup: int
    dt: float
    nominal: np.ndarray = field(repr=False)
    vessel: str = "cybership2"
    name: str = "static-offset"
    structure: str = "merged"
    warmup_forces: np.ndarray | None = field(default=None, repr=False)
    plan: Any = field(default=None, repr=False)

    @property
    def n_experiments(self) -> int:
        return int(self.inputs.shape[0])

    @property
    def n_samples(self) -> int:
        return int(self.inputs.shape[1])

    @property
    def ok(self) -> bool:
        """Every state of every experiment keeps its margin (A10/A15)."""
        return bool(self.margins["ok"].all())

    def violations(self) -> pd.DataFrame:
        """Rows of :attr:`margins` that violate the margin."""
        return self.margins[~self.margins["ok"]]

    def warmup_inputs(self) -> np.ndarray:
        """Inputs with the warm-up prepended, ``(N_E, warmup + N, 3)`` (the constant
        offset of each experiment, or the planned design's straight approach)."""
        if self.warmup_forces is not None:
            return np.concatenate([self.warmup_forces, self.inputs], axis=1)
        offsets = self.table[["X", "Y", "N"]].to_numpy(float)
        pre = np.repeat(offsets[:, None, :], self.warmup, axis=1)
        return np.concatenate([pre, self.inputs], axis=1)


def _pulses(rng: np.random.Generator, n: int, amplitude: float, width: tuple[int, int]):
    """Random pulses: piecewise-constant ``U(−a, a)`` levels of ``U(width)`` samples."""
    if amplitude == 0:
        return np.zeros(n)
    lo, hi = width
    n_seg = n // max(lo, 1) + 2
    widths = rng.integers(lo, hi + 1, n_seg)
    levels = rng.uniform(-amplitude, amplitude, n_seg)
    out = np.repeat(levels, widths)
    while out.size < n:  # pragma: no cover - n_seg covers n with the minimum width
        out = np.concatenate([out, np.repeat(rng.uniform(-amplitude, amplitude, n_seg), widths)])
    return out[:n]


def design_sea_trial(
    experiments: int = 6,
    samples: int = 20000,
    *,
    levels: Sequence[Sequence[float]] | None = None,
    perturbation: Sequence[float] = DEFAULT_PERTURBATION,
    pulse_width: tuple[float, float] = (5.0, 40.0),
    dt: float = 0.1,
    warmup: float = 60.0,
    eta: Mapping[str, float] | None = None,
    seed: int | np.random.SeedSequence | None = 0,
    rng: np.random.Generator | None = None,
    check: bool = True,
    vessel: str = "cybership2",
) -> SeaTrialDesign:
    """Design ``N_E`` sea-trial experiments with static offsets (A8, A10/A15).

    Experiment ``e`` holds the operating point ``levels[e]`` — surge thrust ``X``, sway
    force ``Y`` and yaw moment ``N`` of a steady turn; ``side = −1`` mirrors ``Y`` and
    ``N`` into a port turn — plus independent random pulses on the three forces
    (amplitudes ``perturbation``, widths ``pulse_width`` seconds). With ``len(levels) <
    experiments`` the levels are reused with the thrust scaled by ``1 ± 0.1`` per cycle.

    Parameters
    ----------
    experiments, samples : int
        ``N_E`` and samples per experiment ``N_D``.
    levels : sequence of (X, Y, N, side), optional
        Operating points (default :data:`DEFAULT_LEVELS`).
    perturbation : (float, float, float)
        Pulse amplitudes for ``X, Y, N``.
    pulse_width : (float, float)
        Range of pulse widths (s).
    dt : float
        Sample time (s).
    warmup : float
        Constant-offset lead-in (s) simulated and discarded so every experiment starts in
        its steady turn (no sign change of ``v``, ``r`` in the transient).
    eta : mapping state -> float, optional
        Margins for the check; default ``{"u": 0.08, "v": 0.08, "r": 0.02}``: the A15
        margin ``η_e1 + η_e2 + η_v`` for the default sensors (3σ = 0.015 m/s each) and a
        current of 0.05 m/s, and 3σ of the gyro plus slack for ``r``.
    seed, rng
        Randomness of the pulses (``rng`` wins when given).
    check : bool
        Raise :class:`SeaTrialError` when the nominal design violates a margin (the
        violations are always in :attr:`SeaTrialDesign.margins`).
    vessel : str
        Catalogue vessel. A vessel other than CyberShip II brings its own defaults for
        ``levels``, ``perturbation`` and ``eta`` (``TRIAL_LEVELS``, ``TRIAL_PERTURBATION``,
        ``TRIAL_ETA`` of its data module).

    Returns
    -------
    SeaTrialDesign
    """
    from vesselid.plant.catalogue import vessel_module
    from vesselid.plant.vessels import VesselSensors, simulate_vessel

    module = vessel_module(vessel)
    if vessel != "cybership2":
        levels = levels or module.TRIAL_LEVELS
        if perturbation is DEFAULT_PERTURBATION:
            perturbation = module.TRIAL_PERTURBATION
        eta = module.TRIAL_ETA if eta is None else eta
    n_e, n_d = int(experiments), int(samples)
    if n_e < 2:
        raise SeaTrialError(f"need at least 2 experiments (turns to both sides), got {n_e}")
    if n_d < 50:
        raise SeaTrialError(f"need at least 50 samples per experiment, got {n_d}")
    lv = [tuple(float(x) for x in row) for row in (levels or DEFAULT_LEVELS)]
    if any(len(row) != 4 or row[3] not in (-1.0, 1.0) for row in lv):
        raise SeaTrialError("levels must be rows (X, Y, N, side) with side = +1 or -1")
    amp = tuple(float(a) for a in perturbation)
    if len(amp) != 3 or any(not (a >= 0) for a in amp):
        raise SeaTrialError(f"perturbation needs three non-negative amplitudes, got {perturbation}")
    w_lo, w_hi = (max(1, round(float(w) / dt)) for w in pulse_width)
    if w_hi < w_lo:
        raise SeaTrialError(f"pulse_width must be (low, high), got {pulse_width}")
    gen = rng if rng is not None else np.random.default_rng(seed)
    rows, inputs = [], np.empty((n_e, n_d, 3))
    for e in range(n_e):
        x, y, n, side = lv[e % len(lv)]
        cycle = e // len(lv)
        if cycle:
            x *= 1.0 + 0.1 * (cycle if cycle % 2 else -cycle) / 2.0
        off = np.array([x, side * y, side * n])
        inputs[e] = off
        for j in range(3):
            inputs[e, :, j] += _pulses(gen, n_d, amp[j], (w_lo, w_hi))
        rows.append({"experiment": e, "side": "starboard" if side > 0 else "port",
                     "X": off[0], "Y": off[1], "N": off[2],
                     "pert_X": amp[0], "pert_Y": amp[1], "pert_N": amp[2]})
    n_warm = max(0, round(float(warmup) / dt))
    table = pd.DataFrame(rows)
    design = SeaTrialDesign(inputs=inputs, table=table, margins=pd.DataFrame(), eta={},
                            warmup=n_warm, dt=float(dt), nominal=np.empty(0), vessel=vessel)
    sim = simulate_vessel(module.HULL, design.warmup_inputs(), seed=0, dt=dt,
                          sensors=VesselSensors.noiseless())
    nominal = np.ascontiguousarray(sim.nu_r[:, n_warm:])
    spec = seatrial_spec(dt, None, vessel=vessel)
    eta_used = {"u": 0.08, "v": 0.08, "r": 0.02} if eta is None else {
        s: float(eta.get(s, 0.0)) for s in spec.states}
    margins = _nominal_margins(nominal, spec, eta_used, table)
    design.margins, design.eta, design.nominal = margins, eta_used, nominal
    if check and not design.ok:
        bad = design.violations().iloc[0]
        raise SeaTrialError(
            f"design violates the A10/A15 margin: state {bad['state']!r} of experiment "
            f"{bad['experiment']} comes within η={bad['eta']:.3g} of zero (min |x| = "
            f"{bad['min_abs']:.3g}, {bad['sign_changes']} sign changes); raise the offsets "
            "or lower the perturbation"
        )
    return design


def planned_sea_trial_design(
    experiments: int = 6,
    samples: int = 20000,
    *,
    dt: float = 0.1,
    warmup: float = 60.0,
    levels: Any = None,
    plan: Any = None,
) -> SeaTrialDesign:
    """The planned design: standard manoeuvres chosen by
    :func:`vesselid.studies.planner.plan_trial`.

    Each experiment is a programme of manoeuvres (zig-zags, turning circles, stopping,
    thruster tests, ...) whose rudder switching instants were found on the nominal
    model; the forces are applied open loop (A4). Zig-zags make ``v`` and ``r`` change
    sign, so the design is identified with the full structure (``v·|r|`` and ``r·|v|``
    apart) and its A10/A15 margins are reported, not enforced.

    Parameters
    ----------
    experiments, samples : int
        ``N_E`` and samples per experiment.
    dt : float
        Sample time (s).
    warmup : float
        Straight approach (s) simulated and discarded before each experiment.
    levels : vesselid.studies.planner.DisturbanceLevels, optional
        Disturbances the planner assumes (default: the sea-trial defaults).
    plan : vesselid.studies.planner.TrialPlan, optional
        A ready plan (its experiments and samples win).

    Returns
    -------
    SeaTrialDesign
        With ``plan`` holding the :class:`~vesselid.studies.planner.TrialPlan`.
    """
    from vesselid.studies.planner import plan_trial

    n_e, n_d = int(experiments), int(samples)
    if n_e < 1:
        raise SeaTrialError(f"need at least 1 experiment, got {n_e}")
    if n_d < 50:
        raise SeaTrialError(f"need at least 50 samples per experiment, got {n_d}")
    n_warm = max(0, round(float(warmup) / dt))
    if plan is None:
        plan = plan_trial(n_e * n_d, n_e, levels=levels, dt=dt, warmup=n_warm)
    n_e, n_d, n_warm = plan.experiments, plan.samples, plan.warmup
    plant = plan.levels.plant(dt)
    forces = plan.forces(plant)
    nominal = np.stack([plant.run(f, np.zeros(3))[n_warm:-1] for f in forces])
    rows = []
    for e, prog in enumerate(plan.programmes):
        f = forces[e, n_warm:]
        rows.append({"experiment": e, "programme": prog.label(),
                     "X": float(f[:, 0].mean()), "Y": float(f[:, 1].mean()),
                     "N": float(f[:, 2].mean())})
    table = pd.DataFrame(rows)
    spec = seatrial_spec(dt, None, "full")
    eta_used = {"u": 0.08, "v": 0.08, "r": 0.02}
    margins = _nominal_margins(nominal, spec, eta_used, table)
    return SeaTrialDesign(
        inputs=np.ascontiguousarray(forces[:, n_warm:]), table=table, margins=margins,
        eta=eta_used, warmup=n_warm, dt=float(dt), nominal=nominal, name="planned",
        structure="full", warmup_forces=np.ascontiguousarray(forces[:, :n_warm]), plan=plan)


def _nominal_margins(nominal: np.ndarray, spec: ModelSpec, eta: Mapping[str, float],
                     table: pd.DataFrame) -> pd.DataFrame:
    """A10/A15 margins of a noise-free design ``nominal`` (experiments × samples × 3); adds
    each experiment's mean and min |x| per state to ``table``."""
    from vesselid.identify.diagnostics import design_margins

    n_e, n_d = nominal.shape[:2]
    starts = np.arange(n_e + 1, dtype=np.int64) * n_d
    margins = design_margins(nominal.reshape(-1, 3), starts, spec, eta, list(range(n_e)),
                             threshold=0.0)
    for j, s in enumerate(spec.states):
        table[f"mean_{s}"] = nominal[:, :, j].mean(axis=1)
        table[f"min_abs_{s}"] = np.abs(nominal[:, :, j]).min(axis=1)
    return margins


def _make_design(name: str | None, experiments: int, samples: int, dt: float, seed: Any,
                 options: Mapping[str, Any]) -> SeaTrialDesign:
    """Design by name; ``None``: planned for CyberShip II (the planner's vessel), else
    static-offset."""
    options = dict(options)
    vessel = options.get("vessel", "cybership2")
    if name is None:
        name = "planned" if vessel == "cybership2" else "static-offset"
    if name == "static-offset":
        return design_sea_trial(experiments, samples, dt=dt, seed=seed, **options)
    if name == "planned":
        if vessel != "cybership2":
            raise SeaTrialError(f"the trial planner knows CyberShip II only, not {vessel!r}; "
                                "use design='static-offset'")
        options.pop("vessel", None)
        allowed = {"warmup", "levels", "plan"}
        bad = set(options) - allowed
        if bad:
            raise SeaTrialError(f"options {sorted(bad)} apply to the static-offset design only")
        return planned_sea_trial_design(experiments, samples, dt=dt, **options)
    raise SeaTrialError(f"unknown design {name!r}; choose from {list(DESIGNS)}")


# --------------------------------------------------------------------------- simulation
def _disturbances(current_speed: float, current_direction: float, wind_speed: float,
                  wind_direction: float, current_variation: float, wind_gust: float,
                  force_noise: Sequence[float]):
    from vesselid.plant.vessels import VesselDisturbances

    for name, val in (("current_speed", current_speed), ("wind_speed", wind_speed),
                      ("current_variation", current_variation), ("wind_gust", wind_gust)):
        if not (math.isfinite(float(val)) and float(val) >= 0):
            raise SeaTrialError(f"{name} must be a non-negative number, got {val!r}")
    return VesselDisturbances(
        current_speed=float(current_speed),
        current_direction=float(current_direction),
        current_speed_std=float(current_variation),
        current_direction_std=float(current_variation) / max(float(current_speed), 0.05)
        if current_variation > 0 else 0.0,
        wind_speed=float(wind_speed),
        wind_direction=float(wind_direction),
        gust_std=float(wind_gust),
        wind_direction_std=0.1 if wind_gust > 0 else 0.0,
        force_noise_std=tuple(float(f) for f in force_noise),
    )


def simulate_sea_trial(
    experiments: int = 6,
    samples: int = 20000,
    seed: int | None = 0,
    *,
    design: SeaTrialDesign | str | None = None,
    current_speed: float = 0.05,
    current_direction: float = math.radians(30.0),
    current_variation: float = 0.005,
    wind_speed: float = 1.0,
    wind_direction: float = math.radians(-60.0),
    wind_gust: float = 0.1,
    force_noise: Sequence[float] = (0.02, 0.02, 0.01),
    sensors: Any = None,
    aggregate: str | None = "relative",
    source: str = "batch",
    dt: float = 0.1,
    vessel: str = "cybership2",
    waves: Any = None,
    wind_input: str | None = "anemometer",
    closed_loop: bool = False,
    **design_options: Any,
):
    """Simulate a multi-experiment CyberShip II sea trial and return its trial log.

    Parameters
    ----------
    experiments, samples : int
        ``N_E`` experiments of ``N_D`` samples (ignored when ``design`` is given).
    seed : int, optional
        One seed for everything: the design's pulses and all disturbances
        (``SeedSequence(seed).spawn(2)``).
    design : SeaTrialDesign or {"planned", "static-offset"}, optional
        A ready design, or the name of one (:data:`DESIGNS`; default ``"planned"``:
        :func:`planned_sea_trial_design`; ``"static-offset"``: :func:`design_sea_trial`
        with ``design_options``).
    current_speed, current_direction : float
        Mean earth-fixed current (m/s, going-to direction in rad). Default 0.05 m/s at
        model scale (≈ 0.8 kn full scale, Froude scaling 1:70).
    current_variation : float
        Std of the bounded Gauss–Markov current-speed variation (m/s).
    wind_speed, wind_direction, wind_gust : float
        Mean true wind (m/s model scale; 1 m/s ≈ 8 m/s full scale), direction (rad) and
        gust std (m/s).
    force_noise : (float, float, float)
        Std of unmodelled Gauss–Markov forces (N, N, N m).
    sensors : VesselSensors or mapping, optional
        Sensor noise (default: GNSS/speed log/current meter 0.005 m/s, gyro 0.002 rad/s).
    aggregate : {"relative", "speed_log", "current_meter", "none", None}
        Predictor (:func:`seatrial_spec`). With ``"relative"`` (default) the columns
        ``u, v`` hold the speed-log readings and the GNSS moves to ``u_gnss, v_gnss``.
    source : {"batch", "env"}
        ``"batch"``: :func:`vesselid.plant.vessels.simulate_cybership2`; ``"env"``: the same
        forces played through ``vesselid/Manoeuvring3DOF-v0`` and recorded with
        :class:`vesselid.envs.recorder.TrialRecorder` (same physics; slower, and the
        current/wind directions are fixed per episode to the given values).
    dt : float
        Sample time (s).
    vessel : str
        Catalogue vessel (ignored when ``design`` is given: the design's vessel).
    waves : vesselid.plant.waves.WaveConditions, optional
        Sea state: first-order wave-induced motion (JONSWAP, :mod:`vesselid.plant.waves`) added
        to the measured velocities (GNSS, speed log, gyro) and heading as a coloured
        sensor disturbance, drawn from the same seed; recorded in the metadata.
    wind_input : {"anemometer", "none", None}
        ``"anemometer"`` (default): the load of the mean wind measured by the anemometer
        (per experiment, with the GNSS velocity and heading; :func:`_add_wind_input`)
        under the vessel's known wind model (Blendermann 1994, the hull's
        :class:`~vesselid.plant.vessels.wind.BlendermannWind`) is a *measured input*: the
        columns ``X, Y, N`` hold commanded force + wind load (the commands move to
        ``X_cmd, Y_cmd, N_cmd``, the load to ``X_wind, Y_wind, N_wind``). The mean wind
        load depends on the heading, which the manoeuvres correlate with the
        instruments; left in the equation error it biases every instrumental-variable
        estimate. ``"none"``/``None``: ``X, Y, N`` are the commands only (the wind load is
        an unmodelled disturbance).
    closed_loop : bool
        Run the trial under feedback instead of an open-loop force design: PI velocity
        loops ``X → u``, ``Y → v``, ``N → r`` (:func:`closed_loop_trial_controller`) on the
        speed log and the gyro, tracking random-step references with white force
        dithers (:data:`CLOSED_LOOP_TRIAL`), in ``vesselid/Manoeuvring3DOF-v0``. The log
        gets the columns ``u_ref, v_ref, r_ref, X_dither, Y_dither, N_dither`` and
        ``metadata["closed_loop"]``, so that ``identify`` (``auto``) uses ``cl-iv``.
        CyberShip II, ``aggregate="relative"`` (the loops control the speed-log
        velocities the model identifies) and no ``design``; ``source`` is ignored.

    Returns
    -------
    TrialLog
        Columns ``experiment, time, u, v, r, X, Y, N, psi, u_log, v_log, r_log, u_c, v_c,
        wind_speed, wind_angle, true_*`` (with waves also ``true_wave_u, true_wave_v,
        true_wave_r, true_wave_psi``); metadata ``spec`` (identification spec with θ0 and
        the aggregate relation), ``design`` (the experiment table), ``system``, ``waves``.

    Notes
    -----
    The log describes the trial, not how to identify it: ``sriv`` and ``auto``'s SRIV
    fallback need an AR noise model of order :data:`vesselid.studies.planner.SRIV_ORDER`
    (16) on this trial's equation error, given explicitly —
    ``identify(log, noise_order=SRIV_ORDER)``, ``vesselid identify --noise-order 16``
    (``vesselid sea-trial`` prints that command).
    """
    from vesselid.data.logs import TrialLog

    key = aggregate_key(aggregate)
    root = np.random.SeedSequence(seed)
    design_seed, sim_seed = root.spawn(2)
    if closed_loop:
        return _closed_loop_sea_trial(
            experiments, samples, seed, root, sim_seed, design=design, key=key,
            current_speed=current_speed, current_direction=current_direction,
            current_variation=current_variation, wind_speed=wind_speed,
            wind_direction=wind_direction, wind_gust=wind_gust, force_noise=force_noise,
            sensors=sensors, dt=dt, vessel=vessel, waves=waves, wind_input=wind_input,
            design_options=design_options)
    if design is None or isinstance(design, str):
        design = _make_design(design, experiments, samples, dt, design_seed,
                              dict(design_options, vessel=vessel))
    elif design_options:
        raise SeaTrialError("design options are ignored when a design is given")
    dist = _disturbances(current_speed, current_direction, wind_speed, wind_direction,
                         current_variation, wind_gust, force_noise)
    spec = seatrial_spec(design.dt, key, design.structure, vessel=design.vessel)
    plant = _plant(design.vessel, design.dt, dist, sensors)
    if source == "batch":
        log = _simulate_batch(design, plant, sim_seed)
    elif source == "env":
        log = _simulate_env(design, plant, sensors, sim_seed)
    else:
        raise SeaTrialError(f"source must be 'batch' or 'env', got {source!r}")
    frame = log.to_frame()
    wind_key = _wind_input_key(wind_input)
    if wind_key == "anemometer" and dist.wind_on:
        _add_wind_input(frame, plant)
    if waves is not None:
        _add_waves(frame, waves, design.dt, root.spawn(1)[0])
    if key == "relative":
        frame = frame.rename(columns={"u": "u_gnss", "v": "v_gnss"})
        frame["u"] = frame["u_log"]
        frame["v"] = frame["v_log"]
    meta = dict(log.metadata)
    meta.update({
        "spec": spec.to_dict(),
        "aggregate": key,
        "seed": seed,
        "source": source,
        "vessel": design.vessel,
        "design": design.table.to_dict(orient="list"),
        "design_name": design.name,
        "structure": design.structure,
        "design_eta": design.eta,
        "warmup_samples_discarded": design.warmup,
        "samples_per_experiment": design.n_samples,
        "experiments": design.n_experiments,
        "wind_input": wind_key if dist.wind_on else "none",
    })
    noise = _regressor_noise_std(key, (meta.get("system") or {}).get("sensors"))
    if noise:
        meta["sensor_noise_std"] = noise
    if design.plan is not None:
        meta["plan"] = design.plan.to_dict()
    if waves is not None:
        meta["waves"] = waves.to_dict()
    return TrialLog(frame, meta)


def _closed_loop_sea_trial(experiments: int, samples: int, seed: Any,
                           root: np.random.SeedSequence, sim_seed: np.random.SeedSequence, *,
                           design: Any, key: str, current_speed: float,
                           current_direction: float, current_variation: float,
                           wind_speed: float, wind_direction: float, wind_gust: float,
                           force_noise: Sequence[float], sensors: Any, dt: float, vessel: str,
                           waves: Any, wind_input: str | None,
                           design_options: Mapping[str, Any]):
    """:func:`simulate_sea_trial` with ``closed_loop=True``."""
    from vesselid.data.logs import TrialLog

    if design is not None or design_options:
        raise SeaTrialError("a closed-loop sea trial has no open-loop force design: leave "
                            "design and its options out")
    if key != "relative":
        raise SeaTrialError(f"a closed-loop sea trial needs aggregate='relative' (its loops "
                            f"control the speed-log velocities), got {key!r}")
    pid = closed_loop_trial_controller(dt, vessel)  # refuses other vessels
    dist = _disturbances(current_speed, current_direction, wind_speed, wind_direction,
                         current_variation, wind_gust, force_noise)
    log = _simulate_env_closed_loop(experiments, samples, dt, dist, sensors, sim_seed, vessel)
    frame = log.to_frame()
    wind_key = _wind_input_key(wind_input)
    if wind_key == "anemometer" and dist.wind_on:
        _add_wind_input(frame, _plant(vessel, dt, dist, sensors))
    if waves is not None:
        _add_waves(frame, waves, dt, root.spawn(1)[0])
    frame = frame.rename(columns={"u": "u_gnss", "v": "v_gnss"})
    frame["u"] = frame["u_log"]
    frame["v"] = frame["v_log"]
    spec = seatrial_spec(dt, key, "merged", vessel=vessel)
    meta = dict(log.metadata)
    meta.update({
        "spec": spec.to_dict(), "aggregate": key, "seed": seed, "source": "env",
        "vessel": vessel, "design_name": "closed-loop", "structure": "merged",
        "samples_per_experiment": samples, "experiments": experiments,
        "wind_input": wind_key if dist.wind_on else "none",
        "closed_loop_trial": {"controller": pid.to_dict(),
                              "references": {"u": list(CLOSED_LOOP_TRIAL["u"]),
                                             "v": list(CLOSED_LOOP_TRIAL["vr"]),
                                             "r": list(CLOSED_LOOP_TRIAL["vr"]),
                                             "hold_s": list(CLOSED_LOOP_TRIAL["hold"])},
                              "dither_std": dict(CLOSED_LOOP_TRIAL["dither"])},
    })
    noise = _regressor_noise_std(key, (meta.get("system") or {}).get("sensors"))
    if noise:
        meta["sensor_noise_std"] = noise
    if waves is not None:
        meta["waves"] = waves.to_dict()
    return TrialLog(frame, meta)


def _regressor_noise_std(key: str, sensors: Mapping[str, Any] | None) -> dict[str, float]:
    """Std of the white sensor noise on each regressor signal of the aggregate option
    ``key``, from the simulation's sensor specification ``sensors``
    (``metadata["sensor_noise_std"]``, for identify's errors-in-variables
    correction, :mod:`vesselid.identify.eiv`): the speed log for ``u, v`` with
    ``relative``/``speed_log``, GNSS and current meter for ``current_meter``, GNSS for
    ``none``; the gyro for ``r``. The noise is clipped at ``±clip`` std, which lowers its
    variance by :func:`~vesselid.plant.vessels.environment.clipped_variance`."""
    if not sensors:  # the log's metadata["system"]["sensors"]
        return {}
    from vesselid.plant.vessels.environment import clipped_variance

    factor = clipped_variance(sensors.get("clip", np.inf))

    def std(*names: str) -> float | None:
        var = 0.0
        for n in names:
            val = sensors.get(n)
            if val is None:
                return None
            var += float(np.max(np.atleast_1d(val))) ** 2
        return math.sqrt(var * factor)

    uv = {"relative": ("speed_log",), "speed_log": ("speed_log",),
          "current_meter": ("gnss", "current_meter"), "none": ("gnss",)}[key]
    out = {"u": std(*uv), "v": std(*uv), "r": std("gyro")}
    return {k: v for k, v in out.items() if v is not None and v > 0}


#: How the wind load enters the identification (:func:`simulate_sea_trial`).
WIND_INPUTS = ("anemometer", "none")


def _wind_input_key(wind_input: str | None) -> str:
    key = "none" if wind_input is None else str(wind_input)
    if key not in WIND_INPUTS:
        raise SeaTrialError(f"unknown wind input {wind_input!r}; choose from {list(WIND_INPUTS)}")
    return key


def _add_wind_input(frame: pd.DataFrame, plant: Any) -> None:
    """Wind load of the measured mean wind added to the force columns ``X, Y, N``.

    Per experiment the true wind (earth frame) is the mean of apparent wind
    (anemometer) plus ground velocity (GNSS) rotated with the heading; the load at each
    sample is the plant's wind load
    (:meth:`~vesselid.plant.vessels.kernel.VesselModel.apparent_wind_load`) at the
    apparent wind of that mean wind and the measured velocity and heading. Using
    the mean wind rather than each anemometer reading keeps the sensor noise out of the
    force columns (which are their own instruments: noise there biases the input
    coefficients); gusts stay an unmodelled zero-mean disturbance. Commands are kept in
    ``X_cmd, Y_cmd, N_cmd``, the load in ``X_wind, Y_wind, N_wind``.
    """
    need = ("wind_speed", "wind_angle", "u", "v", "psi")
    missing = [c for c in need if c not in frame]
    if missing:
        raise SeaTrialError(f"wind_input='anemometer' needs the anemometer, GNSS and heading "
                            f"columns (missing {missing}); enable them or use wind_input='none'")
    speed = np.abs(frame["wind_speed"].to_numpy())
    gam = frame["wind_angle"].to_numpy()
    u, v, psi = (frame[c].to_numpy() for c in ("u", "v", "psi"))
    c, s = np.cos(psi), np.sin(psi)
    # air velocity in the body frame: ground velocity minus apparent wind (u_rw, v_rw)
    wu = u - speed * np.cos(gam)
    wv = v + speed * np.sin(gam)
    north, east = c * wu - s * wv, s * wu + c * wv
    exp = frame["experiment"].to_numpy() if "experiment" in frame else np.zeros(len(frame))
    _, inv = np.unique(exp, return_inverse=True)
    count = np.bincount(inv)
    north = (np.bincount(inv, north) / count)[inv]
    east = (np.bincount(inv, east) / count)[inv]
    urw = u - (c * north + s * east)
    vrw = v - (-s * north + c * east)
    load = plant.apparent_wind_load(urw, vrw)
    for j, name in enumerate(("X", "Y", "N")):
        cmd = frame[name].to_numpy()
        frame[f"{name}_cmd"] = cmd
        frame[f"{name}_wind"] = load[:, j]
        frame[name] = cmd + load[:, j]


def _add_waves(frame: pd.DataFrame, waves: Any, dt: float, seed: np.random.SeedSequence) -> None:
    """Add first-order wave-induced motion to the measured columns, experiment by experiment."""
    from vesselid.plant.waves import WaveConditions, wave_motion

    if not isinstance(waves, WaveConditions):
        raise SeaTrialError(f"waves must be WaveConditions, got {type(waves).__name__}")
    rng = np.random.default_rng(seed)
    exp = frame["experiment"].to_numpy()
    cols = {c: np.zeros(len(frame)) for c in ("u", "v", "r", "psi")}
    for e in np.unique(exp):
        idx = np.flatnonzero(exp == e)
        m = wave_motion(waves, dt, frame["true_psi"].to_numpy()[idx],
                        frame["true_north"].to_numpy()[idx], frame["true_east"].to_numpy()[idx],
                        rng)
        for c in cols:
            cols[c][idx] = m[c]
    for name, c in (("u", "u"), ("v", "v"), ("u_log", "u"), ("v_log", "v"), ("r", "r"),
                    ("r_log", "r")):
        if name in frame:
            frame[name] = frame[name].to_numpy() + cols[c]
    if "psi" in frame:
        a = frame["psi"].to_numpy() + cols["psi"]
        frame["psi"] = a - 2.0 * np.pi * np.floor((a + np.pi) / (2.0 * np.pi))
    for c in cols:
        frame[f"true_wave_{c}"] = cols[c]


def _plant(vessel: str, dt: float, dist: Any, sensors: Any):
    """The sea trial's plant: the catalogue vessel in its sea with its sensors."""
    from vesselid.plant.catalogue import vessel_module
    from vesselid.plant.vessels import VesselModel

    return VesselModel(vessel_module(vessel).HULL, dt=dt, disturbances=dist, sensors=sensors)


def _simulate_batch(design: SeaTrialDesign, plant: Any, seed: np.random.SeedSequence):
    from vesselid.data.logs import TrialLog

    sim = plant.simulate(design.warmup_inputs(), seed=seed)
    log = sim.to_log()
    frame = log.to_frame()
    n_tot = design.warmup + design.n_samples
    keep = np.tile(np.arange(n_tot) >= design.warmup, design.n_experiments)
    frame = frame.loc[keep].reset_index(drop=True)
    frame["time"] = np.tile(np.arange(design.n_samples) * design.dt, design.n_experiments)
    return TrialLog(frame, log.metadata)


def _simulate_env(design: SeaTrialDesign, plant: Any, sensors: Any,
                  seed: np.random.SeedSequence):
    """The design through the environment built with the plant's disturbances and the
    given ``sensors`` settings."""
    import gymnasium as gym

    import vesselid.envs  # noqa: F401  (registers the environments)
    from vesselid.data.logs import TrialLog
    from vesselid.envs.recorder import TrialRecorder

    dist = plant.disturbances
    fmax = np.array(plant.force_max)
    if np.any(np.abs(design.inputs) > fmax + 1e-12):
        raise SeaTrialError(f"the design exceeds the vessel's force limits {tuple(fmax)}")
    env = TrialRecorder(gym.make(
        "vesselid/Manoeuvring3DOF-v0", vessel=design.vessel,
        max_episode_steps=design.warmup + design.n_samples + 1,
        dt=design.dt, current_speed=dist.current_speed,
        current_direction=dist.current_direction, current_variation=dist.current_speed_std,
        wind_speed=dist.wind_speed, wind_direction=dist.wind_direction,
        wind_gust=dist.gust_std, force_noise=dist.force_noise_std, sensors=sensors,
        force_max=tuple(fmax)))
    frames = []
    seeds = seed.generate_state(design.n_experiments)
    inputs = design.warmup_inputs() / fmax
    for e in range(design.n_experiments):
        env.clear()
        env.reset(seed=int(seeds[e]), options={"nu": [0.0, 0.0, 0.0], "eta": [0.0, 0.0, 0.0]})
        for a in inputs[e]:
            env.step(a)
        fr = env.to_log().to_frame()
        fr = fr.iloc[design.warmup:design.warmup + design.n_samples].reset_index(drop=True)
        fr["experiment"] = e
        fr["time"] = np.arange(len(fr)) * design.dt
        frames.append(fr)
        meta = env.to_log().metadata
    env.close()
    return TrialLog(pd.concat(frames, ignore_index=True), meta)


#: The closed-loop sea trial's velocity loops (CyberShip II): PI gains, feed-forward surge
#: force, reference levels (m/s, rad/s; held 5–30 s) and force dithers (N, N, N m). The
#: sway and yaw references take the four sign combinations in turn over the experiments,
#: so that every modulus term is excited (as :func:`vesselid.plant.closedloop.
#: cybership2_velocity_design`).
CLOSED_LOOP_TRIAL = {"kp": {"X": 30.0, "Y": 30.0, "N": 3.0}, "ki": {"X": 6.0, "Y": 6.0, "N": 0.6},
                     "offset": {"X": 1.4}, "u": (0.5, 1.0), "vr": (0.05, 0.15),
                     "hold": (5.0, 30.0), "dither": {"X": 0.3, "Y": 0.3, "N": 0.03}}


def closed_loop_trial_controller(dt: float = 0.1, vessel: str = "cybership2"):
    """The PI velocity loops ``X → u``, ``Y → v``, ``N → r`` of the closed-loop sea trial
    (:data:`CLOSED_LOOP_TRIAL`), saturated at the vessel's force limits."""
    from vesselid.plant.catalogue import vessel_module
    from vesselid.plant.closedloop import PID

    if vessel != "cybership2":
        raise SeaTrialError(f"the closed-loop sea trial's velocity loops are tuned for "
                            f"CyberShip II, not {vessel!r}")
    fmax = tuple(float(f) for f in vessel_module(vessel).HULL.force_max)
    c = CLOSED_LOOP_TRIAL
    return PID(loops={"X": "u", "Y": "v", "N": "r"}, kp=c["kp"], ki=c["ki"],
               offset=c["offset"], limits={j: (-f, f) for j, f in zip("XYN", fmax, strict=True)},
               dt=dt)


def _closed_loop_signals(rng: np.random.Generator, n: int, experiment: int, dt: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """References ``(n, 3)`` (u, v, r) and dithers ``(n, 3)`` (X, Y, N) of one experiment."""
    c = CLOSED_LOOP_TRIAL
    width = tuple(max(1, round(t / dt)) for t in c["hold"])
    lo, hi = c["vr"]
    sv, sr = [(1, 1), (1, -1), (-1, 1), (-1, -1)][experiment % 4]

    def steps(a: float, b: float) -> np.ndarray:
        n_seg = n // width[0] + 2
        widths = rng.integers(width[0], width[1] + 1, n_seg)
        return np.repeat(rng.uniform(a, b, n_seg), widths)[:n]

    ref = np.column_stack([steps(*c["u"]), sv * steps(lo, hi), sr * steps(lo, hi)])
    dith = rng.standard_normal((n, 3)) * np.array([c["dither"][j] for j in "XYN"])
    return ref, dith


def _simulate_env_closed_loop(experiments: int, samples: int, dt: float, dist, sensors,
                              seed: np.random.SeedSequence, vessel: str):
    """The closed-loop sea trial in ``vesselid/Manoeuvring3DOF-v0``: at every step the PI
    loops of :func:`closed_loop_trial_controller` act on the speed log (``u``, ``v``
    through the water) and the gyro (``r``), plus the dither; the recorder logs the
    references and dithers and declares the loop."""
    import gymnasium as gym

    import vesselid.envs  # noqa: F401  (registers the environments)
    from vesselid.data.logs import TrialLog
    from vesselid.envs.recorder import TrialRecorder
    from vesselid.plant.catalogue import vessel_module

    pid = closed_loop_trial_controller(dt, vessel)
    fmax = np.array(vessel_module(vessel).HULL.force_max, dtype=float)
    env = TrialRecorder(gym.make(
        "vesselid/Manoeuvring3DOF-v0", vessel=vessel, max_episode_steps=samples + 1, dt=dt,
        current_speed=dist.current_speed, current_direction=dist.current_direction,
        current_variation=dist.current_speed_std, wind_speed=dist.wind_speed,
        wind_direction=dist.wind_direction, wind_gust=dist.gust_std,
        force_noise=dist.force_noise_std, sensors=sensors, force_max=tuple(fmax)))
    frames = []
    env_seeds = seed.spawn(2)
    seeds = env_seeds[0].generate_state(experiments)
    rngs = [np.random.default_rng(s) for s in env_seeds[1].spawn(experiments)]
    meta: dict[str, Any] = {}
    for e in range(experiments):
        ref, dith = _closed_loop_signals(rngs[e], samples, e, dt)
        policy = pid.policy(env.model_spec)
        env.clear()
        env.declare_closed_loop(pid, reference={"u": "u_ref", "v": "v_ref", "r": "r_ref"},
                                dither={"X": "X_dither", "Y": "Y_dither", "N": "N_dither"})
        _, info = env.reset(seed=int(seeds[e]),
                            options={"nu": [float(ref[0, 0]), 0.0, 0.0], "eta": [0.0, 0.0, 0.0]})
        for k in range(samples):
            y = [float(info["speed_log"][0]), float(info["speed_log"][1]),
                 float(np.ravel(info["gyro"])[0])]
            tau = policy(y, ref[k], dith[k])
            env.annotate(u_ref=ref[k, 0], v_ref=ref[k, 1], r_ref=ref[k, 2],
                         X_dither=dith[k, 0], Y_dither=dith[k, 1], N_dither=dith[k, 2])
            _, _, _, _, info = env.step((np.asarray(tau) / fmax).astype(np.float32))
        log = env.to_log()
        fr = log.to_frame().iloc[:samples].reset_index(drop=True)
        fr["experiment"] = e
        fr["time"] = np.arange(len(fr)) * dt
        frames.append(fr)
        meta = log.metadata
    env.close()
    return TrialLog(pd.concat(frames, ignore_index=True), meta)


# ------------------------------------------------------------------------------ results
def markdown_table(df: pd.DataFrame, fmt: str = ".4f") -> str:
    """A pipe (GitHub) markdown table of ``df`` with its index (no tabulate needed)."""
    def cell(x: Any) -> str:
        if isinstance(x, (float, np.floating)):
            return format(float(x), fmt)
        return str(x)

    name = df.index.name or ""
    head = [str(name)] + [str(c) for c in df.columns]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] * len(head)) + "|"]
    for idx, row in df.iterrows():
        lines.append("| " + " | ".join([cell(idx)] + [cell(x) for x in row]) + " |")
    return "\n".join(lines)


def normalized_errors(params: pd.Series | np.ndarray, theta0: pd.Series) -> pd.Series:
    """``(θ̂ − θ0) / θ0`` per parameter (:func:`vesselid.identify.diagnostics.normalized_error`)."""
    from vesselid.identify.diagnostics import normalized_error

    return pd.Series(normalized_error(params, theta0.to_numpy()), index=theta0.index)


def free_run_nrmse(log, spec: ModelSpec, theta: np.ndarray) -> dict[str, float]:
    """Free-run (simulation) error of ``theta`` on ``log``, NRMSE % per state.

    ``100 ‖y − ŷ‖ / ‖y − ȳ‖`` pooled over the experiments of ``log`` (0 = perfect; the
    ratio is :func:`vesselid.identify.diagnostics.free_run_ratio`); ``inf`` for every state when
    the simulation of some experiment diverges.
    """
    from vesselid.identify.data import from_log
    from vesselid.identify.diagnostics import free_run_ratio

    data, spec = from_log(log, spec)
    ratio, all_ok = free_run_ratio(data, spec, theta)
    if not all_ok:
        return {st: float("inf") for st in spec.states}
    return {st: float(100.0 * ratio[i]) for i, st in enumerate(spec.states)}


@dataclass
class SeaTrialResult:
    """Outcome of :func:`run_pipeline`.

    Attributes
    ----------
    log, holdout : TrialLog
        Estimation log (``N_E`` experiments) and the held-out validation experiment.
    design : SeaTrialDesign
    results : dict method -> IdentificationResult
    comparison : DataFrame
        Per parameter: ``theta0``, and per method the estimate and its normalized error.
    validation : DataFrame
        Free-run NRMSE % on the held-out experiment, methods × states (plus ``theta0``).
    timings : dict
        Wall times (s) of the stages.
    """

    log: Any
    holdout: Any
    design: SeaTrialDesign
    spec: ModelSpec
    results: dict[str, Any]
    comparison: pd.DataFrame
    validation: pd.DataFrame
    timings: dict[str, float]

    def errors(self) -> pd.DataFrame:
        """Normalized errors, parameters × methods."""
        return self.comparison[[c for c in self.comparison.columns if c.startswith("err ")]]

    def thetas(self) -> dict[str, np.ndarray]:
        """θ0 and every estimate as flat vectors (for :mod:`vesselid.control.controllers`)."""
        out = {"theta0": self.spec.theta0_vector()}
        out.update({m: r.params.to_numpy() for m, r in self.results.items()})
        return out

    def summary(self) -> str:
        """Markdown tables: normalized errors, held-out NRMSE, design margins."""
        lines = [f"Sea trial: {self.design.n_experiments} experiments x "
                 f"{self.design.n_samples} samples, aggregate = "
                 f"{self.log.metadata.get('aggregate')}", "",
                 "Normalized errors (θ̂ − θ0)/θ0:", "",
                 markdown_table(self.errors(), ".4f"), "",
                 "Free-run NRMSE % on the held-out experiment:", "",
                 markdown_table(self.validation, ".2f"), ""]
        design = self.results[next(iter(self.results))].diagnostics["design"]
        bad = design[~design["ok"]]
        lines.append("Design margins (A10/A15) on the data: "
                     + ("all experiments and states OK" if bad.empty else
                        f"{len(bad)} violation(s):\n"
                        + markdown_table(bad.set_index("experiment"), ".3g")))
        lines.append("Timings (s): " + ", ".join(f"{k} {v:.2f}" for k, v in self.timings.items()))
        return "\n".join(lines)


def run_pipeline(
    experiments: int = 6,
    samples: int = 20000,
    seed: int | None = 0,
    *,
    methods: Sequence[str] = ("ls", "iv", "iv-zero-mean"),
    combine: str = "pooled",
    aggregate: str | None = "relative",
    holdout_samples: int | None = None,
    design: str | None = None,
    **simulation_options: Any,
) -> SeaTrialResult:
    """Design, simulate and identify a sea trial; validate on a held-out experiment.

    ``experiments + 1`` experiments are designed and simulated together; the last one (a
    different operating point) is held out and the estimates are validated by free-run
    simulation on it (:func:`free_run_nrmse`).

    Parameters
    ----------
    experiments, samples, seed
        As :func:`simulate_sea_trial`.
    methods : sequence of {"ls", "iv", "iv-zero-mean"}
    combine : {"pooled", "stacked"}
        Multi-experiment equations (6)/(10).
    aggregate : str or None
        As :func:`simulate_sea_trial`.
    holdout_samples : int, optional
        Length of the validation experiment used (default ``min(samples, 5000)``).
    design : {"planned", "static-offset"}, optional
        Input design (:data:`DESIGNS`; default planned for CyberShip II).
    **simulation_options
        Passed to :func:`simulate_sea_trial` (current, wind, sensors, design options).

    Returns
    -------
    SeaTrialResult
    """
    from vesselid.data.logs import TrialLog
    from vesselid.identify import identify

    t0 = time.perf_counter()
    design_keys = {"levels", "perturbation", "pulse_width", "warmup", "eta", "check", "plan",
                   "vessel"}
    design_opts = {k: simulation_options.pop(k) for k in list(simulation_options)
                   if k in design_keys}
    dt = float(simulation_options.pop("dt", 0.1))
    design_seed = np.random.SeedSequence(seed).spawn(2)[0]  # as simulate_sea_trial does
    design = _make_design(design, int(experiments) + 1, samples, dt, design_seed,
                          design_opts)
    full = simulate_sea_trial(seed=seed, design=design, aggregate=aggregate,
                              **simulation_options)
    t1 = time.perf_counter()
    frame = full.to_frame()
    is_test = frame["experiment"].to_numpy() == int(experiments)
    meta = dict(full.metadata, experiments=int(experiments))
    log = TrialLog(frame.loc[~is_test].reset_index(drop=True), meta)
    n_hold = min(int(samples), 5000) if holdout_samples is None else int(holdout_samples)
    holdout = TrialLog(frame.loc[is_test].iloc[:n_hold].reset_index(drop=True), full.metadata)
    spec = full.spec
    results: dict[str, Any] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for m in methods:
            results[m] = identify(log, spec, method=m, combine=combine)
    t2 = time.perf_counter()
    theta0 = spec.theta0_series()
    comp = pd.DataFrame({"theta0": theta0})
    for m, r in results.items():
        comp[f"est {m}"] = r.params.to_numpy()
    for m, r in results.items():
        comp[f"err {m}"] = normalized_errors(r.params, theta0).to_numpy()
    comp.index = [f"{eq}: {term}" for eq, term in theta0.index]
    val = {"theta0": free_run_nrmse(holdout, spec, theta0.to_numpy())}
    for m, r in results.items():
        val[m] = free_run_nrmse(holdout, spec, r.params.to_numpy())
    validation = pd.DataFrame(val).T
    validation.index.name = "model"
    t3 = time.perf_counter()
    return SeaTrialResult(
        log=log, holdout=holdout, design=design, spec=spec, results=results,
        comparison=comp, validation=validation,
        timings={"simulate": t1 - t0, "identify": t2 - t1, "validate": t3 - t2,
                 "total": t3 - t0},
    )
