"""ROS 1 and ROS 2 bags → channel streams (optional extra ``ros``: the ``rosbags`` package).

ROS 2 bags (a directory with ``metadata.yaml``, or a ``.db3``/``.mcap`` file) and ROS 1
bags (``.bag``) are read through :class:`rosbags.highlevel.AnyReader` (which uses
:class:`rosbags.rosbag1.Reader` / :class:`rosbags.rosbag2.Reader`); ROS 1 message
definitions come from the bag's connection records, and anything the bag does not define
from the ROS 1 Noetic typestore (:func:`rosbags.typesys.get_typestore`). ROS 1 type names
(``nav_msgs/Odometry``) are normalised to the ``pkg/msg/Type`` form used below.

Read message types (topics chosen by ``[ros]`` in the ingest configuration, else the first
topic of each type):

* ``nav_msgs/msg/Odometry``: position → ``north, east``, orientation → ``psi``, body twist
  → ``u, v`` and ``r`` (the yaw rate only when there is no IMU),
* ``sensor_msgs/msg/Imu``: gyro ``angular_velocity.z`` → ``r``,
* ``sensor_msgs/msg/NavSatFix``: ``lat, lon`` (used instead of the odometry position),
* ``geometry_msgs/msg/WrenchStamped``: generalised forces → the inputs (zero-order hold),
  mapped by ``inputs = { X = "force.x", Y = "force.y", N = "torque.z" }``.

Frames: ROS REP 103 uses ENU world and FLU body axes; marine models use NED and FRD. With
``frame = "enu"`` (default) ``north = y``, ``east = x``, ``ψ = π/2 − yaw``, ``v = −v_y``,
``r = −ω_z`` and forces/moments about y and z change sign; ``frame = "ned"`` takes the
messages as NED/FRD already. Times are the message header stamps (the bag's receive time
when a stamp is zero).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from vesselid.data.ingest.config import IngestError
from vesselid.data.ingest.streams import Stream

__all__ = ["read_bag"]

ODOM = "nav_msgs/msg/Odometry"
IMU = "sensor_msgs/msg/Imu"
FIX = "sensor_msgs/msg/NavSatFix"
WRENCH = "geometry_msgs/msg/WrenchStamped"
_KEYS = {"odometry": ODOM, "imu": IMU, "navsatfix": FIX, "wrench": WRENCH}


def _stamp(msg: Any, fallback_ns: int) -> float:
    st = msg.header.stamp
    ns = int(st.sec) * 1_000_000_000 + int(getattr(st, "nanosec", getattr(st, "nsec", 0)))
    return (ns if ns > 0 else fallback_ns) / 1e9


def _get(obj: Any, dotted: str) -> float:
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return float(obj)


def read_bag(path: str | Path, ros: dict[str, Any] | None = None):
    """Read odometry, IMU, GNSS fix and wrench messages of a ROS 1 or ROS 2 bag.

    Parameters
    ----------
    path : str or Path
        ROS 2 bag directory (with ``metadata.yaml``), a single ``.db3``/``.mcap`` file, or
        a ROS 1 ``.bag`` file.
    ros : dict, optional
        The ``[ros]`` table of the ingest configuration (topics, ``frame``, ``inputs``).

    Returns
    -------
    streams : list of Stream
    quality : dict
        ``format`` (``ros1bag``/``ros2bag``), topics read and message counts.

    Raises
    ------
    IngestError
        rosbags missing, unreadable bag, unknown frame.
    """
    ros = dict(ros or {})
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as exc:
        raise IngestError("reading ROS bags needs the optional package 'rosbags': "
                          "pip install 'vesselid[ros]'") from exc
    frame = str(ros.get("frame", "enu")).lower()
    if frame not in ("enu", "ned"):
        raise IngestError(f"[ros] frame must be 'enu' or 'ned', got {frame!r}")
    enu = frame == "enu"
    inputs = ros.get("inputs", {"X": "force.x", "Y": "force.y", "N": "torque.z"})
    path = Path(path)
    ros1 = path.is_file() and path.suffix.lower() == ".bag"
    kind = "ROS 1" if ros1 else "ROS 2"
    data: dict[str, dict[str, list[float]]] = {}
    q: dict[str, Any] = {"bag": str(path), "format": "ros1bag" if ros1 else "ros2bag",
                         "frame": frame, "topics": {}}
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    try:
        with AnyReader([path], default_typestore=store) as reader:
            chosen: dict[str, Any] = {}
            for key, msgtype in _KEYS.items():
                want = ros.get(key)
                cands = [c for c in reader.connections if c.msgtype == msgtype
                         and (want is None or c.topic == want)]
                if want is not None and not cands:
                    raise IngestError(f"{path.name}: topic {want!r} ({msgtype}) is not in the bag")
                if cands:
                    chosen[msgtype] = [c for c in cands if c.topic == cands[0].topic]
            conns = [c for cs in chosen.values() for c in cs]
            counts: dict[str, int] = {}
            for conn, t_ns, raw in reader.messages(connections=conns):
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception:
                    q["corrupt"] = q.get("corrupt", 0) + 1
                    continue
                counts[conn.topic] = counts.get(conn.topic, 0) + 1
                rec = data.setdefault(conn.msgtype, {})
                t = _stamp(msg, t_ns)
                rec.setdefault("t", []).append(t)
                if conn.msgtype == ODOM:
                    p, o = msg.pose.pose.position, msg.pose.pose.orientation
                    tw = msg.twist.twist
                    yaw = math.atan2(2 * (o.w * o.z + o.x * o.y), 1 - 2 * (o.y**2 + o.z**2))
                    for k, v in (("x", p.x), ("y", p.y), ("yaw", yaw), ("vx", tw.linear.x),
                                 ("vy", tw.linear.y), ("wz", tw.angular.z)):
                        rec.setdefault(k, []).append(float(v))
                elif conn.msgtype == IMU:
                    rec.setdefault("wz", []).append(float(msg.angular_velocity.z))
                elif conn.msgtype == FIX:
                    ok = int(msg.status.status) >= 0
                    rec.setdefault("lat", []).append(float(msg.latitude) if ok else math.nan)
                    rec.setdefault("lon", []).append(float(msg.longitude) if ok else math.nan)
                else:
                    for name, field in inputs.items():
                        rec.setdefault(name, []).append(_get(msg.wrench, field))
            q["topics"] = counts
    except IngestError:
        raise
    except Exception as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise IngestError(f"cannot read {kind} bag {path}: {first}") from exc
    streams: list[Stream] = []
    name = path.name

    def add(ch, t, x, kind="linear", prio=0, src=""):
        streams.append(Stream(ch, np.asarray(t), np.asarray(x, dtype=float), kind=kind,
                              source=f"{name}:{src}", priority=prio).clean())

    if ODOM in data:
        d = {k: np.asarray(v) for k, v in data[ODOM].items()}
        north, east = (d["y"], d["x"]) if enu else (d["x"], d["y"])
        psi = math.pi / 2 - d["yaw"] if enu else d["yaw"]
        sgn = -1.0 if enu else 1.0
        add("north", d["t"], north, src="odometry")
        add("east", d["t"], east, src="odometry")
        add("psi", d["t"], np.mod(psi + math.pi, 2 * math.pi) - math.pi, "angle", src="odometry")
        add("u", d["t"], d["vx"], src="odometry twist")
        add("v", d["t"], sgn * d["vy"], src="odometry twist")
        add("r", d["t"], sgn * d["wz"], prio=1, src="odometry twist")
    if IMU in data:
        d = {k: np.asarray(v) for k, v in data[IMU].items()}
        add("r", d["t"], (-1.0 if enu else 1.0) * d["wz"], src="imu gyro")
    if FIX in data:
        d = {k: np.asarray(v) for k, v in data[FIX].items()}
        add("lat", d["t"], d["lat"], src="navsatfix")
        add("lon", d["t"], d["lon"], src="navsatfix")
    if WRENCH in data:
        d = data[WRENCH]
        for ch, field in inputs.items():
            flip = enu and field.split(".")[-1] in ("y", "z")
            add(ch, d["t"], (-1.0 if flip else 1.0) * np.asarray(d[ch]), "hold",
                src=f"wrench {field}")
    if not streams:
        raise IngestError(f"{path}: no odometry, IMU, NavSatFix or wrench messages")
    return streams, q
