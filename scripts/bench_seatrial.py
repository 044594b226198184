"""Benchmark of the CyberShip II sea-trial pipeline (median wall time after warm-up).

The whole pipeline — design (with its noise-free margin check), batch simulation of
6 + 1 (held-out) experiments × 2·10⁴ samples with current, wind and sensors, identification
with LS, IV and IV with zero-mean instruments (:func:`vesselid.identify.identify`, with
diagnostics), and free-run validation on the held-out experiment — target ≤ 10 s on the
2-core machine. Run ``python scripts/bench_seatrial.py``; ``scripts/bench.py`` loads
:func:`bench_seatrial`.
"""

from __future__ import annotations

import json
import statistics
import time
import warnings


def bench_seatrial(repeats: int = 3, experiments: int = 6, samples: int = 20_000) -> dict:
    """Median wall time (s) of :func:`vesselid.studies.seatrial.run_pipeline` after one warm-up."""
    from vesselid.studies.seatrial import run_pipeline

    warnings.simplefilter("ignore")
    run_pipeline(experiments, 2_000, seed=0)  # JIT warm-up (compiled kernels are cached)
    times, stages = [], []
    for i in range(repeats):
        t0 = time.perf_counter()
        res = run_pipeline(experiments, samples, seed=i)
        times.append(time.perf_counter() - t0)
        stages.append(res.timings)
    med = statistics.median(times)
    key = f"seatrial_pipeline_{experiments}x{samples}_s"
    return {
        key: med,
        "seatrial_pipeline_times_s": times,
        "seatrial_stage_medians_s": {k: statistics.median(s[k] for s in stages)
                                     for k in stages[0]},
        "seatrial_target_s": 10.0,
        "seatrial_within_target": med <= 10.0,
    }


if __name__ == "__main__":
    print(json.dumps(bench_seatrial(), indent=2))


def bench_seatrial_cli(repeats: int = 3) -> dict:
    """Median whole-process wall time (s) of ``vesselid sea-trial`` (default planned
    design, 6 × 2·10⁴ samples) plus ``vesselid plan-trial`` (default budget), each a new
    Python process (import, planning and simulation included); target ≤ 10 s together."""
    import subprocess
    import sys
    import tempfile

    def one(args: list[str]) -> float:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "vesselid", *args], check=True,
                       stdout=subprocess.DEVNULL)
        return time.perf_counter() - t0

    sea, plan = [], []
    with tempfile.TemporaryDirectory() as tmp:
        one(["plan-trial"])  # compiled kernels cached
        for i in range(repeats):
            sea.append(one(["sea-trial", "--seed", str(i), "--out", tmp]))
            plan.append(one(["plan-trial"]))
    both = statistics.median(s + p for s, p in zip(sea, plan, strict=True))
    return {"seatrial_cli_s": statistics.median(sea), "plan_trial_cli_s": statistics.median(plan),
            "seatrial_plus_plan_trial_s": both, "seatrial_plus_plan_trial_target_s": 10.0,
            "seatrial_plus_plan_trial_within_target": both <= 10.0}
