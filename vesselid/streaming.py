"""Identification of logs larger than memory: Parquet experiments streamed, moments summed.

The LS and IV estimates depend on the data only through per-experiment sums (the moments
of :func:`vesselid.identify.estimators.compute_moments`: ``Σ ζφᵀ``, ``Σ ζy``, ``Σ ζ``,
``Σ φ``, ``Σ y``, counts). :func:`identify_stream` therefore reads one experiment at a
time from a directory (or list) of Parquet trial logs, accumulates its moments with the
same compiled kernel the in-memory estimator uses, and solves the same equations
(:func:`~vesselid.identify.estimators.solve_moments`). The refined IV iteration
(:func:`~vesselid.identify.estimators.refined_iv`, unchanged: step control, best iterate)
needs the instruments simulated from the latest estimate, i.e. one sequential pass per
experiment per iteration; it gets its moments from the stream through its
``moment_source`` hook. Memory is bounded by the largest experiment.

With a Dask ``client`` the per-experiment passes run on the cluster (one task per
experiment and iteration; the workers read the Parquet files themselves); the moments are
gathered in experiment order and summed locally, so the results equal the local ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.errors import IdentificationError, LogValidationError
from vesselid.model import ModelSpec

__all__ = ["ParquetExperiments", "StreamResult", "identify_stream"]


class ParquetExperiments:
    """The experiments of one or more Parquet trial logs, read one at a time.

    Parameters
    ----------
    paths : path or sequence of paths
        Parquet files or directories of them (``*.parquet``, ``*.pq``, sorted by name).
        Each file's ``experiment`` column (absent: one experiment) defines its
        experiments; only that column is read to build the index.
    """

    def __init__(self, paths: str | Path | Sequence[str | Path]) -> None:
        import pyarrow.parquet as pq

        if isinstance(paths, str | Path):
            paths = [paths]
        files: list[Path] = []
        for p in map(Path, paths):
            if p.is_dir():
                files += sorted(x for x in p.iterdir() if x.suffix.lower() in (".parquet", ".pq"))
            elif p.is_file():
                files.append(p)
            else:
                raise LogValidationError(f"{p} does not exist")
        if not files:
            raise LogValidationError("no Parquet trial logs found")
        self.files = files
        self.index: list[tuple[Path, Any]] = []
        for f in files:
            schema = pq.read_schema(f)
            if "experiment" in schema.names:
                ids = pd.unique(pq.read_table(f, columns=["experiment"])["experiment"]
                                .to_numpy())
                self.index += [(f, v.item() if hasattr(v, "item") else v)
                               for v in sorted(ids.tolist())]
            else:
                self.index.append((f, None))
        self.metadata = _metadata(files[0])

    @property
    def spec(self) -> ModelSpec | None:
        raw = self.metadata.get("spec")
        return ModelSpec.from_dict(raw) if raw else None

    def __len__(self) -> int:
        return len(self.index)

    def read(self, i: int) -> pd.DataFrame:
        """Experiment ``i`` as a DataFrame (only its rows are materialised)."""
        return _read_experiment(*self.index[i])


def _metadata(path: Path) -> dict:
    import json

    import pyarrow.parquet as pq

    from vesselid.logs import PARQUET_METADATA_KEY

    raw = (pq.read_schema(path).metadata or {}).get(PARQUET_METADATA_KEY)
    if raw is None:
        return {}
    env = json.loads(raw.decode("utf-8"))
    return env.get("metadata", env) if isinstance(env, dict) else {}


def _read_experiment(path: Path, eid: Any) -> pd.DataFrame:
    import pyarrow.parquet as pq

    if eid is None:
        return pq.read_table(path).to_pandas()
    return pq.read_table(path, filters=[("experiment", "=", eid)]).to_pandas()


def _regression_data(frame: pd.DataFrame, spec: ModelSpec):
    from vesselid.identify.data import from_log
    from vesselid.logs import TrialLog

    frame = frame.drop(columns=["experiment"], errors="ignore")
    data, _ = from_log(TrialLog(frame.reset_index(drop=True)), spec)
    return data


def _experiment_moments(path: Path, eid: Any, spec_dict: dict, theta, limit_factor: float,
                        mode: int | None = None):
    """Moments of one experiment (runs on a worker with Dask)."""
    from vesselid.identify.estimators import compute_moments

    spec = ModelSpec.from_dict(spec_dict)
    data = _regression_data(_read_experiment(path, eid), spec)
    th = None if theta is None else np.atleast_2d(np.asarray(theta, dtype=float))
    return compute_moments(data, spec, th, limit_factor=limit_factor, mode=mode)


@dataclass
class _Stacked:
    """What the moment solvers read from RegressionData, for S streamed experiments."""

    n_segments: int
    target_max: np.ndarray

    n_groups: int = 1

    @property
    def group(self) -> np.ndarray:
        return np.zeros(self.n_segments, dtype=np.int64)

    @property
    def target(self) -> np.ndarray:  # _limits reads max |target| per segment
        return self.target_max

    def segment(self, s: int) -> slice:
        return slice(s, s + 1)


def _stack(parts: list) -> Any:
    from vesselid.identify.estimators import Moments

    return Moments(**{f: np.concatenate([getattr(p, f) for p in parts])
                      for f in ("zphi", "zy", "z", "phi", "y", "count", "status")})


@dataclass
class StreamResult:
    """Estimates from :func:`identify_stream`.

    Attributes
    ----------
    params : Series
        Indexed by ``(equation, term)`` as :class:`IdentificationResult.params`.
    converged, iterations, stop_reason
        Refined IV iteration outcome (LS: closed form).
    n_experiments, n_samples : int
    passes : int
        Sequential passes over the data.
    """

    method: str
    spec: ModelSpec
    params: pd.Series
    converged: bool
    iterations: int
    stop_reason: str
    n_experiments: int
    n_samples: int
    passes: int


def identify_stream(
    source: ParquetExperiments | str | Path | Sequence[str | Path],
    spec: ModelSpec | None = None,
    method: str = "iv-zero-mean",
    *,
    combine: str = "pooled",
    max_iter: int = 100,
    tol: float = 1e-9,
    limit_factor: float = 1e3,
    client: Any | None = None,
) -> StreamResult:
    """Identify from Parquet logs experiment by experiment (bounded memory).

    Parameters
    ----------
    source : ParquetExperiments or path(s)
    spec : ModelSpec, optional
        Default: the spec in the first file's metadata.
    method : {"ls", "iv", "iv-zero-mean"}
    combine : {"pooled", "stacked"}
    max_iter, tol, limit_factor
        As the in-memory refined IV.
    client : dask.distributed.Client, optional
        Run the per-experiment passes on a Dask cluster.

    Returns
    -------
    StreamResult
        The same estimates as :func:`vesselid.identify.identify` with the same method on
        the concatenated log (to rounding).
    """
    from vesselid.identify.estimators import refined_iv, solve_moments

    src = source if isinstance(source, ParquetExperiments) else ParquetExperiments(source)
    spec = spec or src.spec
    if spec is None:
        raise IdentificationError("the Parquet logs carry no model spec; pass spec=")
    if method not in ("ls", "iv", "iv-zero-mean"):
        raise IdentificationError(f"streaming supports ls, iv and iv-zero-mean, not {method!r}")
    spec_dict = spec.to_dict()
    passes = 0

    def all_moments(theta):
        nonlocal passes
        passes += 1
        if client is None:
            parts = [_experiment_moments(f, e, spec_dict, theta, limit_factor)
                     for f, e in src.index]
        else:
            futures = client.map(_experiment_moments, [f for f, _ in src.index],
                                 [e for _, e in src.index], spec_dict=spec_dict, theta=theta,
                                 limit_factor=limit_factor, pure=False)
            parts = client.gather(futures)
        return _stack(parts)

    mom_ls = all_moments(None)
    n_seg = len(src)
    # per-experiment max |target| for the auxiliary-model divergence limits
    target_max = np.zeros((n_seg, spec.n_states))
    stand_in = _Stacked(n_seg, target_max)
    theta_ls, ok = solve_moments(mom_ls, stand_in, spec, combine=combine)
    n_samples = int(mom_ls.count.sum() + n_seg)
    index = spec.param_index
    if method == "ls" or not ok[0]:
        return StreamResult(method, spec, pd.Series(theta_ls[0], index=index, name="estimate"),
                            bool(ok[0]), 0, "closed form" if ok[0] else "singular",
                            n_seg, n_samples, passes)

    def moment_source(theta, active, out, limits):
        mom = all_moments(np.nan_to_num(theta[0]))
        for f in ("zphi", "zy", "z", "phi", "y", "count", "status"):
            getattr(out, f)[...] = getattr(mom, f)
        return out

    it = refined_iv(stand_in, spec, theta_ls, zero_mean=method == "iv-zero-mean",
                    combine=combine, max_iter=max_iter, tol=tol, limit_factor=limit_factor,
                    moment_source=moment_source)
    return StreamResult(method, spec, pd.Series(it.theta[0], index=index, name="estimate"),
                        bool(it.converged[0]), int(it.iterations[0]), str(it.reason[0]),
                        n_seg, n_samples, passes)
