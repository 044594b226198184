"""Calibration of the reported uncertainty: Monte Carlo coverage of confidence intervals.

A covariance estimator is calibrated when the nominal 95 % intervals
``θ̂ ± 1.96 SE`` cover θ0 in 95 % of independent runs. :func:`coverage_study`
simulates a scenario many times, estimates every run on the batched fast path,
computes each run's covariance exactly as :func:`vesselid.identify.identify` does
(:func:`group_covariances`, the same :mod:`~vesselid.identify.covariance` call on the
same instruments and residuals), and :func:`coverage_table` reports per parameter
the coverage with its Wilson interval and the ratio of the reported standard error
to the Monte Carlo spread.

Scenarios (:data:`SCENARIOS`): the paper's heave vehicle (§6) with the Table 1 design
(alternating and random pulses), Table 2 (current measured, relative target), a
Gauss–Markov current (time constant 25 samples) and Gauss–Markov sensor noise
(time constant 20 samples), each with both pulse designs; and ``"seatrial"``, the
CyberShip II sea trial a user gets from :func:`vesselid.studies.seatrial.simulate_sea_trial`
(:func:`seatrial_coverage`).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from vesselid.core import seeds
from vesselid.errors import VesselidError
from vesselid.identify import kernels
from vesselid.identify.covariance import DEFAULT_COV_TYPE, get_covariance_estimator
from vesselid.identify.data import RegressionData, from_arrays
from vesselid.model.regressors import weights_matrix
from vesselid.model.spec import ModelSpec

__all__ = [
    "SCENARIOS",
    "coverage_identify",
    "coverage_study",
    "coverage_table",
    "group_covariances",
    "heave_scenario",
    "one_group",
    "wilson_interval",
]


def wilson_interval(successes: Any, trials: Any, level: float = 0.95) -> tuple[Any, Any]:
    """Wilson score interval for a binomial proportion (vectorised)."""
    k = np.asarray(successes, dtype=float)
    n = np.asarray(trials, dtype=float)
    zq = stats.norm.ppf(0.5 + level / 2)
    p = k / n
    den = 1 + zq**2 / n
    centre = (p + zq**2 / (2 * n)) / den
    half = zq * np.sqrt(p * (1 - p) / n + zq**2 / (4 * n**2)) / den
    return centre - half, centre + half


def heave_scenario(name: str):
    """``(System, aggregate, target)`` of a heave calibration scenario (:data:`SCENARIOS`)."""
    from vesselid.plant.disturbances import GaussMarkov
    from vesselid.plant.systems import heave

    if name not in SCENARIOS:
        raise KeyError(f"unknown scenario {name!r}; choose from {list(SCENARIOS)}")
    kind, design = SCENARIOS[name]
    if kind == "table2":
        return heave(current_mean=0.1, pulse_design=design), True, "aggregated"
    system = heave(pulse_design=design)
    if kind == "gm-current":
        system = dataclasses.replace(system, current={"w": GaussMarkov(0.0, 0.1, 25.0)})
    elif kind == "gm-sensor":
        system = dataclasses.replace(system, sensor_noise={"w": GaussMarkov(0.0, 0.1, 20.0)})
    return system, False, "measured"


#: Heave scenarios: name -> (disturbance setting, pulse design). Noise levels of §6
#: (std 0.1); the Gauss–Markov processes have the same stationary std as the white
#: ones they replace.
SCENARIOS: dict[str, tuple[str, str]] = {
    "table1-alternating": ("table1", "alternating"),
    "table1-random": ("table1", "random"),
    "table2": ("table2", "alternating"),
    "gm-current-alternating": ("gm-current", "alternating"),
    "gm-current-random": ("gm-current", "random"),
    "gm-sensor-alternating": ("gm-sensor", "alternating"),
    "gm-sensor-random": ("gm-sensor", "random"),
}


def group_covariances(
    data: RegressionData,
    spec: ModelSpec,
    theta: np.ndarray,
    theta_aux: np.ndarray | None,
    *,
    method: str = "iv-zero-mean",
    combine: str = "pooled",
    cov_type: str = DEFAULT_COV_TYPE,
    **cov_config: Any,
) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Covariance of every group's estimate (batched Monte Carlo data).

    ``theta`` (G, P) are the estimates, ``theta_aux`` the auxiliary models whose
    simulated instruments gave them (refined IV; ignored for LS). Groups whose
    estimate is not finite get NaN.

    Returns
    -------
    cov : ndarray (G, P, P)
    configs : list of dict
        The covariance settings used per group (e.g. the bandwidth).
    """
    est = get_covariance_estimator(cov_type, **cov_config)
    codes = spec.codes
    n_par = spec.n_params
    out = np.full((data.n_groups, n_par, n_par), np.nan)
    configs: list[dict[str, Any]] = [{} for _ in range(data.n_groups)]
    for g in range(data.n_groups):
        if not np.all(np.isfinite(theta[g])):
            continue
        sl, starts = data.group_rows(g)
        a, b = sl.start, sl.stop
        phi = kernels.regressor_matrix(data.regsig[sl], data.u[sl], starts, codes.factors)
        if method == "ls":
            z = phi
        else:
            z, _ = kernels.instrument_matrix(data.target[sl], data.u[sl], starts,
                                             theta_aux[g], codes.factors, codes.equation,
                                             spec.n_states)
        zero_mean = method == "iv-zero-mean"
        weights = weights_matrix(codes, theta[g])
        rows = np.ones(b - a, dtype=bool)
        rows[starts[:-1]] = False
        resid = data.target[sl] - np.where(rows[:, None], phi, 0.0) @ weights
        z = np.where(rows[:, None], z, 0.0)
        if zero_mean:
            for s in range(starts.size - 1):
                r = slice(int(starts[s]) + 1, int(starts[s + 1]))
                z[r] -= z[r].mean(axis=0)
        if not np.all(np.isfinite(z[rows])):
            continue
        # the refined IV's intervals take the fixed-b critical value, as in ``identify``
        res = est.estimate(z, np.where(rows[:, None], phi, 0.0), resid, starts, codes.equation,
                           zero_mean=zero_mean, combine=combine, fixed_b_square=method != "ls")
        out[g] = res.cov
        configs[g] = dict(res.config)
    return out, configs


