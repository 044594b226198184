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

Standard errors come from one more pass at the estimate: the registered estimator's own
final instruments, regressors and residuals (``equation_designs``) of each experiment
are reduced to the sums the covariance sandwich needs — ``A_E = Σ z φᵀ``, ``Σ z zᵀ``,
column norms, ``Σ ε²``, the score sum and the score lag products ``Γ_E(j)`` — from which
the unadjusted, HAC (automatic bandwidth included) and cluster covariances of
:mod:`vesselid.identify.covariance` follow as in memory (to ~1e-10). A pooled Bartlett-HAC
covariance of the IV estimates takes, as in memory, the fixed-b critical value at each
parameter's effective bandwidth ratio (:mod:`vesselid.identify.fixedb`): one more pass
sums the ratios' Bartlett products per experiment once the covariance is known. The result is an
:class:`~vesselid.identify.results.IdentificationResult`.

With a Dask ``client`` the per-experiment passes run on the cluster (one task per
experiment and iteration; the workers read the Parquet files themselves); the moments are
gathered in experiment order and summed locally, so the results equal the local ones.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.errors import IdentificationError, LogValidationError
from vesselid.identify.registry import DEFAULT_STREAM_METHOD, STREAM_METHODS
from vesselid.model.spec import ModelSpec

__all__ = ["DEFAULT_STREAM_METHOD", "STREAM_METHODS", "ParquetExperiments", "identify_stream"]


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
        #: rows of every experiment (same order as :attr:`index`), and columns of the logs
        self.rows: list[int] = []
        self.columns = 0
        for f in files:
            try:
                schema = pq.read_schema(f)
            except (OSError, ValueError) as exc:  # pyarrow.ArrowInvalid is a ValueError
                reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                raise LogValidationError(f"{f} is not a readable Parquet trial log "
                                         f"({reason})") from None
            self.columns = max(self.columns, len(schema.names))
            if "experiment" in schema.names:
                counts = (pq.read_table(f, columns=["experiment"])["experiment"].to_pandas()
                          .value_counts())
                for v in sorted(counts.index.tolist()):
                    self.index.append((f, v.item() if hasattr(v, "item") else v))
                    self.rows.append(int(counts[v]))
            else:
                self.index.append((f, None))
                self.rows.append(int(pq.ParquetFile(f).metadata.num_rows))
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

    from vesselid.data.logs import PARQUET_METADATA_KEY

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
    from vesselid.data.logs import TrialLog
    from vesselid.identify.data import from_log

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
    def target(self) -> np.ndarray:
        return self.target_max

    @property
    def target_abs_max(self) -> np.ndarray:  # _limits reads max |target| per segment
        from vesselid.identify.data import segment_abs_max

        return segment_abs_max(self.target_max, np.arange(self.n_segments + 1))

    def segment(self, s: int) -> slice:
        return slice(s, s + 1)


def _stack(parts: list) -> Any:
    from vesselid.identify.estimators import Moments

    return Moments(**{f: np.concatenate([getattr(p, f) for p in parts])
                      for f in ("zphi", "zy", "z", "phi", "y", "count", "status")})


#: Lag products ``Γ_E(j)`` of the scores kept by the covariance pass when the HAC
#: bandwidth is automatic; a bandwidth needing more lags costs one more pass.
KEEP_LAGS = 64


def _experiment_designs(path: Path, eid: Any, spec_dict: dict, method: str, theta,
                        theta_aux) -> tuple[ModelSpec, Any, list]:
    """``(spec, data, designs)`` of one experiment: its regression data and the
    estimator's final estimating equations at ``theta`` (auxiliary model ``theta_aux``),
    :meth:`Estimator.equation_designs` on this experiment alone."""
    from vesselid.identify import kernels
    from vesselid.identify.estimators import IterationResult
    from vesselid.identify.registry import get_estimator

    spec = ModelSpec.from_dict(spec_dict)
    data = _regression_data(_read_experiment(path, eid), spec)
    it = IterationResult(theta=np.asarray(theta, dtype=float)[None],
                         theta_aux=np.asarray(theta_aux, dtype=float)[None],
                         converged=np.ones(1, dtype=bool), iterations=np.zeros(1, dtype=int),
                         reason=np.array([""], dtype=object), residual=np.zeros(1),
                         oscillation=np.zeros(1, dtype=bool))
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    return spec, data, get_estimator(method).equation_designs(data, spec, it, phi, "pooled")


