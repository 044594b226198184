"""ROS 1 and ROS 2 bags → trial log (rosbags writes the bag in the test)."""

from __future__ import annotations

import math

import numpy as np
import pymap3d  # noqa: F401  (a missing test dependency fails)
import pytest

from vesselid.data.ingest import ingest


def _write_bag(path, n=700, dt=0.05):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]
    Header = T["std_msgs/msg/Header"]
    Vec = T["geometry_msgs/msg/Vector3"]
    Point = T["geometry_msgs/msg/Point"]
    Quat = T["geometry_msgs/msg/Quaternion"]
    t0 = 1_780_000_000.0
    k = np.arange(n)
    t = t0 + k * dt
    yaw_enu = 0.2 + 0.05 * np.sin(0.02 * k)          # ROS ENU yaw
    u = 0.5 + 0.1 * np.sin(0.01 * k)                 # FLU forward speed
    vy = 0.02 * np.cos(0.03 * k)                     # FLU left speed
    wz = 0.01 * np.cos(0.02 * k)                     # FLU yaw rate (counter-clockwise)
    fx, fy, tz = 2.0 + 0 * k, 0.3 + 0 * k, -0.1 + 0 * k
    with Writer(path, version=8) as w:
        c_odom = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        c_imu = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts)
        c_wr = w.add_connection("/thrust", "geometry_msgs/msg/WrenchStamped", typestore=ts)
        for i in range(n):
            sec = int(t[i])
            ns = round((t[i] - sec) * 1e9)
            hdr = Header(stamp=Time(sec=sec, nanosec=ns), frame_id="odom")
            q = Quat(x=0.0, y=0.0, z=math.sin(yaw_enu[i] / 2), w=math.cos(yaw_enu[i] / 2))
            pose = T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](position=Point(x=0.01 * i, y=0.02 * i, z=0.0),
                                                 orientation=q),
                covariance=np.zeros(36))
            twist = T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=Vec(x=u[i], y=vy[i], z=0.0),
                                                   angular=Vec(x=0.0, y=0.0, z=wz[i])),
                covariance=np.zeros(36))
            odom = T["nav_msgs/msg/Odometry"](header=hdr, child_frame_id="base_link",
                                              pose=pose, twist=twist)
            stamp_ns = sec * 1_000_000_000 + ns
            w.write(c_odom, stamp_ns, ts.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
            imu = T["sensor_msgs/msg/Imu"](
                header=hdr, orientation=q, orientation_covariance=np.zeros(9),
                angular_velocity=Vec(x=0.0, y=0.0, z=wz[i] + 0.001),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=Vec(x=0.0, y=0.0, z=9.81),
                linear_acceleration_covariance=np.zeros(9))
            w.write(c_imu, stamp_ns, ts.serialize_cdr(imu, "sensor_msgs/msg/Imu"))
            if i % 2 == 0:  # wrench commands at 10 Hz
                wr = T["geometry_msgs/msg/WrenchStamped"](
                    header=hdr, wrench=T["geometry_msgs/msg/Wrench"](
                        force=Vec(x=fx[i], y=fy[i], z=0.0), torque=Vec(x=0.0, y=0.0, z=tz[i])))
                w.write(c_wr, stamp_ns,
                        ts.serialize_cdr(wr, "geometry_msgs/msg/WrenchStamped"))
    return yaw_enu, u, vy, wz


def test_bag_to_trial_log_in_ned_frd(tmp_path):
    yaw, u, vy, wz = _write_bag(tmp_path / "bag")
    log = ingest(tmp_path / "bag", 0.1, min_duration=5)
    d = log.data
    assert len(log.experiment_ids) == 1 and len(d) > 300
    # NED/FRD: psi = pi/2 - yaw, v = -vy, r from the IMU gyro (preferred over the twist)
    np.testing.assert_allclose(np.mod(d["psi"].iloc[0], 2 * np.pi), np.pi / 2 - yaw[0],
                               atol=2e-3)
    np.testing.assert_allclose(d["u"].iloc[:50], u[:100:2], atol=2e-3)
    np.testing.assert_allclose(d["v"].iloc[:50], -vy[:100:2], atol=2e-3)
    np.testing.assert_allclose(d["r"].iloc[:50], -(wz[:100:2] + 0.001), atol=2e-4)
    np.testing.assert_array_equal(d["X"], 2.0)
    np.testing.assert_array_equal(d["Y"], -0.3)
    np.testing.assert_array_equal(d["N"], 0.1)
    q = log.metadata["quality"]
    assert q["columns"]["r"]["source"].endswith("imu gyro")
    assert q["columns"]["u"]["resampling"].startswith("anti-aliased")


def _write_ros1_bag(path, n=400, dt=0.05):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    Vec = T["geometry_msgs/msg/Vector3"]
    t0 = 1_780_000_000.0
    k = np.arange(n)
    t = t0 + k * dt
    yaw = 0.3 + 0.05 * np.sin(0.02 * k)
    u = 0.8 + 0.1 * np.sin(0.01 * k)
    wz = 0.02 * np.cos(0.02 * k)
    with Writer(path) as w:
        c_odom = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        c_wr = w.add_connection("/thrust", "geometry_msgs/msg/WrenchStamped", typestore=ts)
        for i in range(n):
            sec = int(t[i])
            ns = round((t[i] - sec) * 1e9)
            hdr = T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](
                sec=sec, nanosec=ns), frame_id="odom")
            q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw[i] / 2),
                                                  w=math.cos(yaw[i] / 2))
            pose = T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=0.04 * i, y=0.01 * i, z=0.0),
                    orientation=q), covariance=np.zeros(36))
            twist = T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=Vec(x=u[i], y=0.0, z=0.0),
                                                   angular=Vec(x=0.0, y=0.0, z=wz[i])),
                covariance=np.zeros(36))
            odom = T["nav_msgs/msg/Odometry"](header=hdr, child_frame_id="base_link",
                                              pose=pose, twist=twist)
            stamp = sec * 1_000_000_000 + ns
            w.write(c_odom, stamp, ts.serialize_ros1(odom, "nav_msgs/msg/Odometry"))
            wr = T["geometry_msgs/msg/WrenchStamped"](
                header=hdr, wrench=T["geometry_msgs/msg/Wrench"](
                    force=Vec(x=5.0, y=0.5, z=0.0), torque=Vec(x=0.0, y=0.0, z=0.2)))
            w.write(c_wr, stamp, ts.serialize_ros1(wr, "geometry_msgs/msg/WrenchStamped"))
    return yaw, u, wz


def test_ros1_bag_to_trial_log(tmp_path):
    yaw, u, wz = _write_ros1_bag(tmp_path / "run.bag")
    log = ingest(tmp_path / "run.bag", 0.1, min_duration=5)
    d = log.data
    assert len(log.experiment_ids) == 1 and len(d) > 150
    np.testing.assert_allclose(d["psi"].iloc[0], np.pi / 2 - yaw[0], atol=2e-3)
    np.testing.assert_allclose(d["u"].iloc[:50], u[:100:2], atol=2e-3)
    np.testing.assert_allclose(d["r"].iloc[:50], -wz[:100:2], atol=2e-4)
    np.testing.assert_array_equal(d["X"], 5.0)
    np.testing.assert_array_equal(d["N"], -0.2)
    src = log.metadata["quality"]["sources"][0]
    assert src["type"] == "ros1bag" and src["topics"] == {"/odom": 400, "/thrust": 400}


def test_ros1_bag_garbage_is_refused(tmp_path):
    from vesselid.data.ingest import IngestError

    (tmp_path / "x.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 20)
    with pytest.raises(IngestError, match=r"cannot read ROS 1 bag .*x\.bag"):
        ingest(tmp_path / "x.bag", 0.1)