def coverage_table(
    theta: np.ndarray,
    std_errors: np.ndarray,
    theta0: np.ndarray,
    names: list[str],
    *,
    level: float = 0.95,
) -> pd.DataFrame:
    """Per parameter: coverage of ``θ̂ ± z SE`` with Wilson interval, SE / MC spread.

    ``se_ratio`` is the RMS standard error over the Monte Carlo standard deviation;
    ``se_ratio_robust`` the median SE over the IQR-based spread (``IQR/1.349``), which
    a few runs with very large errors or SEs do not dominate; ``kurtosis`` the
    (non-excess) kurtosis of the errors.

    Runs with a non-finite estimate or standard error are left out (``runs`` counts
    the ones used).
    """
    zq = stats.norm.ppf(0.5 + level / 2)
    rows = []
    for p, name in enumerate(names):
        ok = np.isfinite(theta[:, p]) & np.isfinite(std_errors[:, p])
        err = theta[ok, p] - theta0[p]
        se = std_errors[ok, p]
        n = int(ok.sum())
        hits = int(np.sum(np.abs(err) <= zq * se))
        lo, hi = wilson_interval(hits, n, level) if n else (np.nan, np.nan)
        sd = float(np.std(err, ddof=1)) if n > 1 else np.nan
        rows.append({
            "parameter": name,
            "runs": n,
            "coverage": hits / n if n else np.nan,
            "wilson_low": float(lo),
            "wilson_high": float(hi),
            "se_rms": float(np.sqrt(np.mean(se**2))) if n else np.nan,
            "mc_sd": sd,
            "se_ratio": float(np.sqrt(np.mean(se**2)) / sd) if n > 1 and sd > 0 else np.nan,
            # robust to a few runs with huge errors / SEs: median SE over the IQR-based spread
            "se_ratio_robust": float(np.median(se) / (np.subtract(*np.percentile(err, [75, 25]))
                                                      / 1.349)) if n > 3 else np.nan,
            "bias_z": float(np.mean(err) / sd * math.sqrt(n)) if n > 1 and sd > 0 else np.nan,
            # non-excess kurtosis of the errors (3 for Gaussian): the sampling error of
            # log(mc_sd) is √((κ − 1)/(4n))
            "kurtosis": float(stats.kurtosis(err, fisher=False)) if n > 3 else np.nan,
        })
    return pd.DataFrame(rows)


