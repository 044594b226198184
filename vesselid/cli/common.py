"""Argument types and checks shared by the commands (one-line refusals, exit 2)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

__all__ = ["check_output_file", "check_raw_dir", "finite_float", "int_at_least", "write_json"]


def int_at_least(minimum: int) -> Any:
    """An argparse ``type``: an integer ``>= minimum`` (the error names the option)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
        return value

    parse.__name__ = f"integer >= {minimum}"
    return parse

def finite_float(text: str) -> float:
    """An argparse ``type``: a finite float."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value

def check_output_file(option: str, target: str) -> None:
    """An output file path: not a directory, and no regular file among its parents."""
    path = Path(target)
    if path.is_dir():
        raise IsADirectoryError(21, f"{option} path is a directory", target)
    parent = next((p for p in path.absolute().parents if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise NotADirectoryError(20, f"{option}: not a directory", str(parent))

def check_raw_dir(raw: str) -> None:
    """``--raw DIR`` (simulate, sea-trial): refuse a path that cannot become a directory
    before anything is simulated or written (all outputs or none)."""
    path = Path(raw)
    if path.exists() and not path.is_dir():
        raise NotADirectoryError(20, "--raw must be a directory, not an existing file", raw)
    parent = next((p for p in path.absolute().parents if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise NotADirectoryError(20, "not a directory", str(parent))


def write_json(target: str | None, text: str) -> bool:
    """``--json TARGET``: ``"-"`` prints ``text`` on stdout, a path gets it written
    atomically (no half-written file); returns whether a file was written."""
    if not target:
        return False
    if target == "-":
        print(text)
        return False
    from vesselid.core.fileio import atomic_write_text

    atomic_write_text(target, text + "\n")
    return True