def _design_parts(path: Path, eid: Any, spec_dict: dict, method: str, theta, theta_aux,
                  lags: int, weights: list | None) -> dict:
    """Covariance and fit sums of one experiment (runs on a worker with Dask).

    Per state equation, from the estimator's own final instruments, regressors and
    residuals (:meth:`Estimator.equation_designs` on this experiment alone):
    ``A_E = Σ z φᵀ``, ``M_E = Σ z zᵀ``, column sums of squares, ``Σ ε²``, the score sum
    ``Σ g``, the last score, and either the lag products ``Γ_E(j) = Σ_k g(k) g(k−j)ᵀ``
    (``j ≤ lags``) or, with known kernel ``weights``, the long-run covariance ``S_E``.
    """
    from vesselid.identify.covariance import long_run_covariance
    from vesselid.identify.diagnostics import free_run_ratio

    theta = np.asarray(theta, dtype=float)
    spec, data, designs = _experiment_designs(path, eid, spec_dict, method, theta, theta_aux)
    equations = []
    for i, d in enumerate(designs):
        z, ph, r = d.z, d.phi, d.resid
        eps = r - r.mean() if d.zero_mean else r
        g = z * eps[:, None]
        n = r.shape[0]
        y = r + ph @ theta[spec.codes.equation == i]
        part = {"a": z.T @ ph, "m": z.T @ z, "n": n, "zsq": np.einsum("tk,tk->k", z, z),
                "fixed_b": bool(d.fixed_b),
                "psq": np.einsum("tk,tk->k", ph, ph), "ee": float(eps @ eps),
                "rr": float(r @ r), "y": float(y.sum()), "yy": float(y @ y),
                "gsum": g.sum(axis=0), "last": g[-1].copy()}
        if weights is not None:
            part["s"] = long_run_covariance(g, np.asarray(weights[i]))
        else:
            k = g.shape[1]
            gam = np.zeros((lags + 1, k, k))
            for j in range(min(lags, n - 1) + 1):
                gam[j] = g[j:].T @ g[: n - j]
            part["gamma"] = gam
        equations.append(part)
    ratio, ok = free_run_ratio(data, spec, theta)
    y_all = data.target
    den = np.sum((y_all - y_all.mean(axis=0)) ** 2, axis=0)
    return {"equations": equations, "free_num": ratio**2 * den if ok else np.zeros_like(den),
            "free_den": den if ok else np.zeros_like(den), "free_ok": bool(ok)}


def _fixed_b_parts(path: Path, eid: Any, spec_dict: dict, method: str, theta, theta_aux,
                   rows: list) -> list:
    """Per state equation, this experiment's part of the effective bandwidth ratios
    ``b_p`` (:func:`vesselid.identify.fixedb.effective_b`) of a pooled estimate whose
    designs take the fixed-b critical value; ``rows[i]``: ``(A⁻¹, u, lags)`` of equation
    ``i`` (influence rows, directions ``V_{·p}/V_pp``, Bartlett lags), or None."""
    from vesselid.identify.fixedb import bartlett_cross

    _, _, designs = _experiment_designs(path, eid, spec_dict, method, theta, theta_aux)
    out = []
    for d, row in zip(designs, rows, strict=True):
        if row is None:
            out.append(None)
            continue
        infl, u, lags = row
        ph = d.phi - d.phi.mean(axis=0) if d.zero_mean else d.phi
        sums = (d.z @ np.asarray(infl).T) * (ph @ np.asarray(u))
        out.append(bartlett_cross(sums, sums, int(lags), [slice(0, sums.shape[0])]))
    return out


