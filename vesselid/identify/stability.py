"""Stability of an identified model: free-run boundedness and local spectral radii.

Two complementary checks of ``x(k+1) = Σ_p θ_p φ_p(x(k), u(k))`` (Definition 2.1):

* **Free run on the log's inputs** (the decisive one): each experiment is simulated
  from its measured initial state with its measured inputs (and the measured disturbance
  inside the nonlinearity when the spec has an ``[aggregate]`` relation), as the
  free-run fit does. The model is *bounded* on the log when every simulated state stays
  finite and within :data:`BOUND_FACTOR` times the measured excursion of that state
  about its experiment mean (``max |x̂ − ȳ_E| ≤ 10 · max |y − ȳ_E|``). A model that
  leaves that band on its own training inputs has no use as a simulator, whatever its
  one-step fit.
* **Linearisation about the operating points**: the Jacobian ``J(k) = ∂x(k+1)/∂x(k)``
  of the identified map at every measured sample (``∂|s|/∂s = sign(s)``) and at each
  experiment's mean operating point; its spectral radius ``ρ``. ``ρ > 1`` at the mean
  operating point means the model is locally unstable there (e.g. the course-unstable
  sway–yaw mode of a tanker); the nonlinear damping terms may still bound the free
  run, so ``ρ`` is reported, and the verdict is the free run's.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from vesselid.model.spec import ModelSpec

if TYPE_CHECKING:
    from vesselid.identify.data import RegressionData

__all__ = ["BOUND_FACTOR", "free_run_states", "jacobians", "stability_report"]

#: The per-sample spectral radii are computed on at most this many evenly spaced samples.
MAX_SAMPLES = 2048

#: A free-run state farther than this many measured excursions from the experiment's mean
#: counts as unbounded (the model is then called unstable on the log).
BOUND_FACTOR = 10.0


def free_run_states(data: RegressionData, spec: ModelSpec, theta: np.ndarray
                    ) -> list[np.ndarray]:
    """The free-run simulation of every experiment of ``data`` (one group) with ``theta``:
    from the measured initial state, with the measured inputs (and the measured current
    inside the nonlinearity with an aggregate relation); diverged samples are NaN."""
    from vesselid.identify.backend import numpy_active

    if numpy_active():  # a small log estimated without compiled kernels
        from vesselid.identify._npkernels import simulate_states
    else:
        from vesselid.plant.simulate import simulate_states

    out = []
    for s in range(data.n_segments):
        sl = data.segment(s)
        y = data.target[sl]
        v = data.sensor[sl] if data.sensor is not None else None
        out.append(simulate_states(spec, data.u[sl], theta=np.asarray(theta, float), x0=y[0],
                                   v=v, raise_on_divergence=False))
    return out


def jacobians(spec: ModelSpec, theta: np.ndarray, states: np.ndarray,
              inputs: np.ndarray) -> np.ndarray:
    """``∂x(k+1)/∂x(k)`` of the model at the operating points ``(states, inputs)``.

    Parameters
    ----------
    spec : ModelSpec
    theta : ndarray (P,)
    states : ndarray (T, n)
        Regressor signals of the states (the aggregated state where the spec has one).
    inputs : ndarray (T, m)

    Returns
    -------
    ndarray (T, n, n)
    """
    codes = spec.codes
    n = spec.n_states
    s = np.concatenate([np.asarray(states, float), np.asarray(inputs, float)], axis=1)
    n_s = s.shape[1]
    f = np.concatenate([s, np.abs(s), np.ones((s.shape[0], 1))], axis=1)
    sgn = np.sign(s)
    jac = np.zeros((s.shape[0], n, n))

    def d_factor(idx: int, j: int) -> np.ndarray | float:
        if idx == j:
            return 1.0
        if idx == n_s + j:
            return sgn[:, j]
        return 0.0

    for p in range(codes.n_params):
        a, b = int(codes.factors[p, 0]), int(codes.factors[p, 1])
        eq = int(codes.equation[p])
        for j in range(n):
            d = d_factor(a, j) * f[:, b] + f[:, a] * d_factor(b, j)
            if not np.isscalar(d) or d != 0.0:
                jac[:, eq, j] += theta[p] * d
    return jac


def _radius(jac: np.ndarray) -> np.ndarray:
    if jac.shape[1] == 1:
        return np.abs(jac[:, 0, 0])
    return np.max(np.abs(np.linalg.eigvals(jac)), axis=1)


def stability_report(data: RegressionData, spec: ModelSpec, theta: np.ndarray,
                     sims: list[np.ndarray] | None = None) -> dict[str, Any]:
    """The stability verdict of ``theta`` on ``data`` (JSON-ready; module docstring).

    Returns
    -------
    dict
        ``stable`` (bool: the free run stays bounded in every experiment),
        ``free_run_bounded``, ``unbounded_experiments`` (ids), ``bound_factor``,
        ``worst_excursion`` (largest ``max |x̂ − ȳ_E| / max |y − ȳ_E|`` over states and
        experiments; ``inf`` where the simulation diverged), ``spectral_radius``
        (``operating_point``: largest over experiments at the mean operating point;
        ``median``, ``max`` and ``share_above_one`` over the measured samples, at most
        :data:`MAX_SAMPLES` of them, evenly spaced) and
        ``sentence`` (plain words for ``summary()``).
    """
    theta = np.asarray(theta, float)
    if not np.all(np.isfinite(theta)):
        return {"stable": False, "free_run_bounded": False, "unbounded_experiments": [],
                "bound_factor": BOUND_FACTOR, "worst_excursion": float("inf"),
                "spectral_radius": None,
                "sentence": "not assessed: the estimate is not finite"}
    if sims is None:
        sims = free_run_states(data, spec, theta)
    ids = list(data.experiment_ids) or list(range(data.n_segments))
    bad: list[Any] = []
    worst = 0.0
    op_rho = []
    for s, x in enumerate(sims):
        sl = data.segment(s)
        y = data.target[sl]
        centre = y.mean(axis=0)
        scale = np.max(np.abs(y - centre), axis=0)
        scale = np.where(scale > 0, scale, np.maximum(np.abs(centre), 1.0))
        with np.errstate(invalid="ignore"):
            exc = (np.max(np.abs(x - centre), axis=0) / scale
                   if np.all(np.isfinite(x)) else np.full(spec.n_states, np.inf))
        ratio = float(np.max(exc)) if exc.size else 0.0
        worst = max(worst, ratio)
        if not ratio <= BOUND_FACTOR:
            e = ids[s] if s < len(ids) else s
            bad.append(e.item() if hasattr(e, "item") else e)
        j_op = jacobians(spec, theta, data.regsig[sl].mean(axis=0)[None],
                         data.u[sl].mean(axis=0)[None])
        op_rho.append(float(_radius(j_op)[0]))
    # per-sample radii on at most MAX_SAMPLES evenly spaced samples (the summary figures
    # of a long log do not need every sample)
    step = max(1, -(-data.regsig.shape[0] // MAX_SAMPLES))
    rho = _radius(jacobians(spec, theta, data.regsig[::step], data.u[::step]))
    rho = rho[np.isfinite(rho)]
    spectral = {
        "operating_point": float(max(op_rho)) if op_rho else float("nan"),
        "median": float(np.median(rho)) if rho.size else float("nan"),
        "max": float(np.max(rho)) if rho.size else float("nan"),
        "share_above_one": float(np.mean(rho > 1.0)) if rho.size else float("nan"),
    }
    bounded = not bad
    local = spectral["operating_point"]
    if bounded:
        sentence = (f"stable on the log: the free run stays within {worst:.2g}× the measured "
                    f"excursion (limit {BOUND_FACTOR:g}×)")
        if local > 1:
            sentence += (f"; locally unstable about the mean operating point (spectral radius "
                         f"{local:.4g} > 1), bounded by the nonlinear terms")
        else:
            sentence += f"; spectral radius at the mean operating point {local:.4g}"
    else:
        where = ", ".join(str(e) for e in bad[:5]) + (" …" if len(bad) > 5 else "")
        how = ("diverges" if not np.isfinite(worst) else
               f"leaves {BOUND_FACTOR:g}× the measured excursion ({worst:.3g}×)")
        sentence = (f"UNSTABLE: the free-run simulation on the log's inputs {how} in "
                    f"experiment(s) {where}; spectral radius at the mean operating point "
                    f"{local:.4g}")
    return {"stable": bounded, "free_run_bounded": bounded, "unbounded_experiments": bad,
            "bound_factor": BOUND_FACTOR, "worst_excursion": worst,
            "spectral_radius": spectral, "sentence": sentence}
