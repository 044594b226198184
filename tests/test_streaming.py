"""Streaming identification of Parquet logs (bounded memory) and on a Dask cluster."""

from __future__ import annotations

import warnings

import numpy as np
import pyarrow  # noqa: F401  (a missing test dependency fails)
import pytest

from vesselid.identify import identify
from vesselid.logs import TrialLog
from vesselid.streaming import ParquetExperiments, identify_stream
from vesselid.systems import get_system


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


@pytest.mark.parametrize("method", ["ls", "iv-zero-mean"])
def test_streamed_equals_in_memory(logs, method):
    d, log = logs
    src = ParquetExperiments(d)
    assert len(src) == 4
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = identify(log, method=method)
    got = identify_stream(src, method=method)
    np.testing.assert_allclose(got.params.to_numpy(), ref.params.to_numpy(), rtol=1e-12,
                               atol=1e-14)
    assert got.iterations == ref.iterations
    assert got.n_experiments == 4 and got.passes >= 1


def test_dask_cluster_equals_local(logs):
    import distributed
    d, _log = logs
    local = identify_stream(d, method="iv-zero-mean")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        remote = identify_stream(d, method="iv-zero-mean", client=client)
    np.testing.assert_array_equal(remote.params.to_numpy(), local.params.to_numpy())