def _auto_bandwidth(est: Any, parts: list[dict], t_total: int, cap: float) -> float:
    """The automatic bandwidth of :func:`vesselid.identify.covariance.automatic_bandwidth`
    from summed lag products (the rule is scale free, so unscaled scores give the same)."""
    gam = sum(p["gamma"] for p in parts)
    if est.bandwidth == "andrews":
        num = np.diagonal(gam[1]).copy()
        den = np.diagonal(gam[0]) - sum(p["last"] ** 2 for p in parts)
        ok = den > 0
        if not ok.any():
            return 0.0
        rho = np.clip(num[ok] / den[ok], -0.97, 0.97)
        if est.kernel == "bartlett":
            a = np.sum(4 * rho**2 / ((1 - rho) ** 6 * (1 + rho) ** 2)) / np.sum(1 / (1 - rho) ** 4)
            s_t = 1.1447 * (a * t_total) ** (1 / 3)
        else:
            a = np.sum(4 * rho**2 / (1 - rho) ** 8) / np.sum(1 / (1 - rho) ** 4)
            s_t = (2.6614 if est.kernel == "parzen" else 1.3221) * (a * t_total) ** (1 / 5)
        b = s_t if est.kernel == "qs" else max(s_t - 1.0, 0.0)
        return float(min(b, cap))
    q, c, n_exp = {"bartlett": (1, 1.1447, 2 / 9), "parzen": (2, 2.6614, 4 / 25),
                   "qs": (2, 1.3221, 2 / 25)}[est.kernel]
    n = math.ceil(4 * (t_total / 100) ** n_exp)
    if gam.shape[1] > 1:
        scale = np.sqrt(np.diagonal(gam[0]) / t_total)
        scale[scale == 0] = 1.0
        gam = gam / np.outer(scale, scale)
    sig = gam[: n + 1].sum(axis=(1, 2)) / t_total
    s0 = sig[0] + 2 * sig[1:].sum()
    sq = 2 * np.sum(np.arange(1, n + 1) ** q * sig[1:])
    if s0 == 0:
        return 0.0
    gamma = c * ((sq / s0) ** 2) ** (1 / (2 * q + 1))
    return float(min(math.ceil(gamma * t_total ** (1 / (2 * q + 1))), cap))


def _pilot_lags(est: Any, t_total: int) -> int:
    if getattr(est, "name", "") != "hac" or not isinstance(est.bandwidth, str):
        return 0
    if est.bandwidth == "andrews":
        return 1
    n_exp = {"bartlett": 2 / 9, "parzen": 4 / 25, "qs": 2 / 25}[est.kernel]
    return math.ceil(4 * (t_total / 100) ** n_exp)


def _sandwich(parts: list[dict], meat: list[np.ndarray], combine: str) -> np.ndarray:
    """The IV sandwich of one equation from per-experiment sums, on column-equilibrated
    instruments and regressors, as
    :meth:`vesselid.identify.covariance.CovarianceEstimator.estimate` forms it: pooled
    ``A_Σ⁻¹ (Σ_E S_E) A_Σ⁻ᵀ``; stacked ``H⁻¹ (Σ_E G_E S_E G_Eᵀ) H⁻ᵀ`` in its QR form."""
    from vesselid.identify.covariance import sandwich_from_sums
    from vesselid.identify.linalg import stacked_row_weights

    def scale(key: str) -> np.ndarray:
        s = np.sqrt(sum(p[key] for p in parts))
        return np.where((s > 0) & np.isfinite(s), s, 1.0)

    zs, ps = scale("zsq"), scale("psq")
    a_list = [p["a"] / np.outer(zs, ps) for p in parts]
    s_list = [m / np.outer(zs, zs) for m in meat]
    row_weight = None
    if combine == "stacked" and len(parts) > 1:
        w_row = stacked_row_weights(np.stack([p["a"] / max(p["n"], 1) for p in parts]))
        row_weight = w_row * zs**2
    cov = sandwich_from_sums(a_list, s_list, [p["n"] for p in parts], row_weight=row_weight)
    if not np.all(np.isfinite(cov)):
        return cov
    return cov / np.outer(ps, ps)


