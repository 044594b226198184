"""What the sea does to a vessel, and what its sensors read: the vessel disturbance model.

:class:`VesselDisturbances` — earth-fixed ocean current (mean plus bounded Gauss–Markov
variations of speed and direction, rotated into the body frame by the kernel, the
paper's non-additive ``v = −ν_c``), Blendermann wind with gusts, unmodelled Gauss–Markov
forces — and :class:`VesselSensors` (GNSS, Doppler speed log, current meter, anemometer,
gyro, heading) are the components every hull shares. More components plug in through
:class:`DisturbanceComponent` (``VesselDisturbances(components=(...))``): a component
draws its own signals after the built-in ones, from the same per-run generator, and adds
body-frame forces (to the additive ``w``) and/or coloured disturbances on sensor channels
(e.g. wave-frequency motion on the measured heading and velocities).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np

from vesselid.errors import VesselidError
from vesselid.plant.disturbances import GaussMarkov, Process, process_from_dict
from vesselid.plant.vessels.wind import BlendermannWind

__all__ = [
    "SENSOR_CHANNELS",
    "SENSOR_GROUPS",
    "ComponentDraw",
    "DisturbanceComponent",
    "ProcessForce",
    "VesselDisturbances",
    "VesselSensors",
    "clipped_variance",
]


@dataclass
class ComponentDraw:
    """What a :class:`DisturbanceComponent` adds to one run of ``n`` samples.

    Attributes
    ----------
    force : ndarray (n, 3), optional
        Body-frame force ``[X, Y, N]`` (N, N, N m) added to the unmodelled forces (enters
        ``w`` through ``dt M⁻¹``).
    sensors : mapping channel -> ndarray (n,), optional
        Additive disturbance on sensor channels (:data:`SENSOR_CHANNELS`); angles are
        wrapped after the addition.
    """

    force: np.ndarray | None = None
    sensors: Mapping[str, np.ndarray] = field(default_factory=dict)


@runtime_checkable
class DisturbanceComponent(Protocol):
    """A pluggable disturbance (e.g. waves): draws one run's signals from ``rng``.

    ``draw`` is called once per run, after the built-in draws, with the run's generator,
    the number of samples and the sample time; ``to_dict`` describes the settings for
    log metadata.
    """

    name: str

    def draw(self, rng: np.random.Generator, n: int, dt: float) -> ComponentDraw: ...

    def to_dict(self) -> dict[str, Any]: ...


@dataclass(frozen=True)
class ProcessForce:
    """A :class:`~vesselid.plant.disturbances.Process` acting as a body-frame force: the
    :class:`DisturbanceComponent` ``τ(k) = p(k) · gain``.

    Any process kind works, including one added with
    :func:`~vesselid.plant.disturbances.register_process` (which also makes the component
    rebuildable from log metadata, :meth:`from_dict`). The force enters every user of the
    plant: :func:`~vesselid.plant.vessels.kernel.simulate_vessel` (sea trials) and
    :meth:`~vesselid.plant.vessels.kernel.VesselModel.disturbed_paths` (the trial planner).

    Parameters
    ----------
    process : Process
        The scalar disturbance ``p``.
    gain : (float, float, float)
        Force ``[X, Y, N]`` (N, N, N m) per unit of ``p``.
    name : str
        Name in the log metadata.
    """

    process: Process
    gain: tuple[float, float, float] = (1.0, 0.0, 0.0)
    name: str = "process_force"

    def __post_init__(self) -> None:
        if not isinstance(self.process, Process):
            raise VesselidError(f"ProcessForce needs a Process, got {type(self.process)}")
        gain = tuple(float(x) for x in np.ravel(self.gain))
        if len(gain) != 3 or not all(math.isfinite(x) for x in gain):
            raise VesselidError(f"ProcessForce gain needs three finite values, got {self.gain!r}")
        object.__setattr__(self, "gain", gain)

    def draw(self, rng: np.random.Generator, n: int, dt: float) -> ComponentDraw:
        return ComponentDraw(force=np.outer(self.process.sample(rng, n), self.gain))

    def to_dict(self) -> dict[str, Any]:
        return {"process": self.process.to_dict(), "gain": list(self.gain)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ProcessForce:
        """Rebuild from :meth:`to_dict` output (the ``name`` entry of the metadata too)."""
        return cls(process_from_dict(dict(data["process"])), tuple(data["gain"]),
                   str(data.get("name", "process_force")))


@dataclass(frozen=True)
class VesselDisturbances:
    """Current, wind and unmodelled-force settings (model scale, SI units).

    Directions are *going-to* angles in the earth frame, from north towards east (rad).
    Each variation is a first-order Gauss–Markov process (:class:`GaussMarkov`) with
    stationary std ``*_std``, time constant ``*_time_constant`` and, for the current,
    the bound ``current_bound`` (in units of its std), so that the current is bounded as
    the paper's A11 asks.

    Parameters
    ----------
    current_speed, current_direction : float
        Mean earth-frame current ``V_c`` (m/s) and direction ``β_c`` (rad).
    current_speed_std, current_direction_std : float
        Std of the GM variation of speed (m/s) and direction (rad).
    current_time_constant, current_bound : float
        Time constant (s) and bound (in stds) of both current variations.
    wind_speed, wind_direction : float
        Mean true wind speed (m/s, model scale: Froude-scaled ≈ full scale / 8.4) and
        going-to direction (rad).
    gust_std, gust_time_constant : float
        Coloured gusts: GM variation of the wind speed (bounded at 3 std, speed ≥ 0).
    wind_direction_std, wind_direction_time_constant : float
        GM variation of the wind direction (rad, s).
    force_noise_std : tuple of 3 floats
        Std of unmodelled GM forces ``[X, Y, N]`` (N, N, N m) added to ``w``.
    force_noise_time_constant : float
        Their time constant (s).
    cubic_surge : bool
        Add the published cubic surge damping ``X_uuu u_r³`` (not second-order modulus:
        the identification spec is then misspecified).
    wind_model : BlendermannWind, optional
        Wind-load coefficients and areas; default the hull's.
    wind_loads : bool, optional
        Compute wind loads from the apparent wind. Default: only with wind or gusts, so
        that without wind the plant is exactly the identification model (the air drag of
        the vessel's own motion, ~1 % of the thrust, is then neglected).
    components : tuple of DisturbanceComponent
        Further disturbances (e.g. waves), drawn after the built-in ones.
    """

    current_speed: float = 0.0
    current_direction: float = 0.0
    current_speed_std: float = 0.0
    current_direction_std: float = 0.0
    current_time_constant: float = 120.0
    current_bound: float = 3.0
    wind_speed: float = 0.0
    wind_direction: float = 0.0
    gust_std: float = 0.0
    gust_time_constant: float = 5.0
    wind_direction_std: float = 0.0
    wind_direction_time_constant: float = 30.0
    force_noise_std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    force_noise_time_constant: float = 2.0
    cubic_surge: bool = False
    wind_model: BlendermannWind | None = None
    wind_loads: bool | None = None
    components: tuple[DisturbanceComponent, ...] = ()

    @property
    def wind_on(self) -> bool:
        """Whether wind loads are computed (default: iff there is wind or gusts)."""
        if self.wind_loads is not None:
            return bool(self.wind_loads)
        return self.wind_speed > 0 or self.gust_std > 0

    def __post_init__(self) -> None:
        fn = tuple(float(x) for x in self.force_noise_std)
        if len(fn) != 3:
            raise VesselidError("force_noise_std needs three values (X, Y, N)")
        object.__setattr__(self, "force_noise_std", fn)
        for name in ("current_speed_std", "current_direction_std", "gust_std",
                     "wind_direction_std", "wind_speed"):
            if not getattr(self, name) >= 0:
                raise VesselidError(f"{name} must be non-negative")
        if any(x < 0 for x in fn):
            raise VesselidError("force_noise_std must be non-negative")

    def processes(self, dt: float) -> list[GaussMarkov]:
        """The seven zero-mean GM variations, in disturbance-channel order.

        ``[current speed, current direction, wind speed, wind direction, X, Y, N]``.
        """
        b = self.current_bound
        ct = self.current_time_constant
        fn = self.force_noise_std

        def gm(std: float, tc: float, bound: float) -> GaussMarkov:
            return GaussMarkov(0.0, std, tc, dt, bound * std if std > 0 else math.inf)

        return [
            gm(self.current_speed_std, ct, b),
            gm(self.current_direction_std, ct, b),
            gm(self.gust_std, self.gust_time_constant, 3.0),
            gm(self.wind_direction_std, self.wind_direction_time_constant, 3.0),
            gm(fn[0], self.force_noise_time_constant, 3.0),
            gm(fn[1], self.force_noise_time_constant, 3.0),
            gm(fn[2], self.force_noise_time_constant, 3.0),
        ]

    def to_dict(self) -> dict[str, Any]:
        d = asdict(replace(self, components=()))
        d.pop("components")
        d["force_noise_std"] = list(self.force_noise_std)
        d["wind_loads"] = self.wind_on
        if self.components:
            d["components"] = [{"name": c.name, **c.to_dict()} for c in self.components]
        return d


#: Sensor groups and the channels (columns) each produces, in kernel order.
SENSOR_GROUPS: dict[str, tuple[str, ...]] = {
    "gnss": ("u", "v"),
    "speed_log": ("u_log", "v_log"),
    "current_meter": ("u_c", "v_c"),
    "anemometer": ("wind_speed", "wind_angle"),
    "gyro": ("r",),
    "heading": ("psi",),
}
#: All sensor channels in kernel order.
SENSOR_CHANNELS: tuple[str, ...] = tuple(c for g in SENSOR_GROUPS.values() for c in g)
N_SENSOR_CHANNELS = len(SENSOR_CHANNELS)


def clipped_variance(clip: float) -> float:
    """Variance of a standard normal clipped at ``±clip`` (``1`` for an infinite clip):
    the factor by which :class:`VesselSensors`' clipping lowers a noise variance,
    ``(2Φ(c) − 1) − 2cφ(c) + 2c²(1 − Φ(c))``."""
    c = float(clip)
    if not math.isfinite(c):
        return 1.0
    p = math.erf(c / math.sqrt(2.0))
    pdf = math.exp(-0.5 * c * c) / math.sqrt(2.0 * math.pi)
    return float(p - 2 * c * pdf + c * c * math.erfc(c / math.sqrt(2.0)))


@dataclass(frozen=True)
class VesselSensors:
    """Sensor suite; each entry is the noise std, ``None`` switches the sensor off.

    * ``gnss`` (m/s): absolute body-frame velocity ``[u, v] + e`` (the paper's ``y₁``),
    * ``speed_log`` (m/s): Doppler log, velocity through water ``[u_r, v_r] + e`` — the
      aggregated state of Remark 4.3 (``r_r = r``: the current is irrotational),
    * ``current_meter`` (m/s): body-frame current ``[u_c, v_c] + e`` (the paper's ``y₂``),
    * ``anemometer`` (m/s, rad): apparent wind speed and angle ``γ_rw`` (0 = from ahead),
    * ``gyro`` (rad/s): yaw rate ``r + e``,
    * ``heading`` (rad): ``ψ + e`` wrapped to ``[−π, π)``.

    Noise is white Gaussian clipped at ``clip`` std, i.e. zero-mean and bounded (A2).
    """

    gnss: float | None = 0.005
    speed_log: float | None = 0.005
    current_meter: float | None = 0.005
    anemometer: tuple[float, float] | None = (0.05, 0.05)
    gyro: float | None = 0.002
    heading: float | None = 0.005
    clip: float = 3.0

    def __post_init__(self) -> None:
        if not self.clip > 0:
            raise VesselidError("sensor noise clip must be positive")
        for name in SENSOR_GROUPS:
            val = getattr(self, name)
            if val is None:
                continue
            vals = np.atleast_1d(np.asarray(val, dtype=float))
            if vals.size not in (1, len(SENSOR_GROUPS[name])) or np.any(~(vals >= 0)):
                raise VesselidError(f"sensor {name!r}: noise std must be >= 0, got {val!r}")

    @classmethod
    def noiseless(cls) -> VesselSensors:
        """All sensors on, without noise."""
        return cls(0.0, 0.0, 0.0, (0.0, 0.0), 0.0, 0.0)

    @property
    def enabled(self) -> tuple[str, ...]:
        """Enabled sensor groups in kernel order."""
        return tuple(g for g in SENSOR_GROUPS if getattr(self, g) is not None)

    @property
    def channels(self) -> tuple[str, ...]:
        """Channels of the enabled sensors in kernel order."""
        return tuple(c for g in self.enabled for c in SENSOR_GROUPS[g])

    def channel_index(self) -> np.ndarray:
        """Kernel indices of :attr:`channels`."""
        return np.array([SENSOR_CHANNELS.index(c) for c in self.channels], dtype=np.int64)

    def std_vector(self) -> np.ndarray:
        """Noise std per kernel channel (0 for disabled sensors)."""
        out = np.zeros(N_SENSOR_CHANNELS)
        i = 0
        for g, chans in SENSOR_GROUPS.items():
            val = getattr(self, g)
            if val is not None:
                out[i:i + len(chans)] = np.broadcast_to(np.asarray(val, dtype=float), len(chans))
            i += len(chans)
        return out

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if self.anemometer is not None:
            d["anemometer"] = list(self.anemometer)
        return d


def coerce(cls, value, name: str):
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        try:
            return cls(**value)
        except TypeError as exc:
            raise VesselidError(f"invalid {name} settings: {exc}") from exc
    raise VesselidError(f"{name} must be a {cls.__name__} or a mapping, got {type(value)}")

