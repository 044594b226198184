"""The default's specification check on multi-state logs (``auto`` → SRIV).

When ``auto``'s tests reject the delayed instruments on a multi-state log, it falls back to
simulated instruments with an AR noise-model prefilter (SRIV). Under a *correct* model
structure the prefilter changes only the efficiency: SRIV and the unfiltered
simulated-instrument estimate (IV_E{ζ}=0, Lemma 3.1/4.1) are both consistent for the same
θ. Under a *misspecified* structure (a real vessel's forces are never exactly a
second-order modulus polynomial) they are not: each converges to its own pseudo-true
value, and the whitening prefilter — a high-pass filter when the equation error is
dominated by slow, structural error — weights the band where the model is worst. A
significant difference between the two is therefore evidence of misspecification
(a Hausman-type test), and then the unfiltered estimate is returned: its weighting of the
frequencies follows the signals', as the free-run simulation that validates a model does.

Second, once misspecification is evident the per-experiment constants of the zero-mean
instruments stand for an unknown mean disturbance (a current) that the identified model,
simulated without offsets, will not have. The plain refined IV (no constants, the paper's
IV) is consistent when there is no such offset; when it does not differ significantly from
IV_E{ζ}=0, the data show no offset and the plain estimate is returned (it keeps the level
information the constants throw away); when it differs, IV_E{ζ}=0 is kept.

The test. Neither estimator is efficient under misspecification or coloured disturbances,
so the classical variance difference ``V_b − V_a`` is not a valid variance of
``θ̂_a − θ̂_b``. The check uses the bound ``sd(θ̂_a,j − θ̂_b,j) ≤ se_a,j + se_b,j``
(Cauchy–Schwarz, whatever the correlation of the two estimates) and rejects when
``max_j |θ̂_a,j − θ̂_b,j| / (se_a,j + se_b,j)`` exceeds the normal quantile
``z_{1−α/(2P)}`` (Bonferroni over the ``P`` parameters): its size is at most ``α``, so
a correctly specified log keeps SRIV in at least ``1 − α`` of the cases (it is
conservative: only gross differences reject). The measured effect on the HSVA KVLCC2
zig-zags and on the simulated sea trials is in ``docs/guide/real-vessel.md``
(``scripts/kvlcc2_study.py``).
"""

from __future__ import annotations

import math
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

from vesselid.errors import IdentificationError, MisspecificationWarning

if TYPE_CHECKING:
    from vesselid.identify.results import IdentificationResult

__all__ = ["SPEC_ALPHA", "bounded_hausman", "check_default"]

#: Level of each of the two checks (at most; the test is conservative).
SPEC_ALPHA = 0.01


def bounded_hausman(a: IdentificationResult, b: IdentificationResult,
                    alpha: float = SPEC_ALPHA) -> dict[str, Any]:
    """Conservative Hausman-type comparison of two estimates of the same θ.

    Parameters
    ----------
    a, b : IdentificationResult
        Two estimates of the same spec (same parameter index).
    alpha : float
        Level (an upper bound on the size, module docstring).

    Returns
    -------
    dict
        ``statistic`` (largest ``|Δθ_j| / (se_a,j + se_b,j)``), ``critical``
        (``z_{1−α/(2P)}``), ``parameter`` (where the largest difference is), ``pvalue_bound``
        (``min(1, 2P(1 − Φ(statistic)))``, an upper bound of the p-value), ``rejected``,
        ``level``, ``methods`` (``[a.method, b.method]``); ``rejected`` is ``False`` and
        ``statistic`` NaN where a standard error is missing (no evidence either way).
    """
    from vesselid.identify._special import norm_ppf

    ta, tb = a.params.to_numpy(float), b.params.to_numpy(float)
    sa, sb = a.std_errors.to_numpy(float), b.std_errors.to_numpy(float)
    n = ta.size
    crit = float(norm_ppf(1.0 - alpha / (2.0 * n)))
    den = sa + sb
    ok = np.isfinite(ta) & np.isfinite(tb) & np.isfinite(den) & (den > 0)
    out: dict[str, Any] = {"methods": [a.method, b.method], "level": float(alpha),
                           "critical": crit, "n_params": int(n)}
    if not ok.all():
        out.update(statistic=float("nan"), parameter="", pvalue_bound=float("nan"),
                   rejected=False)
        return out
    z = np.abs(ta - tb) / den
    j = int(np.argmax(z))
    eq, term = a.params.index[j]
    stat = float(z[j])
    out.update(statistic=stat, parameter=f"{eq}: {term}",
               pvalue_bound=float(min(1.0, n * math.erfc(stat / math.sqrt(2.0)))),
               rejected=bool(stat > crit))
    return out


def _usable(res: IdentificationResult | None) -> bool:
    if res is None:
        return False
    from vesselid.identify.results import assess

    return assess(res)[0] == "accepted"


