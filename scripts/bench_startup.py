"""Whole-process benchmarks of the command line (fast start).

Every figure is a *whole process* (interpreter start, imports, kernel loading, work,
exit), timed from outside with ``subprocess``. The commands are run alternately —
``python -c "import numpy, pandas"`` (the reference every ratio is taken against),
``vesselid --help``, ``vesselid identify`` on a 10⁴-sample heave log and
``vesselid reproduce --table 1`` (1000 runs × 10⁴ samples) — so that a busy machine
slows all of them alike, and medians are reported.

* ``help_ratio`` and ``identify_ratio``: medians over the reference's median
  (targets ≤ 1.0 and ≤ 2.0).
* ``reproduce_table1_process_s`` and its Monte Carlo part (``table1_s`` of
  ``summary.json``, target ≤ 1.0 s), against the plain-numpy baseline
  (``scripts/baseline_numpy.py``) run once in the same call: ``speedup_vs_numpy``
  (target ≥ 15). The same in CPU seconds of all threads (``*_cpu_s``,
  ``speedup_vs_numpy_cpu``; ``table1_cpu_s`` of ``summary.json``): robust to other jobs
  on a shared machine, where wall ratios penalise the two-threaded vesselid process
  against the single-threaded baseline.
* The same job with the baseline's rows only, ``vesselid reproduce --table 1 --extra
  none`` (LS, IV, IV_E{ζ}=0: what ``scripts/baseline_numpy.py`` computes; the default
  command adds the package default ``auto`` as a fourth row): ``*_paper_rows`` figures,
  the like-for-like ratio ``speedup_vs_numpy_paper_rows``.
* :func:`bench_cold_start`: the first run after a fresh install — a new virtual
  environment, a wheel of this checkout installed into it, empty numba and
  generated-kernel caches (``NUMBA_CACHE_DIR``, ``VESSELID_KERNEL_DIR``) — of
  ``vesselid reproduce`` (both tables; target ≤ 15 s), then a second run with the
  caches the first one left.

* :func:`bench_kernel_paths`: ``vesselid identify`` on the 10⁴-sample heave log with the
  numpy kernels (the default for small logs) against the compiled ones, warm and cold
  (``--kernel-paths``).

    python scripts/bench_startup.py [--repeats 5] [--baseline-runs 1000] [--cold]
    python scripts/bench_startup.py --kernel-paths
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

try:
    import resource  # POSIX: CPU time of child processes
except ImportError:  # pragma: no cover - Windows
    resource = None  # type: ignore[assignment]

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

REFERENCE = [sys.executable, "-c", "import numpy, pandas"]


def vesselid_command() -> list[str]:
    """The installed ``vesselid`` console script next to this interpreter (else ``-m``)."""
    exe = Path(sys.executable).with_name("vesselid")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "vesselid"]


def user_env(**extra: str) -> dict[str, str]:
    """The environment of a user's shell: bytecode caching on (a development shell may
    set ``PYTHONDONTWRITEBYTECODE``, which makes every process recompile the package)."""
    env = dict(os.environ, **extra)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def run_timed(cmd: list[str], env: dict[str, str] | None = None, check: bool = True,
              cwd: str | Path | None = None) -> tuple[float, subprocess.CompletedProcess]:
    """Wall time (s) of one whole process and its completed-process record; the record's
    ``cpu_s`` is the process's user + system CPU time (all threads; a load-robust figure)."""
    env = user_env() if env is None else env
    before = resource.getrusage(resource.RUSAGE_CHILDREN) if resource else None
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=cwd)
    dt = time.perf_counter() - t0
    if before is not None:
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        proc.cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if check and proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr[-2000:]}")
    return dt, proc


