"""Streaming identification of Parquet logs (bounded memory) and on a Dask cluster."""

from __future__ import annotations

import warnings

import numpy as np
import pyarrow  # noqa: F401  (a missing test dependency fails)
import pytest

from vesselid.data.logs import TrialLog
from vesselid.identify import identify
from vesselid.identify.streaming import ParquetExperiments, identify_stream
from vesselid.plant.catalogue import get_system


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    sim = get_system("heave").simulate(2000, n_runs=4, seed=21)
    log = sim.to_log()
    frame = log.data
    # two files (two "vessels"), two experiments each
    for i, ids in enumerate(([0, 1], [2, 3])):
        part = frame[frame["experiment"].isin(ids)].reset_index(drop=True)
        TrialLog(part, log.metadata).save(d / f"vessel{i}.parquet")
    return d, log


def _same_cov(got, ref, rtol=1e-10):
    """Covariances equal to ``rtol`` of the largest entry (the sandwich is summed in
    another order; the estimates themselves are bit-identical)."""
    c1, c2 = got.cov.to_numpy(), ref.cov.to_numpy()
    assert np.all(np.isfinite(c1))
    assert np.max(np.abs(c1 - c2)) <= rtol * np.max(np.abs(c2))
    np.testing.assert_allclose(got.std_errors.to_numpy(), ref.std_errors.to_numpy(), rtol=1e-9)


@pytest.mark.parametrize(("method", "combine", "cov_type", "cov_config"), [
    ("ls", "pooled", None, None),                                   # default HAC
    ("iv-zero-mean", "pooled", None, None),                         # fixed-b scaled
    ("iv-zero-mean", "pooled", "hac", {"fixed_b": False}),
    ("iv", "pooled", "hac", {"bandwidth": 12}),                      # fixed-b, fixed lags
    ("iv", "stacked", "unadjusted", None),
    ("iv-zero-mean", "stacked", "cluster", None),
    ("iv-zero-mean", "pooled", "hac", {"bandwidth": "andrews", "kernel": "parzen"}),
    ("iv-zero-mean", "pooled", "hac", {"kernel": "qs"}),             # all lags: 2nd pass
    ("ls", "pooled", "hac", {"bandwidth": 80}),                      # fixed, > KEEP_LAGS
])
def test_streamed_equals_in_memory(logs, method, combine, cov_type, cov_config):
    d, log = logs
    src = ParquetExperiments(d)
    assert len(src) == 4
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = identify(log, method=method, combine=combine, cov_type=cov_type,
                       cov_config=cov_config)
    got = identify_stream(src, method=method, combine=combine, cov_type=cov_type,
                          cov_config=cov_config)
    np.testing.assert_allclose(got.params.to_numpy(), ref.params.to_numpy(), rtol=1e-12,
                               atol=1e-14)
    _same_cov(got, ref)
    assert got.iterations == ref.iterations
    assert got.n_experiments == 4 and got.n_samples == ref.n_samples
    assert got.diagnostics["passes"] >= 2
    assert got.diagnostics["cov_label"] == ref.diagnostics["cov_label"]
    scaled = method != "ls" and combine == "pooled" and cov_type in (None, "hac") and (
        (cov_config or {}).get("kernel", "bartlett") == "bartlett")
    assert ("fixed-b" in got.diagnostics["cov_label"]) == (
        scaled and (cov_config or {}).get("fixed_b", True))
    for key in ("fit_one_step", "fit_free_run", "instrument_condition"):
        for state, value in ref.diagnostics[key].items():
            assert got.diagnostics[key][state] == pytest.approx(value, rel=1e-9)


def test_streamed_result_is_an_identification_result(logs, tmp_path):
    from vesselid.identify import IdentificationResult
    from vesselid.model.spec import ModelSpec

    d, _ = logs
    got = identify_stream(d)
    assert isinstance(got, IdentificationResult) and got.method == "iv-zero-mean"
    text = got.summary()
    assert "streamed" in text and "HAC" in text
    assert np.all(np.isfinite(got.conf_int().to_numpy()))
    back = ModelSpec.load(got.export(tmp_path / "model.toml"))
    np.testing.assert_allclose(back.theta0_series().to_numpy(), got.params.to_numpy())
    assert '"stderr"' in got.to_json()


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"method": "auto"}, "not a sum over experiments"),
    ({"method": "gmm"}, "supports methods"),
    ({"cov_type": "hac", "cov_config": {"prewhiten": True}}, "pre-whiten"),
    ({"cov_type": "nope"}, "nope"),
    ({"combine": "mean"}, "combine"),
])
def test_streaming_refuses_what_it_cannot_do(logs, kwargs, words):
    from vesselid.errors import IdentificationError

    d, _ = logs
    with pytest.raises(IdentificationError, match=words):
        identify_stream(d, **kwargs)


def test_not_parquet_is_a_clear_error(tmp_path):
    from vesselid.errors import LogValidationError

    bad = tmp_path / "trial.parquet"
    bad.write_text("time,w\n0,1\n")
    with pytest.raises(LogValidationError, match="not a readable Parquet"):
        ParquetExperiments(bad)
    with pytest.raises(LogValidationError, match="no Parquet"):
        (tmp_path / "empty").mkdir()
        ParquetExperiments(tmp_path / "empty")


def test_cli_identify_stream(logs, tmp_path, capsys):
    import json

    from vesselid.cli import main

    d, _log = logs
    out = tmp_path / "r.json"
    assert main(["identify", str(d), "--stream", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["method"] == "iv-zero-mean" and res["cov_type"] == "hac"
    assert all(v > 0 for eq in res["stderr"].values() for v in eq.values())
    assert res["diagnostics"]["streamed"] is True
    capsys.readouterr()
    assert main(["identify", str(d), "--stream", "--method", "auto"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot be streamed" in err[0]
    # the size guard looks at the largest experiment, not the whole directory
    monkey = pytest.MonkeyPatch()
    monkey.setenv("VESSELID_MAX_MEMORY", "1M")
    try:
        assert main(["identify", str(d), "--stream"]) == 2
    finally:
        monkey.undo()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "largest experiment ~2e+03 rows" in err[0]


def test_dask_cluster_equals_local(logs):
    import distributed
    d, _log = logs
    local = identify_stream(d, method="iv-zero-mean")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        remote = identify_stream(d, method="iv-zero-mean", client=client)
    np.testing.assert_array_equal(remote.params.to_numpy(), local.params.to_numpy())
    np.testing.assert_array_equal(remote.cov.to_numpy(), local.cov.to_numpy())
