"""Naval-architecture figures of standard manoeuvres, from a measured or simulated run.

The definitions follow ITTC Recommended Procedure 7.5-04-02-01 (*Full Scale Manoeuvring
Trials*, §2.2.1 turning circle, §2.2.2 zig-zag) and the IMO *Standards for Ship
Manoeuvrability* (MSC.137(76)):

* **zig-zag** ``δ₀/ψ_s``: the rudder is put to ``δ₀`` and reversed whenever the heading
  change from the heading at the first execute reaches ``±ψ_s``. The *first overshoot
  angle* is how far the heading change goes beyond ``ψ_s`` after the first reversal, the
  *second* beyond ``−ψ_s`` after the second reversal;
* **turning circle**: the rudder is put to ``δ₀`` and held. With positions in the frame of
  the approach heading (``x`` along it, ``y`` across), the *advance* is ``x`` where the
  heading has changed by 90°, the *transfer* ``|y|`` there, the *tactical diameter*
  ``|y|`` where it has changed by 180°, the *steady turn rate* the median ``|r|`` once the
  heading has changed by more than 270° (when it does).

:func:`detect` classifies a run from its rudder signal alone: a rudder that reverses
between plateaus of one amplitude at least twice is a zig-zag; a rudder put over once and
held while the heading turns by at least 90° is a turning circle; either holds the rudder
at ``±δ₀`` for at least 60 % of the samples after the execute. Angles are in radians
in and degrees out (the figures are reported as naval architects quote them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ManoeuvreInfo", "detect", "integrate_track", "turning_figures", "zigzag_figures"]

#: Rudder amplitude below which a run is not a manoeuvre (rad, 1°).
MIN_RUDDER = math.radians(1.0)


@dataclass(frozen=True)
class ManoeuvreInfo:
    """A detected standard manoeuvre.

    Parameters
    ----------
    kind : {"zigzag", "turning_circle"}
    execute : int
        Sample of the first rudder execute.
    delta0 : float
        Rudder amplitude (rad).
    first_sign : float
        Sign of the first rudder deflection.
    rate : float
        Rudder rate (rad/s) while the rudder moves.
    reversals : tuple of int
        First samples off a rudder plateau when it reverses (zig-zag).
    psi_switch : float
        Heading change at the reversals (rad; zig-zag), the mean of the first two.
    gain_sign : float
        +1 if a positive rudder turns the heading positive.
    """

    kind: str
    execute: int
    delta0: float
    first_sign: float
    rate: float
    reversals: tuple[int, ...] = ()
    psi_switch: float = float("nan")
    gain_sign: float = 1.0

    def label(self) -> str:
        if self.kind == "zigzag":
            return (f"zig-zag {math.degrees(self.delta0):.0f}°/"
                    f"{math.degrees(self.psi_switch):.1f}°")
        return f"turning circle δ = {math.degrees(self.first_sign * self.delta0):.0f}°"


def _plateaus(delta: np.ndarray) -> tuple[np.ndarray, float]:
    """Sign (+1, -1, 0) of every sample relative to half the largest deflection."""
    dmax = float(np.max(np.abs(delta))) if delta.size else 0.0
    sign = np.zeros(delta.size, dtype=int)
    sign[delta > 0.5 * dmax] = 1
    sign[delta < -0.5 * dmax] = -1
    return sign, dmax


def _reversals(delta: np.ndarray, sign: np.ndarray) -> tuple[list[int], list[int]]:
    """Samples where the rudder leaves a plateau toward the other sign, and the segment
    signs in order."""
    idx = np.flatnonzero(sign != 0)
    if idx.size == 0:
        return [], []
    segs = [int(sign[idx[0]])]
    revs: list[int] = []
    start = int(idx[0])
    for k in idx[1:]:
        s = int(sign[k])
        if s != segs[-1]:
            # the reversal: the first sample off the previous plateau (the rudder order was
            # given when the heading reached the switching angle, at or just before it)
            seg_vals = delta[start: k]
            ext = seg_vals.max() if segs[-1] > 0 else seg_vals.min()
            near = np.flatnonzero(np.abs(seg_vals - ext) <= 0.02 * abs(ext))
            revs.append(int(start + near[-1] + 1))
            segs.append(s)
            start = int(k)
    return revs, segs


def detect(delta: np.ndarray, psi: np.ndarray, dt: float, *,
           psi_switch: float | None = None) -> ManoeuvreInfo | None:
    """Classify a run as a zig-zag or a turning circle from its rudder signal.

    Parameters
    ----------
    delta : ndarray
        Rudder angle (rad).
    psi : ndarray
        Heading (rad, unwrapped), used for the switching angle and the turn.
    dt : float
        Sample time (s).
    psi_switch : float, optional
        The nominal switching angle of a zig-zag (rad; e.g. 10° of a 10°/10° test);
        default the mean heading change at the first two reversals.

    Returns
    -------
    ManoeuvreInfo or None
        None when the run is neither (rudder below 1°, or no reversal and a heading change
        under 90°).
    """
    delta = np.asarray(delta, dtype=float)
    psi = np.asarray(psi, dtype=float)
    sign, dmax = _plateaus(delta)
    if dmax < MIN_RUDDER:
        return None
    moving = np.flatnonzero(np.abs(delta) > 0.05 * dmax)
    execute = int(moving[0]) if moving.size else 0
    if execute > 0 and abs(delta[execute - 1]) < abs(delta[execute]):
        execute -= 1  # the last sample before the rudder leaves midships
    plateau = np.abs(delta) > 0.9 * dmax
    delta0 = float(np.median(np.abs(delta[plateau])))
    d = np.abs(np.diff(delta)) / dt
    mid = (np.abs(delta[1:]) > 0.1 * delta0) & (np.abs(delta[1:]) < 0.9 * delta0)
    rate = float(np.median(d[mid])) if np.any(mid) else float(np.max(d, initial=0.0))
    revs, segs = _reversals(delta, sign)
    first = float(segs[0]) if segs else 1.0
    h = psi - psi[execute]
    # a standard manoeuvre holds the rudder at ±δ₀ most of the time after the execute (an
    # autopilot's or a random rudder does not)
    held = float(np.mean(np.abs(delta[execute:]) >= 0.9 * delta0))
    if held < 0.6:
        return None
    if len(revs) >= 2:
        sw = [abs(h[k]) for k in revs[:2]]
        gain = float(np.sign(h[revs[0]]) * first) or 1.0
        return ManoeuvreInfo("zigzag", execute, delta0, first, rate, tuple(revs),
                             float(np.mean(sw)) if psi_switch is None else float(psi_switch),
                             gain)
    if not revs and np.max(np.abs(h[execute:])) >= math.pi / 2:
        gain = float(np.sign(h[-1]) * first) or 1.0
        return ManoeuvreInfo("turning_circle", execute, delta0, first, rate, (), float("nan"),
                             gain)
    return None


def zigzag_figures(psi: np.ndarray, delta: np.ndarray, info: ManoeuvreInfo,
                   dt: float) -> dict[str, Any]:
    """Overshoot angles of a zig-zag run (measured or simulated).

    The reversals are found in this run's own rudder signal (a simulated zig-zag reverses
    where its simulated heading reaches ``ψ_s``); the overshoots are measured from the
    switching angle ``info.psi_switch`` of the detected manoeuvre.

    Returns
    -------
    dict
        ``first_overshoot_deg``, ``second_overshoot_deg`` (None where the run ends
        first), ``first_overshoot_time_s`` (from the execute), ``reversals``.
    """
    psi = np.asarray(psi, dtype=float)
    sign, _ = _plateaus(np.asarray(delta, dtype=float))
    revs, _ = _reversals(np.asarray(delta, dtype=float), sign)
    h = (psi - psi[info.execute]) * info.gain_sign * info.first_sign
    out: dict[str, Any] = {"reversals": [int(k) for k in revs], "first_overshoot_deg": None,
                           "second_overshoot_deg": None, "first_overshoot_time_s": None}
    bounds = [*revs, psi.size]
    if len(revs) >= 1:
        seg = h[revs[0]: bounds[1] + 1]
        k = int(np.argmax(seg))
        if revs[0] + k < psi.size - 1:  # a peak, not the end of the record
            out["first_overshoot_deg"] = math.degrees(float(seg[k]) - info.psi_switch)
            out["first_overshoot_time_s"] = (revs[0] + k - info.execute) * dt
    if len(revs) >= 2:
        seg = -h[revs[1]: bounds[2] + 1]
        k = int(np.argmax(seg))
        if revs[1] + k < psi.size - 1:
            out["second_overshoot_deg"] = math.degrees(float(seg[k]) - info.psi_switch)
    return out


def integrate_track(u: np.ndarray, v: np.ndarray, r: np.ndarray, dt: float, psi0: float = 0.0,
                    north0: float = 0.0, east0: float = 0.0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heading and position from body velocities (trapezoidal rule).

    ``ψ̇ = r``, ``ṅ = u cos ψ − v sin ψ``, ``ė = u sin ψ + v cos ψ``.

    Returns
    -------
    psi, north, east : ndarray
    """
    r = np.asarray(r, dtype=float)
    psi = psi0 + np.concatenate([[0.0], np.cumsum(0.5 * dt * (r[1:] + r[:-1]))])
    vn = u * np.cos(psi) - v * np.sin(psi)
    ve = u * np.sin(psi) + v * np.cos(psi)
    north = north0 + np.concatenate([[0.0], np.cumsum(0.5 * dt * (vn[1:] + vn[:-1]))])
    east = east0 + np.concatenate([[0.0], np.cumsum(0.5 * dt * (ve[1:] + ve[:-1]))])
    return psi, north, east


