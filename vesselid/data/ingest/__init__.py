"""Raw sensor data → trial logs: ``vesselid ingest RAW_DIR_OR_FILES --dt 0.1 --out trial.csv``.

One module per source: :mod:`~vesselid.data.ingest.nmea` (NMEA 0183), :mod:`~vesselid.data.ingest.tables`
(mapped multi-rate CSV), :mod:`~vesselid.data.ingest.tank` (model-test tables, one experiment per
file), :mod:`~vesselid.data.ingest.rosbag` (ROS 1 and ROS 2 bags, optional extra ``ros``);
:mod:`~vesselid.data.ingest.streams` resamples, :mod:`~vesselid.data.ingest.pipeline`
assembles the log and its quality report, :mod:`~vesselid.data.ingest.config` reads the small
configuration TOML (origin, latencies, column mappings).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from vesselid.data.ingest.config import IngestError
from vesselid.data.ingest.pipeline import ingest

__all__ = ["IngestError", "add_parser", "ingest"]


def add_parser(subparsers: Any) -> None:
    """Register ``vesselid ingest`` (the CLI plugin contract of :mod:`vesselid.cli.app`)."""
    from vesselid.cli.app import plugin_parser

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
    from vesselid.cli.app import check_output_file

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


def summary(log: Any) -> str:
    """The quality report in a few lines: per source what was read and what was not,
    per column the rate and every dropped, interpolated or re-timed sample."""
    q = log.metadata.get("quality", {})
    lines = []
    for s in q.get("sources", []):
        if s.get("type") == "nmea0183":
            line = (f"{s['file']}: {s['lines']} lines, {s['sentences']} sentences ok, "
                    f"{s['bad_checksum']} bad checksums, {s['corrupt']} corrupt, "
                    f"{s.get('clock_jumps', 0)} clock jumps, "
                    f"unsupported {s.get('unsupported', {})}")
            if s.get("invalid"):
                line += f", not used (void, empty or of another kind) {s['invalid']}"
            lines.append(line)
            for kind, why in s.get("unusable", {}).items():
                lines.append(f"  unused {kind}: {why}")
            if s.get("xdr_unmapped"):
                lines.append(f"  XDR transducers not mapped in [nmea] xdr (not read): "
                             f"{s['xdr_unmapped']}")
            if s.get("time_outliers"):
                lines.append(f"  {s['time_outliers']} fix(es) with an outlying clock dropped")
        elif s.get("type") == "csv":
            line = f"{s.get('file')}: csv ({s.get('kind')}), {s.get('rows')} rows"
            if s.get("bad_time"):
                line += f", {s['bad_time']} rows without a usable time dropped"
            if s.get("bad_values"):
                line += f", empty/unparsable cells skipped {s['bad_values']}"
            if s.get("time_rebuilt"):
                tr = s["time_rebuilt"]
                line += (f"; time axis rebuilt at {tr['sample_rate_hz']:g} Hz "
                         f"({tr['duplicate_times']} duplicated stamps, max shift "
                         f"{tr['max_shift_s']:.3g} s)")
            lines.append(line)
        elif s.get("type") == "tank":
            yc = s.get("yaw_rate_check", {})
            check = (f"r vs dψ/dt misfit {yc['relative_misfit']:.3f}" if yc.get("checked")
                     else f"yaw rate not checked ({yc.get('why')})")
            lines.append(f"{s['file']}: {s['rows']} rows at {s['dt_file']:g} s, {check}; "
                         f"{'; '.join(s['conversions']) or 'no conversion'}; resampling "
                         f"{s.get('resampling', 'none')}")
        else:
            lines.append(f"{s.get('file', s.get('bag'))}: {s.get('type')}"
                         + (f", topics {s['topics']}" if s.get("topics") else ""))
    for name, c in q.get("columns", {}).items():
        if "derived" in c:
            lines.append(f"  {name:<10} derived: {c['derived']}")
            continue
        rate = c.get("rate_hz")
        head = f"  {name:<10} {c.get('source', '')}"
        if rate:
            head += (f": {rate:.2f} Hz, {c.get('dropouts', 0)} dropouts, interpolated "
                     f"{100 * c['interpolated_fraction']:.2f} %, {c.get('resampling')}")
        extra = []
        if c.get("duplicate_times"):
            extra.append(f"{c['duplicate_times']} duplicate-time samples dropped")
        if c.get("non_finite"):
            extra.append(f"{c['non_finite']} empty/non-finite samples dropped")
        if c.get("time_interpolated"):
            extra.append(f"{c['time_interpolated']} sample times interpolated between fixes")
        if c.get("quantisation_deg"):
            extra.append(f"quantised to {c['quantisation_deg']:g} deg (noise std "
                         f"{c['quantisation_noise_std_rad']:.4f} rad)")
        if c.get("magnetic"):
            extra.append(f"magnetic, variation from {c.get('variation_from')}")
        if c.get("heading_offset_deg"):
            extra.append(f"heading offset {c['heading_offset_deg']:g} deg removed")
        if c.get("renamed_from"):
            extra.append(f"from NMEA channel {c['renamed_from']!r}")
        if extra:
            head += "; " + "; ".join(extra)
        lines.append(head)
    if q.get("lever_arm_m"):
        lines.append(f"  lever arm {q['lever_arm_m']} m applied to "
                     f"{', '.join(q.get('lever_arm_applied_to', [])) or 'nothing'}")
    for d in q.get("dropped_segments", []):
        lines.append(f"  dropped a {d['rows']}-row stretch at {d['start_utc']} (too short)")
    if "kept_s" in q:
        rest = q["input_span_s"] - q["kept_s"]
        lines.append(f"  kept {q['kept_s']:.1f} s of the {q['input_span_s']:.1f} s the inputs "
                     f"span in {len(q.get('experiments', []))} experiment(s)"
                     + (f"; {rest:.1f} s outside: a channel missing there, a gap or a stretch "
                        f"too short" if rest > 1e-6 else ""))
    return "\n".join(lines)
