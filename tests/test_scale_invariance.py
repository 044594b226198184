"""Units must not matter: identify gives the same model for signals scaled by 10^±6."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vesselid.errors import IdentificationError
from vesselid.identify import identify
from vesselid.logs import TrialLog
from vesselid.systems import get_system


@pytest.fixture(scope="module")
def log() -> TrialLog:
    return get_system("heave", current_mean=0.1).simulate(3000, n_runs=2, seed=1).to_log()


def _scaled(log: TrialLog, s: float) -> TrialLog:
    data = log.data.copy()
    for c in data.columns:
        if c not in ("experiment", "time"):
            data[c] = data[c] * s
    return TrialLog(data, log.metadata)


@pytest.mark.parametrize("method", ["ls", "iv-zero-mean"])
@pytest.mark.parametrize("s", [1e6, 1e-6])
def test_results_do_not_depend_on_units(log, method, s):
    """x → s·x, τ → s·τ: a and f are unchanged, the modulus coefficient becomes n/s."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = identify(log, method=method)
        res = identify(_scaled(log, s), method=method)
    unit = np.array([1.0, s, 1.0])
    np.testing.assert_allclose(res.params.to_numpy() * unit, ref.params.to_numpy(), rtol=1e-8)


@pytest.mark.parametrize("method", ["ls", "iv-zero-mean"])
@pytest.mark.parametrize("s", [1e6, 1e-6])
def test_standard_errors_do_not_depend_on_units(log, method, s):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = identify(log, method=method)
        res = identify(_scaled(log, s), method=method)
    unit = np.array([1.0, s, 1.0])
    np.testing.assert_allclose(res.std_errors.to_numpy() * unit, ref.std_errors.to_numpy(),
                               rtol=1e-8)


def test_overflowing_moments_are_named(log):
    with pytest.raises(IdentificationError, match=r"'w: w\*\|w\|' reaches .* overflow float64"):
        identify(_scaled(log, 1e150), method="ls")
