"""ROS 2 bags (sqlite3 or MCAP) into the project's drive log, without a ROS installation.

Uses the ``rosbags`` package. A mapping (YAML, :class:`BagMapping`; the shipped
``pcvfe_ros2`` is the public implementation's topics) names the topics; the 7-state is
assembled at the odometry's times as FACTS.md section 8 describes a real car must:

==========  ===============================================================================
column      from
==========  ===============================================================================
sx, sy      odometry ``pose.pose.position.x``, ``.y`` [m]
psi         yaw of odometry ``pose.pose.orientation`` [rad], unwrapped (continuous)
v, beta     odometry twist ``(vx, vy)`` in the body frame: ``v = |(vx, vy)|``,
            ``beta = atan2(vy, vx)`` (0 below ``min_speed_for_beta_mps``); a ``world``-frame
            twist is rotated by ``-psi`` first
psi_dot     IMU ``angular_velocity.z`` at the odometry time (linear interpolation; the
            odometry's ``twist.angular.z`` without an IMU topic)
delta       the drive command's ``steering_angle`` held (the VESC does not measure it), or the
            integral of ``steering_angle_velocity`` (``delta: integrate``)
steer_rate  the drive command's ``steering_angle_velocity`` held from its time [rad/s]
accel       the drive command's ``acceleration`` held from its time [m/s^2]
image       every ``image.every``-th camera frame as PNG in ``frames/`` beside the log, on the
            first row at or after its capture time
==========  ===============================================================================

Time ``t`` starts at 0 at the first odometry message (``time: header`` uses the messages'
stamps, ``bag`` the recording times). Rows before the first drive command take zero input.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

MAPPING_DIR = Path(__file__).resolve().parents[1] / "data" / "bag_mappings"
"""Shipped mappings (``pcvfe_ros2``)."""

ACKERMANN_MSGS = {
    "ackermann_msgs/msg/AckermannDrive": (
        "float32 steering_angle\nfloat32 steering_angle_velocity\nfloat32 speed\n"
        "float32 acceleration\nfloat32 jerk\n"
    ),
    "ackermann_msgs/msg/AckermannDriveStamped": (
        "std_msgs/Header header\nackermann_msgs/AckermannDrive drive\n"
    ),
}
"""``ackermann_msgs`` definitions (not in rosbags' stock type store)."""


@dataclass
class TopicMapping:
    topic: str = ""


@dataclass
class OdometryMapping(TopicMapping):
    topic: str = "/fixposition/odometry"
    twist_frame: str = "body"


@dataclass
class ImuMapping(TopicMapping):
    topic: str = "/fixposition/corrimu"


@dataclass
class DriveMapping(TopicMapping):
    topic: str = "/drive"
    delta: str = "steering_angle"


@dataclass
class ImageMapping(TopicMapping):
    topic: str = "/camera/image_raw"
    every: int = 1


@dataclass
class BagMapping:
    """Which topics hold what (see the module doc); an empty ``topic`` leaves a role out
    (only ``odometry`` is required)."""

    odometry: OdometryMapping = field(default_factory=OdometryMapping)
    imu: ImuMapping = field(default_factory=ImuMapping)
    drive: DriveMapping = field(default_factory=DriveMapping)
    image: ImageMapping = field(default_factory=ImageMapping)
    time: str = "header"
    min_speed_for_beta_mps: float = 0.3

    def problems(self) -> list[str]:
        out = []
        if not self.odometry.topic:
            out.append("odometry.topic is required")
        if self.odometry.twist_frame not in ("body", "world"):
            out.append(f"odometry.twist_frame={self.odometry.twist_frame!r}: 'body' or 'world'")
        if self.drive.delta not in ("steering_angle", "integrate"):
            out.append(f"drive.delta={self.drive.delta!r}: 'steering_angle' or 'integrate'")
        if not (isinstance(self.image.every, int) and self.image.every >= 1):
            out.append(f"image.every={self.image.every!r}: an integer >= 1")
        if self.time not in ("header", "bag"):
            out.append(f"time={self.time!r}: 'header' or 'bag'")
        return out


def load_mapping(name_or_path: str | Path) -> BagMapping:
    """A mapping from a YAML file or a shipped name; errors name the file and the field."""
    path = Path(name_or_path)
    if not path.is_file():
        shipped = MAPPING_DIR / f"{name_or_path}.yaml"
        if not shipped.is_file():
            names = ", ".join(sorted(p.stem for p in MAPPING_DIR.glob("*.yaml")))
            raise FileNotFoundError(
                f"mapping {str(name_or_path)!r} is neither a file nor a shipped mapping ({names})"
            )
        path = shipped
    raw = yaml.safe_load(path.read_text()) or {}
    if not isinstance(raw, dict):
        raise ValueError(f"mapping {path}: must be a mapping of roles to settings")
    kwargs = {}
    roles = {f.name: f.type for f in dataclasses.fields(BagMapping)}
    for key, value in raw.items():
        if key not in roles:
            raise ValueError(f"mapping {path}: unknown field {key!r} (known: {', '.join(roles)})")
        default = getattr(BagMapping(), key)
        if dataclasses.is_dataclass(default):
            if not isinstance(value, dict):
                raise ValueError(f"mapping {path}: {key} must be a mapping (topic: ...)")
            known = {f.name for f in dataclasses.fields(default)}
            unknown = sorted(set(value) - known)
            if unknown:
                raise ValueError(f"mapping {path}: unknown field(s) {key}.{unknown}")
            kwargs[key] = dataclasses.replace(default, **value)
        else:
            kwargs[key] = value
    mapping = BagMapping(**kwargs)
    problems = mapping.problems()
    if problems:
        raise ValueError(f"mapping {path}: " + "; ".join(problems))
    return mapping


def typestore():
    """rosbags' ROS 2 Humble type store plus ``ackermann_msgs``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    for name, text in ACKERMANN_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def _stamp_s(msg, bag_ns: int, use_header: bool) -> float:
    header = getattr(msg, "header", None)
    if use_header and header is not None:
        s = header.stamp.sec + header.stamp.nanosec * 1e-9
        if s > 0:
            return float(s)
    return bag_ns * 1e-9


def yaw_of(q) -> float:
    """Yaw [rad] of a quaternion message (x, y, z, w)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def image_rgb(msg) -> np.ndarray:
    """A ``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8) as RGB (H, W, 3) uint8."""
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}.get(msg.encoding)
    if channels is None:
        raise ValueError(f"image encoding {msg.encoding!r} is not supported (8-bit colour/mono)")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if data.size < step * h or step < w * channels:
        raise ValueError(f"image data of {data.size} bytes does not hold {w} x {h} x {channels}")
    pixels = data[: step * h].reshape(h, step)[:, : w * channels].reshape(h, w, channels)
    if channels == 1:
        return np.repeat(pixels, 3, axis=2)
    rgb = pixels[:, :, :3]
    if msg.encoding.startswith("bgr"):
        rgb = rgb[:, :, ::-1]
    return np.ascontiguousarray(rgb)


