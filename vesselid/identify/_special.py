"""χ² tail probabilities and normal quantiles, importing ``scipy.special`` only if needed.

``scipy.special`` costs ≈ 0.1 s of CPU to import — a third of ``import numpy, pandas`` —
which the small-log path of ``vesselid identify`` (:mod:`vesselid.identify.backend`)
avoids:

* :func:`norm_ppf` returns the exact ``scipy.special.ndtri`` values of the quantiles of
  the usual confidence levels from a table (``tests/test_npkernels.py`` compares them bit
  for bit) and asks scipy for any other.
* :func:`chi2_sf` is ``scipy.special.chdtrc(df, x)``; while the numpy path runs, integer
  degrees of freedom use the closed forms of the regularised upper incomplete gamma
  function ``Q(df/2, x/2)`` (finite sums of Poisson terms, plus ``erfc`` for odd ``df``),
  equal to scipy's values to rounding.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["chi2_sf", "norm_ppf"]

#: ``scipy.special.ndtri(0.5 + level / 2)`` for the usual confidence levels (exact floats).
_NDTRI = {
    0.9: 1.2815515655446004,
    0.95: 1.6448536269514722,
    0.975: 1.959963984540054,
    0.99: 2.3263478740408408,
    0.995: 2.5758293035489004,
    0.9995: 3.2905267314919255,
}


def norm_ppf(q: float) -> Any:
    """Standard normal quantile (= ``scipy.special.ndtri`` = ``scipy.stats.norm.ppf``)."""
    value = _NDTRI.get(float(q))
    if value is not None:
        return np.float64(value)
    from scipy.special import ndtri

    return ndtri(q)


def _chi2_sf_closed(x: np.ndarray, k: int) -> np.ndarray:
    """``Q(k/2, x/2)`` for integer ``k ≥ 1`` in closed form (x ≥ 0; NaN stays NaN)."""
    h = x / 2.0
    out = np.full(x.shape, np.nan)
    pos = h > 0
    out[h == 0] = 1.0
    out[np.isposinf(h)] = 0.0
    fin = pos & np.isfinite(h)
    hp = h[fin]
    log_h = np.log(hp)
    if k % 2 == 0:
        acc = np.zeros_like(hp)
        for j in range(k // 2):
            acc += np.exp(j * log_h - math.lgamma(j + 1.0) - hp)
    else:
        acc = np.array([math.erfc(math.sqrt(v)) for v in hp])
        for j in range((k - 1) // 2):
            acc += np.exp((j + 0.5) * log_h - math.lgamma(j + 1.5) - hp)
    out[fin] = acc
    return out


def chi2_sf(x: Any, df: Any) -> Any:
    """χ² survival function ``P(χ²_df > x)`` (= ``scipy.special.chdtrc(df, x)``)."""
    from vesselid.identify.backend import numpy_active

    k = float(df) if np.ndim(df) == 0 else None
    if numpy_active() and k is not None and k >= 1 and k == int(k):
        arr = np.asarray(x, dtype=np.float64)
        if not (arr < 0).any():
            res = _chi2_sf_closed(np.atleast_1d(arr), int(k))
            return np.float64(res[0]) if arr.ndim == 0 else res.reshape(arr.shape)
    from scipy.special import chdtrc

    return chdtrc(df, x)
