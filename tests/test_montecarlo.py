"""Monte Carlo engine: seeding independent of batching/threads/Dask, tidy output, I/O."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from vesselid.errors import VesselidError
from vesselid.studies.montecarlo import (
    COLUMNS,
    Study,
    load_results,
    paper_table,
    run_chunk,
    run_study,
    save_results,
    summary_table,
)

SMALL = Study(options={"pulse_design": "alternating"}, runs=12, samples=1500, seed=5)


@pytest.fixture(scope="module")
def reference() -> pd.DataFrame:
    return run_study(SMALL, progress=False)


def test_tidy_columns_and_order(reference):
    df = reference
    assert tuple(df.columns) == COLUMNS
    assert len(df) == SMALL.runs * 3 * 3
    assert list(df["method"].cat.categories) == list(SMALL.methods)
    # sorted by run, method, parameter
    first = df[df["run"] == 0]
    assert list(first["method"].astype(str)) == ["ls"] * 3 + ["iv"] * 3 + ["iv-zero-mean"] * 3
    assert list(first["term"])[:3] == ["w", "w*|w|", "tau"]
    np.testing.assert_allclose(first["theta0"].to_numpy()[:3], [0.99, -0.1, 1.0])
    err = (df["estimate"] - df["theta0"]) / df["theta0"]
    np.testing.assert_allclose(df["normalized_error"], err)
    assert (df.loc[df["method"] == "ls", "stop_reason"] == "closed form").all()


@pytest.mark.parametrize("batch_size", [1, 5, 12])
def test_bit_identical_whatever_the_batch_size(reference, batch_size):
    pd.testing.assert_frame_equal(run_study(SMALL, batch_size=batch_size, progress=False),
                                  reference)


def test_bit_identical_whatever_the_thread_count(reference):
    pd.testing.assert_frame_equal(run_study(SMALL, n_jobs=1, batch_size=4, progress=False),
                                  reference)


def test_concurrent_chunks_bit_identical(reference, monkeypatch):
    """Chunks run concurrently on the local threads (serial kernels each) give the frame
    of one chunk with threaded kernels; the default chunk count is a multiple of the
    threads."""
    from vesselid.studies import montecarlo as mc

    pd.testing.assert_frame_equal(run_study(SMALL, n_jobs=2, batch_size=5, progress=False),
                                  reference)
    monkeypatch.setattr("vesselid.core.threads.n_threads", lambda: 2)
    assert mc._local_batch(1000) == 250 and mc._local_batch(750) == 188
    assert mc._local_batch(200) == mc.DEFAULT_BATCH_SIZE  # one chunk: threaded kernels
    monkeypatch.setattr("vesselid.core.threads.n_threads", lambda: 1)
    assert mc._local_batch(750) == mc.DEFAULT_BATCH_SIZE


def test_local_chunks_taper_and_cover_every_run(monkeypatch):
    """Several workers: chunks cover every run once, in order, and taper from at most
    the batch size down to the minimum; one worker: equal batches."""
    from vesselid.studies import montecarlo as mc

    monkeypatch.setattr("vesselid.core.threads.n_threads", lambda: 2)
    chunks = mc._local_chunks(1000)
    assert chunks[0][0] == 0 and chunks[-1][1] == 1000
    assert all(b == c for (_, b), (c, _) in itertools.pairwise(chunks))
    sizes = [b - a for a, b in chunks]
    assert sizes[0] == mc.DEFAULT_BATCH_SIZE and sizes == sorted(sizes, reverse=True)
    assert min(sizes[:-1]) == mc.MIN_LOCAL_CHUNK and len(chunks) > 4
    assert mc._local_chunks(200) == [(0, 200)]
    # long runs: no chunk above the samples cap, the same taper below it
    capped = mc._local_chunks(1000, 10_000)
    sizes = [b - a for a, b in capped]
    assert max(sizes) == mc.MAX_WORKER_CHUNK_SAMPLES // 10_000 < mc.DEFAULT_BATCH_SIZE
    assert capped[-1][1] == 1000 and sizes == sorted(sizes, reverse=True)
    assert all(b == c for (_, b), (c, _) in itertools.pairwise(capped))
    assert max(b - a for a, b in mc._local_chunks(1000, 10**9)) == mc.MIN_LOCAL_CHUNK
    assert mc._local_chunks(1000, 100) == chunks  # short runs: the runs cap binds
    monkeypatch.setattr("vesselid.core.threads.n_threads", lambda: 1)
    assert mc._local_chunks(1000) == mc._chunks(1000, mc.DEFAULT_BATCH_SIZE)
    assert mc._local_chunks(1000, 10_000) == mc._chunks(1000, mc.DEFAULT_BATCH_SIZE)


def test_study_seeds_are_the_root_seeds_children():
    from vesselid.core import seeds

    study = Study(options={}, runs=30, samples=100, seed=4)
    every = seeds.run_seeds(4, 30)
    for a, b in ((0, 30), (7, 12), (29, 30)):
        got = study.run_seeds(a, b)
        assert [s.spawn_key for s in got] == [s.spawn_key for s in every[a:b]]
        assert all(np.array_equal(g.generate_state(4), e.generate_state(4))
                   for g, e in zip(got, every[a:b], strict=True))


def test_a_run_depends_only_on_its_own_seed(reference):
    chunk = run_chunk(SMALL, 7, 9).drop(columns="_p")
    ref = reference[reference["run"].isin([7, 8])]
    for col in ("estimate", "iterations"):
        got = chunk.sort_values(["run", "method"], kind="stable")[col].to_numpy()
        exp = ref.sort_values(["run", "method"], kind="stable")[col].to_numpy()
        np.testing.assert_array_equal(np.sort(got), np.sort(exp))


def test_parallel_kernels_path_matches_small_batches():
    """Chunks big enough for the threaded kernels give the same numbers as tiny chunks."""
    study = Study(options={"pulse_design": "alternating"}, runs=24, samples=10_000, seed=2,
                  methods=("iv-zero-mean",))
    pd.testing.assert_frame_equal(run_study(study, progress=False),
                                  run_study(study, batch_size=3, progress=False))


def test_dask_local_cluster_bit_identical(reference):
    import distributed
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        got = run_study(SMALL, client=client, batch_size=5, progress=False)
        address = cluster.scheduler_address
        got_addr = run_study(SMALL, client=address, progress=False)
    pd.testing.assert_frame_equal(got, reference)
    pd.testing.assert_frame_equal(got_addr, reference)


def test_summary_table_statistics(reference):
    s = summary_table(reference)
    assert list(s["method"]) == ["ls"] * 3 + ["iv"] * 3 + ["iv-zero-mean"] * 3
    sub = reference[(reference["method"] == "iv") & (reference["term"] == "tau")]
    row = s[(s["method"] == "iv") & (s["term"] == "tau")].iloc[0]
    e = sub["normalized_error"].to_numpy()
    assert row["mean"] == pytest.approx(e.mean())
    assert row["sd"] == pytest.approx(e.std(ddof=1))
    assert row["se"] == pytest.approx(e.std(ddof=1) / np.sqrt(len(e)))
    assert row["runs"] == SMALL.runs and row["failed"] == 0


def test_failed_runs_are_kept_counted_and_excluded(reference):
    df = reference.copy()
    bad = (df["run"] == 3) & (df["method"] == "iv")
    df.loc[bad, ["estimate", "normalized_error"]] = np.nan
    df.loc[bad, "converged"] = False
    df.loc[bad, "stop_reason"] = "auxiliary model of the initial estimate diverges"
    s = summary_table(df)
    row = s[(s["method"] == "iv") & (s["term"] == "w")].iloc[0]
    assert row["failed"] == 1 and row["not_converged"] >= 1 and row["used"] == SMALL.runs - 1
    ok = df[(df["method"] == "iv") & (df["term"] == "w") & ~bad]["normalized_error"]
    assert row["mean"] == pytest.approx(ok.mean())


def test_paper_table_format(reference):
    text = paper_table(summary_table(reference), labels={"w": "a", "w*|w|": "n", "tau": "f"})
    assert list(text.index) == ["ls", "iv", "iv-zero-mean"]
    assert list(text.columns) == [f"({s}\u0302 − {s}0)/{s}0" for s in "anf"]
    cell = text.loc["iv", text.columns[0]]
    mean, sd = cell.split(" ± ")
    assert mean.startswith(("+", "-")) and len(sd.split(".")[1]) == 4


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_save_load_round_trip(reference, tmp_path, suffix):
    path = save_results(reference, tmp_path / f"res{suffix}")
    back = load_results(path)
    pd.testing.assert_frame_equal(back, reference, check_dtype=False, check_categorical=False)
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # atomic: no temp left


def test_bad_study_settings_are_domain_errors():
    with pytest.raises(VesselidError, match="methods"):
        Study(methods=("ml",))
    with pytest.raises(ValueError, match="run"):
        Study(runs=0)
    with pytest.raises(VesselidError, match="target"):
        Study(target="both")
    with pytest.raises(VesselidError, match="batch_size"):
        run_study(SMALL, batch_size=0)
    with pytest.raises(VesselidError, match="csv"):
        save_results(pd.DataFrame(columns=list(COLUMNS)), "x.txt")


def test_experiments_per_run_seeds_are_distinct():
    study = Study(runs=3, experiments_per_run=2, seed=1)
    seeds = study.run_seeds()
    assert len(seeds) == 6
    assert len({tuple(s.spawn_key) for s in seeds}) == 6
    assert [tuple(s.spawn_key) for s in study.run_seeds(1, 2)] == [(1, 0), (1, 1)]


@pytest.mark.parametrize("use_sim", [False, True])
def test_specialised_kernel_bit_identical_to_generic(monkeypatch, use_sim):
    """The generated (unrolled) moment kernel reproduces the generic one exactly,
    including a run whose auxiliary model diverges."""
    from vesselid.identify import estimators
    from vesselid.identify.data import from_arrays
    from vesselid.plant.systems import heave

    system = heave(current_mean=0.1, current_sensor=True, pulse_design="alternating")
    spec = system.identification_spec()
    sim = system.simulate(3000, n_runs=4, seed=0)
    data = from_arrays(spec, sim.y, sim.u, y2=sim.y2)
    theta = np.tile(spec.theta0_vector(), (4, 1))
    theta[2] = [1.5, 0.2, 1.0]
    th = theta if use_sim else None
    fast = estimators.compute_moments(data, spec, th)
    monkeypatch.setenv("VESSELID_GENERIC_KERNELS", "1")
    slow = estimators.compute_moments(data, spec, th)
    for name in ("zphi", "zy", "z", "phi", "y", "count", "status"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(slow, name), err_msg=name)
    assert fast.status[2] == (1 if use_sim else 0)


def test_auto_shares_the_chunks_iv_zero_mean_result_bit_for_bit(monkeypatch):
    """``auto`` starts from the converged IV_{E{ζ}=0} iteration: a chunk computes it once
    and hands it over (or takes auto's when auto comes first); the frame is identical
    to estimating every method on its own."""
    import vesselid.studies.montecarlo as mc
    from vesselid.studies.montecarlo import Study, run_study

    calls = []
    real = mc.get_estimator("auto").estimate_parameters
    monkeypatch.setenv("VESSELID_MC_WORKERS", "threads")  # the spy counts in this process

    def spy(*args, **kwargs):
        calls.append("base" in kwargs)
        return real(*args, **kwargs)

    for methods in (("ls", "iv-zero-mean", "auto"), ("auto", "iv-zero-mean")):
        study = Study(system="heave", options={"pulse_design": "alternating"},
                      methods=methods, runs=6, samples=1500, seed=3)
        with monkeypatch.context() as m:
            m.setattr(mc.get_estimator("auto"), "estimate_parameters", spy)
            shared = run_study(study, progress=False, batch_size=3)
        with monkeypatch.context() as m:
            m.setattr(mc, "_takes_base", lambda *a: False)
            m.setattr(mc, "_is_zero_mean_iv", lambda *a: False)
            alone = run_study(study, progress=False, batch_size=3)
        pd.testing.assert_frame_equal(shared, alone, check_exact=True)
    assert calls == [True, True, False, False]  # handed over when iv-zero-mean came first


def test_concurrent_chunks_in_processes_and_threads_agree(reference, monkeypatch):
    """The concurrent chunks give the same frame bit for bit in forked worker processes
    (the default where the platform forks) and in threads."""
    from vesselid.studies import montecarlo as mc

    if mc._fork_context() is None:
        pytest.skip("no fork on this platform")
    in_processes = run_study(SMALL, n_jobs=2, batch_size=4, progress=False)
    monkeypatch.setenv("VESSELID_MC_WORKERS", "threads")
    assert mc._fork_context() is None
    in_threads = run_study(SMALL, n_jobs=2, batch_size=4, progress=False)
    pd.testing.assert_frame_equal(in_processes, reference)
    pd.testing.assert_frame_equal(in_threads, reference)


def test_a_workers_long_fallback_overlaps_bit_identical(monkeypatch):
    """A worker process's chunk may fit ``auto``'s prediction-error candidates on a
    second thread (``overlap``); its frame is the serial chunk's bit for bit. Run 204 of
    Table 1 is one where both validity tests reject and the fallback is taken."""
    from vesselid.core import threads
    from vesselid.studies import montecarlo as mc
    from vesselid.studies.reproduce import table_study

    if threads.n_threads() < 2:
        pytest.skip("one core: no second thread")
    study = table_study(1, runs=1000, samples=10_000)
    jobs = []
    real = threads.background

    def spy(fn):
        job = real(fn)
        jobs.append(job)
        return job

    monkeypatch.setattr(threads, "background", spy)
    serial = pd.DataFrame(mc._serial_chunk(study, 204, 205))
    assert jobs == [None]  # a serial worker fits the candidates in turn
    overlapped = pd.DataFrame(mc._serial_chunk(study, 204, 205, True))
    assert len(jobs) == 2 and jobs[1] is not None
    pd.testing.assert_frame_equal(overlapped, serial, check_exact=True)


def test_forked_workers_keep_one_blas_thread_and_the_parent_its_own(monkeypatch):
    """A worker process runs its chunks with the BLAS on one thread and keeps it so
    between chunks (no BLAS thread started to spin for work); the parent's setting is
    left as it was."""
    from threadpoolctl import threadpool_info

    from vesselid.studies import montecarlo as mc

    def blas_threads() -> int:
        return max([i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"],
                   default=0)

    if mc._fork_context() is None:
        pytest.skip("no fork on this platform")
    before = blas_threads()
    if before < 2:
        pytest.skip("the BLAS runs on one thread here anyway")
    original = mc._serial_chunk

    def probe(study, start, stop, *args):  # pickled by reference: the workers run it
        cols = original(study, start, stop, *args)
        cols["_blas"] = np.full(cols["run"].size, blas_threads())
        return cols

    probe.__module__, probe.__qualname__ = original.__module__, original.__qualname__
    monkeypatch.setattr(mc, "_serial_chunk", probe)
    monkeypatch.setattr("vesselid.core.threads.n_threads", lambda: 2)

    class Bar:
        def update(self, n):
            pass

    cols = mc._run_local(SMALL, mc._chunks(SMALL.runs, 3), Bar())
    assert {int(x) for c in cols for x in np.unique(c["_blas"])} == {1}
    assert blas_threads() == before


@pytest.mark.parametrize(("workers", "expected"), [(2, False), (3, True)])
def test_workers_overlap_a_long_job_only_where_their_shares_are_small(workers, expected,
                                                                      monkeypatch):
    """A worker gives a long job a second thread (``overlap``) only where a worker's
    share of the runs is at most a default chunk."""
    from vesselid.studies import montecarlo as mc

    if mc._fork_context() is None:
        pytest.skip("no fork on this platform")
    original = mc._serial_chunk

    def probe(study, start, stop, overlap=False):
        cols = original(study, start, stop, overlap)
        cols["_overlap"] = np.full(cols["run"].size, overlap)
        return cols

    monkeypatch.setattr(mc, "_serial_chunk", probe)
    monkeypatch.setattr("vesselid.core.threads.n_threads", lambda: workers)
    runs = workers * mc.DEFAULT_BATCH_SIZE + (0 if expected else 1)
    assert mc._overlaps(runs, workers) is expected

    class Bar:
        def update(self, n):
            pass

    study = Study(options={"pulse_design": "alternating"}, runs=runs, samples=200, seed=5,
                  methods=("ls",))
    cols = mc._run_local(study, mc._chunks(runs, 200), Bar())
    assert {bool(x) for c in cols for x in c["_overlap"]} == {expected}
