"""Evidence for the result diagnostics (docs/guide/diagnostics.md).

Two studies, each printing one table:

``convergence``
    The planned CyberShip II trial, ``vesselid sea-trial --vessel cybership2 --experiments 6
    --samples 20000 --seed S`` then ``vesselid identify --json`` with the defaults, for each
    seed: the exit code, ``converged``, ``status``, iterations, the standard-error figures of
    the stopping rule (averaged step and location of a stalled iteration, in the IV_E{ζ}=0
    iteration's own standard errors) and the estimator that answered.
``smoothness``
    The A10/A15 warning on the paper's Table 1 designs (heave, white disturbances,
    alternating and random pulses): the share of runs on which the share-of-samples rule
    (more than 1 % within η = 3σ of zero in some experiment) flags the design, and on which
    ``identify`` warns (the non-smoothness bias reaches
    :data:`vesselid.identify.diagnostics.SMOOTHNESS_BIAS_SE` standard errors), with the distribution
    of that bias.

Usage::

    python scripts/diagnostics_study.py convergence --seeds 0-9 --out /tmp/trials
    python scripts/diagnostics_study.py smoothness --runs 200 --samples 10000
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import warnings
from pathlib import Path

import numpy as np


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def _fmt(value: object) -> str:
    return f"{value:.3f}" if isinstance(value, float) else "-"


def convergence(seeds: list[int], out: Path) -> None:
    from vesselid.cli import main

    print("seed | exit | converged | status | iterations | mean step (SE) | location (SE) | "
          "method")
    for seed in seeds:
        trial = out / f"seatrial-{seed}"
        if not (trial / "seatrial.parquet").exists():
            with contextlib.redirect_stdout(io.StringIO()):
                main(["sea-trial", "--vessel", "cybership2", "--experiments", "6",
                      "--samples", "20000", "--seed", str(seed), "--out", str(trial)])
        report = trial / "identify.json"
        with contextlib.redirect_stdout(io.StringIO()), \
                contextlib.redirect_stderr(io.StringIO()):
            code = main(["identify", str(trial / "seatrial.parquet"), "--model",
                         str(trial / "cybership2.toml"), "--json", str(report)])
        d = json.loads(report.read_text())
        avg = d["diagnostics"].get("stall_average") or {}
        print(f"{seed} | {code} | {d['converged']} | {d['status']} | {d['iterations']} | "
              f"{_fmt(avg.get('mean_step_se'))} | {_fmt(avg.get('location_se'))} | "
              f"{d['method']}", flush=True)


def smoothness(runs: int, samples: int, seed: int) -> None:
    from vesselid.errors import ExperimentDesignWarning
    from vesselid.identify import identify
    from vesselid.studies.calibration import heave_scenario

    print("design | runs | share rule flags | identify warns | median share within 3σ | "
          "bias (SE) median / 95th pct / max")
    for name in ("table1-alternating", "table1-random"):
        system, aggregate, _ = heave_scenario(name)
        spec = system.identification_spec(aggregate=aggregate)
        flagged = warned = 0
        bias, share = [], []
        for r in range(runs):
            log = system.simulate(samples, n_runs=1, seed=seed + r).to_log()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                res = identify(log, spec)
            warned += any(issubclass(w.category, ExperimentDesignWarning) for w in caught)
            flagged += int(not res.diagnostics["design"]["ok"].all())
            rep = res.diagnostics["smoothness"]["w"]
            bias.append(rep["bias_se"])
            share.append(rep["share_within_eta"])
        b = np.asarray(bias, dtype=float)
        print(f"{name} | {runs} | {100 * flagged / runs:.1f} % | {100 * warned / runs:.1f} % | "
              f"{100 * np.median(share):.1f} % | {np.median(b):.3f} / "
              f"{np.percentile(b, 95):.3f} / {b.max():.3f}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="study", required=True)
    c = sub.add_parser("convergence")
    c.add_argument("--seeds", default="0-9")
    c.add_argument("--out", type=Path, default=Path("diagnostics-study"))
    s = sub.add_parser("smoothness")
    s.add_argument("--runs", type=int, default=200)
    s.add_argument("--samples", type=int, default=10_000)
    s.add_argument("--seed", type=int, default=1000)
    args = parser.parse_args()
    if args.study == "convergence":
        convergence(_seeds(args.seeds), args.out)
    else:
        smoothness(args.runs, args.samples, args.seed)


if __name__ == "__main__":
    main()
