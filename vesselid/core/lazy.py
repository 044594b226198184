"""Lazy attributes of a package (PEP 562): names imported from their module on first use.

``__getattr__, __dir__ = lazy_attributes(__name__, {"Name": "pkg.module"}, __all__)`` in a
package ``__init__`` keeps ``import pkg`` light; the first ``pkg.Name`` imports
``pkg.module`` and caches the value in the package namespace.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterable, Mapping
from typing import Any

__all__ = ["lazy_attributes"]


def lazy_attributes(package: str, table: Mapping[str, str], names: Iterable[str]
                    ) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Module-level ``__getattr__`` and ``__dir__`` for ``package``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    table : mapping
        Attribute name -> module that defines it.
    names : iterable of str
        The package's public names (``__all__``), listed by ``dir()``.
    """
    public = tuple(names)

    def __getattr__(name: str) -> Any:
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        vars(sys.modules[package])[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(public))

    return __getattr__, __dir__
