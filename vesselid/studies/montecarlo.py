"""Monte Carlo studies: many seeded runs of simulate → estimate, as a tidy DataFrame.

A :class:`Study` is a system (catalogue name or factory, plus options), the
estimators to compare, the number of runs, samples per experiment and experiments
per run, and one seed. :func:`run_study` executes it and returns one row per
(run, method, parameter)::

    run  method  equation  term  estimate  theta0  normalized_error  converged  iterations
    stop_reason

Seeding
-------
Run ``r`` draws everything from the child seed ``SeedSequence(seed).spawn(runs)[r]``
(with several experiments per run, experiment ``e`` of run ``r`` uses the child
``SeedSequence(entropy, spawn_key=(r, e))`` of that seed). A run's data and
estimates therefore depend on nothing but ``(study, r)``: the results are
bit-identical whatever the batch size, the number of local threads, or whether
the chunks run locally or on a Dask cluster.

Execution
---------
Runs are processed in chunks of ``batch_size``: one batch simulation
(:meth:`~vesselid.plant.systems.System.simulate` with the chunk's seeds) and one batched
``estimate_parameters`` call per registered estimator, which estimates all
runs of the chunk at once in the compiled kernels. Locally, several chunks run
concurrently, one per core, each with serial kernels (the estimators' numpy parts
overlap too); a single chunk runs its kernels parallel over runs on all local cores.
With ``client`` (a :class:`dask.distributed.Client` or a scheduler address) every
chunk is a task — a pure function of ``(study, first run, last run)`` — and the
results are gathered and concatenated in run order.

Failures are never silent: a run whose auxiliary model could not be formed keeps
its rows with ``estimate = NaN``, ``converged = False`` and the ``stop_reason``;
:func:`summary_table` leaves such rows out of the means and reports how many.
"""

from __future__ import annotations

import gc
import math
import os
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.core import seeds
from vesselid.core.fileio import atomic_write_with
from vesselid.errors import VesselidError
from vesselid.identify.data import RegressionData, from_arrays
from vesselid.identify.diagnostics import normalized_error
from vesselid.identify.efficient import InstrumentalGMM
from vesselid.identify.estimators import COMBINE_MODES, IterationResult
from vesselid.identify.linalg import one_blas_thread
from vesselid.identify.methods import RefinedIV
from vesselid.identify.pem import PredictionError
from vesselid.identify.registry import ESTIMATORS, PAPER_METHODS, get_estimator
from vesselid.model.spec import ModelSpec
from vesselid.plant.catalogue import get_system
from vesselid.plant.systems import System

__all__ = [
    "COLUMNS",
    "TARGETS",
    "Study",
    "load_results",
    "paper_table",
    "run_study",
    "save_results",
    "summary_table",
]

#: Columns of the tidy result frame, in order.
COLUMNS = (
    "run", "method", "equation", "term", "estimate", "theta0", "normalized_error",
    "converged", "iterations", "stop_reason",
)

#: Regression targets: ``"measured"`` — the state measurement ``y₁(k)`` as in (4), (6)
#: and (10); ``"aggregated"`` — the aggregated signal ``ỹ(k) = y₁(k) ± y₂(k)`` also on
#: the left-hand side (predictor (9) used for ``ỹ`` itself).
TARGETS = ("measured", "aggregated")

#: Default number of runs simulated and estimated together.
DEFAULT_BATCH_SIZE = 250


