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


#: Optional notes of a record (a source or a column of the quality report): ``(key,
#: template)``, the template filled from the record where ``record[key]`` is set.
Notes = tuple[tuple[str, str], ...]

#: appended to an NMEA source's line
_NMEA_SUFFIX: Notes = (
    ("invalid", ", not used (void, empty or of another kind) {invalid}"),
)
#: lines below an NMEA source's line (after its unusable sentence kinds)
_NMEA_LINES: Notes = (
    ("xdr_unmapped", "  XDR transducers not mapped in [nmea] xdr (not read): {xdr_unmapped}"),
    ("time_outliers", "  {time_outliers} fix(es) with an outlying clock dropped"),
)
#: appended to a mapped CSV source's line
_CSV_SUFFIX: Notes = (
    ("bad_time", ", {bad_time} rows without a usable time dropped"),
    ("bad_values", ", empty/unparsable cells skipped {bad_values}"),
)
#: a column's notes, joined by "; " after its head
_COLUMN_NOTES: Notes = (
    ("duplicate_times", "{duplicate_times} duplicate-time samples dropped"),
    ("non_finite", "{non_finite} empty/non-finite samples dropped"),
    ("time_interpolated", "{time_interpolated} sample times interpolated between fixes"),
    ("quantisation_deg", "quantised to {quantisation_deg:g} deg (noise std "
                         "{quantisation_noise_std_rad:.4f} rad)"),
    ("magnetic", "magnetic, variation from {variation_from}"),
    ("heading_offset_deg", "heading offset {heading_offset_deg:g} deg removed"),
    ("renamed_from", "from NMEA channel {renamed_from!r}"),
)


class _Record(dict):
    """A quality record for ``str.format_map``: a field it lacks reads as ``None``."""

    def __missing__(self, key: str) -> None:
        return None


def _notes(record: dict[str, Any], notes: Notes) -> list[str]:
    """The notes of ``record`` whose key is set, filled in, in table order."""
    rec = _Record(record)
    return [template.format_map(rec) for key, template in notes if record.get(key)]


def _source_lines(s: dict[str, Any]) -> list[str]:
    """What one source (file or bag) gave: one line, and for NMEA the unused parts."""
    kind = s.get("type")
    if kind == "nmea0183":
        line = (f"{s['file']}: {s['lines']} lines, {s['sentences']} sentences ok, "
                f"{s['bad_checksum']} bad checksums, {s['corrupt']} corrupt, "
                f"{s.get('clock_jumps', 0)} clock jumps, "
                f"unsupported {s.get('unsupported', {})}")
        return ([line + "".join(_notes(s, _NMEA_SUFFIX))]
                + [f"  unused {k}: {why}" for k, why in s.get("unusable", {}).items()]
                + _notes(s, _NMEA_LINES))
    if kind == "csv":
        line = (f"{s.get('file')}: csv ({s.get('kind')}), {s.get('rows')} rows"
                + "".join(_notes(s, _CSV_SUFFIX)))
        if s.get("time_rebuilt"):
            tr = s["time_rebuilt"]
            line += (f"; time axis rebuilt at {tr['sample_rate_hz']:g} Hz "
                     f"({tr['duplicate_times']} duplicated stamps, max shift "
                     f"{tr['max_shift_s']:.3g} s)")
        return [line]
    if kind == "tank":
        yc = s.get("yaw_rate_check", {})
        check = (f"r vs dψ/dt misfit {yc['relative_misfit']:.3f}" if yc.get("checked")
                 else f"yaw rate not checked ({yc.get('why')})")
        return [f"{s['file']}: {s['rows']} rows at {s['dt_file']:g} s, {check}; "
                f"{'; '.join(s['conversions']) or 'no conversion'}; resampling "
                f"{s.get('resampling', 'none')}"]
    return [f"{s.get('file', s.get('bag'))}: {s.get('type')}"
            + (f", topics {s['topics']}" if s.get("topics") else "")]


def _column_line(name: str, c: dict[str, Any]) -> str:
    """One column: where it came from, its rate and every sample dropped or re-timed."""
    if "derived" in c:
        return f"  {name:<10} derived: {c['derived']}"
    rate = c.get("rate_hz")
    head = f"  {name:<10} {c.get('source', '')}"
    if rate:
        head += (f": {rate:.2f} Hz, {c.get('dropouts', 0)} dropouts, interpolated "
                 f"{100 * c['interpolated_fraction']:.2f} %, {c.get('resampling')}")
    extra = _notes(c, _COLUMN_NOTES)
    return head + ("; " + "; ".join(extra) if extra else "")


def summary(log: Any) -> str:
    """The quality report in a few lines: per source what was read and what was not,
    per column the rate and every dropped, interpolated or re-timed sample."""
    q = log.metadata.get("quality", {})
    lines = [line for s in q.get("sources", []) for line in _source_lines(s)]
    lines += [_column_line(name, c) for name, c in q.get("columns", {}).items()]
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
