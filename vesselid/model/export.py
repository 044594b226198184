"""Identified models out: python-control systems and reusable spec files.

* :func:`to_control` — the identified second-order modulus model as a discrete-time
  :class:`control.NonlinearIOSystem` (``x(k+1) = Φᵀ([x(k) + v(k); τ(k)]) θ̂``, eq. (1a)
  without disturbances), with named states, inputs and outputs (outputs = states). With an
  aggregate relation (paper eq. (9)) the measured sensor columns are extra inputs.
* :func:`export_model` — the spec with ``[theta0]`` = θ̂ plus an ``[estimate]`` table
  (method, standard errors, covariance, the prior θ0), written atomically; ``ModelSpec.load``
  reads it back as a spec whose θ0 is θ̂ and :func:`load_model` also returns the covariance.

python-control is an optional dependency (``pip install 'vesselid[control]'``), imported
lazily.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from vesselid.errors import ModelSpecError, VesselidError
from vesselid.model.regressors import predict
from vesselid.model.spec import ModelSpec

__all__ = ["control_signals", "export_model", "load_model", "to_control"]


def control_signals(spec: ModelSpec) -> tuple[list[str], list[str]]:
    """State and input names of the control system (inputs: the spec's, then sensors)."""
    return list(spec.states), [*spec.inputs, *spec.sensors]


def _regressor_state(spec: ModelSpec):
    """Function ``(x, u_all) -> signals`` of the aggregated state (eq. (9), Remark 4.3)."""
    n, m = spec.n_states, spec.n_inputs
    sensor_pos = {name: m + i for i, name in enumerate(spec.sensors)}
    aggs = [(spec.states.index(s), a) for s, a in spec.aggregate.items()]

    def signals(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        s = np.empty(n + m)
        s[:n] = x
        for i, a in aggs:
            y = u[sensor_pos[a.sensor]]
            s[i] = y if a.sign == 0 else x[i] + a.sign * y
        s[n:] = u[:m]
        return s

    return signals


def to_control(spec: ModelSpec, theta: Any | None = None, *, dt: float | None = None,
               name: str | None = None) -> Any:
    """The model ``x(k+1) = Φᵀ([x(k) + v(k); τ(k)]) θ`` as a python-control system.

    Parameters
    ----------
    spec : ModelSpec
        Structure (states, inputs, terms, aggregate relations, ``dt``).
    theta : array-like or Series, optional
        Parameters in spec order (default θ0 of the spec).
    dt : float, optional
        Sample time (default ``spec.dt``; required when the spec has none).
    name : str, optional
        System name (default the spec's name).

    Returns
    -------
    control.NonlinearIOSystem
        Discrete time (``dt``), states = spec states, inputs = spec inputs followed by the
        aggregate sensor columns, outputs = the states (``y = x``).

    Raises
    ------
    ModelSpecError
        No ``dt``, or a wrong number of parameters / non-finite parameters.
    ImportError
        python-control is not installed.
    """
    try:
        import control as ct
    except ImportError as exc:  # pragma: no cover - exercised without the extra
        raise ImportError("to_control needs python-control: pip install 'vesselid[control]'") \
            from exc
    dt = spec.dt if dt is None else float(dt)
    if dt is None or not (math.isfinite(dt) and dt > 0):
        raise ModelSpecError("the model has no sample time; pass dt= or set dt in the spec")
    th = spec.theta0_vector() if theta is None else spec.vector_from(theta)
    th = np.asarray(th, dtype=float)
    if th.shape != (spec.n_params,) or not np.all(np.isfinite(th)):
        raise ModelSpecError(f"theta must be {spec.n_params} finite values")
    layout = spec.codes
    signals = _regressor_state(spec)

    def update(t, x, u, params=None):
        # the numpy twin of the compiled step: same term order, agrees bitwise
        s = signals(np.asarray(x, dtype=float), np.atleast_1d(np.asarray(u, dtype=float)))
        return predict(layout, th, s)

    states, inputs = control_signals(spec)
    return ct.nlsys(update, None, states=states, inputs=inputs, outputs=list(states), dt=dt,
                    name=name or spec.name)


# ----------------------------------------------------------------------------- export
def export_model(result: Any, path: str | Path, *, source: str | None = None) -> Path:
    """Write the identified model as a spec TOML with ``[theta0]`` = θ̂ and ``[estimate]``.

    Parameters
    ----------
    result : IdentificationResult
        Provides ``spec``, ``params``, ``cov``, ``std_errors``, ``method``,
        ``n_samples``, ``n_experiments``, ``converged``.
    path : str or Path
        Output file (written atomically).
    source : str, optional
        Where the data came from (recorded).

    Returns
    -------
    Path
    """
    import tomli_w

    from vesselid.core.fileio import atomic_write_text

    spec: ModelSpec = result.spec
    theta = np.asarray(result.params, dtype=float)
    if not np.all(np.isfinite(theta)):
        raise VesselidError("the estimate holds non-finite values; nothing to export")
    data = spec.with_theta0(theta).to_dict()
    cov = np.asarray(result.cov, dtype=float)
    est: dict[str, Any] = {
        "method": str(result.method),
        "experiments": int(result.n_experiments),
        "samples": int(result.n_samples),
        "converged": bool(result.converged),
        "parameters": [f"{eq}: {term}" for eq, term in spec.param_index],
        "stderr": _per_state(spec, np.asarray(result.std_errors, dtype=float)),
        "covariance": [[float(x) for x in row] for row in cov],
    }
    if source is not None:
        est["source"] = str(source)
    if spec.theta0 is not None:
        est["theta_prior"] = _per_state(spec, spec.theta0_vector())
    data["estimate"] = est
    text = ("# identified model written by vesselid; [theta0] holds the estimate θ̂, "
            "[estimate] its uncertainty\n" + tomli_w.dumps(data))
    path = Path(path)
    atomic_write_text(path, text)
    return path


def _per_state(spec: ModelSpec, values: np.ndarray) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {}
    for (eq, _term), v in zip(spec.param_index, np.asarray(values, dtype=float), strict=True):
        out.setdefault(eq, []).append(float(v))
    return out


def load_model(path: str | Path) -> tuple[ModelSpec, np.ndarray, np.ndarray | None]:
    """Read a model written by :func:`export_model`.

    Returns
    -------
    spec : ModelSpec
        With θ0 = θ̂.
    theta : ndarray (P,)
    cov : ndarray (P, P) or None
        The covariance, when the file has one.
    """
    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover
        import tomli as tomllib
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ModelSpecError(f"cannot read model file {path}: {exc.strerror}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ModelSpecError(f"{path}: invalid TOML: {exc}") from exc
    est = data.pop("estimate", None)
    spec = ModelSpec.from_dict(data)
    theta = spec.theta0_vector() if spec.theta0 is not None else None
    if theta is None:
        raise ModelSpecError(f"{path} has no [theta0]")
    cov = None
    if isinstance(est, dict) and "covariance" in est:
        cov = np.asarray(est["covariance"], dtype=float)
        if cov.shape != (spec.n_params, spec.n_params):
            raise ModelSpecError(f"{path}: covariance must be {spec.n_params}x{spec.n_params}")
    return spec, theta, cov