@dataclass(frozen=True)
class Study:
    """A Monte Carlo study (paper §6: 1000 runs × 10⁴ samples).

    Parameters
    ----------
    system : str or callable
        Catalogue name (:func:`vesselid.plant.catalogue.get_system`) or a picklable factory
        returning a :class:`~vesselid.plant.systems.System`; called with ``options``.
    options : mapping
        Keyword options of the system factory (e.g. ``current_mean=0.1``).
    methods : sequence of str
        Registered estimators (:data:`vesselid.identify.ESTIMATORS`); default the
        paper's three: ``"ls"`` (16), ``"iv"`` (4)/(6), ``"iv-zero-mean"`` (A7).
    runs : int
        Monte Carlo runs.
    samples : int
        Samples per experiment (``N_D``).
    experiments_per_run : int
        Experiments per run (``N_E`` of (6)/(10)); all are combined into one estimate.
    seed : int
        Root seed; run ``r`` uses ``SeedSequence(seed).spawn(runs)[r]``.
    combine : {"pooled", "stacked"}
        Multi-experiment equations (see :func:`~vesselid.identify.identify`).
    aggregate : bool, optional
        Aggregated-state predictor (9) (default: iff the system has disturbance sensors).
    target : {"measured", "aggregated"}
        Left-hand side of the regression (see :data:`TARGETS`).
    max_iter, tol : int, float
        Refined-IV iteration limits.
    name : str
        Label (tables, file names).
    """

    system: str | Callable[..., System] = "heave"
    options: Mapping[str, Any] = field(default_factory=dict)
    methods: Sequence[str] = PAPER_METHODS
    runs: int = 1000
    samples: int = 10_000
    experiments_per_run: int = 1
    seed: int = 0
    combine: str = "pooled"
    aggregate: bool | None = None
    target: str = "measured"
    max_iter: int = 100
    tol: float = 1e-9
    name: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "methods", tuple(self.methods))
        object.__setattr__(self, "options", dict(self.options))
        unknown = [m for m in self.methods if m not in ESTIMATORS]
        if unknown or not self.methods:
            raise VesselidError(f"methods must be a non-empty subset of {list(ESTIMATORS)}, "
                                f"got {list(self.methods)}")
        for m in self.methods:
            if self.combine not in get_estimator(m).multi_experiment:
                raise VesselidError(f"method {m!r} does not support combine={self.combine!r}")
        if int(self.runs) < 1:
            raise VesselidError(f"need at least one run, got {self.runs}")
        if int(self.samples) < 10:
            raise VesselidError(f"need at least 10 samples per experiment, got {self.samples}")
        if int(self.experiments_per_run) < 1:
            raise VesselidError("experiments_per_run must be at least 1")
        if self.combine not in COMBINE_MODES:
            raise VesselidError(f"combine must be one of {COMBINE_MODES}, got {self.combine!r}")
        if self.target not in TARGETS:
            raise VesselidError(f"target must be one of {TARGETS}, got {self.target!r}")
        if not isinstance(self.seed, (int, np.integer)) or int(self.seed) < 0:
            raise VesselidError(f"seed must be a non-negative integer, got {self.seed!r}")

    # ------------------------------------------------------------------ pieces
    def build_system(self) -> System:
        """The simulated plant."""
        if callable(self.system):
            return self.system(**self.options)
        return get_system(str(self.system), **self.options)

    def identification_spec(self, system: System | None = None) -> ModelSpec:
        """The model structure every run is identified with (θ0 included)."""
        system = system or self.build_system()
        spec = system.identification_spec(aggregate=self.aggregate)
        if self.target == "aggregated" and not spec.aggregate:
            raise VesselidError("target='aggregated' needs an aggregated-state predictor "
                                "(a system with a disturbance sensor)")
        return spec

    def run_seeds(self, start: int = 0, stop: int | None = None) -> list[np.random.SeedSequence]:
        """Seeds of the experiments of runs ``start … stop−1`` (flattened, run-major)."""
        stop = int(self.runs) if stop is None else stop
        # run r's seed is the root's child r (seeds.run_seeds(seed, runs)[r]), made alone:
        # a chunk pays for its own runs, not for spawning every run of the study
        root = seeds.root(int(self.seed))
        children = [seeds.child(root, r) for r in range(int(start), min(int(stop), self.runs))]
        e_count = int(self.experiments_per_run)
        if e_count == 1:
            return children
        return [seeds.child(c, e) for c in children for e in range(e_count)]

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable settings."""
        system = self.system if isinstance(self.system, str) else getattr(
            self.system, "__qualname__", repr(self.system))
        return {
            "name": self.name, "system": system, "options": dict(self.options),
            "methods": list(self.methods), "runs": int(self.runs),
            "samples": int(self.samples), "experiments_per_run": int(self.experiments_per_run),
            "seed": int(self.seed), "combine": self.combine, "aggregate": self.aggregate,
            "target": self.target, "max_iter": int(self.max_iter), "tol": float(self.tol),
        }


# ----------------------------------------------------------------------- engine
def regression_data(study: Study, system: System, spec: ModelSpec, sim) -> RegressionData:
    """Batch arrays of a simulation → regression data, one parameter group per run."""
    y2 = sim.y2 if spec.aggregate else None
    data = from_arrays(spec, sim.y, sim.u, y2=y2,
                       experiments_per_group=int(study.experiments_per_run))
    if study.target == "aggregated":
        data = replace(data, target=data.regsig)
    return data


def run_chunk(study: Study, start: int, stop: int) -> pd.DataFrame:
    """Simulate and estimate runs ``start … stop−1`` of ``study`` (tidy frame).

    A pure function of its arguments: this is the unit of work for local batches
    and for Dask tasks. The BLAS runs on one thread meanwhile
    (:func:`~vesselid.identify.linalg.one_blas_thread`: the same numbers): the
    parallelism is the Monte Carlo's own, over runs, and a BLAS thread pool in each of
    several concurrent workers only oversubscribes the cores.
    """
    return pd.DataFrame(_chunk_columns(study, start, stop))


@one_blas_thread
def _chunk_columns(study: Study, start: int, stop: int) -> dict[str, np.ndarray]:
    """The columns of :func:`run_chunk`'s frame (local chunks return these: arrays
    travel back from a worker process for a fraction of a frame's pickling, and the
    study's frame is made once from all chunks)."""
    system = study.build_system()
    spec = study.identification_spec(system)
    sim = system.simulate(int(study.samples), run_seeds=study.run_seeds(start, stop))
    data = regression_data(study, system, spec, sim)
    theta0 = spec.theta0_vector()
    frames = []
    base = None  # the converged IV_{E{ζ}=0} result on this chunk's data, once computed
    for method in study.methods:
        est = get_estimator(method)
        options: dict[str, Any] = {"combine": study.combine, "max_iter": int(study.max_iter),
                                   "tol": float(study.tol)}
        if base is not None and _is_zero_mean_iv(est, study):
            res = base
        else:
            if base is not None and _takes_base(est, study):
                options["base"] = base
            res = est.estimate_parameters(data, spec, **options)
        if _is_zero_mean_iv(est, study):
            base = res
        elif (base is None and _takes_base(est, study)
              and isinstance(res.info.get("base"), IterationResult)):
            base = res.info["base"]
        frames.append(_tidy(res, method, spec, theta0, start, len(frames)))
    # one frame per chunk from the methods' columns (a frame per method costs more than
    # the method's estimate on small chunks), its rows already in the study's order (run,
    # method, parameter): the chunks' frames then only need concatenating
    cols = _concat_columns(frames)
    idx = np.lexsort((cols["_p"], cols["_m"], cols["run"]))
    return {c: v[idx] for c, v in cols.items()}


