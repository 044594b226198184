"""Which covariance should ``auto`` report where it takes the likelihood estimator?

``auto`` falls back to the prediction-error (quasi-ML) estimator of
:mod:`vesselid.identify.pem` where a coloured disturbance rejects its instruments, and
then reports one of three covariances of that fit: the inverse Fisher information, the
quasi-ML sandwich ``F⁻¹ Ŝ F⁻¹``, or the smallest covariance above both
(``conservative``, :func:`vesselid.identify.pem.conservative_covariance`; ``auto``'s
``pem_cov`` default). This study runs ``auto`` once per log (its batched path: the same
estimates and reported standard errors as ``identify(log, spec, "auto")``) and keeps,
for every run that took the likelihood estimator, the standard errors of all three, so
the coverage of each is measured on the same estimates. Per choice of ``auto`` and
parameter: runs, 95 % coverage with its Wilson interval, bias z, mean SE / Monte Carlo
sd, RMS SE / RMS error. With ``--details`` the runs that took the likelihood estimator
are fitted again with every candidate model kept (:func:`vesselid.identify.pem.fit_groups`
``details=True``): the single-process, the bounded joint and the unbounded joint fit
(its ``pem-*`` rows per candidate, on the same runs).

Designs: ``robustness:<design>`` (:mod:`robustness_study`'s heave model with its own θ0,
seeded as that script seeds the design) or ``calibration:<scenario>`` (the heave
scenarios of :data:`vesselid.studies.calibration.SCENARIOS`, seeded as
``scripts/calibration.py`` seeds them: run ``r`` of ``--runs`` is run ``r`` of the
calibration table)::

    nice -n 10 python scripts/pem_covariance_study.py robustness:gm-current --runs 1000 \\
        --seed 2025 --workers 2 --out docs/pem_covariance_gm_current.csv
    nice -n 10 python scripts/pem_covariance_study.py calibration:gm-sensor-random \\
        --runs 300 --details --workers 2
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices; threads only contend

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

from robustness_study import wilson  # the scripts folder, on the path above

from vesselid.core.fileio import atomic_write_text

COVS = ("fisher", "sandwich", "conservative")
Z95 = 1.959964


def _logs(design: str, seed: int, runs: range, samples: int):
    """``(spec, y (R, N, 1), u (R, N, 1))`` of the runs ``runs`` of ``design``."""
    kind, name = design.split(":", 1)
    if kind == "robustness":
        import robustness_study as rs

        d = rs.DESIGNS[name]
        seeds = rs.design_seeds(seed, name, runs.stop)
        logs = [rs.simulate(d, np.random.default_rng(seeds[r]), d.samples or samples)
                for r in runs]
        y = np.stack([lg["w"].to_numpy() for lg in logs])[:, :, None]
        u = np.stack([lg["tau"].to_numpy() for lg in logs])[:, :, None]
        return rs.SPEC, y, u
    from vesselid.studies.calibration import SCENARIOS, heave_scenario

    system, _, _ = heave_scenario(name)
    spec = system.identification_spec(aggregate=False)
    seeds = np.random.SeedSequence(seed + list(SCENARIOS).index(name)).spawn(runs.stop)
    sim = system.simulate(samples, run_seeds=seeds[runs.start:runs.stop])
    return spec, sim.y, sim.u


def chunk(design: str, seed: int, start: int, stop: int, samples: int,
          details: bool, options: tuple[tuple[str, int | float | str], ...] = ()
          ) -> list[dict]:
    """Per run of ``range(start, stop)`` and parameter: estimate, the reported SE and,
    where ``auto`` took the likelihood estimator, each covariance's SE."""
    from vesselid.identify import from_arrays, get_estimator, pem
    from vesselid.identify.covariance import DEFAULT_COV_TYPE
    from vesselid.studies.calibration import registry_covariances

    spec, y, u = _logs(design, seed, range(start, stop), samples)
    data = from_arrays(spec, y, u)
    if options:
        from vesselid.identify.efficient import InstrumentalGMM
        from vesselid.identify.registry import entry

        est = InstrumentalGMM(**{**entry("auto").options, **dict(options)})
    else:
        est = get_estimator("auto")
    it = est.estimate_parameters(data, spec)
    reported = registry_covariances(data, spec, it, "auto",
                                    {"d": (DEFAULT_COV_TYPE, {})}, estimator=est)["d"]
    used = it.info["instrument_set"]
    model = it.info.get("pem_model", np.full(data.n_groups, "", dtype=object))
    theta0 = np.asarray(spec.theta0_vector(), dtype=float)
    names = [f"{eq}: {term}" for eq, term in spec.param_index]
    took = np.flatnonzero(np.asarray(used) == "pem")
    cand: dict[str, np.ndarray] = {}
    if details and took.size:
        from vesselid.identify.efficient import _subset

        sub = _subset(data, np.isin(np.arange(data.n_groups), took))
        base = it.info["base"].theta[took]
        res = pem.fit_groups(sub, spec, base, joint=True, boundary=est.pem_boundary,
                             details=True)
        cand = {k: v for k, v in res.items()}
    rows = []
    for g in range(data.n_groups):
        choice = "pem-" + str(model[g]) if used[g] == "pem" else (
            {"simulated": "sriv"}.get(str(used[g]), str(used[g])))
        k = int(np.searchsorted(took, g)) if used[g] == "pem" else -1
        for j, p in enumerate(names):
            row = {"design": design, "run": start + g, "choice": choice, "param": p,
                   "theta0": theta0[j], "estimate": it.theta[g, j],
                   "se_reported": reported[g, j]}
            for c in COVS:
                key = "pem_" + pem.COVARIANCE_KEYS[c]
                row["se_" + c] = (np.sqrt(abs(it.info[key][g][j, j]))
                                  if used[g] == "pem" else reported[g, j])
            if cand and k >= 0:
                for pre in ("single_", "joint_", "local_"):
                    row[pre + "estimate"] = cand[pre + "theta"][k, j]
                    for c in COVS:
                        key = pre + pem.COVARIANCE_KEYS[c]
                        row[pre + "se_" + c] = np.sqrt(abs(cand[key][k][j, j]))
                row["joint_converged"] = bool(cand["joint_converged"][k])
                row["lr_joint"] = float(cand["lr_joint"][k])
                npar = len(names)
                for pre in ("single_", "joint_"):
                    for off, lab in ((3, "rho_c"), (4, "sigma_c"), (6, "sigma_e")):
                        row[pre + lab] = float(cand[pre + "psi"][k][npar + off])
            rows.append(row)
    return rows


