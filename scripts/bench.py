"""Performance benchmarks (medians after JIT warm-up), with plain-numpy baselines.

Targets (2-core machine):

* simulation of the heave system, 1000 runs × 10⁴ samples ≤ 0.2 s;
* ``identify(log, spec)`` on one heave log of 10⁴ samples — default estimator, default
  (HAC) covariance, every diagnostic — ≤ 20 ms in-process (``identify``);
* a 3-state, 10⁵-sample, 4-experiment log ≤ 1 s (``identify_3state``);
* Table 1 at paper size ≤ 4 s, both tables ≤ 10 s (``bench_reproduce``); where its
  Monte Carlo time goes, per estimator, wall and CPU, with iterations (``estimators``);
* Heave-v0 ≥ 100k raw steps/s, Manoeuvring3DOF-v0 ≥ 30k, vector 1024 envs ≥ 1M;
* the sea-trial pipeline at 6 × 2·10⁴ samples ≤ 10 s;
* whole processes, alternated against ``python -c "import numpy, pandas"`` (``startup``,
  ``scripts/bench_startup.py``): ``vesselid --help`` ≤ 1.0×, ``vesselid identify`` on a
  10⁴-sample heave log ≤ 2.0×, ``vesselid reproduce --table 1`` ≥ 15× faster than the
  plain-numpy baseline with its Monte Carlo part ≤ 1 s; the first ``vesselid reproduce``
  after a fresh install (empty caches, ``cold_start``) ≤ 15 s;
* ``vesselid ingest`` of 10⁶ NMEA 0183 sentences ≤ 10 s (``ingest``,
  ``scripts/bench_ingest.py``);
* ``vesselid identify`` on a 10⁶-sample one-state heave log (default estimator) ≤ 400 MB
  peak resident memory and ≤ 3 s, growing linearly with the log (``identify_memory``:
  10⁵, 10⁶ and 4·10⁶ samples); the bounded-memory forms it takes on long logs move the
  estimates, covariance and test statistics from the whole-array forms by rounding only
  (``identify_large_paths``: the largest relative difference on a 10⁶-sample log).

Run ``python scripts/bench.py`` (all) or ``python scripts/bench.py --only simulate identify``;
``--json PATH`` writes the figures; ``python scripts/bench.py --docs`` runs the scaling
benchmarks (``scripts/bench_scaling.py``: single environments against CartPole-v1, the
Monte Carlo on one and two workers, ``identify``'s peak memory per sample, the ``pem``
path) and writes the generated page ``docs/performance.md``. Benchmarks live here,
never in timed tests.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def median_time(fn: Callable[[], object], repeats: int = 5, warmup: int = 1, *,
                clock: Callable[[], float] = time.perf_counter) -> float:
    """Median time of ``fn()`` in seconds after ``warmup`` calls (``clock``: wall by
    default; ``time.process_time`` gives the CPU time of all the process's threads)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = clock()
        fn()
        times.append(clock() - t0)
    return statistics.median(times)


def numpy_simulate(spec, u, x0, v, w):
    """Plain-numpy baseline: Python loop over samples, vectorised across runs, same terms."""
    from vesselid.model.regressors import predict

    theta = spec.theta0_vector()
    n_runs, n_samples, n = v.shape
    x = np.empty((n_runs, n_samples, n))
    x[:, 0] = x0
    for k in range(n_samples - 1):
        s = np.concatenate([x[:, k] + v[:, k], u[:, k]], axis=1)
        x[:, k + 1] = predict(spec.codes, theta, s) + w[:, k]
    return x


def bench_simulate(repeats: int = 5) -> dict:
    from vesselid.plant.simulate import simulate_states
    from vesselid.plant.systems import heave

    system = heave()
    sim = system.simulate(10_000, n_runs=1000, seed=0)
    spec = system.spec
    v = -sim.q
    x0 = np.array([1.3])
    kernel = median_time(lambda: simulate_states(spec, sim.u, x0=x0, v=v, w=sim.w), repeats)
    end_to_end = median_time(lambda: system.simulate(10_000, n_runs=1000, seed=0),
                             max(repeats // 2, 1))
    t0 = time.perf_counter()
    x_np = numpy_simulate(spec, sim.u, x0, v, sim.w)
    numpy_time = time.perf_counter() - t0
    assert np.allclose(x_np, sim.x, rtol=1e-10, atol=1e-10)
    return {
        "simulate_heave_1000x1e4_kernel_s": kernel,
        "simulate_heave_1000x1e4_with_noise_generation_s": end_to_end,
        "simulate_heave_1000x1e4_numpy_loop_s": numpy_time,
        "simulate_speedup_vs_numpy": numpy_time / kernel,
    }


def _three_state_log(samples: int, experiments: int):
    """A 3-state log: the CyberShip II sea trial when available, else a generic 3-state model."""
    try:
        from vesselid.studies.seatrial import design_sea_trial  # noqa: F401

        have_seatrial = True
    except ImportError:
        have_seatrial = False
    if have_seatrial:
        from vesselid.studies.seatrial import simulate_sea_trial

        log = simulate_sea_trial(experiments=experiments, samples=samples, seed=0)
        return log, log.spec
    from vesselid.model.spec import ModelSpec
    from vesselid.plant.disturbances import Gaussian, Uniform
    from vesselid.plant.signals import RandomPulses, StaticOffset
    from vesselid.plant.systems import System

    spec = ModelSpec(
        name="three_state",
        states=["u", "v", "r"],
        inputs=["X", "Y", "N"],
        equations={
            "u": ["u", "u*|u|", "v*r", "X"],
            "v": ["v", "v*|v|", "u*r", "r*|v|", "Y", "N"],
            "r": ["r", "r*|r|", "u*v", "v*|r|", "Y", "N"],
        },
        theta0={"u": [0.98, -0.02, 0.01, 0.05], "v": [0.9, -0.05, -0.05, 0.01, 0.05, 0.01],
                "r": [0.9, -0.05, 0.01, 0.01, 0.01, 0.05]},
    )
    noise = {s: Gaussian(0, 0.01) for s in spec.states}
    system = System(
        spec=spec,
        inputs={"X": StaticOffset(2.0, Uniform(0, 0.5)), "Y": RandomPulses(0.2, 0.6, 20, 200),
                "N": RandomPulses(0.2, 0.6, 20, 200)},
        process_noise=noise, sensor_noise=noise, x0={"u": 1.0, "v": 0.5, "r": 0.5},
    )
    log = system.simulate(samples, n_runs=experiments, seed=0).to_log()
    return log, log.spec


#: The estimators :func:`bench_identify` times by name after the default.
NAMED_ESTIMATORS = ("ls", "iv", "iv-zero-mean", "lagged-2sls", "sriv")


def bench_identify(repeats: int = 15, methods: tuple[str, ...] = NAMED_ESTIMATORS) -> dict:
    """``identify`` on one 10⁴-sample heave log, in-process: first as a user calls it,
    ``identify(log, spec)`` (default estimator, default HAC covariance, every diagnostic —
    checked below), then each estimator of ``methods`` by name. Median wall and CPU
    (process) time. The log (seed 1) is one where the default keeps its instruments, so
    the timed call runs the instrument diagnostics; a white log in the colour test's guard
    band (about 15 %; seed 0 is one) fits the likelihood model instead (the
    ``white_path`` item times both over 20 logs)."""
    from vesselid.identify import DEFAULT_METHOD, identify
    from vesselid.plant.systems import heave

    warnings.simplefilter("ignore")
    log = heave().simulate(10_000, seed=1).to_log()
    spec = log.spec
    res = identify(log, spec)
    diag = res.diagnostics
    missing = [k for k in ("cov_type", "specification", "whiteness", "residual_correlation",
                           "instrument_condition") if k not in diag]
    assert res.method == DEFAULT_METHOD and not missing, f"diagnostics missing: {missing}"
    assert {"first_stage", "endogeneity"} <= set(diag["specification"][spec.states[0]])
    out: dict = {"default_method": DEFAULT_METHOD, "default_cov_type": diag["cov_type"]}
    out["identify_heave_1e4_default_ms"] = 1000 * median_time(lambda: identify(log, spec),
                                                              repeats)
    out["identify_heave_1e4_default_cpu_ms"] = 1000 * median_time(
        lambda: identify(log, spec), repeats, clock=time.process_time)
    for m in methods:
        out[f"identify_heave_1e4_{m}_ms"] = 1000 * median_time(
            lambda m=m: identify(log, spec, method=m), max(repeats // 2, 3))
    out["default_choice"] = str(diag.get("choice"))
    return out


def bench_pem(repeats: int = 5) -> dict:
    """The prediction-error estimator on one 10⁴-sample heave log with a Gauss–Markov
    current (time constant 25 samples, random pulses): ``identify(log)`` as a user calls it
    (``auto`` takes ``pem`` there: both validity tests reject) and ``method="pem"``, median
    wall and CPU time; one step of its Fisher scoring — the filter with the exact
    sensitivities of all 10 parameters (the tangent pass, with the likelihood, gradient
    and Fisher information) against the 11 filter rows a forward-difference Jacobian
    would run together — per sample; and one filter row compiled against the same
    function run as plain Python (``gaussian_filter.py_func``), per row and sample."""
    from vesselid.identify import identify
    from vesselid.identify._pemkernels import (
        gaussian_filter,
        gaussian_filter_tangent,
        term_kinds,
    )
    from vesselid.studies.calibration import heave_scenario

    warnings.simplefilter("ignore")
    system, _, _ = heave_scenario("gm-current-random")
    log = system.simulate(10_000, seed=0).to_log(aggregate=False)
    res = identify(log)
    assert res.diagnostics["instruments"].startswith("none: prediction-error"), res.diagnostics
    out: dict = {"auto_choice": res.diagnostics["disturbance_model"] + " model (pem)"}
    for key, fn in (("default", lambda: identify(log)),
                    ("pem", lambda: identify(log, method="pem"))):
        out[f"identify_gm_current_1e4_{key}_ms"] = 1000 * median_time(fn, repeats)
        out[f"identify_gm_current_1e4_{key}_cpu_ms"] = 1000 * median_time(
            fn, repeats, clock=time.process_time)
    y = log.data["w"].to_numpy(float)
    u = log.data[["tau"]].to_numpy(float)
    n = y.size
    kinds = term_kinds(res.spec.codes.factors, 2)
    starts, p_init = np.array([0, n]), np.array([float(np.var(y))])
    row = np.r_[res.params.to_numpy(), 0.0, 1.8, -2.3, 0.0, -2.3, -2.3, -2.3]
    idx = np.arange(row.size)
    d = idx.size

    def run(rows, fn=gaussian_filter):
        e, v = np.empty((rows.shape[0], n)), np.empty((rows.shape[0], n))
        fn(0, rows.shape[0], rows, y, u, starts, p_init, *kinds, e, v)

    def tangent():
        gaussian_filter_tangent(row, idx, y, u, starts, p_init, *kinds, np.empty(n),
                                np.empty(n), np.empty((n, d)), np.empty((n, d)),
                                np.empty(d), np.empty((d, d)), np.empty(1))

    rows_fd = np.repeat(row[None], d + 1, axis=0)
    tan = median_time(tangent, repeats * 3, clock=time.process_time) / n
    fd = median_time(lambda: run(rows_fd), repeats * 3, clock=time.process_time) / n
    one = median_time(lambda: run(row[None]), repeats * 3, clock=time.process_time) / n
    base = median_time(lambda: run(row[None], gaussian_filter.py_func), 3, warmup=0) / n
    out["scoring_step_tangent_ns_per_sample"] = 1e9 * tan
    out["scoring_step_11_filter_rows_ns_per_sample"] = 1e9 * fd
    out["scoring_step_speedup_tangent_vs_rows"] = fd / tan
    out["filter_ns_per_row_sample_1_row"] = 1e9 * one
    out["filter_plain_python_ns_per_row_sample"] = 1e9 * base
    out["filter_speedup_vs_python_1_row"] = base / one
    return out


def bench_identify_3state(repeats: int = 5) -> dict:
    """Refined IV, zero-mean, on a 3-state log of 4 experiments × 10⁵ samples."""
    from vesselid.identify import identify

    warnings.simplefilter("ignore")
    log3, spec3 = _three_state_log(100_000, 4)
    return {"identify_3state_4x1e5_iv-zero-mean_s": median_time(
                lambda: identify(log3, spec3, method="iv-zero-mean"), repeats),
            "identify_3state_model": spec3.name}


def _load(name: str, func: str) -> Callable | None:
    path = HERE / f"{name}.py"
    if not path.exists():
        return None
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return getattr(module, func, None)


BENCHES: dict[str, Callable[[], Callable | None]] = {
    "simulate": lambda: bench_simulate,
    "identify": lambda: bench_identify,
    "pem": lambda: bench_pem,
    "identify_3state": lambda: bench_identify_3state,
    "heave_env": lambda: _load("bench_envs_heave", "bench_heave"),
    "manoeuvring_env": lambda: _load("bench_envs", "bench_manoeuvring"),
    "reproduce": lambda: _load("bench_reproduce", "bench_reproduce"),
    "estimators": lambda: _load("bench_reproduce", "bench_estimators"),
    "seatrial": lambda: _load("bench_seatrial", "bench_seatrial"),
    "seatrial_cli": lambda: _load("bench_seatrial", "bench_seatrial_cli"),
    "startup": lambda: _load("bench_startup", "bench_startup"),
    "cold_start": lambda: _load("bench_startup", "bench_cold_start"),
    "kernel_paths": lambda: _load("bench_startup", "bench_kernel_paths"),
    "new_structure": lambda: _load("bench_startup", "bench_new_structure"),
    "ingest": lambda: _load("bench_ingest", "bench_ingest"),
    "single_envs": lambda: _load("bench_scaling", "bench_single_envs"),
    "mc_threads": lambda: _load("bench_scaling", "bench_mc_threads"),
    "identify_memory": lambda: _load("bench_scaling", "bench_identify_memory"),
    "identify_large_paths": lambda: _load("bench_scaling", "bench_identify_large_paths"),
    "pem_path": lambda: _load("bench_scaling", "bench_pem_path"),
    "white_path": lambda: _load("bench_scaling", "bench_white_path"),
    "select": lambda: _load("bench_select", "bench_select"),
}

#: The benchmarks of the generated performance page (``--docs``).
DOCS_BENCHES = ("single_envs", "mc_threads", "identify_memory", "pem_path", "white_path",
                "kernel_paths")


def _each_in_own_process(names: list[str]) -> dict:
    """The figures of ``names``, each benchmark run by ``python bench.py --only NAME`` in
    a process of its own (its console lines pass through)."""
    import subprocess
    import tempfile

    results: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            out = Path(tmp) / f"{name}.json"
            subprocess.run([sys.executable, __file__, "--only", name, "--json", str(out)],
                           check=True)
            results.update(json.loads(out.read_text()))
    return results


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description="vesselid benchmarks (medians)")
    parser.add_argument("--only", nargs="*", choices=sorted(BENCHES), help="subset to run")
    parser.add_argument("--json", help="write the figures as JSON")
    parser.add_argument("--docs", action="store_true",
                        help="run the scaling benchmarks and write docs/performance.md")
    parser.add_argument("--from-json", metavar="PATH",
                        help="with --docs: write the page from figures saved by --json")
    args = parser.parse_args(argv)
    if args.docs and args.from_json:
        results = json.loads(Path(args.from_json).read_text())
        print(f"wrote {_load('bench_scaling', 'write_docs')(results)}")
        return results
    results: dict = {}
    names = args.only or (list(DOCS_BENCHES) if args.docs else list(BENCHES))
    if args.docs and len(names) > 1:
        # every figure of the page from a fresh process, as a user's command starts: one
        # benchmark's objects (environments, large logs) would otherwise weigh on the
        # next (a forked Monte Carlo worker copies the pages its parent's heap touches)
        results = _each_in_own_process(names)
        names = []
    for name in names:
        fn = BENCHES[name]()
        if fn is None:
            print(f"[{name}] not available")
            continue
        print(f"[{name}] running ...", flush=True)
        figures = fn()
        figures["load_average_1min"] = os.getloadavg()[0]  # 2 cores: compare with 2
        results[name] = figures
        for key, value in figures.items():
            shown = f"{value:,.4g}" if isinstance(value, float) else value
            print(f"    {key:<55s} {shown}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2, default=str) + "\n")
    if args.docs:
        print(f"wrote {_load('bench_scaling', 'write_docs')(results)}")
    return results


if __name__ == "__main__":
    main()
