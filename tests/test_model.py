"""ModelSpec: structure checks and the TOML contract of docs/architecture.md."""

import numpy as np
import pandas as pd
import pytest

from vesselid.errors import ModelSpecError
from vesselid.model.spec import Aggregate, ModelSpec

HEAVE_TOML = """
name = "heave"
states = ["w"]            # one measured column per state, same name, in logs
inputs = ["tau"]          # one column per input
dt = 1.0                  # sample time, optional

[equations]
w = ["w", "w*|w|", "tau"]

[theta0]
w = [0.99, -0.1, 1.0]

[aggregate]
w = "w - w_c"
"""


def heave_spec(**kw):
    args = dict(name="heave", states=["w"], inputs=["tau"],
                equations={"w": ["w", "w*|w|", "tau"]}, theta0={"w": [0.99, -0.1, 1.0]},
                aggregate={"w": "w - w_c"}, dt=1.0)
    args.update(kw)
    return ModelSpec(**args)


def test_design_md_example_parses():
    spec = ModelSpec.from_toml(HEAVE_TOML)
    assert spec == heave_spec()
    assert spec.sensors == ("w_c",)
    assert spec.aggregate["w"] == Aggregate("w", "w_c", -1)
    np.testing.assert_array_equal(spec.theta0_vector(), [0.99, -0.1, 1.0])
    assert list(spec.param_index) == [("w", "w"), ("w", "w*|w|"), ("w", "tau")]


def test_toml_round_trip(tmp_path):
    spec = ModelSpec(name="m", states=["u", "r"], inputs=["X", "N"],
                     equations={"u": ["u", "u*|u|", "X"], "r": ["r", "u*r", "|r|*r", "N"]},
                     theta0={"u": [0.9, -0.1, 0.5], "r": [0.8, 0.01, -0.2, 0.3]})
    path = spec.save(tmp_path / "m.toml")
    assert ModelSpec.load(path) == spec
    assert ModelSpec.from_dict(spec.to_dict()) == spec


def test_theta0_series_is_labelled():
    s = heave_spec().theta0_series()
    assert isinstance(s, pd.Series)
    assert s.loc[("w", "w*|w|")] == -0.1


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"equations": {"w": ["w", "q*|w|"]}, "theta0": None}, "unknown signal 'q'"),
        ({"equations": {"w": []}, "theta0": None}, "equation of 'w' is empty"),
        ({"equations": {"w": ["w", "w"]}, "theta0": None}, "duplicate term"),
        ({"equations": {"w": ["w*tau", "tau*w"]}, "theta0": None}, "duplicate term"),
        ({"theta0": {"w": [1.0, 2.0]}}, "theta0 of 'w' has 2 values but the equation has 3"),
        ({"theta0": {"w": [1.0, float("nan"), 1.0]}}, "non-finite"),
        ({"equations": {"w": ["w"], "z": ["w"]}, "theta0": None}, "unknown states"),
        ({"aggregate": {"w": "w * w_c"}}, "aggregate relation"),
        ({"aggregate": {"w": "w - tau"}}, "must differ"),
        ({"inputs": ["w"]}, "unique"),
        ({"equations": {"w": ["w", "|w|*|tau|", "tau"]}}, "allowed forms"),
        ({"dt": -1.0}, "dt must be a positive"),
    ],
)
def test_spec_errors(kwargs, message):
    with pytest.raises(ModelSpecError, match=message):
        heave_spec(**kwargs)


def test_direct_aggregate_measurement():
    """Remark 4.3: a speed log measures the aggregated state itself."""
    spec = heave_spec(aggregate={"w": "w_log"})
    assert spec.aggregate["w"] == Aggregate("w", "w_log", 0)
    assert spec.sensors == ("w_log",)
    assert ModelSpec.from_toml(spec.to_toml()) == spec
    with pytest.raises(ModelSpecError, match="cannot be the state itself"):
        heave_spec(aggregate={"w": "w"})


def test_toml_errors(tmp_path):
    with pytest.raises(ModelSpecError, match="does not exist"):
        ModelSpec.load(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("states = [", encoding="utf-8")
    with pytest.raises(ModelSpecError, match="invalid TOML"):
        ModelSpec.load(bad)
    bad.write_text('states = ["w"]\n[equations]\nw=["w"]\n[extra]\n', encoding="utf-8")
    with pytest.raises(ModelSpecError, match="unknown model spec keys"):
        ModelSpec.load(bad)


def test_missing_theta0_is_reported():
    spec = heave_spec(theta0=None)
    with pytest.raises(ModelSpecError, match="has no theta0"):
        spec.theta0_vector()


def test_with_theta0_and_aggregate():
    spec = heave_spec()
    assert spec.with_aggregate(None).aggregate == {}
    new = spec.with_theta0(np.array([1.0, 2.0, 3.0]))
    assert new.theta0 == {"w": (1.0, 2.0, 3.0)}


def test_merge_terms_folds_coefficient():
    spec = ModelSpec("m", ["v", "r"], ["N"],
                     {"v": ["v", "v*|r|", "r*|v|", "N"], "r": ["r", "r*|v|", "|r|*v", "N"]},
                     theta0={"v": [0.9, 0.2, 0.5, 1.0], "r": [0.8, 0.3, 0.1, 2.0]})
    merged = spec.merge_terms("r*|v|", "v*|r|", -1.0)
    assert [str(t) for t in merged.equations["v"]] == ["v", "r*|v|", "N"]
    assert merged.theta0["v"] == (0.9, 0.5 - 0.2, 1.0)
    # |r|*v is the same term as v*|r|: folded too
    assert merged.theta0["r"] == (0.8, 0.3 - 0.1, 2.0)
    rng = np.random.default_rng(0)
    v, r = rng.uniform(0.1, 1, 50), -rng.uniform(0.1, 1, 50)  # opposite signs
    full = 0.9 * v + 0.2 * v * np.abs(r) + 0.5 * r * np.abs(v)
    np.testing.assert_allclose(full, 0.9 * v + 0.3 * r * np.abs(v))
