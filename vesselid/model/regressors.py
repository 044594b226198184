"""The one owner of regressor evaluation: term layout, Φ, and the one-step update Φᵀθ.

Every piece of code that evaluates the regressors of Definition 2.1 — simulation,
the moment kernels, instrument generation, generated kernels, vessels, environments,
controllers — goes through this module. A new term form is one edit here.

API
---
Layout (plain numpy, no compilation):

``RegressorLayout``
    The encoding of a model's terms over its ordered signal vector ``s = [x; u]``
    (length ``S``). Term ``p`` is ``F[factors[p, 0]] * F[factors[p, 1]]`` with the
    *factor vector* ``F = [s, |s|, 1]`` (length ``2 S + 1``); ``equation[p]`` is the
    state equation it belongs to. Built by :func:`encode_terms` (what
    ``ModelSpec.codes`` returns).
``encode_terms(terms_per_equation, signal_names)``
    Build the layout; unknown signals raise :class:`~vesselid.errors.ModelSpecError`.
``factor_source(idx, n_signals)``
    ``(signal index, modulus)`` of factor ``idx``, or ``None`` for the constant 1
    (what code generators use to spell factors).
``evaluate(factors, signals)``
    Φ for an array of signal vectors ``(..., S)`` → ``(..., P)`` (vectorised numpy).
``predict(layout, theta, signals)``
    One-step predictions ``Φᵀθ`` per equation, ``(..., S)`` → ``(..., n_equations)``.
``factor_vector(signals)`` / ``weights_matrix(layout, theta)``
    ``F = [s, |s|, 1]`` for arrays of signal vectors; ``W`` with ``Φ W = Φᵀθ`` for a
    precomputed Φ matrix (one BLAS product; equal to ``predict`` up to rounding).

Compiled helpers (numba, ``inline="always"``; call them from compiled code; numba is
imported on first access to one of them or to :func:`kernel`, not with this module):

``fill_factors(s, f)`` / ``fill_factors_xu(x, u, f)``
    Fill the factor vector ``f = [s, |s|, 1]`` from a signal vector, or from the
    states and inputs given separately.
``regressors(factors, f, phi)``
    ``phi[p] = f[factors[p, 0]] * f[factors[p, 1]]`` (Φ from a filled factor vector).
``one_step(equation, theta, phi, out)``
    The one-step update ``out[equation[p]] += θ_p φ_p`` in term order (callers
    initialise ``out`` with the additive part, e.g. the process noise, or zeros).
``advance(factors, equation, theta, s, f, phi, out)``
    ``fill_factors`` + ``regressors`` + ``one_step`` for one signal vector.

Compiling with a salted cache:

``kernel(**options)``
    Drop-in for ``numba.njit(cache=True, **options)`` whose on-disk cache entries are
    keyed additionally by :data:`SALT`, a digest of this file, so that an edit here
    invalidates the cached kernels of every module that inlines these helpers
    (numba's own cache only tracks the file a function is defined in).

All evaluations perform the same floating-point operations in the same order, so
every path (numpy, compiled, generated) gives bit-identical results.
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from vesselid.errors import ModelSpecError

if TYPE_CHECKING:  # pragma: no cover
    from vesselid.model.terms import Term

__all__ = [
    "SALT",
    "RegressorLayout",
    "advance",  # noqa: F822 - bound on first access (module __getattr__)
    "encode_terms",
    "evaluate",
    "factor_source",
    "factor_vector",
    "fill_factors",  # noqa: F822 - bound on first access (module __getattr__)
    "fill_factors_xu",  # noqa: F822 - bound on first access (module __getattr__)
    "kernel",
    "one_step",  # noqa: F822 - bound on first access (module __getattr__)
    "predict",
    "regressors",  # noqa: F822 - bound on first access (module __getattr__)
    "weights_matrix",
]


# ---------------------------------------------------------------------------- layout
@dataclass(frozen=True)
class RegressorLayout:
    """Factor layout of a model's terms over the signal vector ``s = [x; u]``.

    Parameters
    ----------
    factors : ndarray of int64, shape (P, 2)
        Term ``p`` is ``F[factors[p, 0]] * F[factors[p, 1]]`` with ``F = [s, |s|, 1]``.
    equation : ndarray of int64, shape (P,)
        State equation of every term (terms of one equation are contiguous).
    n_signals : int
        Length ``S`` of the signal vector.
    """

    factors: np.ndarray
    equation: np.ndarray
    n_signals: int

    @property
    def n_params(self) -> int:
        """Number of terms (parameters) ``P``."""
        return int(self.factors.shape[0])

    @property
    def n_factors(self) -> int:
        """Length ``2 S + 1`` of the factor vector."""
        return 2 * self.n_signals + 1


def encode_terms(
    terms_per_equation: Sequence[Sequence[Term]], signal_names: Sequence[str]
) -> RegressorLayout:
    """Encode per-equation term lists against an ordered list of signal names.

    Raises
    ------
    ModelSpecError
        If a term uses a signal that is not in ``signal_names``.
    """
    index = {name: i for i, name in enumerate(signal_names)}
    n_s = len(signal_names)
    rows: list[tuple[int, int]] = []
    equation: list[int] = []
    for eq, terms in enumerate(terms_per_equation):
        for term in terms:
            for name in term.signals:
                if name not in index:
                    raise ModelSpecError(
                        f"term {term} uses unknown signal {name!r}; known: {list(signal_names)}"
                    )
            left = index[term.left] + n_s * int(term.left_abs)
            right = (2 * n_s if term.right is None
                     else index[term.right] + n_s * int(term.right_abs))
            rows.append((left, right))
            equation.append(eq)
    factors = np.ascontiguousarray(np.asarray(rows, dtype=np.int64).reshape(-1, 2))
    return RegressorLayout(factors=factors, equation=np.asarray(equation, dtype=np.int64),
                           n_signals=n_s)


def factor_source(idx: int, n_signals: int) -> tuple[int, bool] | None:
    """``(signal index, modulus)`` of factor ``idx`` of ``F = [s, |s|, 1]``; None for 1."""
    if idx < n_signals:
        return idx, False
    if idx < 2 * n_signals:
        return idx - n_signals, True
    return None


def factor_vector(signals: np.ndarray) -> np.ndarray:
    """The factor vectors ``F = [s, |s|, 1]`` of an array of signal vectors ``(..., S)``."""
    s = np.asarray(signals, dtype=np.float64)
    return np.concatenate([s, np.abs(s), np.ones((*s.shape[:-1], 1))], axis=-1)


def evaluate(factors: np.ndarray | RegressorLayout, signals: np.ndarray) -> np.ndarray:
    """Evaluate the regressors on an array of signal vectors (vectorised numpy).

    Parameters
    ----------
    factors : ndarray, shape (P, 2), or RegressorLayout
        Factor layout from :func:`encode_terms`.
    signals : ndarray, shape (..., S)
        Signal vectors ``[x; u]``, last axis ordered as at encoding.

    Returns
    -------
    ndarray, shape (..., P)
        The regressor values Φ (Definition 2.1).
    """
    fac = factors.factors if isinstance(factors, RegressorLayout) else np.asarray(factors)
    f = factor_vector(signals)
    return f[..., fac[:, 0]] * f[..., fac[:, 1]]


def predict(layout: RegressorLayout, theta: np.ndarray, signals: np.ndarray) -> np.ndarray:
    """One-step predictions ``Φᵀ(s) θ`` of every equation (vectorised numpy).

    Sums in term order, like the compiled :func:`one_step`, so both agree bitwise.

    Parameters
    ----------
    layout : RegressorLayout
    theta : ndarray, shape (P,)
    signals : ndarray, shape (..., S)

    Returns
    -------
    ndarray, shape (..., n_equations)
    """
    contrib = evaluate(layout, signals) * np.asarray(theta, dtype=np.float64)
    n_eq = int(layout.equation.max()) + 1 if layout.n_params else 0
    out = np.zeros((*contrib.shape[:-1], n_eq))
    for p, i in enumerate(layout.equation):  # term order, as the compiled one_step
        out[..., i] += contrib[..., p]
    return out


def weights_matrix(layout: RegressorLayout, theta: np.ndarray) -> np.ndarray:
    """``W (P, n_equations)`` with ``Φ W = Φᵀθ`` per equation, for Φ matrices of many rows.

    ``phi @ weights_matrix(layout, θ)`` is one BLAS product (fast; equal to the term-order
    sum of :func:`predict` / :func:`one_step` up to rounding, not bit for bit).
    """
    n_eq = int(layout.equation.max()) + 1 if layout.n_params else 0
    weights = np.zeros((layout.n_params, n_eq))
    weights[np.arange(layout.n_params), layout.equation] = np.asarray(theta, dtype=np.float64)
    return weights


# ------------------------------------------------------------------ salted caching
def _salt() -> str:
    try:
        text = Path(__file__).read_bytes()
    except OSError:  # pragma: no cover - e.g. zip imports
        from vesselid import __version__ as text  # type: ignore[assignment]
        text = str(text).encode()
    return hashlib.sha256(text).hexdigest()[:16]


#: Digest of this module's source; part of every :func:`kernel` cache key.
SALT = _salt()

def _salted_cache_class() -> type | None:
    """numba's function cache with :data:`SALT` in the index key (None if numba moved it)."""
    try:
        from numba.core.caching import FunctionCache
    except ImportError:  # pragma: no cover - numba reorganised its internals
        return None

    class _SaltedCache(FunctionCache):
        """numba's function cache with :data:`SALT` in the index key."""

        def _index_key(self, sig, codegen):
            return (*super()._index_key(sig, codegen), SALT)

    return _SaltedCache