def summarise(df: pd.DataFrame, est_col: str = "estimate", prefix: str = "") -> pd.DataFrame:
    """Per choice (``all`` first), parameter and covariance: coverage with Wilson interval,
    bias z, mean SE / MC sd, RMS SE / RMS error (the sd and bias of the whole design)."""
    out = []
    for p, gp in df.groupby("param", sort=False):
        err_all = gp[est_col] - gp["theta0"]
        sd = float(err_all.std(ddof=1))
        for choice in ["all", *sorted(gp["choice"].unique())]:
            g = gp if choice == "all" else gp[gp["choice"] == choice]
            err = g[est_col] - g["theta0"]
            ok = np.isfinite(err)
            for c in ("reported", *COVS):
                if prefix + "se_" + c not in g:
                    continue
                se = g[prefix + "se_" + c]
                good = ok & np.isfinite(se)
                r = int(good.sum())
                if r == 0:
                    continue
                e, s = err[good], se[good]
                hit = int((np.abs(e) <= Z95 * s).sum())
                lo, hi = wilson(hit, r)
                sd_g = float(e.std(ddof=1)) if r > 1 else float("nan")
                out.append({"param": p, "choice": choice, "covariance": c, "runs": r,
                            "coverage": hit / r, "wilson_lo": lo, "wilson_hi": hi,
                            "bias_z": float(e.mean() / (sd_g / np.sqrt(r))) if r > 1
                            and sd_g > 0 else float("nan"),
                            "se_over_sd": float(s.mean() / sd),
                            "se_over_sd_group": float(s.mean() / sd_g) if r > 1 else np.nan,
                            "rms_se_over_rms_err": float(np.sqrt(np.mean(s * s))
                                                         / np.sqrt(np.mean(e * e)))})
    return pd.DataFrame(out)