def _fixed_b_scaling(est: Any, parts: list[dict], bandwidths: list[float], combine: str,
                     cov: np.ndarray, blocks: np.ndarray) -> list | None:
    """``(A⁻¹, u, lags)`` per equation where the in-memory covariance would take the
    fixed-b critical value (designs that ask for it, pooled, Bartlett HAC; None for an
    equation whose covariance is not finite), or None where it does not apply."""
    if not (getattr(est, "name", "") == "hac" and est.fixed_b_applies(combine)
            and len(bandwidths) == len(blocks) - 1
            and all(e["fixed_b"] for p in parts for e in p["equations"])):
        return None
    rows: list = []
    for i, bw in enumerate(bandwidths):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        c = cov[sl, sl]
        try:
            infl = np.linalg.inv(sum(p["equations"][i]["a"] for p in parts))
        except np.linalg.LinAlgError:
            infl = None
        if infl is None or not (np.all(np.isfinite(c)) and np.all(np.isfinite(infl))):
            rows.append(None)
            continue
        from vesselid.identify.fixedb import influence_directions

        u, _ = influence_directions(c)
        rows.append((infl, u, math.floor(bw)))
    return rows


def _scale_to_fixed_b(cov: np.ndarray, blocks: np.ndarray, rows: list, b_parts: list,
                      config: dict) -> None:
    """Scale each equation's block of ``cov`` (in place) by ``q(b_p)/1.96``, the ratios
    summed over the experiments (:func:`_fixed_b_parts`); ``config`` gets them as the
    in-memory covariance reports them."""
    from vesselid.identify.fixedb import critical_scaling, influence_directions

    eff, crit = [], []
    for i, row in enumerate(rows):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        if row is None:
            continue
        _, ok = influence_directions(cov[sl, sl])
        b = sum(p[i] for p in b_parts)
        b = np.where(ok & np.isfinite(b), b, 0.0)
        q, scale = critical_scaling(b)
        cov[sl, sl] *= np.outer(scale, scale)
        eff.extend(float(x) for x in b)
        crit.extend(float(x) for x in q)
    if crit:
        config["effective_b"], config["critical_value"] = eff, crit


def _lagged_meat(parts: list[dict], weights: np.ndarray) -> list[np.ndarray]:
    out = []
    for p in parts:
        gam = p["gamma"]
        s_e = weights[0] * gam[0]
        for j in range(1, min(len(weights) - 1, p["n"] - 1, gam.shape[0] - 1) + 1):
            if weights[j] != 0:
                s_e = s_e + weights[j] * (gam[j] + gam[j].T)
        out.append(s_e)
    return out