def coverage_study(
    scenario: str,
    runs: int,
    *,
    samples: int = 10_000,
    seed: int = 0,
    method: str | None = None,
    covariances: Mapping[str, tuple[str, Mapping[str, Any]]] | None = None,
    estimate_fn: Callable[..., Any] | None = None,
    batch: int | None = None,
    fit: str = "batched",
    experiments: int = 6,
    design: str | None = None,
) -> pd.DataFrame:
    """Coverage of a scenario for one or several covariance estimators.

    Parameters
    ----------
    scenario : str
        Key of :data:`SCENARIOS`, or ``"seatrial"``: the CyberShip II sea trial as
        :func:`vesselid.studies.seatrial.simulate_sea_trial` gives it by default (``design``),
        ``experiments × samples`` per run with the study's current, wind, gusts and
        unmodelled forces, the anemometer's wind load among the forces, identified with
        the relative predictor (speed log); :func:`seatrial_coverage`.
    runs, samples, seed : int
        Monte Carlo runs, samples per run (experiment), root seed (run ``r`` uses
        child ``r``).
    method : str, optional
        Estimator (default: the package default, :func:`default_method`); with the
        estimator registry its batched ``estimate_parameters`` and, per run, the
        ``equation_designs`` its ``fit`` uses (:func:`registry_covariances`).
    covariances : mapping label -> (cov_type, cov_config)
        Default: the package default only.
    estimate_fn : callable, optional
        ``estimate_fn(data, spec) -> IterationResult``; default
        ``estimate(data, spec, method)``.
    batch : int, optional
        Runs simulated (and, batched, estimated) at a time; default 200 heave runs or
        1 sea trial (one trial per batch keeps its final design rows while estimating,
        so its covariance needs no second estimation).
    fit : {"batched", "identify"}
        ``"batched"``: the batched fast path above; ``"identify"``: one trial log per
        run through the public :func:`vesselid.identify.identify` (the user's path;
        default method unless ``method``; no ``method`` column, no ``estimate_fn``).
    experiments : int
        Experiments per sea trial.
    design : str, optional
        Sea-trial input design (:data:`vesselid.studies.seatrial.DESIGNS`; default: the default of
        :func:`vesselid.studies.seatrial.simulate_sea_trial`, planned for CyberShip II).

    Returns
    -------
    DataFrame
        :func:`coverage_table` rows with ``scenario`` and ``covariance`` columns.
    """
    if fit not in ("batched", "identify"):
        raise VesselidError(f"fit must be 'batched' or 'identify', got {fit!r}")
    if fit == "identify" and estimate_fn is not None:
        raise VesselidError("estimate_fn goes with fit='batched', not 'identify'")
    sea = scenario == "seatrial"
    batch = int(batch or (1 if sea else 200))
    covariances = covariances or {DEFAULT_COV_TYPE: (DEFAULT_COV_TYPE, {})}
    if fit == "identify":
        return _coverage_identify(scenario, runs, samples, experiments, seed, method,
                                  covariances, batch, design)
    method = method or default_method()
    batches: Iterator[RegressionData]
    if sea:
        spec, n_e, trials = _seatrial_trials(runs, samples, experiments, seed, design)
        batches = (_trials_data(spec, n_e, list(itertools.islice(trials, batch)))
                   for _ in range(0, int(runs), batch))
    else:
        system, aggregate, target = heave_scenario(scenario)
        spec = system.identification_spec(aggregate=aggregate)
        batches = (_heave_data(spec, sim, aggregate, target)
                   for sim in _heave_batches(system, runs, samples, seed, batch))
    thetas: list[np.ndarray] = []
    ses: dict[str, list[np.ndarray]] = {k: [] for k in covariances}
    for data in batches:
        _estimate_batch(data, spec, method, covariances, estimate_fn, thetas, ses)
    return _coverage_frames(np.vstack(thetas), ses, spec, scenario, method)


