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
(time constant 20 samples), each with both pulse designs; the CyberShip II sea trial
is in ``scripts/calibration.py``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from vesselid.identify import kernels
from vesselid.identify.covariance import DEFAULT_COV_TYPE, get_covariance_estimator
from vesselid.identify.data import RegressionData, from_arrays
from vesselid.model import ModelSpec

__all__ = [
    "SCENARIOS",
    "coverage_study",
    "coverage_table",
    "group_covariances",
    "heave_scenario",
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
    from vesselid.disturbances import GaussMarkov
    from vesselid.systems import heave

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
        segs = np.flatnonzero(data.group == g)
        a, b = int(data.starts[segs[0]]), int(data.starts[segs[-1] + 1])
        starts = data.starts[segs[0]: segs[-1] + 2] - a
        sl = slice(a, b)
        phi = kernels.regressor_matrix(data.regsig[sl], data.u[sl], starts, codes.factors)
        if method == "ls":
            z = phi
        else:
            z, _ = kernels.instrument_matrix(data.target[sl], data.u[sl], starts,
                                             theta_aux[g], codes.factors, codes.equation,
                                             spec.n_states)
        zero_mean = method == "iv-zero-mean"
        weights = np.zeros((n_par, spec.n_states))
        weights[np.arange(n_par), codes.equation] = theta[g]
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
        res = est.estimate(z, np.where(rows[:, None], phi, 0.0), resid, starts, codes.equation,
                           zero_mean=zero_mean, combine=combine)
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
            "bias_z": float(np.mean(err) / sd * math.sqrt(n)) if n > 1 and sd > 0 else np.nan,
        })
    return pd.DataFrame(rows)


def coverage_study(
    scenario: str,
    runs: int,
    *,
    samples: int = 10_000,
    seed: int = 0,
    method: str = "iv-zero-mean",
    covariances: Mapping[str, tuple[str, Mapping[str, Any]]] | None = None,
    estimate_fn: Callable[..., Any] | None = None,
    batch: int = 200,
) -> pd.DataFrame:
    """Coverage of a heave scenario for one or several covariance estimators.

    Parameters
    ----------
    scenario : str
        Key of :data:`SCENARIOS`.
    runs, samples, seed : int
        Monte Carlo runs, samples per run, root seed (run ``r`` uses child ``r``).
    method : str
        Estimator of :func:`vesselid.identify.estimators.estimate`.
    covariances : mapping label -> (cov_type, cov_config)
        Default: the package default only.
    estimate_fn : callable, optional
        ``estimate_fn(data, spec) -> IterationResult``; default
        ``estimate(data, spec, method)``.

    Returns
    -------
    DataFrame
        :func:`coverage_table` rows with ``scenario`` and ``covariance`` columns.
    """
    from vesselid.identify.estimators import estimate

    system, aggregate, target = heave_scenario(scenario)
    spec = system.identification_spec(aggregate=aggregate)
    covariances = covariances or {DEFAULT_COV_TYPE: (DEFAULT_COV_TYPE, {})}
    root = np.random.SeedSequence(seed)
    seeds = root.spawn(int(runs))
    thetas = []
    ses: dict[str, list[np.ndarray]] = {k: [] for k in covariances}
    for c in range(0, int(runs), batch):
        sim = system.simulate(int(samples), run_seeds=seeds[c:c + batch])
        data = from_arrays(spec, sim.y, sim.u, y2=sim.y2 if aggregate else None)
        if target == "aggregated":
            data = dataclasses.replace(data, target=data.regsig)
        it = (estimate_fn(data, spec) if estimate_fn is not None
              else estimate(data, spec, method))
        thetas.append(it.theta)
        for label, (cov_type, cfg) in covariances.items():
            cov, _ = group_covariances(data, spec, it.theta, it.theta_aux, method=method,
                                       cov_type=cov_type, **dict(cfg))
            ses[label].append(np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None)))
    theta = np.vstack(thetas)
    names = [f"{eq}: {term}" for eq, term in spec.param_index]
    frames = []
    for label in covariances:
        tab = coverage_table(theta, np.vstack(ses[label]), spec.theta0_vector(), names)
        tab.insert(0, "covariance", label)
        tab.insert(0, "scenario", scenario)
        frames.append(tab)
    return pd.concat(frames, ignore_index=True)


def seatrial_coverage(
    runs: int,
    *,
    samples: int = 20_000,
    experiments: int = 6,
    seed: int = 0,
    method: str = "iv-zero-mean",
    covariances: Mapping[str, tuple[str, Mapping[str, Any]]] | None = None,
    estimate_fn: Callable[..., Any] | None = None,
    chunk: int = 5,
) -> pd.DataFrame:
    """Coverage on the CyberShip II sea trial (:mod:`vesselid.seatrial`): ``runs``
    independent trials of ``experiments × samples`` with the study's current, wind,
    gusts and unmodelled forces, identified with the relative predictor (speed log)."""
    from vesselid.identify.estimators import estimate
    from vesselid.seatrial import _disturbances, design_sea_trial, seatrial_spec
    from vesselid.vessels import SENSOR_CHANNELS, simulate_cybership2

    spec = seatrial_spec()
    design = design_sea_trial(experiments, samples, seed=seed)
    dist = _disturbances(0.05, np.radians(30.0), 1.0, np.radians(-60.0), 0.005, 0.1,
                         (0.02, 0.02, 0.01))
    idx = [SENSOR_CHANNELS.index(c) for c in ("u_log", "v_log", "r")]
    inputs = design.warmup_inputs()
    covariances = covariances or {DEFAULT_COV_TYPE: (DEFAULT_COV_TYPE, {})}
    seeds = np.random.SeedSequence(seed + 2000).spawn(int(runs))
    thetas = []
    ses: dict[str, list[np.ndarray]] = {k: [] for k in covariances}
    n_e = design.n_experiments
    for c in range(0, int(runs), chunk):
        group_seeds = seeds[c:c + chunk]
        y = np.empty((len(group_seeds) * n_e, design.n_samples, 3))
        tau = np.empty_like(y)
        for g, ss in enumerate(group_seeds):
            sim = simulate_cybership2(inputs, run_seeds=ss.spawn(n_e), dt=design.dt,
                                      disturbances=dist)
            y[g * n_e:(g + 1) * n_e] = sim.sensors[:, design.warmup:, idx]
            tau[g * n_e:(g + 1) * n_e] = sim.tau[:, design.warmup:]
            del sim
        data = from_arrays(spec, y, tau, experiments_per_group=n_e)
        it = (estimate_fn(data, spec) if estimate_fn is not None
              else estimate(data, spec, method))
        thetas.append(it.theta)
        for label, (cov_type, cfg) in covariances.items():
            cov, _ = group_covariances(data, spec, it.theta, it.theta_aux, method=method,
                                       cov_type=cov_type, **dict(cfg))
            ses[label].append(np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None)))
    theta = np.vstack(thetas)
    names = [f"{eq}: {term}" for eq, term in spec.param_index]
    frames = []
    for label in covariances:
        tab = coverage_table(theta, np.vstack(ses[label]), spec.theta0_vector(), names)
        tab.insert(0, "covariance", label)
        tab.insert(0, "scenario", "seatrial")
        frames.append(tab)
    return pd.concat(frames, ignore_index=True)
