"""Compiled or plain-numpy estimation kernels, chosen per estimation.

The estimators reach their kernels through the two module-like objects of this module,
``kernels`` (:mod:`vesselid.identify.kernels`) and ``ivk``
(:mod:`vesselid.identify._ivkernels`). Inside :func:`choose` with the numpy path
selected, an attribute is taken from :mod:`vesselid.identify._npkernels` if it has it;
otherwise (and outside) from the compiled module, imported — with numba — on first use.

Why: a whole ``vesselid identify`` process on a small log spent more time loading numba
and its cached kernels (≈ 0.4 s of CPU: the import, the target initialisation with its
``scipy.linalg`` BLAS check, one cache file per kernel) than estimating. The numpy path
runs the sequential recursions as generated Python loops (≈ 0.15 µs per sample for the
heave model), so it wins below :data:`NUMPY_MAX_SAMPLE_TERMS` — but only while numba is
not loaded yet: once it is (a simulation, an earlier compiled estimate), the compiled
kernels are faster at every size.

``VESSELID_KERNELS`` = ``compiled`` / ``numpy`` forces one path (``auto``, the default,
chooses as above). Results of the two paths agree to rounding
(``tests/test_npkernels.py``); the compiled one is bit-identical across batch sizes.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import importlib
import os
import sys
from collections.abc import Callable, Iterator
from types import ModuleType
from typing import Any

from vesselid.core.memory import drop_library_code

__all__ = ["NUMPY_MAX_SAMPLE_TERMS", "choose", "chooses_kernels", "ivk", "kernels",
           "loaded_kernel", "numpy_active", "use_numpy"]

#: The numpy path is chosen (numba not loaded yet) for logs of at most this many
#: samples × terms (measured: ``scripts/bench_startup.py``; a 10⁴-sample heave log is
#: 3·10⁴).
NUMPY_MAX_SAMPLE_TERMS = 300_000

_NUMPY = contextvars.ContextVar("vesselid_numpy_kernels", default=False)
_NP_MODULE = "vesselid.identify._npkernels"


def use_numpy(n_samples: int, n_params: int) -> bool:
    """Whether an estimation of this size takes the numpy path (see module docstring)."""
    mode = os.environ.get("VESSELID_KERNELS", "auto").strip().lower()
    if mode == "numpy":
        return True
    if mode == "compiled":
        return False
    return "numba" not in sys.modules and n_samples * max(n_params, 1) <= NUMPY_MAX_SAMPLE_TERMS


def numpy_active() -> bool:
    """True inside :func:`choose` when the numpy path was selected."""
    return _NUMPY.get()


@contextlib.contextmanager
def choose(n_samples: int, n_params: int) -> Iterator[bool]:
    """Select the kernels for one estimation (context manager; yields the choice).

    Nested uses keep the outer choice, so one estimate never mixes the two paths.
    """
    if _NUMPY.get():
        yield True
        return
    numpy_path = use_numpy(n_samples, n_params)
    token = _NUMPY.set(numpy_path)
    try:
        yield numpy_path
    finally:
        _NUMPY.reset(token)


def _log_size(log: Any, spec: Any) -> tuple[int, int]:
    """(rows, parameters) of a trial log and spec, cheaply (0 where unknown)."""
    if isinstance(log, str | bytes | os.PathLike):
        return 0, 0  # not a log object (fit refuses it): unknown size
    try:
        rows = len(log)
    except TypeError:
        rows = 0
    spec = spec if spec is not None else getattr(log, "spec", None)
    return int(rows), int(getattr(spec, "n_params", 0) or 0)


def chooses_kernels(fit: Callable[..., Any]) -> Callable[..., Any]:
    """Decorator of ``Estimator.fit(self, log, spec=None, ...)``: run it inside
    :func:`choose` for the log's size (unknown sizes take the compiled path)."""

    @functools.wraps(fit)
    def wrapper(self: Any, log: Any, spec: Any = None, *args: Any, **kwargs: Any) -> Any:
        rows, n_params = _log_size(log, spec)
        with choose(rows if n_params else NUMPY_MAX_SAMPLE_TERMS + 1, n_params):
            return fit(self, log, spec, *args, **kwargs)

    return wrapper


def loaded_kernel(name: str) -> Any:
    """The compiled kernel ``name`` of :mod:`vesselid.identify._ivkernels` when that module
    is loaded already and the numpy path is not selected, else None: for helpers that
    have a numpy formulation of their own and must never import numba."""
    mod = sys.modules.get("vesselid.identify._ivkernels")
    if mod is None or _NUMPY.get():
        return None
    return getattr(mod, name, None)


class _Kernels:
    """Module-like access to one compiled kernel module and its numpy counterparts."""

    def __init__(self, compiled: str) -> None:
        self._compiled = compiled

    def __getattr__(self, name: str) -> Any:
        if _NUMPY.get():
            np_mod = importlib.import_module(_NP_MODULE)
            if hasattr(np_mod, name):
                return getattr(np_mod, name)
        return getattr(self.module, name)

    @property
    def module(self) -> ModuleType:
        """The compiled module (imports numba)."""
        first = self._compiled not in sys.modules
        mod = importlib.import_module(self._compiled)
        if first:
            # the pages of LLVM's code that loading the library faulted in (its static
            # initialisers) leave the process before the first kernel is loaded, where
            # the command asked for it (vesselid.core.memory)
            drop_library_code()
        return mod


#: :mod:`vesselid.identify.kernels` or its numpy counterparts.
kernels = _Kernels("vesselid.identify.kernels")
#: :mod:`vesselid.identify._ivkernels` or its numpy counterparts.
ivk = _Kernels("vesselid.identify._ivkernels")
