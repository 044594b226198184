"""Identification in closed loop: the closed-loop refined IV and the feedback test.

Closed-loop refined IV (``--method cl-iv``)
-------------------------------------------
Under feedback the logged input carries the noise (``u(k)`` reacts to ``y(k) = x(k) +
e(k)``), so instruments simulated from it (the paper's auxiliary model, Lemma 3.1) violate
A6. Following the refined IV for closed loops of Gilson & Van den Hof (2005), the
instruments are built from the *external* signals only: the closed loop itself is
simulated noise-free with the current estimate θ̂ and the known controller, driven by
the reference ``r`` and the dither ``d`` alone,

    x̂(k+1) = Φᵀ([x̂(k); û(k)]) θ̂,   û(k) = C(r(k) − x̂(k)) + d(k),

and the instruments are the model's own (modulus) regressors of that simulation,
``ζ(k) = φ(x̂(k−1), û(k−1))``, centred per experiment (A7). They depend on ``r`` and ``d``
only, which are independent of the disturbances ``v``, ``w``, ``e``: (5b) holds term by
term exactly as in the proof of Lemma 3.1 (the input now appears only among the
regressors, whose noise the zero-mean instruments average out under A10), and (5a) holds
as long as the reference and dither excite the loop.

Sensor noise in the modulus regressors: ``E[(x+e)|x+e| | x] = x|x| + σ²·sign(x)`` away
from zero, a constant that the zero-mean instruments remove only while the sign of ``x``
is fixed (A10). A loop that turns drives the sway velocity and the yaw rate through zero
within an experiment (the sway–yaw coupling of a yaw-rate step), so ``σ²θ·sign(x(k))``
correlates with the instruments and biases the estimate by an amount that does not
shrink with the trial's length. When the log carries its sensor noise
(``metadata["sensor_noise_std"]`` or ``identify(..., sensor_noise={...})``) the
regressors are the corrected scores of :mod:`vesselid.identify.eiv` (``y|y| − σ²
sign(y)``, ``y² − σ²``), which remove that term. What they leave is confined to a few
``σ`` around zero speed: ``E[h(x+e) | x] − x|x|`` is a bump of at most ``0.2σ²``
(:func:`~vesselid.identify.eiv.signed_square_bias`), and the modulus factor ``|z+e|`` of
a product of two different states (``v·|r|``, ``r·|v|``) has no conditionally unbiased
score (``|z|`` is not analytic at 0) and keeps ``2σ(φ(t) − tQ(t))``
(:func:`~vesselid.identify.eiv.modulus_bias`). They are left as they are: on the
CyberShip II velocity loops, where the sway velocity and yaw rate cross zero many times,
they bias the estimate by at most 0.003 Monte Carlo sd and the whole bias of ``cl-iv``
(with the effect of iterating the auxiliary model on the same log, up to 0.008 sd) stays
below 0.0061 sd on every parameter — measured with the simulation's noise as a control
variate (``scripts/closed_loop_bias_decomposition.py``, the closed-form conditional means
of :func:`~vesselid.identify.eiv.regressor_error_mean`). The estimate is iterated to the
fixed point ``θ = T(θ)`` with the step control of :func:`~vesselid.identify.estimators.
refined_iv`, from least squares. Covariance: the package's ``cov_type`` (default HAC) on
the final instruments, regressors and residuals; with the Bartlett HAC each standard error
is scaled to the fixed-b critical value at its effective bandwidth ratio
(:mod:`vesselid.identify.fixedb`; ``cov_config={"fixed_b": False}`` turns it off).

The log names its controller and external signals in ``metadata["closed_loop"]``
(:func:`vesselid.plant.closedloop.closed_loop_metadata`, written by
:func:`vesselid.plant.closedloop.simulate_closed_loop` and the environment recorder).

Feedback test
-------------
:func:`vesselid.identify.loop.feedback_test` (re-exported here) asks whether the input is
correlated with past output errors; every open-loop estimator runs it in ``fit`` and warns
(``ClosedLoopWarning``) when it rejects or the log declares closed loop.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from vesselid.errors import IdentificationError
from vesselid.identify.backend import kernels
from vesselid.identify.base import Estimator, square_designs
from vesselid.identify.data import RegressionData
from vesselid.identify.eiv import corrected_regressor_matrix
from vesselid.identify.estimators import (
    STOP_START_DIVERGED,
    IterationResult,
    Moments,
    compute_moments,
    least_squares,
    moments_from_matrices,
    refined_iv,
    solve_moments,
)
from vesselid.identify.loop import (
    ClosedLoopSignals,
    FeedbackTest,
    closed_loop_instruments,
    closed_loop_signals,
    feedback_test,
)
from vesselid.identify.options import FitOptions
from vesselid.model.spec import ModelSpec

__all__ = ["ClosedLoopIV", "ClosedLoopSignals", "FeedbackTest", "closed_loop_signals",
           "feedback_test"]


class ClosedLoopIV(Estimator):
    """Closed-loop refined IV (module docstring): instruments from the reference and dither
    through the simulated closed loop, zero-mean per experiment, HAC intervals.

    Needs a log with ``metadata["closed_loop"]`` (controller, reference, dither).
    """

    name: ClassVar[str] = "cl-iv"
    label: ClassVar[str] = ("closed-loop refined IV (instruments: reference and dither "
                            "through the simulated closed loop)")
    short: ClassVar[str] = "CL-IV"
    plot_label: ClassVar[str] = "closed-loop IV"
    multi_experiment: ClassVar[tuple[str, ...]] = ("pooled", "stacked")
    open_loop: ClassVar[bool] = False
    #: regressors with the corrected score of the modulus terms when the log carries its
    #: sensor noise (module docstring: a loop drives sway and yaw through zero)
    corrects_sensor_noise: ClassVar[bool] = True

    def __init__(self) -> None:
        super().__init__()
        self._signals: ClosedLoopSignals | None = None

    def with_signals(self, signals: ClosedLoopSignals) -> ClosedLoopIV:
        """A copy bound to one log's external signals."""
        est = copy.copy(self)
        est._signals = signals
        return est

    def fit(self, log: Any, spec: ModelSpec | None = None,
            options: FitOptions | Mapping[str, Any] | None = None, **overrides: Any):
        options = FitOptions.of(options, **overrides)
        if self._signals is not None:
            return Estimator.fit(self, log, spec, options)
        if options.instruments is not None:
            raise IdentificationError("method 'cl-iv' builds its own instruments from the "
                                      "reference and dither")
        from vesselid.data.logs import TrialLog

        log = log if isinstance(log, TrialLog) else TrialLog(log)
        signals = closed_loop_signals(log, spec or log.spec)
        return Estimator.fit(self.with_signals(signals), log, spec, options)

    def instruments(self, data: RegressionData, spec: ModelSpec, theta: np.ndarray,
                    limits: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The instruments of auxiliary model ``theta`` (rows as the regressor matrix; NaN
        of a diverged simulation set to 0) and the per-segment status (0 ok, 1 diverged):
        :func:`~vesselid.identify.loop.closed_loop_instruments` of the bound signals."""
        z, status = closed_loop_instruments(data, spec, theta, self._require(), limits)
        return np.where(np.isfinite(z), z, 0.0), status

    def _require(self) -> ClosedLoopSignals:
        if self._signals is None:
            raise IdentificationError("method 'cl-iv' needs the log's closed-loop signals "
                                      "(call fit / identify with the log)")
        return self._signals

    def estimate_parameters(self, data: RegressionData, spec: ModelSpec, *,
                            combine: str = "pooled", theta_start: np.ndarray | None = None,
                            max_iter: int = 100, tol: float = 1e-9,
                            keep_history: bool = False) -> IterationResult:
        self._require()
        if data.n_groups != 1:
            raise IdentificationError("method 'cl-iv' estimates one parameter group at a time")
        phi = corrected_regressor_matrix(data, spec)

        def source(theta: np.ndarray, active: np.ndarray, out: Moments, limits) -> None:
            z, status = self.instruments(data, spec, np.nan_to_num(theta[0]), limits)
            mom = moments_from_matrices(data, spec, z, phi)
            for name in ("zphi", "zy", "z", "phi", "y", "count"):
                getattr(out, name)[...] = getattr(mom, name)
            out.status[...] = np.where(status == 0, kernels.AUX_OK, kernels.AUX_OK + 1)

        opts = dict(zero_mean=True, combine=combine, max_iter=max_iter, tol=tol,
                    keep_history=keep_history, moment_source=source)
        theta_ls, _ = least_squares(data, spec, combine=combine)
        start = (theta_ls if theta_start is None else
                 np.array(np.broadcast_to(np.asarray(theta_start, float), theta_ls.shape)))
        res = refined_iv(data, spec, start, **opts)
        res.start = np.array(["given" if theta_start is not None else "ls"], dtype=object)
        if theta_start is None and res.reason[0] == STOP_START_DIVERGED:
            # the LS model's closed loop diverges: start from basic IV with delayed
            # measurements (no simulation)
            mom = compute_moments(data, spec, mode=kernels.MODE_LAGGED)
            theta_lag, ok_lag = solve_moments(mom, data, spec, zero_mean=True, combine=combine)
            if ok_lag[0]:
                res = refined_iv(data, spec, theta_lag, **opts)
                res.start = np.array(["lagged-iv"], dtype=object)
        return res

    def equation_designs(self, data, spec, it, phi, combine):
        z, _ = self.instruments(data, spec, it.theta_aux[0])
        return square_designs(data, spec, z, phi, it.theta[0], zero_mean=True,
                              combine=combine, fixed_b=True)

    def describe(self, it: IterationResult) -> dict[str, Any]:
        sig = self._signals
        return {"instruments": "simulated closed loop driven by the reference and dither, "
                               "zero-mean per experiment",
                "controller": None if sig is None else sig.controller.to_dict()}


#: ``auto`` hands a log that declares a simulable loop to this estimator
#: (:meth:`Estimator.fit`; set here because the estimator subclasses the base class).