def _fit(method: str, log: Any, spec: Any, options: Any
         ) -> tuple[IdentificationResult | None, list, str]:
    from vesselid.errors import EstimationFailedError
    from vesselid.identify.methods import RefinedIV

    # the comparison estimators by class, not through the registry (which names this
    # module's caller): "iv" and "iv-zero-mean" are the registry's RefinedIV entries
    estimator = RefinedIV(zero_mean=method == "iv-zero-mean")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            res = estimator.fit(log, spec, options)
        except (EstimationFailedError, IdentificationError, np.linalg.LinAlgError,
                FloatingPointError) as exc:
            return None, [], str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return res, list(caught), ""


def check_default(sriv: IdentificationResult, caught: list, log: Any, spec: Any,
                  options: Any) -> tuple[IdentificationResult, list]:
    """The specification check of ``auto``'s SRIV result ``sriv`` (module docstring).

    ``caught``: the warnings of ``sriv``'s fit; ``options``: the fit options (passed on to
    the comparison fits). Returns the chosen result and its warnings (to re-emit); the
    chosen result's ``diagnostics["specification_check"]`` holds both tests, and where the
    choice is not SRIV, ``choice``, ``choice_reason`` and a leading warning say why.
    """
    from vesselid.identify.options import FitOptions

    opts = FitOptions.of(options, instruments=None)
    zm, zm_caught, zm_err = _fit("iv-zero-mean", log, spec, opts)
    if not _usable(zm):
        sriv.diagnostics["specification_check"] = {
            "prefilter": None,
            "levels": None,
            "sentence": ("specification check not run: the unfiltered simulated-instrument "
                         "estimate (IV_E{ζ}=0) is not usable on this log"
                         + (f" ({zm_err})" if zm_err else "")),
        }
        return sriv, caught
    assert zm is not None
    pre = bounded_hausman(sriv, zm)
    if not pre["rejected"]:
        sriv.diagnostics["specification_check"] = {
            "prefilter": pre, "levels": None,
            "sentence": (f"SRIV and the unfiltered IV_E{{ζ}}=0 agree (largest difference "
                         f"{pre['statistic']:.2f} summed standard errors, at "
                         f"{pre['parameter']}; critical {pre['critical']:.2f} at level "
                         f"{pre['level']:g}): no sign of misspecification"),
        }
        return sriv, caught
    pre_txt = (f"SRIV (AR noise-model prefilter) and the unfiltered IV_E{{ζ}}=0 differ by "
               f"{pre['statistic']:.1f} summed standard errors at {pre['parameter']} "
               f"(critical {pre['critical']:.2f}, level {pre['level']:g}; p ≤ "
               f"{pre['pvalue_bound']:.2g}): both are consistent under a correct model, so "
               "the model structure is misspecified on this log and the prefilter, which "
               "weights the band where the model is worst, is dropped")
    plain, pl_caught, pl_err = _fit("iv", log, spec, opts)
    levels = bounded_hausman(plain, zm) if _usable(plain) else None
    if levels is not None and not levels["rejected"]:
        assert plain is not None
        chosen, chosen_caught, key = plain, pl_caught, "iv"
        lvl_txt = (f"the refined IV without per-experiment constants agrees with IV_E{{ζ}}=0 "
                   f"(largest difference {levels['statistic']:.2f} summed standard errors, "
                   f"critical {levels['critical']:.2f}): no sign of a mean disturbance per "
                   "experiment, so the estimate without constants is used — it keeps the "
                   "level information the constants discard, and the model is simulated "
                   "without offsets")
    else:
        chosen, chosen_caught, key = zm, zm_caught, "iv-zero-mean"
        lvl_txt = ("the refined IV without per-experiment constants "
                   + (f"is not usable ({pl_err or 'see its fallback outcome'})"
                      if levels is None else
                      f"differs from IV_E{{ζ}}=0 by {levels['statistic']:.1f} summed standard "
                      f"errors at {levels['parameter']} (critical {levels['critical']:.2f}): "
                      "the experiments carry mean disturbances")
                   + ", so IV_E{ζ}=0 (zero-mean instruments) is used")
    reason = f"auto's specification check: {pre_txt}; {lvl_txt}."
    diag = chosen.diagnostics
    diag["specification_check"] = {"prefilter": pre, "levels": levels, "sentence": reason}
    diag["auto_instrument_choice"] = sriv.diagnostics.get("instrument_choice")
    diag["choice"] = key
    diag["choice_reason"] = reason
    note = (f"the model structure looks misspecified on this log: {pre_txt}; the result is "
            f"{key!r}'s ({lvl_txt.split(', so ')[0]})")
    diag.setdefault("warnings", []).insert(0, note)
    with warnings.catch_warnings(record=True) as mine:
        warnings.simplefilter("always")
        warnings.warn(note, MisspecificationWarning, stacklevel=2)
    return chosen, [*mine, *chosen_caught]
