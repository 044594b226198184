"""Monte Carlo study of term selection (``vesselid select``) against FROLS and STLSQ.

For every design, ``--runs`` independent logs are simulated with a current inside the
modulus (white or Gauss–Markov), and on each log:

* ``ivsel`` — :func:`vesselid.selection.select_terms` (IV stepwise selection, HAC Wald
  tests); base model (``--base``): every equation linear in the states and inputs
  (default), or the true structure (a user who knows the vessel's usual structure);
* ``frols`` — SysIdentPy's FROLS (error-reduction ratio, AIC for the number of terms) on
  the same candidate regressors of the same log (``pip install sysidentpy``);
* ``stlsq`` — PySINDy's STLSQ (its default threshold 0.1) on the same candidates
  (``pip install pysindy``).

A method finds the true structure in a run when the set of selected candidates, each
mapped to the candidate that represents it in that log (``|w| = w`` when ``w > 0``),
equals the set of true terms so mapped. Reported per design and method: the share of
runs with the true structure (with its binomial standard error), the share keeping every
true term, the largest share of runs keeping any one zero-coefficient candidate, the
share of runs with the *detectable* structure (every true term whose test has at least
95 % power at this length kept, no zero-coefficient candidate kept), and for ``ivsel``
the coverage of the 95 % intervals of ``identify(method="iv-zero-mean")`` on the
selected spec (runs with the true structure; HAC covariance; and, as
``coverage_no_zero_term``, over the kept true terms of every run that keeps no
zero-coefficient candidate) and of the same intervals on the true structure (the
oracle, first ``--oracle-runs`` runs). A comparator that is
not installed is skipped. Per true term: its keep rate by every method, the median
``|t|`` and the noncentrality ``|θ0|/SE`` of the oracle fit, the power of the
selection's test at this length and the log length at which it reaches 95 %, and the
oracle fit's bias (in Monte Carlo sd and standard errors) and mean SE over its spread.

Systems (``--system``): ``heave`` (1 × 30 000 samples); ``cybership2`` (the
catalogue's CyberShip II model with the pulse design :data:`CYBERSHIP_LEVELS`; length
``--experiments`` × ``--samples``, default 4 × 5 000); ``cybership2-planned`` (the same
vessel driven open loop by the trial planner's manoeuvres, :func:`planned_programmes`;
default 4 × 2 500); ``viknes830`` (the catalogue's Viknes 830 with its pulse design,
default 4 × 2 500); ``cybership2-squares`` (CyberShip II under two alternating
thruster squares, :data:`CYBERSHIP_SQUARES`, 4 × 125 000 samples: long enough for the
whole 25-term structure). ``--first library`` starts the selection from the library model
(``select_terms(first_model="library")``).

``--workers N`` runs the runs in ``N`` processes; every run is seeded from ``--seed``,
its design and its run index and computed single-threaded, so the tables do not depend
on ``N``, and ``--first-run``/``--runs`` chunks of one study summarise together with
``--from-csv``. ``--summary-out`` writes the acceptance figures as counts with 95 %
Wilson intervals; ``--comparators off`` skips FROLS and STLSQ (skipped anyway where
they are not installed). ``--scan-excitation`` compares CyberShip II input designs by the
noncentrality of the true terms instead of running the study.

    nice -n 10 python scripts/selection_study.py --runs 200 --system heave
    OMP_NUM_THREADS=1 nice -n 10 python scripts/selection_study.py --runs 200 \
        --system cybership2 --samples 2500 --oracle-runs 50 --power-out power.csv
    OMP_NUM_THREADS=1 nice -n 10 python scripts/selection_study.py --runs 200 \
        --system viknes830 --oracle-runs 50
    OMP_NUM_THREADS=1 nice -n 10 python scripts/selection_study.py --runs 200 \
        --system cybership2-planned --first library --oracle-runs 50
    nice -n 10 python scripts/selection_study.py --system cybership2-squares \
        --first library --runs 48 --oracle-runs 200 --workers 16 --comparators off \
        --out squares.csv --summary-out squares.json
"""

from __future__ import annotations

import argparse
import functools
import gc
import json
import math
import os
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

# one BLAS/OpenMP thread per process, set before numpy loads: every run is computed by the
# same single-threaded code whatever --workers is, so the results do not depend on it
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from vesselid.identify import identify  # noqa: E402
from vesselid.model.spec import ModelSpec  # noqa: E402
from vesselid.model.terms import Term  # noqa: E402
from vesselid.plant.disturbances import Gaussian, GaussMarkov  # noqa: E402
from vesselid.plant.signals import InputSignal  # noqa: E402
from vesselid.plant.systems import System, heave  # noqa: E402
from vesselid.selection import select_terms  # noqa: E402
from vesselid.selection.engine import library_factors, regressors  # noqa: E402
from vesselid.selection.library import canonical, resolve_library  # noqa: E402

if TYPE_CHECKING:
    from vesselid.plant.vessels.hull import Hull


# ----------------------------------------------------------------------------- designs
def _heave_system(current) -> System:
    base = heave(xi_mean=0.0, pulse_high=0.5)  # w stays positive (A10)
    return System(spec=base.spec.with_aggregate(None), inputs=base.inputs,
                  current={"w": current}, current_sign={"w": -1},
                  process_noise=base.process_noise, sensor_noise=base.sensor_noise,
                  x0=base.x0)


#: CyberShip II input design: random pulses (20–60 s) on static offsets, turns to
#: starboard in even and to port in odd experiments (paper §6 / A10: ``v`` and ``r``
#: keep their sign within an experiment, so the logs carry the merged structure of
#: :func:`vesselid.plant.vessels.cybership2.cybership2_system`), with wider sway-force and
#: yaw-moment ranges than the catalogue entry's so that the turn rate and drift vary
#: by a factor of several within every experiment.
CYBERSHIP_LEVELS = {"X": (1.0, 2.0), "Y": ((-0.6, 0.2), (-0.2, 0.6)),
                    "N": ((0.05, 0.45), (-0.45, -0.05))}


def _cybership_system(current_u, current_v) -> System:
    from vesselid.plant.signals import RandomPulses
    from vesselid.plant.vessels.cybership2 import cybership2_system

    base = cybership2_system()
    dt = base.spec.dt

    def pulses(level):
        lo, hi = round(20.0 / dt), round(60.0 / dt)
        if isinstance(level[0], tuple):
            return tuple(RandomPulses(a, b, lo, hi) for a, b in level)
        return RandomPulses(level[0], level[1], lo, hi)

    return System(spec=base.spec, inputs={k: pulses(v) for k, v in CYBERSHIP_LEVELS.items()},
                  current={"u": current_u, "v": current_v},
                  process_noise=base.process_noise, sensor_noise=base.sensor_noise,
                  x0=base.x0, model=base.model)


class _Schedule(InputSignal):
    """A fixed force schedule (one experiment of a planned trial) as an input design."""

    def __init__(self, values: np.ndarray, label: str) -> None:
        self.values = np.asarray(values, dtype=float)
        self.label = label

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        if n > self.values.size:
            raise ValueError(f"the schedule has {self.values.size} samples, {n} asked for")
        return self.values[:n].copy()

    def to_dict(self) -> dict:
        return {"kind": "schedule", "programme": self.label, "samples": int(self.values.size)}


