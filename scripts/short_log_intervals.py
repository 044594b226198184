"""Why ``auto``'s intervals fell short on 10³-sample logs, and which correction closes it.

On the robustness study's ``short`` design (white disturbances, random pulses, 10³
samples; :mod:`robustness_study`) ``auto`` keeps the delayed instruments (two-step
GMM) in about 94 % of runs. For those runs this script recomputes the covariance of
the reported estimate from its final design (instruments, regressors, residuals, HAC
weight, weight Jacobian) with several candidates and prints, per parameter, the
coverage of the 95 % interval with its Wilson interval, the mean SE over the Monte
Carlo sd and the sd of the t statistic:

* ``default``: the package default (Bartlett HAC, Newey–West bandwidth, Windmeijer's
  correction, fixed-b critical value at the effective bandwidth ratio);
* ``no fixed-b``: the same with the normal quantile (``cov_config fixed_b=False``);
* ``no Windmeijer``: the plain two-step sandwich (``windmeijer=False``);
* ``fixed-b at M/T``: the Kiefer–Vogelsang critical value at the nominal ratio
  ``(⌊bandwidth⌋ + 1)/T`` instead of the effective one;
* ``Andrews bandwidth``, ``bandwidth 2``: other bandwidths, normal quantile;
* ``HAC at θ0``: the HAC of the scores at the *true* residuals (an oracle: the
  estimation error removed from the scores), normal quantile.

    nice -n 10 python scripts/short_log_intervals.py --runs 600 --seed 2024
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import robustness_study as rs

from vesselid.identify import covariance_api, identify
from vesselid.identify.covariance import get_covariance_estimator
from vesselid.identify.fixedb import bartlett_critical_value

Z975 = 1.959964


def designs(runs: int, seed: int, samples: int) -> list[dict]:
    """``auto`` on ``runs`` logs of the short design (the study's seeds): per run the
    estimate and, where it kept the delayed instruments, the design its covariance used."""
    captured: list = []
    original = covariance_api.resolve

    def resolve(cov_type, cov_config=None):
        name, fn = original(cov_type, cov_config)

        def keep(design, combine="pooled"):
            captured.append(design)
            return fn(design, combine=combine)
        return name, keep

    covariance_api.resolve = resolve
    try:
        d = rs.DESIGNS["short"]
        root = np.random.SeedSequence(seed)
        seeds = np.random.SeedSequence(root.entropy, spawn_key=(list(rs.DESIGNS).index("short"),)
                                       ).spawn(runs)
        out = []
        for s in seeds:
            log = rs.simulate(d, np.random.default_rng(s), samples)
            captured.clear()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                res = identify(log, rs.SPEC, "auto")
            if res.diagnostics.get("choice") == "combined" and captured:
                out.append({"theta": res.params.to_numpy().copy(), "design": captured[-1]})
        return out
    finally:
        covariance_api.resolve = original


def _se(design, theta: np.ndarray, truth: np.ndarray | None = None, **cfg) -> tuple:
    resid = design.resid if truth is None else design.resid + design.phi @ (theta - truth)
    res = get_covariance_estimator("hac", **cfg).estimate(
        design.z, design.phi, resid, design.starts, weight=design.weight,
        zero_mean=design.zero_mean, skip_first=False, weight_jacobian=design.weight_jacobian)
    return np.sqrt(np.diag(res.cov)), res.config


def wilson(k: int, n: int) -> tuple[float, float]:
    p, z = k / n, Z975
    den = 1 + z * z / n
    c, h = (p + z * z / (2 * n)) / den, z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return c - h, c + h


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=600)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--samples", type=int, default=1000)
    args = ap.parse_args(argv)
    if args.runs < 10 or args.samples < 200:
        ap.error("--runs must be at least 10 and --samples at least 200")
    recs = designs(args.runs, args.seed, args.samples)
    truth = np.array(rs.THETA0)
    theta = np.array([r["theta"] for r in recs])
    err = theta - truth
    sd = err.std(0, ddof=1)
    rows: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    cands = {"default": {}, "no fixed-b": {"fixed_b": False},
             "no Windmeijer": {"windmeijer": False},
             "Andrews bandwidth": {"bandwidth": "andrews", "fixed_b": False},
             "bandwidth 2": {"bandwidth": 2.0, "fixed_b": False}}
    for name, cfg in cands.items():
        se = np.array([_se(r["design"], r["theta"], **cfg)[0] for r in recs])
        rows[name] = (se, np.full(se.shape, Z975))
    se, crit = [], []
    for r in recs:
        s, cfg = _se(r["design"], r["theta"], fixed_b=False)
        m_over_t = (math.floor(cfg["bandwidth"]) + 1) / r["design"].z.shape[0]
        se.append(s)
        crit.append(np.full(3, float(bartlett_critical_value(m_over_t))))
    rows["fixed-b at M/T"] = (np.array(se), np.array(crit))
    rows["HAC at θ0 (oracle)"] = (np.array([_se(r["design"], r["theta"], truth, fixed_b=False)[0]
                                            for r in recs]), np.full(err.shape, Z975))
    b_eff = np.array([_se(r["design"], r["theta"])[1]["effective_b"] for r in recs])
    print(f"short design, {args.samples} samples, seed {args.seed}: {len(recs)} of {args.runs} "
          "runs kept the delayed instruments (two-step GMM)")
    print(f"median effective bandwidth ratio b_p (a, n, f): {np.round(np.median(b_eff, 0), 4)}")
    print(f"{'candidate':22s} | " + " | ".join(f"{p}: coverage [Wilson]  SE/sd  t sd"
                                             for p in rs.PARAMS))
    for name, (se, crit) in rows.items():
        cells = []
        for j in range(3):
            k = int(np.sum(np.abs(err[:, j]) <= crit[:, j] * se[:, j]))
            lo, hi = wilson(k, len(recs))
            cells.append(f"{100 * k / len(recs):5.1f} [{100 * lo:.1f}, {100 * hi:.1f}] "
                         f"{se[:, j].mean() / sd[j]:5.2f} "
                         f"{np.std(err[:, j] * Z975 / (crit[:, j] * se[:, j])):5.2f}")
        print(f"{name:22s} | " + " | ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
