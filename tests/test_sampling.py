"""identify's sampling check: the log's time steps against the spec's dt."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from vesselid.cli import main
from vesselid.data.sampling import SamplingError, check_sampling


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    d = tmp_path_factory.mktemp("dt")
    assert main(["simulate", "--samples", "400", "--experiments", "2", "--seed", "3",
                 "--out", str(d / "t.csv")]) == 0
    return d


def _with_time(sim, tmp_path, fn, name="x.csv"):
    frame = pd.read_csv(sim / "t.csv")
    frame = fn(frame)
    frame.to_csv(tmp_path / name, index=False)
    return str(tmp_path / name)


def _identify(path, spec, capsys, *extra):
    code = main(["identify", path, "--model", str(spec), "--method", "ls", *extra])
    return code, capsys.readouterr().err.strip()


def test_matching_dt_passes(sim, capsys):
    code, _err = _identify(str(sim / "t.csv"), sim / "t.toml", capsys)
    assert code == 0


def test_dt_mismatch_is_refused_naming_ingest_dt(sim, tmp_path, capsys):
    path = _with_time(sim, tmp_path, lambda f: f.assign(time=f["time"] * 0.1))
    code, err = _identify(path, sim / "t.toml", capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert "sampled every 0.1 s" in err and "spec's dt is 1 s" in err
    assert "ingest RAW --dt 1" in err


def test_jittered_time_is_refused(sim, tmp_path, capsys):
    rng = np.random.default_rng(0)

    def jitter(f):
        out = []
        for _e, g in f.groupby("experiment"):
            out.append(np.cumsum(rng.uniform(0.05, 3.0, len(g))))
        return f.assign(time=np.concatenate(out))

    path = _with_time(sim, tmp_path, jitter)
    code, err = _identify(path, sim / "t.toml", capsys)
    assert code == 2 and len(err.splitlines()) == 1
    assert "irregular sampling in experiment 0" in err and "--dt 1" in err


def test_tolerance_option(sim, tmp_path, capsys):
    # one step 3 % long: refused at the default 1 %, accepted with --dt-tolerance 0.05
    def stretch(f):
        t = f["time"].to_numpy(dtype=float).copy()
        t[10:200] += 0.03
        return f.assign(time=t)

    path = _with_time(sim, tmp_path, stretch)
    code, err = _identify(path, sim / "t.toml", capsys)
    assert code == 2 and "beyond the 1 % tolerance" in err
    code, _ = _identify(path, sim / "t.toml", capsys, "--dt-tolerance", "0.05")
    assert code == 0
    code, err = _identify(path, sim / "t.toml", capsys, "--dt-tolerance", "2")
    assert code == 2 and "fraction" in err


def test_no_time_column_is_taken_at_the_spec_dt(sim, tmp_path, capsys):
    path = _with_time(sim, tmp_path, lambda f: f.drop(columns=["time"]))
    code, _ = _identify(path, sim / "t.toml", capsys)
    assert code == 0


def test_spec_without_dt_checks_regularity_only(sim, tmp_path, capsys):
    spec = tmp_path / "nodt.toml"
    spec.write_text("\n".join(ln for ln in (sim / "t.toml").read_text().splitlines()
                              if not ln.startswith("dt")) + "\n")
    path = _with_time(sim, tmp_path, lambda f: f.assign(time=f["time"] * 0.1))
    assert _identify(path, spec, capsys)[0] == 0
    path = _with_time(sim, tmp_path, lambda f: f.assign(
        time=f["time"] ** 1.5), name="y.csv")
    code, err = _identify(path, spec, capsys)
    assert code == 2 and "irregular sampling" in err


def test_check_sampling_api():
    f = pd.DataFrame({"experiment": [0] * 5 + [1] * 5,
                      "time": [0, .1, .2, .3, .4, 7, 7.1, 7.2, 7.3, 7.4]})
    rep = check_sampling(f, 0.1)
    assert rep.checked and abs(rep.interval - 0.1) < 1e-12 and rep.worst_step_deviation < 1e-9
    with pytest.raises(SamplingError, match="experiment 1"):
        check_sampling(f.assign(time=[0, .1, .2, .3, .4, 7, 7.2, 7.4, 7.6, 7.8]), 0.1)
    assert not check_sampling(f.drop(columns="time"), 0.1).checked
    assert isinstance(SamplingError("x"), ValueError)


# -------------------------------------------------- the Python identify() path
def _load(sim, fn=None):
    from vesselid.data.logs import TrialLog
    from vesselid.model.spec import ModelSpec

    log = TrialLog.load(sim / "t.csv")
    if fn is not None:
        log = TrialLog(fn(log.data.copy()), log.metadata)
    return log, ModelSpec.load(sim / "t.toml")


def test_identify_api_refuses_dt_mismatch(sim):
    from vesselid.identify import identify

    log, spec = _load(sim, lambda f: f.assign(time=f["time"] * 0.1))
    with pytest.raises(SamplingError) as exc:
        identify(log, spec, method="ls")
    msg = str(exc.value)
    assert len(msg.splitlines()) == 1
    assert "sampled every 0.1 s" in msg and "spec's dt is 1 s" in msg and "--dt 1" in msg
    # the DataFrame form of the log is checked too
    with pytest.raises(SamplingError, match=r"sampled every 0\.1 s"):
        identify(log.data, spec, method="ls")


def test_identify_api_refuses_irregular_sampling(sim):
    from vesselid.identify import identify

    rng = np.random.default_rng(1)

    def jitter(f):
        return f.assign(time=np.concatenate(
            [np.cumsum(rng.uniform(0.05, 3.0, len(g))) for _e, g in f.groupby("experiment")]))

    log, spec = _load(sim, jitter)
    for method in ("ls", "auto"):  # the default's fallback chain refuses it before any fit
        with pytest.raises(SamplingError, match=r"irregular sampling in experiment 0.*--dt 1"):
            identify(log, spec, method=method)


def test_identify_api_tolerance_and_opt_out(sim):
    from vesselid.errors import IdentificationError
    from vesselid.identify import identify

    def stretch(f):
        t = f["time"].to_numpy(dtype=float).copy()
        t[10:200] += 0.03
        return f.assign(time=t)

    log, spec = _load(sim, stretch)
    with pytest.raises(SamplingError, match="beyond the 1 % tolerance"):
        identify(log, spec, method="ls")
    ok = identify(log, spec, method="ls", dt_tolerance=0.05)
    exact = identify(_load(sim)[0], spec, method="ls")
    # the rows are the samples either way: the same estimate as the regular log
    assert np.array_equal(ok.params.to_numpy(), exact.params.to_numpy())
    scaled, _ = _load(sim, lambda f: f.assign(time=f["time"] * 0.1))
    assert identify(scaled, spec, method="ls", dt_tolerance=None).status == "ok"
    for bad in ("loose", True, [0.1]):
        with pytest.raises(IdentificationError, match="dt_tolerance"):
            identify(log, spec, method="ls", dt_tolerance=bad)
    with pytest.raises(SamplingError, match="tolerance"):
        identify(log, spec, method="ls", dt_tolerance=2.0)


def test_experiment_runs_match_groupby():
    """The run-boundary grouping of an experiment column gives pandas' groupby indices
    (keys, order, positions) or defers to it (interleaved or missing labels)."""
    from vesselid.data.sampling import _experiment_runs

    for col in (np.repeat([3, 1, 2], [4, 5, 6]), np.repeat(["b", "a"], [3, 3]),
                np.repeat([0.5, 1.5], [2, 2]), np.zeros(7, dtype=np.int64)):
        frame = pd.DataFrame({"experiment": col})
        ref = list(frame.groupby("experiment", sort=False).indices.items())
        got = _experiment_runs(frame["experiment"])
        assert [k for k, _ in got] == [k for k, _ in ref]
        assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(got, ref, strict=True))
    assert _experiment_runs(pd.Series(np.repeat([1, 2, 1], 2))) is None
    assert _experiment_runs(pd.Series([1.0, np.nan, 2.0])) is None
