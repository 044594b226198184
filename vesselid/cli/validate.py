"""``vesselid validate``: an identified model on held-out experiments
(:mod:`vesselid.validation.report`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vesselid.cli.common import check_output_file, int_at_least, write_json
from vesselid.validation.report import DEFAULT_HORIZON, ValidationError, validate


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``vesselid validate``."""
    p.add_argument("log", help="trial log (.csv with optional .json sidecar, or .parquet)")
    p.add_argument("--model", required=True,
                   help="identified model TOML (identify --export) or a spec with [theta0]")
    p.add_argument("--experiments", metavar="ID[,ID...]",
                   help="held-out experiments to validate on (default: every experiment)")
    p.add_argument("--horizon", type=int_at_least(1), default=DEFAULT_HORIZON,
                   help=f"steps of the k-step-ahead prediction (default {DEFAULT_HORIZON})")
    p.add_argument("--rudder", default="delta", help="rudder input column (default delta)")
    p.add_argument("--manoeuvres", metavar="FILE.toml",
                   help="nominal test settings per experiment, e.g. [Z_10_05] psi_switch_deg = 5 "
                        "(default: the log's metadata, else read off the heading)")
    p.add_argument("--plot", metavar="PATH", help="write the measured-vs-simulated figure")
    p.add_argument("--json", metavar="PATH|-", help="write the report as JSON ('-' = stdout)")
    p.set_defaults(func=cmd_validate)


def _read_manoeuvres(path: str) -> dict[str, dict[str, float]]:
    """``--manoeuvres FILE.toml``: ``[experiment] psi_switch_deg = ...`` tables."""
    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ValidationError(f"--manoeuvres {path}: invalid TOML: {exc}") from exc
    for key, entry in data.items():
        if not isinstance(entry, dict) or set(entry) - {"psi_switch_deg", "delta0_deg"}:
            raise ValidationError(f"--manoeuvres {path}: [{key}] must hold psi_switch_deg "
                                  f"(and optionally delta0_deg), got {entry!r}")
    return data


def cmd_validate(args: argparse.Namespace) -> int:
    """``vesselid validate``: print the report, write JSON / figure on request."""

    for option, target in (("--json", args.json), ("--plot", args.plot)):
        if target and target != "-":
            check_output_file(option, target)
    if args.plot and Path(args.plot).suffix.lower() not in (".png", ".pdf", ".svg"):
        raise ValidationError(f"--plot must end in .png, .pdf or .svg, got {args.plot!r}")
    from vesselid.model.export import load_model

    spec, _theta, _ = load_model(args.model)
    if spec.theta0 is None:  # pragma: no cover - load_model refuses it
        raise ValidationError(f"{args.model} has no [theta0]")
    experiments = ([e.strip() for e in args.experiments.split(",") if e.strip()]
                   if args.experiments else None)
    nominal = _read_manoeuvres(args.manoeuvres) if args.manoeuvres else None
    report = validate(args.log, spec, experiments=experiments, horizon=args.horizon,
                      rudder=args.rudder, manoeuvres=nominal)
    out = sys.stderr if args.json == "-" else sys.stdout
    print(report.summary(), file=out)
    if write_json(args.json, report.to_json(indent=2)):
        print(f"wrote {args.json}", file=out)
    if args.plot:
        report.plot(args.plot)
        print(f"wrote {args.plot}", file=out)
    return 0
