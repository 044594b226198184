"""``vesselid select``: choose the modulus terms of a model from a trial log (CLI plugin)."""

from __future__ import annotations

import argparse
import sys
import warnings

from vesselid.cli.common import check_output_file, int_at_least, write_json

__all__ = ["add_arguments", "cmd_select"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``vesselid select``."""
    p.add_argument("log", help="trial log (CSV with its JSON sidecar, or Parquet)")
    p.add_argument("--model", metavar="BASE.toml",
                   help="base spec: states, inputs, dt, aggregate relations, and equations "
                        "whose fit simulates the first instruments (default: the log's spec)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--library", metavar="TERMS", default=None,
                     help="candidates: 'full' (every Definition 2.1 form over states and "
                          "inputs, default), 'vessel' (state forms; inputs linear and times "
                          "states), 'u, v, u*|u|' (every equation) or 'u: u, u*|u|; v: v'")
    src.add_argument("--candidates", metavar="SPEC.toml",
                     help="a spec whose [equations] table lists each equation's candidates")
    p.add_argument("--out", required=True, metavar="SPEC.toml",
                   help="write the selected spec (with the selection report as comments)")
    p.add_argument("--json", metavar="PATH|-", help="write the full report as JSON ('-' = stdout)")
    p.add_argument("--alpha", type=float, default=0.01,
                   help="family-wise level of the Wald tests (Bonferroni; default 0.01)")
    p.add_argument("--bootstrap", type=int_at_least(0), default=100,
                   help="block-bootstrap replicates for the selection probabilities (default 100)")
    p.add_argument("--block-length", type=int_at_least(2), default=None,
                   help="samples per block of the HAC estimator and the bootstrap")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    p.add_argument("--first-model", choices=("base", "library"), default="base",
                   help="auxiliary model of the first pass's instruments: the base model "
                        "(default) or every candidate of the library fitted by IV from "
                        "the base model's instruments")
    p.set_defaults(func=cmd_select)


def cmd_select(args: argparse.Namespace) -> int:
    """Run the selection, write the spec (and JSON), print the report."""

    check_output_file("--out", args.out)
    if args.json and args.json != "-":
        check_output_file("--json", args.json)
    from vesselid.core import jsonio as _json
    from vesselid.data.logs import TrialLog
    from vesselid.errors import CLIError
    from vesselid.model.spec import ModelSpec
    from vesselid.selection import select_terms
    from vesselid.selection.library import library_from_spec

    spec = ModelSpec.load(args.model) if args.model else None
    log = TrialLog.load(args.log, spec=spec)
    spec = spec or log.spec
    if spec is None:
        raise CLIError(f"{args.log} carries no model spec; pass --model BASE.toml")
    library = (library_from_spec(args.candidates, spec) if args.candidates
               else ("full" if args.library is None else args.library))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = select_terms(log, spec, library, alpha=args.alpha, n_boot=args.bootstrap,
                           block_length=args.block_length, seed=args.seed,
                           first_model=args.first_model)
    res.save(args.out)
    if args.json:
        write_json(args.json, _json.dumps(res.to_dict(), indent=2))
    out = sys.stderr if args.json == "-" else sys.stdout
    print(res.summary(), file=out)
    print(f"wrote {args.out}", file=out)
    return 0