def read_bag(bag: str | Path, mapping: BagMapping, frames_dir: Path | None) -> pd.DataFrame:
    """The drive log of ``bag`` (a ROS 2 bag folder, sqlite3 or MCAP) under ``mapping``; frames
    are written to ``frames_dir`` (None: no frames)."""
    from rosbags.rosbag2 import Reader

    bag = Path(bag)
    if not bag.exists():
        raise FileNotFoundError(f"bag {bag}: no such file or folder")
    store = typestore()
    use_header = mapping.time == "header"
    odo, imu, drive, images = [], [], [], []
    roles = {
        mapping.odometry.topic: "odometry",
        mapping.imu.topic: "imu",
        mapping.drive.topic: "drive",
        mapping.image.topic: "image",
    }
    roles.pop("", None)
    with Reader(bag) as reader:
        present = {c.topic for c in reader.connections}
        if mapping.odometry.topic not in present:
            raise ValueError(
                f"bag {bag}: no odometry topic {mapping.odometry.topic!r} (topics: "
                f"{', '.join(sorted(present))}); name it in the mapping"
            )
        connections = [c for c in reader.connections if c.topic in roles]
        n_image = 0
        for connection, ns, raw in reader.messages(connections=connections):
            msg = store.deserialize_cdr(raw, connection.msgtype)
            t = _stamp_s(msg, ns, use_header)
            role = roles[connection.topic]
            if role == "odometry":
                p, tw = msg.pose.pose, msg.twist.twist
                odo.append(
                    (
                        t,
                        p.position.x,
                        p.position.y,
                        yaw_of(p.orientation),
                        tw.linear.x,
                        tw.linear.y,
                        tw.angular.z,
                    )  # fmt: skip
                )
            elif role == "imu":
                imu.append((t, msg.angular_velocity.z))
            elif role == "drive":
                d = msg.drive
                drive.append((t, d.steering_angle, d.steering_angle_velocity, d.acceleration))
            elif role == "image" and frames_dir is not None:
                if n_image % mapping.image.every == 0:
                    images.append((t, image_rgb(msg)))
                n_image += 1
    return assemble(np.array(odo), np.array(imu), np.array(drive), images, mapping, frames_dir)


