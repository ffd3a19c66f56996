"""CameraView: the frame panel follows the car, one frame object per update, the border and
id take the context's colour, the caption is drawn."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.sensors import ImageRgba8U

from pcvfe_drake.perception.features import DescriptorExtractor
from pcvfe_drake.systems.camera_view import CameraView
from pcvfe_drake.views.labels import FrameCaptioner


@pytest.fixture
def meshcat(local_meshcat_server):
    return local_meshcat_server


def image(rgb) -> ImageRgba8U:
    img = ImageRgba8U(32, 32)
    img.mutable_data[:, :, :3] = rgb
    img.mutable_data[:, :, 3] = 255
    return img


def test_panel_frames_context_and_caption(meshcat, probe):
    extractor = DescriptorExtractor()
    red = np.zeros((64, 64, 3), np.uint8)
    red[..., 0] = 200
    blue = np.zeros((64, 64, 3), np.uint8)
    blue[..., 2] = 200
    captioner = FrameCaptioner(extractor, {"red_tex": red, "blue_tex": blue})
    view = CameraView(
        meshcat, extractor.dim, caption=captioner, frame_period_s=0.5, offset_m=(7, 0, 9)
    )
    simulator = Simulator(view)
    context = simulator.get_mutable_context()
    view.GetInputPort("state").FixValue(context, np.array([5.0, -3.0, 0, 4.0, 0, 0, 0]))
    view.GetInputPort("image").FixValue(context, image((10, 10, 210)))
    view.GetInputPort("context_id").FixValue(context, np.array([3.0]))
    view.GetInputPort("features").FixValue(context, extractor.extract([blue])[0])
    simulator.AdvanceTo(0.6)  # publishes at 0 and 0.5: two frames
    assert view.frames_drawn == 2
    np.testing.assert_allclose(probe.translation(meshcat, "/pcvfe/camera"), [12.0, -3.0, 9.0])
    assert meshcat.HasPath("/pcvfe/camera/frame/00001")
    assert probe.visible(meshcat, "/pcvfe/camera/frame/00001") is True
    assert probe.visible(meshcat, "/pcvfe/camera/frame/00000") is False
    assert b"png" in probe.object_bytes(meshcat, "/pcvfe/camera/frame/00001").lower()
    assert view._border.shown == 3
    assert view._context.shown == "context 3"
    assert view._caption_label.shown == "nearest texture: blue_tex"
    # Noise: the border turns to the noise colour and the text says so.
    view.GetInputPort("context_id").FixValue(context, np.array([-1.0]))
    view.GetInputPort("features").FixValue(context, extractor.extract([red])[0])
    simulator.AdvanceTo(1.1)
    assert view._border.shown == -1
    assert view._context.shown == "noise (-1)"
    assert view._caption_label.shown == "nearest texture: red_tex"
    assert probe.visible(meshcat, view._border.path(3)) is False


def test_frame_alone_without_context_or_features(meshcat, probe):
    view = CameraView(meshcat, 23, frame_period_s=0.5)
    simulator = Simulator(view)
    context = simulator.get_mutable_context()
    view.GetInputPort("state").FixValue(context, np.array([1.0, 2.0, 0, 4.0, 0, 0, 0]))
    view.GetInputPort("image").FixValue(context, image((200, 10, 10)))
    simulator.AdvanceTo(0.1)  # context_id and features unconnected: a loop without them
    assert view.frames_drawn == 1 and meshcat.HasPath("/pcvfe/camera/frame/00000")
    assert view._border.shown is None and view._context.shown is None
    assert view._caption_label.shown is None


def test_bad_arguments(meshcat):
    with pytest.raises(ValueError, match="frame_period_s"):
        CameraView(meshcat, 23, frame_period_s=0.0)
    with pytest.raises(ValueError, match="thumbnail_px"):
        CameraView(meshcat, 23, thumbnail_px=4)
