"""Switching-current study: when does the telegraph-current likelihood beat the
Gauss–Markov one, and how good is its estimate?

On the designs of ``scripts/robustness_study.py`` (the same logs, the same seeds), every
log is fitted with the Gauss–Markov likelihood models exactly as ``auto`` fits them
(:func:`vesselid.identify.pem.fit_groups`, ``joint=True, boundary="auto"``) and with the
switching-current model (:mod:`vesselid.identify.switching`) regardless of ``auto``'s
gate. Per design: how often the kurtosis test of the smoothed current rejects a
Gaussian current (the gate), how often Vuong's test prefers the switching model at
its level, how often both (``auto``'s choice of the switching model), the quantiles of
Vuong's z, and the switching estimate's coverage and bias z over all runs. Writes
``docs/robustness_switching.csv`` and ``docs/robustness_switching.md``::

    nice -n 10 python scripts/switching_study.py --runs 50 --samples 10000 --seed 2024
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

import robustness_study as rs

from vesselid.core.fileio import atomic_write_text
from vesselid.identify import pem, switching
from vesselid.identify.data import from_log
from vesselid.identify.estimators import estimate

DESIGNS = ("telegraph", "gm-current", "two-coloured", "white")


def one_run(design: rs.Design, seed: np.random.SeedSequence, n: int) -> dict:
    log = rs.simulate(design, np.random.default_rng(seed), n)
    data, spec = from_log(log, rs.SPEC)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        base = estimate(data, spec, "iv-zero-mean", combine="pooled")
    t0 = time.perf_counter()
    res = pem.fit_groups(data, spec, base.theta, joint=True, boundary="auto")
    t1 = time.perf_counter()
    cmp = switching.compare_with_gaussian(data, spec, base.theta, res,
                                          np.ones(1, dtype=bool))
    t2 = time.perf_counter()
    row = {"design": design.name, "gm_model": str(res["model"][0]),
           "shape_z": float(res["shape_z"][0]), "bimodal": bool(res["shape_bimodal"][0]),
           "vuong": float(cmp["vuong"][0]), "vuong_prefers": bool(cmp["taken"][0]),
           "converged": bool(cmp["converged"][0]), "gm_s": t1 - t0, "switch_s": t2 - t1}
    ses = {k: np.sqrt(np.diag(cmp[switching.COVARIANCE_KEYS[k]][0]))
           for k in switching.COVARIANCES}
    for i, p in enumerate(rs.PARAMS):
        row[f"est_{p}"] = float(cmp["theta"][0, i])
        row[f"se_{p}"] = float(ses["conservative"][i])
        for k in ("fisher", "sandwich"):
            row[f"se_{k}_{p}"] = float(ses[k][i])
    row.update({f"noise_{k}": float(v) for k, v in zip(switching.NOISE_NAMES,
                                                         cmp["noise"][0], strict=True)})
    return row


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    out = []
    th0 = dict(zip(rs.PARAMS, rs.THETA0, strict=True))
    for design, g in df.groupby("design", sort=False):
        r = len(g)
        row = {"design": design, "runs": r,
               "gate_rejects": float(g["bimodal"].mean()),
               "vuong_prefers": float(g["vuong_prefers"].mean()),
               "auto_takes": float((g["bimodal"] & g["vuong_prefers"]).mean()),
               "vuong_z_q10": float(np.nanquantile(g["vuong"], 0.1)),
               "vuong_z_median": float(np.nanmedian(g["vuong"])),
               "vuong_z_q90": float(np.nanquantile(g["vuong"], 0.9)),
               "converged": float(g["converged"].mean()),
               "median_switch_s": float(g["switch_s"].median())}
        for p in rs.PARAMS:
            ok = g[np.isfinite(g[f"est_{p}"]) & np.isfinite(g[f"se_{p}"])]
            err = ok[f"est_{p}"] - th0[p]
            sd = float(err.std(ddof=1))
            row[f"coverage_{p}"] = float((np.abs(err) <= 1.959964 * ok[f"se_{p}"]).mean())
            row[f"bias_z_{p}"] = float(err.mean() / (sd / np.sqrt(len(ok))))
            row[f"se_over_sd_{p}"] = float(ok[f"se_{p}"].mean() / sd)
            for k in ("fisher", "sandwich"):  # the other covariances of the same fits
                row[f"coverage_{k}_{p}"] = float(
                    (np.abs(err) <= 1.959964 * ok[f"se_{k}_{p}"]).mean())
                row[f"se_over_sd_{k}_{p}"] = float(ok[f"se_{k}_{p}"].mean() / sd)
        out.append(row)
    return pd.DataFrame(out)


def markdown(s: pd.DataFrame, args: argparse.Namespace) -> str:
    lines = ["---", "orphan: true", "---", "", "# The switching-current model against the "
             "Gauss–Markov one", "",
             f"{args.runs} runs × {args.samples} samples per design, seed {args.seed} (the "
             "logs of the robustness study). `python scripts/switching_study.py --runs "
             f"{args.runs} --samples {args.samples} --seed {args.seed}`. Gate: the kurtosis "
             "test of the smoothed current rejects a Gaussian current (level "
             "0.01); Vuong: the switching model's likelihood beats the Gauss–Markov "
             f"model `auto` fits (one-sided level {switching.VUONG_ALPHA}); auto takes "
             "it where both hold. The estimate columns are the switching model's on "
             "every run, whatever `auto` takes.", "",
             "| design | gate rejects | Vuong prefers | auto takes | Vuong z q10 / median "
             "/ q90 | coverage a / n / f | bias z a / n / f | SE / MC sd a / n / f | "
             "median s |", "|---|---|---|---|---|---|---|---|---|"]
    for _, r in s.iterrows():
        cov = " / ".join(f"{100 * r[f'coverage_{p}']:.1f} %" for p in rs.PARAMS)
        bz = " / ".join(f"{r[f'bias_z_{p}']:+.2f}" for p in rs.PARAMS)
        so = " / ".join(f"{r[f'se_over_sd_{p}']:.2f}" for p in rs.PARAMS)
        lines.append(f"| {r.design} | {100 * r.gate_rejects:.1f} % | "
                     f"{100 * r.vuong_prefers:.1f} % | {100 * r.auto_takes:.1f} % | "
                     f"{r.vuong_z_q10:+.1f} / {r.vuong_z_median:+.1f} / {r.vuong_z_q90:+.1f}"
                     f" | {cov} | {bz} | {so} | {r.median_switch_s:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = rs.study_parser(__doc__.split("\n\n")[0], runs=50, seed=2024, designs=DESIGNS)
    args = ap.parse_args(argv)
    rs.check_study_args(ap, args)
    summary = summarise(pd.DataFrame(rs.run_designs(args, lambda d, s, n: [one_run(d, s, n)])))
    pd.set_option("display.width", 250)
    print(summary.to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out / "robustness_switching.csv",
                      summary.to_csv(index=False, float_format="%.5g"))
    atomic_write_text(args.out / "robustness_switching.md", markdown(summary, args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
