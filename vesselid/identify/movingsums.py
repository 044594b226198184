"""Moving sums of a zero-padded series: the Bartlett kernel's building block.

``Σ_t h hᵀ / (L + 1)`` with ``h(t) = Σ_{i=0}^{L} x(t − i)`` is the Bartlett long-run
covariance (:func:`vesselid.identify.covariance.bartlett_long_run`,
:func:`vesselid.identify.gmm.hac_sums`) and, between two series, the fixed-b
cross-products (:func:`vesselid.identify.fixedb.bartlett_cross`). A module of its own
so that those three share one formulation.
"""

from __future__ import annotations

import numpy as np

from vesselid.identify.backend import loaded_kernel

__all__ = ["moving_sums"]


def moving_sums(x: np.ndarray, lag: int) -> np.ndarray:
    """``h(t) = Σ_{i=0}^{lag} x(t − i)`` of the zero-padded series ``x`` (q, n), for
    ``t = 0 … n + lag − 1``: differences of one running sum (the Bartlett long-run
    covariance is ``Σ_t h hᵀ / (lag + 1)``;
    :func:`vesselid.identify.covariance.bartlett_long_run`,
    :func:`vesselid.identify.gmm.hac_sums`)."""
    kernel = loaded_kernel("moving_sums")
    if kernel is not None and x.shape[1] > 0:  # the same sums in one compiled pass
        return kernel(np.ascontiguousarray(x, dtype=float), int(lag))
    q, n = x.shape
    c = np.zeros((q, n + 2 * lag + 1))
    np.cumsum(x, axis=1, out=c[:, lag + 1:n + lag + 1])
    c[:, n + lag + 1:] = c[:, n + lag:n + lag + 1]
    return c[:, lag + 1:] - c[:, :-(lag + 1)]
