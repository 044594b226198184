"""Where a small bias of the closed-loop refined IV could come from: variants on the same logs.

Run ``python scripts/closed_loop_bias_study.py [--samples 3000] [--runs 300] [--seed 7]
[--variants ...] [--out docs/closed_loop_bias_variants.csv]``.

Every run simulates one log of the ``3dof`` closed-loop design of
:mod:`vesselid.plant.closedloop` (seeds as ``scripts/closed_loop_study.py``: the
closed-loop log of run ``r`` is the first child of the ``r``-th spawn of ``--seed``) and
estimates it with ``cl-iv`` and with variants that each remove one candidate source of a
finite-sample bias, on the same log:

* ``cl-iv`` — the estimator as shipped (refined iteration to the fixed point, instruments
  simulated from θ̂ starting at each experiment's first measured state, the modulus
  regressors corrected for the sensor noise the log declares);
* ``uncorrected`` — the same without the sensor-noise correction (``sensor_noise=False``);
  the variants below are all uncorrected, each removing one other candidate source:
* ``theta0`` — one IV step with the instruments simulated from the true θ0 (no
  instrument estimation: isolates the effect of estimating the auxiliary model);
* ``theta0-true-start`` — as ``theta0`` with the simulation started at the true (noise-free)
  first state (an oracle: isolates the first measurement's noise in the instruments);
* ``reference-start`` — the refined iteration with the simulation started at the reference
  (instruments built from the external signals only);
* ``cross-fit`` — experiment ``i``'s instruments simulated from the ``cl-iv`` estimate of
  the other experiments, then one IV step on all of them (no own-noise dependence of the
  auxiliary model);
* ``jackknife`` — leave-one-experiment-out bias correction
  ``K θ̂ − (K − 1) mean_i θ̂_(−i)``.

Reported per variant and parameter: bias in Monte Carlo standard deviations (``bias_sd``),
``z = bias/(sd/√R)``, the Monte Carlo sd relative to ``cl-iv``'s, and the paired
difference to ``cl-iv`` in its own Monte Carlo standard errors (``z_vs_cl_iv``: the same
logs, so far sharper than comparing two biases).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from vesselid.identify.backend import kernels
from vesselid.identify.closedloop import ClosedLoopIV
from vesselid.identify.data import RegressionData, from_log
from vesselid.identify.estimators import moments_from_matrices, solve_moments
from vesselid.identify.loop import ClosedLoopSignals, closed_loop_signals
from vesselid.model.spec import ModelSpec
from vesselid.plant.closedloop import DESIGNS, closed_loop_states

__all__ = ["VARIANTS", "run"]

VARIANTS = ("cl-iv", "uncorrected", "theta0", "theta0-true-start", "reference-start", "cross-fit",
            "jackknife")


def _start(data: RegressionData, spec: ModelSpec, signals: ClosedLoopSignals, s: int,
           how: str, x_true: np.ndarray | None) -> np.ndarray:
    first = int(data.starts[s])
    if how == "measured":
        return data.target[first]
    if how == "true":
        return x_true[s]
    x0 = data.target[first].copy()   # "reference": controlled states start at their reference
    for j, inp in enumerate(spec.inputs):
        state = signals.controller.loops.get(inp)
        if state is not None:
            x0[spec.states.index(state)] = signals.reference[first, j]
    return x0


def instruments(data: RegressionData, spec: ModelSpec, theta: np.ndarray,
                signals: ClosedLoopSignals, start: str = "measured",
                x_true: np.ndarray | None = None) -> np.ndarray:
    """``cl-iv``'s instruments (the closed loop simulated from the reference and dither)
    with the simulation of each experiment started as ``start`` says."""
    xs = np.empty_like(data.target)
    us = np.empty_like(data.u)
    lim = 1e3 * np.maximum(data.target_abs_max, 1.0)
    for s in range(data.n_segments):
        sl = data.segment(s)
        x, u, _ = closed_loop_states(
            spec, signals.controller, signals.reference[sl], dither=signals.dither[sl],
            theta=theta, x0=_start(data, spec, signals, s, start, x_true), limit=lim[s],
            raise_on_divergence=False)
        xs[sl], us[sl] = x, u
    return kernels.regressor_matrix(np.nan_to_num(xs), np.nan_to_num(us), data.starts,
                                    spec.codes.factors)


class _ReferenceStart(ClosedLoopIV):
    """``cl-iv`` with every experiment's simulation started at the reference."""

    def instruments(self, data, spec, theta, limits=None):
        z = instruments(data, spec, theta, self._require(), "reference")
        return np.where(np.isfinite(z), z, 0.0), np.zeros(data.n_segments, np.int64)


