"""``vesselid ingest``: raw sensor streams into a trial log (:mod:`vesselid.data.ingest`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vesselid.cli.common import check_output_file
from vesselid.data.ingest import IngestError, ingest, summary


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``vesselid ingest``."""
    p.add_argument("inputs", nargs="+", metavar="RAW_DIR_OR_FILES")
    p.add_argument("--dt", type=float, required=True, help="sample time of the log (s)")
    p.add_argument("--out", required=True, help="trial.csv or trial.parquet")
    p.add_argument("--config", help="ingest configuration TOML (default: DIR/ingest.toml)")
    p.add_argument("--origin", help="local NED origin LAT,LON[,H] (default: configuration, "
                                    "else the first fix)")
    p.add_argument("--max-gap", type=float, default=None,
                   help="longest gap bridged by interpolation (s); longer ones split experiments")
    p.add_argument("--min-duration", type=float, default=None,
                   help="shortest experiment kept (s)")
    p.add_argument("--sample-rate", type=float, default=None, metavar="HZ",
                   help="the tables' logging rate (Hz): rebuilds a quantised or duplicated "
                        "time column (refused without it)")
    p.set_defaults(func=cmd_ingest)


def cmd_ingest(args: argparse.Namespace) -> int:
    """``vesselid ingest``: write the trial log and print a short quality summary."""
    out = Path(args.out)
    if out.suffix.lower() not in (".csv", ".parquet", ".pq"):
        raise IngestError(f"--out must end in .csv or .parquet, got {out.name!r}")
    origin = None
    if args.origin:
        try:
            origin = [float(x) for x in args.origin.split(",")]
        except ValueError:
            raise IngestError(f"--origin needs LAT,LON[,H], got {args.origin!r}") from None
    from vesselid.core import limits

    check_output_file("--out", args.out)  # before parsing anything
    limits.check_inputs("ingest", args.inputs)
    log = ingest(args.inputs, args.dt, config=args.config, origin=origin,
                 max_gap=args.max_gap, min_duration=args.min_duration,
                 sample_rate=args.sample_rate)
    log.metadata["command"] = "vesselid " + " ".join(sys.argv[1:]) if sys.argv else ""
    log.save(out)
    print(summary(log))
    print(f"wrote {out} ({len(log)} rows, {len(log.experiment_ids)} experiment(s)); quality "
          f"report in the metadata" + (f" ({out.with_suffix('.json')})"
                                       if out.suffix.lower() == ".csv" else ""))
    if log.metadata.get("spec_file"):
        print(f"next: vesselid identify {out} --model {log.metadata['spec_file']}")
    return 0
