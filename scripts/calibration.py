"""Calibration study: do the reported 95 % intervals cover θ0 in 95 % of runs?

Runs the package's default estimator on every heave scenario of
:data:`vesselid.studies.calibration.SCENARIOS` (Table 1 with alternating and random pulses,
Table 2, a Gauss–Markov current with time constant 25 samples and Gauss–Markov
sensor noise with time constant 20 samples, both pulse designs) and on the
CyberShip II sea trial (6 × 2·10⁴ samples), computes each run's covariance with
several covariance estimators, and prints per scenario and parameter the coverage
with its Wilson interval and the ratio of the reported SE to the Monte Carlo spread.
Writes ``docs/calibration.csv`` (the table) and ``docs/calibration.png`` (coverage
per parameter and scenario with Wilson bars).

    python scripts/calibration.py                  # 1000 heave runs, 400 sea-trial runs
    python scripts/calibration.py --quick          # smoke run
    python scripts/calibration.py --scenarios "" --update   # the sea trial only, keep the
                                                            # heave rows of the CSV
    python scripts/calibration.py --by-choice gm-sensor-random --runs 300
        # coverage per choice of ``auto`` on the scenario's first 300 runs (no files)
    python scripts/calibration.py --by-choice gm-sensor-random --runs 300 --pem-level 1
        # the same with ``auto``'s likelihood fallback on any rejection
    python scripts/calibration.py --by-choice gm-sensor-random --runs 300 --colour-guard 0
        # the same without ``auto``'s colour guard
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices; threads only contend

import numpy as np
import pandas as pd

from vesselid.core.fileio import atomic_write_text, atomic_write_with
from vesselid.identify.covariance import DEFAULT_COV_TYPE
from vesselid.studies.calibration import SCENARIOS, coverage_study, seatrial_coverage

DOCS = Path(__file__).resolve().parents[1] / "docs"

#: Covariance estimators compared (label -> (cov_type, cov_config)); the first is the default.
CANDIDATES = {
    "hac (default: Bartlett, Newey-West bandwidth)": (DEFAULT_COV_TYPE, {}),
    "unadjusted": ("unadjusted", {}),
    "hac default without the Windmeijer correction": (DEFAULT_COV_TYPE, {"windmeijer": False}),
    "hac default without the fixed-b critical values": (DEFAULT_COV_TYPE, {"fixed_b": False}),
    "hac Bartlett, Andrews AR(1) bandwidth": ("hac", {"kernel": "bartlett",
                                                       "bandwidth": "andrews"}),
    "hac QS, Newey-West bandwidth": ("hac", {"kernel": "qs"}),
    "hac Bartlett, Newey-West, VAR(1) pre-whitened": ("hac", {"prewhiten": True}),
}


def plot(df: pd.DataFrame, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    labels = list(dict.fromkeys(df["covariance"]))[:2]
    scen = list(dict.fromkeys(df["scenario"]))
    fig = Figure(figsize=(11, 4.6), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    x0 = 0
    ticks, ticklabels = [], []
    for s in scen:
        sub = df[df["scenario"] == s]
        params = list(dict.fromkeys(sub["parameter"]))
        for k, lab in enumerate(labels):
            t = sub[sub["covariance"] == lab].set_index("parameter").loc[params]
            xs = x0 + np.arange(len(params)) + (k - 0.5) * 0.3
            ax.errorbar(xs, 100 * t["coverage"],
                        # clipped: at 0 or 100 % the Wilson bound equals the coverage to
                        # rounding, which can leave a bar of -1e-14
                        yerr=[100 * (t["coverage"] - t["wilson_low"]).clip(lower=0),
                              100 * (t["wilson_high"] - t["coverage"]).clip(lower=0)],
                        fmt="o" if k == 0 else "s", ms=3, lw=1, capsize=1.5,
                        color="C0" if k == 0 else "0.6", label=lab if s == scen[0] else None)
        ticks.append(x0 + (len(params) - 1) / 2)
        ticklabels.append("\n".join(s.rsplit("-", 1)) + f"\n({int(sub['runs'].max())} runs)")
        x0 += len(params) + 1
    ax.axhspan(93, 97, color="C2", alpha=0.15, label="target 93–97 %")
    ax.axhline(95, color="C2", lw=0.8)
    ax.set_xticks(ticks, ticklabels, fontsize=7)
    ax.set_ylabel("coverage of nominal 95 % intervals (%)")
    ax.set_ylim(max(0, 100 * df["wilson_low"].min() - 5), 100.5)
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title("Calibration: coverage per parameter (Wilson 95 % bars)", fontsize=9)
    atomic_write_with(path, lambda p: fig.savefig(p, dpi=80, format="png"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--seatrial-runs", type=int, default=400)
    ap.add_argument("--samples", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--quick", action="store_true", help="40 heave runs, 4 sea-trial runs")
    ap.add_argument("--out", type=Path, default=DOCS)
    ap.add_argument("--update", action="store_true",
                    help="keep the rows of the scenarios not run from the existing CSV")
    ap.add_argument("--by-choice", metavar="SCENARIO", default=None,
                    help="print the coverage per choice of auto on SCENARIO's first --runs "
                         "runs and exit (writes nothing)")
    ap.add_argument("--pem-level", type=float, default=None,
                    help="with --by-choice: auto's pem_level (the likelihood fallback where "
                         "a test rejects at this times its level; default: the registered)")
    ap.add_argument("--colour-guard", type=float, default=None,
                    help="with --by-choice: auto's colour_guard (0: none; default: the "
                         "registered)")
    args = ap.parse_args(argv)
    if args.pem_level is not None and not (args.by_choice and 0 < args.pem_level <= 1):
        ap.error("--pem-level needs --by-choice and a value in (0, 1]")
    if args.colour_guard is not None and not (args.by_choice and 0 <= args.colour_guard < 1):
        ap.error("--colour-guard needs --by-choice and a value in [0, 1)")
    runs = 40 if args.quick else args.runs
    if args.by_choice is not None:
        if args.by_choice not in SCENARIOS:
            ap.error(f"unknown scenario {args.by_choice!r}; choose from {list(SCENARIOS)}")
        if runs < 2:
            ap.error("--runs must be at least 2")
        print(by_choice(args.by_choice, runs, args.samples, args.seed,
                        args.pem_level, args.colour_guard).to_string(
            index=False, float_format=lambda x: f"{x:.3g}"))
        return 0
    sea_runs = 4 if args.quick else args.seatrial_runs
    names = [s for s in args.scenarios.split(",") if s]
    unknown = sorted(set(names) - set(SCENARIOS))
    if unknown:
        ap.error(f"unknown scenarios {unknown}; choose from {list(SCENARIOS)}")
    frames = []
    for name in names:
        t0 = time.time()
        # a scenario's seed is fixed by its place in SCENARIOS, so a subset (--update)
        # reruns exactly the runs of the full table
        df = coverage_study(name, runs, samples=args.samples,
                            seed=args.seed + list(SCENARIOS).index(name),
                            covariances=CANDIDATES)
        frames.append(df)
        print(f"{name}: {time.time() - t0:.0f} s", flush=True)
        print(_short(df), flush=True)
    if sea_runs:
        t0 = time.time()
        df = seatrial_coverage(sea_runs, seed=args.seed, covariances=CANDIDATES)
        frames.append(df)
        print(f"seatrial: {time.time() - t0:.0f} s", flush=True)
        print(_short(df), flush=True)
    out = pd.concat(frames, ignore_index=True)
    old_csv = args.out / "calibration.csv"
    if args.update and old_csv.exists():
        old = pd.read_csv(old_csv)
        old = old[~old["scenario"].isin(out["scenario"].unique())]
        out = pd.concat([old, out], ignore_index=True)
        # the table's order: the heave scenarios as in SCENARIOS, then the sea trial
        rank = {s: i for i, s in enumerate([*SCENARIOS, "seatrial"])}
        out = out.sort_values("scenario", kind="stable",
                              key=lambda c: c.map(rank)).reset_index(drop=True)
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out / "calibration.csv", out.to_csv(index=False, float_format="%.5g"))
    plot(out, args.out / "calibration.png")
    print("\nmarkdown (default covariance):\n")
    print(markdown(out[out["covariance"] == next(iter(CANDIDATES))]))
    return 0


def by_choice(scenario: str, runs: int, samples: int, seed: int,
              pem_level: float | None = None,
              colour_guard: float | None = None) -> pd.DataFrame:
    """Coverage of the default covariance per choice of ``auto`` on the first ``runs``
    runs of a heave scenario (the seeds of the table): which branch of the choice loses
    coverage. Per choice: runs, coverage, mean error and root-mean-square error in units
    of the scenario's Monte Carlo sd, and mean SE / that sd. ``pem_level``,
    ``colour_guard``: ``auto`` with that option
    (:class:`vesselid.identify.efficient.InstrumentalGMM`)."""
    from vesselid.identify import from_arrays, get_estimator
    from vesselid.studies.calibration import heave_scenario, registry_covariances

    system, _, _ = heave_scenario(scenario)
    spec = system.identification_spec(aggregate=False)
    seeds = np.random.SeedSequence(seed + list(SCENARIOS).index(scenario)).spawn(runs)
    sim = system.simulate(samples, run_seeds=seeds)
    data = from_arrays(spec, sim.y, sim.u)
    changed = {k: v for k, v in (("pem_level", pem_level), ("colour_guard", colour_guard))
               if v is not None}
    if not changed:
        est = get_estimator("auto")
    else:
        from vesselid.identify.efficient import InstrumentalGMM
        from vesselid.identify.registry import entry

        est = InstrumentalGMM(**{**entry("auto").options, **changed})
    it = est.estimate_parameters(data, spec)
    se = registry_covariances(data, spec, it, "auto", {"d": (DEFAULT_COV_TYPE, {})})["d"]
    used = it.info["instrument_set"]
    model = it.info.get("pem_model", np.full(runs, "", dtype=object))
    keys = np.array([{"simulated": "sriv"}.get(u, u) if u != "pem" else f"pem-{m}"
                     for u, m in zip(used, model, strict=True)])
    err = it.theta - np.asarray(spec.theta0_vector(), dtype=float)
    sd = err.std(0, ddof=1)
    rows = []
    for key in ["all", *sorted(set(keys))]:
        sel = np.ones(runs, dtype=bool) if key == "all" else keys == key
        for j, name in enumerate(f"{eq}: {term}" for eq, term in spec.param_index):
            e, s_ = err[sel, j], se[sel, j]
            rows.append({"choice": key, "parameter": name, "runs": int(sel.sum()),
                         "coverage": float(np.mean(np.abs(e) <= 1.959964 * s_)),
                         "mean_err_over_sd": float(e.mean() / sd[j]),
                         "rms_err_over_sd": float(np.sqrt(np.mean(e * e)) / sd[j]),
                         "se_over_sd": float(s_.mean() / sd[j])})
    return pd.DataFrame(rows)


def _short(df: pd.DataFrame) -> str:
    t = df.assign(cov=lambda d: (100 * d["coverage"]).round(1),
                  wilson=lambda d: [f"[{100 * a:.1f}, {100 * b:.1f}]"
                                    for a, b in zip(d["wilson_low"], d["wilson_high"],
                                                    strict=True)],
                  ratio=lambda d: d["se_ratio"].round(2),
                  robust=lambda d: d["se_ratio_robust"].round(2),
                  bias_z=lambda d: d["bias_z"].round(1))
    return t[["covariance", "parameter", "runs", "cov", "wilson", "ratio", "robust",
              "bias_z"]].to_string(index=False)


def markdown(df: pd.DataFrame) -> str:
    lines = ["| scenario | parameter | runs | coverage % | Wilson 95 % | SE / MC sd "
             "| median SE / robust sd | bias (z) |",
             "|---|---|---|---|---|---|---|---|"]
    for _, r in df.iterrows():
        lines.append(f"| {r['scenario']} | {r['parameter']} | {r['runs']} | "
                     f"{100 * r['coverage']:.1f} | [{100 * r['wilson_low']:.1f}, "
                     f"{100 * r['wilson_high']:.1f}] | {r['se_ratio']:.2f} | "
                     f"{r['se_ratio_robust']:.2f} | {r['bias_z']:.1f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
