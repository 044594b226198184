"""Figure helpers below the studies layer: the Agg figure factory and the residual-analysis
figure that :meth:`vesselid.identify.results.IdentificationResult.plot_residuals` draws.

Kept apart from :mod:`vesselid.studies.plots` (which labels estimators from the registry) so that
the
results object, low in the identify layer, imports nothing that imports the registry.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = ["new_figure", "residual_analysis"]


def new_figure(width: float, height: float) -> Figure:
    """A constrained-layout figure on the Agg canvas (no pyplot state, nothing shown)."""
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def residual_analysis(rc: Any, *, title: str | None = None) -> Figure:
    """MATLAB ``resid``-style figure: residual autocorrelation (top) and residual–input
    cross-correlation (bottom), one line per output (and input), with the
    confidence band of :func:`vesselid.identify.specification.residual_correlations`.

    Parameters
    ----------
    rc : ResidualCorrelation
        From :func:`~vesselid.identify.specification.residual_correlations` (or
        ``result.diagnostics["residual_correlation"]``, also as its ``to_dict()``).
    """
    if isinstance(rc, Mapping):
        get = rc.__getitem__
    else:
        def get(key: str) -> Any:
            return getattr(rc, key)
    lags, acf = np.asarray(get("lags")), np.asarray(get("acf"))
    xl, ccf = np.asarray(get("cross_lags")), np.asarray(get("ccf"))
    band, level = float(get("band")), float(get("level"))
    outputs, inputs = list(get("outputs")), list(get("inputs"))
    fig = new_figure(7.0, 5.2)
    ax1, ax2 = fig.subplots(2, 1)
    for i, o in enumerate(outputs):
        ax1.plot(lags[1:], acf[i, 1:], "o-", ms=2.5, lw=1, label=f"ε {o}")
    ax1.axhspan(-band, band, color="C2", alpha=0.15, label=f"{100 * level:.0f} % band")
    ax1.axhline(0, color="0.3", lw=0.6)
    ax1.set_xlabel("lag (samples)")
    ax1.set_ylabel("autocorrelation")
    ax1.set_title(title or "Residual analysis", fontsize=9)
    ax1.legend(fontsize=7, ncol=min(4, len(outputs) + 1))
    for i, o in enumerate(outputs):
        for j, u in enumerate(inputs):
            ax2.plot(xl, ccf[i, j], lw=1, label=f"ε {o} · {u}")
    ax2.axhspan(-band, band, color="C2", alpha=0.15)
    ax2.axhline(0, color="0.3", lw=0.6)
    ax2.set_xlabel("lag τ (samples; τ > 0: input leads)")
    ax2.set_ylabel("cross-correlation")
    if inputs:
        ax2.legend(fontsize=7, ncol=min(4, len(outputs) * len(inputs)))
    return fig
