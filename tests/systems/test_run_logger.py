"""RunLogger and RunLog: rows from the fixed inputs, frames saved, chunks on disk."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantValueSource, ConstantVectorSource

from pcvfe_drake.runs.drivelog import read_drive_log
from pcvfe_drake.runs.runlog import RunLog
from pcvfe_drake.systems.run_logger import RunLogger
from pcvfe_drake.systems.texture_camera import to_drake_image


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
    assert len(run_log) == 10  # the row of t = 1.0 waits for the input applied from it
    on_disk = read_drive_log(tmp_path / "drive_log.csv")
    assert len(on_disk) == 8  # two chunks of 4 written while running
    logger = simulator.get_system().GetSubsystemByName("run_logger")
    logger.finish()
    logger.finish()  # idempotent
    assert len(run_log) == 11
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
    simulator.get_system().GetSubsystemByName("run_logger").finish()
    assert len(run_log) == 4 and set(run_log.to_frame()["image"]) == {""}
    with pytest.raises(ValueError, match="features has 2 entries"):
        run_log.append(1.0, np.zeros(7), np.zeros(2), np.zeros(2), 0, np.ones(3), 0.5, 0)


def test_each_row_gets_the_input_applied_from_it():
    """A controller updating at the log's rate (offset 0, like the Nmpc): its new output at t
    is held over [t, t + period); the row of t must carry that value, not the one before."""
    from pydrake.systems.framework import BasicVector, EventStatus, LeafSystem

    class Counter(LeafSystem):  # output k on [0.1 k, 0.1 (k + 1)): 1 from t = 0 on
        def __init__(self) -> None:
            super().__init__()
            index = self.DeclareDiscreteState(BasicVector([0.0, 0.0]))
            self.DeclarePeriodicDiscreteUpdateEvent(0.1, 0.0, self._update)
            self.DeclareStateOutputPort("actuation", index)

        def _update(self, context, discrete_state):
            k = context.get_discrete_state_vector().GetAtIndex(0) + 1.0
            discrete_state.set_value([k, 0.0])
            return EventStatus.Succeeded()

    run_log = RunLog(None, ["sand"], 3)
    builder = DiagramBuilder()
    logger = builder.AddNamedSystem("run_logger", RunLogger(run_log, period_s=0.1))
    counter = builder.AddSystem(Counter())
    builder.Connect(counter.get_output_port(), logger.GetInputPort("actuation"))
    for name, size in (
        ("state", 7),
        ("features", 3),
        ("context_id", 1),
        ("theta_hat", 3),
        ("true_mu", 1),
        ("true_terrain", 1),
    ):
        source = builder.AddSystem(ConstantVectorSource(np.ones(size)))
        builder.Connect(source.get_output_port(), logger.GetInputPort(name))
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(0.5)
    logger.finish()
    df = run_log.to_frame()
    np.testing.assert_allclose(df["t"], [0.0, 0.1, 0.2, 0.3, 0.4, 0.5], atol=1e-12)
    # Rows 0..4 carry the value applied from them; the last row the value held into it.
    np.testing.assert_allclose(df["steer_rate"], [1.0, 2.0, 3.0, 4.0, 5.0, 5.0])


def test_without_truth_ports_and_with_a_lost_state(tmp_path):
    """A hardware station: no truth connected, and rows whose state is NaN are skipped."""
    run_log = RunLog(tmp_path / "drive_log.csv", ["sand"], 3, chunk_rows=2)
    builder = DiagramBuilder()
    logger = builder.AddNamedSystem("run_logger", RunLogger(run_log, period_s=0.1))
    values = {
        "actuation": [0.05, 0.5],
        "features": [0.1, 0.2, 0.3],
        "context_id": [-1.0],
        "theta_hat": [0.61, 20.0, 21.0],
    }
    for name, value in values.items():
        source = builder.AddSystem(ConstantVectorSource(np.array(value)))
        builder.Connect(source.get_output_port(), logger.GetInputPort(name))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    ctx = logger.GetMyMutableContextFromRoot(simulator.get_mutable_context())
    state = logger.GetInputPort("state")
    state.FixValue(ctx, [1.0, 2.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    simulator.AdvanceTo(0.35)  # rows at 0.0, 0.1, 0.2, 0.3
    state.FixValue(ctx, np.full(7, np.nan))
    simulator.AdvanceTo(0.55)  # 0.4, 0.5 are lost
    logger.finish()
    run_log.close()
    assert logger.skipped_rows == 2
    df = read_drive_log(tmp_path / "drive_log.csv")
    assert len(df) == 4 and df["mu_true"].isna().all() and (df["terrain"] == "").all()
