"""Benchmark: raw NMEA streams with 10⁶ sentences — writing them, `vesselid ingest`, and
identifying the ingested log streamed from Parquet against in memory.

Target: ingest of 10⁶ NMEA 0183 sentences (plus the actuator CSV) ≤ 10 s. For reference
the per-line pynmea2 parse rate is measured on a sample and extrapolated to 10⁶ lines.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

SENTENCES_PER_SECOND = 48  # GGA 5 + RMC 10 + HDT 20 + ROT 10 + VHW 2 + MWV 1 Hz


def bench_ingest(repeats: int = 3, sentences: int = 1_000_000) -> dict:
    import pynmea2

    from vesselid.data.ingest import ingest
    from vesselid.data.rawexport import write_raw_streams
    from vesselid.plant.catalogue import get_system

    per_exp = int(sentences / SENTENCES_PER_SECOND / 2 / 0.1) + 1
    log = get_system("cybership2").simulate(per_exp, n_runs=2, seed=0).to_log()
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "raw"
        writes = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            manifest = write_raw_streams(log, raw, seed=0)
            writes.append(time.perf_counter() - t0)
        n = sum(manifest["sentences"].values())
        ingest(raw, 0.1)  # warm-up (imports)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = ingest(raw, 0.1)
            times.append(time.perf_counter() - t0)
        lines = (raw / "nav.nmea").read_text().splitlines()[:20000]
        t0 = time.perf_counter()
        for line in lines:
            pynmea2.parse(line.rpartition("\\")[2])
        per_line = (time.perf_counter() - t0) / len(lines)
        stream = _bench_stream(out, Path(tmp), 1)  # one run: ~20 s of 2 cores
    return {
        "NMEA sentences": n,
        "rows written to the trial log": len(out),
        "write raw streams median (s)": statistics.median(writes),
        "ingest median (s)": statistics.median(times),
        "ingest sentences per second": n / statistics.median(times),
        "pynmea2.parse per line (us)": per_line * 1e6,
        "pynmea2.parse extrapolated to 1e6 lines (s)": per_line * 1e6,
        **stream,
    }


def _bench_stream(log, tmp: Path, repeats: int) -> dict:
    """iv-zero-mean with HAC standard errors: in memory vs streamed from Parquet."""
    import warnings

    import numpy as np

    from vesselid.identify import identify
    from vesselid.identify.streaming import identify_stream

    spec = log.spec
    path = tmp / "trial.parquet"
    log.save(path)
    mem, st = [], []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(repeats):
            t0 = time.perf_counter()
            ref = identify(log, spec, "iv-zero-mean")
            mem.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            got = identify_stream(path, spec, "iv-zero-mean")
            st.append(time.perf_counter() - t0)
    c1, c2 = got.cov.to_numpy(), ref.cov.to_numpy()
    return {
        "identify iv-zero-mean in memory (s)": statistics.median(mem),
        "identify_stream iv-zero-mean (s)": statistics.median(st),
        "identify_stream passes over the data": got.diagnostics["passes"],
        "streamed vs in-memory max rel. param difference": float(np.max(
            np.abs(got.params.to_numpy() - ref.params.to_numpy())
            / np.abs(ref.params.to_numpy()))),
        "streamed vs in-memory max cov difference / max |cov|": float(
            np.max(np.abs(c1 - c2)) / np.max(np.abs(c2))),
    }


if __name__ == "__main__":
    for k, v in bench_ingest().items():
        print(f"{k:<55s} {v:,.4g}" if isinstance(v, float) else f"{k:<55s} {v}")
