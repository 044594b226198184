"""``vesselid recursive``: the command's registration (:mod:`vesselid.cli.closed_loop`)."""

from __future__ import annotations

from typing import Any

__all__ = ["add_parser"]


def add_parser(subparsers: Any) -> None:
    """Register ``vesselid recursive`` (plugin contract of :mod:`vesselid.cli.app`)."""
    from vesselid.cli.closed_loop import add_recursive_parser

    add_recursive_parser(subparsers)
