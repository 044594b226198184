"""Simulate straight to disk in chunks: logs larger than memory (``vesselid simulate``).

:func:`simulate_to_file` writes the same trial log as
``system.simulate(samples, n_runs, seed).to_log().save(out)`` without holding it in
memory: whole runs are simulated and appended in batches of about
:data:`BATCH_ROWS` rows, so the peak memory is bounded whatever the number of
experiments. Batching whole runs does not change a single value (run ``r`` draws
only from ``SeedSequence(seed).spawn(R)[r]``), so for runs of at most
:data:`CHUNK_SAMPLES` samples the file is the one the in-memory path writes.

A run longer than :data:`CHUNK_SAMPLES` samples is simulated in time chunks of at
most that length: chunk ``c`` of run ``r`` draws its inputs and noise from
``SeedSequence(seed).spawn(R)[r].spawn(C)[c]`` and starts from the state the
previous chunk reached (the recursion (1a) runs on exactly, ``x(k0) =
Φᵀ([x(k0−1)+v(k0−1); u(k0−1)])θ0 + w(k0−1)``). The result is deterministic for a
seed; the random signals restart at chunk boundaries (a pulse is cut there, a
Gauss–Markov process restarts from its stationary distribution), which is why such
runs differ from what an in-memory simulation of the same length would draw. The
metadata records ``chunk_samples``.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from vesselid.errors import VesselidError

__all__ = ["BATCH_ROWS", "CHUNK_SAMPLES", "log_columns", "peak_rows", "simulate_to_file"]

#: Longest run simulated in one piece; longer runs are simulated in time chunks.
CHUNK_SAMPLES = 2**22
#: Rows of whole runs simulated and written together (memory, not results).
BATCH_ROWS = 2**21


def log_columns(system: Any) -> int:
    """Number of columns of the trial log :meth:`Simulation.to_frame` writes for ``system``."""
    spec = system.spec
    n = 2 + 2 * spec.n_states + spec.n_inputs + len(system.sensor_states)
    for s in spec.states:
        if s in system.current and not system.current[s].is_zero:
            n += 1
        if s in system.process_noise and not system.process_noise[s].is_zero:
            n += 1
    return n


def peak_rows(n_samples: int, n_runs: int) -> int:
    """Most rows :func:`simulate_to_file` holds in memory at once."""
    if n_samples > CHUNK_SAMPLES:
        return CHUNK_SAMPLES
    per_batch = max(1, BATCH_ROWS // n_samples)
    return min(n_runs, per_batch) * n_samples


def _chunk_bounds(n_samples: int, chunk: int) -> list[tuple[int, int]]:
    n_chunks = math.ceil(n_samples / chunk)
    edges = np.linspace(0, n_samples, n_chunks + 1).round().astype(np.int64)
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]


def simulate_to_file(
    system: Any,
    n_samples: int,
    n_runs: int,
    seed: int | None,
    out: str | Path,
    *,
    metadata: Mapping[str, Any] | None = None,
    extra: Mapping[str | Path, str] | None = None,
    chunk_samples: int = CHUNK_SAMPLES,
    batch_rows: int = BATCH_ROWS,
) -> int:
    """Simulate ``n_runs`` runs of ``n_samples`` samples and write the log to ``out``.

    Parameters
    ----------
    system : vesselid.plant.systems.System
        The plant.
    n_samples, n_runs : int
        Samples per experiment and experiments.
    seed : int or None
        Root seed (module docstring).
    out : path
        ``.csv`` (plus its ``.json`` sidecar) or ``.parquet``.
    metadata : mapping, optional
        Extra metadata entries (e.g. ``command``).
    extra : mapping path -> str, optional
        Text files placed together with the log (the model spec): all appear or none.
    chunk_samples, batch_rows : int
        Chunk length of long runs and rows per batch of whole runs.

    Returns
    -------
    int
        Rows written.

    Raises
    ------
    SimulationDivergedError
        A run diverged; nothing is written.
    """
    from vesselid.data.logs import TrialLogWriter
    from vesselid.plant.simulate import simulate_states

    n_samples, n_runs = int(n_samples), int(n_runs)
    if n_samples < 2:
        raise VesselidError(f"need at least 2 samples, got {n_samples}")
    if n_runs < 1:
        raise VesselidError(f"need at least one experiment, got {n_runs}")
    root = np.random.SeedSequence(seed)
    run_seeds = root.spawn(n_runs)
    keys = [list(ss.spawn_key) for ss in run_seeds]
    extra_meta = dict(metadata or {})

    with TrialLogWriter(out, extra=extra) as writer:
        if n_samples <= chunk_samples:
            per_batch = max(1, batch_rows // n_samples)
            for a in range(0, n_runs, per_batch):
                b = min(a + per_batch, n_runs)
                log = system.simulate(n_samples, seed=seed, run_seeds=run_seeds[a:b]).to_log()
                if a == 0:
                    writer.metadata = {**log.metadata, "spawn_keys": keys,
                                       "experiments": n_runs, **extra_meta}
                frame = log.data
                if a:
                    frame["experiment"] += a
                writer.append(frame)
            return writer.rows

        bounds = _chunk_bounds(n_samples, chunk_samples)
        signs = np.array([system.sign(s) for s in system.spec.states], dtype=float)
        dt = system.spec.dt or 1.0
        for r, run_seed in enumerate(run_seeds):
            chunk_seeds = run_seed.spawn(len(bounds))
            fixed = {name: system.input_design(name, r) for name in system.spec.inputs}
            x0 = dict(system.x0)
            for c, (k0, k1) in enumerate(bounds):
                part = dataclasses.replace(system, inputs=fixed, x0=x0)
                sim = part.simulate(k1 - k0, seed=seed, run_seeds=[chunk_seeds[c]])
                log = sim.to_log()
                if r == 0 and c == 0:
                    writer.metadata = {
                        **log.metadata, "system": system.describe(), "spawn_keys": keys,
                        "experiments": n_runs, "samples_per_experiment": n_samples,
                        "chunk_samples": int(chunk_samples), **extra_meta}
                frame = log.data
                frame["experiment"] = np.int64(r)
                frame["time"] = (np.arange(k1 - k0) + k0) * dt
                writer.append(frame)
                # the state the recursion reaches at k1, from the last sample's signals
                u_last = np.repeat(sim.u[0, -1:], 2, axis=0)
                v_last = np.repeat(sim.q[0, -1:] * signs, 2, axis=0)
                w_last = np.repeat(sim.w[0, -1:], 2, axis=0)
                x_next = simulate_states(system.spec, u_last, x0=sim.x[0, -1], v=v_last,
                                         w=w_last)[1]
                x0 = dict(zip(system.spec.states, (float(v) for v in x_next), strict=True))
        return writer.rows
