"""Validating an identified model on held-out experiments, as naval architects do.

``vesselid validate trial.csv --model identified.toml [--experiments A,B] [--horizon K]
[--plot PATH] [--json PATH|-]`` and :func:`validate`: simulate the model on each experiment
with its measured inputs (:class:`vesselid.validation.freerun.Plant`: derived inputs recomputed
from the
simulated states) and report, per experiment and state,

* the **free-run fit** ``100 (1 − ‖y − ŷ‖/‖y − ȳ‖)`` % (MATLAB ``compare``; the one metric
  definition of :func:`vesselid.identify.diagnostics.nrmse_fit`), simulated from the measured
  initial state;
* the **k-step-ahead prediction fit** (each prediction started from the measured state
  ``horizon`` samples earlier);
* where the experiment is a standard manoeuvre (detected from the rudder signal,
  :func:`vesselid.validation.metrics.detect`), the figures measured vs simulated: a zig-zag
  is simulated *as a zig-zag* (the rudder reverses when the simulated heading reaches the
  measured switching angle, at the measured rudder rate and amplitude) and its first and
  second overshoot angles compared with the measured ones; a turning circle gives
  advance, transfer, tactical diameter and steady turn rate, with heading and position
  integrated from the simulated body velocities.

The yaw rate, surge and sway states are found by name (``r``, ``u``, ``v``; a derived state
such as ``du = u − U₀`` counts as ``u``), the rudder input by ``rudder`` (default
``delta``). The pooled fits weight every experiment by its variance about its own mean,
as :func:`vesselid.identify.diagnostics.free_run_ratio` does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.errors import VesselidError
from vesselid.model.spec import ModelSpec

__all__ = ["ExperimentValidation", "ValidationError", "ValidationReport",
           "validate"]

DEFAULT_HORIZON = 10


class ValidationError(VesselidError):
    """A log or model that cannot be validated (reason in the message)."""


@dataclass
class ExperimentValidation:
    """Validation of one experiment (fits in percent; figures in degrees, metres)."""

    experiment: Any
    samples: int
    free_run_fit: dict[str, float | None]
    k_step_fit: dict[str, float | None]
    diverged_at: int | None
    manoeuvre: dict[str, Any] | None = None
    series: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {"experiment": _plain(self.experiment), "samples": self.samples,
                "free_run_fit": self.free_run_fit, "k_step_fit": self.k_step_fit,
                "diverged_at": self.diverged_at, "manoeuvre": self.manoeuvre}


@dataclass
class ValidationReport:
    """Result of :func:`validate`.

    Attributes
    ----------
    model : str
        Model name.
    states : tuple of str
    horizon : int
        Steps of the k-step prediction.
    dt : float
    experiments : list of ExperimentValidation
    free_run_fit, k_step_fit : dict state -> float
        Pooled over the experiments (None where every experiment diverged).
    """

    model: str
    states: tuple[str, ...]
    horizon: int
    dt: float
    experiments: list[ExperimentValidation]
    free_run_fit: dict[str, float | None]
    k_step_fit: dict[str, float | None]

    @property
    def stable(self) -> bool:
        """No experiment's free run diverged."""
        return all(e.diverged_at is None for e in self.experiments)

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, "states": list(self.states), "horizon": self.horizon,
                "dt": self.dt, "free_run_fit": self.free_run_fit, "k_step_fit": self.k_step_fit,
                "stable": self.stable, "experiments": [e.to_dict() for e in self.experiments]}

    def to_json(self, **kwargs: Any) -> str:
        from vesselid.core.jsonio import dumps

        return dumps(self.to_dict(), **kwargs)

    def manoeuvre_table(self) -> pd.DataFrame:
        """One row per figure of every detected manoeuvre: measured, simulated, difference."""
        rows = []
        for e in self.experiments:
            m = e.manoeuvre
            if not m:
                continue
            for key, meas in m["measured"].items():
                sim = m["simulated"].get(key)
                rows.append({"experiment": e.experiment, "manoeuvre": m["label"], "figure": key,
                             "measured": meas, "simulated": sim,
                             "difference": (None if meas is None or sim is None
                                            else sim - meas)})
        return pd.DataFrame(rows, columns=["experiment", "manoeuvre", "figure", "measured",
                                           "simulated", "difference"])

    def summary(self) -> str:
        """Plain-text report (what the command line prints)."""
        w = max(12, *(len(str(e.experiment)) for e in self.experiments))
        head = f"{'experiment':<{w}} " + " ".join(f"{s + ' free':>10} {s + ' k':>8}"
                                                    for s in self.states)
        lines = [f"validation of {self.model!r}: free-run fit and {self.horizon}-step "
                 f"prediction fit (%, 100 = perfect), dt = {self.dt:g} s", head]

        def f(x: float | None) -> str:
            return "diverged" if x is None else f"{x:.1f}"

        for e in self.experiments:
            lines.append(f"{e.experiment!s:<{w}} " + " ".join(
                f"{f(e.free_run_fit[s]):>10} {f(e.k_step_fit[s]):>8}" for s in self.states))
        lines.append(f"{'pooled':<{w}} " + " ".join(
            f"{f(self.free_run_fit[s]):>10} {f(self.k_step_fit[s]):>8}" for s in self.states))
        table = self.manoeuvre_table()
        if len(table):
            lines.append("standard manoeuvres, measured vs simulated:")
            for _, r in table.iterrows():
                def g(x: Any) -> str:
                    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) \
                        else f"{x:.2f}"
                lines.append(f"  {r.experiment!s:<{w}} {r.manoeuvre:<22} {r.figure:<24} "
                             f"measured {g(r.measured):>8}  simulated {g(r.simulated):>8}")
        if not self.stable:
            bad = [str(e.experiment) for e in self.experiments if e.diverged_at is not None]
            lines.append(f"warning: the free run diverged on {bad}")
        return "\n".join(lines)

    def plot(self, path: str | Path | None = None, *, max_experiments: int = 4) -> Any:
        """MATLAB ``compare``-style figure: measured vs simulated per state and experiment
        (fit in the legend), and the heading of detected zig-zags simulated as zig-zags.

        Returns the matplotlib Figure; written (atomically) when ``path`` is given.
        """
        from vesselid.core.figures import new_figure

        exps = self.experiments[:max_experiments]
        rows = list(self.states) + (["heading"] if any("psi" in e.series for e in exps) else [])
        fig = new_figure(3.2 * len(exps) + 0.6, 1.7 * len(rows) + 0.4)
        axes = fig.subplots(len(rows), len(exps), squeeze=False, sharex="col")
        for j, e in enumerate(exps):
            t = e.series["time"]
            for i, s in enumerate(self.states):
                ax = axes[i, j]
                ax.plot(t, e.series[f"measured_{s}"], color="k", lw=0.9, label="measured")
                fit = e.free_run_fit[s]
                ax.plot(t, e.series[f"simulated_{s}"], color="C0", lw=0.9,
                        label="simulated: " + ("diverged" if fit is None else f"{fit:.1f} %"))
                ax.legend(fontsize=6, loc="best")
                if j == 0:
                    ax.set_ylabel(s)
            if "psi" in e.series:
                ax = axes[len(self.states), j]
                ax.plot(t, np.degrees(e.series["psi"]), color="k", lw=0.9, label="measured")
                ax.plot(t, np.degrees(e.series["psi_sim"]), color="C0", lw=0.9,
                        label="free run")
                if "psi_zigzag" in e.series:
                    ax.plot(t, np.degrees(e.series["psi_zigzag"]), color="C1", lw=0.9, ls="--",
                            label="simulated zig-zag")
                ax.legend(fontsize=6, loc="best")
                if j == 0:
                    ax.set_ylabel("heading (°)")
            axes[0, j].set_title(str(e.experiment), fontsize=8)
            axes[-1, j].set_xlabel("time (s)")
        for ax in axes.flat:
            ax.tick_params(labelsize=7)
        if path is not None:
            from vesselid.core.fileio import atomic_write_with

            atomic_write_with(path, lambda p: fig.savefig(p, dpi=80, format=Path(path).suffix[1:]
                                                          or "png"))
        return fig


