"""``vesselid reproduce``: the paper's Tables 1–2 and Figure 1
(:mod:`vesselid.studies.reproduce`)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from vesselid.cli.common import int_at_least
from vesselid.core.fileio import atomic_write_text, check_parents, strict_json
from vesselid.errors import VesselidError
from vesselid.identify.registry import ESTIMATORS
from vesselid.studies.reproduce import EXTRA_METHODS, PULSES, TARGETS, reproduce, tables_of


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``vesselid reproduce``."""
    p.add_argument("--table", default="all", choices=["1", "2", "all"])
    p.add_argument("--runs", type=int_at_least(2), default=1000,
                   help="Monte Carlo runs (paper: 1000)")
    p.add_argument("--samples", type=int_at_least(10), default=10_000,
                   help="samples per run (paper: 10⁴)")
    p.add_argument("--seed", type=int_at_least(0), default=0)
    p.add_argument("--out", metavar="DIR", help="write figures, tidy results and summary.json")
    p.add_argument("--json", metavar="PATH|-", help="write the summary as JSON ('-' = stdout)")
    p.add_argument("--xi-mean", default="literal", metavar="literal|FLOAT",
                   help="mean of ξ in Table 2: 'literal' = w̄c − 0.05 (§6, default) or a "
                        "number such as -0.05")
    p.add_argument("--target", default="aggregated", choices=list(TARGETS),
                   help="Table 2 regression target: ỹ(k) (default, reproduces the published "
                        "rows) or y1(k) as in eq. (10)")
    p.add_argument("--pulses", default="alternating", choices=list(PULSES),
                   help="input design: alternating 0.1/0.3 pulses of 1-20 samples (default) "
                        "or random levels in [0.1, 0.3] held 10-100 samples")
    p.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address")
    p.add_argument("--batch-size", type=int_at_least(1), default=None, help="runs per chunk")
    p.add_argument("--format", default="csv", choices=["csv", "parquet"],
                   help="format of the tidy results in --out")
    p.add_argument("--extra", nargs="+", metavar="METHOD", default=None,
                   help="estimators shown as extra rows after the paper's three (default: "
                        f"{' '.join(EXTRA_METHODS) or 'none'}); 'none' = the paper's rows only")
    p.add_argument("--strict", action="store_true",
                   help="exit with code 1 when a claim of the paper does not hold")
    p.set_defaults(func=cmd_reproduce)


def _guard(args: argparse.Namespace) -> None:
    """Refuse sizes or output paths that cannot work before running anything."""
    from vesselid.core import limits
    from vesselid.studies.montecarlo import DEFAULT_BATCH_SIZE

    for opt, value in (("--out", args.out), ("--json", args.json)):
        if value is None or value == "-":
            continue
        path = Path(value)
        if opt == "--out" and path.exists() and not path.is_dir():
            raise NotADirectoryError(20, "--out must be a directory, not an existing file",
                                     str(path))
        if opt == "--json" and path.is_dir():
            raise IsADirectoryError(21, "--json path is a directory", str(path))
        check_parents(path)
    n_tables = len(tables_of(args.table))
    batch = min(args.runs, args.batch_size or DEFAULT_BATCH_SIZE)
    # per batch: ~40 float64 arrays of samples per run (signals, states, regressors,
    # instruments), one batch per core at a time; results: 9 tidy rows of ~150 B per run
    # and table
    concurrent = max(1, min(os.cpu_count() or 1, -(-args.runs // batch)))
    memory = (limits.BASE_MEMORY + 40.0 * 8.0 * batch * args.samples * concurrent
              + 1500.0 * args.runs * n_tables)
    seconds = 3e-7 * n_tables * args.runs * args.samples
    limits.check("reproduce", f"{n_tables} table(s) × {args.runs} runs × {args.samples} samples",
                 memory=memory, seconds=seconds)


def _extra(names: list[str] | None) -> tuple[str, ...] | None:
    """``--extra``: ``None`` (default rows), ``none`` (paper rows only) or estimator names."""
    if names is None:
        return None
    if names == ["none"]:
        return ()
    unknown = [m for m in names if m not in ESTIMATORS]
    if unknown or "none" in names:
        raise VesselidError(f"--extra: unknown estimator(s) {unknown or ['none']}: give 'none' "
                            f"alone or names from {list(ESTIMATORS)}")
    return tuple(dict.fromkeys(names))


def cmd_reproduce(args: argparse.Namespace) -> int:
    if args.runs < 2 or args.samples < 10:
        raise VesselidError("need --runs >= 2 and --samples >= 10")
    if args.batch_size is not None and args.batch_size < 1:
        raise VesselidError("--batch-size must be positive")
    extras = _extra(args.extra)
    _guard(args)
    res = reproduce(
        table=args.table, runs=args.runs, samples=args.samples, seed=args.seed, out=args.out,
        xi_mean=args.xi_mean, target=args.target, pulses=args.pulses, client=args.scheduler,
        batch_size=args.batch_size, results_format=args.format,
        extra_methods=extras,
    )
    payload = res.to_dict()
    if args.json == "-":
        print(strict_json(payload, indent=2))
    else:
        print(res.to_text())
        if args.json:
            atomic_write_text(args.json, strict_json(payload, indent=2) + "\n")
            print(f"wrote {args.json}")
    if args.strict and not res.ok:
        return 1
    return 0
