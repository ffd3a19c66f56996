"""ClipFeatures LeafSystem: both backends, caching on the image, degraded mode, wiring."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from pcvfe_drake.diagrams.world_io import world_terrain_map
from pcvfe_drake.perception.camera import DownwardCamera
from pcvfe_drake.perception.features import ClipFeatureExtractor, DescriptorExtractor
from pcvfe_drake.systems.clip_features import ClipFeatures
from pcvfe_drake.systems.texture_camera import TextureCamera, to_drake_image


def load_tiny_clip_helpers():
    path = Path(__file__).resolve().parents[1] / "perception" / "test_features.py"
    spec = importlib.util.spec_from_file_location("tiny_clip_helpers", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def frames():
    cam = DownwardCamera(world_terrain_map("paper"))
    return [cam.render(30, 20, 0.3), cam.render(-30, 20, 0.3)]


def test_descriptor_backend_output_equals_core(frames):
    system = ClipFeatures()
    port = system.GetOutputPort("features")
    assert port.size() == 23 and system.feature_names == DescriptorExtractor().names
    ctx = system.CreateDefaultContext()
    system.GetInputPort("image").FixValue(ctx, to_drake_image(frames[0]))
    z = port.Eval(ctx)
    np.testing.assert_allclose(z, DescriptorExtractor().extract_one(frames[0]), atol=1e-12)
    assert system.HasDirectFeedthrough(0, 0)


def test_clip_backend_from_folder_matches_core(frames, tmp_path):
    helpers = load_tiny_clip_helpers()
    folder = helpers.write_tiny_clip(tmp_path / "clip", helpers.tiny_clip_weights())
    system = ClipFeatures(folder, lambda_c=0.25)
    assert system.GetOutputPort("features").size() == 36
    ctx = system.CreateDefaultContext()
    system.GetInputPort("image").FixValue(ctx, to_drake_image(frames[1]))
    z = system.GetOutputPort("features").Eval(ctx)
    np.testing.assert_allclose(z, ClipFeatureExtractor(folder).extract_one(frames[1]), atol=1e-6)
    single = ClipFeatures(folder, lambda_c=0.25, threads=1)
    assert single.extractor.threads == 1 and system.extractor.threads == 2
    ctx1 = single.CreateDefaultContext()
    single.GetInputPort("image").FixValue(ctx1, to_drake_image(frames[1]))
    np.testing.assert_allclose(single.GetOutputPort("features").Eval(ctx1), z, atol=1e-6)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        ClipFeatures(tmp_path / "missing")


class CountingExtractor(DescriptorExtractor):
    def __init__(self):
        super().__init__()
        self.calls = 0

    def semantic(self, images):
        self.calls += 1
        return super().semantic(images)


def test_features_are_cached_until_the_image_changes(frames):
    extractor = CountingExtractor()
    system = ClipFeatures(extractor)
    ctx = system.CreateDefaultContext()
    image_port = system.GetInputPort("image")
    image_port.FixValue(ctx, to_drake_image(frames[0]))
    out = system.GetOutputPort("features")
    z0 = out.Eval(ctx).copy()
    out.Eval(ctx)
    ctx.SetTime(3.0)  # time is not a prerequisite
    out.Eval(ctx)
    assert extractor.calls == 1
    image_port.FixValue(ctx, to_drake_image(frames[1]))
    z1 = out.Eval(ctx)
    assert extractor.calls == 2 and not np.allclose(z0, z1)


def test_black_frame_gives_nan_and_bad_frame_raises(frames):
    system = ClipFeatures()
    ctx = system.CreateDefaultContext()
    system.GetInputPort("image").FixValue(ctx, to_drake_image(np.zeros((224, 224, 3), np.uint8)))
    assert np.all(np.isnan(system.GetOutputPort("features").Eval(ctx)))
    system.GetInputPort("image").FixValue(ctx, AbstractValue.Make(to_drake_image(frames[0][:8])))
    with pytest.raises(ValueError, match="input 'image'.*too small"):
        system.GetOutputPort("features").Eval(ctx)


def test_camera_to_features_in_a_diagram():
    terrain = world_terrain_map("paper")
    builder = DiagramBuilder()
    source = builder.AddSystem(ConstantVectorSource(np.array([-30.0, -20.0, 0, 5.0, 2.0, 0, 0])))
    camera = builder.AddNamedSystem("camera", TextureCamera(terrain))
    features = builder.AddNamedSystem("features", ClipFeatures())
    builder.Connect(source.get_output_port(), camera.GetInputPort("state"))
    builder.Connect(camera.GetOutputPort("image"), features.GetInputPort("image"))
    diagram = builder.Build()
    sim = Simulator(diagram)
    sim.AdvanceTo(0.25)
    ctx = features.GetMyContextFromRoot(sim.get_context())
    z = features.GetOutputPort("features").Eval(ctx)
    expected = DescriptorExtractor().extract_one(camera.camera.render(-30.0, -20.0, 2.0))
    np.testing.assert_allclose(z, expected, atol=1e-12)


def test_a_frame_becomes_an_opaque_drake_image_with_its_colours():
    rgb = np.random.default_rng(5).integers(0, 256, (24, 40, 3), dtype=np.uint8)
    for frame in (rgb, rgb[:, ::-1]):  # contiguous or a strided view
        image = to_drake_image(frame)
        assert (image.width(), image.height()) == (40, 24)
        np.testing.assert_array_equal(image.data[:, :, :3], frame)
        assert np.all(image.data[:, :, 3] == 255)
