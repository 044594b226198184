"""The joint disturbance model at its boundary: bounded fit against the unbounded step.

On the designs of ``scripts/robustness_study.py`` where ``auto`` takes the
prediction-error estimator, every candidate fit of
:func:`vesselid.identify.pem.fit_groups` is kept on the same logs (``details=True``):

* ``single``: the better single-process model (``current``: a Gauss–Markov current);
* ``joint``: both processes at once, σ_c ≥ 0 (the bounded maximum-likelihood fit);
* ``local``: the sensor-noise variance without its bound at zero (one scoring step
  from the current model, largest |z| over the ρ_c grid;
  :func:`vesselid.identify.pem._local_joint`);
* ``auto``: what ``auto`` reports (the default, ``pem_boundary="auto"``: ``unbounded``
  unless the kurtosis test of the smoothed current finds it bimodal, then ``bounded``
  with the spread between the two fits added to the covariance);
* ``bounded``: what ``pem_boundary="bounded"`` reports: ``joint`` where it converged
  with a likelihood gain, ``single`` otherwise;
* ``unbounded``: what ``pem_boundary="unbounded"`` reports: ``joint``
  where it converged with a likelihood ratio above
  :data:`vesselid.identify.pem.LOCAL_LR`, ``local`` otherwise.

Per design and fit: coverage of the 95 % intervals (Wilson interval), bias z, median
relative error, SE / Monte Carlo sd, the distribution of the joint model's
likelihood-ratio statistic and of the kurtosis z of the smoothed current
(:func:`vesselid.identify.current_shape.smoothed_current_test`; its rejection rate is
the test's size on the Gaussian designs and its power on the telegraph current).
Writes ``docs/robustness_boundary.csv`` and ``docs/robustness_boundary.md``::

    nice -n 10 python scripts/pem_boundary_study.py --runs 200 --seed 7
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

import robustness_study as rs

from vesselid.core.fileio import atomic_write_text
from vesselid.identify import identify, pem

FITS = ("auto", "single", "joint", "local", "bounded", "unbounded")
DESIGNS = ("gm-current", "two-coloured", "telegraph")


def one_run(design: rs.Design, seed: np.random.SeedSequence, n: int) -> dict | None:
    """``auto`` on one log with every candidate fit of its likelihood fallback kept."""
    log = rs.simulate(design, np.random.default_rng(seed), n)
    captured: list[dict] = []
    original = pem.fit_groups

    def keep(*args, **kwargs):
        out = original(*args, **{**kwargs, "details": True})
        captured.append(out)
        return out

    pem.fit_groups = keep
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify(log, rs.SPEC, "auto")
    finally:
        pem.fit_groups = original
    row: dict = {"design": design.name, "choice": str(res.diagnostics.get("choice"))}
    for j, p in enumerate(rs.PARAMS):
        row[f"auto_{p}"] = float(res.params.iloc[j])
        row[f"auto_se_{p}"] = float(res.std_errors.iloc[j])
    if not captured:
        return row
    r = captured[0]
    row["lr"] = float(r["lr_joint"][0])
    row["local_z"] = float(r["local_z"][0])
    row["joint_converged"] = bool(r["joint_converged"][0])
    row["shape_z"] = float(r["shape_z"][0])
    row["shape_bimodal"] = bool(r["shape_bimodal"][0])
    for pre in ("single", "joint", "local"):
        for j, p in enumerate(rs.PARAMS):
            row[f"{pre}_{p}"] = float(r[pre + "_theta"][0][j])
            row[f"{pre}_se_{p}"] = float(np.sqrt(r[pre + "_cov_conservative"][0][j, j]))
    return row


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    if "lr" in df:
        take = (df["joint_converged"].fillna(False).astype(bool)
                & (df["lr"].astype(float) > pem.LOCAL_LR))
        joint = (df["joint_converged"].fillna(False).astype(bool)
                 & (df["lr"].astype(float) >= 0))
        for p in rs.PARAMS:
            for key in (p, f"se_{p}"):
                df[f"unbounded_{key}"] = np.where(take, df[f"joint_{key}"],
                                                  df[f"local_{key}"])
                df[f"bounded_{key}"] = np.where(joint, df[f"joint_{key}"],
                                                df[f"single_{key}"])
    out = []
    for design, g in df.groupby("design", sort=False):
        for fit in FITS:
            for j, p in enumerate(rs.PARAMS):
                if f"{fit}_{p}" not in g:
                    continue
                est, se = g[f"{fit}_{p}"].astype(float), g[f"{fit}_se_{p}"].astype(float)
                ok = np.isfinite(est) & np.isfinite(se)
                err, se = (est - rs.THETA0[j])[ok], se[ok]
                r = len(err)
                if r < 2:
                    continue
                k = int((np.abs(err) <= 1.959964 * se).sum())
                lo, hi = rs.wilson(k, r)
                sd = float(err.std(ddof=1))
                out.append({"design": design, "fit": fit, "param": p, "runs": r,
                            "coverage": k / r, "wilson_lo": lo, "wilson_hi": hi,
                            "bias_z": float(err.mean() / (sd / np.sqrt(r))),
                            "median_rel_err": float(np.median(np.abs(err / rs.THETA0[j]))),
                            "se_over_sd": float(se.mean() / sd)})
    return pd.DataFrame(out)


def markdown(summary: pd.DataFrame, df: pd.DataFrame, args: argparse.Namespace) -> str:
    lines = ["---", "orphan: true", "---", "",
             "# The joint disturbance model at its boundary", "",
             f"{args.runs} runs × {args.samples} samples per design, seed {args.seed}; "
             f"θ0 = {rs.THETA0}; the designs of the robustness study. "
             f"`python scripts/pem_boundary_study.py --runs {args.runs} --samples "
             f"{args.samples} --seed {args.seed}`", "",
             "| design | fit | param | coverage [Wilson 95 %] | bias z | median rel. err | "
             "SE / MC sd |", "|---|---|---|---|---|---|---|"]
    for _, r in summary.iterrows():
        lines.append(f"| {r.design} | {r.fit} | {r.param} | {100 * r.coverage:.1f} % "
                     f"[{100 * r.wilson_lo:.1f}, {100 * r.wilson_hi:.1f}] | {r.bias_z:+.2f} "
                     f"| {r.median_rel_err:.4f} | {r.se_over_sd:.2f} |")
    lines += ["", "Likelihood ratio of the bounded joint fit against the current model, and "
              "the share of runs where the unbounded variant reports the bounded joint fit "
              f"(converged, LR > {pem.LOCAL_LR:g}); the kurtosis z of the smoothed current "
              "(quantiles) and the share of runs where the one-sided test finds the current "
              "bimodal (its size on the Gaussian designs, its power on the telegraph one):",
              "",
              "| design | LR 10 % | LR 50 % | LR 90 % | LR > 2.71 | joint reported "
              "| kurtosis z 10 % / 50 % / 90 % | bimodal (α = 1 %) |",
              "|---|---|---|---|---|---|---|---|"]
    for design, g in df.groupby("design", sort=False):
        conv = g["joint_converged"].fillna(False).astype(bool).to_numpy()
        lr = g["lr"].astype(float).to_numpy() if "lr" in g else np.array([np.nan])
        q = np.nanquantile(lr, [0.1, 0.5, 0.9])
        zs = g["shape_z"].astype(float).to_numpy() if "shape_z" in g else np.array([np.nan])
        qz = np.nanquantile(zs, [0.1, 0.5, 0.9]) if np.isfinite(zs).any() else [np.nan] * 3
        bim = (g["shape_bimodal"].fillna(False).astype(bool).to_numpy()
               if "shape_bimodal" in g else np.zeros(1, dtype=bool))
        lines.append(f"| {design} | {q[0]:.2f} | {q[1]:.2f} | {q[2]:.2f} | "
                     f"{100 * np.mean(lr > 2.71):.1f} % | "
                     f"{100 * np.mean(conv & (lr > pem.LOCAL_LR)):.1f} % | "
                     f"{qz[0]:+.2f} / {qz[1]:+.2f} / {qz[2]:+.2f} | "
                     f"{100 * np.mean(bim):.1f} % |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = rs.study_parser(__doc__.split("\n\n")[0], runs=200, seed=7, designs=DESIGNS)
    args = ap.parse_args(argv)
    rs.check_study_args(ap, args)
    df = pd.DataFrame(rs.run_designs(args, lambda d, s, n: [one_run(d, s, n)]))
    summary = summarise(df)
    pd.set_option("display.width", 200)
    print(summary.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out / "robustness_boundary.csv",
                      summary.to_csv(index=False, float_format="%.5g"))
    atomic_write_text(args.out / "robustness_boundary.md", markdown(summary, df, args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