def _value(text: str) -> int | float | str:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("design", help="robustness:<design> or calibration:<scenario>")
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--samples", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=None,
                    help="root seed (default: the source table's: 2024 robustness, "
                         "0 calibration)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--chunk", type=int, default=25, help="runs per batched estimate")
    ap.add_argument("--details", action="store_true",
                    help="also every candidate likelihood fit on the runs that took one")
    ap.add_argument("--auto-option", action="append", default=[], metavar="KEY=VALUE",
                    help="run auto with this InstrumentalGMM option changed (repeatable; "
                         "e.g. colour_order=2; with --from-raw: the options the raw file "
                         "was made with, for the page's command line)")
    ap.add_argument("--raw", type=Path, default=None, help="write every run's rows")
    ap.add_argument("--from-raw", type=Path, default=None,
                    help="summarise a file --raw wrote (no simulation)")
    ap.add_argument("--out", type=Path, default=None, help="write the summary CSV")
    ap.add_argument("--md", type=Path, default=None,
                    help="write the summary as a Markdown page (the command line on it)")
    args = ap.parse_args(argv)
    kind, _, name = args.design.partition(":")
    if kind not in ("robustness", "calibration") or not name:
        ap.error("design must be robustness:<design> or calibration:<scenario>")
    seed = args.seed if args.seed is not None else (2024 if kind == "robustness" else 0)
    if args.from_raw is not None:
        df = pd.read_csv(args.from_raw)
    else:
        t0 = time.perf_counter()
        bounds = [(a, min(a + args.chunk, args.runs)) for a in range(0, args.runs, args.chunk)]
        options = tuple((k, _value(v)) for k, _, v in
                        (o.partition("=") for o in args.auto_option))
        jobs = [(args.design, seed, a, b, args.samples, args.details, options)
                for a, b in bounds]
        rows: list[dict] = []
        if args.workers > 1:
            with ProcessPoolExecutor(args.workers) as ex:
                for i, part in enumerate(ex.map(chunk, *zip(*jobs, strict=True))):
                    rows += part
                    print(f"{bounds[i][1]} runs: {time.perf_counter() - t0:.0f} s",
                          file=sys.stderr, flush=True)
        else:
            for i, job in enumerate(jobs):
                rows += chunk(*job)
                print(f"{bounds[i][1]} runs: {time.perf_counter() - t0:.0f} s",
                      file=sys.stderr, flush=True)
        df = pd.DataFrame(rows)
        if args.raw is not None:
            atomic_write_text(args.raw, df.to_csv(index=False))
    summary = summarise(df)
    pd.set_option("display.width", 220)
    print(f"{args.design}: {df['run'].nunique()} runs, seed {seed}")
    print(summary.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    extra: dict[str, pd.DataFrame] = {}
    if "single_estimate" in df:
        pe = df[df["choice"].str.startswith("pem")]
        for pre in ("single_", "joint_", "local_"):
            s = summarise(pe, est_col=pre + "estimate", prefix=pre)
            extra[pre.rstrip("_")] = s
            print(f"\ncandidate {pre.rstrip('_')} on the runs that took the likelihood "
                  "estimator (sd: of that candidate on those runs)")
            print(s.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    if args.out is not None:
        atomic_write_text(args.out, summary.to_csv(index=False, float_format="%.5g"))
    if args.md is not None:
        cmd = (f"python scripts/pem_covariance_study.py {args.design} --runs "
               f"{df['run'].nunique()} --seed {seed} --samples {args.samples}"
               + (" --details" if "single_estimate" in df else "")
               + "".join(f" --auto-option {o}" for o in args.auto_option) + " --md ...")
        atomic_write_text(args.md, markdown(summary, args.design, seed, cmd, extra))
    return 0


def markdown(summary: pd.DataFrame, design: str, seed: int, cmd: str,
             candidates: dict[str, pd.DataFrame] | None = None) -> str:
    """The summary as a Markdown page: per parameter, choice and covariance (and, with
    ``candidates``, a table per candidate likelihood fit on the same runs)."""
    runs = int(summary.loc[summary["choice"] == "all", "runs"].max())
    lines = ["---", "orphan: true", "---", "",
             f"# Covariance of `auto`'s likelihood fallback: {design}", "",
             *_table(summary, f"{runs} runs, seed {seed}: `{cmd}`. `reported`: what "
                     "`auto` reports (`identify(log, spec, \"auto\")`); `fisher`, "
                     "`sandwich`, `conservative`: the likelihood fit's inverse Fisher "
                     "information, quasi-ML sandwich and the smallest covariance above "
                     "both, on the runs that took the likelihood estimator (the other "
                     "runs' reported SE in every row). SE / MC sd: the mean SE over the "
                     "design's Monte Carlo sd (all runs); RMS SE / RMS err: within the "
                     "row's runs.")]
    for name, tab in (candidates or {}).items():
        lines += ["", f"## Candidate fit `{name}` on the runs that took the likelihood "
                  "estimator", "",
                  *_table(tab, f"`{name}`: " + {
                      "single": "the better single-process model (current or sensor "
                                "noise)",
                      "joint": "both processes at once, the sensor-noise variance "
                               "bounded at zero",
                      "local": "the joint model's unbounded one-step estimate (where "
                               "computed)"}[name]
                      + "; rows per `auto` choice; SE / MC sd over that candidate's "
                        "Monte Carlo sd on these runs.")]
    return "\n".join(lines) + "\n"


def _table(summary: pd.DataFrame, text: str) -> list[str]:
    lines = [text, "",
             "| parameter | choice | covariance | runs | coverage [Wilson 95 %] | bias z "
             "| SE / MC sd | RMS SE / RMS err |", "|---|---|---|---|---|---|---|---|"]
    for _, r in summary.iterrows():
        lines.append(f"| {r.param} | {r.choice} | {r.covariance} | {r.runs} | "
                     f"{100 * r.coverage:.1f} % [{100 * r.wilson_lo:.1f}, "
                     f"{100 * r.wilson_hi:.1f}] | {r.bias_z:+.2f} | {r.se_over_sd:.3f} | "
                     f"{r.rms_se_over_rms_err:.3f} |")
    return lines


if __name__ == "__main__":
    sys.exit(main())
