"""The command line: ``vesselid <command>``.

:mod:`~vesselid.cli.app` builds the parser and runs ``simulate`` and ``identify``; every other
command is one module here with ``add_arguments(parser)`` (setting ``func``), imported only
when that command runs (:data:`vesselid.cli.app.LAZY_COMMANDS`); :mod:`~vesselid.cli.common`
holds the argument types and checks they share. No module outside this package imports it.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``vesselid`` with ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    from vesselid.cli.app import main as run

    return run(argv)
