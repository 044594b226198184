"""Why do the closed-loop IV intervals under-cover on the CyberShip II loops? A diagnosis.

Run ``python scripts/closedloop_covariance_study.py [--runs 200] [--samples 3000]
[--experiments 4] [--dither-scale 1] [--out docs/closed_loop_covariance.csv]``.

Per run of the ``3dof`` design of :mod:`vesselid.plant.closedloop` (seeds as
``scripts/closed_loop_study.py``: the same closed-loop logs), the ``cl-iv`` estimate
(its modulus regressors not corrected for the sensor noise: ``sensor_noise=False``) and,
on its final instruments, regressors and residuals, the standard errors of several
long-run covariance estimators of the scores ``z ε``:

* ``hac-nw`` — the package default (Bartlett, Newey–West 1994 bandwidth);
* ``hac-150``, ``hac-300``, ``hac-600`` — Bartlett with a fixed, longer bandwidth;
* ``hac-prewhite`` — VAR(1) pre-whitened Bartlett (Andrews & Monahan 1992);
* ``batch-300``, ``batch-600`` — non-overlapping batch means within experiments.

and the *oracle* IV estimate with the instruments simulated from θ0 instead of θ̂ (is
the estimated auxiliary model a source of variance?). Written per parameter: bias in
Monte Carlo SEs (``z``), Monte Carlo sd, sd of the oracle estimate over the sd of cl-iv,
excess kurtosis of the estimates (heavy tails: weak instruments), and per covariance
estimator the mean SE over the Monte Carlo sd and the 95 % coverage.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import kurtosis

from vesselid.identify import covariance as cov
from vesselid.identify.backend import kernels
from vesselid.identify.base import square_designs
from vesselid.identify.closedloop import ClosedLoopIV, closed_loop_signals
from vesselid.identify.data import block_starts, from_log
from vesselid.identify.loop import closed_loop_instruments
from vesselid.plant.closedloop import DESIGNS

__all__ = ["BatchMeans", "run"]


class BatchMeans(cov.CovarianceEstimator):
    """Non-overlapping batch means within experiments: ``S_E = Σ_b (Σ_{k∈b} g)(Σ_{k∈b} g)ᵀ``
    over batches of about ``length`` rows."""

    name = "batch-means"

    def __init__(self, length: int = 300) -> None:
        self.length = int(length)

    def meat(self, g, z, eps, segs, equation):
        out = []
        for s in segs:
            x = g[s]
            n_b = max(x.shape[0] // self.length, 1)
            edges = np.linspace(0, x.shape[0], n_b + 1).astype(int)
            tot = np.add.reduceat(x, edges[:-1], axis=0)
            out.append(tot.T @ tot)
        return out, {"batch_length": self.length}


ESTIMATORS = {
    "hac-nw": cov.get_covariance_estimator("hac"),
    "hac-150": cov.get_covariance_estimator("hac", bandwidth=150.0),
    "hac-300": cov.get_covariance_estimator("hac", bandwidth=300.0),
    "hac-600": cov.get_covariance_estimator("hac", bandwidth=600.0),
    "hac-prewhite": cov.get_covariance_estimator("hac", prewhiten=True),
    "batch-300": BatchMeans(300),
    "batch-600": BatchMeans(600),
}


def run(runs: int, seed: int = 2024, samples: int | None = None,
        experiments: int | None = None, dither_scale: float = 1.0) -> pd.DataFrame:
    opts = {k: v for k, v in (("samples", samples), ("experiments", experiments))
            if v is not None}
    base = (0.3, 0.3, 0.03)  # the design's default force dithers (N, N, N m)
    d = DESIGNS["3dof"](dither_std=tuple(dither_scale * b for b in base), **opts)
    theta0 = d.spec.theta0_vector()
    est, oracle = [], []
    ses: dict[str, list[np.ndarray]] = {k: [] for k in ESTIMATORS}
    t0 = time.perf_counter()
    for r, ss in enumerate(np.random.SeedSequence(seed).spawn(runs)):
        cl_seed, _ = ss.spawn(2)  # the closed-loop log of scripts/closed_loop_study.py
        log = d.simulate(seed=cl_seed).to_log(aggregate=False)
        signals = closed_loop_signals(log, d.spec)
        # the modulus regressors uncorrected for the sensor noise (the covariance question
        # is about the long-run variance of the scores, not the noise-mean correction)
        data, spec = from_log(log, d.spec, sensor_noise=False)
        fit = ClosedLoopIV().with_signals(signals)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            it = fit.estimate_parameters(data, spec)
        phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
        designs = fit.equation_designs(data, spec, it, phi, "pooled")
        est.append(it.theta[0].copy())
        for k, c in ESTIMATORS.items():
            ses[k].append(np.concatenate([
                c.estimate(q.z, q.phi, q.resid, q.starts, zero_mean=True,
                           skip_first=False).std_errors for q in designs]))
        z0, _ = closed_loop_instruments(data, spec, theta0, signals)
        blocks = block_starts(spec)
        parts = []
        for i, q in enumerate(square_designs(data, spec, z0, phi, theta0, zero_mean=True)):
            sl = slice(int(blocks[i]), int(blocks[i + 1]))
            y = q.resid + q.phi @ theta0[sl]
            parts.append(np.linalg.solve(q.z.T @ q.phi, q.z.T @ y))
        oracle.append(np.concatenate(parts))
        if (r + 1) % 20 == 0:
            print(f"  {r + 1}/{runs} runs ({time.perf_counter() - t0:.0f} s)", flush=True)
    th, orc = np.array(est), np.array(oracle)
    sd = th.std(axis=0, ddof=1)
    rows = []
    for p, (eq, term) in enumerate(spec.param_index):
        row = {"samples": d.samples, "experiments": d.experiments,
               "dither_scale": dither_scale, "runs": runs,
               "parameter": f"{eq}: {term}", "theta0": theta0[p],
               "z": (th[:, p].mean() - theta0[p]) / (sd[p] / np.sqrt(runs)),
               "mc_sd": sd[p], "oracle_sd_ratio": orc[:, p].std(ddof=1) / sd[p],
               "excess_kurtosis": float(kurtosis(th[:, p]))}
        for k in ESTIMATORS:
            se = np.array(ses[k])[:, p]
            row[f"{k} se/sd"] = float(se.mean() / sd[p])
            row[f"{k} coverage_%"] = 100.0 * float(np.mean(np.abs(th[:, p] - theta0[p])
                                                           <= 1.96 * se))
        rows.append(row)
    return pd.DataFrame(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--samples", type=int, default=None)
    ap.add_argument("--experiments", type=int, default=None)
    ap.add_argument("--dither-scale", type=float, default=1.0,
                    help="multiply the design's force dithers (0.3 N, 0.3 N, 0.03 N m)")
    ap.add_argument("--out", default="docs/closed_loop_covariance.csv")
    args = ap.parse_args()
    table = run(args.runs, args.seed, args.samples, args.experiments, args.dither_scale)
    from vesselid.core.fileio import atomic_write_text

    atomic_write_text(Path(args.out), table.to_csv(index=False, float_format="%.5g"))
    pd.set_option("display.width", 200)
    cols = ["parameter", "z", "oracle_sd_ratio", "excess_kurtosis",
            *[f"{k} coverage_%" for k in ESTIMATORS]]
    print(table[cols].to_string(index=False, float_format="%.3g"))
    for k in ESTIMATORS:
        c = table[f"{k} coverage_%"]
        print(f"{k:13} coverage {c.min():.1f}-{c.max():.1f} %, "
              f"{int(((c < 93) | (c > 97)).sum())} of {len(c)} outside 93-97 %")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