def _iv_step(data: RegressionData, spec: ModelSpec, z: np.ndarray, phi: np.ndarray
             ) -> np.ndarray:
    mom = moments_from_matrices(data, spec, z, phi)
    theta, _ = solve_moments(mom, data, spec, zero_mean=True, combine="pooled")
    return theta[0]


def _subset(data: RegressionData, signals: ClosedLoopSignals, segs: list[int]
            ) -> tuple[RegressionData, ClosedLoopSignals]:
    rows = np.concatenate([np.arange(data.starts[s], data.starts[s + 1]) for s in segs])
    starts = np.concatenate([[0], np.cumsum(data.lengths[segs])]).astype(data.starts.dtype)
    sub = dataclasses.replace(
        data, target=data.target[rows], regsig=data.regsig[rows], u=data.u[rows],
        starts=starts, group=np.zeros(len(segs), dtype=data.group.dtype),
        experiment_ids=tuple(data.experiment_ids[s] for s in segs) if data.experiment_ids
        else (), sensor=None if data.sensor is None else data.sensor[rows])
    sig = ClosedLoopSignals(reference=np.ascontiguousarray(signals.reference[rows]),
                            dither=np.ascontiguousarray(signals.dither[rows]),
                            controller=signals.controller)
    return sub, sig


def one_run(design, seed: np.random.SeedSequence, variants: tuple[str, ...]
            ) -> dict[str, np.ndarray]:
    """Every requested variant's estimate on one closed-loop log."""
    cl_seed, _ = seed.spawn(2)
    sim = design.simulate(seed=cl_seed)
    log = sim.to_log(aggregate=False)
    signals = closed_loop_signals(log, design.spec)
    data_c, spec = from_log(log, design.spec)   # the log's sensor noise: corrected
    data, _ = from_log(log, design.spec, sensor_noise=False)
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    theta0 = spec.theta0_vector()
    out: dict[str, np.ndarray] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out["cl-iv"] = (ClosedLoopIV().with_signals(signals)
                        .estimate_parameters(data_c, spec).theta[0])
        full = ClosedLoopIV().with_signals(signals).estimate_parameters(data, spec).theta[0]
        out["uncorrected"] = full
        if "theta0" in variants:
            out["theta0"] = _iv_step(data, spec, instruments(data, spec, theta0, signals), phi)
        if "theta0-true-start" in variants:
            z = instruments(data, spec, theta0, signals, "true", sim.x[:, 0, :])
            out["theta0-true-start"] = _iv_step(data, spec, z, phi)
        if "reference-start" in variants:
            est = _ReferenceStart().with_signals(signals)
            out["reference-start"] = est.estimate_parameters(data, spec).theta[0]
        if "cross-fit" in variants or "jackknife" in variants:
            k = data.n_segments
            loo = []
            for i in range(k):
                sub, sig = _subset(data, signals, [j for j in range(k) if j != i])
                loo.append(ClosedLoopIV().with_signals(sig).estimate_parameters(sub, spec)
                           .theta[0])
            z = np.empty_like(phi)
            for i in range(k):
                sub, sig = _subset(data, signals, [i])
                z[data.segment(i)] = instruments(sub, spec, loo[i], sig)
            out["cross-fit"] = _iv_step(data, spec, np.where(np.isfinite(z), z, 0.0), phi)
            out["jackknife"] = k * full - (k - 1) * np.mean(loo, axis=0)
    return {v: out[v] for v in variants}