@functools.lru_cache(maxsize=4)
def planned_programmes(samples: int, experiments: int) -> list:
    """The trial planner's manoeuvres for CyberShip II (:func:`vesselid.studies.planner.
    plan_trial`: blocks of half an experiment chosen to minimise the worst relative
    standard error of the full structure's parameters; thruster squares whose surge force
    alternates ahead/astern, so ``u``, ``v`` and ``r`` all change sign)."""
    from vesselid.studies.planner import plan_trial

    block = samples // 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plan = plan_trial(samples=samples * experiments, experiments=experiments,
                          block=block, evaluate_block=block, paths=0)
    return plan.programmes


def _cybership_planned_system(current_u, current_v, samples: int, experiments: int
                              ) -> System:
    """CyberShip II driven open loop by the planner's manoeuvres. ``u``, ``v`` and ``r``
    change sign within every experiment, so ``v*|r|`` and ``r*|v|`` are distinct in the
    logs: the true structure is the hull's full one (25 terms), not the merged one of
    steady turns."""
    from vesselid.plant.vessels.cybership2 import HULL, cybership2_system
    from vesselid.plant.vessels.kernel import VesselModel
    from vesselid.studies.manoeuvres import FORCE_LIMITS

    base = cybership2_system()
    x0 = [base.x0[s] for s in base.spec.states]
    vessel = VesselModel(HULL, base.spec.dt)
    forces = [prog.schedule(vessel, samples, x0=x0, limits=FORCE_LIMITS)
              for prog in planned_programmes(samples, experiments)]
    inputs = {name: tuple(_Schedule(f[:, j], prog_label) for f, prog_label in
                          zip(forces, (f"experiment {e}" for e in range(experiments)),
                              strict=True))
              for j, name in enumerate(base.spec.inputs)}
    return System(spec=base.spec, inputs=inputs, current={"u": current_u, "v": current_v},
                  process_noise=base.process_noise, sensor_noise=base.sensor_noise,
                  x0=base.x0)


def _viknes_system(current_u, current_v) -> System:
    """The catalogue's Viknes 830 (random pulses on static offsets, starboard and port
    turns in alternate experiments) with a current inside the modulus on ``u`` and ``v``."""
    from vesselid.plant.vessels.viknes830 import system as viknes830_system

    base = viknes830_system()
    return System(spec=base.spec, inputs=base.inputs,
                  current={"u": current_u, "v": current_v},
                  process_noise=base.process_noise, sensor_noise=base.sensor_noise,
                  x0=base.x0, model=base.model)


#: Viknes 830 thruster-square programmes, one per experiment: ``(hold_y, hold_n, hold_x)``
#: seconds of the sway-force, yaw-moment and ahead/astern engine reversals
#: (:class:`vesselid.studies.manoeuvres.ThrusterSquare`, full sway force and yaw moment,
#: engine ±6 kN).
VIKNES_SQUARES = ((10.0, 7.0, 30.0), (7.0, 10.0, 15.0), (5.0, 3.5, 30.0), (10.0, 7.0, 15.0))


def _viknes_manoeuvre_system(current_u, current_v, samples: int, experiments: int
                             ) -> System:
    """Viknes 830 driven open loop by thruster squares (:data:`VIKNES_SQUARES`): ``u``,
    ``v`` and ``r`` change sign within every experiment and the yaw moment reverses
    faster than the yaw rate settles, so ``r`` and ``N`` (and their products with ``u``)
    differ in the logs."""
    from vesselid.plant.vessels.viknes830 import HULL
    from vesselid.plant.vessels.viknes830 import system as viknes830_system

    return _squares_system(viknes830_system(), HULL, VIKNES_SQUARES, (6000.0, 600.0, 2500.0),
                           None, current_u, current_v, samples, experiments)


def _squares_system(base: System, hull: Hull, squares: tuple, forces: tuple,
                    limits: tuple | None, current_u, current_v, samples: int,
                    experiments: int) -> System:
    """``base`` (its spec, noises and start) driven open loop by thruster squares, one
    ``(hold_y, hold_n, hold_x)`` of ``squares`` per experiment in turn, with ``forces``
    ``(thrust, sway, moment)`` and the actuator ``limits`` (None: none), under the
    currents ``current_u``, ``current_v``."""
    from vesselid.plant.vessels.kernel import VesselModel
    from vesselid.studies.manoeuvres import Programme, ThrusterSquare

    x0 = [base.x0[s] for s in base.spec.states]
    vessel = VesselModel(hull, base.spec.dt)
    thrust, sway, moment = forces
    schedules = []
    for e in range(experiments):
        hy, hn, hx = squares[e % len(squares)]
        prog = Programme([ThrusterSquare(thrust=thrust, sway=sway, moment=moment,
                                         hold_y=hy, hold_n=hn, hold_x=hx, low=-1.0)])
        schedules.append((prog.schedule(vessel, samples, x0=x0, limits=limits),
                          prog.label()))
    inputs = {name: tuple(_Schedule(f[:, j], label) for f, label in schedules)
              for j, name in enumerate(base.spec.inputs)}
    return System(spec=base.spec, inputs=inputs, current={"u": current_u, "v": current_v},
                  process_noise=base.process_noise, sensor_noise=base.sensor_noise,
                  x0=base.x0)


#: CyberShip II thruster squares of the long design, one per experiment in turn:
#: ``(hold_y, hold_n, hold_x)`` seconds of the sway-force, yaw-moment and full ahead /
#: full astern engine reversals (two of the trial planner's candidates,
#: :func:`vesselid.studies.planner.candidate_library`; forces at the actuator limits).
CYBERSHIP_SQUARES = ((10.0, 7.0, 30.0), (7.0, 10.0, 15.0))
#: Samples per experiment of the long design (4 experiments): the length at which the
#: weakest true terms, ``v: v*|r|`` and ``v: r*|v|``, reach the noncentrality for
#: 99.5 % power each (see the term-selection guide).
CYBERSHIP_SQUARES_SAMPLES = 125_000


def _cybership_squares_system(current_u, current_v, samples: int, experiments: int
                              ) -> System:
    """CyberShip II driven open loop by thruster squares (:data:`CYBERSHIP_SQUARES`,
    alternating between experiments): ``u``, ``v`` and ``r`` change sign within every
    experiment and ``v``, ``r`` take equal and opposite signs, so the true structure is
    the hull's full one (25 terms). Per sample these squares carry about 2.5 times the
    information on ``v: v*|r|`` and ``v: r*|v|`` of the trial planner's mix
    (:func:`planned_programmes`)."""
    from vesselid.plant.vessels.cybership2 import HULL, cybership2_system
    from vesselid.studies.manoeuvres import FORCE_LIMITS

    return _squares_system(cybership2_system(), HULL, CYBERSHIP_SQUARES, FORCE_LIMITS,
                           FORCE_LIMITS, current_u, current_v, samples, experiments)


SYSTEMS = ("heave", "cybership2", "cybership2-planned", "cybership2-squares", "viknes830",
           "viknes830-manoeuvres")
