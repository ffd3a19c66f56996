"""ROS 2 bags written here with rosbags (sqlite3 and MCAP) round-trip into the drive log."""

import cv2
import numpy as np
import pytest
from bag_writer import BETA, V, truth, write_bag
from rosbags.rosbag2 import StoragePlugin

from pcvfe_drake.cli import main
from pcvfe_drake.hardware.bag_import import import_bag, load_mapping
from pcvfe_drake.runs.drivelog import read_drive_log


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