def seatrial_coverage(runs: int, **options: Any) -> pd.DataFrame:
    """Coverage on the CyberShip II sea trial: :func:`coverage_study` of ``"seatrial"``
    (``samples`` 20 000 unless given)."""
    options.setdefault("samples", 20_000)
    return coverage_study("seatrial", runs, **options)


def _heave_data(spec: ModelSpec, sim: Any, aggregate: bool, target: str) -> RegressionData:
    """The regression data of a batch of heave runs (one group a run)."""
    data = from_arrays(spec, sim.y, sim.u, y2=sim.y2 if aggregate else None)
    if target == "aggregated":
        data = dataclasses.replace(data, target=data.regsig)
    return data


def _trials_data(spec: ModelSpec, n_e: int,
                 trials: list[tuple[np.ndarray, np.ndarray]]) -> RegressionData:
    """The regression data of a batch of sea trials (one group a trial)."""
    y = np.concatenate([yt for yt, _ in trials])
    tau = np.concatenate([tt for _, tt in trials])
    return from_arrays(spec, y, tau, experiments_per_group=n_e)


def _heave_batches(system: Any, runs: int, samples: int, seed: int, batch: int) -> Iterator[Any]:
    """``runs`` simulations of ``system`` (run ``r`` on child ``r`` of ``seed``), ``batch``
    runs at a time."""
    seeds = np.random.SeedSequence(seed).spawn(int(runs))
    for c in range(0, int(runs), batch):
        yield system.simulate(int(samples), run_seeds=seeds[c:c + batch])


def _seatrial_trials(
    runs: int, samples: int, experiments: int, seed: int, design: str | None = None,
) -> tuple[ModelSpec, int, Iterator[tuple[np.ndarray, np.ndarray]]]:
    """The calibration sea trial: its spec, experiments per trial and the states and forces,
    each (experiments, samples, 3), of ``runs`` independent trials, exactly as a user gets
    them from :func:`vesselid.studies.seatrial.simulate_sea_trial` with its defaults (the default
    design — planned for CyberShip II —, the study's current, wind, gusts and unmodelled
    forces, the speed-log predictor and the anemometer's wind load among the forces).

    ``design`` names another input design (:data:`vesselid.studies.seatrial.DESIGNS`). The design
    is built once (as ``simulate_sea_trial(seed=seed, design=design)`` builds it); run
    ``r`` simulates it with its own seed, run ``r`` of the study's own root seed (``seed + 2000``,
    :data:`vesselid.core.seeds.STUDY_OFFSETS`)."""
    from vesselid.studies.seatrial import _make_design, simulate_sea_trial

    trial = _make_design(design, int(experiments), int(samples), 0.1,
                         np.random.SeedSequence(seed).spawn(2)[0], {})
    n_e = trial.n_experiments
    first = simulate_sea_trial(seed=_run_seed(seed, 0), design=trial)
    spec = first.spec

    def arrays(log: Any) -> tuple[np.ndarray, np.ndarray]:
        frame = log.to_frame()
        shape = (n_e, trial.n_samples, -1)
        return (frame[list(spec.states)].to_numpy(float).reshape(shape),
                frame[list(spec.inputs)].to_numpy(float).reshape(shape))

    def trials() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        yield arrays(first)
        for r in range(1, int(runs)):
            yield arrays(simulate_sea_trial(seed=_run_seed(seed, r), design=trial))

    return spec, n_e, trials()


