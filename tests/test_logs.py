"""Tests of vesselid.data.logs: trial log validation, exact save/load round trips, atomicity."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from pandas.testing import assert_frame_equal

from vesselid.data.logs import PARQUET_METADATA_KEY, TrialLog, concat_logs
from vesselid.errors import LogValidationError
from vesselid.model.spec import ModelSpec


@pytest.fixture
def spec() -> ModelSpec:
    return ModelSpec(
        name="heave",
        states=["w"],
        inputs=["tau"],
        equations={"w": ["w", "w*|w|", "tau"]},
        theta0={"w": [0.99, -0.1, 1.0]},
        aggregate={"w": "w - w_c"},
    )


def make_frame(n_exp: int = 2, n: int = 50, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    m = n_exp * n
    # awkward floats: tiny, huge, subnormal, negative zero, many digits
    w = rng.standard_normal(m) * 10.0 ** rng.integers(-300, 300, m)
    w[0] = 5e-324
    w[1] = -0.0
    w[2] = 0.1 + 0.2
    return pd.DataFrame(
        {
            "experiment": np.repeat(np.arange(n_exp), n),
            "time": np.tile(np.arange(n) * 0.1, n_exp),
            "w": w,
            "tau": rng.standard_normal(m),
            "w_c": rng.standard_normal(m) / 3.0,
            "true_w": rng.standard_normal(m) * np.pi,
            "true_w_c": rng.standard_normal(m).astype(np.float32),
        }
    )


@pytest.fixture
def log(spec: ModelSpec) -> TrialLog:
    metadata = {
        "spec": spec.to_dict(),
        "vesselid_version": "0.1.0",
        "seed": 1234,
        "system": "heave",
        "disturbances": {"current": {"kind": "ou", "sigma": 0.05, "tau": 1 / 3}},
        "inputs": {"kind": "prbs", "amplitude": 1.0},
    }
    return TrialLog(make_frame(), metadata)


# ------------------------------------------------------------------------- round trip
@pytest.mark.parametrize("name", ["trial.csv", "trial.parquet", "trial.pq"])
def test_round_trip_is_exact(tmp_path: Path, log: TrialLog, spec: ModelSpec, name: str) -> None:
    path = log.save(tmp_path / name)
    assert path == tmp_path / name
    loaded = TrialLog.load(path)
    assert_frame_equal(loaded.data, log.data, check_exact=True)
    assert loaded.data["experiment"].dtype == np.int64
    assert loaded.data["true_w_c"].dtype == np.float32
    # bit-for-bit, including the sign of zero and subnormals
    np.testing.assert_array_equal(
        loaded.data["w"].to_numpy().view(np.int64), log.data["w"].to_numpy().view(np.int64)
    )
    assert loaded.metadata == log.metadata
    assert loaded.spec == spec
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [name, "trial.json"] if name.endswith(".csv") else [name]
    )


def test_csv_sidecar_contents(tmp_path: Path, log: TrialLog) -> None:
    log.save(tmp_path / "trial.csv")
    sidecar = json.loads((tmp_path / "trial.json").read_text())
    assert sidecar["metadata"] == log.metadata
    assert sidecar["dtypes"]["experiment"] == "int64"
    assert sidecar["vesselid_version"] == "0.1.0"
    header = (tmp_path / "trial.csv").read_text().splitlines()[0]
    assert header == "experiment,time,w,tau,w_c,true_w,true_w_c"


def test_parquet_metadata_in_schema(tmp_path: Path, log: TrialLog) -> None:
    import pyarrow.parquet as pq
    log.save(tmp_path / "trial.parquet")
    schema_meta = pq.read_schema(tmp_path / "trial.parquet").metadata
    assert json.loads(schema_meta[PARQUET_METADATA_KEY])["metadata"] == log.metadata


def test_round_trip_other_dtypes(tmp_path: Path) -> None:
    data = pd.DataFrame(
        {
            "experiment": [3, 3, 7],
            "flag": [True, False, True],
            "label": ["a", "007", "c"],
            "x": [1.0, np.nan, np.inf],
            "n": np.array([1, 2, 3], dtype=np.int32),
        }
    )
    meta = {"seed": np.int64(5), "arr": np.array([1.5, 2.5])}
    log = TrialLog(data, meta)
    for name in ("t.csv", "t.parquet"):
        loaded = TrialLog.load(log.save(tmp_path / name), validate=False)
        assert_frame_equal(loaded.data, data, check_exact=True)
        assert loaded.metadata == {"seed": 5, "arr": [1.5, 2.5]}


def test_save_overwrites(tmp_path: Path, log: TrialLog) -> None:
    path = tmp_path / "trial.csv"
    TrialLog(log.data.iloc[:10].reset_index(drop=True), {"seed": 1}).save(path)
    log.save(path)
    loaded = TrialLog.load(path)
    assert_frame_equal(loaded.data, log.data, check_exact=True)
    assert loaded.metadata == log.metadata


def test_csv_without_sidecar_loads(tmp_path: Path, spec: ModelSpec) -> None:
    path = tmp_path / "mine.csv"
    path.write_text("time,w,tau,w_c\n0.0,0.1,1.0,0.0\n0.1,0.2,-1.0,0.01\n0.2,0.15,1.0,0.02\n")
    log = TrialLog.load(path, spec=spec)
    assert log.metadata == {}
    assert log.spec is None
    assert len(log) == 3
    assert log.experiment_ids == [0]
    assert log.data["w"].tolist() == [0.1, 0.2, 0.15]


def test_csv_without_sidecar_validates_against_spec(tmp_path: Path, spec: ModelSpec) -> None:
    path = tmp_path / "mine.csv"
    path.write_text("time,w,tau\n0.0,0.1,1.0\n0.1,0.2,-1.0\n")
    with pytest.raises(LogValidationError, match=r"w_c"):
        TrialLog.load(path, spec=spec)
    assert len(TrialLog.load(path, spec=spec, validate=False)) == 2


def test_load_validates_against_stored_spec(tmp_path: Path, log: TrialLog) -> None:
    bad = log.data.copy()
    bad.loc[5, "tau"] = np.nan
    TrialLog(bad, log.metadata).save(tmp_path / "bad.csv")
    with pytest.raises(LogValidationError, match=r"column 'tau' has NaN at row 5"):
        TrialLog.load(tmp_path / "bad.csv")
    assert np.isnan(TrialLog.load(tmp_path / "bad.csv", validate=False).data["tau"][5])


def test_load_missing_file(tmp_path: Path) -> None:
    with pytest.raises(LogValidationError, match=r"does not exist"):
        TrialLog.load(tmp_path / "nope.csv")


def test_load_bad_sidecar(tmp_path: Path, log: TrialLog) -> None:
    log.save(tmp_path / "trial.csv")
    (tmp_path / "trial.json").write_text("{not json")
    with pytest.raises(LogValidationError, match=r"trial.json"):
        TrialLog.load(tmp_path / "trial.csv")


@pytest.mark.parametrize("name", ["trial.txt", "trial.json", "trial"])
def test_bad_suffix(tmp_path: Path, log: TrialLog, name: str) -> None:
    with pytest.raises(LogValidationError, match=r"\.csv, \.parquet, \.pq") as err:
        log.save(tmp_path / name)
    assert "unsupported" in str(err.value)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(LogValidationError, match=r"unsupported"):
        TrialLog.load(tmp_path / name)


def test_unserialisable_metadata_writes_nothing(tmp_path: Path, log: TrialLog) -> None:
    with pytest.raises(LogValidationError, match=r"JSON"):
        TrialLog(log.data, {"f": object()}).save(tmp_path / "trial.csv")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- atomicity
def test_atomic_csv_writer_raises(
    tmp_path: Path, log: TrialLog, monkeypatch: pytest.MonkeyPatch
) -> None:
    def boom(data: pd.DataFrame, path: object, *args: object, **kwargs: object) -> None:
        Path(str(path)).write_text("experiment,time,w\n0,0.0,")  # half written
        raise OSError("disk full")

    import vesselid.data.logs

    monkeypatch.setattr(vesselid.data.logs, "_write_csv", boom)
    with pytest.raises(OSError, match="disk full"):
        log.save(tmp_path / "trial.csv")
    assert list(tmp_path.iterdir()) == []


def test_atomic_sidecar_writer_raises_keeps_old_files(
    tmp_path: Path, log: TrialLog, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "trial.csv"
    old = TrialLog(log.data.iloc[:4].reset_index(drop=True), {"seed": 1})
    old.save(path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}

    def boom(self: Path, *args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(Path, "write_text", boom)
    with pytest.raises(OSError, match="disk full"):
        log.save(path)
    monkeypatch.undo()
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    loaded = TrialLog.load(path)
    assert loaded.metadata == {"seed": 1}
    assert len(loaded) == 4


def test_atomic_parquet_writer_raises(
    tmp_path: Path, log: TrialLog, monkeypatch: pytest.MonkeyPatch
) -> None:
    import pyarrow.parquet as pq

    real = pq.ParquetWriter.write_table

    def boom(self: object, table: object, *args: object, **kwargs: object) -> None:
        real(self, table, *args, **kwargs)  # half written: the footer is missing
        raise OSError("disk full")

    monkeypatch.setattr(pq.ParquetWriter, "write_table", boom)
    with pytest.raises(OSError, match="disk full"):
        log.save(tmp_path / "trial.parquet")
    assert list(tmp_path.iterdir()) == []


def test_parquet_without_pyarrow(
    tmp_path: Path, log: TrialLog, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "pyarrow", None)
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
    with pytest.raises(ImportError, match=r"pip install 'vesselid\[parquet\]'") as err:
        log.save(tmp_path / "trial.parquet")
    assert isinstance(err.value, LogValidationError)
    assert list(tmp_path.iterdir()) == []


# -------------------------------------------------------------------------- validation
def test_validate_ok_returns_self(log: TrialLog, spec: ModelSpec) -> None:
    assert log.validate(spec) is log
    assert log.validate() is log  # falls back to the stored spec
    assert TrialLog(log.data).validate() is not None  # no spec: only generic checks


def test_missing_columns_all_named(log: TrialLog, spec: ModelSpec) -> None:
    data = log.data.drop(columns=["w", "w_c"])
    with pytest.raises(LogValidationError) as err:
        TrialLog(data).validate(spec, columns=["extra"])
    msg = str(err.value)
    assert "['w', 'w_c', 'extra']" in msg
    assert "available columns" in msg
    assert "'tau'" in msg and "'time'" in msg
    assert "\n" not in msg


def test_non_numeric_column(log: TrialLog, spec: ModelSpec) -> None:
    data = log.data.copy()
    data["tau"] = data["tau"].astype(str)
    with pytest.raises(LogValidationError, match=r"column 'tau' must be numeric"):
        TrialLog(data).validate(spec)


@pytest.mark.parametrize(
    ("column", "value", "kind"),
    [
        ("w", np.nan, "NaN"),
        ("w_c", np.inf, "inf"),
        ("tau", -np.inf, "-inf"),
        ("time", np.nan, "NaN"),
    ],
)
def test_non_finite_names_column_and_row(
    log: TrialLog, spec: ModelSpec, column: str, value: float, kind: str
) -> None:
    data = log.data.copy()
    data.loc[[57, 60], column] = value
    with pytest.raises(LogValidationError) as err:
        TrialLog(data).validate(spec)
    msg = str(err.value)
    assert msg.startswith(f"column '{column}' has {kind} at row 57 in experiment 1")
    assert "2 non-finite values" in msg


def test_non_finite_reports_index_label_and_position(spec: ModelSpec) -> None:
    data = pd.DataFrame(
        {"w": [0.1, 0.2, np.nan], "tau": [1.0, 2.0, 3.0], "w_c": [0.0, 0.0, 0.0]},
        index=[10, 20, 30],
    )
    with pytest.raises(LogValidationError, match=r"'w' has NaN at row 2 \(index label 30\)"):
        TrialLog(data).validate(spec)


def test_non_finite_in_unrequired_column_is_fine(log: TrialLog, spec: ModelSpec) -> None:
    data = log.data.copy()
    data.loc[3, "true_w"] = np.nan
    TrialLog(data).validate(spec)


def test_time_not_increasing_names_experiment_and_row(log: TrialLog, spec: ModelSpec) -> None:
    data = log.data.copy()
    data.loc[63, "time"] = data.loc[62, "time"]  # experiment 1 starts at row 50
    with pytest.raises(
        LogValidationError,
        match=r"'time' is not strictly increasing in experiment 1 at row 63: 1\.2\d* follows",
    ):
        TrialLog(data).validate(spec)


def test_time_restarting_per_experiment_is_fine(log: TrialLog, spec: ModelSpec) -> None:
    # time restarts at 0 in experiment 1; rows interleaved across experiments also fine
    data = log.data.sample(frac=1.0, random_state=0).sort_values(["time", "experiment"])
    TrialLog(data).validate(spec)


def test_too_few_samples(log: TrialLog, spec: ModelSpec) -> None:
    data = log.data.copy()
    data.loc[len(data)] = data.iloc[0]
    data.loc[len(data) - 1, "experiment"] = 9
    with pytest.raises(LogValidationError, match=r"experiment 9 has 1 sample; at least 2"):
        TrialLog(data).validate(spec)
    with pytest.raises(LogValidationError, match=r"experiment 0 has 50 samples; at least 51"):
        log.validate(spec, min_samples=51)
    with pytest.raises(LogValidationError, match=r"experiment 0 has 0 samples"):
        TrialLog(pd.DataFrame({"w": [], "tau": [], "w_c": []})).validate(spec)


def test_missing_experiment_id(log: TrialLog) -> None:
    data = log.data.astype({"experiment": float})
    data.loc[7, "experiment"] = np.nan
    with pytest.raises(LogValidationError, match=r"'experiment' has a missing value at row 7"):
        TrialLog(data).validate()


# ------------------------------------------------------------------------- experiments
def test_experiments_split() -> None:
    data = pd.DataFrame(
        {"experiment": [2, 0, 2, 0, 1], "time": [0.0, 0.0, 1.0, 1.0, 0.0], "w": [1, 2, 3, 4, 5]}
    )
    log = TrialLog(data)
    assert log.experiment_ids == [0, 1, 2]
    parts = log.experiments()
    assert [eid for eid, _ in parts] == [0, 1, 2]
    assert parts[0][1]["w"].tolist() == [2, 4]
    assert parts[0][1].index.tolist() == [1, 3]
    assert parts[2][1]["w"].tolist() == [1, 3]
    assert all(isinstance(eid, int) for eid in log.experiment_ids)


def test_experiments_without_column(log: TrialLog) -> None:
    single = TrialLog(log.data.drop(columns="experiment"))
    assert single.experiment_ids == [0]
    ((eid, frame),) = single.experiments()
    assert eid == 0
    assert frame is single.data
    assert single.to_frame() is single.data


def test_len_and_repr(log: TrialLog) -> None:
    assert len(log) == 100
    text = repr(log)
    assert "100 rows" in text and "2 experiments" in text and "true_w" in text


def test_spec_property(log: TrialLog, spec: ModelSpec) -> None:
    assert log.spec == spec
    assert log.spec.sensors == ("w_c",)
    assert TrialLog(log.data).spec is None


# ------------------------------------------------------------------------- concat_logs
def test_concat_logs(log: TrialLog, spec: ModelSpec) -> None:
    single = TrialLog(make_frame(1, 20, seed=3).drop(columns="experiment"), {"seed": 99})
    out = concat_logs([log, single, log])
    assert out.experiment_ids == [0, 1, 2, 3, 4]
    assert len(out) == 2 * len(log) + len(single)
    assert list(out.data.columns) == list(log.data.columns)
    assert out.data["experiment"].dtype == np.int64
    assert out.data.index.equals(pd.RangeIndex(len(out)))
    assert out.metadata["spec"] == log.metadata["spec"]
    assert out.metadata["seed"] == 1234
    assert out.metadata["seeds"] == [1234, 99, 1234]
    assert "seeds" not in log.metadata
    parts = dict(out.experiments())
    np.testing.assert_array_equal(parts[2]["w"].to_numpy(), single.data["w"].to_numpy())
    np.testing.assert_array_equal(
        parts[4]["w"].to_numpy(), log.data.loc[log.data["experiment"] == 1, "w"].to_numpy()
    )
    out.validate(spec)


def test_concat_logs_errors(log: TrialLog) -> None:
    with pytest.raises(LogValidationError, match=r"at least one"):
        concat_logs([])
    with pytest.raises(LogValidationError, match=r"missing \['true_w'\]"):
        concat_logs([log, TrialLog(log.data.drop(columns="true_w"))])


def test_atomic_write_uses_umask_mode(tmp_path):
    import os

    from vesselid.core.fileio import atomic_write_text

    path = tmp_path / "f.txt"
    atomic_write_text(path, "x")
    umask = os.umask(0)
    os.umask(umask)
    assert (path.stat().st_mode & 0o777) == (0o666 & ~umask)


def test_csv_floats_shortest_round_trip_text(tmp_path: Path) -> None:
    data = pd.DataFrame({"experiment": [0, 0], "time": [0.0, 0.1], "w": [0.1, 1 / 3],
                         "label": ["a", "b"]})
    for frame in (data, data.drop(columns="label")):  # pandas path and the numeric fast path
        TrialLog(frame, {}).save(tmp_path / "t.csv")
        rows = (tmp_path / "t.csv").read_text().splitlines()
        assert rows[0] == ",".join(frame.columns)
        assert rows[2].startswith("0,0.1,0.3333333333333333")
        back = TrialLog.load(tmp_path / "t.csv", validate=False).data
        pd.testing.assert_frame_equal(back, frame)
