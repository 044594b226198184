"""Standard manoeuvres as open-loop input designs for the force inputs ``X, Y, N``.

The full-scale trial programme of ITTC Recommended Procedure 7.5-04-02-01 (*Full Scale
Manoeuvring Trials*, rev. 02, 2017: §2.2.1 turning circle, §2.2.2 zig-zag, §2.2.5 spiral,
§2.2.6 pull-out, §2.2.7 stopping) and the IMO *Standards for Ship Manoeuvrability*
(resolution MSC.137(76), 2002: turning circle to both sides at the test speed, 10°/10°
and 20°/20° zig-zag, full-astern stopping) translated to a vessel whose inputs are the
generalised forces ``τ = [X, Y, N]`` of the identification model:

* the **engine setting** is a surge force ``X`` (the approach speed is its steady speed);
* the **rudder** at angle ``δ`` gives ``(Y, N) = (δ/δ_max) · (Y_δ, N_δ)``: a rudder aft
  of midships at ``x_r < 0`` produces a sway force and the yaw moment ``N = x_r Y``
  (default :data:`RUDDER`, full deflection ``δ_max = 35°``);
* a **thruster test** (§2.2.13/2.2.14) applies sway force with little moment.

Zig-zag, pull-out and spiral switch the rudder on heading or yaw rate. Here the
switching instants are found **noise-free on the plant** (:meth:`VesselModel.run
<vesselid.plant.vessels.kernel.VesselModel.run>`: the θ0 of the plant's own regression
model in calm water) and the resulting force schedule is then applied *open loop* at
sea: the inputs stay independent of the noise, as the paper's assumption A4 needs for
the instrumental-variable estimators. Every manoeuvre of an experiment is simulated from
the state the previous one left, so a :class:`Programme` (sequence of manoeuvres) is one
continuous run.

>>> from vesselid.plant.vessels import VesselModel, cybership2   # doctest: +SKIP
>>> from vesselid.studies.manoeuvres import Programme, ZigZag
>>> plant = VesselModel(cybership2.HULL, dt=0.1)
>>> forces = Programme([ZigZag(thrust=1.5, rudder=10, heading=10)]).schedule(plant, 20000)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar

import numpy as np

from vesselid.errors import VesselidError
from vesselid.plant.plant import heading
from vesselid.plant.vessels.cybership2 import FORCE_MAX
from vesselid.plant.vessels.kernel import VesselModel

__all__ = [
    "FORCE_LIMITS",
    "MANOEUVRES",
    "RUDDER",
    "AccelerationStopping",
    "Crabbing",
    "Manoeuvre",
    "ManoeuvreError",
    "Programme",
    "PullOut",
    "Spiral",
    "ThrusterSquare",
    "TurningCircle",
    "ZigZag",
    "manoeuvre_from_dict",
    "steer",
]

#: Actuator limits ``(X, Y, N)`` (N, N, N m) of CyberShip II: its hull's ``force_max`` (the
#: environment's limits too); defined once, in :mod:`vesselid.plant.vessels.cybership2`.
FORCE_LIMITS: tuple[float, float, float] = tuple(FORCE_MAX)
#: Full-deflection rudder forces ``(Y_δ, N_δ)`` at ``δ_max = 35°`` for a starboard rudder:
#: a lateral force to port at ``x_r = −0.5 L ≈ −0.63 m`` gives ``N = x_r Y``.
RUDDER = (-1.2, 0.75)
RUDDER_MAX_DEG = 35.0


class ManoeuvreError(VesselidError):
    """Bad manoeuvre parameters (unknown name, out of the actuator limits, ...)."""


def steer(delta_deg: float, rudder: tuple[float, float] = RUDDER) -> tuple[float, float]:
    """``(Y, N)`` of rudder angle ``δ`` (degrees, + starboard) for full-rudder forces
    ``rudder = (Y_δ, N_δ)``."""
    f = float(delta_deg) / RUDDER_MAX_DEG
    return f * rudder[0], f * rudder[1]


@dataclass
class _Track:
    """Forces, states and heading accumulated while a programme is scheduled on the
    noise-free plant (:meth:`VesselModel.run`)."""

    plant: VesselModel
    limits: tuple[float, float, float]
    rudder: tuple[float, float]
    x: np.ndarray
    psi: float = 0.0
    forces: list[np.ndarray] = field(default_factory=list)
    n: int = 0

    def hold(self, tau: Sequence[float], n: int,
             until: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
             chunk: int = 600) -> bool:
        """Apply constant ``tau`` for at most ``n`` samples, stopping after the first
        sample where ``until(states, psi)`` holds. Returns whether it stopped early."""
        tau = np.asarray(tau, dtype=float)
        lim = np.asarray(self.limits)
        if np.any(np.abs(tau) > lim + 1e-12):
            raise ManoeuvreError(f"forces {tau.round(3).tolist()} exceed the actuator limits "
                                 f"{list(self.limits)}")
        left = int(n)
        while left > 0:
            m = min(chunk, left)
            xs = self.plant.run(np.tile(tau, (m, 1)), self.x)
            psi = self.psi + heading(xs, self.dt)
            stop = m
            if until is not None:
                hit = np.flatnonzero(until(xs[1:], psi[1:]))
                if hit.size:
                    stop = int(hit[0]) + 1
            self.forces.append(np.tile(tau, (stop, 1)))
            self.x = xs[stop]
            self.psi = float(psi[stop])
            self.n += stop
            left -= stop
            if stop < m:
                return True
        return False

    def hold_for(self, tau: Sequence[float], seconds: float, n_max: int,
                 until: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> bool:
        """:meth:`hold` for ``seconds``, never past sample ``n_max``."""
        return self.hold(tau, min(n_max - self.n, round(seconds / self.dt)), until)

    @property
    def dt(self) -> float:
        return self.plant.dt

    def steer(self, delta_deg: float) -> tuple[float, float]:
        """``(Y, N)`` of rudder angle ``δ`` (degrees, + starboard)."""
        return steer(delta_deg, self.rudder)

    def alternating(self, count: int, n_max: int, start: int = 1) -> Iterator[int]:
        """Signs ``start, −start, ...`` for ``count`` repetitions while samples remain."""
        s = start
        for _ in range(int(count)):
            if self.n >= n_max:
                return
            yield s
            s = -s

    def schedule(self) -> np.ndarray:
        return np.vstack(self.forces) if self.forces else np.empty((0, 3))


# ---------------------------------------------------------------------------- manoeuvres
@dataclass(frozen=True)
class Manoeuvre:
    """One standard manoeuvre; :meth:`apply` appends its forces to a track."""

    kind: ClassVar[str] = ""
    thrust: float = 1.5

    def __post_init__(self) -> None:
        for f in self.__dataclass_fields__:
            v = getattr(self, f)
            if isinstance(v, (int, float)) and not math.isfinite(float(v)):
                raise ManoeuvreError(f"{self.kind}: {f} must be finite, got {v!r}")

    def apply(self, track: _Track, n_max: int) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def label(self) -> str:
        return self.kind

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, **asdict(self)}


def _side(side: int) -> int:
    if side not in (-1, 1):
        raise ManoeuvreError(f"side must be +1 (starboard) or -1 (port), got {side!r}")
    return int(side)


@dataclass(frozen=True)
class TurningCircle(Manoeuvre):
    """Turning circle (ITTC §2.2.1, IMO MSC.137(76) 4.2.2): straight approach, then the
    rudder at ``rudder`` degrees to ``side`` held for ``turn`` degrees of heading change,
    then the rudder to the other side until the turn reverses (the next circle)."""

    kind: ClassVar[str] = "turning_circle"
    rudder: float = 35.0
    side: int = 1
    turn: float = 540.0

    def apply(self, track: _Track, n_max: int) -> None:
        s = _side(self.side)
        y, n = track.steer(s * self.rudder)
        start = track.psi
        goal = math.radians(self.turn)
        track.hold([self.thrust, y, n], n_max - track.n,
                   until=lambda x, psi: s * (psi - start) >= goal)
        # counter rudder until the yaw rate has reversed (ready for the next manoeuvre)
        y, n = track.steer(-s * self.rudder)
        track.hold([self.thrust, y, n], n_max - track.n, until=lambda x, psi: s * x[:, 2] <= 0)

    def label(self) -> str:
        side = "stbd" if self.side > 0 else "port"
        return f"turning circle {self.rudder:g}° {side}, X={self.thrust:g}"


@dataclass(frozen=True)
class ZigZag(Manoeuvre):
    """Zig-zag ``δ/ψ`` (ITTC §2.2.2, IMO 10°/10° and 20°/20°): rudder ``δ`` to ``side``,
    reversed whenever the heading deviates ``ψ`` from the initial course; at most
    ``cycles`` full periods (two rudder reversals each; default: until the block ends)."""

    kind: ClassVar[str] = "zigzag"
    rudder: float = 10.0
    heading: float = 10.0
    side: int = 1
    cycles: int = 1000
    timeout: float = 120.0

    def apply(self, track: _Track, n_max: int) -> None:
        s = _side(self.side)
        base = track.psi
        lim = math.radians(self.heading)
        timeout = round(self.timeout / track.dt)
        for sg in track.alternating(2 * int(self.cycles), n_max, s):
            y, n = track.steer(sg * self.rudder)
            left = n_max - track.n
            hit = track.hold([self.thrust, y, n], min(left, timeout),
                             until=lambda x, psi, sg=sg: sg * (psi - base) >= lim)
            if not hit and left >= timeout:
                raise ManoeuvreError(
                    f"zig-zag {self.rudder:g}/{self.heading:g} at X={self.thrust:g}: the heading "
                    f"does not reach the next execute within {self.timeout:g} s — the vessel "
                    "does not answer this rudder (directionally unstable: the rudder lies "
                    "inside the spiral loop); use a larger rudder angle")

    def label(self) -> str:
        return f"zig-zag {self.rudder:g}/{self.heading:g}, X={self.thrust:g}"


@dataclass(frozen=True)
class PullOut(Manoeuvre):
    """Pull-out (ITTC §2.2.6): rudder ``rudder`` to ``side`` until the yaw rate is steady,
    then rudder amidships for ``hold`` seconds (a stable ship's yaw rate decays to zero;
    an unstable one's settles at a residual rate); ``repeats`` times, alternating sides."""

    kind: ClassVar[str] = "pull_out"
    rudder: float = 20.0
    side: int = 1
    hold: float = 60.0
    repeats: int = 4

    def apply(self, track: _Track, n_max: int) -> None:
        s = _side(self.side)
        dt = track.dt
        lag = max(1, round(5.0 / dt))
        for sg in track.alternating(self.repeats, n_max, s):
            y, n = track.steer(sg * self.rudder)
            hist: list[float] = []

            def steady(x: np.ndarray, psi: np.ndarray, hist: list[float] = hist) -> np.ndarray:
                r = np.concatenate([hist, x[:, 2]])
                ok = np.zeros(x.shape[0], dtype=bool)
                k0 = len(hist)
                if r.size > lag:
                    d = np.abs(r[lag:] - r[:-lag]) < 1e-4
                    ok[max(0, lag - k0):] = d[max(0, k0 - lag):]
                hist[:] = list(r[-lag:])
                return ok

            track.hold_for([self.thrust, y, n], 300.0, n_max, until=steady)
            track.hold_for([self.thrust, 0.0, 0.0], self.hold, n_max)

    def label(self) -> str:
        return f"pull-out {self.rudder:g}°, X={self.thrust:g}"


@dataclass(frozen=True)
class Spiral(Manoeuvre):
    """Direct (Dieudonné) spiral (ITTC §2.2.5): the rudder stepped from ``+rudder`` to
    ``−rudder`` and back in ``steps`` steps, each held ``hold`` seconds (long enough for a
    steady yaw rate); an unstable ship shows the hysteresis loop."""

    kind: ClassVar[str] = "spiral"
    rudder: float = 25.0
    steps: int = 11
    hold: float = 60.0

    def apply(self, track: _Track, n_max: int) -> None:
        down = np.linspace(self.rudder, -self.rudder, int(self.steps))
        for d in np.concatenate([down, down[::-1][1:]]):
            if track.n >= n_max:
                return
            y, n = track.steer(float(d))
            track.hold_for([self.thrust, y, n], self.hold, n_max)

    def label(self) -> str:
        return f"spiral ±{self.rudder:g}°, X={self.thrust:g}"


@dataclass(frozen=True)
class AccelerationStopping(Manoeuvre):
    """Acceleration and stopping (ITTC §2.2.7, IMO full-astern stopping): from the
    current state full ahead (``thrust``) for ``ahead`` seconds, then full astern
    (``−astern``) until the ship stops (``u ≤ 0``), astern ``hold`` seconds more, then
    engine stop (coasting, the stopping inertia test §2.2.8) for ``coast`` seconds;
    with ``floor > 0`` the stop ends at ``u = floor`` and the coast ends at ``u = floor/2``
    (speed changes between two positive speeds: ``u`` never reaches zero, as the
    identification's assumptions A10/A15 need);
    ``rudder`` (degrees, + starboard) is held throughout, ``repeats`` times with
    alternating rudder."""

    kind: ClassVar[str] = "acceleration_stopping"
    astern: float = 2.0
    ahead: float = 60.0
    hold: float = 20.0
    coast: float = 30.0
    rudder: float = 10.0
    repeats: int = 4
    floor: float = 0.0

    def apply(self, track: _Track, n_max: int) -> None:
        floor = float(self.floor)
        if floor < 0:
            raise ManoeuvreError(f"acceleration/stopping: floor must be >= 0, got {floor:g}")
        for s in track.alternating(self.repeats, n_max):
            y, n = track.steer(s * self.rudder)
            track.hold_for([self.thrust, y, n], self.ahead, n_max)
            track.hold_for([-self.astern, y, n], 300.0, n_max,
                           until=lambda x, psi: x[:, 0] <= floor)
            if floor > 0:
                # crash stop to a positive speed: coast without reversing u (the paper's
                # A10/A15 need u away from zero), never below half the floor speed
                track.hold_for([0.0, y, n], self.coast, n_max,
                               until=lambda x, psi: x[:, 0] <= 0.5 * floor)
                continue
            track.hold_for([-self.astern, y, n], self.hold, n_max)
            track.hold_for([0.0, y, n], self.coast, n_max)

    def label(self) -> str:
        if self.floor > 0:
            return f"acceleration/stopping ±{self.thrust:g}/{self.astern:g} to u={self.floor:g}"
        return f"acceleration/stopping ±{self.thrust:g}/{self.astern:g}"

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        if not self.floor:
            d.pop("floor")  # the crash stop through u = 0 keeps its old record
        return d


@dataclass(frozen=True)
class Crabbing(Manoeuvre):
    """Thruster / crabbing test (ITTC §2.2.13–2.2.14): sway force ``±sway`` with the yaw
    moment ``moment`` per unit sway force, alternated every ``hold`` seconds."""

    kind: ClassVar[str] = "crabbing"
    sway: float = 1.5
    moment: float = 0.0
    hold: float = 40.0
    repeats: int = 6

    def apply(self, track: _Track, n_max: int) -> None:
        for s in track.alternating(self.repeats, n_max):
            track.hold_for([self.thrust, s * self.sway, s * self.sway * self.moment],
                           self.hold, n_max)

    def label(self) -> str:
        return f"crabbing Y=±{self.sway:g} (N/Y={self.moment:g}), X={self.thrust:g}"


@dataclass(frozen=True)
class ThrusterSquare(Manoeuvre):
    """Thruster test with independent sway force and yaw moment (ITTC §2.2.13–2.2.14
    with both thrusters; a multistep input in the sense of system-identification flight
    tests): ``Y = ±sway`` reversed every ``hold_y`` seconds and ``N = ±moment`` every
    ``hold_n`` seconds; with ``low < 1`` the engine setting alternates between
    ``thrust`` and ``low · thrust`` every ``hold_x`` seconds (surge excited too; with
    ``low < 0`` ahead and astern, so ``u`` sweeps through zero and both signs — the
    range that separates the constant sway/yaw couplings from the ``u``-proportional
    ones, e.g. ``r: v`` from ``r: u·v``).
    Incommensurate periods visit all four sign combinations of ``(Y, N)``, so ``v``
    and ``r`` take both equal and opposite signs in the transients (rudder manoeuvres
    give ``v·r < 0`` in every steady turn), which separates ``v·|r|``, ``r·|v|`` and ``r·|r|``."""

    kind: ClassVar[str] = "thruster_square"
    sway: float = 1.5
    moment: float = 1.0
    hold_y: float = 10.0
    hold_n: float = 7.0
    hold_x: float = 30.0
    low: float = 1.0

    def apply(self, track: _Track, n_max: int) -> None:
        dt = track.dt
        ky = max(1, round(self.hold_y / dt))
        kn = max(1, round(self.hold_n / dt))
        kx = max(1, round(self.hold_x / dt))
        k = 0
        while track.n < n_max:
            sy = 1.0 if (k // ky) % 2 == 0 else -1.0
            sn = 1.0 if (k // kn) % 2 == 0 else -1.0
            x = self.thrust if (k // kx) % 2 == 0 else self.low * self.thrust
            step = min(ky - k % ky, kn - k % kn, kx - k % kx, n_max - track.n)
            track.hold([x, sy * self.sway, sn * self.moment], step)
            k += step

    def label(self) -> str:
        x = f"X={self.thrust:g}"
        if self.low != 1.0:
            x += f"/{self.low * self.thrust:g} every {self.hold_x:g} s"
        return (f"thruster square Y=±{self.sway:g}/{self.hold_y:g} s, "
                f"N=±{self.moment:g}/{self.hold_n:g} s, {x}")


#: Manoeuvre classes by name (``kind``).
MANOEUVRES: dict[str, type[Manoeuvre]] = {
    c.kind: c for c in (TurningCircle, ZigZag, PullOut, Spiral, AccelerationStopping,
                        Crabbing, ThrusterSquare)
}


def manoeuvre_from_dict(data: dict[str, Any]) -> Manoeuvre:
    """Rebuild a manoeuvre from :meth:`Manoeuvre.to_dict`."""
    d = dict(data)
    kind = d.pop("kind", None)
    if kind not in MANOEUVRES:
        raise ManoeuvreError(f"unknown manoeuvre {kind!r}; choose from {sorted(MANOEUVRES)}")
    try:
        return MANOEUVRES[kind](**d)
    except TypeError as exc:
        raise ManoeuvreError(f"bad parameters for {kind}: {exc}") from exc


@dataclass(frozen=True)
class Programme:
    """A sequence of manoeuvres run back to back as one continuous experiment.

    Without ``durations`` the manoeuvres are cycled until the experiment is full; with
    ``durations`` (samples per manoeuvre) manoeuvre ``i`` is repeated for exactly
    ``durations[i]`` samples (the last one also fills any remainder).
    """

    manoeuvres: tuple[Manoeuvre, ...]
    durations: tuple[int, ...] | None = None

    def __init__(self, manoeuvres: Sequence[Manoeuvre],
                 durations: Sequence[int] | None = None) -> None:
        ms = tuple(manoeuvres)
        if not ms or not all(isinstance(m, Manoeuvre) for m in ms):
            raise ManoeuvreError("a programme needs at least one manoeuvre")
        if durations is not None:
            durations = tuple(int(d) for d in durations)
            if len(durations) != len(ms) or any(d < 1 for d in durations):
                raise ManoeuvreError("durations need one positive sample count per manoeuvre")
        object.__setattr__(self, "manoeuvres", ms)
        object.__setattr__(self, "durations", durations)

    def schedule(self, plant: VesselModel, n: int, *, warmup: int = 0,
                 x0: Sequence[float] | None = None,
                 limits: Sequence[float] | None = None,
                 rudder: tuple[float, float] = RUDDER) -> np.ndarray:
        """Open-loop forces ``(warmup + n, 3)``: ``warmup`` samples of straight approach,
        then the manoeuvres, switching instants found on the noise-free ``plant``
        (:meth:`~vesselid.plant.vessels.kernel.VesselModel.run`, e.g.
        ``VesselModel(cybership2.HULL, dt)``).

        ``limits`` are the actuator limits ``|X|, |Y|, |N|`` (default the hull's
        ``force_max``); ``rudder`` the full-rudder forces ``(Y_δ, N_δ)``."""
        if int(n) < 1:
            raise ManoeuvreError(f"need at least one sample, got {n}")
        n_tot = int(warmup) + int(n)
        x_start = np.zeros(3) if x0 is None else np.asarray(x0, dtype=float)
        lim = plant.force_max if limits is None else limits
        track = _Track(plant, tuple(float(x) for x in lim),
                       (float(rudder[0]), float(rudder[1])), x_start)
        if warmup:
            track.hold([self.manoeuvres[0].thrust, 0.0, 0.0], int(warmup))
        if self.durations is None:
            segments = [(None, n_tot)]
        else:
            ends = int(warmup) + np.cumsum(self.durations)
            ends[-1] = max(ends[-1], n_tot)
            segments = [(m, min(int(e), n_tot)) for m, e in zip(self.manoeuvres, ends,
                                                                strict=True)]
        for only, end in segments:
            stalled = 0
            while track.n < end:
                before = track.n
                for m in (self.manoeuvres if only is None else (only,)):
                    if track.n >= end:
                        break
                    m.apply(track, end)
                stalled = stalled + 1 if track.n == before else 0
                if stalled > 1:  # pragma: no cover - every manoeuvre advances time
                    raise ManoeuvreError("the programme does not advance")
        return track.schedule()[:n_tot]

    def label(self) -> str:
        if self.durations is None:
            return " + ".join(m.label() for m in self.manoeuvres)
        return " + ".join(f"{m.label()} ({d} samples)"
                          for m, d in zip(self.manoeuvres, self.durations, strict=True))

    def to_dict(self) -> dict[str, Any]:
        return {"manoeuvres": [m.to_dict() for m in self.manoeuvres],
                "durations": None if self.durations is None else list(self.durations)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Programme:
        return cls([manoeuvre_from_dict(d) for d in data["manoeuvres"]], data.get("durations"))
