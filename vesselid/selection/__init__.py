"""Model-structure selection: which modulus terms each state equation needs.

>>> from vesselid.selection import select_terms
>>> res = select_terms(log, base_spec, library="full")     # doctest: +SKIP
>>> print(res.summary()); res.save("selected.toml")        # doctest: +SKIP

Consistent under a current inside the nonlinearity: the tests use instruments simulated
from the inputs (paper §3) with zero mean per experiment (Lemma 3.1), and batch-means
HAC covariances; see :mod:`vesselid.selection.engine`.
"""

from vesselid.selection.library import (
    SelectionError,
    full_library,
    parse_library,
    resolve_library,
)
from vesselid.selection.result import SelectionResult
from vesselid.selection.select import fit_structure, select_terms

__all__ = ["SelectionError", "SelectionResult", "fit_structure", "full_library",
           "parse_library", "resolve_library", "select_terms"]
