"""Estimators beyond the paper: lagged 2SLS, refined IV with a noise model (SRIV),
over-identified GMM and the automatic instrument choice.

All use the explicit-matrix core :mod:`vesselid.identify.gmm` and per-experiment
constants (zero-mean instruments), and are batched over parameter groups.

* :class:`LaggedIV` (``lagged-2sls``) — 2SLS with delayed measured regressors as
  instruments: what a generic IV user would do (linearmodels ``IV2SLS`` with a
  constant on the same rows gives the same numbers). Biased under coloured
  disturbances.
* :class:`InstrumentalGMM` — the refined iteration with instruments simulated from
  the latest estimate, optionally

  - prefiltered with an AR noise model of the equation error estimated inside the
    iteration (Young's refined IV, SRIV/RIV: target, regressors and instruments
    are filtered by ``Ĉ(q)``), and/or
  - over-identified with the lagged instruments (``combined``), two-step GMM with
    a HAC weight, with Hansen's J and the difference-in-J (C) test of the lagged
    subset;
  - ``instruments="auto"``: the combined set unless, in some equation, the C test
    rejects the lagged subset at level ``alpha`` or the colour test
    (:func:`vesselid.identify.gmm.colour_test`: does the equation error correlate with
    the past estimated sensor noise?) rejects at ``colour_alpha``; then the simulated
    set alone with the AR noise-model prefilter, or (``pem_fallback``, one-state logs
    without a disturbance sensor) the prediction-error estimator with a Gauss–Markov
    current and Gauss–Markov sensor noise as filter states. The C test alone missed coloured
    sensor noise in most runs (Gauss–Markov, time constant 20 samples, random pulses:
    41 % rejected at 1 %; the colour test 97.5 % at 5 %): its delayed measurements
    carry the signal, which drowns the small noise correlation that biases the GMM
    estimate by several standard errors. A Hausman test of GMM against the
    simulated-instrument estimate did no better than C (34 %): the simulated estimate
    is too noisy there. The result reports which set was used and why.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from vesselid.errors import IdentifiabilityWarning, IdentificationError, ParameterDriftWarning
from vesselid.identify import gmm, pem, validity
from vesselid.identify.backend import kernels, numpy_active
from vesselid.identify.base import EquationDesign, Estimator, square_designs
from vesselid.identify.data import RegressionData
from vesselid.identify.eiv import corrected_regressor_matrix
from vesselid.identify.estimators import IterationResult, estimate
from vesselid.identify.options import FitOptions
from vesselid.model.spec import ModelSpec

__all__ = ["InstrumentalGMM", "LaggedIV"]

CLOSED_FORM = "closed form"
SINGULAR = "instrument matrix singular"


def _designs_from(sol: gmm.GMMSolution, theta: np.ndarray, spec: ModelSpec,
                  fixed_b: bool = False) -> list[EquationDesign]:
    from vesselid.identify.data import block_starts

    blocks = block_starts(spec)
    out = []
    jacobians = sol.jacobians or [None] * len(sol.designs or [])
    for i, (z, phi, y, valid, w) in enumerate(sol.designs or []):
        sl = slice(int(blocks[i]), int(blocks[i + 1]))
        out.append(EquationDesign(z=z, phi=phi, resid=y - phi @ theta[sl],
                                  starts=_starts_of(valid, sol), weight=w, zero_mean=True,
                                  weight_jacobian=jacobians[i], owned=True,
                                  fixed_b=fixed_b))
    return out


def _starts_of(valid: np.ndarray, sol: gmm.GMMSolution) -> np.ndarray:
    seg = sol.segment_starts  # type: ignore[attr-defined]
    counts = [int(valid[int(seg[s]):int(seg[s + 1])].sum()) for s in range(seg.size - 1)]
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


class LaggedIV(Estimator):
    """2SLS with a constant per experiment and the measured regressors delayed one and
    two samples as instruments (basic IV; efficient on white disturbances only)."""

    name: ClassVar[str] = "lagged-2sls"
    label: ClassVar[str] = "2SLS, delayed measured regressors as instruments"
    short: ClassVar[str] = "2SLS lagged"
    plot_label: ClassVar[str] = "2SLS (lagged)"
    multi_experiment: ClassVar[tuple[str, ...]] = ("pooled",)

    def estimate_parameters(self, data: RegressionData, spec: ModelSpec, *,
                            combine: str = "pooled", theta_start: np.ndarray | None = None,
                            max_iter: int = 100, tol: float = 1e-9,
                            keep_history: bool = False) -> IterationResult:
        phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
        lagged = [gmm.lagged_regressors(data, spec, lag) for lag in gmm.LAGS]
        blocks = gmm.instrument_blocks(spec, "lagged", phi, None, lagged)
        sol = gmm.solve_equations(data, spec, phi, blocks, weight="2sls",
                                  keep_designs=keep_history and data.n_groups == 1)
        sol.segment_starts = data.starts  # type: ignore[attr-defined]
        n = data.n_groups
        return IterationResult(
            theta=sol.theta, theta_aux=sol.theta, converged=sol.ok.copy(),
            iterations=np.zeros(n, dtype=np.int64),
            reason=np.where(sol.ok, CLOSED_FORM, SINGULAR).astype(object),
            residual=np.zeros(n), oscillation=np.zeros(n, dtype=bool),
            info={"solution": sol, "instrument_set": np.full(n, "lagged", dtype=object)},
        )

    def equation_designs(self, data, spec, it, phi, combine):
        return _designs_from(it.info["solution"], it.theta[0], spec)

    def describe(self, it: IterationResult) -> dict[str, Any]:
        sol = it.info["solution"]
        return {"instruments": "lagged (measured regressors delayed 1 and 2 samples), "
                               "constant per experiment",
                "sargan_hansen_j": _jdict(sol.j[0], sol.df)}


def _chi2_sf(x: Any, df: Any) -> Any:
    """``scipy.stats.chi2.sf(x, df)`` for ``df > 0`` (identical values, ``x < 0`` -> 1)
    through ``scipy.special``: importing ``scipy.stats`` costs ~1 s of process start."""
    from vesselid.identify._special import chi2_sf

    return chi2_sf(np.maximum(x, 0.0), df)


def _jdict(j: np.ndarray, df: np.ndarray) -> list[dict[str, float]]:
    return [{"stat": float(j[i]), "df": int(df[i]),
             "pvalue": float(_chi2_sf(j[i], df[i])) if df[i] else float("nan")}
            for i in range(len(df))]


def _named(key: str) -> property:
    """A read-only property returning the instance's configured ``key`` name."""
    return property(lambda self: self._names[key])