def _run_seed(seed: int, run: int) -> int:
    """Integer seed of sea-trial run ``run``: run ``run`` of the study's own root seed
    (:func:`vesselid.core.seeds.study_seed`)."""
    child = seeds.run_seeds(seeds.study_seed(seed, "calibration-seatrial"), int(run) + 1)[-1]
    return int(child.generate_state(1, np.uint64)[0])


def _estimate_batch(
    data: RegressionData,
    spec: ModelSpec,
    method: str,
    covariances: Mapping[str, tuple[str, Mapping[str, Any]]],
    estimate_fn: Callable[..., Any] | None,
    thetas: list[np.ndarray],
    ses: dict[str, list[np.ndarray]],
) -> None:
    """Estimate a batch of runs on the batched fast path and append the estimates to
    ``thetas`` and each covariance estimator's standard errors to ``ses``: through the
    estimator registry (:func:`registry_covariances`) unless ``estimate_fn`` is given
    (or the registry is missing), else ``estimate_fn(data, spec)`` (default
    ``estimate(data, spec, method)``) with :func:`group_covariances`."""
    if _has_registry() and estimate_fn is None:
        from vesselid.identify.registry import get_estimator

        # one group: keep the final design rows now (registry_covariances would otherwise
        # estimate again to get them; the estimates are the same)
        it = get_estimator(method).estimate_parameters(data, spec,
                                                       keep_history=data.n_groups == 1)
        thetas.append(it.theta)
        for label, se in registry_covariances(data, spec, it, method, covariances).items():
            ses[label].append(se)
        return
    from vesselid.identify.estimators import estimate

    it = (estimate_fn(data, spec) if estimate_fn is not None
          else estimate(data, spec, method))
    thetas.append(it.theta)
    for label, (cov_type, cfg) in covariances.items():
        cov, _ = group_covariances(data, spec, it.theta, it.theta_aux, method=method,
                                   cov_type=cov_type, **dict(cfg))
        ses[label].append(np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None)))


def _coverage_frames(
    theta: np.ndarray,
    ses: Mapping[str, Any],
    spec: ModelSpec,
    scenario: str,
    method: str | None = None,
) -> pd.DataFrame:
    """:func:`coverage_table` of every covariance estimator (the keys of ``ses``, each a
    list of (runs, P) blocks), with ``scenario``, ``covariance`` and (given) ``method``
    columns."""
    names = [f"{eq}: {term}" for eq, term in spec.param_index]
    frames = []
    for label, blocks in ses.items():
        tab = coverage_table(theta, np.vstack(blocks), spec.theta0_vector(), names)
        tab.insert(0, "covariance", label)
        tab.insert(0, "scenario", scenario)
        if method is not None:
            tab.insert(2, "method", method)
        frames.append(tab)
    return pd.concat(frames, ignore_index=True)