def _crossing(h: np.ndarray, level: float) -> float | None:
    """Fractional sample where ``h`` first reaches ``level`` (linear interpolation)."""
    k = np.flatnonzero(h >= level)
    if k.size == 0:
        return None
    k0 = int(k[0])
    if k0 == 0:
        return 0.0
    a, b = h[k0 - 1], h[k0]
    return k0 - 1 + (level - a) / (b - a) if b != a else float(k0)


def turning_figures(psi: np.ndarray, north: np.ndarray, east: np.ndarray, r: np.ndarray,
                    info: ManoeuvreInfo) -> dict[str, Any]:
    """Advance, transfer, tactical diameter and steady turn rate of a turning circle.

    Returns
    -------
    dict
        ``advance_m``, ``transfer_m``, ``tactical_diameter_m`` (None where the heading never
        changes by 90° / 180°), ``steady_turn_rate_deg_s`` (None when it never passes
        270°), ``heading_change_deg``.
    """
    k0 = info.execute
    psi = np.asarray(psi, dtype=float)
    h = np.abs(psi[k0:] - psi[k0])
    c, s = math.cos(psi[k0]), math.sin(psi[k0])
    dn, de = north[k0:] - north[k0], east[k0:] - east[k0]
    along = c * dn + s * de
    across = -s * dn + c * de

    def at(level: float, x: np.ndarray) -> float | None:
        k = _crossing(h, level)
        if k is None:
            return None
        return float(np.interp(k, np.arange(x.size), x))

    adv = at(math.pi / 2, along)
    tr = at(math.pi / 2, across)
    td = at(math.pi, across)
    steady = h >= 1.5 * math.pi
    rate = (math.degrees(float(np.median(np.abs(np.asarray(r)[k0:][steady]))))
            if np.any(steady) else None)
    return {"advance_m": adv, "transfer_m": None if tr is None else abs(tr),
            "tactical_diameter_m": None if td is None else abs(td),
            "steady_turn_rate_deg_s": rate, "heading_change_deg": math.degrees(float(h.max()))}