def assemble(odo, imu, drive, images, mapping: BagMapping, frames_dir: Path | None):
    """The drive-log DataFrame from the topics' samples (arrays sorted here by time)."""
    odo = odo[np.argsort(odo[:, 0], kind="stable")]
    keep = np.concatenate([[True], np.diff(odo[:, 0]) > 0])
    odo = odo[keep]
    t_abs = odo[:, 0]
    t0 = t_abs[0]
    psi = np.unwrap(odo[:, 3])
    vx, vy = odo[:, 4], odo[:, 5]
    if mapping.odometry.twist_frame == "world":
        c, s = np.cos(psi), np.sin(psi)
        vx, vy = c * vx + s * vy, -s * vx + c * vy
    v = np.hypot(vx, vy)
    beta = np.where(v >= mapping.min_speed_for_beta_mps, np.arctan2(vy, vx), 0.0)
    if len(imu):
        imu = imu[np.argsort(imu[:, 0], kind="stable")]
        psi_dot = np.interp(t_abs, imu[:, 0], imu[:, 1])
    else:
        psi_dot = odo[:, 6]
    delta = np.zeros_like(t_abs)
    steer_rate = np.zeros_like(t_abs)
    accel = np.zeros_like(t_abs)
    if len(drive):
        drive = drive[np.argsort(drive[:, 0], kind="stable")]
        k = np.searchsorted(drive[:, 0], t_abs, side="right") - 1
        has = k >= 0
        steer_rate[has] = drive[k[has], 2]
        accel[has] = drive[k[has], 3]
        if mapping.drive.delta == "steering_angle":
            delta[has] = drive[k[has], 1]
        else:
            dt = np.diff(t_abs, prepend=t_abs[0])
            delta = np.cumsum(np.concatenate([[0.0], steer_rate[:-1]]) * dt)
    log = pd.DataFrame(
        {
            "t": t_abs - t0,
            "sx": odo[:, 1],
            "sy": odo[:, 2],
            "delta": delta,
            "v": v,
            "psi": psi,
            "psi_dot": psi_dot,
            "beta": beta,
            "steer_rate": steer_rate,
            "accel": accel,
        }
    )
    log["image"] = ""
    if images and frames_dir is not None:
        import cv2

        frames_dir.mkdir(parents=True, exist_ok=True)
        column = log.columns.get_loc("image")
        for t_img, rgb in sorted(images, key=lambda x: x[0]):
            row = int(np.searchsorted(t_abs, t_img - 1e-9, side="left"))
            if row >= len(log):
                continue
            name = f"frame_{int(round((t_img - t0) * 1e6)):012d}.png"
            cv2.imwrite(str(frames_dir / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            if log.iat[row, column]:
                continue  # two frames before one row: the first one
            log.iat[row, column] = f"{frames_dir.name}/{name}"
    return log


def import_bag(bag: str | Path, mapping: BagMapping, out: str | Path) -> pd.DataFrame:
    """Read ``bag`` and write the drive log ``out`` (CSV or Parquet by suffix) with its frames
    in ``frames/`` beside it; returns the log (validated on writing)."""
    from pcvfe_drake.runs.drivelog import write_drive_log

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    log = read_bag(bag, mapping, out.parent / "frames" if mapping.image.topic else None)
    write_drive_log(log, out)
    return log