class InstrumentalGMM(Estimator):
    """Refined IV with simulated instruments, optional AR noise-model prefilter (SRIV)
    and optional lagged over-identifying instruments (GMM), or the automatic choice.
    With the sensor noise known (``sensor_noise`` or the log's metadata) the square
    modulus regressors are corrected for it (:mod:`vesselid.identify.eiv`).

    Parameters
    ----------
    instruments : {"simulated", "combined", "auto"}
        Instrument set (see module docstring).
    noise_order : int
        Order of the AR noise model of the equation error used to prefilter target,
        regressors and instruments (0: no prefilter).
    alpha : float
        Level of the difference-in-J (C) test of the delayed instruments (``auto``).
    colour_alpha : float
        Level of the colour test (``auto``, :func:`vesselid.identify.gmm.colour_test`):
        does the equation error remember the past estimated sensor noise? The delayed
        instruments are used only when neither test rejects (Bonferroni: at most
        ``alpha + colour_alpha`` false rejections on white disturbances).
    colour_order : int
        AR order ``p`` of a whitening prefilter of the colour test (0, the default: the
        unfiltered test over :data:`vesselid.identify.gmm.COLOUR_WINDOW`, fused into the
        combined pass of the Monte Carlo path). ``p > 0``: the whitened test of
        :func:`vesselid.identify.gmm.colour_test` (noise lags
        :func:`vesselid.identify.gmm.whitened_colour_window`; ``p = 2``,
        :data:`vesselid.identify.gmm.WHITENED_COLOUR_ORDER`, is the studied one), more
        powerful at the same level (``scripts/colour_study.py`` measures size and power)
        but computed on explicit rows (batched, not fused), several times the cost of
        ``auto`` on the Monte Carlo path.
    colour_guard : float
        ``auto`` on a log the likelihood fallback applies to (``pem_fallback``, one state
        equation, no disturbance sensor, no low-pass filter) keeps the delayed instruments
        only where the colour test's p-value is at least ``colour_guard`` (a value at most
        ``colour_alpha``, 0 included: no guard); a p-value in ``[colour_alpha,
        colour_guard)`` takes the likelihood fallback with the sensor-noise model alone
        (SRIV where its fit does not converge or its Gaussian model misfits the log,
        ``guard_misfit``). Under coloured sensor noise the colour test misses some logs at
        its level, and there the delayed instruments bias the estimate by 1–3.5 standard
        errors; the default 0.2 moves most of them (Gauss–Markov sensor noise, time
        constant 20 samples, random pulses: 21 of 24 missed logs in 1000 runs). White logs
        reach the band in about 15 % of runs; the sensor-noise model nests white
        disturbances, so its estimate there is as precise as the combined one (the Table 1
        design, alternating pulses: Monte Carlo sd of ``n`` 0.01317 against 0.01331 over
        1000 runs), at the cost of its fit on those logs (:func:`_guard_band_fits`). Where
        the likelihood fallback does not apply the band keeps the delayed instruments: SRIV
        there would raise the Monte Carlo sd of ``n`` on white Table 1 logs by 14 %
        (``scripts/gate_study.py``, ``docs/guide/choosing-an-estimator.md``).
    guard_misfit : float
        In the colour-guard band the likelihood fit is kept only where its quasi-ML
        sandwich standard errors stay within this factor of its inverse-Fisher ones
        (largest ratio over the parameters; ``inf``: always kept); beyond it the Gaussian
        model misfits the log and SRIV takes it. On Student-t₃ sensor noise (the
        robustness study's heavy-tailed design, 200 runs) 2 of 30 band fits had ratios of
        3.9 and 5.0 and errors of 6.8 and 7.4 Monte Carlo sd, the other 28 at most 1.33;
        the largest ratio of any likelihood fit on Gauss–Markov sensor noise (random
        pulses, 1000 runs) was 1.53 (1 of 895 fits) and on white Table 1 logs 1.19
        (``python scripts/pem_covariance_study.py robustness:heavy-tailed --runs 200
        --auto-option guard_misfit=inf``, ``calibration:gm-sensor-random``,
        ``calibration:table1-alternating``, ``--runs 1000``).
    refine : int
        Refinement steps after the converged IV_{E{ζ}=0} iteration (each re-simulates
        the instruments from the latest estimate and re-estimates the noise model).
        The start is consistent, so one step is already asymptotically efficient for
        the chosen instruments; ``converged`` reports the IV_{E{ζ}=0} iteration.
    fallback_refine : int
        Refinement steps of the simulated-instrument fallback of ``auto`` (the AR noise
        model needs a few: one step had heavier tails under a coloured current).
    pem_fallback : bool
        ``auto`` on a one-state log without a disturbance sensor: when a test rejects
        the delayed instruments, use the prediction-error estimator with a Gauss–Markov
        current *and* Gauss–Markov sensor noise as filter states (the joint model of
        :mod:`vesselid.identify.pem`, which nests either process alone) instead of SRIV
        where its likelihood maximisation converges (SRIV elsewhere). A coloured current
        inside the modulus biases every instrument built from the input (its product with
        the modulus correlates with the input's past); the joint model does not, and it
        stays unbiased when the current and the sensor noise are coloured at once, where
        the single-current model is not (``scripts/robustness_study.py``,
        ``docs/guide/choosing-an-estimator.md``).
    pem_level : float
        ``auto`` uses that likelihood fallback only where a test rejects at ``pem_level``
        times its level (C test below ``pem_level · alpha`` or colour test below
        ``pem_level · colour_alpha``) or the colour test's p-value lies in the guard band
        (``colour_guard``); a weaker rejection takes SRIV. SRIV is consistent
        under every coloured disturbance but a coloured current, and a coloured current is
        rejected far beyond the stricter level (Gauss–Markov, two-process and telegraph
        currents at 10⁴ samples: 100 % of runs at 0.1 × the levels), while white logs
        reach it through a rejection in under 0.5 % of runs (rather than the levels'
        4–6 %); the colour guard's band (``colour_guard``) adds about 15 %, where the
        likelihood model nests the white disturbances and loses no precision.
    pem_boundary : {"auto", "bounded", "unbounded"}
        The joint model's sensor-noise variance: bounded at zero, or, where the
        likelihood does not establish the sensor-noise process (likelihood ratio ≤
        :data:`vesselid.identify.pem.LOCAL_LR`), estimated without the bound
        (:data:`vesselid.identify.pem.JOINT_LOCAL`); ``auto`` (default) takes the
        unbounded estimate unless the smoothed current looks bimodal
        (:func:`vesselid.identify.current_shape.smoothed_current_test`), then the bounded
        one. Under a single Gauss–Markov current the bounded estimate fits a spurious
        sensor process in most runs and biases ``n`` by about 0.4 Monte Carlo sd, which
        the unbounded one removes; on a telegraph current, outside every model, the
        unbounded one is biased twice as much as the bounded one, and the kurtosis test
        of the smoothed current tells the two apart (``scripts/robustness_study.py``,
        ``scripts/pem_boundary_study.py``, ``docs/guide/choosing-an-estimator.md``).
    pem_cov : {"conservative", "sandwich", "fisher"}
        Covariance of that fallback: the smallest covariance above both the quasi-ML
        sandwich and the inverse Fisher information (default,
        :func:`vesselid.identify.pem.conservative_covariance`: the sandwich is valid when
        the disturbances are not the modelled Gaussian processes, but its HAC estimate
        undercovers at 10⁴ samples where the inverse Fisher does not), the sandwich, or
        the inverse Fisher information.
    """

    multi_experiment: ClassVar[tuple[str, ...]] = ("pooled",)
    corrects_sensor_noise: ClassVar[bool] = True

    def __init__(self, instruments: str = "simulated", noise_order: int = 0,
                 alpha: float = 0.01, colour_alpha: float = 0.05, refine: int = 3,
                 fallback_refine: int = 3, name: str | None = None, label: str | None = None,
                 short: str | None = None,
                 colour_order: int = 0, pem_fallback: bool = False,
                 pem_cov: str = "conservative", pem_level: float = 0.1,
                 pem_boundary: str = "auto", pem_switching: bool = True,
                 colour_guard: float = 0.2, guard_misfit: float = 1.5) -> None:
        super().__init__(instruments=instruments, noise_order=noise_order, alpha=alpha,
                         colour_alpha=colour_alpha, colour_guard=colour_guard,
                         guard_misfit=guard_misfit, refine=refine,
                         fallback_refine=fallback_refine, colour_order=colour_order,
                         pem_fallback=pem_fallback, pem_cov=pem_cov, pem_level=pem_level,
                         pem_boundary=pem_boundary, pem_switching=pem_switching)
        self.pem_switching = pem_switching
        self.pem_boundary = pem_boundary
        self.pem_fallback = bool(pem_fallback)
        self.pem_level = pem_level
        self.pem_cov = pem_cov
        self.instruments = instruments
        self.noise_order = noise_order
        self.alpha = alpha
        self.colour_alpha = colour_alpha
        self.colour_order = colour_order
        self.colour_guard = colour_guard
        self.guard_misfit = guard_misfit
        self.refine = refine
        self.fallback_refine = fallback_refine
        name = name or f"gmm-{instruments}" + (f"-ar{noise_order}" if noise_order else "")
        self._names = {"name": name, "label": label or name, "short": short or name}

    name = _named("name")  # type: ignore[assignment]
    label = _named("label")  # type: ignore[assignment]
    short = _named("short")  # type: ignore[assignment]
    plot_label = _named("short")  # type: ignore[assignment]

    def _validate(self) -> None:
        if self.instruments not in ("simulated", "combined", "auto"):
            raise IdentificationError(
                f"instruments must be 'simulated', 'combined' or 'auto', got "
                f"{self.instruments!r}")
        if not (isinstance(self.noise_order, int | np.integer) and 0 <= self.noise_order <= 50):
            raise IdentificationError(
                f"noise_order must be an integer in 0..50, got {self.noise_order!r}")
        if not (isinstance(self.colour_order, int | np.integer) and 0 <= self.colour_order <= 10):
            raise IdentificationError(
                f"colour_order must be an integer in 0..10, got {self.colour_order!r}")
        for key in ("alpha", "colour_alpha"):
            val = getattr(self, key)
            if not (isinstance(val, float | int | np.floating | np.integer)
                    and 0 < float(val) < 1):
                raise IdentificationError(f"{key} must be in (0, 1), got {val!r}")
        g = self.colour_guard
        if not (isinstance(g, float | int | np.floating | np.integer) and not isinstance(g, bool)
                and 0 <= float(g) < 1):
            raise IdentificationError(f"colour_guard must be in [0, 1), got {g!r}")
        m = self.guard_misfit
        if not (isinstance(m, float | int | np.floating | np.integer) and not isinstance(m, bool)
                and float(m) >= 1):
            raise IdentificationError(f"guard_misfit must be a number >= 1 (inf: never), "
                                      f"got {m!r}")
        if not (isinstance(self.pem_level, float | int | np.floating | np.integer)
                and not isinstance(self.pem_level, bool) and 0 < float(self.pem_level) <= 1):
            raise IdentificationError(f"pem_level must be in (0, 1], got {self.pem_level!r}")
        for key in ("refine", "fallback_refine"):
            val = getattr(self, key)
            if not (isinstance(val, int | np.integer) and val >= 1):
                raise IdentificationError(f"{key} must be a positive integer, got {val!r}")
        if self.pem_boundary not in pem.BOUNDARIES:
            raise IdentificationError(
                f"pem_boundary must be one of {list(pem.BOUNDARIES)}, got "
                f"{self.pem_boundary!r}")
        if self.pem_cov not in pem.COVARIANCES:
            raise IdentificationError(
                f"pem_cov must be one of {list(pem.COVARIANCES)}, got {self.pem_cov!r}")
        if not isinstance(self.pem_switching, bool | np.bool_):
            raise IdentificationError(
                f"pem_switching must be True or False, got {self.pem_switching!r}")

    def check_options(self, *, combine: str) -> None:
        super().check_options(combine=combine)
        self._validate()

    def fit(self, log: Any, spec: ModelSpec | None = None,
            options: FitOptions | Mapping[str, Any] | None = None, **overrides: Any):
        """:meth:`Estimator.fit`; for ``auto`` on a multi-state log whose choice is SRIV,
        followed by the specification check of
        :mod:`vesselid.identify.misspecification` (the result may then be the unfiltered
        IV_E{ζ}=0 or the plain refined IV, with ``choice_reason`` and a
        :class:`~vesselid.errors.MisspecificationWarning` saying why)."""
        options = FitOptions.of(options, **overrides)
        if self.instruments != "auto" or options.instruments is not None:
            return super().fit(log, spec, options)
        import warnings

        routed = self._closed_loop_route(log, spec, options)
        if routed is not None:
            return routed

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = super().fit(log, spec, options)
        out, out_caught = res, list(caught)
        if (res.method == self.name and res.spec.n_states > 1
                and res.diagnostics.get("choice") == "sriv"
                and str(res.diagnostics.get("noise_model", "")).startswith("AR(")):
            from vesselid.identify.misspecification import check_default

            out, out_caught = check_default(res, out_caught, log, spec, options)
        for w in out_caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        return out

    def _closed_loop_route(self, log: Any, spec: ModelSpec | None, options: FitOptions):
        """``auto`` on a closed-loop log: a log that declares its loop (controller,
        reference), or an undeclared one whose feedback test rejects and that logs a
        reference (the PID law estimated), is identified by the closed-loop estimator
        ``cl-iv`` (:mod:`vesselid.identify.closedloop`); None otherwise."""
        import warnings

        from vesselid.identify.loop import closed_loop_route

        signals = closed_loop_route(log, spec)
        found = None
        if signals is None:
            from vesselid.identify.loop import undeclared_closed_loop_route

            route = undeclared_closed_loop_route(log, spec)
            if route is not None:
                signals, found = route
        if signals is None:
            return None
        from vesselid.identify.closedloop import ClosedLoopIV

        res = ClosedLoopIV().with_signals(signals).fit(log, spec, options)
        if found is None:
            why = "cl-iv: the log declares closed loop (metadata['closed_loop'])"
        else:
            from vesselid.errors import ClosedLoopWarning

            why = ("cl-iv: the log does not declare its loop, but the feedback test "
                   f"rejects open loop (p = {found['feedback']['pvalue']:.2g}) and "
                   f"it logs a reference; {found['sentence']}; instruments from the "
                   "reference through the closed loop of that law — declare the "
                   "controller in metadata['closed_loop'] to use the true one")
            res.diagnostics["closed_loop_detected"] = found
            res.diagnostics["warnings"] = [*res.diagnostics.get("warnings", []), why]
            warnings.warn(why, ClosedLoopWarning, stacklevel=4)
        res.diagnostics["auto_choice"] = why
        res.diagnostics["choice_reason"] = why
        return res

    # ------------------------------------------------------------------ core
    def _refine(self, data, spec, phi, lagged, theta, kind, order, keep, tol, steps=None,
                colour=False, first_z: list | None = None):
        """``refine`` refinement steps of one instrument set from the consistent start
        ``theta`` (instruments re-simulated from, and the noise model re-estimated at,
        the latest estimate); returns ``(solution, theta, steps)``. ``colour``: on the
        fused path, the first step (instruments simulated from ``theta``) also runs the
        colour test (``solution.colour``, :func:`vesselid.identify.gmm.combined_solution`).
        ``first_z`` (a list) receives the instruments simulated from ``theta`` when the
        rows are formed (the explicit colour test of the fit path needs the same ones)."""
        n = data.n_groups
        iters = np.zeros(n, dtype=np.int64)
        active = np.all(np.isfinite(theta), axis=1)
        sol = first = None
        fused = kind == "combined" and not order and not keep
        # a long log's final rows are formed again when the covariance needs them
        # (:meth:`equation_designs`) instead of being held through every test between
        defer = keep and kind == "combined" and not order and _long_log(data)
        n_steps = int(self.refine if steps is None else steps)
        for step in range(n_steps):
            if fused:  # Monte Carlo fast path: two compiled passes, no row matrices
                sol, ok_sim = gmm.combined_solution(
                    data, spec, theta, colour=gmm.COLOUR_WINDOW if colour and not step else None)
                if first is None:
                    first = sol
            else:
                if defer:  # (the colour test simulates the first step's instruments again)
                    blocks, ok_sim = _combined_blocks(data, spec, theta)
                    ar = None
                else:
                    z_sim, ok_sim = gmm.simulated_instruments(data, spec, theta)
                    if first_z is not None and step == 0:
                        first_z.append(z_sim)
                    ar = gmm.noise_model(data, spec, phi, theta, order) if order else None
                    blocks = gmm.instrument_blocks(spec, kind, phi, z_sim, lagged)
                    del z_sim  # (first_z keeps the first step's; the blocks the others)
                last = step == n_steps - 1
                if last and lagged:  # gathered for the last time (the caller's list)
                    lagged.clear()
                sol = None  # the previous step's rows: only the last step's are kept
                keep_rows = keep and last and not defer
                sol = gmm.solve_equations(data, spec, phi, blocks, weight="hac", ar=ar,
                                          keep_designs=keep_rows,
                                          keep_jacobians=keep_rows, release=True)
                del blocks
                if defer and last:  # the start of the step that formed the final rows
                    sol.rebuild_from = theta.copy()  # type: ignore[attr-defined]
            new = np.where((sol.ok & ok_sim & active)[:, None], sol.theta, np.nan)
            iters += active
            active &= np.all(np.isfinite(new), axis=1)
            theta = new
        if first is not None and sol is not first:
            sol.colour, sol.colour_df, sol.colour_ok = (first.colour, first.colour_df,
                                                        first.colour_ok)
        return sol, theta, iters

    def _colour_test(self, data, spec, phi, theta0, sol, z_first=None):
        """The colour test of the instruments simulated from ``theta0``: the statistic
        fused into the first combined step where it has it (``sol.colour_ok``), else
        :func:`vesselid.identify.gmm.colour_test` on explicit rows (the fit path; no
        generated kernel; ``theta0`` not finite or non-finite sums). ``z_first``: those
        instruments when the first refinement step simulated them already (the same call
        on the same arrays). ``(stat, df)``."""
        n = data.n_groups
        if self.colour_order:  # the whitened test: explicit rows, batched over groups
            phi = phi if phi is not None else corrected_regressor_matrix(data, spec)
            z_sim = (z_first if z_first is not None else
                     gmm.simulated_instruments(data, spec, theta0)[0])
            return gmm.colour_test(data, spec, phi, z_sim, theta=theta0,
                                   noise_order=int(self.colour_order))
        if sol.colour is not None:
            stat, df, todo = sol.colour.copy(), sol.colour_df, ~sol.colour_ok
        else:
            stat, df, todo = np.zeros((n, spec.n_states)), None, np.ones(n, dtype=bool)
        if todo.any():
            sub = data if todo.all() else _subset(data, todo)
            phi_s = (phi if phi is not None and todo.all() else
                     corrected_regressor_matrix(sub, spec))
            # the instruments handed over (freed inside once copied into their blocks)
            z_sim = [z_first if z_first is not None and todo.all() else
                     gmm.simulated_instruments(sub, spec, theta0[todo])[0]]
            del z_first
            stat[todo], df = gmm.colour_test(sub, spec, phi_s, z_sim)
        return stat, df

    def estimate_parameters(self, data: RegressionData, spec: ModelSpec, *,
                            combine: str = "pooled", theta_start: np.ndarray | None = None,
                            max_iter: int = 100, tol: float = 1e-9,
                            keep_history: bool = False,
                            base: IterationResult | None = None) -> IterationResult:
        """Estimate every group (module docstring). ``base``: the converged
        IV_{E{ζ}=0} result of exactly this call's ``data``, ``spec``, ``theta_start``,
        ``max_iter`` and ``tol`` (pooled), when the caller already has it (the Monte
        Carlo shares its ``iv-zero-mean`` row); it is not recomputed then. The result
        keeps it as ``info["base"]``."""
        self._validate()
        if base is None:
            base = estimate(data, spec, "iv-zero-mean", combine="pooled",
                            theta_start=theta_start, max_iter=max_iter, tol=tol)
        n = data.n_groups
        keep = keep_history and n == 1
        checks = _ValidityChecks.start(
            data, spec, base,
            self.instruments == "auto" and keep and np.all(np.isfinite(base.theta_aux[0])))
        try:
            return self._estimate_groups(data, spec, base, keep, checks, tol, keep_history)
        finally:
            checks.close()

    def _estimate_groups(self, data: RegressionData, spec: ModelSpec, base: IterationResult,
                         keep: bool, checks: _ValidityChecks, tol: float,
                         keep_history: bool) -> IterationResult:
        """The body of :meth:`estimate_parameters` once the base estimate is known and
        the validity checks are under way (``checks``)."""
        n = data.n_groups
        fused = self.instruments in ("combined", "auto") and not keep
        # the fused combined path (with auto's unfiltered colour test) needs no regressor
        # rows; the whitened colour test needs them for every group (auto's fallback then
        # takes its groups' rows from them), the explicit unfiltered test and the fallback
        # compute them for their groups (with the errors-in-variables correction of the
        # square modulus regressors when the data carry the sensor noise,
        # :mod:`vesselid.identify.eiv`)
        whitened = self.instruments == "auto" and bool(self.colour_order)
        phi = (None if fused and not whitened else corrected_regressor_matrix(data, spec))
        lagged = None
        if self.instruments in ("combined", "auto") and keep and not _long_log(data):
            # explicit rows (fit path; a long log's are formed one source at a time,
            # :func:`_combined_blocks`)
            lagged = [gmm.lagged_regressors(data, spec, lag) for lag in gmm.LAGS]
        theta0 = base.theta.copy()
        used = np.full(n, self.instruments, dtype=object)
        # the AR order of the simulated-instrument set (sriv; auto's fallback)
        info: dict[str, Any] = {"noise_order": (self._ar_order(data) if self.instruments
                                                == "simulated" else self._fallback_order(data))}
        if self.instruments == "simulated":
            sol, theta, iters = self._refine(data, spec, phi, None, theta0, "simulated",
                                             info["noise_order"], keep, tol)
        else:
            first_z: list = []
            sol, theta, iters = self._refine(data, spec, phi, lagged, theta0, "combined", 0,
                                             keep, tol,
                                             colour=self.instruments == "auto"
                                             and not self.colour_order,
                                             first_z=first_z)
            lagged = None  # (the delayed regressors serve the combined steps only)
            pvals = np.ones((n, spec.n_states))
            for i in range(spec.n_states):
                if sol.c_df[i]:
                    pvals[:, i] = _chi2_sf(sol.c[:, i], sol.c_df[i])
            c_p = pvals.min(axis=1)
            info.update(c_stat=sol.c.copy(), c_df=sol.c_df.copy(), c_pvalue=c_p,
                        j_stat=sol.j.copy(), j_df=sol.df.copy())
            used[:] = "combined"
            if self.instruments == "auto":
                w_stat, w_df = self._colour_test(data, spec, phi, theta0, sol,
                                                 z_first=first_z.pop() if first_z else None)
                w_p = np.ones((n, spec.n_states))
                for i in range(spec.n_states):
                    if w_df[i]:
                        w_p[:, i] = _chi2_sf(w_stat[:, i], w_df[i])
                info.update(colour_stat=w_stat, colour_df=w_df, colour_pvalue=w_p.min(axis=1),
                            colour_order=int(self.colour_order))
                c_rej = c_p < float(self.alpha)
                w_rej = w_p.min(axis=1) < float(self.colour_alpha)
                applies = bool(self.pem_fallback and pem.supports(spec, data))
                # the guard band [colour_alpha, colour_guard): the test misses coloured
                # sensor noise there often enough that the delayed instruments' bias
                # outweighs their precision; the likelihood model, which nests white
                # disturbances and coloured sensor noise, takes these logs where it
                # applies (elsewhere SRIV would cost the white logs in the band their
                # precision, so the delayed instruments stay)
                info["colour_guarded"] = (~(c_rej | w_rej) & applies
                                          & (w_p.min(axis=1) < float(self.colour_guard)))
                reject = c_rej | w_rej | info["colour_guarded"]
                # a test rejects white disturbances: on a one-state log without a
                # disturbance sensor a coloured current inside the modulus biases every
                # instrument built from the input — model both processes instead
                # the likelihood model only on strong evidence (each test's p-value below
                # pem_level times its level): a coloured current, the one disturbance
                # that biases every instrument, is rejected far beyond that at 10⁴ samples
                strong = reject & ((c_p < float(self.alpha) * float(self.pem_level))
                                   | (w_p.min(axis=1)
                                      < float(self.colour_alpha) * float(self.pem_level))
                                   | info["colour_guarded"])
                info["pem_strong"] = strong
                if strong.any() and applies:
                    self._pem_fallback(data, spec, theta0, strong, theta, iters, used, info)
                    if info["colour_guarded"].any():
                        # in the band the evidence of colour is weak: a likelihood fit
                        # whose Gaussian model misfits the log gives way to SRIV
                        misfit = info["colour_guarded"] & (used == "pem") & (
                            _sandwich_fisher_ratio(info) > float(self.guard_misfit))
                        info["pem_guard_misfit"] = misfit
                        used[misfit] = "combined"
                    reject = reject & (used != "pem")
                info["pem_applies"] = applies
                if reject.any():
                    sub = _subset(data, reject)
                    phi_s = (phi[_rows(data, reject)] if phi is not None else
                             corrected_regressor_matrix(sub, spec))
                    sol_s, th_s, it_s = self._refine(
                        sub, spec, phi_s, None, theta0[reject], "simulated",
                        info["noise_order"], keep, tol, steps=self.fallback_refine)
                    theta[reject] = th_s
                    iters[reject] = it_s
                    used[reject] = "simulated"
                    if keep:
                        sol = sol_s
        info.update(checks.result())
        ok = np.all(np.isfinite(theta), axis=1) & np.all(np.isfinite(base.theta), axis=1)
        theta[~ok] = np.nan
        if sol is not None:
            sol.segment_starts = data.starts  # type: ignore[attr-defined]
        reason = np.where(ok, base.reason, np.where(np.isfinite(base.theta).all(axis=1),
                                                    SINGULAR, base.reason)).astype(object)
        info.update(solution=sol, instrument_set=used, base=base, lowpassed=data.lowpassed,
                    sensor_noise=(None if data.regressor_noise is None else
                                  {s: float(v) for s, v in zip(spec.states,
                                                               data.regressor_noise,
                                                               strict=True) if v > 0}))
        return IterationResult(
            theta=theta, theta_aux=theta.copy(), converged=base.converged & ok,
            iterations=base.iterations + iters, reason=reason, residual=base.residual,
            oscillation=base.oscillation, start=base.start, info=info,
            history=[theta.copy()] if keep_history else [],
        )

    def _pem_fallback(self, data, spec, theta0, reject, theta, iters, used, info) -> None:
        """The prediction-error estimator on the groups ``reject``, from their IV_{E{ζ}=0}
        estimates; taken where its likelihood maximisation converged (in place; the
        others fall back to SRIV). A group sent here by the colour test's guard band
        alone (``info["colour_guarded"]``) fits the sensor-noise model only
        (:func:`_guard_band_fits`)."""
        guarded = info.get("colour_guarded")
        band = (np.asarray(guarded, dtype=bool)[reject] if guarded is not None
                else np.zeros(int(reject.sum()), dtype=bool))
        sub = _subset(data, reject)
        res = _on_own_thread(lambda: _guard_band_fits(sub, spec, theta0[reject], band,
                                                      self.pem_boundary))
        ok = res["converged"] & np.all(np.isfinite(res["theta"]), axis=1)
        idx = np.flatnonzero(reject)
        n = data.n_groups
        for key in ("psi", "cov", "cov_sandwich", "cov_conservative", "loglik", "vuong",
                    "model", "lr_joint", "local_z", "shape_z", "boundary"):
            arr = res[key]
            full = (np.full(n, "", dtype=object) if arr.dtype == object else
                    np.full((n, *arr.shape[1:]), np.nan))
            full[idx] = arr
            info[f"pem_{key}"] = full
        take = idx[ok]
        theta[take] = res["theta"][ok]
        iters[take] += res["iterations"][ok]
        used[take] = "pem"
        if self.pem_switching:
            self._switching(sub, spec, theta0[reject], res, ok, idx, theta, iters, info)

    @staticmethod
    def _switching(sub, spec, theta0, res, ok, idx, theta, iters, info) -> None:
        """Where the smoothed current of the Gauss–Markov fit looks bimodal, the
        switching-current model of :mod:`vesselid.identify.switching`, reported instead
        where Vuong's test prefers its likelihood (in place)."""
        from vesselid.identify import switching

        gate = ok & res["shape_bimodal"] & np.isin(res["model"].astype(str),
                                                   list(switching.GAUSSIAN_FREE))
        n = theta.shape[0]
        info["pem_switch_vuong"] = np.full(n, np.nan)
        info["pem_switch_noise"] = np.full((n, 5), np.nan)
        info["pem_switch_loglik"] = np.full(n, np.nan)
        info["pem_gaussian_model"] = info["pem_model"].copy()
        if not gate.any():
            return
        cmp = switching.compare_with_gaussian(sub, spec, theta0, res, gate)
        info["pem_switch_vuong"][idx] = cmp["vuong"]
        info["pem_switch_noise"][idx] = cmp["noise"]
        info["pem_switch_loglik"][idx] = cmp["loglik"]
        for j in np.flatnonzero(cmp["taken"]):
            g = idx[j]
            theta[g] = cmp["theta"][j]
            iters[g] += cmp["iterations"][j]
            info["pem_model"][g] = "switching"
            for key in pem.COVARIANCE_KEYS.values():
                info[f"pem_{key}"][g] = cmp[key][j]

    def equation_designs(self, data, spec, it, phi, combine):
        if it.info["instrument_set"][0] == "pem":  # diagnostics only (own covariance)
            return square_designs(data, spec, phi, phi, it.theta[0], zero_mean=False,
                                  combine=combine)
        sol = it.info["solution"]
        if sol.designs is None and getattr(sol, "rebuild_from", None) is not None:
            sol = self._final_rows(data, spec, sol.rebuild_from)
        # the refined IV's intervals use the fixed-b critical value at the effective
        # bandwidth ratio, as the two-step GMM's do (vesselid.identify.fixedb)
        return _designs_from(sol, it.theta[0], spec, fixed_b=True)

    def defers_designs(self, it: IterationResult) -> bool:
        sol = it.info.get("solution")
        return (it.info["instrument_set"][0] == "combined"
                and getattr(sol, "rebuild_from", None) is not None)

    def _final_rows(self, data: RegressionData, spec: ModelSpec, theta: np.ndarray
                    ) -> gmm.GMMSolution:
        """The last combined refinement step from its start ``theta`` again, keeping its
        rows and weight derivatives (the same calls on the same arrays: the same
        numbers as the step :meth:`_refine` ran)."""
        blocks, _ = _combined_blocks(data, spec, theta)
        # the regressor rows handed over: freed once the rows are centred
        sol = gmm.solve_equations(data, spec, [corrected_regressor_matrix(data, spec)],
                                  blocks, weight="hac", ar=None, keep_designs=True,
                                  keep_jacobians=True, release=True)
        sol.segment_starts = data.starts  # type: ignore[attr-defined]
        return sol

    def own_covariance(self, it: IterationResult) -> np.ndarray | None:
        if it.info["instrument_set"][0] == "pem":
            return it.info["pem_" + pem.COVARIANCE_KEYS[self.pem_cov]][0]
        return None

    def own_covariance_label(self, it: IterationResult) -> tuple[str, str]:
        model = it.info.get("pem_model")
        if model is not None and str(model[0]) == "switching":
            from vesselid.identify.switching import covariance_label

            return covariance_label(self.pem_cov)
        return pem.covariance_label(self.pem_cov)

    def _fallback_order(self, data: RegressionData) -> int:
        """AR order of ``auto``'s fallback: none on a low-pass-filtered log, where the
        whitening prefilter re-weights the regression toward the removed band (measured on
        the wave-filtered sea trial, moderate sea: SRIV's bias on ``r: r`` was 7.7 Monte
        Carlo sd, IV_E{ζ}=0's 0.5)."""
        return 0 if data.lowpassed else self._ar_order(data)

    def _ar_order(self, data: RegressionData) -> int:
        """The AR noise-model order: the estimator's ``noise_order``, or the order identify's
        ``noise_order`` asks for (``data.noise_order``) when the estimator prefilters at
        all. A sea trial needs
        :data:`vesselid.studies.planner.SRIV_ORDER`: its equation error is the differenced white
        sensor noise (an MA(1) with its root near the unit circle) plus 2-s Gauss–Markov
        forces, which a short AR model whitens poorly."""
        if not self.noise_order or data.noise_order is None:
            return int(self.noise_order)
        return int(data.noise_order)

    def describe(self, it: IterationResult) -> dict[str, Any]:
        info = it.info
        noise_model = "none"
        if info["instrument_set"][0] == "pem" and info["pem_model"][0] == "switching":
            from vesselid.identify import switching

            out = {**switching.describe_auto(info, 0),
                   "instruments": "none: maximum likelihood, switching current"}
        elif info["instrument_set"][0] == "pem":  # its disturbance model; the tests below
            out: dict[str, Any] = {**pem.describe_fit(info, 0, it.theta.shape[1]),
                                   "instruments": "none: prediction-error estimator (PEM)"}
            vz = info.get("pem_switch_vuong")
            if vz is not None and np.isfinite(vz[0]):  # the switching model lost
                out["switching_current"] = {
                    "vuong_z": float(vz[0]),
                    "test": "Vuong's test of the two-level switching-current likelihood "
                            "against the Gauss–Markov one (positive: switching fits "
                            "better); not preferred at its level"}
        else:
            if info["instrument_set"][0] == "simulated" and self.noise_order:
                order = info["noise_order"]
                noise_model = (f"AR({order}) prefilter (SRIV)" if order
                               else "none (the log is low-pass filtered)")
            out = {
                "instruments": str(info["instrument_set"][0]),
                "noise_model": noise_model,
                "sensor_noise_correction": (
                    "none" if not info.get("sensor_noise") else
                    "square modulus regressors corrected for white sensor noise (std "
                    + ", ".join(f"{k} {v:.3g}" for k, v in info["sensor_noise"].items())
                    + "): y|y| - s^2 sign(y), y^2 - s^2"),
            }
        if "c_pvalue" in info:
            out["hansen_j_combined"] = _jdict(info["j_stat"][0], info["j_df"])
            out["c_test_lagged"] = _jdict(info["c_stat"][0], info["c_df"])
            if "colour_pvalue" in info:
                out["colour_test"] = _jdict(info["colour_stat"][0], info["colour_df"])
                out["colour_test_prefilter"] = (f"AR({info['colour_order']})"
                                                if info.get("colour_order") else "none")
                out["instrument_choice"] = self._choice_text(info)
                out["choice"] = self._choice_key(info)
                out["choice_reason"] = self._choice_sentence(info)
        for key in ("stability", "mean_current"):
            if info.get(key) is not None:
                out["parameter_stability" if key == "stability" else key] = info[key]
        return out

    def result_warnings(self, it: IterationResult) -> list[tuple[str, type[Warning]]]:
        out: list[tuple[str, type[Warning]]] = []
        mc = it.info.get("mean_current")
        if mc is not None and mc["warned"]:
            out.append((mc["sentence"], IdentifiabilityWarning))
        st = it.info.get("stability")
        if st is not None and st["rejected"]:
            out.append((st["sentence"], ParameterDriftWarning))
        return out

    @staticmethod
    def _choice_key(info: dict[str, Any]) -> str:
        """``auto``'s choice as one token: ``combined``, ``sriv`` or ``pem-<model>``."""
        used = str(info["instrument_set"][0])
        if used == "pem":
            return f"pem-{info['pem_model'][0]}"
        return {"simulated": "sriv"}.get(used, used)

    def _choice_sentence(self, info: dict[str, Any]) -> str:
        """Why ``auto`` chose what it chose, in one plain sentence."""
        used = str(info["instrument_set"][0])
        p_c, p_w = float(info["c_pvalue"][0]), float(info["colour_pvalue"][0])
        if used == "combined":
            return (f"auto used simulated + delayed instruments because neither the C test "
                    f"of the delayed instruments (p = {p_c:.2g}) nor the colour test "
                    f"(p = {p_w:.2g}) rejects white disturbances, and then the delayed "
                    "measurements make the estimate more precise.")
        rejected = [n for n, p, a in (("C test", p_c, self.alpha),
                                      ("colour test", p_w, self.colour_alpha)) if p < a]
        guarded = info.get("colour_guarded")
        guard = (not rejected and guarded is not None and bool(guarded[0]))
        if guard:
            band = (f"the colour test's p = {p_w:.2g} lies below its guard "
                    f"{float(self.colour_guard):g}, though not below its level "
                    f"{self.colour_alpha:g}: coloured sensor noise that the test misses at "
                    "its level biases the delayed instruments")
            if used == "simulated":
                mis = info.get("pem_guard_misfit")
                why_not = ("the Gaussian likelihood model misfits the log (its quasi-ML "
                           "sandwich standard error exceeds the inverse-Fisher one "
                           f"{float(_sandwich_fisher_ratio(info)[0]):.2g} times, more than "
                           f"{float(self.guard_misfit):g})" if mis is not None and mis[0] else
                           "the prediction-error fit did not converge")
                return (f"auto used simulated instruments with an AR noise-model prefilter "
                        f"(SRIV) because {band}, and {why_not}; SRIV stays consistent "
                        "under coloured sensor noise.")
            if used == "pem" and str(info["pem_model"][0]) != "switching":
                cov = {"sandwich": "quasi-ML sandwich", "fisher": "inverse Fisher",
                       "conservative": "larger of the quasi-ML sandwich and inverse Fisher"
                       }[self.pem_cov]
                return (f"auto used the prediction-error estimator with Gauss–Markov "
                        f"sensor noise as a filter state ({info['pem_model'][0]} model) "
                        f"because {band}; that model nests white disturbances as well, so "
                        f"it stays precise if they are white; its intervals are the {cov} "
                        "ones.")
        why = " and the ".join(rejected) or "the colour test's guard"
        st = info.get("stability")
        if st is not None and st["rejected"]:
            why += (f" (the split-sample stability test, p = {st['pvalue']:.2g}, says the "
                    "parameters may drift instead)")
        if used == "pem" and str(info["pem_model"][0]) == "switching":
            from vesselid.identify.current_shape import SHAPE_ALPHA
            from vesselid.identify.switching import VUONG_ALPHA

            return (f"auto used the maximum-likelihood estimator with a two-level switching "
                    f"(telegraph) current because the {why} rejected white disturbances "
                    "(a coloured current, which biases every instrument built from the "
                    "input), the smoothed current of the Gauss–Markov fit looks bimodal "
                    f"(kurtosis z = {float(info['pem_shape_z'][0]):.2f}, level "
                    f"{SHAPE_ALPHA:g}) and Vuong's test prefers the switching model's "
                    f"likelihood (z = {float(info['pem_switch_vuong'][0]):.2f}, one-sided "
                    f"level {VUONG_ALPHA:g}); its intervals are the larger of the quasi-ML "
                    "sandwich and the inverse observed information.")
        if used == "pem":
            cov = {"sandwich": "quasi-ML sandwich", "fisher": "inverse Fisher",
                   "conservative": "larger of the quasi-ML sandwich and inverse Fisher"
                   }[self.pem_cov]
            local = ("" if str(info["pem_model"][0]) != pem.JOINT_LOCAL else
                     " (the sensor-noise variance estimated without its bound at zero, "
                     "one scoring step from the current-only fit, since the likelihood "
                     "does not establish a sensor-noise process: a bounded estimate "
                     "would bias the parameters whenever there is none)")
            zs = info.get("pem_shape_z")
            zs = float(zs[0]) if zs is not None else float("nan")
            if str(info.get("pem_boundary", [""])[0]) == "bounded" and np.isfinite(zs) \
                    and self.pem_boundary == "auto":
                vz = info.get("pem_switch_vuong")
                vz = float(vz[0]) if vz is not None else float("nan")
                tried = ("" if not np.isfinite(vz) else
                         f" and a two-level switching current fits no better, Vuong z = "
                         f"{vz:.2f}")
                local = (" (the sensor-noise variance bounded at zero: the smoothed current "
                         f"looks bimodal, kurtosis z = {zs:.2f}, as a switching current "
                         f"would{tried}; no model of the estimator describes such a "
                         "current, so the estimate can be biased by a fraction of its "
                         "standard error, and its intervals include the spread between the "
                         "bounded and the unbounded fit)")
            return (f"auto used the prediction-error estimator with a Gauss–Markov current "
                    f"and Gauss–Markov sensor noise as filter states{local} because the "
                    f"{why} rejected white disturbances, and on a one-state log without a "
                    "disturbance sensor a coloured current biases every instrument built "
                    f"from the input; its intervals are the {cov} ones.")
        strong = info.get("pem_strong")
        if info.get("pem_applies") and strong is not None and not strong[0]:
            reason = (f"the rejection is too weak (p ≥ {self.pem_level:g} × the test's level) "
                      "to point at a coloured current, the one disturbance SRIV does not "
                      "handle")
        elif info.get("pem_applies"):
            reason = "the prediction-error fit did not converge"
        else:
            reason = ("the prediction-error estimator models one state equation without a "
                      "disturbance sensor on an unfiltered log only")
        return (f"auto used simulated instruments with an AR noise-model prefilter (SRIV) "
                f"because the {why} rejected white disturbances and {reason}.")

    def _choice_text(self, info: dict[str, Any]) -> str:
        """The ``auto`` decision in plain words, with both tests' p-values."""
        p_c, p_w = float(info["c_pvalue"][0]), float(info["colour_pvalue"][0])
        c_txt = f"C test of the delayed instruments p = {p_c:.3g} (level {self.alpha:g})"
        order = int(info.get("colour_order", 0))
        kind = f"AR({order})-whitened colour test" if order else "colour test"
        w_txt = (f"{kind} (does the equation error remember the past sensor noise?) "
                 f"p = {p_w:.3g} (level {self.colour_alpha:g})")
        why = [t for t, p, a in ((c_txt, p_c, self.alpha), (w_txt, p_w, self.colour_alpha))
               if p < a]
        st = info.get("stability")
        if st is not None and st["rejected"]:  # drift, not (only) colour, may explain it
            look = ("the equation error remembers its past — coloured disturbances or "
                    f"drifting parameters (split-sample stability test p = {st['pvalue']:.2g} "
                    "rejects constant parameters)")
        else:
            look = "the disturbances look coloured"
        if info["instrument_set"][0] == "pem" and info["pem_model"][0] == "switching":
            return ("maximum likelihood with a two-level switching current (interacting "
                    "multiple-model filter): the delayed measurements are not valid "
                    f"instruments on this log — {look}, and the current switches between "
                    "two levels; rejected by the " + " and the ".join(why))
        if info["instrument_set"][0] == "pem":
            return ("prediction-error estimator with the disturbances as Gauss–Markov filter "
                    f"states ({info['pem_model'][0]} model): the delayed measurements are not "
                    f"valid instruments on this log — {look}; "
                    "rejected by the " + " and the ".join(why))
        guarded = info.get("colour_guarded")
        if not why and guarded is not None and guarded[0]:
            why = [w_txt + f" below its guard {float(self.colour_guard):g}"]
        if info["instrument_set"][0] == "simulated":
            how = ("simulated only, no noise-model prefilter (the log is low-pass "
                   "filtered, and a whitening prefilter would weight the removed band)"
                   if info.get("lowpassed") else "simulated only (SRIV)")
            return (how + ": the delayed measurements are not valid "
                    f"instruments on this log — {look}, and using "
                    "them would bias the estimate; rejected by the " + " and the ".join(why))
        return ("simulated + delayed measurements: the disturbances look white, so the "
                "delayed measurements are valid and make the estimate more precise; neither "
                f"test rejects ({c_txt}; {w_txt})")


