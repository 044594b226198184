"""The split-sample and mean-current tests' regression rows: centring in place on one run
of kept rows and the one-segment HAC lags give the numbers of the masked forms exactly."""

from __future__ import annotations

import numpy as np
import pytest

from vesselid.identify import validity
from vesselid.identify.data import from_log
from vesselid.identify.estimators import estimate
from vesselid.identify.gmm import hac_lags
from vesselid.plant.systems import heave


def _masked_rows(data, spec, theta_aux, extra):
    """The centring with a boolean mask per experiment (the reference form)."""
    from vesselid.identify.backend import kernels

    codes = spec.codes
    sl, starts = data.group_rows(0)
    phi = kernels.regressor_matrix(data.regsig[sl], data.u[sl], starts, codes.factors)
    z, xhat = kernels.instrument_matrix(data.target[sl], data.u[sl], starts, theta_aux,
                                        codes.factors, codes.equation, spec.n_states)
    y = data.target[sl, 0].astype(float)
    if extra:
        prev = np.full((y.size, 2), np.nan)
        for s in range(starts.size - 1):
            a, b = int(starts[s]), int(starts[s + 1])
            prev[a + 1:b, 0] = np.abs(data.regsig[sl][a:b - 1, 0])
            prev[a + 1:b, 1] = np.abs(xhat[a:b - 1, 0])
        phi = np.column_stack([phi, prev[:, 0]])
        z = np.column_stack([z, prev[:, 1]])
    keep = np.all(np.isfinite(phi), axis=1) & np.all(np.isfinite(z), axis=1)
    seg = np.repeat(np.arange(starts.size - 1), np.diff(starts))
    for s in range(starts.size - 1):
        r = keep & (seg == s)
        for arr in (phi, z):
            arr[r] -= arr[r].mean(axis=0)
        y[r] -= y[r].mean()
    return phi[keep], z[keep], y[keep], seg[keep]


def _masked_hac(m, seg):
    s = m.T @ m
    bw = hac_lags(m.shape[0])
    for lag in range(1, bw + 1):
        same = (seg[lag:] == seg[:-lag]).astype(float)[:, None]
        c = (m[lag:] * same).T @ m[:-lag]
        s += (1.0 - lag / (bw + 1.0)) * (c + c.T)
    return s


@pytest.mark.parametrize("runs", [1, 3])
@pytest.mark.parametrize("extra", [False, True])
def test_rows_equal_the_masked_form(runs: int, extra: bool) -> None:
    log = heave().simulate(1500, n_runs=runs, seed=4).to_log()
    data, spec = from_log(log, log.spec)[:2]
    aux = estimate(data, spec, "iv-zero-mean").theta_aux[0]
    got = validity._rows(data, spec, aux, extra)
    want = _masked_rows(data, spec, aux, extra)
    for g, w in zip(got, want, strict=True):
        assert np.array_equal(g, w)
    phi, z, y, seg = got
    fit = validity._hac_iv(z, phi, y, seg)
    if fit is not None:
        theta, cov = fit
        a_inv = np.linalg.inv(z.T @ phi)
        meat = _masked_hac(z * (y - phi @ theta)[:, None], seg)
        assert np.array_equal(cov, a_inv @ meat @ a_inv.T)