#: Seed index of the designs added on request (their runs' seeds do not depend on which
#: other designs are run); the others take their position in :func:`designs`.
SEED_INDEX = {"CyberShip II squares, white current": 10,
              "CyberShip II squares, Gauss-Markov current": 11}


def system_key(design: str) -> str:
    """The ``--system`` name of a design."""
    if design.startswith("CyberShip II planned"):
        return "cybership2-planned"
    if design.startswith("CyberShip II squares"):
        return "cybership2-squares"
    if design.startswith("CyberShip"):
        return "cybership2"
    if design.startswith("Viknes 830 manoeuvres"):
        return "viknes830-manoeuvres"
    if design.startswith("Viknes"):
        return "viknes830"
    return "heave"


def designs(quick: bool, samples: int | None = None, experiments: int | None = None,
            planned: bool = False, manoeuvres: bool = False, squares: bool = False) -> dict:
    """name -> (system, samples per experiment, experiments, library).

    ``samples``/``experiments`` override the CyberShip II log length (default 4 × 5 000
    samples at 0.1 s; ``quick``: 4 × 1 000).
    """
    dt = 0.1
    n_h = 3000 if quick else 30000
    n_c = int(samples) if samples else (1000 if quick else 5000)
    n_v = int(samples) if samples else (1000 if quick else 2500)
    k_c = int(experiments) if experiments else 4
    out = {
        "heave, white current": (_heave_system(Gaussian(0.0, 0.1)), n_h, 1, "vessel"),
        "heave, Gauss-Markov current": (
            _heave_system(GaussMarkov(0.0, 0.05, 5.0, 1.0, 0.15)), n_h, 1, "vessel"),
    }

    def small() -> tuple:  # CyberShip II (model scale): the currents in u and v
        return Gaussian(0.0, 0.005), Gaussian(0.0, 0.005)

    def small_gm() -> tuple:
        return (GaussMarkov(0.0, 0.002, 1.0, dt, 0.006),
                GaussMarkov(0.0, 0.002, 1.0, dt, 0.006))

    def full() -> tuple:  # Viknes 830 (full scale)
        return Gaussian(0.0, 0.05), Gaussian(0.0, 0.05)

    def full_gm() -> tuple:
        return GaussMarkov(0.0, 0.02, 1.0, dt, 0.06), GaussMarkov(0.0, 0.02, 1.0, dt, 0.06)

    def both(label: str, build, n: int, white, coloured) -> None:
        """The design ``label`` under a white and under a Gauss–Markov current
        (``build(current_u, current_v)``: its system)."""
        out[f"{label}, white current"] = (build(*white()), n, k_c, "vessel")
        out[f"{label}, Gauss-Markov current"] = (build(*coloured()), n, k_c, "vessel")

    both("CyberShip II", _cybership_system, n_c, small, small_gm)
    both("Viknes 830", _viknes_system, n_v, full, full_gm)
    if planned:  # the planner runs only when these designs are asked for
        n_p = int(samples) if samples else (1000 if quick else 2500)
        both("CyberShip II planned",
             lambda cu, cv: _cybership_planned_system(cu, cv, n_p, k_c), n_p, small, small_gm)
    if squares:
        n_s = int(samples) if samples else (2500 if quick else CYBERSHIP_SQUARES_SAMPLES)
        both("CyberShip II squares",
             lambda cu, cv: _cybership_squares_system(cu, cv, n_s, k_c), n_s, small, small_gm)
    if manoeuvres:
        both("Viknes 830 manoeuvres",
             lambda cu, cv: _viknes_manoeuvre_system(cu, cv, n_v, k_c), n_v, full, full_gm)
    return out


def linear_base(spec: ModelSpec) -> ModelSpec:
    """Every equation linear in all states and inputs (the first auxiliary model)."""
    return ModelSpec(spec.name, spec.states, spec.inputs,
                     {s: list(spec.signals) for s in spec.states}, dt=spec.dt)


