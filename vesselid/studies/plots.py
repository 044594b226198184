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

import matplotlib as mpl
import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from vesselid.core.figures import new_figure as _figure
from vesselid.core.figures import residual_analysis
from vesselid.errors import VesselidError

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


class _UnhintedTextFigure(Figure):
    """A :class:`~matplotlib.figure.Figure` whose text is drawn without FreeType hinting.

    Agg (matplotlib >= 3.11) renders text glyph by glyph, and hinting each glyph makes
    text most of the cost of saving a figure; unhinted glyphs are a little softer but
    as legible at these sizes and cost less (``scripts/bench_figure.py``).
    """

    def draw(self, renderer: Any) -> None:
        """Draw the figure (as :meth:`Figure.draw`) with unhinted text."""
        with mpl.rc_context({"text.hinting": "no_hinting"}):
            super().draw(renderer)


def _tick_text(locs: np.ndarray) -> list[str]:
    """Tick labels with the fewest decimals that show every location exactly (as
    matplotlib's ScalarFormatter does without offset), with a Unicode minus."""
    step = float(np.min(np.abs(np.diff(locs)))) if locs.size > 1 else 1.0
    dec = next((d for d in range(6)
                if np.all(np.abs(np.round(locs, d) - locs) < 1e-6 * step)), None)
    fmt = f".{dec}f" if dec is not None else ".2e"  # tiny spans in scientific notation
    return [f"{v:{fmt}}".replace("-", "\u2212") for v in np.where(locs == 0, 0.0, locs)]


