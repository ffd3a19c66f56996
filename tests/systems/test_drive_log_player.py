"""DriveLogPlayer: the recorded state, input, frames and truth at the context time."""

import cv2
import numpy as np
import pandas as pd

from pcvfe_drake.hardware.replay import ReplayLog
from pcvfe_drake.systems.drive_log_player import DriveLogPlayer


def test_outputs_follow_the_log(tmp_path):
    t = np.array([0.0, 0.05, 0.1])
    log = pd.DataFrame({"t": t})
    for i, name in enumerate(("sx", "sy", "delta", "v", "psi", "psi_dot", "beta")):
        log[name] = t + i
    log["steer_rate"], log["accel"] = [0.1, 0.2, 0.3], [1.0, 2.0, 3.0]
    log["mu_true"], log["terrain_index"] = [0.3, 0.3, 0.8], [2, 2, 0]
    rgb = np.zeros((8, 10, 3), np.uint8)
    rgb[..., 1] = 77
    cv2.imwrite(str(tmp_path / "f.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    log["image"] = ["f.png", "", ""]
    player = DriveLogPlayer(ReplayLog.from_frame(log, tmp_path), width_px=10, height_px=8)
    ctx = player.CreateDefaultContext()
    ctx.SetTime(0.07)
    np.testing.assert_allclose(player.GetOutputPort("state").Eval(ctx), 0.05 + np.arange(7))
    np.testing.assert_allclose(player.GetOutputPort("logged_actuation").Eval(ctx), [0.2, 2.0])
    image = np.asarray(player.GetOutputPort("image").Eval(ctx).data)
    assert image.shape == (8, 10, 4) and (image[..., 1] == 77).all()
    ctx.SetTime(0.1)
    assert player.GetOutputPort("true_mu").Eval(ctx)[0] == 0.8
    assert player.GetOutputPort("true_terrain").Eval(ctx)[0] == 0.0
    no_truth = log.assign(mu_true=np.nan)
    player = DriveLogPlayer(ReplayLog.from_frame(no_truth, tmp_path))
    assert not player.HasOutputPort("true_mu") and not player.HasOutputPort("true_terrain")
