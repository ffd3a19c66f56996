"""TextureCamera LeafSystem: ports, frame rate, held output, seeded effects, bad input."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from pcvfe_drake.diagrams.world_io import world_terrain_map
from pcvfe_drake.perception.camera import CameraConfig
from pcvfe_drake.systems.texture_camera import TextureCamera


@pytest.fixture(scope="module")
def terrain():
    return world_terrain_map("paper")


def state(x=30.0, y=20.0, v=6.0, psi=0.3):
    return np.array([x, y, 0.0, v, psi, 0.0, 0.0])


def test_ports_rate_and_first_frame_at_initialization(terrain):
    cam = TextureCamera(terrain)
    assert cam.GetInputPort("state").size() == 7
    assert cam.period_s == pytest.approx(0.1)
    assert not cam.HasDirectFeedthrough(0, 0)
    ctx = cam.CreateDefaultContext()
    cam.GetInputPort("state").FixValue(ctx, state())
    image = cam.GetOutputPort("image").Eval(ctx)
    assert (image.width(), image.height()) == (224, 224)
    assert not image.data[:, :, :3].any()  # nothing rendered before initialization
    sim = Simulator(cam, ctx)
    sim.Initialize()
    rgba = np.array(cam.GetOutputPort("image").Eval(ctx).data)
    expected = cam.camera.render_state(state(), cam.frame_rng(0.0))
    assert np.array_equal(rgba[:, :, :3], expected)
    assert np.all(rgba[:, :, 3] == 255)


def test_frames_follow_the_car_at_10_hz_and_hold_between(terrain):
    cfg = CameraConfig(exposure_s=0.002, exposure_jitter=0.05, noise_std=3.0)
    cam = TextureCamera(terrain, cfg, seed=11)
    ctx = cam.CreateDefaultContext()
    port = cam.GetInputPort("state")
    port.FixValue(ctx, state(psi=0.3))
    sim = Simulator(cam, ctx)
    sim.Initialize()
    sim.AdvanceTo(0.05)
    first = np.array(cam.GetOutputPort("image").Eval(ctx).data)
    port.FixValue(ctx, state(x=-30.0, psi=1.0))  # the car jumps onto brick
    sim.AdvanceTo(0.09)
    held = np.array(cam.GetOutputPort("image").Eval(ctx).data)
    assert np.array_equal(first, held)  # nothing new before the next frame time
    sim.AdvanceTo(0.15)  # (Drake runs the updates due at t = 0.1 when it steps past 0.1)
    new = np.array(cam.GetOutputPort("image").Eval(ctx).data)
    expected = cam.camera.render_state(state(x=-30.0, psi=1.0), cam.frame_rng(0.1))
    assert np.array_equal(new[:, :, :3], expected)
    # brick is red, grass is green
    assert (
        new[:, :, 0].mean() > new[:, :, 1].mean() and first[:, :, 1].mean() > first[:, :, 0].mean()
    )


def test_same_seed_same_frames_other_seed_other_noise(terrain):
    cfg = CameraConfig(noise_std=5.0)

    def frame(seed):
        cam = TextureCamera(terrain, cfg, seed=seed)
        ctx = cam.CreateDefaultContext()
        cam.GetInputPort("state").FixValue(ctx, state())
        sim = Simulator(cam, ctx)
        sim.AdvanceTo(0.2)
        return np.array(cam.GetOutputPort("image").Eval(ctx).data)

    assert np.array_equal(frame(1), frame(1))
    assert not np.array_equal(frame(1), frame(2))


def test_bad_inputs_raise_clear_errors(terrain):
    with pytest.raises(ValueError, match="period_s"):
        TextureCamera(terrain, period_s=0.0)
    with pytest.raises(ValueError, match="seed"):
        TextureCamera(terrain, seed=-1)
    cam = TextureCamera(terrain)
    ctx = cam.CreateDefaultContext()
    cam.GetInputPort("state").FixValue(ctx, state(v=np.nan))
    with pytest.raises(ValueError, match="input 'state'.*not finite"):
        Simulator(cam, ctx).Initialize()
    cam.GetInputPort("state").FixValue(ctx, state(x=400.0))
    with pytest.raises(ValueError, match="outside the terrain map"):
        Simulator(cam, ctx).Initialize()
