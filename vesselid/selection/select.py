"""``select_terms``: choose the modulus terms of every state equation from a log.

The method is described in :mod:`vesselid.selection.engine`; this module validates the
input, runs the passes and the bootstrap, and builds the :class:`SelectionResult`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from vesselid.identify.backend import kernels
from vesselid.identify.data import from_log
from vesselid.model.spec import ModelSpec
from vesselid.model.terms import Term
from vesselid.selection import engine
from vesselid.selection.library import Library, SelectionError, resolve_library
from vesselid.selection.result import SelectionResult

__all__ = ["fit_structure", "select_terms"]


def _least_squares(data, spec: ModelSpec) -> np.ndarray | None:
    """Least squares of ``spec`` on the centred equation rows (per equation)."""
    segs = engine.equation_rows_per_segment(data)
    codes = spec.codes
    phi_c = engine.centred(kernels.regressor_matrix(data.regsig, data.u, data.starts,
                                                    codes.factors), segs)
    y_c = engine.centred(data.target, segs)
    theta = np.zeros(spec.n_params)
    for i in range(spec.n_states):
        cols = np.flatnonzero(codes.equation == i)
        theta[cols] = np.linalg.lstsq(phi_c[:, cols], y_c[:, i], rcond=None)[0]
    return theta if np.all(np.isfinite(theta)) else None


def _refined_iv(data, spec: ModelSpec, *, max_iter: int = 30, tol: float = 1e-8
                ) -> np.ndarray | None:
    """Refined IV with zero-mean instruments (the paper's ``IV_E{ζ}=0``, (4)/(6) pooled)
    from the least-squares start, on the generic kernels (no kernel compiled per
    structure: selection visits many structures). ``None`` when no auxiliary simulation
    stays bounded; else the last iterate whose instruments could be simulated."""
    theta = _least_squares(data, spec)
    if theta is None:
        return None
    segs = engine.equation_rows_per_segment(data)
    codes = spec.codes
    phi_c = engine.centred(kernels.regressor_matrix(data.regsig, data.u, data.starts,
                                                    codes.factors), segs)
    y_c = engine.centred(data.target, segs)
    bound = 1e3 * max(float(np.abs(data.target).max()), 1.0)
    eq_cols = [np.flatnonzero(codes.equation == i) for i in range(spec.n_states)]
    phi_eq = [phi_c[:, cols] for cols in eq_cols]  # each equation's columns, copied once
    del phi_c
    good = None
    for _ in range(max_iter):
        with np.errstate(all="ignore"):
            z, xhat = kernels.instrument_matrix(data.target, data.u, data.starts, theta,
                                                codes.factors, codes.equation, spec.n_states)
        if not np.all(np.isfinite(xhat)) or float(np.abs(xhat).max()) > bound:
            return good
        good = theta
        z_c = engine.centred(z, segs)
        new = np.zeros_like(theta)
        for i, cols in enumerate(eq_cols):
            z_i = z_c[:, cols]
            try:
                new[cols] = np.linalg.solve(z_i.T @ phi_eq[i], z_i.T @ y_c[:, i])
            except np.linalg.LinAlgError:
                return good
        if not np.all(np.isfinite(new)):
            return good
        step = np.max(np.abs(new - theta)) / max(float(np.max(np.abs(new))), 1e-300)
        theta = new
        if step < tol:
            break
    return theta


def _library_model(data, spec: ModelSpec, union: list[Term], keep_idx: dict[str, np.ndarray],
                   z: np.ndarray, segs, phi_c: np.ndarray, y_c: np.ndarray,
                   iterations: int = 3) -> tuple[np.ndarray, float, ModelSpec] | None:
    """Every represented candidate, fitted by IV with zero-mean instruments ``z`` (those
    of the base model) and refined ``iterations`` times with the instruments it simulates
    itself, and the same model fitted by refined IV from least squares: consistent models
    of the whole library whose simulation tracks the vessel where a base model with few
    terms does not. With many candidates one such fit can come out far off in a given log
    (weak first instruments), so every iterate of both chains is scored by its
    :func:`~vesselid.selection.engine.simulation_error` and the best is kept. Returns its
    instruments, their simulation error and the library spec, or ``None`` when no iterate
    gives a bounded simulation."""
    full = _spec_with(spec, {s: [union[j] for j in keep_idx[s]] for s in spec.states},
                      name=f"{spec.name} (library)")
    best = None
    z_cur = z
    for _ in range(int(iterations)):
        z_next = _iv_start(data, full, union, keep_idx, z_cur, segs, phi_c, y_c)
        if z_next is None:
            break
        if best is None or z_next[1] < best[1]:
            best = z_next
        z_cur = z_next[0]
    theta_ls = _refined_iv(data, full, max_iter=int(iterations))
    if theta_ls is not None:
        try:
            alt = engine.instruments(data, union, full, theta_ls, with_error=True)
        except SelectionError:
            alt = None
        if alt is not None and (best is None or alt[1] < best[1]):
            best = alt
    return None if best is None else (*best, full)


def _iv_start(data, full, union, keep_idx, z, segs, phi_c, y_c
              ) -> tuple[np.ndarray, float] | None:
    """Instruments simulated by the library model fitted by IV with instruments ``z`` and
    their simulation error; ``None`` when that fit is singular or its simulation
    diverges."""
    z_c = engine.centred(z, segs)
    theta = []
    for i, s in enumerate(full.states):
        sub = keep_idx[s]
        try:
            theta.append(np.linalg.solve(z_c[:, sub].T @ phi_c[:, sub],
                                         z_c[:, sub].T @ y_c[:, i]))
        except np.linalg.LinAlgError:
            return None
    theta_v = np.concatenate(theta)
    if not np.all(np.isfinite(theta_v)):
        return None
    try:
        return engine.instruments(data, union, full, theta_v, with_error=True)
    except SelectionError:
        return None


def _spec_with(spec: ModelSpec, equations: dict[str, list[Term]], name: str | None = None
               ) -> ModelSpec:
    return ModelSpec(name or spec.name, spec.states, spec.inputs,
                     {s: list(equations[s]) for s in spec.states},
                     aggregate=dict(spec.aggregate) or None, dt=spec.dt,
                     derived=dict(spec.derived) or None)


def _check_number(name: str, value: Any, lo: float, hi: float) -> float:
    try:
        val = float(value)
    except (TypeError, ValueError):
        raise SelectionError(f"{name} must be a number in ({lo:g}, {hi:g}), got {value!r}"
                             ) from None
    if not (math.isfinite(val) and lo < val < hi):
        raise SelectionError(f"{name} must be a number in ({lo:g}, {hi:g}), got {value!r}")
    return val


def select_terms(
    log: Any,
    spec: ModelSpec | None = None,
    library: str | Library | list | None = None,
    *,
    alpha: float = 0.01,
    n_boot: int = 100,
    block_length: int | None = None,
    tol: float = 1e-4,
    passes: int = 3,
    near: float = 0.999,
    seed: int = 0,
    first_model: str = "base",
) -> SelectionResult:
    """Select the terms of every state equation from a candidate library.

    Parameters
    ----------
    log : TrialLog or DataFrame
        The trial log (one column per state, input and aggregate sensor).
    spec : ModelSpec, optional
        Base model: states, inputs, ``dt``, aggregate relations, and equations whose
        refined-IV fit is the first auxiliary model of the instruments (its terms need not
        be right; a stable model with the dominant terms is enough). Default: the log's.
    library : str, list of terms, or mapping state -> terms, optional
        Candidates (see :func:`~vesselid.selection.library.resolve_library`); default
        every form of Definition 2.1 over the states and inputs (``"full"``).
    alpha : float
        Family-wise level of the Bonferroni part of the critical value (default 0.01).
    n_boot : int
        Block-bootstrap replicates for the selection probabilities (0: none).
    block_length : int, optional
        Samples per block of the HAC estimator and the bootstrap (default
        :func:`~vesselid.selection.engine.make_blocks`).
    tol : float
        Share of a centred regressor's sum of squares left after projection on earlier
        candidates below which it counts as the same in the data.
    passes : int
        Most selection passes (each re-simulates the instruments from the last selection).
    near : float
        ``|corr|`` of centred regressors from which an unselected candidate is reported as
        a near alternative of a selected one.
    seed : int
        Seed of the bootstrap.
    first_model : {"base", "library"}
        Auxiliary model of the first pass's instruments: the base model's refined-IV fit
        (``"base"``), or (``"library"``) every represented candidate of the library
        fitted by IV with the base model's instruments and refined three times with its
        own simulated instruments, or by refined IV from least squares: of these fits the
        one whose simulation tracks the log best
        (:func:`~vesselid.selection.engine.simulation_error`), when it tracks the log at
        least as well as the base model's fit (else the base model). The library model
        tracks a vessel whose base model is too simple (e.g. linear) far better, which
        strengthens the instruments of every test.

    Returns
    -------
    SelectionResult

    Raises
    ------
    SelectionError
        Empty library, unknown term or signal, a library larger than the log supports,
        invalid options, an auxiliary model whose simulation diverges.
    LogValidationError
        Missing columns, NaN/inf, non-increasing time.
    """
    if first_model not in ("base", "library"):
        raise SelectionError(f"first_model must be 'base' or 'library', got {first_model!r}")
    alpha = _check_number("alpha", alpha, 0.0, 1.0)
    tol = _check_number("tol", tol, 0.0, 1.0)
    near = _check_number("near", near, 0.0, 1.0 + 1e-12)
    for label, val, lo in (("n_boot", n_boot, 0), ("passes", passes, 1)):
        if isinstance(val, bool) or not isinstance(val, int | np.integer) or val < lo:
            raise SelectionError(f"{label} must be an integer >= {lo}, got {val!r}")
    if block_length is not None and (isinstance(block_length, bool) or not isinstance(
            block_length, int | np.integer) or block_length < 2):
        raise SelectionError(f"block_length must be an integer >= 2, got {block_length!r}")
    if spec is None:
        from vesselid.data.logs import TrialLog

        spec = (log if isinstance(log, TrialLog) else TrialLog(log)).spec
        if spec is None:
            raise SelectionError("no base model given and the log carries no spec")
    lib = resolve_library(library, spec)
    data, spec = from_log(log, spec)
    union, cols = engine.library_factors(lib, spec)
    names = [str(t) for t in union]
    phi = engine.regressors(data, union, spec)
    segs = engine.equation_rows_per_segment(data)
    offset = np.zeros(int(data.starts[-1]), dtype=np.int64)
    pos = 0
    for a, b in segs:
        offset[a:b] = pos + np.arange(b - a)
        pos += b - a
    n_rows = pos
    phi_c = engine.centred(phi, segs)
    if not np.all(np.isfinite(phi_c)):
        raise SelectionError("a candidate regressor overflows on this log (values too large "
                             "for their squares and products); rescale the signals")
    y_c = engine.centred(data.target, segs)
    blocks = engine.make_blocks(data, block_length)

    keep_idx: dict[str, np.ndarray] = {}
    groups: dict[str, list[dict]] = {}
    screened: dict[tuple[int, ...], tuple] = {}  # equations with the same candidates
    for s in spec.states:
        sub_names = [names[j] for j in cols[s]]
        key = tuple(int(j) for j in cols[s])
        if key not in screened:
            screened[key] = engine.same_in_data_groups(phi_c[:, cols[s]], sub_names, tol)
        k, g = screened[key]
        if k.size == 0:
            raise SelectionError(f"no candidate of equation {s!r} varies within an experiment "
                                 "of this log")
        keep_idx[s] = cols[s][k]
        groups[s] = g
    max_terms = max(min(n_rows // 10, (blocks.n - 1) // 2), 0)
    for s in spec.states:
        if len(lib[s]) > max_terms:
            raise SelectionError(
                f"the library of equation {s!r} has {len(lib[s])} candidates, more than this "
                f"log supports ({max_terms}: {n_rows} samples in {blocks.n} blocks of "
                f"{blocks.length}); use a smaller library or a longer log")
    m_total = sum(int(k.size) for k in keep_idx.values())
    crit = engine.critical_value(alpha, m_total, n_rows)

    z = None
    for fitter, label in ((_refined_iv, "refined IV, zero-mean instruments"),
                          (_least_squares, "least squares")):
        theta_aux = fitter(data, spec)
        if theta_aux is None:
            continue
        try:
            z, z_err = engine.instruments(data, union, spec, theta_aux, with_error=True)
        except SelectionError:
            continue
        aux_source = f"base model ({label})"
        break
    if z is None:
        raise SelectionError("the base model cannot be fitted to this log or its simulation "
                             "diverges, so no instruments can be formed; give a stable base "
                             "model (--model) whose equations hold the dominant terms")

    if first_model == "library":
        lib_model = _library_model(data, spec, union, keep_idx, z, segs, phi_c, y_c)
        if lib_model is not None and lib_model[1] <= z_err:
            z, z_err = lib_model[0], lib_model[1]
            aux_source = "library model (IV from the base model's instruments, refined)"

    # refined-IV fits by structure: the converged pass refits the structure it selects,
    # and that fit is the reported one (each computed once)
    refits: dict[tuple, np.ndarray | None] = {}

    def refit(aux: ModelSpec) -> np.ndarray | None:
        key = tuple(tuple(str(t) for t in aux.equations[s]) for s in aux.states)
        if key not in refits:
            refits[key] = _refined_iv(data, aux)
        return refits[key]

    history: list[dict[str, list[str]]] = []
    fits: dict[str, tuple] = {}
    moments = None
    converged = False
    for _ in range(int(passes)):
        z_c = engine.centred(z, segs)
        m_mat, m_vec = engine.block_moments(z_c, phi_c, y_c, blocks, offset)
        moments = (m_mat, m_vec)
        ones = np.ones(blocks.n)
        chosen: dict[str, list[Term]] = {}
        for i, s in enumerate(spec.states):
            sub = keep_idx[s]
            fits[s] = engine.select_equation(m_mat[:, sub][:, :, sub], m_vec[:, sub, i], ones, crit)
            chosen[s] = [union[sub[j]] for j in np.flatnonzero(fits[s][0])]
        key = {s: [str(t) for t in chosen[s]] for s in spec.states}
        if history and key == history[-1]:
            history.append(key)
            converged = True
            break
        history.append(key)
        new_aux = _spec_with(spec, chosen)
        new_theta = refit(new_aux)
        if new_theta is None:
            break
        try:
            z_new, err_new = engine.instruments(data, union, new_aux, new_theta,
                                                with_error=True)
        except SelectionError:  # keep the last instruments that could be simulated
            break
        z, z_err = z_new, err_new
        aux_source = "selected model (refined IV, zero-mean instruments)"
    if not converged and len(history) >= 2 and history[-1] == history[-2]:
        converged = True

    final = history[-1]
    selected_terms = {s: [Term.parse(t) for t in final[s]] for s in spec.states}
    out_spec = _spec_with(spec, selected_terms)

    # block bootstrap of the last pass
    prob = {s: np.zeros(keep_idx[s].size) for s in spec.states}
    if n_boot > 0 and moments is not None:
        m_mat, m_vec = moments
        rng = np.random.default_rng(seed)
        counts = engine.bootstrap_counts(blocks, int(n_boot), rng)
        for i, s in enumerate(spec.states):
            sub = keep_idx[s]
            mm = m_mat[:, sub][:, :, sub]
            mv = m_vec[:, sub, i]
            acc = np.zeros(sub.size)
            for r in range(int(n_boot)):
                acc += engine.select_equation(mm, mv, counts[r], crit)[0]
            prob[s] = acc / n_boot
    theta_final = refit(out_spec)

    undecided: dict[str, dict[int, list[int]]] = {}
    if moments is not None:
        m_mat, m_vec = moments
        for i, s in enumerate(spec.states):
            sub = keep_idx[s]
            undecided[s] = engine.indistinguishable(m_mat[:, sub][:, :, sub], m_vec[:, sub, i],
                                                    fits[s][0], crit)
    table = _table(spec, lib, names, cols, keep_idx, groups, fits, prob, phi_c, near,
                   n_boot > 0, undecided)
    return SelectionResult(
        spec=out_spec, base=spec, library=lib, table=table, groups=groups,
        alpha=alpha, critical_value=crit, n_candidates=m_total, n_boot=int(n_boot),
        block_length=blocks.length, n_blocks=blocks.n, passes=len(history),
        converged=converged, history=history, aux_source=aux_source,
        n_samples=int(data.starts[-1]), n_experiments=data.n_segments, seed=int(seed),
        theta=(None if theta_final is None else
               pd.Series(theta_final, index=out_spec.param_index, name="estimate")),
    )


def _table(spec, lib, names, cols, keep_idx, groups, fits, prob, phi_c, near, boot,
           undecided):
    rows = []
    for s in spec.states:
        keep, theta, t, cov = fits[s]
        sub = keep_idx[s]
        kept_names = [names[j] for j in sub]
        where = {n: k for k, n in enumerate(kept_names)}
        member_of: dict[str, dict] = {}
        for g in groups[s]:
            for mname in g["members"]:
                if mname not in where:
                    member_of[mname] = g
        # near alternatives among the identifiable candidates
        cc = phi_c[:, sub]
        sd = np.sqrt(np.einsum("ij,ij->j", cc, cc))
        corr = (cc.T @ cc) / np.outer(sd, sd)
        alternatives: dict[str, list[str]] = {}
        for k in np.flatnonzero(keep):
            alt = [kept_names[j] for j in np.flatnonzero(np.abs(corr[k]) >= near)
                   if j != k and not keep[j]]
            if alt:
                alternatives[kept_names[k]] = alt
        either = {kept_names[j]: ", ".join(kept_names[k] for k in ks)
                  for j, ks in undecided.get(s, {}).items()}
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
        for term in lib[s]:
            name = str(term)
            if name in where:
                k = where[name]
                rows.append({
                    "equation": s, "term": name, "represented_by": name,
                    "selected": bool(keep[k]),
                    "probability": float(prob[s][k]) if boot else math.nan,
                    "estimate": float(theta[k]) if keep[k] else math.nan,
                    "stderr": float(se[k]) if keep[k] else math.nan,
                    "t": float(t[k]), "same_as": "",
                    "alternatives": ", ".join(alternatives.get(name, [])),
                    "undecided": either.get(name, ""),
                })
            else:
                g = member_of.get(name, {"kept": None, "reason": "", "members": []})
                rep = g.get("kept")
                if rep is None:
                    rep_members = [m for m in g["members"] if m in where]
                    rep = rep_members[0] if len(rep_members) == 1 else None
                p = (float(prob[s][where[rep]]) if (boot and rep is not None)
                     else (0.0 if boot else math.nan))
                rows.append({
                    "equation": s, "term": name, "represented_by": rep or "",
                    "selected": False, "probability": p,
                    "estimate": math.nan, "stderr": math.nan, "t": math.nan,
                    "same_as": g.get("reason", ""), "alternatives": "", "undecided": "",
                })
    return pd.DataFrame(rows)


def fit_structure(log: Any, spec: ModelSpec) -> pd.Series:
    """Refined IV with zero-mean instruments of ``spec`` on ``log`` (the estimator the
    selection uses for its auxiliary models), on the generic kernels: no kernel is
    compiled per structure, so trying many candidate structures stays cheap. For the
    reported identification (covariance, diagnostics) use ``identify`` on the written
    spec.

    Raises
    ------
    SelectionError
        If no auxiliary simulation of the structure stays bounded on the log.
    """
    data, spec = from_log(log, spec)
    theta = _refined_iv(data, spec)
    if theta is None:
        raise SelectionError(f"the structure {spec.name!r} cannot be fitted to this log "
                             "(its auxiliary simulation diverges)")
    return pd.Series(theta, index=spec.param_index, name="estimate")
