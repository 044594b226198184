"""Benchmark: ``select_terms`` on a 3-DOF log of 6 × 2·10⁴ samples with a 40-term
library per equation (CyberShip II, white current inside the modulus).

Target: ≤ 30 s for the whole selection, block-bootstrap selection probabilities (100
replicates) included. Printed: median wall time over ``--repeats`` runs after one
warm-up (imports, compiled kernels), the median CPU time of the process (all its
threads; on a loaded machine the wall time exceeds it), and the split without the
bootstrap.

    python scripts/bench_select.py [--repeats 3] [--bootstrap 100]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path


def bench_select(repeats: int = 3, n_boot: int = 100, samples: int = 20_000,
                 experiments: int = 6) -> dict:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from selection_study import designs, linear_base

    from vesselid.selection import select_terms
    from vesselid.selection.library import vessel_library

    system, _, _, _ = designs(False)["CyberShip II, white current"]
    log = system.simulate(samples, experiments, seed=0).to_log(aggregate=False)
    base = linear_base(system.model.with_aggregate(None))
    lib = {s: terms[:40] for s, terms in vessel_library(base).items()}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        select_terms(log, base, lib, n_boot=2)  # warm-up: imports, compiled kernels
        out = {}
        for label, nb in (("with_bootstrap", n_boot), ("without_bootstrap", 0)):
            times, cpu = [], []
            for _ in range(repeats):
                t0, c0 = time.perf_counter(), time.process_time()
                res = select_terms(log, base, lib, n_boot=nb)
                times.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            out[label] = statistics.median(times)
            out[f"{label}_cpu"] = statistics.median(cpu)
    out.update(samples=int(log.data.shape[0]), library=len(lib["u"]), bootstrap=n_boot,
               selected=res.selected, target_s=30.0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--bootstrap", type=int, default=100)
    args = ap.parse_args(argv)
    r = bench_select(args.repeats, args.bootstrap)
    print(f"select_terms: {r['samples']} samples, {r['library']} candidates per equation, "
          f"{r['bootstrap']} bootstrap replicates: median {r['with_bootstrap']:.2f} s "
          f"(target <= {r['target_s']:.0f} s), CPU {r['with_bootstrap_cpu']:.2f} s; "
          f"without the bootstrap {r['without_bootstrap']:.2f} s "
          f"(CPU {r['without_bootstrap_cpu']:.2f} s)")
    print(f"selected: {r['selected']}")
    return 0 if r["with_bootstrap"] <= r["target_s"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
