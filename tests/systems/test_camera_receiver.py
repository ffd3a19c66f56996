"""CameraReceiver: queued frames decoded while fresh, blank after a timeout or for nothing,
malformed and repeated frames rejected."""

import numpy as np
from pydrake.systems.analysis import Simulator

from pcvfe_drake.hardware.image_messages import encode_image_array
from pcvfe_drake.hardware.playout import MessageQueue
from pcvfe_drake.systems.camera_receiver import CameraReceiver


def test_frames_pass_while_fresh_and_faults_blank_or_hold():
    queue = MessageQueue()
    rx = CameraReceiver(
        queue=queue, width_px=16, height_px=12, period_s=0.005, timeout_s=0.15, max_delay_s=0.1
    )
    sim = Simulator(rx)
    ctx = sim.get_mutable_context()
    sim.Initialize()
    image = rx.GetOutputPort("image")
    blank = np.asarray(image.Eval(ctx).data)
    assert blank.shape == (12, 16, 4) and not blank.any()

    rgb = np.random.default_rng(0).integers(1, 255, size=(12, 16, 3), dtype=np.uint8)
    queue.push(encode_image_array(rgb, utime=100_000).encode())
    sim.AdvanceTo(0.001)  # checked (accepted) at t = 0
    np.testing.assert_array_equal(np.asarray(image.Eval(ctx).data)[:, :, :3], rgb)

    broken = encode_image_array(rgb[::-1].copy(), utime=200_000)
    broken.images[0].data = broken.images[0].data[:100]
    broken.images[0].size = 100
    queue.push(broken.encode())
    queue.push(encode_image_array(rgb[::-1].copy(), utime=100_000).encode())  # a repeat
    queue.push(b"\x00" * 7)  # not an image array at all
    sim.AdvanceTo(0.1)
    status = rx.GetOutputPort("status").Eval(ctx)
    assert dict(status.rejected) == {"malformed": 2, "duplicate": 1} and status.accepted == 1
    np.testing.assert_array_equal(np.asarray(image.Eval(ctx).data)[:, :, :3], rgb)  # held

    sim.AdvanceTo(0.26)  # 0.16 s since the last good frame
    assert not np.asarray(image.Eval(ctx).data).any()
    assert rx.GetOutputPort("status").Eval(ctx).timeouts == 1
