"""The estimator registry: one source for names, labels, CLI choices; strict JSON."""

import json
import warnings

import numpy as np
import pandas as pd
import pytest

from vesselid.cli.app import build_parser, main
from vesselid.core.jsonio import dumps, strict
from vesselid.errors import IdentificationError
from vesselid.identify import (
    DEFAULT_METHOD,
    ESTIMATORS,
    PAPER_METHODS,
    Estimator,
    get_estimator,
    identify,
    method_labels,
)
from vesselid.identify.covariance_api import available as cov_names
from vesselid.plant.systems import heave


def _choices(parser, command: str, option: str) -> list[str]:
    sub = next(a for a in parser._actions if a.dest == "command")
    act = next(a for a in sub.choices[command]._actions if option in a.option_strings)
    return list(act.choices)


def test_registry_drives_cli_and_labels():
    parser = build_parser()
    assert _choices(parser, "identify", "--method") == list(ESTIMATORS)
    assert _choices(parser, "identify", "--cov") == cov_names()
    assert DEFAULT_METHOD in ESTIMATORS
    assert set(PAPER_METHODS) <= set(ESTIMATORS)
    for kind in ("short", "plot", "long"):
        labels = method_labels(kind)
        assert set(labels) == set(ESTIMATORS) and all(labels.values())
    for name, est in ESTIMATORS.items():
        assert isinstance(est, Estimator) and est.name == name


def test_unknown_options_are_one_line_errors():
    log = heave().simulate(300, seed=0).to_log()
    with pytest.raises(IdentificationError, match="unknown method 'nope'"):
        get_estimator("nope")
    with pytest.raises(IdentificationError, match="unknown cov_type"):
        identify(log, method="ls", cov_type="nope")
    with pytest.raises(IdentificationError, match="unknown target"):
        identify(log, method="ls", target="nope")
    with pytest.raises(IdentificationError, match="needs an \\[aggregate\\]"):
        identify(log, log.spec.with_aggregate(None), method="ls", target="aggregated")


def test_cli_bad_option_exits_two(tmp_path, capsys):
    log = tmp_path / "t.csv"
    assert main(["simulate", "--samples", "300", "--out", str(log)]) == 0
    # main() returns 2 on bad options (usage errors included) with a one-line reason
    assert main(["identify", str(log), "--method", "nope"]) == 2
    assert "--method" in capsys.readouterr().err
    assert main(["identify", str(log), "--max-iter", "0"]) == 2
    assert "--max-iter" in capsys.readouterr().err


def test_strict_json_has_no_non_finite_values():
    doc = {"a": np.float64("inf"), "b": [1.0, float("nan")], "c": np.arange(2),
           "d": {1: np.int64(3)}}
    assert strict(doc) == {"a": None, "b": [1.0, None], "c": [0, 1], "d": {"1": 3}}
    assert json.loads(dumps(doc)) == strict(doc)
    log = heave().simulate(2000, seed=0).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="ls")
    res.cov.iloc[0, 0] = np.inf
    res.__dict__.pop("std_errors", None)
    res.diagnostics["fit_free_run"] = {"w": float("nan")}
    text = res.to_json()
    assert "Infinity" not in text and "NaN" not in text
    payload = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict {c}"))
    assert payload["stderr"]["w"]["w"] is None


def test_aggregated_target_matches_monte_carlo_table2_path():
    """identify(target='aggregated') and the Monte Carlo path of reproduce --table 2 give
    the same estimates on the same data (one documented target rule)."""
    from vesselid.identify import from_arrays
    from vesselid.identify.estimators import estimate

    system = heave(current_mean=0.1, current_sensor=True)
    sim = system.simulate(3000, seed=3)
    spec = system.identification_spec(aggregate=True)
    data = from_arrays(spec, sim.y, sim.u, y2=sim.y2)
    from dataclasses import replace

    mc = estimate(replace(data, target=data.regsig), spec, "iv-zero-mean").theta[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(sim.to_log(), spec, method="iv-zero-mean", target="aggregated")
        measured = identify(sim.to_log(), spec, method="iv-zero-mean")
    np.testing.assert_allclose(res.params.to_numpy(), mc, rtol=1e-10)
    assert res.diagnostics["target"] == "aggregated"
    assert measured.diagnostics["target"] == "measured"
    assert not np.allclose(measured.params.to_numpy(), mc)
    assert isinstance(res.params, pd.Series)
