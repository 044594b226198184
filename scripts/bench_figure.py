"""Time Figure 1 (``vesselid.studies.plots.error_histograms``) in fresh processes, as ``reproduce``
draws it: each child process loads a saved Table 1 results file, then builds the figure
and saves it at 90 dpi (the first figure of a process pays font loading), reporting CPU
(``time.process_time``) and wall seconds of each stage; medians over the processes.

    python scripts/bench_figure.py --results results/results_table1.csv --repeat 7
    PYTHONPATH=/path/to/old/checkout python scripts/bench_figure.py --results ... \
        --compress-level 6          # another checkout, zlib level 6

Without ``--results`` it first runs ``vesselid reproduce --table 1`` (1000 × 10⁴) into a
temporary directory. ``PYTHONPATH`` chooses the code measured (e.g. another checkout's
source tree for a paired comparison, alternated by the caller).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CHILD = r"""
import json, sys, time
from vesselid.studies.montecarlo import load_results
from vesselid.studies.plots import error_histograms
from vesselid.studies.reproduce import PARAMETER_LABELS
df = load_results(sys.argv[1])
c0, w0 = time.process_time(), time.perf_counter()
fig = error_histograms(df, labels=PARAMETER_LABELS,
                       title="Table 1 setting: normalized estimation errors")
c1, w1 = time.process_time(), time.perf_counter()
fig.savefig(sys.argv[2], dpi=90, format="png", pil_kwargs={"compress_level": int(sys.argv[3])})
c2, w2 = time.process_time(), time.perf_counter()
print(json.dumps({"build_cpu": c1 - c0, "save_cpu": c2 - c1, "total_cpu": c2 - c0,
                  "total_wall": w2 - w0}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", help="a results_table1 file written by `reproduce --out`")
    ap.add_argument("--repeat", type=int, default=7, help="fresh processes (default 7)")
    ap.add_argument("--compress-level", type=int, default=1,
                    help="PNG zlib level (reproduce: 1; matplotlib's default: 6)")
    args = ap.parse_args()
    env = {**os.environ, "MPLBACKEND": "Agg"}
    with tempfile.TemporaryDirectory() as tmp:
        results = args.results
        if results is None:
            subprocess.run([sys.executable, "-m", "vesselid", "reproduce", "--table", "1",
                            "--out", tmp], check=True, env=env, stdout=subprocess.DEVNULL)
            results = str(next(Path(tmp).glob("results_table1.*")))
        rows = []
        for _ in range(args.repeat):
            out = subprocess.run([sys.executable, "-c", CHILD, results, f"{tmp}/fig.png",
                                  str(args.compress_level)],
                                 check=True, env=env, capture_output=True, text=True).stdout
            rows.append(json.loads(out.strip().splitlines()[-1]))
        size = Path(f"{tmp}/fig.png").stat().st_size
    med = {k: float(np.median([r[k] for r in rows])) for k in rows[0]}
    print(f"Figure 1, {args.repeat} fresh processes, medians: "
          + ", ".join(f"{k} {v:.3f} s" for k, v in med.items())
          + f"; PNG {size / 1e3:.0f} kB; load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