def _x_ticks(ax: Any, lo: float, hi: float, length: float, fontsize: float) -> None:
    """Bottom x ticks drawn as one line collection and plain texts (what the axis would
    draw, without its per-tick artists, which cost more than the rest of the figure)."""
    locs = MaxNLocator(5).tick_values(lo, hi)
    locs = locs[(locs >= lo - 1e-9 * (hi - lo)) & (locs <= hi + 1e-9 * (hi - lo))]
    ax.set_xticks([])
    tr = ax.get_xaxis_transform()  # x in data, y in axes coordinates
    ax.add_collection(LineCollection([[(x, 0.0), (x, -length)] for x in locs], colors="k",
                                     linewidths=0.8, transform=tr, clip_on=False),
                      autolim=False)
    for x, lab in zip(locs, _tick_text(locs), strict=True):
        ax.text(x, -1.4 * length, lab, transform=tr, ha="center", va="top",
                fontsize=fontsize, clip_on=False)


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
        Tidy Monte Carlo results (:func:`vesselid.studies.montecarlo.run_study`).
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
        (the true value), a solid line each estimator's mean; a one-line note above
        each histogram states mean ± sd and the non-finite or out-of-range runs, the
        number of finite estimates per histogram is stated once in the bottom-left
        corner (and in the note of any histogram with another count). Text is drawn
        unhinted (see ``_UnhintedTextFigure``); saving takes well under 0.1 s
        (``scripts/bench_figure.py``).
    """
    if df.empty:
        raise VesselidError("no results to plot")
    # label columns as numpy str arrays (pandas' astype(str) or drop_duplicates of an
    # Arrow-backed or categorical column costs several ms the first time in a process)
    eq_col, term_col, meth_col = (np.asarray(df[c].to_numpy(object), dtype=str)
                                  for c in ("equation", "term", "method"))
    params = list(dict.fromkeys(zip(eq_col.tolist(), term_col.tolist(), strict=True)))
    meths = _methods(df, methods)
    multi = len({eq for eq, _ in params}) > 1
    n_r, n_c = len(meths), len(params)
    width, height = figsize or (3.0 * n_c + 0.8, 1.3 * n_r + 0.8)
    # One axes per parameter with the estimators stacked as rows inside it, fixed margins
    # (no layout engine), precomputed counts drawn as one polygon per histogram in one
    # collection per panel, one single-line note per histogram in a strip above its bars
    # (no text boxes), the common run count stated once: ~40 short text lines in all.
    # Agg renders text glyph by glyph, so text dominates the cost of saving; this keeps
    # drawing and saving well under 0.1 s (``scripts/bench_figure.py``).
    fig = _UnhintedTextFigure(figsize=(width, height))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.95 / width, right=1.0 - 0.12 / width, bottom=0.32 / height,
                        top=1.0 - (0.62 if title else 0.34) / height, wspace=0.05)
    axes = np.atleast_1d(fig.subplots(1, n_c, squeeze=False)[0])
    # x tick marks (3.5 pt) as a fraction of the axes height, for _x_ticks
    tick_len = 3.5 / 72.0 / (height * (fig.subplotpars.top - fig.subplotpars.bottom))
    err_all = df["normalized_error"].to_numpy(float)
    finite_all = np.isfinite(err_all)
    # the most common number of finite estimates per histogram, stated once for the figure
    counts_fin = [int(np.count_nonzero(finite_all & (eq_col == eq) & (term_col == term)
                                       & (meth_col == m)))
                  for eq, term in params for m in meths]
    n_common = max(set(counts_fin), key=counts_fin.count)
    for j, (eq, term) in enumerate(params):
        ax = axes[j]
        sel_p = (eq_col == eq) & (term_col == term)
        vals = err_all[sel_p & finite_all & np.isin(meth_col, meths)]
        if vals.size:
            lo, hi = np.percentile(vals, [clip, 100.0 - clip])
            if not hi > lo:
                lo, hi = lo - 0.5, hi + 0.5
            pad = 0.05 * (hi - lo)
            lo, hi = min(lo - pad, -pad), max(hi + pad, pad)
        else:
            lo, hi = -1.0, 1.0
        edges = np.linspace(lo, hi, bins + 1)
        xs = np.concatenate([edges[:1], np.repeat(edges[1:-1], 2), edges[-1:],
                             edges[-1:], edges[:1]])
        outlines, mean_segs = [], []
        for i, meth in enumerate(meths):
            base = float(n_r - 1 - i)  # first estimator on top
            e = err_all[sel_p & (meth_col == meth)]
            fin = e[np.isfinite(e)]
            inside = fin[(fin >= lo) & (fin <= hi)]
            counts, _ = np.histogram(inside, bins=edges)
            peak = max(int(counts.max(initial=0)), 1)
            top = base + 0.78 * counts / peak  # bars below the note strip (0.84–0.97)
            outlines.append(np.column_stack([xs, np.concatenate([np.repeat(top, 2),
                                                                 [base, base]])]))
            note = []
            if fin.size:
                mean, sd = float(np.mean(fin)), float(np.std(fin, ddof=1)) if fin.size > 1 else 0.0
                mean_segs.append([(mean, base), (mean, base + 0.82)])
                note.append(f"{mean:+.4f} ± {sd:.4f}")
            if fin.size != n_common:
                note.append(f"n = {fin.size}")
            if fin.size < e.size:
                note.append(f"{e.size - fin.size} failed")
            if inside.size < fin.size:
                note.append(f"{fin.size - inside.size} off-scale")
            ax.text(lo + 0.015 * (hi - lo), base + 0.97, ", ".join(note), va="top", ha="left",
                    fontsize=6.5)
        # every histogram a polygon of one collection (limits set below, so no autoscaling);
        # the true value (dashed), each estimator's mean (solid) and the row rules as lines
        ax.add_collection(PolyCollection(outlines, facecolors="C0", alpha=0.75, linewidths=0),
                          autolim=False)
        ax.add_collection(LineCollection([[(0.0, b), (0.0, b + 0.82)] for b in range(n_r)],
                                         colors="k", linestyles="--",
                                         linewidths=1.0), autolim=False)
        ax.add_collection(LineCollection(
            mean_segs + [[(lo, r), (hi, r)] for r in range(1, n_r)],
            colors=["C3"] * len(mean_segs) + ["0.6"] * (n_r - 1),
            linewidths=[1.5] * len(mean_segs) + [0.6] * (n_r - 1)), autolim=False)
        ax.set_xlim(lo, hi)
        ax.set_ylim(0.0, float(n_r))
        _x_ticks(ax, lo, hi, tick_len, fontsize=7)
        ax.set_title(_param_label(eq, term, labels, multi), fontsize=9)
        if j == 0:
            ax.set_yticks(np.arange(n_r) + 0.5,
                          [_labels().get(m, m) for m in reversed(meths)], fontsize=9)
            ax.tick_params(axis="y", length=0)
        else:
            ax.set_yticks([])
    # the run count shared by the histograms, once (bottom-left corner)
    fig.text(0.08 / width, 0.1 / height, f"n = {n_common} each", fontsize=7, va="bottom")
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
    from vesselid.data.logs import TrialLog

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
