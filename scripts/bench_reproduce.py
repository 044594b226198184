"""Benchmark of the paper reproduction (to be merged into ``scripts/bench.py``).

``bench_reproduce(repeats=3)`` measures, after warm-up, the median wall time of
Table 1 at paper size (1000 runs × 10⁴ samples, LS + IV + IV_E{ζ}=0 iterated to
convergence) and of both tables; the JIT compile time (first call in a fresh
process with empty numba and generated-kernel caches) and the time to load the
cached kernels in a fresh process; and the plain-numpy baseline
(``scripts/baseline_numpy.py``, run once at full size by default) with the
speed-up ratio, measured in the same call. Targets on the 2-core machine: Table 1
≤ 4 s, both tables ≤ 10 s.

    python scripts/bench_reproduce.py [--repeats 3] [--baseline-runs 1000]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

_WARM = ("import time; t=time.perf_counter(); from vesselid.studies.reproduce import warm_up; "
         "i=time.perf_counter(); warm_up(); print(i-t, time.perf_counter()-i)")


def _fresh_process_warmup(env: dict[str, str]) -> tuple[float, float]:
    """(import seconds, warm-up seconds) in a new interpreter with ``env``."""
    out = subprocess.run([sys.executable, "-c", _WARM], env=env, capture_output=True,
                         text=True, check=True)
    imp, warm = (float(x) for x in out.stdout.split())
    return imp, warm


def bench_reproduce(repeats: int = 3, baseline_runs: int = 1000) -> dict:
    """Median timings of the reproduction and the numpy-baseline ratio (see module doc)."""
    from vesselid.studies.montecarlo import run_study
    from vesselid.studies.reproduce import table_study, warm_up

    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"),
                   VESSELID_KERNEL_DIR=str(Path(tmp) / "kernels"))
        _, compile_s = _fresh_process_warmup(env)   # empty caches: compile everything
        _, cached_s = _fresh_process_warmup(env)    # same caches: load compiled code
    warm_up()
    studies = {t: table_study(t) for t in (1, 2)}
    t1, both = [], []
    for _ in range(repeats):
        a = time.perf_counter()
        run_study(studies[1], progress=False)
        b = time.perf_counter()
        run_study(studies[2], progress=False)
        c = time.perf_counter()
        t1.append(b - a)
        both.append(c - a)
    sys.path.insert(0, str(HERE))
    from baseline_numpy import table1_numpy

    base = table1_numpy(baseline_runs, 10_000, 0)["total_s"]
    base_full = base * 1000 / baseline_runs
    table1 = statistics.median(t1)
    return {
        "reproduce_table1_1000x1e4_s": table1,
        "reproduce_both_tables_1000x1e4_s": statistics.median(both),
        "reproduce_table1_runs_s": t1,
        "reproduce_both_runs_s": both,
        "jit_compile_fresh_process_s": compile_s,
        "jit_cached_load_fresh_process_s": cached_s,
        "numpy_baseline_table1_s": base_full,
        "numpy_baseline_runs": baseline_runs,
        "numpy_baseline_scaled": baseline_runs != 1000,
        "speedup_vs_numpy": base_full / table1,
        "targets": {"table1_s": 4.0, "both_tables_s": 10.0},
    }


def bench_estimators(runs: int = 1000, repeats: int = 3) -> dict:
    """Where Table 1's Monte Carlo time goes (in-process, after warm-up): per chunk as
    :func:`vesselid.studies.montecarlo.run_chunk` does it — one simulation, then every estimator
    in the table's order, ``auto`` handed the chunk's converged IV_{E{ζ}=0} result — wall
    and CPU seconds (all threads) per part, summed over the chunks; medians over
    ``repeats``; median and mean iterations per estimator. ``python scripts/bench.py
    --only estimators``."""
    import numpy as np

    from vesselid.studies import montecarlo as mc
    from vesselid.studies.reproduce import table_study, warm_up

    warm_up(tables=(1,), runs=runs)
    study = table_study(1, runs=runs)
    system = study.build_system()
    spec = study.identification_spec(system)
    parts = ("simulate", *study.methods)
    walls: dict[str, list[float]] = {k: [] for k in parts}
    cpus: dict[str, list[float]] = {k: [] for k in parts}
    iters: dict[str, list[np.ndarray]] = {m: [] for m in study.methods}
    for rep in range(repeats):
        wall = dict.fromkeys(parts, 0.0)
        cpu = dict.fromkeys(parts, 0.0)
        for a, b in mc._chunks(runs, mc.DEFAULT_BATCH_SIZE):
            t, c = time.perf_counter(), time.process_time()
            sim = system.simulate(int(study.samples), run_seeds=study.run_seeds(a, b))
            data = mc.regression_data(study, system, spec, sim)
            wall["simulate"] += time.perf_counter() - t
            cpu["simulate"] += time.process_time() - c
            base = None
            for m in study.methods:
                est = mc.get_estimator(m)
                t, c = time.perf_counter(), time.process_time()
                if base is not None and mc._is_zero_mean_iv(est, study):
                    res = base
                else:
                    opt = {"base": base} if base is not None and mc._takes_base(est, study) else {}
                    res = est.estimate_parameters(data, spec, combine=study.combine,
                                                  max_iter=int(study.max_iter),
                                                  tol=float(study.tol), **opt)
                wall[m] += time.perf_counter() - t
                cpu[m] += time.process_time() - c
                if mc._is_zero_mean_iv(est, study):
                    base = res
                elif base is None and mc._takes_base(est, study):
                    base = res.info.get("base")
                if rep == 0:
                    iters[m].append(np.asarray(res.iterations))
        for k in parts:
            walls[k].append(wall[k])
            cpus[k].append(cpu[k])
    out: dict = {"runs": runs, "samples": int(study.samples)}
    for k in parts:
        out[f"{k}_wall_s"] = statistics.median(walls[k])
        out[f"{k}_cpu_s"] = statistics.median(cpus[k])
    for m in study.methods:
        it = np.concatenate(iters[m])
        out[f"{m}_iterations_median"] = float(np.median(it))
        out[f"{m}_iterations_mean"] = float(np.mean(it))
    out["total_wall_s"] = sum(out[f"{k}_wall_s"] for k in parts)
    out["total_cpu_s"] = sum(out[f"{k}_cpu_s"] for k in parts)
    out["load_average"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return out


def main() -> None:
    p = argparse.ArgumentParser(description="benchmark vesselid reproduce")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--baseline-runs", type=int, default=1000,
                   help="runs of the numpy baseline (scaled linearly to 1000 if fewer)")
    args = p.parse_args()
    print(json.dumps(bench_reproduce(args.repeats, args.baseline_runs), indent=2))


if __name__ == "__main__":
    main()