# ------------------------------------------------------------------ through identify()
def _identify_runs(
    frames: list[pd.DataFrame],
    spec: ModelSpec,
    covariances: Mapping[str, tuple[str, Mapping[str, Any]]],
    method: str | None,
    target: str,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Fit every run's log with the public ``identify`` (the user's path), once per
    covariance estimator. Failed fits give NaN rows."""
    import warnings

    from vesselid.identify import identify

    n_par = spec.n_params
    theta = np.full((len(frames), n_par), np.nan)
    ses = {k: np.full((len(frames), n_par), np.nan) for k in covariances}
    for r, frame in enumerate(frames):
        for first, (label, (cov_type, cfg)) in enumerate(covariances.items()):
            kw: dict[str, Any] = {"target": target, "cov_type": cov_type,
                                  "cov_config": dict(cfg)}
            if method is not None:
                kw["method"] = method
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    res = identify(frame, spec, **kw)
            except ValueError:
                continue
            if first == 0:
                theta[r] = res.params.to_numpy()
            ses[label][r] = res.std_errors.to_numpy()
    return theta, ses


def coverage_identify(scenario: str, runs: int, **options: Any) -> pd.DataFrame:
    """:func:`coverage_study` with ``fit="identify"`` (through the public
    :func:`vesselid.identify.identify`; ``batch`` 100 unless given)."""
    options.setdefault("batch", 100)
    return coverage_study(scenario, runs, fit="identify", **options)


def _coverage_identify(
    scenario: str, runs: int, samples: int, experiments: int, seed: int, method: str | None,
    covariances: Mapping[str, tuple[str, Mapping[str, Any]]], batch: int,
    design: str | None = None,
) -> pd.DataFrame:
    """:func:`coverage_study`'s ``fit="identify"``."""
    theta_all: list[np.ndarray] = []
    ses_all: dict[str, list[np.ndarray]] = {k: [] for k in covariances}
    runs_frames: Iterator[list[pd.DataFrame]]
    if scenario == "seatrial":
        spec, _, trials = _seatrial_trials(runs, samples, experiments, seed, design)
        target = "measured"
        runs_frames = ([_trial_frame(spec, y, tau)] for y, tau in trials)
    else:
        system, aggregate, target = heave_scenario(scenario)
        spec = system.identification_spec(aggregate=aggregate)
        runs_frames = ([_run_frame(spec, system, sim, r, aggregate) for r in range(sim.n_runs)]
                       for sim in _heave_batches(system, runs, samples, seed, batch))
    for frames in runs_frames:
        th, se = _identify_runs(frames, spec, covariances, method, target)
        theta_all.append(th)
        for k in covariances:
            ses_all[k].append(se[k])
    return _coverage_frames(np.vstack(theta_all), ses_all, spec, scenario)


def _trial_frame(spec: ModelSpec, y: np.ndarray, tau: np.ndarray) -> pd.DataFrame:
    """A trial log of experiments ``y``, ``tau`` (E, N, ·) in ``spec``'s column names."""
    n_e, n_k = y.shape[0], y.shape[1]
    cols: dict[str, np.ndarray] = {"experiment": np.repeat(np.arange(n_e), n_k)}
    for i, s in enumerate(spec.states):
        cols[s] = y[:, :, i].ravel()
    for j, s in enumerate(spec.inputs):
        cols[s] = tau[:, :, j].ravel()
    return pd.DataFrame(cols)


def _run_frame(spec: ModelSpec, system: Any, sim: Any, r: int, aggregate: bool) -> pd.DataFrame:
    """The trial log of run ``r`` of a heave simulation (with the current sensor's column
    when ``aggregate``)."""
    cols = {s: sim.y[r, :, i] for i, s in enumerate(spec.states)}
    cols |= {s: sim.u[r, :, j] for j, s in enumerate(spec.inputs)}
    for j, s in enumerate(system.sensor_states):
        if aggregate:
            cols[system.sensor_name(s)] = sim.y2[r, :, j]
    return pd.DataFrame(cols)


# ------------------------------------------------------------------ registry estimators
def _has_registry() -> bool:
    try:
        import vesselid.identify.registry  # noqa: F401
    except ImportError:
        return False
    return True


def default_method() -> str:
    """The package's default estimator (``iv-zero-mean`` before the registry existed)."""
    try:
        from vesselid.identify.registry import DEFAULT_METHOD
    except ImportError:  # pragma: no cover - older layout
        return "iv-zero-mean"
    return str(DEFAULT_METHOD)