# ------------------------------------------------------------------------- comparators
def _frols(phi: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    try:
        from sysidentpy.model_structure_selection import FROLS
    except ImportError:
        return None
    from sysidentpy.parameter_estimation import LeastSquares

    p = phi.shape[1]
    model = FROLS(order_selection=True, info_criteria="aic", n_info_values=min(p, 20),
                  ylag=1, xlag=1, estimator=LeastSquares())
    n_info = min(p, 20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # the ERR drops the first max_lag (= 1) target rows: give it one more
        y_lag = np.concatenate([y[:1], y]).reshape(-1, 1)
        # FROLS.information_criterion reruns the greedy ERR for every model size; its
        # order is greedy (the first i pivots do not depend on how many are asked for),
        # so one ERR pass and the same per-size fit and criterion give the same values
        _, piv, _ = model.error_reduction_ratio(phi, y_lag, n_info)
        target = model._default_estimation_target(y_lag)
        n_samples = y_lag.shape[0] - model.max_lag
        ic = np.empty(n_info)
        for i in range(n_info):
            reg = phi[:, np.asarray(piv[:i + 1], dtype=int)]
            theta = model.estimator.optimize(reg, target)
            e_var = float(np.var(target - reg @ theta, ddof=1))
            ic[i] = model.info_criteria_function(i + 1, n_samples, e_var)
        n_terms = int(np.nanargmin(ic)) + 1
    out = np.zeros(p, dtype=bool)
    out[np.asarray(piv[:n_terms], dtype=int)] = True
    return out


def _stlsq(phi: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    try:
        import pysindy as ps
    except ImportError:
        return None
    opt = ps.STLSQ()  # defaults: threshold 0.1, alpha 0.05
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opt.fit(phi, y)
    return np.abs(np.asarray(opt.coef_).ravel()) > 0


# --------------------------------------------------------------------------------- run
def one_run(system: System, n: int, k: int, library: str, seed, oracle: bool = True,
            base: str = "linear", first: str = "base", comparators: bool = True
            ) -> list[dict]:
    sim = system.simulate(n, k, seed=seed)
    log = sim.to_log(aggregate=False)
    truth = system.model if system.model is not None else system.spec
    truth = truth.with_aggregate(None)
    base = linear_base(truth) if base == "linear" else truth
    lib = resolve_library(library, linear_base(truth))
    rows: list[dict] = []
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = select_terms(log, base, lib, n_boot=0, first_model=first)
    secs = time.perf_counter() - t0
    tab = res.table
    rep = {(r.equation, r.term): (r.represented_by or r.term) for r in tab.itertuples()}
    theta0 = truth.theta0_series()
    true_rep = {s: {rep[(s, str(canonical(t)))] for t in truth.equations[s]}
                for s in truth.states}
    selections: dict[str, dict[str, set]] = {"ivsel": {s: {rep[(s, t)] for t in res.selected[s]}
                                                       for s in truth.states}}
    if comparators:
        # the candidate regressors of the log for the comparators (rows k -> target k)
        from vesselid.identify.data import from_log

        lin = linear_base(truth)
        data, _ = from_log(log, lin)
        union, cols = library_factors(lib, lin)
        phi = regressors(data, union, lin)
        ok = np.isfinite(phi).all(axis=1)
        for name, fn in (("frols", _frols), ("stlsq", _stlsq)):
            picked: dict[str, set] = {}
            for i, s in enumerate(truth.states):
                sel = fn(phi[ok][:, cols[s]], data.target[ok, i])
                if sel is None:  # not installed: skipped
                    picked = {}
                    break
                picked[s] = {rep[(s, str(union[cols[s][j]]))] for j in np.flatnonzero(sel)}
            if picked:
                selections[name] = picked
        del phi
    # oracle: |t| of the true terms in the IV fit of the true structure
    t_oracle = None
    oracle_hits = None
    if oracle:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                fit_true = identify(log, truth, "iv-zero-mean")
                se_true = np.sqrt(np.diag(fit_true.cov))
                t_oracle = (fit_true.params / se_true).abs()
                err = np.abs(fit_true.params.to_numpy() - theta0.loc[fit_true.params.index]
                             .to_numpy())
                oracle_hits = pd.Series(err <= 1.959964 * se_true, index=fit_true.params.index)
            except Exception:
                t_oracle = None
    # ivsel up to the pairs the log cannot tell apart (the table's ``undecided``): a kept
    # zero term reported as undecided with a true term stands for that true term
    either = {s: set(selections["ivsel"][s]) for s in truth.states}
    for x in tab.itertuples():
        if not (x.selected and getattr(x, "undecided", "")):
            continue
        s, j = x.equation, rep[(x.equation, x.term)]
        alts = [rep[(s, a.strip())] for a in str(x.undecided).split(",")]
        true_alts = [a for a in alts if a in true_rep[s] and a not in either[s]]
        if j not in true_rep[s] and true_alts:
            either[s].discard(j)
            either[s].add(true_alts[0])
    for method, picked in selections.items():
        exact = all(picked[s] == true_rep[s] for s in truth.states)
        row = {"method": method, "exact": exact,
               "all_true_kept": all(true_rep[s] <= picked[s] for s in truth.states),
               "seconds": secs if method == "ivsel" else math.nan,
               "critical_value": res.critical_value, "n_candidates": res.n_candidates,
               "n_rows": res.n_samples - res.n_experiments}
        for s in truth.states:
            for cand in sorted({rep[(s, str(t))] for t in lib[s]}):
                row[f"keep|{s}|{cand}"] = cand in picked[s]
                row[f"true|{s}|{cand}"] = cand in true_rep[s]
            for t in truth.equations[s]:  # each true term, through its representative
                row[f"tkeep|{s}|{t}"] = rep[(s, str(canonical(t)))] in picked[s]
            if method == "ivsel":
                for cand in sorted({rep[(s, str(t))] for t in lib[s]}):
                    row[f"ukeep|{s}|{cand}"] = cand in either[s]
                for t in truth.equations[s]:
                    row[f"utkeep|{s}|{t}"] = rep[(s, str(canonical(t)))] in either[s]
        if method == "ivsel":
            row["exact_undecided"] = all(either[s] == true_rep[s] for s in truth.states)
        no_false = all(picked[s] <= true_rep[s] for s in truth.states)
        fit = None
        same = t_oracle is not None and all(
            sorted(str(canonical(t)) for t in res.spec.equations[s])
            == sorted(str(canonical(t)) for t in truth.equations[s]) for s in truth.states)
        if method == "ivsel" and no_false and same:
            # the selected spec is the true structure: its fit is the oracle's (one fit)
            row["covered"], row["intervals"] = int(oracle_hits.sum()), int(oracle_hits.size)
            row["covered_kept"], row["intervals_kept"] = row["covered"], row["intervals"]
        elif method == "ivsel" and no_false:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    fit = identify(log, res.spec, "iv-zero-mean")
                except ValueError:  # the selected structure cannot be fitted: no intervals
                    row["fit_failed"] = True
        if fit is not None:
            se = np.sqrt(np.diag(fit.cov))
            hits = 0
            total = 0
            for (s, term), est, sd in zip(fit.params.index, fit.params.to_numpy(), se,
                                          strict=True):
                true_terms = [t for t in truth.equations[s]
                              if rep[(s, str(canonical(t)))] == term]
                if len(true_terms) != 1:
                    continue
                th0 = float(theta0[(s, str(true_terms[0]))])
                sign = _sign(Term.parse(term), true_terms[0], log, s)
                hits += int(abs(est - sign * th0) <= 1.959964 * sd)
                total += 1
            if exact:
                row["covered"], row["intervals"] = hits, total
            # every kept term true (true terms below the power bound may be missing)
            row["covered_kept"], row["intervals_kept"] = hits, total
        if t_oracle is not None and method == "ivsel":
            for (s, term), tv in t_oracle.items():
                row[f"oracle_t|{s}|{term}"] = float(tv)
                row[f"oracle_se|{s}|{term}"] = float(se_true[
                    list(fit_true.params.index).index((s, term))])
                row[f"oracle_cover|{s}|{term}"] = bool(oracle_hits[(s, term)])
                row[f"oracle_est|{s}|{term}"] = float(fit_true.params[(s, term)])
        rows.append(row)
    return rows


def _sign(chosen: Term, true: Term, log, state: str) -> float:
    """+1 or −1: the representative equals ± the true term on this log."""
    if str(canonical(chosen)) == str(canonical(true)):
        return 1.0
    spec = ModelSpec("s", log.spec.states, log.spec.inputs, {s: [chosen, true] if s == state
                                                              else [Term.parse(s)]
                                                              for s in log.spec.states})
    from vesselid.identify.data import from_log

    data, _ = from_log(log, spec)
    phi = regressors(data, [chosen, true], spec)
    ok = np.isfinite(phi).all(axis=1)
    return float(np.sign(np.sum(phi[ok, 0] * phi[ok, 1])))


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    out = []
    for (design, method), g in df.groupby(["design", "method"], sort=False):
        n = len(g)
        p = g["exact"].mean()
        keep_cols = [c for c in g.columns if c.startswith("keep|") and g[c].notna().any()]
        kept = {c: g[c].fillna(False).to_numpy(dtype=bool) for c in keep_cols}
        true = {c: g[c.replace("keep|", "true|")].fillna(False).to_numpy(dtype=bool)
                for c in keep_cols}
        # share of all runs keeping a candidate that stands for no true term in any run
        false_rates = [float(kept[c].mean()) for c in keep_cols if not true[c].any()]
        row = {"design": design, "method": method, "runs": n,
               "true_structure": p, "se": math.sqrt(max(p * (1 - p), 1e-12) / n),
               "all_true_kept": g["all_true_kept"].mean(),
               "max_false_keep": max(false_rates) if false_rates else math.nan,
               "true_terms_kept": float(np.mean(sum(
                   (kept[c] & true[c]).astype(int) for c in keep_cols))),
               "false_terms_kept": float(np.mean(sum(
                   (kept[c] & ~true[c]).astype(int) for c in keep_cols)))}
        if "covered" in g and g["intervals"].sum() > 0:
            cov = g["covered"].sum() / g["intervals"].sum()
            row["coverage"] = cov
            row["coverage_se"] = math.sqrt(cov * (1 - cov) / g["intervals"].sum())
            row["intervals"] = int(g["intervals"].sum())
        if "covered_kept" in g and g["intervals_kept"].sum() > 0:
            cov = g["covered_kept"].sum() / g["intervals_kept"].sum()
            row["coverage_no_zero_term"] = cov
            row["coverage_no_zero_term_se"] = math.sqrt(cov * (1 - cov)
                                                        / g["intervals_kept"].sum())
            row["intervals_no_zero_term"] = int(g["intervals_kept"].sum())
        if method == "ivsel":
            row["median_seconds"] = float(g["seconds"].median())
        out.append(row)
    return pd.DataFrame(out)


def power_table(df: pd.DataFrame, truth: ModelSpec, n_rows: int, n_candidates: int,
                alpha: float = 0.01) -> pd.DataFrame:
    """Per true term: θ0, the median oracle ``|t|`` and the noncentrality ``δ = |θ0| /
    median SE`` of the IV fit of the true structure, the keep rate of every method, the
    oracle interval coverage, the oracle's bias (``oracle_bias_sd``: in Monte Carlo sd of
    its estimate; ``oracle_bias_z``: in its Monte Carlo standard errors, ``bias/(sd/√R)``)
    and its mean standard error over that sd (``oracle_se_over_sd``),
    the power of the selection's test at this length (normal
    approximation, ``P(|N(δ, 1)| ≥ c)``) and the log length (samples, all experiments)
    at which that power reaches 95 % (``δ`` grows like ``√n``; the critical value's
    ``√log n`` part is followed). The oracle estimates are the per-run table's
    ``oracle_est|`` columns; a table written without them gives them as
    ``sign(θ0)·|t|·SE`` for terms whose ``|t|`` is at least 4 in every run (the sign of
    the estimate is then that of θ0 in every run but with a chance below 10⁻⁴)."""
    from statistics import NormalDist

    from vesselid.selection.engine import critical_value

    nd = NormalDist()
    crit = critical_value(alpha, n_candidates, n_rows)
    iv = df[df.method == "ivsel"]
    theta0 = truth.theta0_series()
    rows = []
    for s in truth.states:
        for t in truth.equations[s]:
            kc, oc, cc = f"tkeep|{s}|{t}", f"oracle_t|{s}|{t}", f"oracle_cover|{s}|{t}"
            sc = f"oracle_se|{s}|{t}"
            t_med = float(iv[oc].median()) if oc in iv and iv[oc].notna().any() else math.nan
            # noncentrality: |θ0| over the median standard error (the median |t| of a
            # term whose θ0 is far below its SE is that of noise, ≈ 0.67)
            delta = (abs(float(theta0[(s, str(t))])) / float(iv[sc].median())
                     if sc in iv and iv[sc].notna().any() else math.nan)
            power = nd.cdf(delta - crit) + nd.cdf(-delta - crit) if math.isfinite(delta) \
                else math.nan
            n95 = math.nan
            if math.isfinite(delta) and delta > 0:
                n95 = float(n_rows)
                for _ in range(50):  # fixed point of δ·√(n/n_rows) = c(n) + z_0.95
                    need = critical_value(alpha, n_candidates, int(min(n95, 1e15))) + 1.644854
                    n95 = n_rows * (need / delta) ** 2
            bias_sd, bias_z, se_sd = _oracle_bias(iv, s, str(t), float(theta0[(s, str(t))]))
            rows.append({
                "equation": s, "term": str(t), "theta0": float(theta0[(s, str(t))]),
                **{f"kept_{m}": (float(df[df.method == m][kc].mean()) if kc in df
                                 else math.nan) for m in df.method.unique()},
                "oracle_median_t": t_med, "noncentrality": delta,
                "oracle_coverage": (float(iv[cc].dropna().astype(float).mean())
                                    if cc in iv and iv[cc].notna().any() else math.nan),
                "oracle_bias_sd": bias_sd, "oracle_bias_z": bias_z,
                "oracle_se_over_sd": se_sd,
                "power": power, "samples_for_95pct_power": n95})
    return pd.DataFrame(rows)


def _oracle_bias(iv: pd.DataFrame, s: str, t: str, theta0: float
                 ) -> tuple[float, float, float]:
    """Bias of the oracle estimate of term ``t`` of equation ``s`` over the runs that fit
    it: in Monte Carlo sd, and in Monte Carlo standard errors; and the mean standard
    error over that sd (:func:`power_table`)."""
    ec, tc, sc = f"oracle_est|{s}|{t}", f"oracle_t|{s}|{t}", f"oracle_se|{s}|{t}"
    if ec in iv and iv[ec].notna().any():
        est = iv[ec].dropna().to_numpy(float)
    elif tc in iv and sc in iv and iv[tc].notna().any() and float(iv[tc].min()) >= 4:
        ok = iv[tc].notna() & iv[sc].notna()
        est = math.copysign(1.0, theta0) * (iv[tc][ok] * iv[sc][ok]).to_numpy(float)
    else:
        return math.nan, math.nan, math.nan
    sd = float(est.std(ddof=1)) if est.size > 1 else 0.0
    if sd == 0:
        return math.nan, math.nan, math.nan
    bias = float(est.mean()) - theta0
    se = float(iv[sc].dropna().mean()) if sc in iv else math.nan
    return bias / sd, bias / (sd / math.sqrt(est.size)), se / sd


def detectable_structure(df: pd.DataFrame, power: pd.DataFrame, prefix: str = ""
                         ) -> dict[str, float]:
    """Per method: share of runs that keep every true term whose power at this length is
    at least 95 % and no zero-coefficient candidate (true terms below that power may be
    kept or dropped). ``prefix="u"``: the selection read up to the pairs the log cannot
    tell apart (``ukeep|``/``utkeep|`` columns, ``select`` only)."""
    det = [f"{prefix}tkeep|{r.equation}|{r.term}" for r in power.itertuples()
           if r.power >= 0.95]
    keep_cols = [c for c in df.columns if c.startswith(f"{prefix}keep|")]
    out = {}
    for m, g in df.groupby("method", sort=False):
        if prefix and not all(c in g and g[c].notna().any() for c in det):
            continue
        ok = np.ones(len(g), dtype=bool)
        for c in det:
            ok &= g[c].fillna(False).to_numpy(dtype=bool)
        for c in keep_cols:  # a candidate that stands for no true term in that run
            kept = g[c].fillna(False).to_numpy(dtype=bool)
            true = g["true|" + c.split("|", 1)[1]].fillna(False).to_numpy(dtype=bool)
            ok &= ~(kept & ~true)
        out[m] = float(ok.mean())
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--quick", action="store_true", help="short logs (development)")
    ap.add_argument("--system", choices=SYSTEMS, action="append",
                    help="only the designs of this system (default: all)")
    ap.add_argument("--design", action="append", help="only these designs (substring)")
    ap.add_argument("--samples", type=int,
                    help="CyberShip II samples per experiment (default 5000)")
    ap.add_argument("--experiments", type=int,
                    help="CyberShip II experiments (default 4)")
    ap.add_argument("--out", type=Path, help="write the per-run table (CSV)")
    ap.add_argument("--power-out", type=Path,
                    help="write the per-term table (keep rates, oracle |t|, power) (CSV)")
    ap.add_argument("--base", choices=("linear", "true"), default="linear",
                    help="base model of the selection (its first auxiliary model): every "
                         "equation linear in the states and inputs (default), or the true "
                         "structure (a user who knows the vessel's usual structure)")
    ap.add_argument("--first", choices=("base", "library"), default="base",
                    help="auxiliary model of the first pass (select_terms' first_model): "
                         "the base model, or every candidate fitted by IV from the base "
                         "model's instruments")
    ap.add_argument("--first-run", type=int, default=0,
                    help="skip the runs before this one (continue a study cut short: "
                         "the same seeds; summarise both tables with --from-csv)")
    ap.add_argument("--from-csv", type=Path, action="append",
                    help="summarise the per-run table(s) written by --out instead of "
                         "simulating")
    ap.add_argument("--oracle-runs", type=int, default=25,
                    help="runs that also fit the true structure for the oracle |t|")
    ap.add_argument("--workers", type=int, default=1,
                    help="processes running the runs in parallel (each run seeded from "
                         "--seed, the design and its run index, computed single-threaded: "
                         "the results do not depend on this number)")
    ap.add_argument("--comparators", choices=("auto", "off"), default="auto",
                    help="FROLS and STLSQ on the same logs when installed (auto), or not")
    ap.add_argument("--summary-out", type=Path,
                    help="write the summary with 95 %% Wilson intervals (.json, else CSV)")
    ap.add_argument("--scan-excitation", choices=("white", "gauss-markov"),
                    help="instead of the study: the weakest terms' noncentrality at 10^6 "
                         "samples per CyberShip II input design (--runs logs of "
                         "--experiments x --samples each; writes --power-out)")
    args = ap.parse_args(argv)
    if args.scan_excitation:
        tab = scan_excitation(args.samples or 25_000, args.experiments or 4, args.runs,
                              "white" if args.scan_excitation == "white" else "gm", args.seed)
        if args.power_out:
            _write_csv(tab, args.power_out)
        return 0
    if args.workers < 1:
        ap.error(f"--workers must be at least 1, got {args.workers}")
    frames, powers, summaries, jobs = [], [], [], []
    loaded = None
    if args.from_csv:
        loaded = pd.concat([pd.read_csv(f, low_memory=False) for f in args.from_csv],
                           ignore_index=True).copy()
        if "base" not in loaded:
            loaded["base"] = "linear"
        loaded["base"] = loaded["base"].fillna("linear").astype(str).str.lower()
    for d_i, (name, (system, n, k, library)) in enumerate(
            designs(args.quick, args.samples, args.experiments,
                    planned=bool(args.system and "cybership2-planned" in args.system),
                    squares=bool(args.system and "cybership2-squares" in args.system),
                    manoeuvres=bool(args.system and "viknes830-manoeuvres" in args.system)
                    ).items()):
        key = system_key(name)
        if args.system and key not in args.system:
            continue
        if args.design and not any(s in name for s in args.design):
            continue
        truth = (system.model or system.spec).with_aggregate(None)
        if loaded is not None:
            for base, df in loaded[loaded.design == name].groupby("base", sort=False):
                df = _from_table(df, loaded[(loaded.design == name)
                                            & (loaded.method == "ivsel")])
                frames.append(df)
                print(f"{name}, base {base}:")
                powers.append(report(df, name, truth))
                summaries.append(summary_table(df, powers[-1]))
            continue
        jobs.append((name, SEED_INDEX.get(name, d_i), system, n, k, library, truth))
    opts = {"seed": args.seed, "oracle_runs": args.oracle_runs, "base": args.base,
            "first": args.first, "comparators": args.comparators == "auto"}
    if jobs:
        for name, df in run_designs(jobs, opts, range(args.first_run, args.runs),
                                    args.workers, args.out, frames):
            truth = next(j[6] for j in jobs if j[0] == name)
            frames.append(df)
            power = report(df, name, truth)
            powers.append(power)
            summaries.append(summary_table(df, power))
    if args.out and frames and loaded is None:
        _write_csv(pd.concat(frames, ignore_index=True), args.out)
    if args.power_out and powers:
        _write_csv(pd.concat(powers, ignore_index=True), args.power_out)
    if args.summary_out and summaries:
        _write_summary(pd.concat(summaries, ignore_index=True), args.summary_out)
    return 0


# ------------------------------------------------------------------ excitation scan
#: Thruster squares compared by :func:`scan_excitation` ``(hold_y, hold_n, hold_x, low)``
#: (the planner's candidates with the engine reversing, two with longer or shorter holds
#: and one half-astern engine).
SCAN_SQUARES = ((5.0, 3.5, 30.0, -1.0), (7.0, 10.0, 15.0, -1.0), (10.0, 7.0, 30.0, -1.0),
                (20.0, 14.0, 60.0, -1.0), (3.5, 5.0, 20.0, -1.0), (15.0, 10.0, 30.0, -0.5))


def scan_excitation(samples: int, experiments: int, runs: int, current: str,
                    seed: int = 7) -> pd.DataFrame:
    """Per CyberShip II input design (the planner's mix, each of :data:`SCAN_SQUARES` in
    every experiment, and :data:`CYBERSHIP_SQUARES` alternating): the noncentrality
    ``|θ0| / SE`` of every true term in the IV fit of the true structure
    (``identify(method="iv-zero-mean")``, median SE over ``runs`` logs), scaled to 10⁶
    samples (``δ ∝ √n``). The weakest terms decide how long a trial must be."""
    from vesselid.plant.vessels.cybership2 import HULL, cybership2_system
    from vesselid.plant.vessels.kernel import VesselModel
    from vesselid.studies.manoeuvres import FORCE_LIMITS, Programme, ThrusterSquare

    base = cybership2_system()
    x0 = [base.x0[s] for s in base.spec.states]
    vessel = VesselModel(HULL, base.spec.dt)
    cur = ((Gaussian(0.0, 0.005), Gaussian(0.0, 0.005)) if current == "white" else
           (GaussMarkov(0.0, 0.002, 1.0, 0.1, 0.006), GaussMarkov(0.0, 0.002, 1.0, 0.1, 0.006)))

    def square(hy, hn, hx, low):
        return Programme([ThrusterSquare(thrust=FORCE_LIMITS[0], sway=FORCE_LIMITS[1],
                                         moment=FORCE_LIMITS[2], hold_y=hy, hold_n=hn,
                                         hold_x=hx, low=low)])

    designs_ = {"planner's mix": planned_programmes(samples, experiments)}
    for q in SCAN_SQUARES:
        designs_[square(*q).label()] = [square(*q)] * experiments
    designs_["alternating " + " / ".join(f"{hy:g}-{hn:g}-{hx:g} s" for hy, hn, hx in
                                        CYBERSHIP_SQUARES)] = [
        square(*CYBERSHIP_SQUARES[e % len(CYBERSHIP_SQUARES)], -1.0)
        for e in range(experiments)]
    rows = []
    for label, progs in designs_.items():
        forces = [p.schedule(vessel, samples, x0=x0, limits=FORCE_LIMITS) for p in progs]
        inputs = {name: tuple(_Schedule(f[:, j], label) for f in forces)
                  for j, name in enumerate(base.spec.inputs)}
        system = System(spec=base.spec, inputs=inputs, current={"u": cur[0], "v": cur[1]},
                        process_noise=base.process_noise, sensor_noise=base.sensor_noise,
                        x0=base.x0)
        truth = system.spec.with_aggregate(None)
        theta0 = truth.theta0_series()
        ses = []
        for r in range(runs):
            log = system.simulate(samples, experiments,
                                  seed=np.random.SeedSequence([seed, r])).to_log(aggregate=False)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fit = identify(log, truth, "iv-zero-mean")
            ses.append(np.sqrt(np.diag(fit.cov)))
        se = pd.Series(np.median(ses, axis=0), index=fit.params.index)
        delta = theta0.loc[se.index].abs() / se * math.sqrt(1e6 / (samples * experiments))
        for (eq, term), d in delta.sort_values().items():
            rows.append({"design": label, "current": current, "equation": eq, "term": term,
                         "noncentrality_1e6": float(d)})
        weak = delta.sort_values()[:2]
        print(f"{label}: " + ", ".join(f"{e}: {t} {d:.2f}" for (e, t), d in weak.items()),
              flush=True)
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------- parallel runs
#: (name, design index, system, samples, experiments, library, truth) of the designs being
#: run and the run options: set before the worker processes fork (or by their initializer)
_JOBS: dict[str, tuple] = {}
_OPTS: dict = {}


def run_seed(seed: int, design_index: int, run: int) -> np.random.SeedSequence:
    """The seed of one run: child ``run`` of ``SeedSequence([seed, design_index])`` (the
    same as ``.spawn(runs)[run]``), so a run's log does not depend on which process runs
    it or on how many runs are asked for."""
    return np.random.SeedSequence([seed, design_index], spawn_key=(run,))


def _init_worker(jobs: dict, opts: dict) -> None:
    _JOBS.update(jobs)
    _OPTS.update(opts)


def _one_task(name: str, run: int) -> list[dict]:
    """Every method's row of run ``run`` of design ``name`` (serial kernels)."""
    from vesselid.core.threads import serial_here

    _, d_i, system, n, k, library, _ = _JOBS[name]
    o = _OPTS
    cpu = time.process_time()
    with serial_here():
        rows = one_run(system, n, k, library, run_seed(o["seed"], d_i, run),
                       oracle=run < o["oracle_runs"], base=o["base"], first=o["first"],
                       comparators=o["comparators"])
    cpu = time.process_time() - cpu
    label = o["base"] if o["first"] == "base" else f"{o['base']}+library"
    for row in rows:
        row.update(design=name, run=run, base=label, cpu_seconds=cpu)
    return rows


def _fork_context():
    import multiprocessing

    if "fork" in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("fork")
    return None


def run_designs(jobs: list[tuple], opts: dict, runs: range, workers: int,
                out: Path | None = None, done: list | None = None):
    """Run ``runs`` of every design in ``jobs`` on ``workers`` processes and yield
    ``(name, per-run table)`` per design, rows in run order (the same table whatever
    ``workers``). ``out``: the finished runs so far are written there every 10 runs."""
    table = {j[0]: j for j in jobs}
    tasks = [(j[0], r) for j in jobs for r in runs]
    results: dict[tuple[str, int], list[dict]] = {}
    t0 = time.perf_counter()
    last = [0]

    def finished(key: tuple[str, int], rows: list[dict]) -> None:
        results[key] = rows
        count = len(results)
        if count % 10 == 0 or count == len(tasks) or time.perf_counter() - last[0] > 30:
            last[0] = time.perf_counter()
            print(f"  {count} of {len(tasks)} runs, {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr, flush=True)
            if out is not None:  # the runs so far, so that a long study can be cut short
                _write_csv(pd.concat([*(done or []), pd.DataFrame(
                    [r for key in sorted(results) for r in results[key]])],
                    ignore_index=True), out)

    _JOBS.clear()
    _JOBS.update(table)
    _OPTS.clear()
    _OPTS.update(opts)
    if workers <= 1 or len(tasks) <= 1:
        for key in tasks:
            finished(key, _one_task(*key))
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        ctx = _fork_context()
        # forked workers inherit the designs (and any kernel loaded here); elsewhere
        # each worker receives them once through its initializer
        kw = ({"mp_context": ctx} if ctx is not None else
              {"initializer": _init_worker, "initargs": (table, opts)})
        gc.collect()
        gc.freeze()  # the parent's objects stay out of the workers' collections
        try:
            with warnings.catch_warnings(), ProcessPoolExecutor(min(workers, len(tasks)),
                                                                **kw) as pool:
                warnings.filterwarnings("ignore", message=".*fork.*",
                                        category=DeprecationWarning)
                futures = {pool.submit(_one_task, *key): key for key in tasks}
                for fut in as_completed(futures):
                    finished(futures[fut], fut.result())
        finally:
            gc.unfreeze()
    for j in jobs:
        rows = [r for run in runs for r in results[(j[0], run)]]
        print(f"{j[0]}: {len(runs)} runs, {j[4]} x {j[3]} samples, "
              f"{time.perf_counter() - t0:.0f} s wall, {workers} worker(s)", file=sys.stderr)
        yield j[0], pd.DataFrame(rows)


# --------------------------------------------------------------------------- summary
def wilson(k: float, n: float, z: float = 1.959964) -> tuple[float, float]:
    """95 % Wilson score interval of a binomial share ``k / n``."""
    if n <= 0:
        return math.nan, math.nan
    p = k / n
    den = 1.0 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, mid - half), min(1.0, mid + half)


def summary_table(df: pd.DataFrame, power: pd.DataFrame) -> pd.DataFrame:
    """The acceptance figures of one design as counts with 95 % Wilson intervals, one row
    per (method, measure): ``true_structure`` (every true term kept, no other),
    ``all_true_kept``, ``worst_zero_term`` (runs keeping the zero-coefficient candidate
    kept most often, named in ``term``), ``detectable_structure``, ``coverage`` (the
    95 % intervals of ``identify(method="iv-zero-mean")`` on the selected spec, runs with
    the true structure), ``coverage_no_zero_term``; for ``oracle`` (the IV fit of the true
    structure, runs with ``--oracle-runs``): ``true_structure`` (every true ``|t|`` at
    least the selection's critical value: the ceiling of any rule with that critical
    value on these logs), ``detectable_structure`` and ``coverage``."""
    rows = []
    name = str(df["design"].iloc[0])
    base = str(df["base"].iloc[0]) if "base" in df else ""

    def add(method, measure, k, n, term=""):
        lo, hi = wilson(float(k), float(n))
        rows.append({"design": name, "base": base, "method": method, "measure": measure,
                     "term": term, "count": int(k), "runs": int(n),
                     "share": (k / n if n else math.nan), "wilson_lo": lo, "wilson_hi": hi})

    def flag(g, c):
        return g[c].map({True: True, False: False, "True": True, "False": False}
                        ).fillna(False).to_numpy(dtype=bool)

    det_terms = [f"{r.equation}|{r.term}" for r in power.itertuples() if r.power >= 0.95]
    for method, g in df.groupby("method", sort=False):
        n = len(g)
        add(method, "true_structure", int(g["exact"].astype(bool).sum()), n)
        add(method, "all_true_kept", int(g["all_true_kept"].astype(bool).sum()), n)
        keep_cols = [c for c in g.columns if c.startswith("keep|") and g[c].notna().any()]
        worst, worst_k = "", -1
        det_ok = np.ones(n, dtype=bool)
        for c in keep_cols:
            kept = flag(g, c)
            true = flag(g, "true|" + c.split("|", 1)[1])
            det_ok &= ~(kept & ~true)
            if not true.any() and int(kept.sum()) > worst_k:
                worst, worst_k = c.split("|", 1)[1].replace("|", ": ", 1), int(kept.sum())
        if worst_k >= 0:
            add(method, "worst_zero_term", worst_k, n, worst)
        for t in det_terms:
            if f"tkeep|{t}" in g:
                det_ok &= flag(g, f"tkeep|{t}")
        add(method, "detectable_structure", int(det_ok.sum()), n)
        for col, measure in (("covered", "coverage"), ("covered_kept", "coverage_no_zero_term")):
            tot = col.replace("covered", "intervals")
            if col in g and g[tot].sum() > 0:
                add(method, measure, int(g[col].sum()), int(g[tot].sum()))
    iv = df[df.method == "ivsel"]
    t_cols = [c for c in iv.columns if c.startswith("oracle_t|")]
    if t_cols and "critical_value" in iv:
        ot = iv[t_cols].dropna()
        if len(ot):
            crit = iv.loc[ot.index, "critical_value"].to_numpy()[:, None]
            add("oracle", "true_structure", int((ot.abs().to_numpy() >= crit).all(axis=1).sum()),
                len(ot))
            det_t = [f"oracle_t|{t}" for t in det_terms if f"oracle_t|{t}" in ot]
            if det_t:
                add("oracle", "detectable_structure",
                    int((ot[det_t].abs().to_numpy() >= crit).all(axis=1).sum()), len(ot))
    oc = [c for c in iv.columns if c.startswith("oracle_cover|")]
    if oc:
        hits = iv[oc].stack().dropna().map(
            {True: 1, False: 0, "True": 1, "False": 0}).astype(float)
        if hits.size:
            add("oracle", "coverage", int(hits.sum()), int(hits.size))
    if "cpu_seconds" in iv and iv["cpu_seconds"].notna().any():
        rows.append({"design": name, "base": base, "method": "ivsel",
                     "measure": "median_cpu_seconds_per_run", "term": "", "count": 0,
                     "runs": int(iv["cpu_seconds"].notna().sum()),
                     "share": float(iv["cpu_seconds"].median()), "wilson_lo": math.nan,
                     "wilson_hi": math.nan})
    return pd.DataFrame(rows)


def _write_summary(summary: pd.DataFrame, path: Path) -> None:
    """The summary as JSON (``.json``: a list of records) or CSV, whole or not at all."""
    with pd.option_context("display.width", 250):
        print(summary.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    if path.suffix.lower() == ".json":
        tmp = path.with_name(path.name + ".tmp")
        recs = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                 for k, v in r.items()} for r in summary.to_dict(orient="records")]
        tmp.write_text(json.dumps(recs, indent=1) + "\n")
        tmp.replace(path)
    else:
        _write_csv(summary, path)


def _write_csv(df: pd.DataFrame, path: Path) -> None:
    """Write ``df`` to ``path`` whole or not at all (temporary file, then rename)."""
    tmp = path.with_name(path.name + ".tmp")
    df.to_csv(tmp, index=False, compression="gzip" if path.suffix == ".gz" else None)
    tmp.replace(path)


def _from_table(df: pd.DataFrame, oracle_rows: pd.DataFrame) -> pd.DataFrame:
    """One design and base of a per-run table read back: booleans restored, and oracle
    columns this table lacks taken from another table of the same design and seeds (the
    oracle fits the true structure on the same log, whatever the base)."""
    df = df.dropna(axis=1, how="all").reset_index(drop=True).copy()
    for c in [c for c in df.columns if c.startswith(("keep|", "true|", "tkeep|", "ukeep|",
                                                     "utkeep|"))]:
        df[c] = df[c].map({True: True, False: False, "True": True, "False": False})
    iv = df.method == "ivsel"
    for c in [c for c in oracle_rows.columns if c.startswith("oracle_")]:
        if c in df and df.loc[iv, c].notna().any():
            continue
        src = oracle_rows.dropna(subset=[c]).drop_duplicates("run").set_index("run")[c]
        df[c] = np.where(iv, df["run"].map(src), np.nan)
    return df


def report(df: pd.DataFrame, name: str, truth: ModelSpec) -> pd.DataFrame:
    """Print the summary and the per-term table of one design; return the latter."""
    iv = df[df.method == "ivsel"]
    power = power_table(df, truth, int(iv["n_rows"].iloc[0]), int(iv["n_candidates"].iloc[0]))
    summary = summarise(df)
    det = detectable_structure(df, power)
    summary["detectable_structure"] = summary["method"].map(det)
    det_u = detectable_structure(df, power, prefix="u")
    if det_u:  # select, with the pairs it reports as undecided read either way
        summary["detectable_up_to_undecided"] = summary["method"].map(det_u)
        if "exact_undecided" in iv and iv["exact_undecided"].notna().any():
            summary.loc[summary.method == "ivsel", "true_structure_up_to_undecided"] = float(
                iv["exact_undecided"].map({True: True, False: False, "True": True,
                                           "False": False}).mean())
    # the same tests on the oracle fit (the true structure, first --oracle-runs runs):
    # share of runs whose |t| reaches the critical value for every detectable true term
    # (the most a rule with this critical value can reach on these logs)
    det_t = [f"oracle_t|{r.equation}|{r.term}" for r in power.itertuples() if r.power >= 0.95]
    if det_t and all(c in iv for c in det_t):
        from vesselid.selection.engine import critical_value

        crit = critical_value(0.01, int(iv["n_candidates"].iloc[0]), int(iv["n_rows"].iloc[0]))
        ot = iv[det_t].dropna()
        if len(ot):
            summary.loc[summary.method == "ivsel", "oracle_detectable"] = float(
                (ot.abs() >= crit).all(axis=1).mean())
            summary.loc[summary.method == "ivsel", "oracle_runs"] = len(ot)
    oc = [c for c in iv.columns if c.startswith("oracle_cover|")]
    if oc:
        hits = iv[oc].stack().dropna().astype(float)
        summary.loc[summary.method == "ivsel", "oracle_coverage"] = float(hits.mean())
        summary.loc[summary.method == "ivsel", "oracle_intervals"] = int(hits.size)
    with pd.option_context("display.width", 250):
        print(summary.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
        print(power.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    sys.stdout.flush()
    power.insert(0, "design", name)
    if "base" in df:
        power.insert(1, "base", df["base"].iloc[0])
    return power


if __name__ == "__main__":
    raise SystemExit(main())
