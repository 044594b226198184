"""The default estimator's fallback chain.

``identify(log, spec)`` with the default method runs :data:`CHAIN` in order and returns
the first *usable* result; the chain tried is recorded in the result
(``diagnostics["fallback_chain"]``: one entry per estimator with ``method``, ``outcome``
and a one-line ``reason``; ``summary()``, ``identify --json``).

What counts as a failure of a member (``outcome``):

* ``raised`` — no estimate (:class:`~vesselid.errors.EstimationFailedError`: singular
  instrument equations, an auxiliary model that diverges from every start, a likelihood
  that could not be maximised), or the estimator does not apply to this log (e.g. ``pem``
  on a multi-state log);
* ``non-finite`` — NaN/inf parameters or fit figures;
* ``unstable`` — the free-run simulation on the log's inputs diverges or leaves ten times
  the measured excursion (:mod:`vesselid.identify.stability`);
* ``not converged`` — the refined iteration stopped without meeting either stopping rule
  (relative residual, or a last step below 0.1 standard errors), e.g. its auxiliary model
  diverged on the way.

A member with none of these is ``accepted`` and the chain stops. When no member is
accepted, the first finite and stable one is returned (its own outcome says what is
wrong), else the first finite one (``status`` ``"unstable"``: the command line exits 3);
when no member gave a finite estimate, :class:`~vesselid.errors.NoUsableModelError`
carries the chain. Bad input (missing columns, collinear regressors, bad options) is
raised by the first member at once: no estimator can do better.

The order: the default ``auto``; then the estimators consistent under the broadest
conditions — simulated instruments with zero-mean per experiment (the paper's
IV_E{ζ}=0, Lemma 3.1/4.1), SRIV (the same instruments with an AR noise model), the
prediction-error estimator (efficient when its Gauss–Markov disturbance model holds;
one-state logs); then the members of :data:`CONDITIONAL`: GMM with delayed measurements
added and 2SLS with delayed measured regressors (consistent on white disturbances only),
finally least squares, which always exists and is biased under sensor noise — the chain's
entry says so. The conditional members are reached only when no earlier member gave a
finite, stable result: a result of valid instruments that did not converge (``status``
``"not converged"``, its last step in standard errors in the stop reason) is returned
before an estimate whose instruments may be invalid.

The first member's own result may already be another estimator's: ``auto`` on a
multi-state log ends with its specification check
(:mod:`vesselid.identify.misspecification`), which can return the unfiltered IV_E{ζ}=0
or the plain refined IV instead of SRIV. That is ``auto``'s choice (its
``choice_reason`` and a :class:`~vesselid.errors.MisspecificationWarning` say why), not a
fallback: the chain records ``auto`` as accepted.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from vesselid.errors import (
    EstimationFailedError,
    FallbackWarning,
    IdentificationError,
    NoUsableModelError,
)
from vesselid.identify.options import FitOptions
from vesselid.identify.results import assess

if TYPE_CHECKING:
    from vesselid.identify.results import IdentificationResult

__all__ = ["CHAIN", "assess", "identify_with_fallback"]

#: The fallback order of the default estimator (module docstring).
CHAIN: tuple[str, ...] = ("auto", "iv-zero-mean", "sriv", "pem", "gmm", "lagged-2sls", "ls")

#: Members whose consistency needs white disturbances (delayed measurements among the
#: instruments) or no sensor noise (LS): a finite, stable but not converged result of an
#: earlier member is preferred to them — its instruments are valid, theirs may not be.
CONDITIONAL = ("gmm", "lagged-2sls", "ls")

#: What the chain's entry adds for the estimators whose validity is conditional.
CAVEATS = {
    "lagged-2sls": "consistent only when every disturbance is white",
    "gmm": "its delayed-measurement instruments are valid only when every disturbance "
           "is white",
    "ls": "biased under sensor noise (errors in variables); intervals ignore that bias",
    "pem": "assumes a Gauss–Markov disturbance",
}


def identify_with_fallback(log: Any, spec: Any, chain: tuple[Any, ...] = CHAIN,
                           options: FitOptions | None = None,
                           **overrides: Any) -> IdentificationResult:
    """Run ``chain`` (registry names or estimator objects) on ``log`` with the fit
    ``options`` (``overrides`` by name) and return the first usable result, with
    ``diagnostics["fallback_chain"]`` (module docstring)."""
    import warnings

    from vesselid.identify.registry import get_estimator

    options = FitOptions.of(options, **overrides)

    tried: list[dict[str, str]] = []
    candidates: list[tuple[str, IdentificationResult, list]] = []
    chosen = None
    first = None  # the first member's own result
    for k, item in enumerate(chain):
        est = get_estimator(item)
        name = est.name
        if k and name in CONDITIONAL and any(c[0] == "not converged" for c in candidates):
            break  # a valid-instrument result that did not converge beats these
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                res = est.fit(log, spec, options)
            except EstimationFailedError as exc:
                tried.append(_entry(name, "raised", _one_line(exc)))
                continue
            except (IdentificationError, np.linalg.LinAlgError, FloatingPointError) as exc:
                if k == 0 and isinstance(exc, IdentificationError):
                    raise  # bad input: no estimator of the chain can do better
                tried.append(_entry(name, "raised" if k == 0 else "not applicable",
                                    _one_line(exc)))
                continue
        if k == 0:
            first = res
        outcome, reason = assess(res)
        if name in CAVEATS and outcome == "accepted":
            reason = f"{reason}; {CAVEATS[name]}"
        tried.append(_entry(name, outcome, reason))
        candidates.append((outcome, res, caught))
        if outcome == "accepted":
            chosen = candidates[-1]
            break
    if chosen is None:
        finite = [c for c in candidates if c[0] != "non-finite"]
        stable = [c for c in finite if c[0] == "not converged"]
        pick = stable or finite or candidates
        if not pick:
            raise NoUsableModelError(
                "no estimator gave a finite estimate — "
                + "; ".join(f"{t['method']}: {t['reason']}" for t in tried), chain=tried)
        chosen = pick[0]
    outcome, res, caught = chosen
    for w in caught:  # the chosen fit's warnings reach the caller, as without the chain
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    res.diagnostics["fallback_chain"] = tried
    from vesselid.identify.loop import closed_loop_note

    closed = closed_loop_note(res.diagnostics.get("feedback"))
    prior = str(res.diagnostics.get("choice_reason") or "")
    if closed and not prior.startswith("CLOSED LOOP"):  # an open-loop member's result
        res.diagnostics["choice_reason"] = closed + (f" {prior}" if prior else "")
    if res is not first:  # a later member's result (auto handing a log to cl-iv is not one)
        note = (f"the estimator {tried[0]['method']!r} failed ({tried[0]['outcome']}: "
                f"{tried[0]['reason']}); the result is {res.method!r}'s "
                f"(fallback chain: {' → '.join(t['method'] for t in tried)})")
        res.diagnostics.setdefault("warnings", []).insert(0, note)
        warnings.warn(note, FallbackWarning, stacklevel=3)
    return res


def _entry(method: str, outcome: str, reason: str) -> dict[str, str]:
    return {"method": method, "outcome": outcome, "reason": reason}


def _one_line(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text
