"""RunLogger and RunLog: rows from the fixed inputs, frames saved, chunks on disk."""

from __future__ import annotations

import numpy as np
import pytest
from pcvfe_drake.systems.run_logger import RunLogger
from pcvfe_drake.systems.texture_camera import to_drake_image
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource, ConstantVectorSource

from pcvfe_drake.drivelog import read_drive_log
from pcvfe_drake.runlog import RunLog


def build(run_log: RunLog, with_image: bool):
    builder = DiagramBuilder()
    logger = builder.AddNamedSystem("run_logger", RunLogger(run_log, period_s=0.1))
    values = {
        "state": [1.0, 2.0, 0.01, 5.0, 0.2, 0.0, 0.0],
        "actuation": [0.05, 0.5],
        "features": [0.1, 0.2, 0.3],
        "context_id": [3.0],
        "theta_hat": [0.61, 20.0, 21.0],
        "true_mu": [0.6],
        "true_terrain": [1.0],
    }
    for name, value in values.items():
        source = builder.AddSystem(ConstantVectorSource(np.array(value)))
        builder.Connect(source.get_output_port(), logger.GetInputPort(name))
    if with_image:
        rgb = np.zeros((16, 16, 3), np.uint8)
        rgb[..., 0] = 200
        image = builder.AddSystem(ConstantValueSource(AbstractValue.Make(to_drake_image(rgb))))
        builder.Connect(image.get_output_port(), logger.GetInputPort("image"))
    return builder.Build()


def test_rows_frames_and_chunks(tmp_path):
    run_log = RunLog(
        tmp_path / "drive_log.csv", ["sand", "concrete"], 3, chunk_rows=4, frame_period_s=0.5
    )
    simulator = Simulator(build(run_log, with_image=True))
    simulator.AdvanceTo(1.0)  # publishes at 0.0, 0.1, ..., 1.0
    assert len(run_log) == 11
    on_disk = read_drive_log(tmp_path / "drive_log.csv")
    assert len(on_disk) == 8  # two chunks of 4 written while running
    run_log.close()
    df = run_log.to_frame()
    assert len(read_drive_log(tmp_path / "drive_log.csv")) == 11
    row = df.iloc[5]
    assert (row["terrain"], row["terrain_index"], row["context"]) == ("concrete", 1, 3)
    assert (row["mu_true"], row["mu_hat"], row["C_Sr_hat"]) == (0.6, 0.61, 21.0)
    assert (row["f_00"], row["f_02"], row["v"], row["accel"]) == (0.1, 0.3, 5.0, 0.5)
    saved = df["image"][df["image"] != ""].tolist()
    assert saved == [
        "frames/frame_00000000.png",
        "frames/frame_00000500.png",
        "frames/frame_00001000.png",
    ]
    assert all((tmp_path / p).is_file() for p in saved)


def test_in_memory_without_image_and_bad_features():
    run_log = RunLog(None, ["sand"], 3)
    simulator = Simulator(build(run_log, with_image=False))
    simulator.AdvanceTo(0.35)
    assert len(run_log) == 4 and set(run_log.to_frame()["image"]) == {""}
    with pytest.raises(ValueError, match="features has 2 entries"):
        run_log.append(1.0, np.zeros(7), np.zeros(2), np.zeros(2), 0, np.ones(3), 0.5, 0)
