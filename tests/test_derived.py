"""Derived states and inputs ([derived] in a spec): parsing, TOML, identification, simulation."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from _ship import SHIP, zigzag_log

from vesselid.errors import LogValidationError, ModelSpecError
from vesselid.model.derived import DerivedSignal, add_derived, state_dependent
from vesselid.model.spec import ModelSpec


def test_expressions_expand_to_polynomials():
    d = DerivedSignal.parse("x", "(u**2 + v**2)*delta")
    assert dict(d.terms) == {(("delta", False), ("u", False), ("u", False)): 1.0,
                             (("delta", False), ("v", False), ("v", False)): 1.0}
    assert set(DerivedSignal.parse("x", "2*u*|u|*delta - 3").uses) == {"u", "delta"}
    assert DerivedSignal.parse("du", "u - 1.177").affine() == ("u", 1.0, -1.177)
    assert DerivedSignal.parse("z", "u*delta").affine() is None
    cols = {"u": np.array([1.0, -2.0]), "v": np.array([0.5, 1.0]), "delta": np.array([0.1, 0.2])}
    np.testing.assert_allclose(d.evaluate(cols), (cols["u"] ** 2 + cols["v"] ** 2) * cols["delta"])
    np.testing.assert_allclose(DerivedSignal.parse("z", "u*|u|").evaluate(cols), [1.0, -4.0])


@pytest.mark.parametrize("text, match", [
    ("u / 2", "only numbers"),
    ("|u*v|", "one name"),
    ("u - u", "identically zero"),
    ("sin(u)", "only numbers"),
    ("u**9", "only numbers"),
    ("", "expected an expression"),
])
def test_bad_expressions_refused(text, match):
    with pytest.raises(ModelSpecError, match=match):
        DerivedSignal.parse("x", text)


@pytest.mark.parametrize("edit, match", [
    (("du = \"u - 1.0\"", "du = \"u*u\""), "must be affine"),
    (("uud = \"u*u*delta\"", "uud = \"u*u*delta\"\nzz = \"u\""), "neither a state nor an input"),
    (("uud = \"u*u*delta\"", "uud = \"du*delta\""), "uses derived signal"),
    (("du = \"u - 1.0\"", "du = \"v - 1.0\""), "itself a signal of the spec"),
])
def test_bad_derived_tables_refused(edit, match):
    with pytest.raises(ModelSpecError, match=match):
        ModelSpec.from_toml(SHIP.replace(*edit))


def test_toml_round_trip_and_measured_columns():
    spec = ModelSpec.from_toml(SHIP)
    assert ModelSpec.from_toml(spec.to_toml()) == spec
    assert spec.with_theta0(spec.theta0_vector()).derived == spec.derived
    assert spec.measured_columns == ("u", "v", "r", "delta")
    assert state_dependent(spec) == {"uud": ("u",)}
    assert "derived: uud = u*u*delta" in str(spec)
    with pytest.raises(LogValidationError, match="missing column 'u'"):
        add_derived(pd.DataFrame({"delta": [0.0]}), spec)


def test_noise_free_identification_with_derived_signals_is_exact():
    from vesselid.identify import identify

    spec = ModelSpec.from_toml(SHIP)
    parts = [zigzag_log(spec, delta0=a, psi_s=b, first=f).assign(experiment=i)
             for i, (a, b, f) in enumerate([(0.17, 0.17, 1), (0.35, 0.09, -1), (0.26, 0.17, -1),
                                            (0.35, 0.17, 1)])]
    log = pd.concat(parts, ignore_index=True)
    from vesselid.errors import DerivedInputWarning

    with pytest.warns(DerivedInputWarning, match=r"uud uses \['u'\]"):
        res = identify(log, spec, method="ls")
    np.testing.assert_allclose(np.asarray(res.params), spec.theta0_vector(), rtol=1e-6,
                               atol=1e-9)
