"""The switching study and the robustness study's ``--update`` on tiny sizes."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
from _scripts import load_script

DOCS = Path(__file__).resolve().parent.parent / "docs"


def test_switching_study_writes_its_tables(tmp_path):
    study = load_script("switching_study")
    assert study.main(["--runs", "2", "--samples", "1500", "--designs", "telegraph",
                       "--out", str(tmp_path)]) == 0
    tab = pd.read_csv(tmp_path / "robustness_switching.csv")
    assert list(tab["design"]) == ["telegraph"] and int(tab["runs"].iloc[0]) == 2
    for col in ("gate_rejects", "vuong_prefers", "auto_takes", "coverage_n",
                "coverage_sandwich_n", "coverage_fisher_n"):
        assert 0.0 <= float(tab[col].iloc[0]) <= 1.0
    assert "| telegraph |" in (tmp_path / "robustness_switching.md").read_text()


def test_update_replaces_only_the_rerun_designs(tmp_path):
    """``--update`` for one design and method keeps every other design's rows of the
    summary, of auto's choices and of its warning shares."""
    for name in ("robustness.csv", "robustness_choices.csv", "robustness_warnings.csv"):
        shutil.copy(DOCS / name, tmp_path / name)
    old_ch = pd.read_csv(tmp_path / "robustness_choices.csv")
    old_ws = pd.read_csv(tmp_path / "robustness_warnings.csv")
    rs = load_script("robustness_study")
    assert rs.main(["--runs", "2", "--samples", "400", "--designs", "white", "--methods",
                    "auto", "--update", "--out", str(tmp_path)]) == 0
    ch = pd.read_csv(tmp_path / "robustness_choices.csv")
    ws = pd.read_csv(tmp_path / "robustness_warnings.csv")
    kept = old_ch[~((old_ch["method"] == "auto") & (old_ch["design"] == "white"))]
    merged = ch.merge(kept, on=["method", "design", "choice", "runs"])
    assert len(merged) == len(kept)
    assert ch[(ch["method"] == "auto") & (ch["design"] == "white")]["runs"].sum() == 2
    assert set(ws["design"]) == set(old_ws["design"])
    assert int(ws[ws["design"] == "white"]["runs"].iloc[0]) == 2
    summary = pd.read_csv(tmp_path / "robustness.csv")
    assert len(summary) == len(pd.read_csv(DOCS / "robustness.csv"))
