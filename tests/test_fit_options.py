"""The options of an estimation as one typed object (:class:`FitOptions`): validated in
one place with one-line errors, passed through ``identify`` and ``Estimator.fit`` with
the same results as the keywords."""

import dataclasses
import warnings

import numpy as np
import pytest

from vesselid.errors import IdentificationError
from vesselid.identify import FitOptions, get_estimator, identify
from vesselid.identify.options import FitOptionsError
from vesselid.plant.systems import heave

BAD = [
    ("combine", "nonsense", "unknown combine 'nonsense'"),
    ("target", "both", "unknown target 'both'"),
    ("cov_type", 3, "cov_type must be"),
    ("cov_config", [1, 2], "cov_config must be"),
    ("instruments", "z", "instruments must be"),
    ("max_iter", 0, "max_iter must be a positive integer"),
    ("max_iter", 2.5, "max_iter must be a positive integer"),
    ("max_iter", True, "max_iter must be a positive integer"),
    ("tol", -1e-9, "tol must be a positive number"),
    ("tol", float("nan"), "tol must be a positive number"),
    ("tol", "1e-9", "tol must be a positive number"),
    ("eta", {"w": -0.1}, "eta must map states"),
    ("eta", {"w": float("inf")}, "eta must map states"),
    ("design_threshold", 1.5, r"design_threshold must be a number in \[0, 1\]"),
    ("weak_instrument_cond", 0.0, "weak_instrument_cond must be a positive number"),
    ("min_samples", 0, "min_samples must be a positive integer"),
    ("sensor_noise", 0.01, "sensor_noise must map states"),
    ("noise_order", 0, "noise_order must be an integer in 1..50"),
    ("noise_order", 51, "noise_order must be an integer in 1..50"),
]


@pytest.fixture(scope="module")
def log():
    return heave().simulate(2000, n_runs=2, seed=3).to_log()


@pytest.mark.parametrize(("name", "value", "message"), BAD)
def test_a_bad_value_is_a_one_line_value_error(name, value, message):
    with pytest.raises(FitOptionsError, match=message) as exc:
        FitOptions(**{name: value})
    assert isinstance(exc.value, IdentificationError) and isinstance(exc.value, ValueError)
    text = str(exc.value)
    assert "\n" not in text and text.startswith(("unknown " + name, name))
    assert repr(value) in text


@pytest.mark.parametrize(("name", "value", "message"), BAD[:3] + BAD[5:6] + BAD[-2:-1])
def test_identify_refuses_bad_values_before_any_work(log, name, value, message):
    with pytest.raises(FitOptionsError, match=message):
        identify(log, method="iv-zero-mean", **{name: value})


def test_unknown_name_is_a_type_error_and_the_object_is_frozen():
    with pytest.raises(TypeError, match="max_iters"):
        FitOptions(max_iters=3)
    with pytest.raises(TypeError, match="options must be FitOptions or a mapping"):
        FitOptions.of(3)
    opts = FitOptions(max_iter=7)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.max_iter = 8  # type: ignore[misc]
    both = FitOptions.of(opts, tol=1e-6)
    assert (both.max_iter, both.tol, opts.tol) == (7, 1e-6, 1e-9)
    assert FitOptions.of({"combine": "stacked"}, max_iter=5) == FitOptions(combine="stacked",
                                                                            max_iter=5)
    assert FitOptions.of(opts) is opts
    assert FitOptions.of(None).as_dict() == FitOptions().as_dict()
    assert FitOptions(eta={"w": 0.0}, design_threshold=0, weak_instrument_cond=np.inf)


def test_object_and_keywords_give_the_same_result(log):
    kw = {"combine": "stacked", "max_iter": 40, "tol": 1e-8, "cov_type": "unadjusted"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        by_kw = identify(log, method="iv-zero-mean", **kw)
        by_obj = identify(log, method="iv-zero-mean", options=FitOptions(**kw))
        overridden = identify(log, method="iv-zero-mean",
                              options=FitOptions(**{**kw, "max_iter": 3}), max_iter=40)
        direct = get_estimator("iv-zero-mean").fit(log, None, FitOptions(**kw))
    for res in (by_obj, overridden, direct):
        np.testing.assert_array_equal(res.params.to_numpy(), by_kw.params.to_numpy())
        np.testing.assert_array_equal(res.cov.to_numpy(), by_kw.cov.to_numpy())
        assert res.diagnostics["combine"] == "stacked"
        assert res.iterations == by_kw.iterations
