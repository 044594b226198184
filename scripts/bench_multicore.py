"""Benchmarks for a machine with many cores: how the Monte Carlo scales with its workers,
and the in-process timings of ``identify`` on a quiet machine.

Run ``python scripts/bench_multicore.py --json docs/performance_multicore.json`` on the
machine to measure (every core free); ``python scripts/bench.py --docs`` then adds its
figures to ``docs/performance.md`` as a section of their own (:func:`render`).

Items (each from :mod:`bench_scaling` or :mod:`bench`, run here with the machine's
counts):

* the Monte Carlo part of ``vesselid reproduce --table 1`` (1000 runs × 10⁴ samples)
  with 1, 2, 4, … workers up to the machine's cores (:func:`bench_scaling.bench_mc_threads`:
  wall and CPU medians, the parent's CPU, and whether the result CSVs are byte-identical
  at every count);
* the same with one and two workers in a child process confined to two cores
  (``os.sched_setaffinity``): the two-core figure on an otherwise idle machine;
* ``identify`` with the default estimator on a 10⁴-sample white heave log and on one
  with a Gauss–Markov current, in-process (:func:`bench.bench_identify`,
  :func:`bench_scaling.bench_pem_path`);
* the whole ``vesselid identify`` process on 10⁵- and 10⁶-sample heave logs: wall, CPU
  and peak resident memory (:func:`bench_scaling.bench_identify_memory`);
* single environments against CartPole-v1 and the vector environments
  (:func:`bench_scaling.bench_single_envs`);
* the costliest run of that Monte Carlo (:func:`costliest_run`): every run's CPU on its
  own, then the costliest run alone with every core free — no schedule can finish the
  study sooner, so one worker's time over it bounds the speed-up;
* what the machine itself allows (:func:`machine_ceiling`): the throughput of 1, 2, 4, …
  processes each doing the same fixed work, a compiled arithmetic loop (no memory traffic)
  and a numpy pass over 64 MB arrays (memory bandwidth), against one process.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

__all__ = ["measure", "render"]


def _worker_counts(cores: int) -> tuple[int, ...]:
    counts, n = [], 1
    while n < cores:
        counts.append(n)
        n *= 2
    return (*counts, cores)


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:  # pragma: no cover - not Linux
        pass
    return platform.processor() or "unknown"


def _two_cores(repeats: int, runs: int) -> dict[str, Any]:
    """One and two workers in a child process confined to the first two usable cores."""
    code = (f"import json, os, sys; sys.path.insert(0, {str(HERE)!r}); "
            "os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:2]); "
            "from bench_scaling import bench_mc_threads; "
            f"print(json.dumps(bench_mc_threads(repeats={repeats}, runs={runs}, "
            "workers=(1, 2), project=())))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _compute_work() -> float:
    """Wall seconds of a fixed compiled arithmetic loop (registers only)."""
    import time

    from numba import njit

    @njit(cache=False)
    def logistic(n: int) -> float:  # pragma: no cover - compiled
        s, x = 0.0, 0.5
        for _ in range(n):
            x = 3.9 * x * (1.0 - x)
            s += x
        return s

    logistic(10)
    t0 = time.perf_counter()
    logistic(200_000_000)
    return time.perf_counter() - t0


def _stream_work() -> float:
    """Wall seconds of a fixed numpy pass over two 64 MB arrays (memory bandwidth)."""
    import time

    import numpy as np

    a = np.ones(8_000_000)
    b = np.empty_like(a)
    t0 = time.perf_counter()
    for _ in range(30):
        np.multiply(a, 1.0001, out=b)
        np.add(b, a, out=a)
    return time.perf_counter() - t0


def _each(work: str, _: int) -> float:
    return _compute_work() if work == "compute" else _stream_work()


def machine_ceiling(counts: tuple[int, ...]) -> dict[str, Any]:
    """Throughput of ``n`` forked processes, each doing the same fixed work at once,
    against one process (``n`` × one process's time / the slowest of the ``n``): the
    speed-up a perfectly parallel job of that kind can reach on this machine."""
    import multiprocessing as mp
    from functools import partial

    out: dict[str, Any] = {"counts": list(counts)}
    ctx = mp.get_context("fork")
    for work in ("compute", "stream"):
        base = 0.0
        for n in counts:
            with ctx.Pool(n) as pool:
                times = pool.map(partial(_each, work), range(n))
            if n == 1:
                base = times[0]
            out[f"{work}_{n}_max_s"] = max(times)
            out[f"{work}_{n}_speedup"] = n * base / max(times)
    return out


def costliest_run(runs: int = 1000, samples: int = 10_000, repeats: int = 3
                  ) -> dict[str, Any]:
    """The run of ``vesselid reproduce --table 1``'s Monte Carlo that costs the most CPU
    (each run computed on its own, serial kernels), and its wall time computed alone in
    this process with every core free (median of ``repeats``): its likelihood fit's
    scoring steps follow one another, so the whole study cannot finish sooner."""
    import time

    import numpy as np

    from vesselid.core.threads import serial_here
    from vesselid.studies.montecarlo import _chunk_columns
    from vesselid.studies.reproduce import table_study

    study = table_study(1, runs=runs, samples=samples)
    with serial_here():
        _chunk_columns(study, 0, 1)
        costs = []
        for run in range(runs):
            t0 = time.process_time()
            _chunk_columns(study, run, run + 1)
            costs.append(time.process_time() - t0)
    worst = int(np.argmax(costs))
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        _chunk_columns(study, worst, worst + 1)
        walls.append(time.perf_counter() - t0)
    order = np.sort(costs)[::-1]
    return {"run": worst, "cpu_s": float(costs[worst]),
            "alone_wall_s": float(np.median(walls)),
            "next_cpu_s": [float(c) for c in order[1:4]], "all_cpu_s": float(np.sum(costs))}


def measure(repeats: int = 2, runs: int = 1000,
            memory_sizes: tuple[int, ...] = (100_000, 1_000_000)) -> dict[str, Any]:
    """Every item of the module docstring on this machine."""
    import numpy as np
    from bench import bench_identify
    from bench_scaling import (
        bench_identify_memory,
        bench_mc_threads,
        bench_pem_path,
        bench_single_envs,
    )

    cores = len(os.sched_getaffinity(0))
    results: dict[str, Any] = {"machine": {
        "cpu": _cpu_model(), "cores": cores,
        "python": platform.python_version(), "numpy": np.__version__}}
    results["mc_threads"] = bench_mc_threads(repeats=repeats, runs=runs,
                                             workers=_worker_counts(cores), project=())
    if cores > 2:
        results["mc_two_cores"] = _two_cores(repeats + 1, runs)
    white = bench_identify(methods=())
    results["identify"] = {"white_default_ms": white["identify_heave_1e4_default_ms"],
                           "white_default_cpu_ms": white["identify_heave_1e4_default_cpu_ms"]}
    results["pem_path"] = bench_pem_path()
    results["identify_memory"] = bench_identify_memory(sizes=memory_sizes, phases_at=None)
    results["envs"] = bench_single_envs(repeats=5)
    results["ceiling"] = machine_ceiling(_worker_counts(cores))
    results["costliest_run"] = costliest_run(runs=runs)
    return results


def _mc_rows(mc: dict[str, Any]) -> list[str]:
    rows = ["| workers | wall (s) | CPU, all (s) | parent CPU (s) | speed-up (wall) |",
            "|---:|---:|---:|---:|---:|"]
    base = mc[f"w{mc['workers'][0]}_wall_s"]
    for n in mc["workers"]:
        rows.append(f"| {n} | {mc[f'w{n}_wall_s']:.2f} | {mc[f'w{n}_cpu_s']:.2f} | "
                    f"{mc[f'w{n}_parent_cpu_s']:.2f} | {base / mc[f'w{n}_wall_s']:.2f}× |")
    return rows


def render(results: dict[str, Any]) -> str:
    """The performance page's section for the figures of :func:`measure`."""
    m, mc = results["machine"], results.get("mc_threads")
    lines = [
        "## On a machine with many cores",
        "",
        f"Measured by `python scripts/bench_multicore.py` on a quiet machine: {m['cpu']}, "
        f"{m['cores']} cores, Python {m['python']}, numpy {m['numpy']}. Its cores are not "
        "those of the tables above: compare figures within this section.",
    ]
    if mc:
        lines += [
            "",
            f"The Monte Carlo part of `vesselid reproduce --table 1` ({mc['runs']:,} runs × "
            f"{mc['samples']:,} samples), medians of {mc['repeats']} alternated runs; result "
            f"CSVs byte-identical at every worker count: "
            f"{'yes' if mc['csv_byte_identical'] else '**no**'}.",
            "",
            *_mc_rows(mc),
        ]
    else:  # the saved figures are of items whose code the current page still describes
        lines += [
            "",
            "The Monte Carlo and the default estimator on white logs are not in this "
            "section: their saved figures are not those of the current default estimator "
            "(`python scripts/bench_multicore.py --json docs/performance_multicore.json` "
            "measures them); the projection above estimates the Monte Carlo on 4–16 cores.",
        ]
    two = results.get("mc_two_cores")
    if two:
        lines += ["", "The same with one and two workers in a process confined to two of "
                  "the machine's cores (`os.sched_setaffinity`), the other cores idle; "
                  f"CSVs byte-identical: {'yes' if two['csv_byte_identical'] else '**no**'}.",
                  "", *_mc_rows(two)]
    ident, pem = results.get("identify"), results.get("pem_path")
    if ident or pem:
        lines += [
            "",
            "`identify` with the default estimator, in-process, on 10⁴-sample heave logs "
            "(medians):",
            "",
            "| log | wall (ms) | CPU (ms) |",
            "|---|---:|---:|",
        ]
        if ident:
            lines.append(f"| white | {ident['white_default_ms']:.1f} | "
                         f"{ident['white_default_cpu_ms']:.1f} |")
        if pem:
            lines.append(f"| Gauss–Markov current (the default fits its likelihood model) | "
                         f"{pem['identify_ms_wall']:.1f} | {pem['identify_ms_cpu']:.1f} |")
    mem = results.get("identify_memory")
    if mem:
        lines += [
            "",
            "The whole `vesselid identify LOG` process on one-state heave logs (Parquet), "
            f"medians of {mem['repeats']} processes:",
            "",
            "| samples | wall (s) | CPU (s) | peak RSS (MB) |",
            "|---:|---:|---:|---:|",
        ]
        for n in mem["sizes"]:
            lines.append(f"| {n:,} | {mem[f'{n}_wall_s']:.2f} | {mem[f'{n}_cpu_s']:.2f} | "
                         f"{mem[f'{n}_peak_rss_mb']:.0f} |")
    worst = results.get("costliest_run")
    if worst and mc:
        base = mc[f"w{mc['workers'][0]}_wall_s"]
        lines += [
            "",
            f"The costliest of those runs (run {worst['run']}, where `auto` falls back to its "
            f"likelihood model) takes {worst['cpu_s']:.2f} s of CPU on its own (the next: "
            + ", ".join(f"{c:.2f}" for c in worst["next_cpu_s"]) + " s; all runs one by one: "
            f"{worst['all_cpu_s']:.1f} s) and **{worst['alone_wall_s']:.2f} s** of wall time "
            "alone with every core free. Its scoring steps follow one another, so no "
            "schedule finishes the study sooner: at most "
            f"{base / worst['alone_wall_s']:.1f}× one worker's time.",
        ]
    ceiling = results.get("ceiling")
    if ceiling:
        lines += [
            "",
            "What the machine itself allows: the speed-up of n processes each doing the same "
            "fixed work at once, over one process (`machine_ceiling`):",
            "",
            "| processes | " + " | ".join(str(n) for n in ceiling["counts"]) + " |",
            "|---|" + "---:|" * len(ceiling["counts"]),
            "| compiled arithmetic (no memory traffic) | " + " | ".join(
                f"{ceiling[f'compute_{n}_speedup']:.2f}×" for n in ceiling["counts"]) + " |",
            "| numpy over 64 MB arrays (memory bandwidth) | " + " | ".join(
                f"{ceiling[f'stream_{n}_speedup']:.2f}×" for n in ceiling["counts"]) + " |",
        ]
    envs = results.get("envs")
    if envs:
        lines += [
            "",
            f"Environments, `env.unwrapped.step` ({envs['steps']:,} steps, medians of "
            f"{envs['repeats']} alternated runs) and the vector environments "
            f"({envs['num_envs']:,} copies):",
            "",
            "| environment | steps/s (single) | × CartPole-v1 | env-steps/s (vector) |",
            "|---|---:|---:|---:|",
        ]
        for name in ("CartPole-v1", "Heave-v0", "Manoeuvring3DOF-v0"):
            vec = envs.get(f"{name}_vector_env_steps_per_s_wall")
            lines.append(f"| {name} | {envs[f'{name}_steps_per_s_wall']:,.0f} | "
                         f"{envs[f'{name}_ratio_wall']:.2f}× | "
                         f"{'—' if vec is None else f'{vec:,.0f}'} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", required=True, help="write the figures here (JSON)")
    parser.add_argument("--repeats", type=int, default=2,
                        help="alternated Monte Carlo repeats per worker count")
    parser.add_argument("--runs", type=int, default=1000, help="Monte Carlo runs")
    parser.add_argument("--memory-sizes", nargs="+", type=int, default=[100_000, 1_000_000],
                        help="heave log lengths of the whole-process identify item")
    args = parser.parse_args(argv)
    results = measure(repeats=args.repeats, runs=args.runs,
                      memory_sizes=tuple(args.memory_sizes))
    path = Path(args.json)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(results, indent=1, default=float) + "\n")
    tmp.replace(path)
    print(render(results))


if __name__ == "__main__":
    main()
