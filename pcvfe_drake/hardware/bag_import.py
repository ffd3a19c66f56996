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

from pcvfe_drake.yaml_unique import load_unique

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
    try:
        raw = load_unique(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ValueError(f"mapping {path}: not valid YAML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise ValueError(f"mapping {path}: not a YAML file (not UTF-8 text)") from exc
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


class BagError(ValueError):
    """A bag that cannot be imported (damaged, not a bag, a mapped topic missing, or damaged
    partway with ``lenient`` off); the message names the bag and the problem in one line."""


@dataclass
class BagLoss:
    """What a partial import lost: per mapped role, the messages the bag's metadata counts and
    those read; the spans without odometry [s, recording time from the first odometry message,
    which is the log's ``t`` up to the stamps' offset]; why."""

    expected: dict[str, int] = field(default_factory=dict)
    read: dict[str, int] = field(default_factory=dict)
    lost_spans_s: list[tuple[float, float]] = field(default_factory=list)
    reason: str = ""

    @property
    def partial(self) -> bool:
        return bool(self.reason) or any(self.read.get(k, 0) < n for k, n in self.expected.items())

    @property
    def lost_rows(self) -> int:
        """Odometry messages (drive-log rows) lost."""
        return max(0, self.expected.get("odometry", 0) - self.read.get("odometry", 0))

    def describe(self) -> str:
        """One line: the rows and the time span lost, the roles short of messages, why."""
        short = [
            f"{role} {self.read.get(role, 0)} of {n}"
            for role, n in self.expected.items()
            if self.read.get(role, 0) < n
        ]
        spans = ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in self.lost_spans_s)
        lost = sum(b - a for a, b in self.lost_spans_s)
        text = f"{self.lost_rows} rows lost ({lost:.2f} s of odometry: {spans or 'none'})"
        if short:
            text += f"; messages read: {', '.join(short)}"
        if self.reason:
            text += f"; {self.reason}"
        return text


def _damage(exc: BaseException) -> str:
    """The problem behind an exception of the bag reader or the message decoder, in words."""
    from rosbags.rosbag2 import ReaderError
    from rosbags.serde import SerdeError

    text = " ".join(str(exc).split())  # one line (a YAML error quotes the file over several)
    if isinstance(exc, ReaderError):
        return f"not a readable ROS 2 bag: {text}"
    if isinstance(exc, SerdeError):
        return f"a message cannot be decoded (damaged data): {text}"
    return f"the storage file is damaged ({type(exc).__name__}: {text})"


def _lost_spans(t_s: np.ndarray, start_s: float, end_s: float) -> list[tuple[float, float]]:
    """Spans of [start_s, end_s] (recording time, one clock with ``t_s``) without odometry: gaps
    of more than ``GAP_STEPS`` median steps, and the head and tail missing."""
    if len(t_s) < 2:
        return [(start_s, end_s)] if end_s > start_s else []
    step = float(np.median(np.diff(t_s)))
    gap = GAP_STEPS * step
    spans = []
    if t_s[0] - start_s > gap:
        spans.append((start_s, float(t_s[0])))
    for a, b in zip(t_s[:-1], t_s[1:], strict=True):
        if b - a > gap:
            spans.append((float(a), float(b)))
    if end_s - t_s[-1] > gap:
        spans.append((float(t_s[-1]), end_s))
    return spans


GAP_STEPS = 5.0
"""A step between odometry messages longer than this many median steps is a loss."""


def read_bag(
    bag: str | Path,
    mapping: BagMapping,
    frames_dir: Path | None,
    *,
    lenient: bool = False,
    loss: BagLoss | None = None,
) -> pd.DataFrame:
    """The drive log of ``bag`` (a ROS 2 bag folder, sqlite3 or MCAP) under ``mapping``; frames
    are written to ``frames_dir`` (None: no frames).

    A damaged bag is a :class:`BagError` naming it and the problem: one that cannot be opened
    (metadata.yaml missing or not YAML, storage files missing, not a database), a mapped topic
    that is not in it, and one damaged partway (fewer messages than its metadata counts, a
    message that cannot be decoded, a storage error after some messages). With ``lenient`` a
    bag damaged partway is imported from what could be read (undecodable messages skipped),
    and ``loss`` (when given) receives what was lost: rows, time spans, messages per role."""
    from rosbags.rosbag2 import Reader

    bag = Path(bag)
    if not bag.exists():
        raise FileNotFoundError(f"bag {bag}: no such file or folder")
    loss = loss if loss is not None else BagLoss()
    store = typestore()
    use_header = mapping.time == "header"
    odo, imu, drive, images = [], [], [], []
    odo_bag_s: list[float] = []
    roles = {
        mapping.odometry.topic: "odometry",
        mapping.imu.topic: "imu",
        mapping.drive.topic: "drive",
        mapping.image.topic: "image",
    }
    roles.pop("", None)
    try:
        reader = Reader(bag)
        reader.open()
    except FileNotFoundError as exc:
        raise BagError(f"bag {bag}: not a ROS 2 bag (no metadata.yaml beside its data)") from exc
    except Exception as exc:  # noqa: BLE001 - rosbags raises many kinds for a damaged bag
        raise BagError(f"bag {bag}: {_damage(exc)}") from exc
    try:
        present = {c.topic for c in reader.connections}
        if mapping.odometry.topic not in present:
            raise BagError(
                f"bag {bag}: no odometry topic {mapping.odometry.topic!r} (topics: "
                f"{', '.join(sorted(present))}); name it in the mapping"
            )
        missing = sorted(topic for topic in roles if topic not in present)
        if missing:
            raise BagError(
                f"bag {bag}: mapped topic(s) {', '.join(map(repr, missing))} not in the bag "
                f"(topics: {', '.join(sorted(present))}); name the right topic in the mapping, "
                "or set it to '' to leave that role out"
            )
        connections = [c for c in reader.connections if c.topic in roles]
        for c in connections:
            role = roles[c.topic]
            loss.expected[role] = loss.expected.get(role, 0) + int(c.msgcount)
        start_s, end_s = reader.start_time * 1e-9, reader.end_time * 1e-9
        n_image = 0
        undecodable = 0
        try:
            for connection, ns, raw in reader.messages(connections=connections):
                role = roles[connection.topic]
                try:
                    msg = store.deserialize_cdr(raw, connection.msgtype)
                except Exception as exc:  # noqa: BLE001 - a damaged message
                    if not lenient:
                        raise BagError(
                            f"bag {bag}: {_damage(exc)} ({role} message at bag time "
                            f"{ns * 1e-9 - start_s:.3f} s); --lenient imports the rest"
                        ) from exc
                    undecodable += 1
                    continue
                loss.read[role] = loss.read.get(role, 0) + 1
                t = _stamp_s(msg, ns, use_header)
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
                    odo_bag_s.append(ns * 1e-9)
                elif role == "imu":
                    imu.append((t, msg.angular_velocity.z))
                elif role == "drive":
                    d = msg.drive
                    drive.append((t, d.steering_angle, d.steering_angle_velocity, d.acceleration))
                elif role == "image" and frames_dir is not None:
                    if n_image % mapping.image.every == 0:
                        try:
                            images.append((t, image_rgb(msg)))
                        except ValueError as exc:  # the bag is fine, its images unsupported
                            raise BagError(f"bag {bag}: topic {connection.topic}: {exc}") from exc
                    n_image += 1
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001 - the storage fails partway
            loss.reason = f"reading stopped: {_damage(exc)}"
            if not odo:
                raise BagError(f"bag {bag}: {_damage(exc)}") from exc
        if undecodable:
            loss.reason = "; ".join(
                filter(None, [loss.reason, f"{undecodable} message(s) could not be decoded"])
            )
    finally:
        reader.close()
    if not odo:
        raise BagError(f"bag {bag}: the odometry topic {mapping.odometry.topic!r} has no messages")
    t_bag = np.sort(np.asarray(odo_bag_s))
    first = t_bag[0]
    loss.lost_spans_s = [(a - first, b - first) for a, b in _lost_spans(t_bag, start_s, end_s)]
    if loss.partial and not lenient:
        raise BagError(
            f"bag {bag}: damaged or incomplete, a partial import is refused: "
            f"{loss.describe()}; --lenient imports what could be read"
        )
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


def import_bag(
    bag: str | Path,
    mapping: BagMapping,
    out: str | Path,
    *,
    lenient: bool = False,
    loss: BagLoss | None = None,
) -> pd.DataFrame:
    """Read ``bag`` and write the drive log ``out`` (CSV or Parquet by suffix) with its frames
    in ``frames/`` beside it; returns the log (validated on writing). ``lenient`` and ``loss``:
    see :func:`read_bag` (nothing is written when the bag is refused)."""
    from pcvfe_drake.runs.drivelog import write_drive_log

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    log = read_bag(
        bag,
        mapping,
        out.parent / "frames" if mapping.image.topic else None,
        lenient=lenient,
        loss=loss,
    )
    write_drive_log(log, out)
    return log
