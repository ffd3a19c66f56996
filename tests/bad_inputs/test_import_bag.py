"""`pcvfe import-bag` on damaged bags: one line naming the bag and the problem, exit 2, nothing
written; a bag damaged partway is refused unless --lenient, which reports what it lost."""

from __future__ import annotations

import os
import shutil

import pytest
from bag_writer import write_bag
from rosbags.rosbag2 import StoragePlugin

from pcvfe_drake.cli import main
from pcvfe_drake.runs.drivelog import read_drive_log

DATA = {"SQLITE3": "bag.db3", "MCAP": "bag.mcap"}


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """A clean sqlite3 and MCAP bag (3 s: odometry 300, IMU 600, drive 60, camera 30)."""
    root = tmp_path_factory.mktemp("bags")
    for storage in (StoragePlugin.SQLITE3, StoragePlugin.MCAP):
        write_bag(root / storage.name / "bag", storage)
    return root


def _zero(path, frac: float, size: int) -> None:
    data = bytearray(path.read_bytes())
    start = int(len(data) * frac)
    data[start : start + size] = bytes(size)
    path.write_bytes(bytes(data))


DAMAGE = {
    "metadata.yaml not YAML": (
        lambda d, f: (d / "metadata.yaml").write_text("rosbag2_bagfile_information: [: :\n"),
        "Could not load YAML",
    ),
    "metadata.yaml missing": (lambda d, f: (d / "metadata.yaml").unlink(), "no metadata.yaml"),
    "metadata.yaml empty": (
        lambda d, f: (d / "metadata.yaml").write_text(""),
        "Invalid bag metadata",
    ),
    "metadata.yaml without files": (
        lambda d, f: (d / "metadata.yaml").write_text(
            "rosbag2_bagfile_information:\n  version: 9\n"
        ),
        "metadata key is missing",
    ),
    "storage file missing": (lambda d, f: f.unlink(), "files are missing"),
    "storage file empty": (lambda d, f: f.write_bytes(b""), "not a readable ROS 2 bag"),
    "storage file is noise": (lambda d, f: f.write_bytes(os.urandom(4000)), "not a readable"),
    "storage file truncated": (
        lambda d, f: f.write_bytes(f.read_bytes()[: f.stat().st_size // 2]),
        "not a readable",
    ),
    "metadata counts more messages": (
        lambda d, f: (d / "metadata.yaml").write_text(
            (d / "metadata.yaml").read_text().replace("message_count: 300", "message_count: 400")
        ),
        "100 rows lost",
    ),
}


def _damaged(bags, tmp_path, storage: str, damage) -> tuple:
    bag = tmp_path / f"{storage}_bag"
    shutil.copytree(bags / storage / "bag", bag)
    damage(bag, bag / DATA[storage])
    return bag, tmp_path / "out" / "drive.csv"


@pytest.mark.parametrize("storage", sorted(DATA))
@pytest.mark.parametrize("case", sorted(DAMAGE))
def test_a_damaged_bag_is_one_line_naming_it(bags, tmp_path, capsys, storage, case):
    damage, words = DAMAGE[case]
    bag, out = _damaged(bags, tmp_path, storage, damage)
    assert main(["import-bag", str(bag), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert str(bag) in err and words in err
    assert not out.exists()


def test_a_mapped_topic_missing_from_the_bag_is_named(bags, tmp_path, capsys):
    mapping = tmp_path / "m.yaml"
    mapping.write_text("imu:\n  topic: /imu/data\n")
    bag = bags / "MCAP" / "bag"
    assert (
        main(["import-bag", str(bag), "--mapping", str(mapping), "--out", str(tmp_path / "x.csv")])
        == 2
    )
    err = capsys.readouterr().err
    assert "'/imu/data' not in the bag" in err and "set it to ''" in err


def test_a_zeroed_chunk_is_refused_then_imported_with_lenient(bags, tmp_path, capsys):
    bag, out = _damaged(bags, tmp_path, "MCAP", lambda d, f: _zero(f, 0.65, 4096))
    assert main(["import-bag", str(bag), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "a partial import is refused" in err and "rows lost" in err and "--lenient" in err
    assert not out.exists()
    assert main(["import-bag", str(bag), "--out", str(out), "--lenient"]) == 0
    text = capsys.readouterr().out
    log = read_drive_log(out)
    lost = 300 - len(log)
    assert lost > 0
    assert f"partial import of {bag}: {lost} rows lost" in text
    assert f"{log['t'].iloc[-1]:.2f}-2.99 s" in text  # the lost tail, on the log's clock


@pytest.mark.parametrize(
    ("text", "words"),
    [("imu: [: :\n", "not valid YAML"), ("imu: {topic: /a}\nimu: {topic: /b}\n", "given twice")],
)
def test_a_mapping_that_is_not_yaml_is_named(bags, tmp_path, capsys, text, words):
    mapping = tmp_path / "m.yaml"
    mapping.write_text(text)
    bag = bags / "MCAP" / "bag"
    argv = ["import-bag", str(bag), "--mapping", str(mapping), "--out", str(tmp_path / "x.csv")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"mapping {mapping}: not valid YAML" in err and words in err and "Traceback" not in err