def identify_stream(
    source: ParquetExperiments | str | Path | Sequence[str | Path],
    spec: ModelSpec | None = None,
    method: str = DEFAULT_STREAM_METHOD,
    *,
    combine: str = "pooled",
    cov_type: str | None = None,
    cov_config: dict | None = None,
    max_iter: int = 100,
    tol: float = 1e-9,
    limit_factor: float = 1e3,
    client: Any | None = None,
) -> Any:
    """Identify from Parquet logs experiment by experiment (bounded memory).

    Parameters
    ----------
    source : ParquetExperiments or path(s)
    spec : ModelSpec, optional
        Default: the spec in the first file's metadata.
    method : {"ls", "iv", "iv-zero-mean"}
        Default ``"iv-zero-mean"`` (:data:`DEFAULT_STREAM_METHOD`); other registered
        methods are refused with the reason.
    combine : {"pooled", "stacked"}
    cov_type, cov_config
        Covariance estimator and options as :func:`vesselid.identify.identify`
        (default: the package default, HAC): ``unadjusted``, ``hac`` (any kernel, fixed
        or automatic bandwidth; not pre-whitened) and ``cluster``.
    max_iter, tol, limit_factor
        As the in-memory refined IV.
    client : dask.distributed.Client, optional
        Run the per-experiment passes on a Dask cluster.

    Returns
    -------
    IdentificationResult
        The estimates and covariance of :func:`vesselid.identify.identify` with the same
        method on the concatenated log (to rounding), with ``summary()``, ``export()``
        and ``to_control()``. Per-sample outputs are not kept: ``residuals`` is empty and
        the diagnostics hold the streamed ones (instrument condition, one-step and
        free-run fit, ``passes``), not the design margins or specification tests.

    Notes
    -----
    Passes over the data: one for the LS moments, one per refined-IV iteration, one for
    the covariance (it also accumulates the score lag products ``Γ_E(j)``, ``j ≤``
    :data:`KEEP_LAGS`, from which an automatic HAC bandwidth and the long-run covariance
    follow), and one more only when the chosen bandwidth needs more lags.
    """
    import warnings

    from vesselid.errors import ConvergenceWarning
    from vesselid.identify import covariance_api, kernels
    from vesselid.identify.covariance import get_covariance_estimator, kernel_weights
    from vesselid.identify.estimators import STOP_START_DIVERGED, refined_iv, solve_moments
    from vesselid.identify.linalg import condition_number
    from vesselid.identify.registry import get_estimator
    from vesselid.identify.results import IdentificationResult

    if method not in STREAM_METHODS:
        raise IdentificationError(
            f"streamed identification supports methods {list(STREAM_METHODS)}, not "
            f"{method!r} (its estimate is not a sum over experiments); use one of them or "
            "identify in memory")
    if combine not in ("pooled", "stacked"):
        raise IdentificationError(f"unknown combine {combine!r}; choose from "
                                  "['pooled', 'stacked']")
    cov_name, _ = covariance_api.resolve(cov_type, cov_config)  # validates name and options
    est = get_covariance_estimator(cov_name, **dict(cov_config or {}))
    if getattr(est, "prewhiten", False):
        raise IdentificationError("streamed identification does not pre-whiten the HAC "
                                  "scores (prewhiten=True); identify in memory")
    src = source if isinstance(source, ParquetExperiments) else ParquetExperiments(source)
    spec = spec or src.spec
    if spec is None:
        raise IdentificationError("the Parquet logs carry no model spec; pass spec=")
    spec_dict = spec.to_dict()
    passes = 0

    def run(fn, **kw):
        nonlocal passes
        passes += 1
        if client is None:
            return [fn(f, e, **kw) for f, e in src.index]
        futures = client.map(fn, [f for f, _ in src.index], [e for _, e in src.index],
                             pure=False, **kw)
        return client.gather(futures)

    def all_moments(theta, mode=None):
        return _stack(run(_experiment_moments, spec_dict=spec_dict, theta=theta,
                          limit_factor=limit_factor, mode=mode))

    mom_ls = all_moments(None)
    n_seg = len(src)
    # per-experiment max |target| for the auxiliary-model divergence limits
    target_max = np.zeros((n_seg, spec.n_states))
    stand_in = _Stacked(n_seg, target_max)
    theta_ls, ok = solve_moments(mom_ls, stand_in, spec, combine=combine)
    if not ok[0]:
        raise IdentificationError("the streamed least-squares equations are singular "
                                  "(collinear regressors or too little excitation)")
    n_samples = int(mom_ls.count.sum() + n_seg)
    warn_msgs: list[str] = []
    start = None
    if method == "ls":
        theta, theta_aux = theta_ls[0], theta_ls[0]
        converged, iterations, reason = True, 0, "closed form"
    else:
        def moment_source(theta, active, out, limits):
            mom = all_moments(np.nan_to_num(theta[0]))
            for f in ("zphi", "zy", "z", "phi", "y", "count", "status"):
                getattr(out, f)[...] = getattr(mom, f)
            return out

        zero_mean = method == "iv-zero-mean"
        it = refined_iv(stand_in, spec, theta_ls, zero_mean=zero_mean,
                        combine=combine, max_iter=max_iter, tol=tol,
                        limit_factor=limit_factor, moment_source=moment_source)
        start = "ls"
        if it.reason[0] == STOP_START_DIVERGED:
            # as the in-memory estimator: the LS model's simulation diverges, so start from
            # basic IV with delayed measurements as instruments (no simulation needed)
            theta_lag, ok_lag = solve_moments(all_moments(None, kernels.MODE_LAGGED),
                                              stand_in, spec, zero_mean=zero_mean,
                                              combine=combine)
            if ok_lag[0]:
                it = refined_iv(stand_in, spec, theta_lag, zero_mean=zero_mean,
                                combine=combine, max_iter=max_iter, tol=tol,
                                limit_factor=limit_factor, moment_source=moment_source)
                start = "lagged-iv"
        theta, theta_aux = it.theta[0], it.theta_aux[0]
        if not np.all(np.isfinite(theta)):
            tried = ("the LS estimate and basic IV with delayed measurements"
                     if start == "lagged-iv" else "the LS estimate")
            raise IdentificationError(f"{method}: {it.reason[0]} (starts tried: {tried}); no "
                                      "instrument could be formed")
        converged, iterations, reason = (bool(it.converged[0]), int(it.iterations[0]),
                                         str(it.reason[0]))
        if not converged:
            warn_msgs.append(f"refined IV did not converge ({reason}, {iterations} "
                             f"iterations, fixed-point residual {it.residual[0]:.3g}); "
                             "returning the IV estimate of the best iterate")

    # covariance pass
    counts = mom_ls.count.astype(int)
    t_total, longest = int(counts.sum()), int(counts.max())
    cap = float(max(int(counts.min()) - 1, 0))
    fixed = est.name == "hac" and not isinstance(est.bandwidth, str)
    weights = None
    if fixed:
        n_lags = (longest - 1 if est.kernel == "qs"
                  else min(math.floor(est.bandwidth) + 1, longest - 1))
        weights = [kernel_weights(est.kernel, est.bandwidth, n_lags)] * spec.n_states
    lags = max(_pilot_lags(est, t_total), KEEP_LAGS) if est.name == "hac" and not fixed else 0
    parts = run(_design_parts, spec_dict=spec_dict, method=method, theta=theta,
                theta_aux=theta_aux, lags=lags, weights=weights)
    blocks = np.concatenate([[0], np.cumsum([len(spec.equations[s]) for s in spec.states])])
    cov = np.zeros((spec.n_params, spec.n_params))
    cond: dict[str, float] = {}
    fit_one: dict[str, float] = {}
    config: dict[str, Any] = dict(est.config())
    second: list[int] = []
    bandwidths: list[float] = []
    meats: list[list[np.ndarray] | None] = []
    for i in range(spec.n_states):
        eq_parts = [p["equations"][i] for p in parts]
        if est.name == "unadjusted":
            sig = sum(p["ee"] for p in eq_parts) / sum(p["n"] for p in eq_parts)
            meats.append([p["m"] * sig for p in eq_parts])
        elif est.name == "cluster":
            if n_seg < 2:
                raise IdentificationError("cov_type 'cluster' needs at least two experiments")
            meats.append([np.outer(p["gsum"], p["gsum"]) for p in eq_parts])
            config["clusters"] = n_seg
        elif fixed:
            meats.append([p["s"] for p in eq_parts])
            bandwidths.append(float(est.bandwidth))
        else:
            bw = _auto_bandwidth(est, eq_parts, t_total, cap)
            bandwidths.append(bw)
            n_lags = (longest - 1 if est.kernel == "qs" else min(math.floor(bw) + 1, longest - 1))
            if n_lags <= lags:
                meats.append(_lagged_meat(eq_parts, kernel_weights(est.kernel, bw, n_lags)))
            else:
                meats.append(None)
                second.append(i)
    if second:  # the bandwidth needs more lags than were kept: one more pass
        w_all = []
        for i in range(spec.n_states):
            bw = bandwidths[i]
            n_lags = (longest - 1 if est.kernel == "qs" else min(math.floor(bw) + 1, longest - 1))
            w_all.append(kernel_weights(est.kernel, bw, n_lags))
        again = run(_design_parts, spec_dict=spec_dict, method=method, theta=theta,
                    theta_aux=theta_aux, lags=0, weights=w_all)
        for i in second:
            meats[i] = [p["equations"][i]["s"] for p in again]
    for i, s in enumerate(spec.states):
        eq_parts = [p["equations"][i] for p in parts]
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        cov[sl, sl] = _sandwich(eq_parts, meats[i], combine)
        cond[s] = float(condition_number(sum(p["a"] for p in eq_parts)))
        n_i = sum(p["n"] for p in eq_parts)
        ysum = sum(p["y"] for p in eq_parts)
        den = sum(p["yy"] for p in eq_parts) - ysum**2 / n_i
        rr = sum(p["rr"] for p in eq_parts)
        fit_one[s] = float(100 * (1 - np.sqrt(rr / den))) if den > 0 else float("nan")
    fixed_b = _fixed_b_scaling(est, parts, bandwidths, combine, cov, blocks)
    if fixed_b is not None:  # one more pass: the effective bandwidth ratios
        config["fixed_b"] = bool(est.fixed_b)
        if est.fixed_b:
            b_parts = run(_fixed_b_parts, spec_dict=spec_dict, method=method, theta=theta,
                          theta_aux=theta_aux, rows=fixed_b)
            _scale_to_fixed_b(cov, blocks, fixed_b, b_parts, config)
    if bandwidths:
        config["bandwidth"] = bandwidths[0] if len(set(bandwidths)) == 1 else bandwidths
    label = est.label({**config, "bandwidth": bandwidths[0]} if bandwidths else config)
    if len(set(bandwidths)) > 1:
        label = label.replace(f"bandwidth {bandwidths[0]:.3g}", "bandwidth "
                              + "/".join(f"{b:.3g}" for b in bandwidths))
    if config.get("fixed_b") and "critical_value" in config:
        label += ("; standard errors scaled to the fixed-b (Kiefer-Vogelsang 2005) 95 % "
                  "critical value at the effective bandwidth ratio")
    num = sum(p["free_num"] for p in parts)
    den = sum(p["free_den"] for p in parts)
    with np.errstate(divide="ignore", invalid="ignore"):
        fit_free = {s: float(100 * (1 - np.sqrt(num[i] / den[i])))
                    for i, s in enumerate(spec.states)}
    if not all(p["free_ok"] for p in parts):
        warn_msgs.append("free-run simulation of the estimated model diverged")
    if not np.all(np.isfinite(cov)):
        warn_msgs.append("the covariance of the estimates could not be computed (singular "
                         "instrument or moment matrix); standard errors are reported as null")
    for msg in warn_msgs:
        warnings.warn(msg, ConvergenceWarning, stacklevel=2)
    index = spec.param_index
    diagnostics = {
        "combine": combine, "cov_type": cov_name, "cov_label": label, "cov_config": config,
        "target": "measured", "instrument_condition": cond, "fit_one_step": fit_one,
        "fit_free_run": fit_free, "start": start, "streamed": True, "passes": passes,
        **({} if method == "ls" else {
            "instruments": "simulated (auxiliary model)"
            + (", zero-mean per experiment" if method == "iv-zero-mean" else "")}),
        "warnings": warn_msgs,
    }
    return IdentificationResult(
        method=method, spec=spec, params=pd.Series(theta, index=index, name="estimate"),
        cov=pd.DataFrame(cov, index=index, columns=index),
        residuals=pd.DataFrame(columns=list(spec.states), dtype=float),
        converged=converged, iterations=iterations, stop_reason=reason,
        n_samples=n_samples, n_experiments=n_seg, diagnostics=diagnostics,
        label=get_estimator(method).label + " — streamed")