def _plain(x: Any) -> Any:
    return x.item() if isinstance(x, np.generic) else x


def _pooled_fit(parts: list[tuple[np.ndarray, np.ndarray]]) -> float | None:
    num = den = 0.0
    for y, yh in parts:
        ok = np.isfinite(y) & np.isfinite(yh)
        if not ok.any():
            continue
        num += float(np.sum((y[ok] - yh[ok]) ** 2))
        den += float(np.sum((y[ok] - y[ok].mean()) ** 2))
    if den == 0:
        return None
    return 100.0 * (1.0 - math.sqrt(num / den))


def _fit(y: np.ndarray, yh: np.ndarray) -> float | None:
    from vesselid.identify.diagnostics import nrmse_fit

    if not np.all(np.isfinite(yh)):
        return None
    v = nrmse_fit(y, yh)
    return None if not math.isfinite(v) else v


def _model(model: Any) -> tuple[ModelSpec, np.ndarray]:
    if isinstance(model, str | Path):
        from vesselid.model.export import load_model

        spec, theta, _ = load_model(model)
        return spec, theta
    if isinstance(model, ModelSpec):
        if model.theta0 is None:
            raise ValidationError(f"model {model.name!r} has no parameters ([theta0])")
        return model, model.theta0_vector()
    spec = getattr(model, "spec", None)
    params = getattr(model, "params", None)
    if isinstance(spec, ModelSpec) and params is not None:
        return spec, np.asarray(params, dtype=float)
    raise ValidationError("model must be a spec with [theta0], an exported model file or an "
                          "identification result")


