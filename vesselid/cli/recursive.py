"""``vesselid recursive``: recursive (online) LS / IV over a trial log
(:mod:`vesselid.identify.recursive`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from vesselid.cli.common import int_at_least
from vesselid.errors import CLIError

__all__ = ["add_arguments", "cmd_recursive"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``vesselid recursive``."""
    p.add_argument("log", help="trial log (.csv + .json sidecar, or .parquet)")
    p.add_argument("--model", help="model spec TOML (default: the log's)")
    p.add_argument("--method", choices=["iv", "ls"], default="iv")
    p.add_argument("--forgetting", type=float, default=1.0, help="λ in (0, 1]")
    p.add_argument("--instruments", choices=["delayed", "auxiliary"], default="delayed",
                   help="RIV instruments; 'auxiliary' simulates the model of --theta-aux "
                        "(default: the batch IV_E{ζ}=0 estimate of the log)")
    p.add_argument("--delay", type=int_at_least(1), default=1)
    p.add_argument("--history", help="write θ̂ every --every samples to this CSV")
    p.add_argument("--every", type=int_at_least(1), default=100)
    p.set_defaults(func=cmd_recursive)


def cmd_recursive(args: argparse.Namespace) -> int:
    """``vesselid recursive``: recursive LS / IV over a log."""
    from vesselid.identify.recursive import check_forgetting, recursive_estimate

    lam = check_forgetting(args.forgetting)  # before reading anything
    if args.history and Path(args.history).suffix.lower() != ".csv":
        raise CLIError(f"--history must end in .csv, got {args.history!r}")
    from vesselid.data.logs import TrialLog
    from vesselid.model.spec import ModelSpec

    log = TrialLog.load(args.log)
    spec = ModelSpec.load(args.model) if args.model else log.spec
    if spec is None:
        raise CLIError("the log carries no model spec; pass --model SPEC.toml")
    opts: dict[str, Any] = {"instruments": args.instruments, "delay": args.delay}
    if args.method == "ls":
        opts = {}
    elif args.instruments == "auxiliary":
        from vesselid.identify import identify

        opts["theta_aux"] = identify(log, spec, "iv-zero-mean").params.to_numpy()
    res = recursive_estimate(log, spec, args.method, forgetting=lam,
                             history_every=args.every if args.history else 0, **opts)
    print(f"recursive {args.method.upper()} (λ = {lam:g}"
          + (f", {args.instruments} instruments" if args.method == "iv" else "") + ")")
    for name, val in res.params.items():
        print(f"  {name[0]}: {name[1]:<14} {val: .6g}" if isinstance(name, tuple)
              else f"  {name}: {val: .6g}")
    if not res.ready:
        print("warning: an equation did not finish its warm-up (too few samples)",
              file=sys.stderr)
    if args.history:
        from vesselid.core.fileio import atomic_write_text

        hist = res.history
        hist.columns = [f"{e}: {t}" for e, t in hist.columns] if isinstance(
            hist.columns[0], tuple) else hist.columns
        atomic_write_text(args.history, hist.to_csv())
        print(f"wrote {args.history} ({len(hist)} rows)")
    return 0