def kernel(**options: Any) -> Callable[[Callable], Any]:
    """``numba.njit(cache=True, **options)`` with the cache key salted by :data:`SALT`.

    Use it for every cached kernel that (inlines or) calls the helpers of this module.
    numba is imported when a function is decorated, not when this module is imported.
    """

    def decorate(fn: Callable) -> Any:
        from numba import njit

        _compiled_helpers()  # the helpers a kernel inlines, as module globals
        dispatcher = njit(**options)(fn)
        salted = _salted_cache_class()
        if salted is not None:
            try:
                dispatcher._cache = salted(dispatcher.py_func)
                return dispatcher
            except Exception:  # pragma: no cover - fall back to numba's plain cache
                pass
        dispatcher.enable_caching()  # pragma: no cover
        return dispatcher  # pragma: no cover

    return decorate


# --------------------------------------------------------------- compiled helpers
# Plain-Python bodies; :func:`_compiled_helpers` binds ``numba.njit(inline="always")``
# versions to the public names (module globals, where numba resolves them) on first use,
# so that importing this module (the layout, the numpy evaluation) does not import numba.
_HELPERS = ("fill_factors", "fill_factors_xu", "regressors", "one_step", "advance")
_HELPERS_LOCK = threading.Lock()


def _compiled_helpers() -> None:
    g = globals()
    if "advance" in g:
        return
    with _HELPERS_LOCK:
        if "advance" in g:
            return
        from numba import njit

        for name in _HELPERS:
            fn = g[f"_py_{name}"]
            g[name] = njit(inline="always")(fn)


