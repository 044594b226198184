"""vesselid: consistent identification of second-order modulus vessel models.

Simulate marine vessels under current, wind and sensor noise, and identify their
physical models with the consistent instrumental-variable estimators of
Ljungberg & Enqvist ("Consistent Parameter Estimators for Second-order Modulus
Systems with Non-additive Disturbances").
"""

from __future__ import annotations

__version__ = "0.1.0"

import sys
from typing import Any

from vesselid.core.lazy import lazy_attributes
from vesselid.errors import (
    ConvergenceWarning,
    ExperimentDesignWarning,
    IdentificationError,
    LogValidationError,
    ModelSpecError,
    RankDeficientError,
    SimulationDivergedError,
    VesselidError,
    WeakInstrumentWarning,
)

__all__ = [
    "Aggregate",
    "ConvergenceWarning",
    "ExperimentDesignWarning",
    "IdentificationError",
    "LogValidationError",
    "ModelSpec",
    "ModelSpecError",
    "RankDeficientError",
    "SimulationDivergedError",
    "Term",
    "VesselidError",
    "WeakInstrumentWarning",
    "__version__",
]

# Imported on first use (PEP 562), so that ``import vesselid`` — and ``vesselid --help`` —
# load neither pandas nor the numerical stack.
_LAZY = {"Aggregate": "vesselid.model.spec", "ModelSpec": "vesselid.model.spec",
         "Term": "vesselid.model.terms"}


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, __all__)


class _RegisterWithGymnasium:
    """One-shot import hook: registers the environments right after gymnasium is imported.

    ``import vesselid`` thus registers ``vesselid/Heave-v0``, ... for every later
    ``gym.make`` without importing gymnasium itself (≈ 0.1 s) when no environment is
    ever made.
    """

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname != "gymnasium":
            return None
        import importlib.util

        if self in sys.meta_path:
            sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        loader = getattr(spec, "loader", None)
        if loader is None or not hasattr(loader, "exec_module"):
            return spec
        exec_module = loader.exec_module

        def exec_and_register(module: Any) -> None:
            exec_module(module)
            _register()

        loader.exec_module = exec_and_register
        return spec


class _SourceTreeEnvs:
    """Finds ``vesselid.envs`` in a source checkout (folder ``envs/`` beside ``vesselid/``).

    The wheel installs the folder ``envs/`` as ``vesselid.envs`` (``package-dir`` in
    ``pyproject.toml``); an editable install maps it the same way. A plain source tree on
    ``sys.path`` (``python -c ...`` run in the checkout, which shadows a non-editable
    install) has no ``vesselid/envs``: this finder supplies the mapping, so that the
    environments — and their registration with gymnasium — are the same in all three.
    """

    def __init__(self, folder: str) -> None:
        self.folder = folder

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname != "vesselid.envs":
            return None
        import importlib.util
        import os

        return importlib.util.spec_from_file_location(
            fullname, os.path.join(self.folder, "__init__.py"),
            submodule_search_locations=[self.folder])


def _install_source_tree_envs() -> None:
    import os

    here = os.path.dirname(os.path.abspath(__file__))
    if os.path.isdir(os.path.join(here, "envs")):  # installed: vesselid/envs exists
        return
    folder = os.path.join(os.path.dirname(here), "envs")
    if (os.path.isfile(os.path.join(folder, "__init__.py"))
            and not any(isinstance(f, _SourceTreeEnvs) for f in sys.meta_path)):
        sys.meta_path.append(_SourceTreeEnvs(folder))


_install_source_tree_envs()


def _register() -> None:
    try:
        from vesselid.envs import register_envs
    except ImportError:  # the environments are not installed
        return
    register_envs()


if "gymnasium" in sys.modules:  # already imported: register now (cheap)
    _register()
elif not any(isinstance(f, _RegisterWithGymnasium) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterWithGymnasium())
