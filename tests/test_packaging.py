"""Every sub-package on disk is listed for installation (a non-editable install needs it)."""

from __future__ import annotations

import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def test_every_subpackage_is_installed():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    mapped = config.get("package-dir", {})
    on_disk = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for p in (ROOT / "vesselid").rglob("__init__.py")
    }
    on_disk |= {name for name, folder in mapped.items() if (ROOT / folder / "__init__.py").exists()}
    assert on_disk <= listed, f"not installed: {sorted(on_disk - listed)}"