def __getattr__(name: str) -> Any:
    if name in _HELPERS:
        _compiled_helpers()
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _py_fill_factors(s, f):
    """Fill ``f = [s, |s|, 1]`` (``len(f) == 2 len(s) + 1``)."""
    n_s = s.shape[0]
    for i in range(n_s):
        f[i] = s[i]
        f[n_s + i] = abs(s[i])
    f[2 * n_s] = 1.0


def _py_fill_factors_xu(x, u, f):
    """Fill ``f = [x, u, |x|, |u|, 1]``, the factor vector of ``s = [x; u]``."""
    n = x.shape[0]
    m = u.shape[0]
    n_s = n + m
    for i in range(n):
        f[i] = x[i]
        f[n_s + i] = abs(x[i])
    for j in range(m):
        f[n + j] = u[j]
        f[n_s + n + j] = abs(u[j])
    f[2 * n_s] = 1.0


def _py_regressors(factors, f, phi):
    """``phi[p] = f[factors[p, 0]] * f[factors[p, 1]]``: Φ from a filled factor vector."""
    for p in range(factors.shape[0]):
        phi[p] = f[factors[p, 0]] * f[factors[p, 1]]


def _py_one_step(equation, theta, phi, out):
    """The one-step update ``out[equation[p]] += θ_p φ_p`` (term order)."""
    for p in range(equation.shape[0]):
        out[equation[p]] += theta[p] * phi[p]


def _py_advance(factors, equation, theta, s, f, phi, out):
    """``out += Φᵀ(s) θ`` per equation, with the caller's work buffers ``f``, ``phi``."""
    fill_factors(s, f)  # noqa: F821 - the compiled helper (a module global once bound)
    regressors(factors, f, phi)  # noqa: F821
    one_step(equation, theta, phi, out)  # noqa: F821