def modules_loaded(code: str) -> dict[str, bool]:
    """Which heavy modules a snippet leaves in ``sys.modules`` (fresh interpreter)."""
    heavy = ("numba", "scipy", "matplotlib", "dask", "gymnasium", "pyarrow", "pandas")
    probe = (code + "\nimport sys, json\n"
             f"print(json.dumps({{m: m in sys.modules for m in {heavy!r}}}))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True, env=user_env())
    return json.loads(out.stdout.strip().splitlines()[-1])


def import_times(module: str = "vesselid") -> dict[str, float]:
    """``python -X importtime -c 'import module'``: the slowest top-level imports (ms)."""
    out = subprocess.run([sys.executable, "-X", "importtime", "-c", f"import {module}"],
                         capture_output=True, text=True, check=True, env=user_env()).stderr
    rows = []
    for line in out.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, cum, name = (p.strip() for p in line[len("import time:"):].split("|"))
        if cum.isdigit():
            rows.append((name, int(cum) / 1000))
    top = {name: ms for name, ms in rows if not name.startswith(" ")}
    return dict(sorted(top.items(), key=lambda kv: -kv[1])[:8])


def bench_startup(repeats: int = 5, baseline_runs: int = 1000,
                  reproduce_repeats: int = 3) -> dict:
    """Alternated whole-process medians and ratios (see the module docstring)."""
    vid = vesselid_command()
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "heave.csv"
        run_timed([*vid, "simulate", "--system", "heave", "--samples", "10000", "--seed", "0",
                   "--out", str(log)])
        cmds = {
            "numpy_pandas_import": REFERENCE,
            "help": [*vid, "--help"],
            "identify": [*vid, "identify", str(log)],
        }
        for cmd in cmds.values():  # page the files in; load or compile cached kernels
            run_timed(cmd)
        times: dict[str, list[float]] = {k: [] for k in cmds}
        repro, mc, repro_cpu, mc_cpu = [], [], [], []
        paper: dict[str, list[float]] = {"process": [], "mc": []}
        for i in range(repeats):
            for key, cmd in cmds.items():
                times[key].append(run_timed(cmd)[0])
            if i < reproduce_repeats:
                out = Path(tmp) / f"repro{i}"
                dt, proc = run_timed([*vid, "reproduce", "--table", "1", "--out", str(out)])
                repro.append(dt)
                repro_cpu.append(getattr(proc, "cpu_s", float("nan")))
                summary = json.loads((out / "summary.json").read_text())
                mc.append(summary["timings"]["table1_s"])
                mc_cpu.append(summary["timings"].get("table1_cpu_s", float("nan")))
                times["numpy_pandas_import"].append(run_timed(REFERENCE)[0])
                out = Path(tmp) / f"paper{i}"
                dt, _ = run_timed([*vid, "reproduce", "--table", "1", "--extra", "none",
                                   "--out", str(out)])
                paper["process"].append(dt)
                summary = json.loads((out / "summary.json").read_text())
                paper["mc"].append(summary["timings"]["table1_s"])
    med = {k: statistics.median(v) for k, v in times.items()}
    ref = med["numpy_pandas_import"]
    sys.path.insert(0, str(HERE))
    from baseline_numpy import table1_numpy

    c0 = time.process_time()
    base = table1_numpy(baseline_runs, 10_000, 0)["total_s"] * 1000 / baseline_runs
    base_cpu = (time.process_time() - c0) * 1000 / baseline_runs
    repro_med = statistics.median(repro)
    repro_cpu_med = statistics.median(repro_cpu)
    return {
        "numpy_pandas_import_s": ref,
        "help_s": med["help"],
        "identify_heave_1e4_process_s": med["identify"],
        "help_ratio": med["help"] / ref,
        "identify_ratio": med["identify"] / ref,
        "reproduce_table1_process_s": repro_med,
        "reproduce_table1_monte_carlo_s": statistics.median(mc),
        "numpy_baseline_table1_s": base,
        "numpy_baseline_runs": baseline_runs,
        "speedup_vs_numpy": base / repro_med,
        # CPU seconds (all threads): robust to other jobs on the machine; the baseline is
        # single-threaded numpy, so this ratio is the wall ratio on an idle machine only
        # when vesselid's threads find free cores
        "reproduce_table1_process_cpu_s": repro_cpu_med,
        "reproduce_table1_monte_carlo_cpu_s": statistics.median(mc_cpu),
        "numpy_baseline_table1_cpu_s": base_cpu,
        "speedup_vs_numpy_cpu": base_cpu / repro_cpu_med,
        "reproduce_table1_paper_rows_process_s": statistics.median(paper["process"]),
        "reproduce_table1_paper_rows_monte_carlo_s": statistics.median(paper["mc"]),
        "speedup_vs_numpy_paper_rows": base / statistics.median(paper["process"]),
        "help_loads": modules_loaded("from vesselid.cli.app import build_parser\n"
                                     "build_parser(['--help'])"),
        "import_vesselid_top_ms": import_times("vesselid"),
        "all_times_s": {**times, "reproduce": repro, "monte_carlo": mc,
                        "reproduce_cpu": repro_cpu, "monte_carlo_cpu": mc_cpu,
                        "reproduce_paper_rows": paper["process"],
                        "monte_carlo_paper_rows": paper["mc"]},
        "targets": {"help_ratio": 1.0, "identify_ratio": 2.0, "speedup_vs_numpy": 15.0,
                    "reproduce_table1_monte_carlo_s": 1.0},
    }


def bench_kernel_paths(rounds: int = 8, cold_rounds: int = 5, seed: int = 1) -> dict:
    """``vesselid identify`` on a 10⁴-sample heave log: numpy kernels against compiled.

    The log (``seed``) is one where the default keeps its instruments: a log in the colour
    test's guard band (about 15 % of white logs; seed 0 is one) fits the likelihood
    model, whose filter is compiled only, and loads numba on either path.

    Whole processes, warm caches: ``VESSELID_KERNELS=auto`` (the default: the numpy
    kernels of :mod:`vesselid.identify._npkernels`, no numba in the process) against
    ``VESSELID_KERNELS=compiled`` (numba and its cached kernels loaded), alternated in
    ABBA order against the reference ``python -c "import numpy, pandas"``; the paired
    CPU saving (compiled − numpy, per pair of neighbouring runs) with its standard error.
    Cold: the first ``identify`` after an install, empty numba and generated-kernel
    caches (``NUMBA_CACHE_DIR``, ``VESSELID_KERNEL_DIR``) per run, both paths.
    """
    vid = vesselid_command()
    paths = {"numpy": "auto", "compiled": "compiled"}
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        log = tmp / "heave.csv"
        run_timed([*vid, "simulate", "--system", "heave", "--samples", "10000", "--seed",
                   str(seed), "--out", str(log)])
        choice_json = tmp / "choice.json"
        run_timed([*vid, "identify", str(log), "--json", str(choice_json)])
        choice = json.loads(choice_json.read_text())["diagnostics"]["choice"]
        cmds = {k: ([*vid, "identify", str(log)], user_env(VESSELID_KERNELS=v))
                for k, v in paths.items()}
        cmds["numpy_pandas_import"] = (REFERENCE, user_env())
        cmds["import_vesselid"] = ([sys.executable, "-c", "import vesselid"], user_env())
        for cmd, env in cmds.values():  # page in; load or compile cached kernels
            run_timed(cmd, env)
        wall: dict[str, list[float]] = {k: [] for k in cmds}
        cpu: dict[str, list[float]] = {k: [] for k in cmds}
        saving: list[float] = []
        loads = []
        for r in range(rounds):
            first, second = ("numpy", "compiled") if r % 2 == 0 else ("compiled", "numpy")
            for pair in ((first, second), (second, first)):
                got = {}
                for key in pair:
                    dt, proc = run_timed(*cmds[key])
                    wall[key].append(dt)
                    cpu[key].append(proc.cpu_s)
                    got[key] = proc.cpu_s
                saving.append(got["compiled"] - got["numpy"])
                for key in ("numpy_pandas_import", "import_vesselid"):
                    dt, proc = run_timed(*cmds[key])
                    wall[key].append(dt)
                    cpu[key].append(proc.cpu_s)
            loads.append(os.getloadavg()[0])
        cold: dict[str, dict[str, list[float]]] = {k: {"wall": [], "cpu": []} for k in paths}
        for r in range(cold_rounds):
            for key, mode in paths.items():
                d = tmp / f"cold{r}{key}"
                env = user_env(VESSELID_KERNELS=mode, NUMBA_CACHE_DIR=str(d / "numba"),
                               VESSELID_KERNEL_DIR=str(d / "kernels"))
                dt, proc = run_timed([*vid, "identify", str(log)], env)
                cold[key]["wall"].append(dt)
                cold[key]["cpu"].append(proc.cpu_s)
            loads.append(os.getloadavg()[0])
    med = statistics.median
    out: dict = {"rounds": rounds, "runs_per_path": len(cpu["numpy"]),
                 "cold_runs_per_path": cold_rounds, "seed": seed, "choice": choice}
    for key in cmds:
        out[f"{key}_wall_s"] = med(wall[key])
        out[f"{key}_cpu_s"] = med(cpu[key])
    for key in paths:
        out[f"cold_{key}_wall_s"] = med(cold[key]["wall"])
        out[f"cold_{key}_cpu_s"] = med(cold[key]["cpu"])
    out["cpu_saving_s"] = med(saving)
    out["cpu_saving_mean_s"] = statistics.mean(saving)
    out["cpu_saving_se_s"] = statistics.stdev(saving) / len(saving) ** 0.5
    out["cpu_saving_share"] = out["cpu_saving_s"] / out["compiled_cpu_s"]
    out["cold_cpu_saving_s"] = out["cold_compiled_cpu_s"] - out["cold_numpy_cpu_s"]
    ref = out["numpy_pandas_import_cpu_s"]
    out["identify_ratio_cpu_numpy"] = out["numpy_cpu_s"] / ref
    out["identify_ratio_cpu_compiled"] = out["compiled_cpu_s"] / ref
    out["load_average"] = med(loads)
    return out


#: A 39-parameter 3-DOF structure (three distinct 13-term equations) of the kind a user
#: writes or ``vesselid select`` proposes.
_WIDE_EQUATIONS = {
    "u": ["u", "u*|u|", "v*r", "r*r", "X", "v*v", "r*|r|", "v*|v|", "u*v", "u*r", "X*u",
          "|u|", "v*|r|"],
    "v": ["v", "r", "u*r", "u*v", "v*|v|", "v*|r|", "r*|v|", "r*|r|", "Y", "N", "u", "|u|",
          "X*v"],
    "r": ["v", "r", "u*r", "u*v", "v*|v|", "v*|r|", "r*|v|", "r*|r|", "Y", "N", "u", "|u|",
          "X*r"],
}


def bench_new_structure(samples: int = 5000, experiments: int = 4) -> dict:
    """``vesselid identify`` on a CyberShip II sea trial with a structure it has not seen
    (empty generated-kernel cache, warm numba cache): the catalogue's 25-parameter model
    and a 39-parameter one, then the same command again (kernels cached); whole
    processes, CPU seconds (wall on a loaded machine measures the neighbours)."""
    vid = vesselid_command()
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        run_timed([*vid, "sea-trial", "--vessel", "cybership2", "--experiments",
                   str(experiments), "--samples", str(samples), "--seed", "3", "--out",
                   str(tmp / "trial")], env=user_env(MPLBACKEND="Agg"))
        log, model = tmp / "trial" / "seatrial.parquet", tmp / "trial" / "cybership2.toml"
        text = model.read_text(encoding="utf-8")
        head = text[:text.index("[equations]")]
        wide = tmp / "wide.toml"
        wide.write_text(head + "[equations]\n" + "".join(
            f"{s} = {json.dumps(terms)}\n" for s, terms in _WIDE_EQUATIONS.items()),
            encoding="utf-8")
        # page in and compile the structure-independent kernels (numba's own cache)
        run_timed([*vid, "identify", str(log), "--model", str(model), "--noise-order", "16"],
                  env=user_env(VESSELID_KERNEL_DIR=str(tmp / "warm")))
        for name, spec, params in (("cybership2", model, 25), ("wide", wide, 39)):
            env = user_env(VESSELID_KERNEL_DIR=str(tmp / f"kernels_{name}"))
            cmd = [*vid, "identify", str(log), "--model", str(spec), "--noise-order", "16"]
            first_wall, first = run_timed(cmd, env)
            again_wall, again = run_timed(cmd, env)
            out.update({f"{name}_params": params,
                        f"{name}_first_cpu_s": first.cpu_s, f"{name}_first_wall_s": first_wall,
                        f"{name}_cached_cpu_s": again.cpu_s,
                        f"{name}_cached_wall_s": again_wall})
    out["samples"] = samples * experiments
    return out


def _fresh_venv(tmp: Path) -> Path:
    """A new virtual environment with a wheel of this checkout; dependencies shared."""
    wheels = tmp / "wheels"
    env = user_env()
    env.pop("PYTHONPATH", None)  # else pip may take a checkout on the path for an install
    build = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheels),
             str(ROOT)]
    try:  # the installed setuptools, if recent enough (fast, offline)
        subprocess.run([*build, "--no-build-isolation"], check=True, capture_output=True,
                       env=env)
    except subprocess.CalledProcessError:  # else an isolated build (fetches setuptools)
        subprocess.run(build, check=True, capture_output=True, env=env)
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    py = venv / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()"
                           "['purelib'])"], capture_output=True, text=True, check=True)
    import numpy

    deps = Path(numpy.__file__).resolve().parent.parent  # where the dependencies live
    Path(site.stdout.strip(), "_deps.pth").write_text(str(deps) + "\n")
    wheel = next(wheels.glob("vesselid-*.whl"))
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q",
                    "--no-deps", str(wheel)], check=True, capture_output=True, env=env)
    if not (venv / "bin" / "vesselid").exists():
        raise RuntimeError("the wheel did not install the vesselid console script")
    return venv


