"""auto's specification check on multi-state logs (vesselid.identify.misspecification)."""

from __future__ import annotations

import copy
import math
import warnings
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from vesselid.data.logs import TrialLog
from vesselid.errors import MisspecificationWarning
from vesselid.identify import identify
from vesselid.identify import misspecification as ms
from vesselid.identify._special import norm_ppf
from vesselid.model.spec import ModelSpec


@pytest.fixture(scope="module")
def ship(tmp_path_factory):
    from vesselid.cli import main

    d = tmp_path_factory.mktemp("ship")
    assert main(["simulate", "--system", "cybership2", "--samples", "400", "--seed", "2",
                 "--out", str(d / "s.csv")]) == 0
    log, spec = TrialLog.load(d / "s.csv"), ModelSpec.load(d / "s.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        base = identify(log, spec, method="ls")
    return log, spec, base


def _shifted(res, method, shift_se=None, at=0):
    """A copy of ``res`` named ``method`` with parameter ``at`` moved by ``shift_se`` of its
    standard errors (and the fit's diagnostics of an accepted result)."""
    out = replace(res, method=method, diagnostics=copy.deepcopy(res.diagnostics),
                  params=res.params.copy())
    if shift_se is not None:
        out.params.iloc[at] += shift_se * float(res.std_errors.iloc[at])
    return out


def test_bounded_hausman_by_hand(ship):
    _log, _spec, base = ship
    p = base.params.size
    a = _shifted(base, "a", 5.0, at=3)
    out = ms.bounded_hausman(a, base, alpha=0.01)
    # |Δθ| = 5 se, summed standard errors 2 se: statistic 2.5 at the shifted parameter
    assert math.isclose(out["statistic"], 2.5, rel_tol=1e-12)
    eq, term = base.params.index[3]
    assert out["parameter"] == f"{eq}: {term}"
    assert math.isclose(out["critical"], float(norm_ppf(1 - 0.01 / (2 * p))), rel_tol=1e-15)
    assert out["rejected"] is False  # 2.5 < z_{1-0.01/(2P)} for P > 2
    assert math.isclose(out["pvalue_bound"], min(1.0, p * math.erfc(2.5 / math.sqrt(2))))
    far = ms.bounded_hausman(_shifted(base, "a", 20.0, at=3), base, alpha=0.01)
    assert far["rejected"] and math.isclose(far["statistic"], 10.0, rel_tol=1e-12)
    assert ms.bounded_hausman(base, base)["statistic"] == 0.0


def test_bounded_hausman_without_standard_errors_does_not_reject(ship):
    _log, _spec, base = ship
    cov = base.cov.copy()
    cov.iloc[0, 0] = np.nan
    out = ms.bounded_hausman(replace(base, cov=cov), _shifted(base, "b", 50.0))
    assert out["rejected"] is False and math.isnan(out["statistic"])


def _patch_fits(monkeypatch, results):
    def fake(method, log, spec, options):
        res = results[method]
        if isinstance(res, str):
            return None, [], res
        return res, [], ""
    monkeypatch.setattr(ms, "_fit", fake)


def test_agreeing_estimates_keep_sriv(ship, monkeypatch):
    log, spec, base = ship
    sriv = _shifted(base, "auto", 1.0)
    _patch_fits(monkeypatch, {"iv-zero-mean": _shifted(base, "iv-zero-mean"), "iv": "unused"})
    out, caught = ms.check_default(sriv, [], log, spec, {})
    assert out is sriv and caught == []
    check = out.diagnostics["specification_check"]
    assert check["prefilter"]["rejected"] is False and check["levels"] is None
    assert "no sign of misspecification" in check["sentence"]


def test_misspecified_without_offsets_returns_plain_iv(ship, monkeypatch):
    log, spec, base = ship
    sriv = _shifted(base, "auto", 30.0, at=2)
    zm = _shifted(base, "iv-zero-mean")
    plain = _shifted(base, "iv", 1.0, at=2)
    _patch_fits(monkeypatch, {"iv-zero-mean": zm, "iv": plain})
    out, caught = ms.check_default(sriv, [], log, spec, {})
    assert out is plain
    d = out.diagnostics
    assert d["choice"] == "iv" and d["specification_check"]["prefilter"]["rejected"]
    assert not d["specification_check"]["levels"]["rejected"]
    assert "misspecified" in d["choice_reason"] and "without constants" in d["choice_reason"]
    assert len(caught) == 1 and caught[0].category is MisspecificationWarning
    assert d["warnings"][0] == str(caught[0].message)


def test_misspecified_with_offsets_returns_zero_mean_iv(ship, monkeypatch):
    log, spec, base = ship
    sriv = _shifted(base, "auto", 30.0, at=2)
    zm = _shifted(base, "iv-zero-mean")
    plain = _shifted(base, "iv", 30.0, at=5)
    _patch_fits(monkeypatch, {"iv-zero-mean": zm, "iv": plain})
    out, _caught = ms.check_default(sriv, [], log, spec, {})
    assert out is zm and out.diagnostics["choice"] == "iv-zero-mean"
    assert out.diagnostics["specification_check"]["levels"]["rejected"]
    assert "mean disturbances" in out.diagnostics["choice_reason"]
    # plain IV without a usable estimate: IV_E{ζ}=0 as well
    _patch_fits(monkeypatch, {"iv-zero-mean": _shifted(base, "iv-zero-mean"),
                              "iv": "iv: no instrument could be formed"})
    out, _caught = ms.check_default(_shifted(base, "auto", 30.0, at=2), [], log, spec, {})
    assert out.method == "iv-zero-mean" and "not usable" in out.diagnostics["choice_reason"]


def test_unusable_comparison_keeps_sriv(ship, monkeypatch):
    log, spec, base = ship
    sriv = _shifted(base, "auto", 30.0)
    _patch_fits(monkeypatch, {"iv-zero-mean": "iv-zero-mean: singular", "iv": "unused"})
    out, _ = ms.check_default(sriv, [], log, spec, {})
    assert out is sriv and "not run" in out.diagnostics["specification_check"]["sentence"]
    # a non-finite comparison estimate is not usable either
    bad = _shifted(base, "iv-zero-mean")
    bad.params.iloc[0] = np.nan
    _patch_fits(monkeypatch, {"iv-zero-mean": bad, "iv": "unused"})
    out, _ = ms.check_default(_shifted(base, "auto", 30.0), [], log, spec, {})
    assert out.method == "auto"


def test_auto_runs_the_check_only_on_its_multi_state_sriv_choice(ship, monkeypatch):
    log, spec, _base = ship
    calls = []
    monkeypatch.setattr(ms, "check_default",
                        lambda res, caught, *a: (calls.append(res.method), (res, caught))[1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, spec, method="auto", fallback=False)
    assert calls == (["auto"] if res.diagnostics.get("choice") == "sriv" else [])
    assert isinstance(res.params, pd.Series)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        identify(log, spec, method="sriv", fallback=False)  # an explicit choice is kept
    assert calls == (["auto"] if res.diagnostics.get("choice") == "sriv" else [])


@pytest.mark.slow
def test_correct_structure_keeps_sriv_end_to_end(tmp_path):
    """A simulated sea trial (the spec is the simulated structure): auto's tests reject the
    delayed instruments, SRIV is reached and the check keeps it — with the statistic far
    below the critical value, as the size bound predicts for a correct model."""
    from vesselid.cli import main

    assert main(["sea-trial", "--vessel", "cybership2", "--experiments", "3", "--samples",
                 "4000", "--seed", "1", "--out", str(tmp_path / "st")]) == 0
    log = TrialLog.load(tmp_path / "st" / "seatrial.parquet")
    spec = ModelSpec.load(tmp_path / "st" / "cybership2.toml")
    from vesselid.studies.planner import SRIV_ORDER

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = identify(log, spec, noise_order=SRIV_ORDER)  # as sea-trial's command says
    assert res.method == "auto" and res.diagnostics["choice"] == "sriv"
    pre = res.diagnostics["specification_check"]["prefilter"]
    assert not pre["rejected"] and pre["statistic"] < pre["critical"]
    assert not any(w.category is MisspecificationWarning for w in caught)
    assert res.status == "ok"
