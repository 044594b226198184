"""The repository's text speaks of the product, not of its making.

Docs, docstrings, comments, tests and scripts carry no development history: no issue or
work-round numbers, no session/turn references, no clock times, no commit hashes, no branch
names, no "was merged"/"previously" narratives. Evidence belongs in study scripts and the
tables they write. This test scans every tracked text file for such patterns and names the
file, line and pattern of each hit.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
THIS = Path(__file__).resolve()

TEXT_SUFFIXES = {".py", ".md", ".rst", ".txt", ".toml", ".cfg", ".ini", ".yml", ".yaml", ".sh"}

#: name -> pattern (case-insensitive), each matched against single lines.
PATTERNS: dict[str, re.Pattern[str]] = {
    name: re.compile(pattern, re.IGNORECASE)
    for name, pattern in {
        "issue number": r"\bissues?\s+#?\d+\b|\(#\d+\)|\bissue\s+\d+'s\b",
        "turn, session or work-round number": r"\b(?:turn|session|work[- ]round)\s+#?\d+\b",
        "reference to a session": r"\b(?:this|previous|last)\s+(?:session|turn)\b|\bturn's start\b",
        "clock time": r"\b\d{1,2}:\d{2}(?::\d{2})?(?:\s*[–-]\s*\d{1,2}:\d{2}(?::\d{2})?)?\s*UTC\b",
        "timestamp in prose": r"\b20\d\d-\d\d-\d\d \d\d:\d\d\b",
        "commit hash": (r"\b(?:commit|git archive|git show|git checkout|git diff|revision)"
                        r"\s+`?[0-9a-f]{7,40}\b"),
        "branch name": r"\bbranch\s+`?[a-z][a-z0-9_-]*\d\b|\bon branch\b",
        "development narrative": r"\bwere merged\b|\bpreviously\b",
    }.items()
}

#: Bare hexadecimal tokens that look like abbreviated commit hashes (letters and digits,
#: 7-12 characters), looked for in Markdown prose only (code holds digests and seeds).
HASH_TOKEN = re.compile(r"(?<![\w./-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{7,12}(?![\w./-])")


def tracked_text_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                             check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        pytest.skip("not a git checkout: the tracked files are unknown")
    files = []
    for name in out.decode().split("\0"):
        if not name:
            continue
        path = ROOT / name
        if path.resolve() == THIS or not path.is_file():
            continue
        if path.suffix in TEXT_SUFFIXES or name.startswith(".ci/"):
            files.append(path)
    return files


def scan_text(text: str, markdown: bool = False) -> list[tuple[int, str, str]]:
    """``(line number, pattern name, line)`` of every history pattern in ``text``."""
    hits = []
    for number, line in enumerate(text.splitlines(), start=1):
        for name, pattern in PATTERNS.items():
            if pattern.search(line):
                hits.append((number, name, line.strip()))
        if markdown and HASH_TOKEN.search(line):
            hits.append((number, "commit-hash-like token", line.strip()))
    return hits


@pytest.mark.parametrize("text, name", [
    ("Planning a sea trial (`vesselid plan-trial`, issue {n})", "issue number"),
    ("the planner before issue {n}'s acceptance", "issue number"),
    ("Since turn {n} the first run also compiles", "turn, session or work-round number"),
    ("before: this section's previous turn", "reference to a session"),
    ("at the end of the session", None),
    ("{hh}:38–{hh}:40 UTC, load 0.8–1.1", "clock time"),
    ("on a fresh clone at load 0.4 (2026-11-27 {hh}:44 UTC)", "clock time"),
    ("the previous version from `git archive 027bfc9`", "commit hash"),
    ("measured on branch fast3", "branch name"),
    ("(issue {n}) were merged with the plant", "development narrative"),
    ("the vessel turns to port; after the turn the heading settles", None),
    ("start_utc: str = \"2026-06-01T10:00:00Z\"", None),
    ("σ² term is a constant (lag-1 correlation −0.5)", None),
])
def test_patterns_find_history_and_spare_prose(text: str, name: str | None) -> None:
    # the numbers are filled in here, so that this file's own text stays free of them
    found = {hit[1] for hit in scan_text(text.replace("{n}", "12").replace("{hh}", "22"))}
    if name is None:
        assert not found, found
    else:
        assert name in found, found


def test_hash_tokens_in_markdown() -> None:
    assert scan_text("newcomer run on a fresh clone of a22aaa2", markdown=True)
    assert not scan_text("sha256 digests live in tests, seed 20000, 1e-12", markdown=True)


def test_repository_text_has_no_development_history() -> None:
    problems = []
    for path in tracked_text_files():
        text = path.read_text(encoding="utf-8", errors="replace")
        for number, name, line in scan_text(text, markdown=path.suffix == ".md"):
            problems.append(f"{path.relative_to(ROOT)}:{number}: {name}: {line[:120]}")
    assert not problems, "development history in the repository's text:\n" + "\n".join(problems)