def _sandwich_fisher_ratio(info: dict[str, Any]) -> np.ndarray:
    """Per group: the largest ratio of the likelihood fit's quasi-ML sandwich standard
    error to its inverse-Fisher one over the parameters (NaN where not fitted)."""
    fisher = np.diagonal(info["pem_cov"], axis1=1, axis2=2)
    sandwich = np.diagonal(info["pem_cov_sandwich"], axis1=1, axis2=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.sqrt(np.abs(sandwich) / np.abs(fisher))
    out = np.full(ratio.shape[0], np.nan)
    ok = np.all(np.isfinite(ratio), axis=1)
    out[ok] = ratio[ok].max(axis=1)
    return out


def _combined_blocks(data: RegressionData, spec: ModelSpec, theta: np.ndarray
                     ) -> tuple[list[tuple[np.ndarray, int]], np.ndarray]:
    """``gmm.instrument_blocks(spec, "combined", …)`` of the instruments simulated from
    ``theta`` and the delayed regressors, with the simulation's ``ok``: on one state
    equation each source is formed, copied into its columns and freed before the next
    (the same values; not every source held at once beside the block)."""
    z_sim, ok = gmm.simulated_instruments(data, spec, theta)
    if spec.n_states != 1:
        lagged = [gmm.lagged_regressors(data, spec, lag) for lag in gmm.LAGS]
        return gmm.instrument_blocks(spec, "combined", None, z_sim, lagged), ok
    d_cols = np.flatnonzero(gmm.state_terms(spec))
    p_cols = z_sim.shape[1]
    out = np.empty((z_sim.shape[0], p_cols + len(gmm.LAGS) * d_cols.size))
    out[:, :p_cols] = z_sim
    del z_sim
    pos = p_cols
    for lag in gmm.LAGS:
        lg = gmm.lagged_regressors(data, spec, lag)
        out[:, pos:pos + d_cols.size] = lg[:, d_cols]
        pos += d_cols.size
        del lg
    return [(out, len(gmm.LAGS) * d_cols.size)], ok


def _long_log(data: RegressionData) -> bool:
    """One group longer than :data:`~vesselid.identify.covariance.LARGE_ROWS` rows."""
    from vesselid.identify.covariance import LARGE_ROWS

    return data.n_groups == 1 and int(data.starts[-1]) > LARGE_ROWS


class _ValidityChecks:
    """``auto``'s validity checks of one log (the split-sample stability test and the
    mean-current test, :mod:`vesselid.identify.validity`), which read only the base
    IV_{E{ζ}=0} estimate: run on a second thread while the estimate is refined
    (:func:`vesselid.core.threads.background`), or here when :meth:`result` asks for
    them where no second thread may be used, on a small log that runs the numpy kernels
    (:mod:`vesselid.identify.backend`: the thread count would load numba) and on a long
    log (one experiment above :data:`~vesselid.identify.covariance.LARGE_ROWS` rows: the
    checks' rows and the refinement's would be held at once). The same code on the same
    numbers either way, so the same results."""

    def __init__(self, run: Any, job: Any) -> None:
        self._run, self._job = run, job

    @classmethod
    def start(cls, data: RegressionData, spec: ModelSpec, base: IterationResult,
              wanted: bool) -> _ValidityChecks:
        if not wanted:
            return cls(None, None)

        def run() -> dict[str, Any]:
            return {"stability": _guarded(validity.parameter_stability, data, spec,
                                          validity.STABILITY_ALPHA, base.theta[0]),
                    "mean_current": _guarded(validity.mean_current, data, spec,
                                             base.theta_aux[0])}

        if _long_log(data) or numpy_active():  # after the refinement, on this thread
            # (the numpy kernels' small log: a second thread would load numba)
            return cls(run, None)
        from vesselid.core.threads import background

        return cls(run, background(run))

    def result(self) -> dict[str, Any]:
        """The checks' entries of the estimate's ``info`` (none where not wanted)."""
        if self._run is None:
            return {}
        if self._job is None:
            return self._run()
        job, self._job = self._job, None
        return job.result()

    def close(self) -> None:
        """Never leave while the checks still run on the other thread."""
        if self._job is not None:
            from concurrent.futures import wait

            wait([self._job])


def _guard_band_fits(data: RegressionData, spec: ModelSpec, theta0: np.ndarray,
                     band: np.ndarray, boundary: str) -> dict[str, np.ndarray]:
    """:func:`vesselid.identify.pem.fit_groups` of every group of ``data`` from
    ``theta0``: the groups of the colour test's guard band (``band``) with the
    sensor-noise model alone, the others with every model and the joint stage.

    The guard band's alternative is coloured sensor noise that the colour test misses
    at its level (a coloured current is rejected far below it: the Gauss–Markov,
    two-process and telegraph currents in every run at 10⁴ samples), and that model
    nests white disturbances, so a white log in the band keeps the precision of the
    delayed instruments (the paper's Table 1 design, 1000 runs: Monte Carlo sd of ``n``
    0.0132 against 0.0133 without the guard); its fit alone costs a fraction of every
    candidate's and the joint stage's (the Monte Carlo of Table 1 with ``auto``, one
    worker: 10 s of CPU against 33 s with every candidate in the band, 3.3 s without the
    guard). The
    arrays are those of one ``fit_groups`` call over all groups (``loglik`` in the
    column of each fitted model, the others NaN)."""
    full = {"joint": True, "boundary": boundary}
    if not band.any():
        return pem.fit_groups(data, spec, theta0, **full)
    sensor = pem.DISTURBANCE_MODELS.index("sensor")
    out: dict[str, np.ndarray] = {}
    m = band.size
    for sel, kw in ((~band, full), (band, {"models": ("sensor",), "joint": False})):
        if not sel.any():
            continue
        res = pem.fit_groups(data if sel.all() else _subset(data, sel), spec, theta0[sel],
                             **kw)
        for key, arr in res.items():
            shape = (len(pem.DISTURBANCE_MODELS),) if key == "loglik" else arr.shape[1:]
            if key not in out:
                out[key] = (np.full((m, *shape), "", dtype=object) if arr.dtype == object
                            else np.zeros((m, *shape), dtype=arr.dtype)
                            if arr.dtype.kind in "biu" else np.full((m, *shape), np.nan))
            if key == "loglik" and arr.shape[1] == 1:
                out[key][sel, sensor] = arr[:, 0]
            else:
                out[key][sel] = arr
    return out


def _on_own_thread(fn):
    """``fn()`` — the likelihood fit of ``auto``'s fallback — on a thread of its own
    (:func:`vesselid.core.threads.aside`; here where none may be used, and on the numpy
    kernels' small log). The same code on the same numbers. Its filter passes allocate
    and free arrays of 10⁴ × 10 samples many times over; on that thread they come from
    a malloc arena of its own, whose memory the frees of the calling thread's work do not
    hand back to the operating system between the passes (glibc): measured on a
    10⁴-sample Gauss–Markov-current log, ~870 minor page faults per ``identify`` call
    with the fit on its own thread, 1200–2500 with it on the calling thread (a few µs
    each: 5–10 % of the call's CPU time)."""
    from vesselid.core.threads import aside

    job = None if numpy_active() else aside(fn)
    if job is None:
        return fn()
    try:
        return job.result()
    except BaseException:
        from concurrent.futures import wait

        wait([job])  # never leave while the fit still runs
        raise


def _guarded(fn, *args):
    """A diagnostic that must never stop the estimate: ``None`` where it cannot run."""
    try:
        return fn(*args)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None


def _rows(data: RegressionData, groups: np.ndarray) -> np.ndarray:
    seg = groups[data.group]
    return np.repeat(seg, np.diff(data.starts))


def _subset(data: RegressionData, groups: np.ndarray) -> RegressionData:
    """The regression data of the selected groups only (renumbered)."""
    from dataclasses import replace

    seg = groups[data.group]
    lengths = np.diff(data.starts)[seg]
    new_id = np.cumsum(groups) - 1
    # the selected segments' rows, copied slice by slice (a boolean mask over all rows
    # costs a pass over the whole batch for the few groups a fallback usually takes)
    pieces = [data.segment(int(s)) for s in np.flatnonzero(seg)]

    def take(arr: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(np.concatenate([arr[p] for p in pieces])
                                    if pieces else arr[:0])

    return replace(
        data,
        target=take(data.target),
        regsig=take(data.regsig),
        u=take(data.u),
        starts=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        group=new_id[data.group[seg]].astype(np.int64),
        n_groups=int(groups.sum()),
        experiment_ids=tuple(e for e, k in zip(data.experiment_ids, seg, strict=False) if k),
        sensor=None if data.sensor is None else take(data.sensor),
    )
