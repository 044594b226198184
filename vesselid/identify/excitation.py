"""Excitation of the inputs and what an unexcited input leaves unidentifiable.

A design-level check on the regressors, before any estimate:

* an input is *not excited* when it is constant within every experiment (its range
  within each experiment at most :data:`CONSTANT_RTOL` of its magnitude) — e.g. the
  propeller rpm of free-running zig-zag model tests, held at the self-propulsion point;
* a term is *not identifiable with per-experiment constants* when its regressor, centred
  within each experiment, is zero or collinear with the other centred regressors of its
  equation (:func:`vesselid.identify.diagnostics.collinear_terms`). Every estimator that carries a
  constant per experiment (zero-mean instruments: ``iv-zero-mean``, ``auto``, ``sriv``,
  ``gmm``; ``lagged-2sls``) then cannot estimate it: a constant input's term is absorbed
  into the experiments' offsets. Least squares (no constants) still returns a number for
  it, but only as the equation's constant: a force at that fixed input, not the input's
  effect.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from vesselid.identify.diagnostics import collinear_terms
from vesselid.model.spec import ModelSpec

if TYPE_CHECKING:
    from vesselid.identify.data import RegressionData

__all__ = ["CONSTANT_RTOL", "excitation_report"]

#: An input whose range within every experiment is at most this share of its magnitude
#: counts as constant (not excited).
CONSTANT_RTOL = 1e-6


def excitation_report(data: RegressionData, spec: ModelSpec, phi: np.ndarray,
                      rows: np.ndarray) -> dict[str, Any]:
    """Input excitation and the terms lost to per-experiment constants (JSON-ready).

    Parameters
    ----------
    data : RegressionData
    spec : ModelSpec
    phi : ndarray (T, P)
        Regressor rows of ``data``.
    rows : ndarray (T,) bool
        Rows that hold an equation.

    Returns
    -------
    dict
        ``inputs``: per input ``excited`` (bool), ``range_within_experiments`` (largest
        range within an experiment) and ``magnitude``; ``not_excited`` (names);
        ``unidentifiable`` (state -> list of term groups that are zero or collinear once
        centred per experiment); ``sentences`` (plain words, one per finding).
    """
    inputs: dict[str, Any] = {}
    not_excited: list[str] = []
    for j, name in enumerate(spec.inputs):
        col = data.u[:, j]
        mag = float(np.max(np.abs(col))) if col.size else 0.0
        rng = max((float(np.ptp(col[data.segment(s)])) for s in range(data.n_segments)
                   if data.segment(s).stop > data.segment(s).start), default=0.0)
        excited = rng > CONSTANT_RTOL * max(mag, np.finfo(float).tiny)
        inputs[name] = {"excited": bool(excited), "range_within_experiments": rng,
                        "magnitude": mag}
        if not excited:
            not_excited.append(name)
    # the centred Gram matrix from per-experiment sums (no centred copy of Φ unless some
    # equation fails the full-rank screen)
    pr = phi[rows]
    counts = np.array([int(rows[data.segment(s)].sum()) for s in range(data.n_segments)])
    keep_seg = counts > 0
    starts_r = np.concatenate([[0], np.cumsum(counts)])[:-1][keep_seg]
    sums = np.add.reduceat(pr, starts_r, axis=0) if pr.shape[0] else np.zeros((0, pr.shape[1]))
    gram = pr.T @ pr
    raw_sq = np.diag(gram).copy()
    gram -= sums.T @ (sums / counts[keep_seg][:, None])
    # a constant column leaves rounding noise after centring: zero it relative to its size
    lost = np.diag(gram) <= (1e-9) ** 2 * raw_sq
    gram[lost, :] = 0.0
    gram[:, lost] = 0.0
    unident: dict[str, list[list[str]]] = {}
    pos = 0
    centred = None
    for st in spec.states:
        terms = [str(t) for t in spec.equations[st]]
        sl = slice(pos, pos + len(terms))
        pos += len(terms)
        g = gram[sl, sl]
        norms = np.sqrt(np.maximum(np.diag(g), 0.0))
        keep = norms > 0
        if keep.all():
            eig = np.linalg.eigvalsh(g / np.outer(norms, norms))
            if eig[0] > 1e-10 * eig[-1]:  # surely full rank (collinear_terms' own screen)
                continue
        if centred is None:
            centred = phi.copy()
            for s in range(data.n_segments):
                seg = data.segment(s)
                sub = rows[seg]
                if sub.any():
                    blk = centred[seg]
                    blk[sub] -= blk[sub].mean(axis=0)
            centred = centred[rows]
            centred[:, lost] = 0.0
        groups = collinear_terms(centred[:, sl], terms)
        if groups:
            unident[st] = groups
    sentences = []
    for name in not_excited:
        info = inputs[name]
        sentences.append(
            f"input {name!r} is not excited: constant within every experiment "
            f"(largest range {info['range_within_experiments']:.3g} at magnitude "
            f"{info['magnitude']:.4g})")
    for st, groups in unident.items():
        for g in groups:
            sentences.append(
                f"equation {st!r}: {', '.join(g)} "
                + ("is" if len(g) == 1 else "are")
                + " not identifiable with a constant per experiment (constant, or collinear "
                "once each experiment's mean is removed): estimators with zero-mean "
                "instruments cannot estimate "
                + ("it" if len(g) == 1 else "them")
                + "; least squares returns only the equation's constant at that input")
    return {"inputs": inputs, "not_excited": not_excited, "unidentifiable": unident,
            "sentences": sentences}
