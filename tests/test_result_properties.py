"""Typed diagnostic properties of ``IdentificationResult``: each equals its JSON entry."""

from __future__ import annotations

import dataclasses
import json
import re
import warnings
from pathlib import Path

import pytest

from vesselid.identify import identify
from vesselid.identify.diagnostic_records import (
    FallbackAttempt,
    StabilityReport,
    TestStatistic,
    plain,
)
from vesselid.identify.results import IdentificationResult
from vesselid.plant.catalogue import get_system

DOC = Path(__file__).resolve().parents[1] / "docs" / "guide" / "diagnostics.md"


@pytest.fixture(scope="module")
def log():
    return get_system("heave").simulate(3000, seed=3).to_log()


@pytest.fixture(scope="module")
def fits(log):
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for method in ("auto", "lagged-2sls", "pem", "ls"):
            out[method] = identify(log, method=method)
    return out


def _typed_as_json(result: IdentificationResult, key: str):
    value = getattr(result, key)
    if key == "design":
        return json.loads(value.to_json(orient="records"))
    if key == "residual_correlation":
        return value.to_dict()
    return plain(value)


@pytest.mark.parametrize("method", ["auto", "lagged-2sls", "pem", "ls"])
def test_every_entry_has_a_property_equal_to_its_json(fits, method):
    result = fits[method]
    doc = result.to_dict()
    assert set(result.diagnostics) <= set(IdentificationResult.DIAGNOSTICS)
    for key in result.diagnostics:
        entry = doc["diagnostics"][key] if key in doc["diagnostics"] else doc[key]
        assert _typed_as_json(result, key) == entry, key


def test_streamed_result(log, tmp_path):
    from vesselid.identify.streaming import identify_stream

    log.save(tmp_path / "log.parquet")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = identify_stream(tmp_path)
    doc = result.to_dict()["diagnostics"]
    assert set(result.diagnostics) <= set(IdentificationResult.DIAGNOSTICS)
    for key in result.diagnostics:
        assert _typed_as_json(result, key) == doc[key], key
    assert result.streamed is True and result.passes >= 1


def test_json_rebuilt_from_the_properties(fits):
    """The typed view is lossless: the ``--json`` diagnostics follow from the properties."""
    result = fits["auto"]
    doc = json.loads(result.to_json())
    rebuilt = {k: _typed_as_json(result, k) for k in result.diagnostics}
    top = ("stability", "fallback_chain", "smoothness", "excitation")
    assert {k: v for k, v in rebuilt.items() if k not in top} == doc["diagnostics"]
    assert {k: rebuilt[k] for k in top} == {k: doc[k] for k in top}


def test_typed_values(fits):
    auto = fits["auto"]
    white = auto.whiteness["w"]
    assert isinstance(white, TestStatistic)
    assert white.stat == auto.diagnostics["whiteness"]["w"]["stat"]
    assert white.pval == white.pvalue == auto.diagnostics["whiteness"]["w"]["pvalue"]
    assert white.df == 20 and white.name == "Ljung-Box"
    assert isinstance(auto.stability, StabilityReport)
    assert auto.stability.stable is True
    assert auto.stability.spectral_radius.max == \
        auto.diagnostics["stability"]["spectral_radius"]["max"]
    assert all(isinstance(a, FallbackAttempt) for a in auto.fallback_chain)
    assert auto.fallback_chain[-1].outcome == "accepted"
    fs = auto.first_stage["w"]
    assert fs.cragg_donald == auto.diagnostics["specification"]["w"]["first_stage"]["cragg_donald"]
    assert auto.endogeneity["w"].pvalue == \
        auto.diagnostics["specification"]["w"]["endogeneity"]["pvalue"]
    assert auto.parameter_stability.stat == auto.diagnostics["parameter_stability"]["statistic"]
    assert auto.feedback.stat == auto.diagnostics["feedback"]["statistic"]
    assert auto.fit_one_step["w"] == auto.diagnostics["fit_one_step"]["w"]
    assert auto.design.equals(auto.diagnostics["design"])
    assert auto.residual_correlation.acf.shape[0] == 1
    assert fits["lagged-2sls"].sargan_hansen_j[0].df == \
        fits["lagged-2sls"].diagnostics["sargan_hansen_j"][0]["df"]
    assert fits["pem"].log_likelihood["current"] == \
        fits["pem"].diagnostics["log_likelihood"]["current"]


def test_absent_entries_are_none(fits):
    ls = fits["ls"]
    for key in ("hansen_j_combined", "parameter_stability", "sargan_hansen_j", "instruments",
                "log_likelihood", "stall_average", "mean_current", "controller"):
        assert key not in ls.diagnostics
        assert getattr(ls, key) is None, key


def test_records_are_read_only(fits):
    auto = fits["auto"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        auto.stability.stable = False  # type: ignore[misc]
    with pytest.raises(TypeError):
        auto.fit_one_step["w"] = 0.0  # type: ignore[index]
    with pytest.raises(TypeError):
        auto.whiteness["w"] = None  # type: ignore[index]


def test_properties_follow_later_entries(fits):
    """Entries added after construction (the fallback path adds its chain) are read."""
    result = dataclasses.replace(fits["ls"], diagnostics=dict(fits["ls"].diagnostics))
    result.diagnostics["fallback_chain"] = [{"method": "ls", "outcome": "accepted",
                                             "reason": "test"}]
    assert result.fallback_chain == (FallbackAttempt(method="ls", outcome="accepted",
                                                     reason="test"),)


def test_unknown_keys_are_kept():
    entry = {"stat": 1.5, "df": 2, "pvalue": 0.47, "lags": 4}
    rec = TestStatistic.from_dict(entry)
    assert rec.extra == {"lags": 4}
    assert rec.to_dict() == entry and list(rec.to_dict()) == list(entry)


def test_properties_documented():
    text = DOC.read_text(encoding="utf-8").split("## 7. Typed diagnostics", 1)[1]
    listed = re.findall(r"^\| `([a-z_0-9]+)` \|", text, flags=re.M)
    assert tuple(listed) == IdentificationResult.DIAGNOSTICS
    for name in IdentificationResult.DIAGNOSTICS:
        prop = getattr(IdentificationResult, name)
        assert isinstance(prop, property) and prop.__doc__, name