def _concat_columns(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The columns of ``parts`` (same names, in order) joined end to end."""
    return {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}


def _is_zero_mean_iv(est: Any, study: Study) -> bool:
    """Whether ``est`` is the package's IV_{E{ζ}=0} (pooled), whose result is shared."""
    return type(est) is RefinedIV and est.zero_mean and study.combine == "pooled"


def _takes_base(est: Any, study: Study) -> bool:
    """Whether ``est`` starts from the converged IV_{E{ζ}=0} iteration and can be
    handed it (computed with the same data and settings), instead of iterating again.

    Sharing is bit-identical by construction: the same function on the same arrays.
    """
    return isinstance(est, InstrumentalGMM | PredictionError) and study.combine == "pooled"


def _tidy(res, method: str, spec: ModelSpec, theta0: np.ndarray, start: int, m: int
          ) -> dict[str, np.ndarray]:
    """The tidy columns of one method's estimates on a chunk (:func:`run_chunk` makes
    the frame); ``m`` is the method's place in the study's methods (helper column
    ``_m``, as ``_p`` is the parameter's)."""
    n_runs, n_par = res.theta.shape
    equations = [eq for eq, _ in spec.param_index]
    terms = [term for _, term in spec.param_index]
    est = res.theta.ravel()
    th0 = np.tile(theta0, n_runs)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = normalized_error(est, th0)
    finite = np.all(np.isfinite(res.theta), axis=1)
    converged = np.asarray(res.converged, dtype=bool) & finite
    return {
        "run": np.repeat(np.arange(start, start + n_runs, dtype=np.int64), n_par),
        "method": np.full(n_runs * n_par, method, dtype=object),
        "equation": np.tile(np.asarray(equations, dtype=object), n_runs),
        "term": np.tile(np.asarray(terms, dtype=object), n_runs),
        "estimate": est,
        "theta0": th0,
        "normalized_error": err,
        "converged": np.repeat(converged, n_par),
        "iterations": np.repeat(np.asarray(res.iterations, dtype=np.int64), n_par),
        "stop_reason": np.repeat(np.asarray(res.reason, dtype=object).astype(str), n_par),
        "_p": np.tile(np.arange(n_par), n_runs),
        "_m": np.full(n_runs * n_par, m, dtype=np.int64),
    }


def _chunks(runs: int, batch_size: int) -> list[tuple[int, int]]:
    return [(a, min(a + batch_size, runs)) for a in range(0, runs, batch_size)]


def _progress(total: int, progress: bool | None, desc: str):
    from tqdm.auto import tqdm

    disable = None if progress is None else not progress
    if disable is None and not sys.stderr.isatty():
        disable = True
    return tqdm(total=total, desc=desc, unit="run", disable=disable, leave=False)


def run_study(
    study: Study,
    *,
    client: Any = None,
    batch_size: int | None = None,
    n_jobs: int | None = None,
    progress: bool | None = None,
) -> pd.DataFrame:
    """Run a Monte Carlo study and return the tidy result frame (see module docstring).

    Parameters
    ----------
    study : Study
    client : dask.distributed.Client or str, optional
        Run the chunks as Dask tasks on this client (or on a client connected to
        this scheduler address, closed afterwards). Default: locally.
    batch_size : int, optional
        Runs per chunk (default: 250 on one thread; on several, a tapering schedule
        from 250 runs or :data:`MAX_WORKER_CHUNK_SAMPLES` samples, whichever is fewer,
        down to :data:`MIN_LOCAL_CHUNK`, :func:`_local_chunks`; with Dask:
        enough chunks for every worker thread).
    n_jobs : int, optional
        Local threads (default: all cores): several chunks run concurrently, one per
        thread, with serial kernels; a single chunk runs its kernels on all threads.
        Ignored with Dask.
    progress : bool, optional
        tqdm progress bar over runs; default shown only when stderr is a terminal.

    Returns
    -------
    DataFrame
        Columns :data:`COLUMNS`, sorted by run, method (in ``study.methods`` order)
        and parameter. ``df.attrs["study"]`` holds ``study.describe()``.

    Notes
    -----
    While a local run computes, glibc's ``malloc`` keeps freed memory in the process's
    heap for reuse, and gives it back when the run ends
    (:func:`vesselid.core.heap.kept_heap`; ``VESSELID_KEEP_HEAP=0`` leaves glibc's
    settings alone).
    """
    runs = int(study.runs)
    if batch_size is not None and int(batch_size) < 1:
        raise VesselidError(f"batch_size must be positive, got {batch_size}")
    if client is not None:
        frames = _run_dask(study, client, batch_size, progress)
    else:
        with _threads(n_jobs), _progress(runs, progress, study.name or "runs") as bar:
            chunks = (_local_chunks(runs, int(study.samples)) if batch_size is None
                      else _chunks(runs, int(batch_size)))
            frames = _run_local(study, chunks, bar)
    if isinstance(frames[0], dict):  # local chunks: their columns
        df = pd.DataFrame(_concat_columns(frames))
    else:
        df = pd.concat(frames, ignore_index=True)
    df = _order(df, study)
    df.attrs["study"] = study.describe()
    return df


#: Smallest chunk of the tapering local schedule (:func:`_local_chunks`): below it a
#: chunk's set-up (system, estimators, its frame) costs more than its runs' kernels gain.
MIN_LOCAL_CHUNK = 20
#: Largest chunk of the tapering local schedule in samples (runs × samples per run):
#: the workers run their chunks at once, and each chunk's arrays (~40 of runs × samples
#: doubles) pass through the caches and the memory bus they share. Measured on two
#: workers on two cores, Table 1 (1000 runs × 10⁴ samples): chunks of at most 100 runs
#: took ~8 % less CPU in all than chunks of up to 250 (1.84 s against 2.04 s of wall
#: time), where one worker alone runs either in the same time (``scripts/bench.py``,
#: the Monte Carlo item).
MAX_WORKER_CHUNK_SAMPLES = 1_000_000


def _local_chunks(runs: int, samples: int | None = None) -> list[tuple[int, int]]:
    """The default local chunks. One thread, or runs for one chunk: chunks of
    :func:`_local_batch` (one chunk's kernels threaded over its runs). Several threads
    (the chunks run concurrently, one per worker, each taking the next chunk when it
    finishes one): a tapering schedule, each chunk a ``1/(2·threads)`` share of the runs
    left (at most :data:`DEFAULT_BATCH_SIZE` runs and, for runs of ``samples`` samples,
    :data:`MAX_WORKER_CHUNK_SAMPLES` samples; at least :data:`MIN_LOCAL_CHUNK` runs), so
    the first chunks are large (the batched kernels' efficiency) and the last small: a
    run that costs many times the others (``auto``'s prediction-error fallback on a log
    where both validity tests reject) leaves the workers at most a small chunk apart,
    where equal chunks leave one worker a whole chunk behind. The chunks change how the
    runs are grouped, never a run's numbers."""
    from vesselid.core.threads import n_threads

    threads = n_threads()
    if threads < 2 or runs <= DEFAULT_BATCH_SIZE:
        return _chunks(runs, _local_batch(runs))
    largest = DEFAULT_BATCH_SIZE
    if samples:
        largest = max(MIN_LOCAL_CHUNK, min(largest, MAX_WORKER_CHUNK_SAMPLES // int(samples)))
    out, a = [], 0
    while a < runs:
        left = runs - a
        size = min(largest, max(MIN_LOCAL_CHUNK, math.ceil(left / (2 * threads))))
        out.append((a, min(a + size, runs)))
        a += size
    return out


def _local_batch(runs: int) -> int:
    """Default local chunk size: :data:`DEFAULT_BATCH_SIZE`, evened out so that the
    number of chunks is a multiple of the threads when there are several chunks (the
    chunks run concurrently, one per thread: :func:`_run_local`)."""
    from vesselid.core.threads import n_threads

    n_chunks = math.ceil(runs / DEFAULT_BATCH_SIZE)
    threads = n_threads()
    if n_chunks < 2 or threads < 2:
        return DEFAULT_BATCH_SIZE
    n_chunks = math.ceil(n_chunks / threads) * threads
    return max(1, math.ceil(runs / n_chunks))


def _run_local(study: Study, chunks: list[tuple[int, int]], bar: Any
               ) -> list[dict[str, np.ndarray]]:
    """The chunks' columns (:func:`_chunk_columns`), in order. With several threads
    (numba's thread count) and chunks, the chunks run concurrently, one per worker,
    each with serial kernels (:func:`vesselid.core.threads.serial_here`); else one after
    the other with the kernels threaded over the chunk's runs. Each chunk is computed by
    the same code either way
    (bit-identical results).

    The workers are forked processes where the platform forks (:func:`_fork_context`):
    a chunk's Python and numpy glue (estimator set-up, ``auto``'s tests, the tidy frame)
    holds the GIL for about a fifth of its time, so chunks in threads of one process
    queue behind each other's glue, and more threads add GIL hand-overs until more
    threads are slower. Processes share nothing but the forked memory (the compiled
    kernels, loaded once in this process by a one-run warm-up first where it has not run
    the study's kernels yet) and return small columns, each chunk's already in the
    study's row order. They fork each other as a tree
    (:func:`vesselid.core.forkpool.fork_map`: this process forks one, and every worker
    starts on the chunks once its own forks are done), and each takes the next chunk
    when it finishes one. Elsewhere the chunks run in threads.

    Either way the process keeps freed memory in its heap meanwhile
    (:func:`vesselid.core.heap.kept_heap`, inherited by the workers): the chunks
    allocate and free arrays of ``runs × samples`` doubles over and over, which glibc
    would otherwise return to the system and fault in afresh.
    """
    from vesselid.core.heap import kept_heap

    with kept_heap():
        return _run_chunks(study, chunks, bar)


def _run_chunks(study: Study, chunks: list[tuple[int, int]], bar: Any) -> list[Any]:
    """:func:`_run_local`'s chunks, in this process or in its workers."""
    from vesselid.core.threads import n_threads, serial_here

    workers = min(n_threads(), len(chunks))
    if workers <= 1:
        frames = []
        for a, b in chunks:
            frames.append(_chunk_columns(study, a, b))
            _ran(study)
            bar.update(b - a)
        return frames
    ctx = _fork_context()
    if ctx is None:
        from concurrent.futures import ThreadPoolExecutor

        pool = ThreadPoolExecutor(workers, thread_name_prefix="vesselid-chunk")
        return _gather(pool, study, chunks, bar)
    from vesselid.core.forkpool import fork_map

    if not _has_run(study):
        with serial_here():  # load (or compile) every kernel of the study here, once
            _chunk_columns(study, chunks[0][0], chunks[0][0] + 1)
        _ran(study)
    # the objects alive now (modules, compiled kernels) leave the garbage collector's
    # generations before the workers fork: a worker's collections then do not walk
    # (and so copy-on-write every page of) the parent's heap; measured ~7 % of the
    # workers' CPU on Table 1
    gc.freeze()
    try:
        # the workers count themselves while they compute a chunk: a worker whose long
        # job still runs at the end of the schedule spreads it over the cores the others
        # leave idle (vesselid.core.threads.idle_cores)
        count, cores = ctx.Value("i", 0), n_threads()
        overlap = _overlaps(int(study.runs), workers)
        with warnings.catch_warnings():
            # Python ≥ 3.12 warns on fork() in a process with threads; the children run
            # chunks in their main thread (serial kernels; a long job's helper threads
            # are started there)
            warnings.filterwarnings("ignore", message=".*fork.*", category=DeprecationWarning)
            return fork_map(lambda i: _serial_chunk(study, *chunks[i], overlap), len(chunks),
                            workers, initializer=lambda: _worker_start(count, cores),
                            on_result=lambda i: bar.update(chunks[i][1] - chunks[i][0]))
    finally:
        gc.unfreeze()


def _overlaps(runs: int, workers: int) -> bool:
    """Whether the workers may give a long job more threads (``serial_here(overlap=
    True)``, :func:`_serial_chunk`): where a worker's share of the runs is at most a
    default chunk. A run that costs many times the others (``auto``'s prediction-error
    fallback: up to about as much CPU as 300 ordinary runs) then outlasts a worker's
    share and holds up the end of the schedule, and its second thread and the idle cores
    shorten that; with larger shares every core stays busy to the end, where a second
    thread only takes turns with the other workers on theirs (measured on two workers:
    8 % more CPU in all)."""
    return runs <= workers * DEFAULT_BATCH_SIZE


#: The studies whose chunks this process has computed (:func:`_kernel_key`, methods):
#: their compiled kernels are loaded here, and forked workers inherit them.
_RAN: list[tuple[tuple, frozenset[str]]] = []


def _kernel_key(study: Study) -> tuple:
    """What decides which compiled kernels a study's chunks call, besides its methods:
    the plant, the model structure and the estimation settings (not the number of runs
    or samples, the seed or the iteration limits: every kernel serves every size)."""
    options = repr(sorted(study.options.items(), key=lambda kv: str(kv[0])))
    return (study.system, options, study.combine, study.aggregate, study.target,
            int(study.experiments_per_run))


def _ran(study: Study) -> None:
    """Record that this process computed a chunk of ``study``."""
    if not _has_run(study):
        _RAN.append((_kernel_key(study), frozenset(study.methods)))


def _has_run(study: Study) -> bool:
    """Whether this process has computed a chunk of a study with the same kernels
    (:func:`_kernel_key`) and at least ``study``'s methods: then the one-run warm-up
    before forking the workers would load nothing."""
    key, methods = _kernel_key(study), frozenset(study.methods)
    return any(k == key and methods <= m for k, m in _RAN)


def _worker_start(count: Any = None, cores: int = 1) -> None:
    """A forked worker's set-up: the BLAS on one thread for the worker's life (its
    chunks' :func:`~vesselid.identify.linalg.one_blas_thread` then restores one thread).
    A fork has none of the parent's BLAS threads; restoring more than one at the end of
    each chunk would start one that spins for work, taking CPU from the other workers'
    cores. The parent's setting is not touched. ``count``: the pool's shared count of
    workers computing a chunk, on ``cores`` cores
    (:func:`vesselid.core.threads.share_cores`)."""
    from vesselid.core.threads import share_cores
    from vesselid.identify.linalg import pin_blas_to_one_thread

    if count is not None:
        share_cores(count, cores)
    pin_blas_to_one_thread()  # this process only runs chunks


def _gather(pool: Any, study: Study, chunks: list[tuple[int, int]], bar: Any
            ) -> list[dict[str, np.ndarray]]:
    """Submit every chunk to the thread ``pool`` (:func:`_serial_chunk`) and return
    their columns in order, shutting the pool down."""
    with pool:
        futures = [pool.submit(_serial_chunk, study, a, b) for a, b in chunks]
        frames = []
        for fut, (a, b) in zip(futures, chunks, strict=True):
            frames.append(fut.result())
            bar.update(b - a)
    return frames


def _serial_chunk(study: Study, start: int, stop: int, overlap: bool = False
                  ) -> dict[str, np.ndarray]:
    """:func:`run_chunk`'s columns with serial kernels (one of several concurrent
    workers).

    ``overlap`` (a worker process): a long job may still take a second thread
    (``serial_here(overlap=True)``): a run that costs many times the others
    (``auto``'s prediction-error fallback) then fits its candidate models at once, and
    its line searches filter their trial points on the cores the other workers leave
    idle, so the worker that drew it does not finish far behind the others. Chunk
    threads of one process leave it off (their single background thread would queue
    their jobs)."""
    from vesselid.core.threads import busy, serial_here

    with serial_here(overlap=overlap), busy():
        return _chunk_columns(study, start, stop)


def _fork_context() -> Any:
    """The ``fork`` multiprocessing context where the platform has it (Linux, macOS:
    the forked workers inherit the loaded kernels), else None (threads are used).
    ``VESSELID_MC_WORKERS=threads`` keeps the chunks in threads."""
    import multiprocessing

    if os.environ.get("VESSELID_MC_WORKERS", "").lower() == "threads":
        return None
    if "fork" not in multiprocessing.get_all_start_methods():
        return None
    if multiprocessing.current_process().daemon:  # a pool's worker may not have children
        return None
    return multiprocessing.get_context("fork")


def _order(df: pd.DataFrame, study: Study) -> pd.DataFrame:
    """Sort by run, method (in ``study.methods`` order), parameter; drop the helper
    columns. The chunks' frames come in that order (:func:`run_chunk`) and in run
    order, so the sort is then only checked."""
    m_idx = df["_m"].to_numpy()
    idx = np.lexsort((df["_p"].to_numpy(), m_idx, df["run"].to_numpy()))
    if not np.array_equal(idx, np.arange(idx.size)):
        df, m_idx = df.iloc[idx], m_idx[idx]
    out = df.drop(columns=["_p", "_m"]).reset_index(drop=True)
    out["method"] = pd.Categorical.from_codes(m_idx, categories=list(study.methods))
    return out


class _threads:
    """Temporarily set numba's thread count (``n_jobs``)."""

    def __init__(self, n_jobs: int | None) -> None:
        self.n_jobs = n_jobs
        self.old: int | None = None

    def __enter__(self) -> _threads:
        if self.n_jobs is not None:
            import numba

            n = max(1, min(int(self.n_jobs), numba.config.NUMBA_NUM_THREADS))
            self.old = numba.get_num_threads()
            numba.set_num_threads(n)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.old is not None:
            import numba

            numba.set_num_threads(self.old)


def _run_dask(study: Study, client: Any, batch_size: int | None, progress: bool | None):
    try:
        from distributed import Client, as_completed
    except ImportError as exc:  # pragma: no cover - optional dependency
        raise VesselidError("a Dask client needs the 'distributed' extra: "
                            "pip install 'vesselid[distributed]'") from exc
    own = isinstance(client, str)
    cl = Client(client) if own else client
    try:
        if batch_size is None:
            threads = sum(cl.nthreads().values()) or 1
            batch_size = max(1, min(DEFAULT_BATCH_SIZE, math.ceil(int(study.runs) / threads)))
        chunks = _chunks(int(study.runs), int(batch_size))
        futures = [cl.submit(run_chunk, study, a, b, pure=False) for a, b in chunks]
        index = {f.key: i for i, f in enumerate(futures)}
        frames: list[pd.DataFrame | None] = [None] * len(futures)
        with _progress(int(study.runs), progress, study.name or "runs") as bar:
            for fut in as_completed(futures):
                i = index[fut.key]
                frames[i] = fut.result()
                bar.update(chunks[i][1] - chunks[i][0])
        return frames
    finally:
        if own:
            cl.close()


# ---------------------------------------------------------------------- summary
def summary_table(df: pd.DataFrame) -> pd.DataFrame:
    """Mean ± sd of the normalized errors per method and parameter (Tables 1–2).

    Runs whose estimate is not finite (no instrument could be formed) are left out
    of the statistics and counted in ``failed``; ``not_converged`` counts every run
    whose refined iteration did not converge (finite non-converged estimates — the
    IV estimate of the best iterate — are kept in the statistics).

    Returns
    -------
    DataFrame
        One row per (method, equation, term): ``runs``, ``used``, ``failed``,
        ``not_converged``, ``mean``, ``sd`` (ddof=1), ``se`` (``sd/√used``, the
        standard error of the mean), ``z`` (``mean/se``), ``mean_iterations``.
    """
    if df.empty:
        raise VesselidError("no results to summarise")
    d = df.copy()
    d["_finite"] = np.isfinite(d["normalized_error"].to_numpy(float))
    d["_err"] = d["normalized_error"].where(d["_finite"])
    keys = ["method", "equation", "term"]
    params = list(dict.fromkeys(zip(d["equation"], d["term"], strict=True)))
    g = d.groupby(keys, sort=False, observed=True)
    out = pd.DataFrame({
        "runs": g["run"].nunique(),
        "used": g["_finite"].sum().astype(int),
        "not_converged": g["converged"].apply(lambda s: int((~s.astype(bool)).sum())),
        "mean": g["_err"].mean(),
        "sd": g["_err"].std(ddof=1),
        "mean_iterations": g["iterations"].mean(),
    }).reset_index()
    out["failed"] = out["runs"] - out["used"]
    out["se"] = out["sd"] / np.sqrt(out["used"].clip(lower=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        out["z"] = out["mean"] / out["se"]
    methods = [m for m in (d["method"].cat.categories if hasattr(d["method"], "cat")
                           else pd.unique(d["method"])) if m in set(out["method"])]
    out["_m"] = out["method"].astype(str).map({m: i for i, m in enumerate(methods)})
    out["_p"] = [params.index((e, t)) for e, t in zip(out["equation"], out["term"], strict=True)]
    out = out.sort_values(["_m", "_p"]).drop(columns=["_m", "_p"]).reset_index(drop=True)
    out["method"] = out["method"].astype(str)
    return out[["method", "equation", "term", "runs", "used", "failed", "not_converged",
                "mean", "sd", "se", "z", "mean_iterations"]]


def paper_table(summary: pd.DataFrame, *, digits: int = 4, labels: Mapping | None = None
                ) -> pd.DataFrame:
    """The paper's layout: one row per method, one ``mean ± sd`` column per parameter.

    Column names follow the paper, ``(â − a0)/a0``, when ``labels`` maps terms to
    symbols (e.g. ``{"w": "a", "w*|w|": "n", "tau": "f"}``); default the term names.
    """
    cells: dict[str, dict[str, str]] = {}
    for _, r in summary.iterrows():
        sym = (labels or {}).get(r["term"], None)
        col = f"({sym}̂ − {sym}0)/{sym}0" if sym else f"{r['equation']}: {r['term']}"
        cells.setdefault(r["method"], {})[col] = f"{r['mean']:+.{digits}f} ± {r['sd']:.{digits}f}"
    return pd.DataFrame.from_dict(cells, orient="index")


# ---------------------------------------------------------------------- file I/O
def save_results(df: pd.DataFrame, path: str | os.PathLike[str]) -> Path:
    """Write tidy results atomically to ``.csv`` or ``.parquet``."""
    target = Path(path)
    suffix = target.suffix.lower()
    out = df.copy()
    out["method"] = out["method"].astype(str)
    if suffix == ".csv":
        atomic_write_with(target, lambda p: out.to_csv(p, index=False, float_format="%.17g"))
    elif suffix in (".parquet", ".pq"):
        atomic_write_with(target, lambda p: out.to_parquet(p, index=False))
    else:
        raise VesselidError(f"results must be saved as .csv or .parquet, got {target.name!r}")
    return target


def load_results(path: str | os.PathLike[str]) -> pd.DataFrame:
    """Read tidy results written by :func:`save_results`."""
    source = Path(path)
    suffix = source.suffix.lower()
    if suffix == ".csv":
        df = pd.read_csv(source, keep_default_na=False, na_values=["", "NaN", "nan"])
    elif suffix in (".parquet", ".pq"):
        df = pd.read_parquet(source)
    else:
        raise VesselidError(f"results must be .csv or .parquet, got {source.name!r}")
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise VesselidError(f"{source.name} is not a Monte Carlo result file: missing {missing}")
    methods = list(dict.fromkeys(df["method"].astype(str)))
    df["method"] = pd.Categorical(df["method"].astype(str), categories=methods)
    df["converged"] = df["converged"].astype(bool)
    df["stop_reason"] = df["stop_reason"].astype(str)
    return df[list(COLUMNS)]
