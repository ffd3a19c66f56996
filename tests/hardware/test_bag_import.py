"""ROS 2 bags written here with rosbags (sqlite3 and MCAP) round-trip into the drive log."""

import math

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from pcvfe_drake.cli import main
from pcvfe_drake.hardware.bag_import import import_bag, load_mapping, typestore
from pcvfe_drake.runs.drivelog import read_drive_log

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


@pytest.mark.parametrize("storage", [StoragePlugin.SQLITE3, StoragePlugin.MCAP])
def test_a_bag_round_trips_into_the_drive_log(tmp_path, storage):
    frames = write_bag(tmp_path / "bag", storage)
    out = tmp_path / "log" / "drive.parquet"
    assert main(["import-bag", str(tmp_path / "bag"), "--out", str(out)]) == 0
    log = read_drive_log(out)
    assert len(log) == 300
    t = log["t"].to_numpy()
    np.testing.assert_allclose(t, 0.01 * np.arange(300), atol=1e-6)
    x = truth(0.01 * np.arange(300))
    for name in ("sx", "sy", "psi", "psi_dot"):
        np.testing.assert_allclose(log[name], x[name], atol=1e-6, err_msg=name)
    np.testing.assert_allclose(log["v"], V, atol=1e-9)
    np.testing.assert_allclose(log["beta"], BETA, atol=1e-9)
    # The drive command held from its time: row k at 0.01 k has command floor(k / 5).
    k = np.arange(300) // 5
    np.testing.assert_allclose(log["delta"], 0.1 + 0.01 * k, atol=1e-6)
    np.testing.assert_allclose(log["steer_rate"], 0.2, atol=1e-6)
    np.testing.assert_allclose(log["accel"], 0.5 * (k % 3), atol=1e-6)
    # Every frame on the first row at or after its capture time, pixels intact.
    with_frame = np.flatnonzero(log["image"].to_numpy() != "")
    assert len(with_frame) == len(frames)
    for row, (t_img, rgb) in zip(with_frame, frames, strict=True):
        assert t[row] >= t_img - 1e-6 and t[row] - t_img < 0.01
        back = cv2.cvtColor(cv2.imread(str(out.parent / log["image"].iloc[row])), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(back, rgb)


def test_mapping_errors_name_the_field(tmp_path):
    assert load_mapping("pcvfe_ros2").odometry.topic == "/fixposition/odometry"
    bad = tmp_path / "m.yaml"
    bad.write_text("odometry:\n  topic: /odom\n  twist_frame: up\n")
    with pytest.raises(ValueError, match="twist_frame"):
        load_mapping(bad)
    bad.write_text("odometer:\n  topic: /odom\n")
    with pytest.raises(ValueError, match="unknown field 'odometer'"):
        load_mapping(bad)
    with pytest.raises(FileNotFoundError, match="pcvfe_ros2"):
        load_mapping("nope")
    write_bag(tmp_path / "bag", StoragePlugin.MCAP)
    other = load_mapping("pcvfe_ros2")
    other.odometry.topic = "/odom"
    with pytest.raises(ValueError, match="no odometry topic '/odom'"):
        import_bag(tmp_path / "bag", other, tmp_path / "x.csv")


def test_fit_and_replay_work_on_an_imported_bag(tmp_path, capsys):
    write_bag(tmp_path / "bag", StoragePlugin.MCAP)
    log = tmp_path / "drive.csv"
    assert main(["import-bag", str(tmp_path / "bag"), "--out", str(log)]) == 0
    assert main(["fit", str(log), "--vehicle", "roboracer", "--json"]) == 0
    out = tmp_path / "replayed"
    assert main(["replay", str(log), "--scenario", "roboracer", "--out", str(out),
                 "--no-progress"]) == 0  # fmt: skip
    replayed = read_drive_log(out / "drive_log.csv")
    assert replayed["mu_true"].isna().all()  # a real car's log has no truth
    summary = (out / "summary.json").read_text()
    assert '"ground_truth": false' in summary