def _dt(spec: ModelSpec, log: Any) -> float:
    times = []
    if "time" in log.data.columns:
        for _, g in log.experiments():
            d = np.diff(g["time"].to_numpy(dtype=float))
            if d.size:
                times.append(d)
    dt_log = float(np.median(np.concatenate(times))) if times else None
    if spec.dt is None and dt_log is None:
        raise ValidationError("neither the model (dt) nor the log (time column) gives the "
                              "sample time")
    if spec.dt is not None and dt_log is not None and abs(dt_log - spec.dt) > 0.01 * spec.dt:
        raise ValidationError(f"the log is sampled every {dt_log:g} s but the model has dt = "
                              f"{spec.dt:g} s; resample the log (vesselid ingest --dt "
                              f"{spec.dt:g})")
    return float(spec.dt if spec.dt is not None else dt_log)  # type: ignore[arg-type]


def validate(log: Any, model: Any, *, experiments: Sequence[Any] | None = None,
             horizon: int = DEFAULT_HORIZON, rudder: str = "delta",
             manoeuvres: dict[str, dict[str, float]] | None = None) -> ValidationReport:
    """Simulate an identified model on (held-out) experiments and compare with the log.

    Parameters
    ----------
    log : TrialLog, DataFrame or path
        The experiments (measured states, inputs, and the columns derived signals need).
    model : ModelSpec with θ0, path of an exported model, or IdentificationResult
    experiments : sequence, optional
        Experiment ids to validate on (matched as text); default every experiment.
    horizon : int
        Steps of the k-step-ahead prediction (>= 1).
    rudder : str
        Rudder input column for manoeuvre detection.
    manoeuvres : dict, optional
        Nominal test settings per experiment id (text), e.g. ``{"Z_10_05":
        {"psi_switch_deg": 5.0}}``: a zig-zag's overshoots are measured from its nominal
        switching angle, and the simulated zig-zag reverses there. Default the log's
        ``metadata["manoeuvres"]``, else the heading change read at the reversals.

    Returns
    -------
    ValidationReport

    Raises
    ------
    ValidationError
        Unknown experiment, sampling that disagrees with the model's ``dt``, a horizon
        shorter than one step or longer than an experiment.
    """
    from vesselid.data.logs import TrialLog
    from vesselid.validation.freerun import Plant, ZigZagLogic
    from vesselid.validation.metrics import detect, integrate_track, turning_figures, zigzag_figures

    spec, theta = _model(model)
    if isinstance(log, str | Path):
        log = TrialLog.load(log, spec=spec)
    elif not isinstance(log, TrialLog):
        log = TrialLog(log)
    log.validate(spec)
    if isinstance(horizon, bool) or not isinstance(horizon, int | np.integer) or horizon < 1:
        raise ValidationError(f"horizon must be a positive number of steps, got {horizon!r}")
    dt = _dt(spec, log)
    parts = log.experiments()
    if experiments is not None:
        wanted = [str(e) for e in experiments]
        have = {str(eid): (eid, g) for eid, g in parts}
        unknown = [w for w in wanted if w not in have]
        if unknown:
            raise ValidationError(f"experiment(s) {unknown} not in the log; it has "
                                  f"{list(have)}")
        parts = [have[w] for w in dict.fromkeys(wanted)]
    nominal = manoeuvres if manoeuvres is not None else (log.metadata or {}).get("manoeuvres")
    if nominal is not None and not isinstance(nominal, dict):
        raise ValidationError("manoeuvres must map experiment ids to {psi_switch_deg = ...}")
    nominal = {str(k): v for k, v in (nominal or {}).items()}
    plant = Plant(spec, theta)
    names = {s: s for s in spec.states}
    for s, (col, _a, _c) in plant.source_of.items():
        names[col] = s

    def physical(x: np.ndarray, name: str) -> np.ndarray | None:
        """Column ``name`` (u, v, r) from a state array, mapped back through a derived state."""
        s = names.get(name)
        if s is None:
            return None
        col = x[:, spec.states.index(s)]
        if s in plant.source_of:
            _, a, c = plant.source_of[s]
            col = (col - c) / a
        return col

    results, pooled, pooled_k = [], {s: [] for s in spec.states}, {s: [] for s in spec.states}
    for eid, g in parts:
        if len(g) <= horizon:
            raise ValidationError(f"experiment {eid!r} has {len(g)} samples, not more than the "
                                  f"horizon {horizon}")
        g = g.reset_index(drop=True)
        x, _u_used, bad = plant.simulate(g, dt=dt)
        y, _u, _ = plant.arrays(g)
        kp = plant.k_step(g, horizon)
        free = {s: _fit(y[:, i], x[:, i]) for i, s in enumerate(spec.states)}
        kfit = {s: _fit(y[horizon:, i], kp[horizon:, i]) for i, s in enumerate(spec.states)}
        for i, s in enumerate(spec.states):
            pooled[s].append((y[:, i], x[:, i] if bad < 0 else np.full(len(y), np.nan)))
            pooled_k[s].append((y[horizon:, i], kp[horizon:, i]))
        t = (g["time"].to_numpy(float) - float(g["time"].iloc[0]) if "time" in g.columns
             else np.arange(len(g)) * dt)
        series: dict[str, np.ndarray] = {"time": t}
        for i, s in enumerate(spec.states):
            series[f"measured_{s}"] = y[:, i]
            series[f"simulated_{s}"] = x[:, i]
        manoeuvre = None
        r_m, r_s = physical(y, "r"), physical(x, "r")
        if r_m is not None and rudder in g.columns:
            psi_m = (g["psi"].to_numpy(float) if "psi" in g.columns else
                     integrate_track(np.zeros(len(g)), np.zeros(len(g)), r_m, dt)[0])
            series["psi"] = psi_m
            u_m, v_m = physical(y, "u"), physical(y, "v")
            u_s, v_s = physical(x, "u"), physical(x, "v")
            zeros = np.zeros(len(g))
            psi_s, n_s, e_s = integrate_track(zeros if u_s is None else u_s,
                                              zeros if v_s is None else v_s, r_s, dt,
                                              psi0=psi_m[0])
            series["psi_sim"] = psi_s
            delta = g[rudder].to_numpy(float)
            psw = nominal.get(str(eid), {}).get("psi_switch_deg")
            if psw is not None and not (isinstance(psw, int | float) and 0 < psw < 180):
                raise ValidationError(f"manoeuvres[{str(eid)!r}].psi_switch_deg must be an "
                                      f"angle in (0, 180), got {psw!r}")
            info = detect(delta, psi_m, dt,
                          psi_switch=None if psw is None else math.radians(psw))
            if info is not None and info.kind == "zigzag" and rudder in spec.inputs:
                zz = ZigZagLogic(info.execute, rudder, info.delta0, info.psi_switch, info.rate,
                                 info.gain_sign, info.first_sign)
                xz, uz, bad_z = plant.simulate(g, zigzag=zz, dt=dt)
                psi_z = psi_m[info.execute] + np.concatenate([
                    np.zeros(info.execute + 1),
                    np.cumsum(0.5 * dt * (physical(xz, "r")[info.execute + 1:]
                                          + physical(xz, "r")[info.execute:-1]))])
                series["psi_zigzag"] = psi_z
                meas = zigzag_figures(psi_m, delta, info, dt)
                sim = (zigzag_figures(psi_z, uz[:, spec.inputs.index(rudder)], info, dt)
                       if bad_z < 0 else {})
                keys = ("first_overshoot_deg", "second_overshoot_deg", "first_overshoot_time_s")
                manoeuvre = {"kind": "zigzag", "label": info.label(),
                             "delta0_deg": math.degrees(info.delta0),
                             "psi_switch_deg": math.degrees(info.psi_switch),
                             "rudder_rate_deg_s": math.degrees(info.rate),
                             "measured": {k: meas[k] for k in keys},
                             "simulated": {k: sim.get(k) for k in keys}}
            elif info is not None and info.kind == "turning_circle":
                if u_m is not None and v_m is not None:
                    if {"north", "east"} <= set(g.columns):
                        n_m, e_m = g["north"].to_numpy(float), g["east"].to_numpy(float)
                    else:
                        _, n_m, e_m = integrate_track(u_m, v_m, r_m, dt, psi0=psi_m[0])
                    meas = turning_figures(psi_m, n_m, e_m, r_m, info)
                    sim = (turning_figures(psi_s, n_s, e_s, r_s, info) if bad < 0
                           else dict.fromkeys(meas))
                    manoeuvre = {"kind": "turning_circle", "label": info.label(),
                                 "delta0_deg": math.degrees(info.delta0),
                                 "measured": meas, "simulated": sim}
        results.append(ExperimentValidation(
            experiment=_plain(eid), samples=len(g), free_run_fit=free, k_step_fit=kfit,
            diverged_at=None if bad < 0 else bad, manoeuvre=manoeuvre, series=series))
    return ValidationReport(
        model=spec.name, states=spec.states, horizon=int(horizon), dt=dt, experiments=results,
        free_run_fit={s: _pooled_fit(p) for s, p in pooled.items()},
        k_step_fit={s: _pooled_fit(p) for s, p in pooled_k.items()})
