"""A small ROS 2 bag of a car on a circle with a known side slip, written with ``rosbags``
(the bag-import tests and the damaged-bag cases build on it)."""

import math

import numpy as np
from rosbags.rosbag2 import Writer

from pcvfe_drake.hardware.bag_import import typestore

T0 = 1_700_000_000.0  # stamps as a real clock gives them [s]
R, V, BETA = 8.0, 3.0, 0.05  # circle radius [m], speed [m/s], side slip [rad]


def truth(t):
    """A car on a circle, counter-clockwise, with a constant side slip."""
    course = V / R * t  # heading of the velocity
    return {
        "sx": R * np.sin(course),
        "sy": R * (1 - np.cos(course)),
        "psi": course - BETA,
        "psi_dot": np.full_like(t, V / R),
    }


def write_bag(path, storage):
    ts = typestore()
    T = ts.types
    msgs = {
        "odo": "nav_msgs/msg/Odometry",
        "imu": "sensor_msgs/msg/Imu",
        "drive": "ackermann_msgs/msg/AckermannDriveStamped",
        "img": "sensor_msgs/msg/Image",
    }
    frames = []

    def header(t):
        sec = int(math.floor(t))
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9))),
            frame_id="map",
        )

    vec = lambda x, y, z: T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)
    with Writer(path, version=9, storage_plugin=storage) as writer:
        topics = {
            "odo": "/fixposition/odometry",
            "imu": "/fixposition/corrimu",
            "drive": "/drive",
            "img": "/camera/image_raw",
        }
        conn = {k: writer.add_connection(topics[k], msgs[k], typestore=ts) for k in topics}
        events = []
        for k in range(300):  # odometry 100 Hz, 3 s
            t = 0.01 * k
            x = truth(np.array([t]))
            psi = float(x["psi"][0])
            odo = T[msgs["odo"]](
                header=header(T0 + t),
                child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](
                    pose=T["geometry_msgs/msg/Pose"](
                        position=T["geometry_msgs/msg/Point"](
                            x=float(x["sx"][0]), y=float(x["sy"][0]), z=0.0
                        ),
                        orientation=T["geometry_msgs/msg/Quaternion"](
                            x=0.0, y=0.0, z=math.sin(psi / 2), w=math.cos(psi / 2)
                        ),
                    ),
                    covariance=np.zeros(36),
                ),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](
                        linear=vec(V * math.cos(BETA), V * math.sin(BETA), 0.0),
                        angular=vec(0.0, 0.0, V / R),
                    ),
                    covariance=np.zeros(36),
                ),
            )
            events.append((t, "odo", odo))
        for k in range(600):  # IMU 200 Hz
            t = 0.005 * k
            q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
            imu = T[msgs["imu"]](
                header=header(T0 + t), orientation=q, orientation_covariance=np.zeros(9),
                angular_velocity=vec(0.0, 0.0, V / R), angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vec(0.0, 0.0, 9.81), linear_acceleration_covariance=np.zeros(9),
            )  # fmt: skip
            events.append((t, "imu", imu))
        for k in range(60):  # drive commands 20 Hz
            t = 0.05 * k
            drive = T["ackermann_msgs/msg/AckermannDrive"](
                steering_angle=0.1 + 0.01 * k, steering_angle_velocity=0.2,
                speed=V, acceleration=0.5 * (k % 3), jerk=0.0,
            )  # fmt: skip
            events.append((t, "drive", T[msgs["drive"]](header=header(T0 + t), drive=drive)))
        rng = np.random.default_rng(0)
        for k in range(30):  # camera 10 Hz, bgr8
            t = 0.1 * k + 0.003
            rgb = rng.integers(0, 256, size=(24, 32, 3), dtype=np.uint8)
            frames.append((t, rgb))
            img = T[msgs["img"]](
                header=header(T0 + t), height=24, width=32, encoding="bgr8", is_bigendian=0,
                step=96, data=np.ascontiguousarray(rgb[:, :, ::-1]).reshape(-1),
            )  # fmt: skip
            events.append((t, "img", img))
        for t, kind, msg in sorted(events, key=lambda e: e[0]):
            raw = ts.serialize_cdr(msg, msgs[kind])
            writer.write(conn[kind], int(round((T0 + t + 0.002) * 1e9)), raw)
    return frames