def one_group(data: RegressionData, it: Any, g: int) -> tuple[RegressionData, Any]:
    """Group ``g`` of a batch as a one-group batch.

    Returns its regression data and its slice of the batched estimate ``it`` (an
    :class:`~vesselid.identify.estimators.IterationResult`; its history left out), as
    the checked one-group path holds them."""
    sl, starts = data.group_rows(g)
    n_seg = starts.size - 1
    sub = dataclasses.replace(
        data, target=data.target[sl], regsig=data.regsig[sl], u=data.u[sl],
        starts=starts, group=np.zeros(n_seg, np.int64),
        n_groups=1, experiment_ids=tuple(range(n_seg)),
        sensor=None if data.sensor is None else data.sensor[sl])
    fields = {f.name for f in dataclasses.fields(it)}
    it_g = dataclasses.replace(it, **{f: _slice_group(getattr(it, f), g, data.n_groups)
                                      for f in fields if f != "history"})
    return sub, it_g


def _slice_group(obj: Any, g: int, n_groups: int) -> Any:
    if isinstance(obj, np.ndarray) and obj.ndim and obj.shape[0] == n_groups:
        return obj[g:g + 1]
    if isinstance(obj, list) and len(obj) == n_groups and n_groups > 1:
        return obj[g:g + 1]
    if isinstance(obj, dict):
        return {k: _slice_group(v, g, n_groups) for k, v in obj.items()}
    return obj


def registry_covariances(
    data: RegressionData,
    spec: ModelSpec,
    it: Any,
    method: str,
    covariances: Mapping[str, tuple[str, Mapping[str, Any]]],
    *,
    combine: str = "pooled",
    estimator: Any = None,
) -> dict[str, np.ndarray]:
    """Standard errors (G, P) of a registry estimator's batched estimates, computed as its
    checked ``fit`` does: its ``equation_designs`` (final instruments, weight, residuals
    of each equation) and one covariance call per equation. ``estimator``: the estimator
    object that made ``it`` where it is not the registered ``method`` (other options)."""
    from vesselid.identify.data import block_starts
    from vesselid.identify.registry import get_estimator

    est = estimator if estimator is not None else get_estimator(method)
    blocks = block_starts(spec)
    n_groups = data.n_groups
    out = {k: np.full((n_groups, spec.n_params), np.nan) for k in covariances}
    cov_est = {k: get_covariance_estimator(c, **dict(cfg)) for k, (c, cfg) in covariances.items()}
    for g in range(n_groups):
        if not np.all(np.isfinite(it.theta[g])):
            continue
        sub, it_g = one_group(data, it, g)
        phi = kernels.regressor_matrix(sub.regsig, sub.u, sub.starts, spec.codes.factors)
        try:
            designs = est.equation_designs(sub, spec, it_g, phi, combine)
            if len(designs) < spec.n_states:
                # estimators that keep their final design rows only on the checked
                # one-group path (GMM/SRIV: ``keep_history``): rerun it as ``fit`` does
                it_g = est.estimate_parameters(sub, spec, combine=combine, keep_history=True)
                if not np.all(np.isfinite(it_g.theta[0])):
                    continue
                designs = est.equation_designs(sub, spec, it_g, phi, combine)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if len(designs) < spec.n_states:
            continue
        own = est.own_covariance(it_g)
        if own is not None:  # a likelihood's inverse Fisher information, whatever cov_type
            for label in cov_est:
                out[label][g] = np.sqrt(np.abs(np.diag(own)))
            continue
        for label, ce in cov_est.items():
            for i in range(spec.n_states):
                d = designs[i]
                p_sl = slice(int(blocks[i]), int(blocks[i + 1]))
                try:
                    res = ce.estimate(d.z, d.phi, d.resid, d.starts, weight=d.weight,
                                      zero_mean=d.zero_mean, combine=combine, skip_first=False,
                                      weight_jacobian=d.weight_jacobian,
                                      fixed_b_square=d.fixed_b)
                except ValueError:
                    continue
                out[label][g, p_sl] = res.std_errors
    return out
