"""Figures from Monte Carlo results and trial logs (matplotlib, Agg backend).

* :func:`error_histograms` — Figure 1 of the paper: histograms of the normalized
  estimation errors ``(θ̂ − θ0)/θ0``, one row per estimator and one column per
  parameter, shared bins per parameter, a line at zero and the mean marked.
* :func:`estimate_vs_truth` — estimates of every run with mean ± sd per method,
  against the true value θ0.
* :func:`trial_timeseries` — states (measured and true), inputs and disturbance
  sensors of a trial log.

Figures are built with the object-oriented API on the Agg canvas: no display and
no pyplot state are needed, and nothing is shown; save with ``fig.savefig``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from vesselid.errors import VesselidError
from vesselid.figures import new_figure as _figure
from vesselid.figures import residual_analysis

__all__ = ["error_histograms", "estimate_vs_truth", "residual_analysis", "trial_timeseries"]


def _labels() -> dict[str, str]:
    """Display names of the registered estimators (the paper's notation)."""
    from vesselid.identify.registry import method_labels

    return method_labels("plot")


def _params(df: pd.DataFrame) -> list[tuple[str, str]]:
    """(equation, term) pairs in order of first appearance."""
    pairs = df[["equation", "term"]].drop_duplicates()
    return [(str(e), str(t)) for e, t in pairs.itertuples(index=False, name=None)]


def _panels(df: pd.DataFrame,
            methods: Sequence[str] | None) -> tuple[list[str], list[tuple[str, str]], bool]:
    """The estimators and (equation, term) parameters of Monte Carlo results, and whether
    there are several equations (then panel titles name the equation)."""
    if df.empty:
        raise VesselidError("no results to plot")
    params = _params(df)
    return _methods(df, methods), params, len({eq for eq, _ in params}) > 1


def _methods(df: pd.DataFrame, methods: Sequence[str] | None) -> list[str]:
    present = [str(m) for m in pd.unique(df["method"].to_numpy(object))]
    if methods is None:
        return present
    missing = [m for m in methods if m not in present]
    if missing:
        raise VesselidError(f"no results for methods {missing}; present: {present}")
    return list(methods)


def _param_label(eq: str, term: str, labels: Mapping[str, str] | None, multi: bool) -> str:
    sym = (labels or {}).get(term)
    if sym:  # plain Unicode (no mathtext parsing): (â − a₀)/a₀
        return f"({sym}\u0302 − {sym}₀)/{sym}₀"
    return f"{eq}: {term}" if multi else term


def error_histograms(
    df: pd.DataFrame,
    *,
    methods: Sequence[str] | None = None,
    labels: Mapping[str, str] | None = None,
    bins: int = 40,
    clip: float = 0.5,
    title: str | None = None,
    figsize: tuple[float, float] | None = None,
) -> Figure:
    """Histograms of normalized estimation errors (paper Figure 1).

    Parameters
    ----------
    df : DataFrame
        Tidy Monte Carlo results (:func:`vesselid.montecarlo.run_study`).
    methods : sequence of str, optional
        Estimators (rows), default all in ``df``.
    labels : mapping term -> symbol, optional
        Parameter symbols for the column titles, e.g. ``{"w": "a", "w*|w|": "n",
        "tau": "f"}`` gives ``(â − a0)/a0``.
    bins : int
        Bins per parameter, shared by all estimators (same edges in a column).
    clip : float
        Bin range: the ``clip`` and ``100 − clip`` percentiles of all finite errors
        of the parameter (runs outside are counted in the panel, not dropped silently).
    title : str, optional
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        One axes per parameter (column, shared bins), the estimators stacked as rows
        inside it, each histogram scaled to its own peak. A dashed line marks zero
        (the true value), a solid line each estimator's mean; each panel states
        mean ± sd and the number of runs (and of non-finite or out-of-range runs).
    """
    meths, params, multi = _panels(df, methods)
    n_r, n_c = len(meths), len(params)
    width, height = figsize or (3.0 * n_c + 0.8, 1.3 * n_r + 0.8)
    # One axes per parameter with the estimators stacked as rows inside it, fixed
    # margins (no layout engine), precomputed counts drawn as one filled step artist per
    # panel: a few dozen artists in all, which keeps drawing well under 0.3 s.
    fig = Figure(figsize=(width, height))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.95 / width, right=1.0 - 0.12 / width, bottom=0.32 / height,
                        top=1.0 - (0.62 if title else 0.34) / height, wspace=0.05)
    axes = np.atleast_1d(fig.subplots(1, n_c, squeeze=False)[0])
    eq_col = df["equation"].astype(str).to_numpy()
    term_col = df["term"].astype(str).to_numpy()
    meth_col = df["method"].astype(str).to_numpy()
    err_all = df["normalized_error"].to_numpy(float)
    box = {"boxstyle": "square,pad=0.1", "fc": "white", "alpha": 0.7, "lw": 0}
    for j, (eq, term) in enumerate(params):
        ax = axes[j]
        sel_p = (eq_col == eq) & (term_col == term)
        vals = err_all[sel_p & np.isin(meth_col, meths)]
        vals = vals[np.isfinite(vals)]
        if vals.size:
            lo, hi = np.percentile(vals, [clip, 100.0 - clip])
            if not hi > lo:
                lo, hi = lo - 0.5, hi + 0.5
            pad = 0.05 * (hi - lo)
            lo, hi = min(lo - pad, -pad), max(hi + pad, pad)
        else:
            lo, hi = -1.0, 1.0
        edges = np.linspace(lo, hi, bins + 1)
        means, mean_base, outlines = [], [], []
        for i, meth in enumerate(meths):
            base = float(n_r - 1 - i)  # first estimator on top
            e = err_all[sel_p & (meth_col == meth)]
            fin = e[np.isfinite(e)]
            inside = fin[(fin >= lo) & (fin <= hi)]
            counts, _ = np.histogram(inside, bins=edges)
            peak = max(int(counts.max(initial=0)), 1)
            top = base + 0.8 * counts / peak
            outlines.append(np.column_stack([
                np.concatenate([edges[:1], np.repeat(edges[1:-1], 2), edges[-1:],
                                edges[::-1][:1], edges[:1]]),
                np.concatenate([np.repeat(top, 2), [base, base]])]))
            note = [f"n = {fin.size}"]
            if fin.size:
                mean, sd = float(np.mean(fin)), float(np.std(fin, ddof=1)) if fin.size > 1 else 0.0
                means.append(mean)
                mean_base.append(base)
                note.insert(0, f"{mean:+.4f} ± {sd:.4f}")
            if fin.size < e.size:
                note.append(f"{e.size - fin.size} failed")
            if inside.size < fin.size:
                note.append(f"{fin.size - inside.size} off-scale")
            ax.text(lo + 0.015 * (hi - lo), base + 0.97, "\n".join(note), va="top", ha="left",
                    fontsize=6.5, bbox=box)
        # every histogram as one polygon of a single collection (limits set below, so no
        # autoscaling); the true value (dashed) through every row, each estimator's mean
        # (solid) and the row rules as line collections
        ax.add_collection(PolyCollection(outlines, facecolors="C0", alpha=0.75, linewidths=0),
                          autolim=False)
        ax.add_collection(LineCollection([[(0.0, 0.0), (0.0, float(n_r))]], colors="k",
                                         linestyles="--", linewidths=1.0), autolim=False)
        ax.add_collection(LineCollection(
            [[(m, b), (m, b + 0.9)] for m, b in zip(means, mean_base, strict=True)]
            + [[(lo, r), (hi, r)] for r in range(1, n_r)],
            colors=["C3"] * len(means) + ["0.6"] * (n_r - 1),
            linewidths=[1.5] * len(means) + [0.6] * (n_r - 1)), autolim=False)
        ax.set_xlim(lo, hi)
        ax.set_ylim(0.0, float(n_r))
        ax.xaxis.set_major_locator(MaxNLocator(5))
        ax.tick_params(labelsize=7)
        ax.set_title(_param_label(eq, term, labels, multi), fontsize=9)
        if j == 0:
            ax.set_yticks(np.arange(n_r) + 0.5,
                          [_labels().get(m, m) for m in reversed(meths)], fontsize=9)
            ax.tick_params(axis="y", length=0)
        else:
            ax.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=10, y=1.0 - 0.08 / height, va="top")
    return fig


