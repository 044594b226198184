"""Command line end to end, in a temporary directory."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from vesselid.cli import main


def run(args, capsys):
    code = main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_help_and_module_entry_point():
    for cmd in ([sys.executable, "-m", "vesselid", "--help"], ["vesselid", "--help"]):
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        assert proc.returncode == 0
        assert "simulate" in proc.stdout and "identify" in proc.stdout


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_simulate_then_identify(tmp_path, capsys, suffix):
    out = tmp_path / f"trial{suffix}"
    code, text, _ = run(["simulate", "--system", "heave", "--samples", "3000", "--experiments",
                         "2", "--current-mean", "0.1", "--current-sensor", "--seed", "0",
                         "--out", str(out)], capsys)
    assert code == 0 and out.exists() and (tmp_path / "trial.toml").exists()
    assert "vesselid identify" in text
    df = pd.read_csv(out) if suffix == ".csv" else pd.read_parquet(out)
    assert {"experiment", "time", "w", "tau", "w_c", "true_w"} <= set(df.columns)
    js = tmp_path / "result.json"
    code, text, _ = run(["identify", str(out), "--model", str(tmp_path / "trial.toml"),
                         "--method", "iv-zero-mean", "--json", str(js)], capsys)
    assert code == 0 and "w*|w|" in text
    payload = json.loads(js.read_text())
    assert payload["method"] == "iv-zero-mean" and payload["experiments"] == 2
    assert payload["samples"] == 6000 and set(payload["params"]["w"]) == {"w", "w*|w|", "tau"}
    code, text, _ = run(["identify", str(out), "--method", "ls", "--json", "-"], capsys)
    assert code == 0 and json.loads(text)["method"] == "ls"


def test_simulate_is_deterministic(tmp_path, capsys):
    for name in ("a", "b"):
        run(["simulate", "--samples", "500", "--seed", "3", "--out", str(tmp_path / f"{name}.csv")],
            capsys)
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


def test_bad_input_exit_code_two(tmp_path, capsys):
    code, _, err = run(["identify", str(tmp_path / "missing.csv"), "--model", "x.toml"], capsys)
    assert code == 2 and "error" in err and len(err.strip().splitlines()) == 1
    log = tmp_path / "t.csv"
    run(["simulate", "--samples", "400", "--out", str(log)], capsys)
    df = pd.read_csv(log)
    df.loc[10, "w"] = np.nan
    df.to_csv(log, index=False)
    code, _, err = run(["identify", str(log), "--model", str(tmp_path / "t.toml")], capsys)
    assert code == 2 and "'w'" in err and "row 10" in err
    df.drop(columns="tau").to_csv(log, index=False)
    code, _, err = run(["identify", str(log), "--model", str(tmp_path / "t.toml")], capsys)
    assert code == 2 and "tau" in err
    code, _, err = run(["simulate", "--out", str(tmp_path / "x.txt")], capsys)
    assert code == 2 and ".csv" in err
    code, _, err = run(["simulate", "--system", "nope", "--out", str(tmp_path / "y.csv")], capsys)
    assert code == 2 and "unknown system" in err
    (tmp_path / "bad.toml").write_text("states = [")
    code, _, err = run(["identify", str(tmp_path / "a.csv"), "--model",
                        str(tmp_path / "bad.toml")], capsys)
    assert code == 2 and "TOML" in err


def test_cybership2_simulate_identify(tmp_path, capsys):
    """Turns to both sides by default; the log carries the identifiable structure."""
    out = tmp_path / "cs.csv"
    code, text, _ = run(["simulate", "--system", "cybership2", "--samples", "6000", "--seed", "1",
                         "--out", str(out)], capsys)
    assert code == 0 and "2 experiment(s)" in text
    code, text, _ = run(["identify", str(out), "--model", str(tmp_path / "cs.toml"),
                         "--method", "iv-zero-mean", "--json", "-"], capsys)
    assert code == 0
    payload = json.loads(text)
    assert "v*|r|" not in payload["params"]["v"] and "r*|v|" in payload["params"]["v"]


def test_os_errors_exit_two_and_bugs_show_as_bugs(tmp_path, capsys, monkeypatch):
    """OSError is bad input (exit 2, one line); a plain ValueError/TypeError is a bug:
    it propagates with its traceback (exit 1 from the console script)."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = run(["simulate", "--samples", "50", "--out", str(blocker / "t.csv")], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1
    import vesselid.identify

    def broken(*args, **kwargs):
        raise ValueError("internal bug")

    log = tmp_path / "t.csv"
    assert run(["simulate", "--samples", "400", "--out", str(log)], capsys)[0] == 0
    monkeypatch.setattr(vesselid.identify, "identify", broken)
    with pytest.raises(ValueError, match="internal bug"):
        main(["identify", str(log), "--model", str(tmp_path / "t.toml")])
