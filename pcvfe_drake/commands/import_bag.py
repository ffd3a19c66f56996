"""``pcvfe import-bag``: a ROS 2 bag (sqlite3 or MCAP) into a drive log, without ROS."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "import-bag",
        help="turn a ROS 2 bag (odometry, IMU, drive commands, camera) into a drive log",
        description=(
            "Read a ROS 2 bag (a folder with metadata.yaml, or a .db3 / .mcap file; sqlite3 or "
            "MCAP storage; no ROS installation needed) and write the project's drive log "
            "(CSV or Parquet by the --out suffix) with its camera frames in frames/ beside it. "
            "MAP names the topics (a YAML file or the shipped `pcvfe_ros2`: the public "
            "implementation's /fixposition/odometry, /fixposition/corrimu, /drive, "
            "/camera/image_raw). Then `pcvfe fit`, `pcvfe diagnose` and `pcvfe replay "
            "LOG --scenario roboracer` work on the recording (docs/hardware.md)."
        ),
    )
    parser.add_argument("bag", type=Path, help="ROS 2 bag folder or file")
    parser.add_argument(
        "--mapping", default="pcvfe_ros2", help="mapping YAML or shipped name (default: pcvfe_ros2)"
    )
    parser.add_argument(
        "--out", type=Path, required=True, help="drive log to write (.csv/.parquet)"
    )
    parser.add_argument(
        "--lenient",
        action="store_true",
        help="import a bag damaged partway from what can be read, and report the rows and the "
        "time span lost (without it such a bag is refused)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pcvfe_drake.hardware.bag_import import BagLoss, import_bag, load_mapping

    loss = BagLoss()
    log = import_bag(
        args.bag, load_mapping(args.mapping), args.out, lenient=args.lenient, loss=loss
    )
    frames = int((log["image"] != "").sum()) if "image" in log.columns else 0
    duration = float(log["t"].iloc[-1]) if len(log) else 0.0
    print(f"{args.out}: {len(log)} rows over {duration:.2f} s, {frames} camera frames")
    if loss.partial:
        print(f"--lenient: partial import of {args.bag}: {loss.describe()}")
    return 0
