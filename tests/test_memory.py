"""Memory of ``identify`` on large logs: freed blocks leave the resident memory, and a
log beyond memory is refused with the way out (``--stream``)."""

from __future__ import annotations

import sys

import numpy as np

from vesselid.cli import main


def test_unmap_large_blocks_keeps_arrays_working() -> None:
    from vesselid.core.memory import unmap_large_blocks

    done = unmap_large_blocks()
    assert done is sys.platform.startswith("linux") or done is False
    a = np.arange(1 << 18, dtype=float)  # 2 MiB: mapped from now on, same values
    assert a.sum() == (1 << 18) * ((1 << 18) - 1) / 2


def test_identify_refusal_names_stream(tmp_path, monkeypatch, capsys) -> None:
    log = tmp_path / "t.csv"
    assert main(["simulate", "--samples", "400", "--out", str(log)]) == 0
    capsys.readouterr()
    monkeypatch.setenv("VESSELID_MAX_MEMORY", "1M")
    assert main(["identify", str(log)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "would need" in err and "--stream" in err
