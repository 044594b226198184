"""Raw sensor data → trial logs: ``vesselid ingest RAW_DIR_OR_FILES --dt 0.1 --out trial.csv``.

One module per source: :mod:`~vesselid.ingest.nmea` (NMEA 0183), :mod:`~vesselid.ingest.tables`
(mapped multi-rate CSV), :mod:`~vesselid.ingest.tank` (model-test tables, one experiment per
file), :mod:`~vesselid.ingest.rosbag` (ROS 2 bags, optional extra
``ros``); :mod:`~vesselid.ingest.streams` resamples, :mod:`~vesselid.ingest.pipeline`
assembles the log and its quality report, :mod:`~vesselid.ingest.config` reads the small
configuration TOML (origin, latencies, column mappings).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from vesselid.ingest.config import IngestError
from vesselid.ingest.pipeline import ingest

__all__ = ["IngestError", "add_parser", "ingest"]


def add_parser(subparsers: Any) -> None:
    """Register ``vesselid ingest`` (the CLI plugin contract of :mod:`vesselid.cli`)."""
    from vesselid.cli import plugin_parser

    p = plugin_parser(subparsers, "ingest")
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
    from vesselid import limits
    from vesselid.cli import check_output_file

    check_output_file("--out", args.out)  # before parsing anything
    limits.check_inputs("ingest", args.inputs)
    log = ingest(args.inputs, args.dt, config=args.config, origin=origin,
                 max_gap=args.max_gap, min_duration=args.min_duration)
    log.metadata["command"] = "vesselid " + " ".join(sys.argv[1:]) if sys.argv else ""
    log.save(out)
    print(summary(log))
    print(f"wrote {out} ({len(log)} rows, {len(log.experiment_ids)} experiment(s)); quality "
          f"report in the metadata" + (f" ({out.with_suffix('.json')})"
                                       if out.suffix.lower() == ".csv" else ""))
    if log.metadata.get("spec_file"):
        print(f"next: vesselid identify {out} --model {log.metadata['spec_file']}")
    return 0


def summary(log: Any) -> str:
    """A few lines of the quality report."""
    q = log.metadata.get("quality", {})
    lines = []
    for s in q.get("sources", []):
        if s.get("type") == "nmea0183":
            lines.append(
                f"{s['file']}: {s['lines']} lines, {s['sentences']} sentences ok, "
                f"{s['bad_checksum']} bad checksums, {s['corrupt']} corrupt, "
                f"{s.get('clock_jumps', 0)} clock jumps, unsupported {s.get('unsupported', {})}")
        elif s.get("type") == "tank":
            yc = s.get("yaw_rate_check", {})
            check = (f"r vs dψ/dt misfit {yc['relative_misfit']:.3f}" if yc.get("checked")
                     else f"yaw rate not checked ({yc.get('why')})")
            lines.append(f"{s['file']}: {s['rows']} rows at {s['dt_file']:g} s, {check}; "
                         f"{'; '.join(s['conversions']) or 'no conversion'}; resampling "
                         f"{s.get('resampling', 'none')}")
        else:
            lines.append(f"{s.get('file', s.get('bag'))}: {s.get('type')}")
    for name, c in q.get("columns", {}).items():
        if "derived" in c:
            lines.append(f"  {name:<10} derived: {c['derived']}")
            continue
        rate = c.get("rate_hz")
        head = f"  {name:<10} {c.get('source', '')}"
        if rate:
            head += (f": {rate:.2f} Hz, {c.get('dropouts', 0)} dropouts, interpolated "
                     f"{100 * c['interpolated_fraction']:.2f} %, {c.get('resampling')}")
        lines.append(head)
    for d in q.get("dropped_segments", []):
        lines.append(f"  dropped a {d['rows']}-row stretch at {d['start_utc']} (too short)")
    return "\n".join(lines)
