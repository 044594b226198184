"""Size guard, chunked simulation to disk, all-or-nothing outputs, strict log schemas."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vesselid.core import limits
from vesselid.core.fileio import atomic_group, strict_json
from vesselid.data.logs import TrialLog, estimate_shape
from vesselid.errors import LogValidationError, ResourceLimitError
from vesselid.plant.catalogue import get_system
from vesselid.plant.todisk import simulate_to_file


def test_check_refuses_with_need_and_limit(monkeypatch):
    monkeypatch.setenv("VESSELID_MAX_MEMORY", "1G")
    with pytest.raises(ResourceLimitError, match=r"~2 GB of memory; the limit is 1 GB"):
        limits.check("simulate", "x", memory=2e9)
    limits.check("simulate", "x", memory=0.5e9)
    monkeypatch.setenv("VESSELID_MAX_SECONDS", "10")
    with pytest.raises(ResourceLimitError, match="would take ~1 min"):
        limits.check("simulate", "x", seconds=60)
    with pytest.raises(ResourceLimitError, match="memory"):
        limits.check("simulate", "x", memory=float("nan"))


def test_available_memory_is_positive():
    mem = limits.available_memory()
    assert mem is None or mem > 0


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_batched_file_equals_in_memory_file(tmp_path, suffix):
    """Batches of whole runs change no value; one batch writes the same bytes."""
    system = get_system("heave")
    ref = system.simulate(300, n_runs=5, seed=2).to_log()
    one = tmp_path / f"one{suffix}"
    many = tmp_path / f"many{suffix}"
    simulate_to_file(system, 300, 5, 2, one)
    simulate_to_file(system, 300, 5, 2, many, batch_rows=600)  # 2 runs per batch
    a, b = TrialLog.load(one), TrialLog.load(many)
    pd.testing.assert_frame_equal(a.data, ref.data)
    pd.testing.assert_frame_equal(b.data, ref.data)
    assert a.metadata == b.metadata
    if suffix == ".csv":
        ref.save(tmp_path / "ref.csv")
        assert (tmp_path / "ref.csv").read_bytes() == one.read_bytes() == many.read_bytes()


def test_time_chunks_continue_the_recursion_exactly(tmp_path):
    system = get_system("heave")
    out = tmp_path / "long.csv"
    simulate_to_file(system, 1000, 2, 7, out, chunk_samples=300)
    again = tmp_path / "again.csv"
    simulate_to_file(system, 1000, 2, 7, again, chunk_samples=300)
    assert out.read_bytes() == again.read_bytes()  # deterministic for a seed
    log = TrialLog.load(out)
    assert log.metadata["chunk_samples"] == 300
    for _, df in log.experiments():
        assert len(df) == 1000
        assert np.array_equal(df["time"].to_numpy(), np.arange(1000.0))
        x = df["true_w"].to_numpy()
        r = x - df["true_current_w"].to_numpy()  # w_r = w_a - w_c
        pred = (0.99 * r[:-1] - 0.1 * r[:-1] * np.abs(r[:-1]) + df["tau"].to_numpy()[:-1]
                + df["true_process_w"].to_numpy()[:-1])
        np.testing.assert_allclose(x[1:], pred, rtol=0, atol=1e-12)  # incl. chunk boundaries


def test_atomic_group_all_or_nothing(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old")
    with pytest.raises(RuntimeError), atomic_group([a, b]) as (ta, tb):
        ta.write_text("new")
        tb.write_text("new")
        raise RuntimeError
    assert a.read_text() == "old" and not b.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]  # no temporary files
    with atomic_group([a, b]) as (ta, tb):
        ta.write_text("new")
        tb.write_text("new")
    assert a.read_text() == b.read_text() == "new"


def test_stale_temporary_files_of_dead_processes_are_removed(tmp_path):
    target = tmp_path / "t.csv"
    dead = tmp_path / ".t.csv.999999999.abc.tmp"  # no such pid
    alive = tmp_path / f".t.csv.{os.getpid()}.abc.tmp"
    dead.write_text("x")
    alive.write_text("x")
    with atomic_group([target]) as (tmp,):
        tmp.write_text("data")
    assert not dead.exists() and alive.exists()


def test_output_path_errors_name_the_path(tmp_path):
    (tmp_path / "dir.csv").mkdir()
    with pytest.raises(IsADirectoryError, match=r"dir\.csv"), atomic_group([tmp_path / "dir.csv"]):
        pass
    (tmp_path / "file").write_text("x")
    with pytest.raises(NotADirectoryError, match="file"), \
            atomic_group([tmp_path / "file" / "x.csv"]):
        pass


def test_strict_json_has_no_nan():
    text = strict_json({"a": float("inf"), "b": [np.nan, 1.0], "c": np.float64("-inf")})
    assert json.loads(text) == {"a": None, "b": [None, 1.0], "c": None}


# ------------------------------------------------------------------------- schemas
@pytest.fixture
def saved(tmp_path) -> Path:
    path = tmp_path / "t.csv"
    get_system("heave").simulate(50, seed=0).to_log().save(path)
    return path


def test_csv_duplicate_column_names_refused(saved):
    text = saved.read_text().splitlines()
    text[0] = text[0].replace("tau", "w")
    saved.write_text("\n".join(text) + "\n")
    saved.with_suffix(".json").unlink()
    with pytest.raises(LogValidationError, match=r"duplicated column names \['w'\]"):
        TrialLog.load(saved)


@pytest.mark.parametrize("edit, match", [
    (lambda e: e["dtypes"].update(w=5), "dtype of column 'w' must be a string"),
    (lambda e: e["dtypes"].update(w="float77"), "is not a dtype"),
    (lambda e: e.update(dtypes=[1]), "'dtypes' must be a JSON object"),
    (lambda e: e.update(columns="w"), "'columns' must be a list"),
    (lambda e: e["metadata"].update(seed="zero"), "'seed' must be an integer"),
    (lambda e: e["metadata"].update(spec=[1]), "'spec' must be a JSON object"),
    (lambda e: e["metadata"]["spec"].update(states=5), "metadata entry 'spec'"),
    (lambda e: e.update(format_version=99), "newer"),
])
def test_sidecar_entry_types(saved, edit, match):
    side = saved.with_suffix(".json")
    env = json.loads(side.read_text())
    edit(env)
    side.write_text(json.dumps(env))
    with pytest.raises(LogValidationError, match=match):
        TrialLog.load(saved)


def test_sidecar_nan_constant_and_binary(saved):
    side = saved.with_suffix(".json")
    side.write_text(side.read_text().replace('"seed": 0', '"seed": NaN'))
    with pytest.raises(LogValidationError, match="NaN is not valid JSON"):
        TrialLog.load(saved)
    side.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(LogValidationError, match="not UTF-8"):
        TrialLog.load(saved)


def test_corrupted_parquet_page_is_detected(tmp_path):
    path = tmp_path / "t.parquet"
    get_system("heave").simulate(2000, seed=0).to_log().save(path)
    raw = bytearray(path.read_bytes())
    for k in range(200, 1200, 97):  # inside the first column's data page
        raw[k] ^= 0x5A
    path.write_bytes(bytes(raw))
    with pytest.raises(LogValidationError, match="cannot read Parquet"):
        TrialLog.load(path)


def test_estimate_shape(tmp_path, saved):
    rows, cols = estimate_shape(saved)
    assert cols == 7 and 40 <= rows <= 60


def test_raw_inputs_and_grids_refused_before_reading(tmp_path, monkeypatch):
    """ingest's guard: a 200 GB (sparse) raw file by its size, a grid by its points."""
    d = tmp_path / "raw"
    d.mkdir()
    with open(d / "nav.nmea", "wb") as fh:
        fh.truncate(200 * 10**9)
    with pytest.raises(ResourceLimitError, match=r"ingest: 1 raw input file\(s\), 200 GB"):
        limits.check_inputs("ingest", [d])
    with pytest.raises(ResourceLimitError, match="200 GB"):
        limits.check_file_size(d / "nav.nmea")
    (d / "nav.nmea").unlink()
    (d / "small.nmea").write_text("$GPGGA\n")
    limits.check_inputs("ingest", [d])  # tiny: passes
    monkeypatch.setenv("VESSELID_MAX_MEMORY", "1G")
    with pytest.raises(ResourceLimitError, match="grid of 1e\\+09 samples"):
        limits.check_grid("ingest", 1e9, 12)
    limits.check_grid("ingest", 1e5, 12)
