"""Benchmarks of how vesselid scales: single environments against CartPole-v1, the
Monte Carlo on one and two workers, the memory of ``vesselid identify`` per sample, the
``pem`` path; and the generated performance page.

Every comparison is measured in alternation in the same process (A, B, A, B, …), and
the medians are reported with the wall and the CPU clock and the load average during
the measurement: on a shared machine the wall clock measures the neighbours too, the
CPU clock (``time.process_time``, all threads of the process; children's CPU from
``wait4``) measures the work.

* ``single_envs``: raw ``env.unwrapped.step`` rate of ``Heave-v0``,
  ``Manoeuvring3DOF-v0`` and ``CartPole-v1`` (random actions drawn beforehand from each
  action space, reset on termination), and the vector environments' env-steps/s;
* ``mc_threads``: the Monte Carlo part of ``vesselid reproduce --table 1`` (1000 runs ×
  10⁴ samples) with one and two workers (``--workers``), wall, the CPU of the parent
  and of every worker process, and whether the result CSVs are byte-identical; and
  the critical paths on 4, 8 and 16 free cores projected from the per-chunk CPU clocks
  of a run with that many worker processes (``--project``), labelled as projections;
* ``identify_memory``: peak resident memory and time of the whole
  ``vesselid identify`` process on one-state heave logs of several lengths (medians of
  three processes), and on the 10⁶-sample log each step of the fit with its CPU time and
  the resident memory at its start and its peak (where the peak is reached);
* ``pem_path``: ``identify`` (default estimator, which takes ``pem`` there) on a
  10⁴-sample log with a Gauss–Markov current, in-process;
* ``white_path``: ``identify`` (default estimator) on white 10⁴-sample heave logs of
  20 seeds, in-process: what it chose on each and the time per log.

``python scripts/bench_scaling.py`` prints the figures; ``python scripts/bench.py
--docs`` runs them and writes ``docs/performance.md`` (:func:`write_docs`).
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

__all__ = [
    "bench_identify_memory",
    "bench_mc_threads",
    "bench_pem_path",
    "bench_single_envs",
    "bench_white_path",
    "machine",
    "write_docs",
]


def _load() -> float:
    return os.getloadavg()[0]


# ----------------------------------------------------------------- single environments
def _single_loop(env_id: str, steps: int) -> Callable[[], tuple[float, float]]:
    """A timed loop of ``steps`` raw steps of ``env_id``: returns (wall, cpu) seconds."""
    import gymnasium as gym

    import vesselid  # noqa: F401  (registers the environments)

    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(256)]
    step, reset = env.step, env.reset
    for i in range(2000):  # warm-up: compilation, first noise blocks
        out = step(actions[i & 255])
        if out[2] or out[3]:
            reset()

    def run() -> tuple[float, float]:
        c0, t0 = time.process_time(), time.perf_counter()
        for i in range(steps):
            out = step(actions[i & 255])
            if out[2] or out[3]:
                reset()
        return time.perf_counter() - t0, time.process_time() - c0

    return run


def _vector_rate(env_id: str, num_envs: int, steps: int, repeats: int) -> dict[str, float]:
    import gymnasium as gym

    envs = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    envs.reset(seed=0)
    width = envs.single_action_space.shape[0]
    actions = np.random.default_rng(0).uniform(-1, 1, (num_envs, width)).astype(np.float32)
    for _ in range(50):
        envs.step(actions)
    wall, cpu = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        for _ in range(steps):
            envs.step(actions)
        wall.append(steps * num_envs / (time.perf_counter() - t0))
        cpu.append(steps * num_envs / (time.process_time() - c0))
    envs.close()
    return {"wall": statistics.median(wall), "cpu": statistics.median(cpu)}


def bench_single_envs(repeats: int = 7, steps: int = 20_000, num_envs: int = 1024,
                      vector_steps: int = 300) -> dict[str, Any]:
    """Steps/s of the single environments against CartPole-v1 (alternated), and the
    vector environments' env-steps/s (module docstring)."""
    warnings.simplefilter("ignore")
    ids = ("CartPole-v1", "vesselid/Heave-v0", "vesselid/Manoeuvring3DOF-v0")
    loops = {k: _single_loop(k, steps) for k in ids}
    wall: dict[str, list[float]] = {k: [] for k in ids}
    cpu: dict[str, list[float]] = {k: [] for k in ids}
    loads = []
    for _ in range(repeats):
        for k in ids:
            w, c = loops[k]()
            wall[k].append(steps / w)
            cpu[k].append(steps / c)
        loads.append(_load())
    out: dict[str, Any] = {"steps": steps, "repeats": repeats,
                           "load_average": statistics.median(loads)}
    base_w, base_c = statistics.median(wall[ids[0]]), statistics.median(cpu[ids[0]])
    for k in ids:
        name = k.split("/")[-1]
        out[f"{name}_steps_per_s_wall"] = statistics.median(wall[k])
        out[f"{name}_steps_per_s_cpu"] = statistics.median(cpu[k])
        out[f"{name}_ratio_wall"] = statistics.median(wall[k]) / base_w
        out[f"{name}_ratio_cpu"] = statistics.median(cpu[k]) / base_c
    for k in ids[1:]:
        rates = _vector_rate(k, num_envs, vector_steps, max(3, repeats // 2))
        name = k.split("/")[-1]
        out[f"{name}_vector_env_steps_per_s_wall"] = rates["wall"]
        out[f"{name}_vector_env_steps_per_s_cpu"] = rates["cpu"]
    out["num_envs"] = num_envs
    out["load_average_end"] = _load()
    return out


# ----------------------------------------------------------------- Monte Carlo workers
class _ChunkClock:
    """Records every worker chunk's CPU seconds (``time.process_time`` of the worker
    process around the chunk), its main thread's critical path (its CPU clock, with the
    longest block in place of the blocks it ran itself in each call spread over idle
    cores, :func:`vesselid.core.threads.span_clock`) and its process id into a file,
    by wrapping :func:`vesselid.studies.montecarlo._serial_chunk` (what each forked worker
    runs, looked up in the module when it runs a chunk): the CPU clock per worker, which
    the children's summed CPU from ``getrusage`` cannot give. The wrapper keeps the
    function's name (a thread pool's chunks call it by reference too)."""

    def __init__(self, path: Path) -> None:
        from vesselid.studies import montecarlo

        self.path = path
        self.module = montecarlo
        self.original = montecarlo._serial_chunk

    def __enter__(self) -> _ChunkClock:
        original, path = self.original, self.path

        from vesselid.core.threads import span_clock

        def clocked(study: Any, start: int, stop: int, *args: Any) -> Any:
            c0, m0 = time.process_time(), time.thread_time() + span_clock()
            out = original(study, start, stop, *args)
            c1, m1 = time.process_time(), time.thread_time() + span_clock()
            with open(path, "a") as fh:  # one short line per chunk (appends are atomic)
                fh.write(f"{os.getpid()} {c1 - c0!r} {m1 - m0!r} {start} {stop}\n")
            return out

        clocked.__module__ = original.__module__
        clocked.__qualname__ = original.__qualname__
        clocked.__name__ = original.__name__
        self.module._serial_chunk = clocked
        self.path.write_text("")
        return self

    def __exit__(self, *exc: object) -> None:
        self.module._serial_chunk = self.original

    def records(self) -> list[tuple[int, float, float]]:
        """``(first run, CPU, main-thread CPU)`` of every chunk of the last run, in the
        order they were submitted; starts the next run's record."""
        rows = [line.split() for line in self.path.read_text().splitlines()]
        self.path.write_text("")
        return sorted((int(r[3]), float(r[1]), float(r[2])) for r in rows)

    def read(self) -> tuple[list[float], list[float]]:
        """CPU seconds per worker process (largest first) and per chunk of the last
        run, the chunks in the order they were submitted (their first runs); starts the
        next run's record."""
        cpu: dict[str, float] = {}
        chunks = []
        for line in self.path.read_text().splitlines():
            pid, sec, _, start, _ = line.split()
            cpu[pid] = cpu.get(pid, 0.0) + float(sec)
            chunks.append((int(start), float(sec)))
        self.path.write_text("")
        return sorted(cpu.values(), reverse=True), [c for _, c in sorted(chunks)]


def _makespan(chunks: list[float], workers: int) -> float:
    """The longest worker's CPU when the chunks (CPU seconds) go to ``workers`` free
    cores, each chunk to the least loaded worker in the pool's order (what the process
    pool does when no other work takes the cores)."""
    load = [0.0] * max(workers, 1)
    for c in chunks:
        i = load.index(min(load))
        load[i] += c
    return max(load)


def _projected_makespan(costs: list[tuple[float, float]], workers: int) -> float:
    """The busiest of ``workers`` free cores when the chunks (``(CPU, main-thread CPU)``
    seconds, in submission order) go in order to the least loaded worker, each taking
    its main thread's CPU (a second thread of a long job runs on a core the other
    workers leave free at the end), and at least the total CPU over the cores."""
    return max(_makespan([m for _, m in costs], workers),
               sum(c for c, _ in costs) / max(workers, 1))


def project_mc_workers(study: Any, counts: tuple[int, ...], clock: _ChunkClock,
                       reference: bytes, tmp: Path, repeats: int = 1) -> dict[str, Any]:
    """Projected critical paths of the Monte Carlo on ``counts`` free cores, from measured
    per-chunk CPU costs: the study is run with that many worker processes on this
    machine's cores (the default schedule for that many workers,
    :func:`vesselid.studies.montecarlo._local_chunks`), every chunk's CPU clock is
    recorded (``clock``), and the chunks are list-scheduled on that many free cores
    (:func:`_projected_makespan`); the critical path adds the parent's own CPU in that
    run (forking the first worker, gathering) and the longest chain of forks that started
    a worker (:func:`vesselid.core.forkpool.start_chains`). Medians of ``repeats``. The
    result CSV is compared with ``reference`` byte for byte. A projection from this machine's
    per-chunk clocks, not a measurement on that many cores (memory bandwidth shared by
    more workers is not in it)."""
    from vesselid.core import threads
    from vesselid.core.forkpool import start_chains
    from vesselid.studies.montecarlo import run_study, save_results

    out: dict[str, Any] = {}
    original = threads.n_threads
    for n in counts:
        spans, parents, totals, longest, identical = [], [], [], [], True
        threads.n_threads = lambda n=n: n  # that many workers (inherited by the forks)
        try:
            for _ in range(repeats):
                clock.read()
                c0 = time.process_time()
                df = run_study(study, progress=False)
                # the parent's CPU and the longest chain of forks that started a worker
                # (vesselid.core.forkpool: the workers fork each other as a tree)
                parents.append(time.process_time() - c0 + max(start_chains(), default=0.0))
                records = clock.records()
                costs = [(cpu, main) for _, cpu, main in records]
                spans.append(_projected_makespan(costs, n))
                totals.append(sum(c for c, _ in costs))
                longest.append(max(records, key=lambda r: r[2]))
                path = tmp / f"table1_projected_{n}.csv"
                save_results(df, path)
                identical &= path.read_bytes() == reference
        finally:
            threads.n_threads = original
        span, parent = statistics.median(spans), statistics.median(parents)
        start, _, main = sorted(longest, key=lambda r: r[2])[len(longest) // 2]
        out.update({
            f"p{n}_chunk_cpu_total_s": statistics.median(totals),
            f"p{n}_longest_chunk": f"from run {start}: {main:.3f} s main thread",
            f"p{n}_parent_cpu_s": parent,
            f"p{n}_makespan_s": span,
            f"p{n}_critical_path_s": parent + span,
            f"p{n}_csv_byte_identical": identical,
        })
    return out


def bench_mc_threads(repeats: int = 3, runs: int = 1000, samples: int = 10_000,
                     workers: tuple[int, ...] = (1, 2),
                     project: tuple[int, ...] = (4, 8, 16)) -> dict[str, Any]:
    """The Monte Carlo part of Table 1 with each worker count of ``workers`` (``n_jobs``),
    alternated: wall, the CPU of this process and of every worker process (medians), and
    the result CSVs compared byte for byte.

    The speed-up of ``n`` workers on ``n`` free cores is estimated from the CPU clocks as
    well as read off the wall clock: the ``n``-worker run's critical path is this
    process's own CPU (forking, gathering; the one-run warm-up where it applies) and the
    longest chain of forks that started a worker, plus the busiest worker's
    CPU, against the one-worker run's CPU. On a quiet machine the wall-clock ratio is the
    measurement; on a shared one it measures the neighbours, and the CPU estimate is the
    figure that holds. The busiest worker is the one of ``n`` free cores: the chunks'
    CPU clocks assigned in order to the least loaded worker (:func:`_makespan`), since on
    a shared machine a descheduled worker leaves its chunks to the others and the
    measured split says more about the neighbours than about the work.

    ``project``: worker counts whose critical paths are projected from measured
    per-chunk CPU costs (:func:`project_mc_workers`), against the one-worker CPU.
    """
    from vesselid.core.forkpool import start_chains
    from vesselid.studies.montecarlo import run_study, save_results
    from vesselid.studies.reproduce import table_study, warm_up

    warnings.simplefilter("ignore")
    warm_up()
    study = table_study(1, runs=runs, samples=samples)
    wall: dict[int, list[float]] = {n: [] for n in workers}
    cpu: dict[int, list[float]] = {n: [] for n in workers}
    own: dict[int, list[float]] = {n: [] for n in workers}
    busiest: dict[int, list[float]] = {n: [] for n in workers}
    per_worker: dict[int, list[list[float]]] = {n: [] for n in workers}
    loads = []
    with tempfile.TemporaryDirectory() as tmp, _ChunkClock(Path(tmp) / "chunks.txt") as clock:
        paths = {n: Path(tmp) / f"table1_{n}.csv" for n in workers}
        for _ in range(repeats):
            for n in workers:
                clock.read()  # start empty
                ch0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                c0, t0 = time.process_time(), time.perf_counter()
                df = run_study(study, n_jobs=n, progress=False)
                wall[n].append(time.perf_counter() - t0)
                ch1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                own[n].append(time.process_time() - c0
                              + (max(start_chains(), default=0.0) if n > 1 else 0.0))
                cpu[n].append(own[n][-1] + (ch1.ru_utime + ch1.ru_stime)
                              - (ch0.ru_utime + ch0.ru_stime))
                workers_cpu, chunks = clock.read()
                per_worker[n].append(workers_cpu)
                # one worker runs its chunks in this process: its CPU is this process's
                busiest[n].append(_makespan(chunks, n) if chunks else 0.0)
                save_results(df, paths[n])
                loads.append(_load())
        first = paths[workers[0]].read_bytes()
        identical = all(paths[n].read_bytes() == first for n in workers)
        proj = (project_mc_workers(study, tuple(project), clock, first, Path(tmp))
                if project else {})
    base_cpu = statistics.median(cpu[workers[0]])
    base_wall = statistics.median(wall[workers[0]])
    out: dict[str, Any] = {"runs": runs, "samples": samples, "repeats": repeats,
                           "workers": list(workers), "csv_byte_identical": identical,
                           "load_average": statistics.median(loads)}
    for n in workers:
        w, c, p = (statistics.median(wall[n]), statistics.median(cpu[n]),
                   statistics.median(own[n]))
        crit = p + statistics.median(busiest[n]) if n > 1 else c
        mid = sorted(per_worker[n], key=sum)[len(per_worker[n]) // 2]
        out.update({f"w{n}_wall_s": w, f"w{n}_cpu_s": c, f"w{n}_parent_cpu_s": p,
                    f"w{n}_worker_cpu_s": [round(x, 3) for x in mid],
                    f"w{n}_critical_path_s": crit,
                    f"w{n}_speedup_wall": base_wall / w,
                    f"w{n}_speedup_cpu_estimate": base_cpu / crit})
    # the names the performance page reads (one and two workers)
    if 1 in workers and 2 in workers:
        out.update({"one_worker_wall_s": out["w1_wall_s"], "two_workers_wall_s": out["w2_wall_s"],
                    "speedup_wall": out["w1_wall_s"] / out["w2_wall_s"],
                    "one_worker_cpu_s": out["w1_cpu_s"], "two_workers_cpu_s": out["w2_cpu_s"],
                    "two_workers_parent_cpu_s": out["w2_parent_cpu_s"],
                    "critical_path_two_cores_s": out["w2_critical_path_s"],
                    "estimated_speedup_two_cores": out["w2_speedup_cpu_estimate"]})
    if project:
        for n in project:
            proj[f"p{n}_projected_speedup"] = base_cpu / proj[f"p{n}_critical_path_s"]
        out.update({"projected_workers": list(project), **proj})
    out["load_average_end"] = _load()
    return out


# ----------------------------------------------------------------- identify's memory
#: Runs a command and prints its wall, CPU and peak RSS: started from this small process,
#: so the child's peak resident memory is its own (a child forked straight from the
#: benchmark process counts the benchmark's pages until it execs).
_MEASURE = """
import os, subprocess, sys, time
t0 = time.perf_counter()
proc = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
_, status, usage = os.wait4(proc.pid, 0)
wall = time.perf_counter() - t0
if os.waitstatus_to_exitcode(status) != 0:
    sys.exit(proc.stderr.read().decode())
print(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss * 1024.0)
"""


def _run_measured(cmd: list[str], env: dict[str, str] | None = None
                  ) -> tuple[float, float, float]:
    """(wall s, CPU s, peak RSS bytes) of a command run as a child process (``env``:
    its environment, default this process's)."""
    out = subprocess.run([sys.executable, "-c", _MEASURE, *cmd], capture_output=True,
                         text=True, check=False, env=env)
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {out.stderr.strip()}")
    wall, cpu, rss = (float(x) for x in out.stdout.split())
    return wall, cpu, rss


#: Runs ``vesselid identify LOG`` in this process with the resident memory sampled every
#: 2 ms and each step of ``Estimator.fit`` (and the steps of the default estimator's
#: estimate) timed: prints one JSON list of ``[step, depth, CPU s, RSS at entry MB, peak
#: RSS during MB]`` in the order the steps start.
_PHASES = """
import functools, json, os, sys, threading, time
page = os.sysconf("SC_PAGE_SIZE")
def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * page / 1e6
open_steps, rows, depth = [], [], [0]
def sample():
    while True:
        r = rss()
        for cell in list(open_steps):
            cell[0] = max(cell[0], r)
        time.sleep(0.002)
threading.Thread(target=sample, daemon=True).start()
from vesselid.core.memory import arrow_system_allocator
arrow_system_allocator()  # as `vesselid identify` does, before pyarrow is imported
def wrap(owner, name, label):
    fn = getattr(owner, name)
    @functools.wraps(fn)
    def timed(*a, **k):
        cell = [rss()]
        entry, c0, start = cell[0], time.process_time(), time.perf_counter()
        open_steps.append(cell)
        depth[0] += 1
        try:
            return fn(*a, **k)
        finally:
            depth[0] -= 1
            open_steps.pop()
            rows.append([start, label, depth[0], time.process_time() - c0, entry,
                         max(cell[0], rss())])
    setattr(owner, name, timed)
from vesselid.data import logs
from vesselid.identify import base, efficient, validity
wrap(logs.TrialLog, "load", "read the log")
for step in ("regression", "estimate", "feedback", "covariance", "specification",
             "fit_quality"):
    wrap(base.Estimator, "_" + step, step.replace("_", " "))
for step, label in (("_refine", "refined GMM steps"), ("_colour_test", "colour test")):
    wrap(efficient.InstrumentalGMM, step, label)
for step in ("parameter_stability", "mean_current"):
    wrap(validity, step, step.replace("_", " "))
from vesselid.cli import main
code = main(["identify", sys.argv[1]])
rows.append([time.perf_counter(), "whole process", 0, time.process_time(), 0.0, float(
    open("/proc/self/status").read().split("VmHWM:")[1].split()[0]) * 1024 / 1e6])
sys.stdout.flush()
print(json.dumps([r[1:] for r in sorted(rows)]), file=sys.stderr)
sys.exit(code)
"""


def bench_identify_memory(sizes: tuple[int, ...] = (100_000, 1_000_000, 4_000_000),
                          repeats: int = 3, fmt: str = "parquet",
                          phases_at: int | None = 1_000_000,
                          floor_samples: int | None = 1_000) -> dict[str, Any]:
    """Peak RSS and time of the whole ``vesselid identify LOG`` process (default
    estimator) on one-state heave logs (``fmt``: Parquet, or CSV) of ``sizes``
    samples, medians of ``repeats`` processes per size; the growth per 10⁶ samples
    between the two largest logs and as the least-squares slope over every size (linear
    growth: the two agree). ``phases_at``: on that log also where the peak is reached —
    every step of the fit with its CPU time, its resident memory at entry and its peak
    (one process sampling its own RSS every 2 ms; the sampling thread costs a little
    CPU). ``floor_samples``: the process on a log that short with the compiled kernels
    (``VESSELID_KERNELS=compiled``): what it holds besides the log's own arrays (the
    imports, numba and its loaded kernels; logs of at most
    :data:`~vesselid.identify.backend.NUMPY_MAX_SAMPLE_TERMS` samples × parameters run on
    the numpy kernels without numba)."""
    import json

    from vesselid.plant.systems import heave

    out: dict[str, Any] = {"sizes": list(sizes), "format": fmt, "repeats": repeats}
    exe = [sys.executable, "-m", "vesselid", "identify"]
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            path = Path(tmp) / f"heave_{n}.{fmt}"
            heave().simulate(n, seed=0).to_log().save(path)
            runs = [_run_measured([*exe, str(path)]) for _ in range(repeats)]
            out[f"{n}_wall_s"] = statistics.median(r[0] for r in runs)
            out[f"{n}_cpu_s"] = statistics.median(r[1] for r in runs)
            out[f"{n}_peak_rss_mb"] = statistics.median(r[2] for r in runs) / 1e6
            out[f"{n}_load_average"] = _load()
            if n == phases_at:
                proc = subprocess.run([sys.executable, "-c", _PHASES, str(path)],
                                      capture_output=True, text=True, check=False,
                                      env={**os.environ, "MPLBACKEND": "Agg"})
                if proc.returncode == 0:
                    out["phases_samples"] = n
                    out["phases"] = json.loads(proc.stderr.strip().splitlines()[-1])
            path.unlink()
        if floor_samples:
            path = Path(tmp) / f"heave_{floor_samples}.{fmt}"
            heave().simulate(floor_samples, seed=0).to_log().save(path)
            env = {**os.environ, "VESSELID_KERNELS": "compiled"}
            runs = [_run_measured([*exe, str(path)], env) for _ in range(repeats)]
            out["floor_samples"] = floor_samples
            out["floor_peak_rss_mb"] = statistics.median(r[2] for r in runs) / 1e6
            from vesselid.identify.backend import NUMPY_MAX_SAMPLE_TERMS

            n_params = heave().spec.n_params
            out["numpy_kernel_sizes"] = [n for n in sizes
                                         if n * n_params <= NUMPY_MAX_SAMPLE_TERMS]
    big = [n for n in sizes if n >= 1_000_000]
    if len(big) >= 2:  # slope per 10⁶ samples between the two largest logs
        a, b = big[-2], big[-1]
        out["rss_mb_per_1e6_samples"] = ((out[f"{b}_peak_rss_mb"] - out[f"{a}_peak_rss_mb"])
                                         / ((b - a) / 1e6))
    if len(sizes) >= 2:
        x = np.array(sizes, dtype=float) / 1e6
        y = np.array([out[f"{n}_peak_rss_mb"] for n in sizes])
        slope, intercept = np.polyfit(x, y, 1)
        out["rss_mb_per_1e6_samples_fit"] = float(slope)
        out["rss_mb_intercept"] = float(intercept)
    return out


def bench_identify_large_paths(n: int = 1_000_000) -> dict[str, Any]:
    """How far the bounded-memory forms of a long log (block-wise sums, refined normal
    equations; taken above ``covariance.LARGE_ROWS`` rows) move ``identify``'s results
    from the whole-array forms: the largest relative difference of the estimates, the
    covariance and every test statistic on one ``n``-sample heave log."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import identify
    from vesselid.plant.systems import heave

    warnings.simplefilter("ignore")
    log = heave().simulate(n, seed=0).to_log()
    got = identify(log)
    large = cv.LARGE_ROWS
    cv.LARGE_ROWS = 1 << 62  # every whole-array form
    try:
        ref = identify(log)
    finally:
        cv.LARGE_ROWS = large

    def rel(a: Any, b: Any) -> float:
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))

    dg, dr = got.diagnostics, ref.diagnostics
    state = next(iter(dr["specification"]))
    sg, sr = dg["specification"][state], dr["specification"][state]
    out = {"samples": n, "params": rel(got.params.to_numpy(), ref.params.to_numpy()),
           "cov": rel(got.cov.to_numpy(), ref.cov.to_numpy())}
    for test in ("endogeneity", "hansen_j"):
        if sr.get(test, {}).get("stat") is not None:
            out[test] = rel(sg[test]["stat"], sr[test]["stat"])
    out["cragg_donald"] = rel(sg["first_stage"]["cragg_donald"],
                              sr["first_stage"]["cragg_donald"])
    out["partial_f"] = max(rel(sg["first_stage"]["partial_f"][k], v)
                           for k, v in sr["first_stage"]["partial_f"].items())
    for key, field in (("feedback", "statistic"), ("parameter_stability", "statistic")):
        if dr.get(key) and dr[key].get(field) is not None:
            out[key] = rel(dg[key][field], dr[key][field])
    for key in ("colour_test", "c_test_lagged", "hansen_j_combined"):
        if dr.get(key):
            out[key] = rel(dg[key][0]["stat"], dr[key][0]["stat"])
    out["max_relative_difference"] = max(v for k, v in out.items() if k != "samples")
    return out


# ----------------------------------------------------------------- the pem path
def bench_pem_path(repeats: int = 11) -> dict[str, Any]:
    """``identify(log)`` on a 10⁴-sample heave log with a Gauss–Markov current (the
    default estimator takes ``pem`` there), in-process: median wall and CPU, as it runs
    (its candidate disturbance models on two threads where two cores are usable) and on
    one thread (``numba.set_num_threads(1)``: every fit in turn), alternating."""
    import numba

    from vesselid.identify import identify
    from vesselid.studies.calibration import heave_scenario

    warnings.simplefilter("ignore")
    system, _, _ = heave_scenario("gm-current-random")
    log = system.simulate(10_000, seed=0).to_log(aggregate=False)
    res = identify(log)
    threads = numba.get_num_threads()
    times: dict[str, list[float]] = {k: [] for k in ("wall", "cpu", "wall_1", "cpu_1")}
    for _ in range(repeats):
        for tail, n in (("", threads), ("_1", 1)):
            numba.set_num_threads(n)
            try:
                c0, t0 = time.process_time(), time.perf_counter()
                identify(log)
                times["wall" + tail].append(time.perf_counter() - t0)
                times["cpu" + tail].append(time.process_time() - c0)
            finally:
                numba.set_num_threads(threads)
    med = {k: 1000 * statistics.median(v) for k, v in times.items()}
    return {"choice": res.diagnostics.get("instruments", ""),
            "identify_ms_wall": med["wall"], "identify_ms_cpu": med["cpu"],
            "identify_ms_wall_one_thread": med["wall_1"],
            "identify_ms_cpu_one_thread": med["cpu_1"], "load_average": _load()}


def bench_white_path(logs: int = 20, repeats: int = 7) -> dict[str, Any]:
    """``identify(log, spec)`` (the default estimator) in-process on white 10⁴-sample
    heave logs (the paper's system, seeds ``0 … logs − 1``): each log's choice and its
    median wall and CPU time over ``repeats`` consecutive calls after a first one (as
    ``scripts/bench.py``'s one-log figure is timed). The default takes the delayed
    instruments on most white logs and a likelihood fit where the colour test's p-value
    falls in its guard band; the figures per choice and over all logs."""
    from vesselid.identify import identify
    from vesselid.plant.systems import heave

    warnings.simplefilter("ignore")
    logs_ = [heave().simulate(10_000, seed=s).to_log() for s in range(logs)]
    spec = logs_[0].spec
    choices = [str(identify(lg, spec).diagnostics.get("choice")) for lg in logs_]
    wall: list[list[float]] = [[] for _ in logs_]
    cpu: list[list[float]] = [[] for _ in logs_]
    for i, lg in enumerate(logs_):
        for _ in range(repeats):
            c0, t0 = time.process_time(), time.perf_counter()
            identify(lg, spec)
            wall[i].append(time.perf_counter() - t0)
            cpu[i].append(time.process_time() - c0)
    per_wall = [1000 * statistics.median(w) for w in wall]
    per_cpu = [1000 * statistics.median(c) for c in cpu]
    by_choice: dict[str, dict[str, float]] = {}
    for ch in sorted(set(choices)):
        idx = [i for i, c in enumerate(choices) if c == ch]
        by_choice[ch] = {"logs": len(idx),
                         "wall_ms": statistics.median(per_wall[i] for i in idx),
                         "cpu_ms": statistics.median(per_cpu[i] for i in idx)}
    return {"logs": logs, "choices": choices, "per_log_wall_ms": per_wall,
            "per_log_cpu_ms": per_cpu, "by_choice": by_choice,
            "median_wall_ms": statistics.median(per_wall),
            "median_cpu_ms": statistics.median(per_cpu),
            "seed0_wall_ms": per_wall[0], "seed0_cpu_ms": per_cpu[0],
            "load_average": _load()}


# ----------------------------------------------------------------- the page
def machine() -> dict[str, Any]:
    """The machine in words: CPU model, cores usable, memory, Python and numpy."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count() or 1
    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError, AttributeError):
        mem = float("nan")
    return {"cpu": model, "cores": cores, "memory_gib": mem,
            "python": platform.python_version(), "numpy": np.__version__,
            "system": f"{platform.system()} {platform.release()}"}


def _fmt(x: float, digits: int = 3) -> str:
    return f"{x:,.{digits}g}" if abs(x) < 10 ** digits else f"{x:,.0f}"


def render(results: dict[str, Any], info: dict[str, Any]) -> str:
    """The performance page (MyST Markdown) from the benchmark figures."""
    lines = [
        "# Performance",
        "",
        "Generated by `python scripts/bench.py --docs` (the benchmarks of "
        "`scripts/bench_scaling.py`); every figure below comes from one run of that "
        "command. Comparisons are measured in alternation in one process and reported "
        "as medians, with the wall clock and the CPU clock (all threads of the process "
        "and, for the Monte Carlo, its worker processes) and the 1-minute load average "
        "while they ran: on a shared machine the wall clock also measures the "
        "neighbours, the CPU clock measures the work.",
        "",
        "## Machine",
        "",
        "| | |",
        "|---|---|",
        f"| CPU | {info['cpu']} |",
        f"| cores usable | {info['cores']} |",
        f"| memory | {info['memory_gib']:.1f} GiB |",
        f"| system | {info['system']}, Python {info['python']}, numpy {info['numpy']} |",
        "",
    ]
    env = results.get("single_envs")
    if env:
        lines += [
            "## Single environments against CartPole-v1",
            "",
            f"Raw `env.unwrapped.step` calls per second, {env['steps']:,} steps per "
            f"timing, median of {env['repeats']} alternated timings; random actions "
            "drawn beforehand from each action space, reset on termination; load "
            f"average {env['load_average']:.1f}.",
            "",
            "| environment | steps/s (wall) | × CartPole (wall) | steps/s (CPU) "
            "| × CartPole (CPU) |",
            "|---|---:|---:|---:|---:|",
        ]
        for name in ("CartPole-v1", "Heave-v0", "Manoeuvring3DOF-v0"):
            lines.append(
                f"| {name} | {_fmt(env[f'{name}_steps_per_s_wall'])} | "
                f"{env[f'{name}_ratio_wall']:.2f} | {_fmt(env[f'{name}_steps_per_s_cpu'])} | "
                f"{env[f'{name}_ratio_cpu']:.2f} |")
        lines += [
            "",
            f"Vector environments ({env['num_envs']} sub-environments, next-step "
            "autoreset), env-steps per second:",
            "",
            "| environment | env-steps/s (wall) | env-steps/s (CPU) |",
            "|---|---:|---:|",
        ]
        for name in ("Heave-v0", "Manoeuvring3DOF-v0"):
            lines.append(f"| {name} | {_fmt(env[f'{name}_vector_env_steps_per_s_wall'])} | "
                         f"{_fmt(env[f'{name}_vector_env_steps_per_s_cpu'])} |")
        lines.append("")
    mc = results.get("mc_threads")
    if mc:
        lines += [
            "## Monte Carlo workers",
            "",
            f"The Monte Carlo part of `vesselid reproduce --table 1` ({mc['runs']:,} runs "
            f"× {mc['samples']:,} samples), median of {mc['repeats']} alternated runs; "
            f"load average {mc['load_average']:.1f}. Concurrent chunks run in forked "
            "worker processes (threads where the platform does not fork); the result "
            "CSVs of one and two workers are "
            + ("byte-identical." if mc["csv_byte_identical"] else "**not** identical.")
            + " CPU: this process and its workers.",
            "",
            "| workers | wall (s) | CPU, all (s) | parent CPU (s) | CPU per worker (s) "
            "| critical path (s) | speed-up (wall) | speed-up (CPU estimate) |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for n in mc.get("workers", [1, 2]):
            per = mc.get(f"w{n}_worker_cpu_s") or []
            lines.append(
                f"| {n} | {mc[f'w{n}_wall_s']:.2f} | {mc[f'w{n}_cpu_s']:.2f} | "
                f"{mc[f'w{n}_parent_cpu_s']:.2f} | "
                f"{' / '.join(f'{x:.2f}' for x in per) if per else '—'} | "
                f"{mc[f'w{n}_critical_path_s']:.2f} | {mc[f'w{n}_speedup_wall']:.2f}× | "
                f"{mc[f'w{n}_speedup_cpu_estimate']:.2f}× |")
        lines += [
            "",
            "CPU per worker: each forked worker process's own CPU clock over its chunks, "
            "as the pool split them in this run. The critical path of a run with several "
            "workers on as many free cores is the parent's own CPU (forking the first "
            "worker, gathering; the one-run warm-up where this process has not run the "
            "study's kernels yet) and the longest chain of forks that started a worker "
            "(the workers fork each other as a tree, `vesselid.core.forkpool`), plus the "
            "busiest worker's CPU when the chunks (their "
            "measured CPU clocks) go in order to the least loaded worker; the CPU "
            "estimate of the speed-up is the one-worker run's CPU over it. On a quiet "
            "machine the wall-clock speed-up is the "
            "measurement; where other work takes the cores, the wall clock measures the "
            "share the scheduler gives this process group, and the CPU estimate is the "
            "figure that holds.",
            "",
            "Each worker keeps the BLAS on one thread for its whole life (set when it "
            "starts; the parent's setting is untouched), so no BLAS thread is started in "
            "a worker to spin for work; where a worker's share of the runs is at most "
            "250 (four or more workers here), a worker may still hand one long job to a "
            "second thread (`auto`'s prediction-error fallback fits its candidate "
            "models at once: the same numbers), and that fallback's line searches filter "
            "their trial steps together, on the cores the other workers leave idle once "
            "they have run out of chunks (`vesselid.core.threads.idle_cores`), with the "
            "tangent pass at the likely step computed ahead on one of them (each trial "
            "step filtered on its own, the steps judged in order, a pass computed ahead "
            "used only where its step is taken: the same numbers). "
            "While the study runs, the process keeps "
            "freed memory in its heap (`vesselid.core.heap.kept_heap`; "
            "`VESSELID_KEEP_HEAP=0` leaves glibc's settings alone), so "
            "the chunks' large arrays reuse it instead of faulting in fresh pages every "
            "chunk; forked workers inherit the setting.",
            "",
        ]
        proj = mc.get("projected_workers") or []
        if proj:
            lines += [
                "Projected, not measured: the critical path on more free cores than this "
                "machine has, from the per-chunk CPU clocks of a run with that many "
                "worker processes here (the default schedule for that many workers), "
                "the chunks list-scheduled in order on that many cores (a chunk takes "
                "its main thread's CPU, with the longest block in place of the blocks it "
                "ran itself where a line search was spread over idle cores, and a pass "
                "computed ahead counted from when it started where the main thread waited "
                "for it; at least the total CPU over the cores), plus the parent's own "
                "CPU in that run and the longest chain of forks that started a worker. "
                "Memory bandwidth shared by more workers is not in it.",
                "",
                "| workers | chunks' CPU (s) | parent CPU (s) | makespan (s) "
                "| critical path (s) | projected speed-up | longest chunk "
                "| CSV byte-identical |",
                "|---:|---:|---:|---:|---:|---:|---|---|",
            ]
            for n in proj:
                lines.append(
                    f"| {n} | {mc[f'p{n}_chunk_cpu_total_s']:.2f} | "
                    f"{mc[f'p{n}_parent_cpu_s']:.2f} | {mc[f'p{n}_makespan_s']:.2f} | "
                    f"{mc[f'p{n}_critical_path_s']:.2f} | "
                    f"{mc[f'p{n}_projected_speedup']:.2f}× | {mc[f'p{n}_longest_chunk']} | "
                    f"{'yes' if mc[f'p{n}_csv_byte_identical'] else '**no**'} |")
            lines.append("")
    mem = results.get("identify_memory")
    if mem:
        lines += [
            "## Memory of `vesselid identify`",
            "",
            "The whole `vesselid identify LOG` process (default estimator, every "
            f"diagnostic) on one-state heave logs ({mem.get('format', 'csv')}), peak "
            "resident memory from `wait4`; medians of "
            f"{mem.get('repeats', 1)} processes per log.",
            "",
            "The command fixes glibc's mmap threshold (freed temporaries leave the "
            "process), makes the C library's allocator Arrow's pool (a Parquet log's "
            "columns hold no more than themselves), and between the steps of the fit "
            "returns the clean code pages of LLVM (faulted in while numba loads the "
            "kernels from its cache: 50–70 MB that the loaded kernels never run) and of "
            "Arrow and Parquet (once the log is read) with `madvise(MADV_DONTNEED)` "
            "(`vesselid.core.memory`): they leave the process's resident set and stay in "
            "the page cache, and a later step that runs that code faults in the pages it "
            "touches. A one-state log's measured state and input are read in place (the "
            "fit's target and input are views of the log's columns, not copies). The peak "
            "is then the log's arrays and the fit's temporaries on top of the imports and "
            "numba's own Python objects.",
            "",
            "| samples | peak RSS (MB) | wall (s) | CPU (s) | load average |",
            "|---:|---:|---:|---:|---:|",
        ]
        for n in mem["sizes"]:
            lines.append(f"| {n:,} | {mem[f'{n}_peak_rss_mb']:.0f} | {mem[f'{n}_wall_s']:.2f} "
                         f"| {mem[f'{n}_cpu_s']:.2f} | {mem[f'{n}_load_average']:.1f} |")
        if "rss_mb_per_1e6_samples" in mem:
            lines += ["", f"Growth between the two largest logs: "
                          f"{mem['rss_mb_per_1e6_samples']:.0f} MB per 10⁶ samples"
                          + (f" (least-squares slope over every size "
                             f"{mem['rss_mb_per_1e6_samples_fit']:.0f} MB per 10⁶ samples, "
                             f"intercept {mem['rss_mb_intercept']:.0f} MB)."
                             if "rss_mb_per_1e6_samples_fit" in mem else ".")]
        numpy_sizes = mem.get("numpy_kernel_sizes") or []
        if "floor_peak_rss_mb" in mem:
            lines += ["", f"A {mem['floor_samples']:,}-sample log on the compiled kernels "
                          f"(`VESSELID_KERNELS=compiled`): {mem['floor_peak_rss_mb']:.0f} MB, "
                          "what the process holds besides the log's own arrays (the "
                          "imports, numba and its loaded kernels; its peak is reached "
                          "while numba initialises LLVM and loads the first kernels, "
                          "before their code pages are returned)."
                          + (" The logs of " + ", ".join(f"{n:,}" for n in numpy_sizes)
                             + " samples run on the numpy kernels, without numba."
                             if numpy_sizes else "")]
        if mem.get("phases"):
            lines += render_phases(mem["phases"], mem["phases_samples"])
        lines.append("")
    pem = results.get("pem_path")
    if pem:
        lines += [
            "## The prediction-error path",
            "",
            "`identify(log)` in-process on a 10⁴-sample heave log with a Gauss–Markov "
            "current (where both instrument-validity tests reject and the default "
            f"estimator takes the {pem['choice'].split(': ', 1)[-1]}): "
            f"{pem['identify_ms_wall']:.0f} ms wall, {pem['identify_ms_cpu']:.0f} ms CPU "
            + (f"with its candidate models on two threads, "
               f"{pem['identify_ms_wall_one_thread']:.0f} ms wall, "
               f"{pem['identify_ms_cpu_one_thread']:.0f} ms CPU on one "
               if "identify_ms_wall_one_thread" in pem else "")
            + f"(medians; load average {pem['load_average']:.1f}).",
            "",
        ]
    white = results.get("white_path")
    if white:
        lines += [
            "## The white path",
            "",
            f"`identify(log, spec)` in-process on white 10⁴-sample heave logs (the paper's "
            f"system, seeds 0–{white['logs'] - 1}), each log's median of its calls "
            f"(load average {white['load_average']:.1f}); per choice of the default "
            "estimator, the median over its logs:",
            "",
            "| choice | logs | wall (ms) | CPU (ms) |",
            "|---|---:|---:|---:|",
            *(f"| {ch} | {v['logs']} | {v['wall_ms']:.1f} | {v['cpu_ms']:.1f} |"
              for ch, v in white["by_choice"].items()),
            f"| all | {white['logs']} | {white['median_wall_ms']:.1f} | "
            f"{white['median_cpu_ms']:.1f} |",
            "",
            f"The log of seed 0: {white['choices'][0]}, {white['seed0_wall_ms']:.1f} ms wall, "
            f"{white['seed0_cpu_ms']:.1f} ms CPU.",
            "",
        ]
    kp = results.get("kernel_paths")
    if kp:
        lines += render_kernel_paths(kp)
    return "\n".join(lines)

def render_phases(phases: list[list[Any]], samples: int) -> list[str]:
    """The memory section's table of where ``vesselid identify``'s peak is reached
    (:data:`_PHASES`, steps of the estimate indented)."""
    peak = max(p[4] for p in phases)
    lines = ["", f"Where the memory goes on the {samples:,}-sample log: each step of the fit "
                 "(the default estimator's own steps indented under *estimate*) with its "
                 "CPU time, the resident memory when it starts and the highest while it "
                 "runs (sampled every 2 ms in one process).", "",
             "| step | CPU (s) | RSS at start (MB) | peak RSS in the step (MB) |",
             "|---|---:|---:|---:|"]
    for name, depth, cpu, entry, top in phases:
        mark = "**" if top == peak else ""
        shown = "—" if name == "whole process" else f"{entry:.0f}"
        lines.append(f"| {'&nbsp;&nbsp;' * depth}{name} | {cpu:.2f} | {shown} | "
                     f"{mark}{top:.0f}{mark} |")
    return lines


def render_kernel_paths(kp: dict[str, Any]) -> list[str]:
    """The page's section on ``identify``'s numpy kernels for small logs
    (``scripts/bench_startup.py``: :func:`bench_kernel_paths`)."""
    return [
        "## Start-up of `vesselid identify`: numpy kernels for small logs",
        "",
        "A `vesselid identify` process on a small log (rows × parameters ≤ 3·10⁵) runs "
        "numpy formulations of the estimation kernels (`identify/_npkernels.py`) "
        "instead of loading numba and its cached kernels; results agree with the "
        "compiled path to rounding. Whole processes on a 10⁴-sample heave log "
        f"(seed {kp.get('seed', 0)}; the default's choice there: {kp.get('choice', '?')}; "
        "a log in the colour test's guard band, about 15 % of white logs, fits the "
        "likelihood model, whose filter is compiled only, and loads numba on either "
        f"path), {kp['runs_per_path']} runs per path in ABBA order (medians; load average "
        f"{kp['load_average']:.1f}); cold: empty numba and generated-kernel caches, "
        f"the first run after an install ({kp['cold_runs_per_path']} runs per path); "
        "`python scripts/bench_startup.py --kernel-paths` measures this section alone.",
        "",
        "| process | wall (s) | CPU (s) |",
        "|---|---:|---:|",
        f"| `python -c \"import numpy, pandas\"` | {kp['numpy_pandas_import_wall_s']:.2f} "
        f"| {kp['numpy_pandas_import_cpu_s']:.2f} |",
        f"| `python -c \"import vesselid\"` | {kp['import_vesselid_wall_s']:.2f} "
        f"| {kp['import_vesselid_cpu_s']:.2f} |",
        f"| `vesselid identify`, numpy kernels | {kp['numpy_wall_s']:.2f} "
        f"| {kp['numpy_cpu_s']:.2f} |",
        f"| `vesselid identify`, compiled kernels | {kp['compiled_wall_s']:.2f} "
        f"| {kp['compiled_cpu_s']:.2f} |",
        f"| first `vesselid identify`, numpy kernels | {kp['cold_numpy_wall_s']:.2f} "
        f"| {kp['cold_numpy_cpu_s']:.2f} |",
        f"| first `vesselid identify`, compiled kernels | {kp['cold_compiled_wall_s']:.2f} "
        f"| {kp['cold_compiled_cpu_s']:.2f} |",
        "",
        f"The numpy kernels save {kp['cpu_saving_s']:.2f} s of CPU per process (paired "
        f"median; mean {kp['cpu_saving_mean_s']:.2f} ± {kp['cpu_saving_se_s']:.2f} s), "
        f"{100 * kp['cpu_saving_share']:.0f} % of the compiled path's process, and "
        f"{kp['cold_cpu_saving_s']:.1f} s on the first run after an install (no kernel "
        "is compiled). They are kept while the saving on this command stays at 0.3 s of "
        "CPU or more; `VESSELID_KERNELS=compiled` selects the compiled kernels.",
        "",
    ]


def write_docs(results: dict[str, Any], path: Path = ROOT / "docs" / "performance.md") -> Path:
    """Write the performance page atomically (with the many-core section of
    ``bench_multicore.py`` where its figures are saved beside the page)."""
    text = render(results, machine())
    multicore = path.with_name("performance_multicore.json")
    if multicore.exists():
        import json

        from bench_multicore import render as render_multicore

        text += "\n\n" + render_multicore(json.loads(multicore.read_text()))
    tmp = path.with_suffix(".md.tmp")
    tmp.write_text(text + "\n")
    tmp.replace(path)
    return path


BENCHES: dict[str, Callable[..., dict[str, Any]]] = {
    "single_envs": bench_single_envs,
    "mc_threads": bench_mc_threads,
    "identify_memory": bench_identify_memory,
    "pem_path": bench_pem_path,
    "white_path": bench_white_path,
}


def run_all(names: list[str] | None = None, *, memory_sizes: tuple[int, ...] | None = None,
            mc_options: dict[str, Any] | None = None,
            memory_format: str | None = None) -> dict[str, Any]:
    """Run the scaling benchmarks (all, or ``names``) and print their figures;
    ``mc_options``: keywords of :func:`bench_mc_threads` (``workers``, ``runs``,
    ``repeats``)."""
    results: dict[str, Any] = {}
    for name in names or list(BENCHES):
        print(f"[{name}] running ...", flush=True)
        kwargs: dict[str, Any] = {}
        if name == "identify_memory":
            kwargs = {k: v for k, v in (("sizes", memory_sizes), ("fmt", memory_format))
                      if v}
        elif name == "mc_threads" and mc_options:
            kwargs = dict(mc_options)
        results[name] = BENCHES[name](**kwargs)
        for key, value in results[name].items():
            shown = f"{value:,.4g}" if isinstance(value, float) else value
            print(f"    {key:<50s} {shown}")
    return results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", choices=sorted(BENCHES))
    parser.add_argument("--memory-sizes", nargs="*", type=int)
    parser.add_argument("--memory-format", choices=("parquet", "csv"),
                        help="identify_memory: log format (parquet)")
    parser.add_argument("--workers", nargs="*", type=int,
                        help="mc_threads: worker counts (default 1 2; the first is the "
                             "baseline)")
    parser.add_argument("--mc-runs", type=int, help="mc_threads: Monte Carlo runs (1000)")
    parser.add_argument("--mc-repeats", type=int, help="mc_threads: alternated repeats (3)")
    parser.add_argument("--project", nargs="*", type=int,
                        help="mc_threads: worker counts projected from measured per-chunk "
                             "CPU costs (default 4 8 16; none without values)")
    parser.add_argument("--docs", action="store_true", help="write docs/performance.md")
    args = parser.parse_args(argv)
    mc: dict[str, Any] = {}
    if args.workers:
        mc["workers"] = tuple(args.workers)
    if args.mc_runs:
        mc["runs"] = args.mc_runs
    if args.mc_repeats:
        mc["repeats"] = args.mc_repeats
    if args.project is not None:
        mc["project"] = tuple(args.project)
    results = run_all(args.only, memory_sizes=tuple(args.memory_sizes or ()) or None,
                      mc_options=mc or None, memory_format=args.memory_format)
    if args.docs:
        print(f"wrote {write_docs(results)}")


if __name__ == "__main__":
    main()