def bench_cold_start(table: str = "all") -> dict:
    """First ``vesselid reproduce`` after a fresh install (empty caches), then a second."""
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        venv = _fresh_venv(tmp)
        load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
        env = user_env(NUMBA_CACHE_DIR=str(tmp / "numba"),
                       VESSELID_KERNEL_DIR=str(tmp / "kernels"), MPLBACKEND="Agg")
        env.pop("PYTHONPATH", None)
        cmd = [str(venv / "bin" / "vesselid"), "reproduce", "--table", table]
        # run outside the checkout, so that the installed copy is the one imported
        first, p1 = run_timed([*cmd, "--out", str(tmp / "first")], env=env, cwd=tmp)
        timings = json.loads((tmp / "first" / "summary.json").read_text())["timings"]
        second, p2 = run_timed([*cmd, "--out", str(tmp / "second")], env=env, cwd=tmp)
        # the compile time of kernels on the first run, measured in-process
        # (each top-level compile event: the dispatcher's CPU seconds, nested ones inside)
        probe = ("import json, time, numba.core.event as ev\n"
                 "stack, tot, per = [], [0, 0.0], {}\n"
                 "class L(ev.Listener):\n"
                 "    def on_start(self, e): stack.append(time.process_time())\n"
                 "    def on_end(self, e):\n"
                 "        t0 = stack.pop()\n"
                 "        if not stack:\n"
                 "            dt = time.process_time() - t0\n"
                 "            tot[0] += 1\n"
                 "            tot[1] += dt\n"
                 "            f = e.data['dispatcher'].py_func\n"
                 "            k = f.__module__.rsplit('.', 1)[-1][:24] + '.' + f.__name__\n"
                 "            per[k] = round(per.get(k, 0.0) + dt, 3)\n"
                 "ev.register('numba:compile', L())\n"
                 "from vesselid.studies.reproduce import warm_up\n"
                 "warm_up()\n"
                 "print(json.dumps([*tot, per]))")
        # in-process compiles only: no helper process (vesselid.studies.precompile)
        cold_env = dict(env, NUMBA_CACHE_DIR=str(tmp / "numba2"),
                        VESSELID_KERNEL_DIR=str(tmp / "kernels2"), VESSELID_PRECOMPILE="0")
        compiles = json.loads(subprocess.run(
            [str(venv / "bin" / "python"), "-c", probe], env=cold_env, capture_output=True,
            text=True, check=True, cwd=tmp).stdout.strip().splitlines()[-1])
        where = subprocess.run([str(venv / "bin" / "python"), "-c",
                                "import vesselid; print(vesselid.__file__)"], env=env,
                               capture_output=True, text=True, check=True,
                               cwd=tmp).stdout.strip()
        shutil.rmtree(venv, ignore_errors=True)
    return {
        f"cold_first_reproduce_{table}_s": first,
        f"cold_first_reproduce_{table}_timings": timings,
        f"second_reproduce_{table}_s": second,
        f"cold_first_reproduce_{table}_cpu_s": getattr(p1, "cpu_s", None),
        f"second_reproduce_{table}_cpu_s": getattr(p2, "cpu_s", None),
        # a fresh-cache warm-up in the new venv: kernels compiled, CPU seconds compiling
        "cold_warm_up_compile_events": compiles[0],
        "cold_warm_up_compile_cpu_s": compiles[1],
        "cold_warm_up_compile_cpu_s_per_kernel": compiles[2],
        "load_average_before": load_before,
        # VESSELID_PRECOMPILE as set for the timed runs ("" = automatic: a helper process
        # compiles kernels on the first run when two cores are idle)
        "precompile_setting": os.environ.get("VESSELID_PRECOMPILE", ""),
        "installed_from": where,
        "target_first_run_s": 15.0,
    }


def main() -> None:
    p = argparse.ArgumentParser(description="whole-process benchmarks of the command line")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--reproduce-repeats", type=int, default=3)
    p.add_argument("--baseline-runs", type=int, default=1000,
                   help="runs of the numpy baseline (scaled linearly to 1000 if fewer)")
    p.add_argument("--cold", action="store_true", help="also the fresh-install first run")
    p.add_argument("--only-cold", action="store_true", help="only the fresh-install first run")
    p.add_argument("--kernel-paths", action="store_true",
                   help="only identify's numpy kernels against the compiled ones")
    args = p.parse_args()
    if args.kernel_paths:
        print(json.dumps(bench_kernel_paths(), indent=2))
        return
    res = {} if args.only_cold else bench_startup(args.repeats, args.baseline_runs,
                                                  args.reproduce_repeats)
    print(json.dumps(res, indent=2), flush=True)
    if args.cold or args.only_cold:
        res.update(bench_cold_start())
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