def estimate_vs_truth(
    df: pd.DataFrame,
    *,
    methods: Sequence[str] | None = None,
    labels: Mapping[str, str] | None = None,
    max_points: int = 400,
    seed: int = 0,
    title: str | None = None,
) -> Figure:
    """Estimates against the true values: one panel per parameter.

    Each method gets a column of (jittered) per-run estimates, at most
    ``max_points`` of them, with the mean ± sd as an error bar; the horizontal
    line is θ0.
    """
    meths, params, multi = _panels(df, methods)
    fig = _figure(3.0 * len(params) + 0.5, 3.2)
    axes = np.atleast_1d(fig.subplots(1, len(params), squeeze=False)[0])
    rng = np.random.default_rng(seed)
    for j, (eq, term) in enumerate(params):
        ax = axes[j]
        sub = df[(df["equation"].astype(str) == eq) & (df["term"].astype(str) == term)]
        theta0 = float(sub["theta0"].iloc[0])
        for i, meth in enumerate(meths):
            est = sub.loc[sub["method"].astype(str) == meth, "estimate"].to_numpy(float)
            est = est[np.isfinite(est)]
            if est.size == 0:
                continue
            pts = est if est.size <= max_points else rng.choice(est, max_points, replace=False)
            ax.scatter(i + rng.uniform(-0.2, 0.2, pts.size), pts, s=3, alpha=0.3, color=f"C{i}")
            sd = float(np.std(est, ddof=1)) if est.size > 1 else 0.0
            ax.errorbar(i, float(np.mean(est)), yerr=sd, fmt="o", color="k", capsize=4)
        ax.axhline(theta0, color="k", ls="--", lw=1.0, label=r"$\theta_0$")
        ax.set_xticks(range(len(meths)), [_labels().get(m, m) for m in meths], fontsize=8)
        sym = (labels or {}).get(term)
        ax.set_title(rf"${sym}$ ($\theta_0$ = {theta0:g})" if sym
                     else f"{eq}: {term}" if multi else term, fontsize=9)
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel("estimate")
    axes[0].legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def trial_timeseries(
    log: Any,
    *,
    experiment: Any = None,
    max_samples: int | None = 2000,
    title: str | None = None,
) -> Figure:
    """Time series of a trial log: states (measured, and true if simulated), inputs, sensors.

    Parameters
    ----------
    log : TrialLog or DataFrame
        A trial log (docs/architecture.md columns); its spec, when present, tells states,
        inputs and sensor columns apart, otherwise the ``true_*`` columns do.
    experiment : optional
        Experiment to plot (default the first).
    max_samples : int, optional
        Plot at most this many samples from the start.
    """
    from vesselid.logs import TrialLog

    if isinstance(log, TrialLog):
        frame, spec = log.to_frame(), log.spec
    elif isinstance(log, pd.DataFrame):
        frame, spec = log, None
    else:
        raise VesselidError(f"expected a TrialLog or DataFrame, got {type(log).__name__}")
    if frame.empty:
        raise VesselidError("the log is empty")
    if "experiment" in frame.columns:
        ids = list(dict.fromkeys(frame["experiment"]))
        pick = ids[0] if experiment is None else experiment
        if pick not in ids:
            raise VesselidError(f"no experiment {experiment!r} in the log; have {ids[:10]}")
        frame = frame[frame["experiment"] == pick]
    if max_samples is not None:
        frame = frame.iloc[: int(max_samples)]
    t = frame["time"].to_numpy(float) if "time" in frame.columns else np.arange(len(frame))
    if spec is not None:
        states, inputs, sensors = list(spec.states), list(spec.inputs), list(spec.sensors)
    else:
        states = [c[5:] for c in frame.columns
                  if c.startswith("true_") and not c.startswith(("true_current_",
                                                                 "true_process_"))]
        states = [s for s in states if s in frame.columns]
        skip = {"experiment", "time", *states}
        inputs = [c for c in frame.columns if c not in skip and not c.startswith("true_")]
        sensors = []
    groups: list[tuple[str, list[str]]] = [(s, [s]) for s in states]
    if inputs:
        groups.append(("inputs", inputs))
    if sensors:
        groups.append(("sensors", sensors))
    fig = _figure(8.0, 1.7 * len(groups) + 0.6)
    axes = np.atleast_1d(fig.subplots(len(groups), 1, sharex=True, squeeze=False)[:, 0])
    for ax, (name, cols) in zip(axes, groups, strict=True):
        for k, c in enumerate(cols):
            if c not in frame.columns:
                continue
            ax.plot(t, frame[c].to_numpy(float), lw=0.7, color=f"C{k}",
                    label=f"{c} (measured)" if name in states else c)
            if name in states and f"true_{c}" in frame.columns:
                ax.plot(t, frame[f"true_{c}"].to_numpy(float), lw=0.9, color="k", alpha=0.8,
                        label=f"{c} (true)")
        ax.set_ylabel(name, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=7, loc="upper right", ncols=2)
    axes[-1].set_xlabel("time")
    if title:
        fig.suptitle(title, fontsize=10)
    return fig