def run(samples: int, runs: int, seed: int, variants: tuple[str, ...] = VARIANTS,
        progress: bool = True) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The summary table and every run's estimates (long format)."""
    variants = ("cl-iv", *[v for v in variants if v != "cl-iv"])
    design = DESIGNS["3dof"](samples=samples)
    theta0 = design.spec.theta0_vector()
    names = [f"{e}: {t}" for e, t in design.spec.param_index]
    est: dict[str, list[np.ndarray]] = {v: [] for v in variants}
    t0 = time.perf_counter()
    for r, ss in enumerate(np.random.SeedSequence(seed).spawn(runs)):
        for v, th in one_run(design, ss, variants).items():
            est[v].append(th)
        if progress and (r + 1) % 25 == 0:
            print(f"  {r + 1}/{runs} runs ({time.perf_counter() - t0:.0f} s)", flush=True)
    base = np.asarray(est["cl-iv"])
    rows, per_run = [], []
    for v, vals in est.items():
        a = np.asarray(vals)
        ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(base), axis=1)
        a_ok, b_ok = a[ok], base[ok]
        n = a_ok.shape[0]
        sd = a_ok.std(axis=0, ddof=1)
        bias = a_ok.mean(axis=0) - theta0
        diff = a_ok - b_ok
        dsd = diff.std(axis=0, ddof=1)
        for p, name in enumerate(names):
            rows.append({
                "samples": samples, "experiments": design.experiments, "runs": n,
                "variant": v, "parameter": name, "theta0": theta0[p], "bias": bias[p],
                "mc_sd": sd[p], "bias_sd": bias[p] / sd[p], "z": bias[p] / (sd[p] / np.sqrt(n)),
                "sd_ratio": sd[p] / b_ok[:, p].std(ddof=1),
                "z_vs_cl_iv": (diff[:, p].mean() / (dsd[p] / np.sqrt(n)) if dsd[p] > 0
                               else 0.0)})
        f = pd.DataFrame(a, columns=names)
        f.insert(0, "run", np.arange(a.shape[0]))
        f.insert(0, "variant", v)
        per_run.append(f)
    return pd.DataFrame(rows), pd.concat(per_run, ignore_index=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=3000, help="samples per experiment")
    ap.add_argument("--runs", type=int, default=300)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--variants", default=",".join(VARIANTS),
                    help=f"comma-separated subset of {', '.join(VARIANTS)}")
    ap.add_argument("--out", default="docs/closed_loop_bias_variants.csv")
    ap.add_argument("--save-runs", default=None, help="also write every run's estimates")
    args = ap.parse_args()
    variants = tuple(v.strip() for v in args.variants.split(",") if v.strip())
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        ap.error(f"unknown variants {unknown}; choose from {', '.join(VARIANTS)}")
    table, per_run = run(args.samples, args.runs, args.seed, variants)
    from vesselid.core.fileio import atomic_write_text

    atomic_write_text(Path(args.out), table.to_csv(index=False, float_format="%.6g"))
    if args.save_runs:
        atomic_write_text(Path(args.save_runs), per_run.to_csv(index=False,
                                                               float_format="%.9g"))
    wide = table.pivot(index="parameter", columns="variant", values="bias_sd")
    wide = wide.loc[table.parameter.unique(), table.variant.unique()]
    pd.set_option("display.width", 160)
    print(f"\nbias / Monte Carlo sd, 4 x {args.samples} samples, {args.runs} runs:")
    print(wide.to_string(float_format=lambda x: f"{x:.3f}"))
    s = table.groupby("variant", sort=False).agg(
        max_abs_z=("z", lambda z: z.abs().max()), max_abs_bias_sd=("bias_sd",
                                                                   lambda b: b.abs().max()),
        sd_ratio_min=("sd_ratio", "min"), sd_ratio_max=("sd_ratio", "max"),
        max_abs_z_vs_cl_iv=("z_vs_cl_iv", lambda z: z.abs().max()))
    print(s.to_string(float_format=lambda x: f"{x:.3f}"))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
