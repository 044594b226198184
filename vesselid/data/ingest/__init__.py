"""Raw sensor data → trial logs: ``vesselid ingest RAW_DIR_OR_FILES --dt 0.1 --out trial.csv``.

One module per source: :mod:`~vesselid.data.ingest.nmea` (NMEA 0183),
:mod:`~vesselid.data.ingest.tables`
(mapped multi-rate CSV), :mod:`~vesselid.data.ingest.tank` (model-test tables, one experiment per
file), :mod:`~vesselid.data.ingest.rosbag` (ROS 1 and ROS 2 bags, optional extra ``ros``);
:mod:`~vesselid.data.ingest.streams` resamples, :mod:`~vesselid.data.ingest.pipeline`
assembles the log and its quality report, :mod:`~vesselid.data.ingest.config` reads the small
configuration TOML (origin, latencies, column mappings).
"""

from __future__ import annotations

from typing import Any

from vesselid.data.ingest.config import IngestError
from vesselid.data.ingest.pipeline import ingest

__all__ = ["IngestError", "ingest", "summary"]


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
