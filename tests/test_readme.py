"""The README's quickstart prints what the README says it prints.

The expected-output blocks after the command-line and Python quickstarts are compared
with what the commands print today: each line of the expected block must be a line of
the output, in order, where ``...`` stands for any text (an abridged part).
"""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


def _section(title: str) -> str:
    text = README.read_text(encoding="utf-8")
    start = text.index(f"### {title}\n")
    end = text.find("\n## ", start)
    return text[start:end if end >= 0 else None]


def _blocks(section: str) -> list[tuple[str, str]]:
    """``(language, body)`` of every fenced block of a README section, in order."""
    return [(m.group(1), m.group(2))
            for m in re.finditer(r"```(\w*)\n(.*?)```", section, flags=re.DOTALL)]


def _squeeze(line: str) -> str:
    return " ".join(line.split())


def _pattern(line: str) -> re.Pattern[str]:
    """A pattern for a whitespace-squeezed output line; ``...`` matches any text."""
    parts = re.split(r"\s*\.\.\.\s*", _squeeze(line))
    return re.compile(".*".join(re.escape(p) for p in parts))


def _assert_lines_in_order(expected: str, output: str) -> None:
    got = [_squeeze(line) for line in output.splitlines()]
    pos = 0
    for line in expected.splitlines():
        if not line.strip() or line.strip() == "...":
            continue
        pattern = _pattern(line)
        while pos < len(got) and not pattern.fullmatch(got[pos]):
            pos += 1
        assert pos < len(got), f"README line not printed (in order): {line!r}\n{output}"
        pos += 1


def test_patterns_treat_dots_as_any_text() -> None:
    assert _pattern("warning: state 'w' ... (A10/A15)").fullmatch(
        "warning: state 'w' in experiment 0 is near zero (A10/A15)")
    assert _pattern("w  w   1.0155").fullmatch(_squeeze(" w w 1.0155 "))
    assert not _pattern("w  w  1.0155").fullmatch("w w 1.0156")


def test_command_line_quickstart_output(tmp_path, monkeypatch) -> None:
    from vesselid.cli import main

    (_, commands), (_, expected) = _blocks(_section("Command line"))[:2]
    monkeypatch.chdir(tmp_path)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        for command in commands.replace("\\\n", " ").splitlines():
            argv = shlex.split(command)
            assert argv[0] == "vesselid"
            assert main(argv[1:]) == 0
    _assert_lines_in_order(expected, out.getvalue())


@pytest.mark.filterwarnings("ignore::vesselid.ExperimentDesignWarning")
def test_python_quickstart_output(tmp_path, monkeypatch) -> None:
    (lang, code), (_, expected) = _blocks(_section("Python"))[:2]
    assert lang == "python"
    monkeypatch.chdir(tmp_path)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, "README.md", "exec"), {})
    _assert_lines_in_order(expected, out.getvalue())
