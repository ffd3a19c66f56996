import json

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper
from PIL import Image

from pcvfe_drake.perception.camera import CameraConfig, DownwardCamera
from pcvfe_drake.perception.features import (
    CAPTIONS,
    CLIP_MEAN,
    CLIP_STD,
    BlankImageError,
    ClipFeatureExtractor,
    DescriptorExtractor,
    as_image_batch,
    make_extractor,
    percentiles_10_90,
    prompts,
)
from pcvfe_drake.perception.terrain import Terrain, TerrainMap
from pcvfe_drake.perception.texture_library import TextureSet

S, D, HIDDEN = 32, 24, 40


def tiny_clip_weights(seed=0):
    rng = np.random.default_rng(seed)
    return {
        "w1": (rng.standard_normal((3 * S * S, HIDDEN)) / np.sqrt(3 * S * S)).astype(np.float32),
        "b1": (0.1 * rng.standard_normal(HIDDEN)).astype(np.float32),
        "w2": (rng.standard_normal((HIDDEN, D)) / np.sqrt(HIDDEN)).astype(np.float32),
        "text": rng.standard_normal((len(CAPTIONS), D)).astype(np.float32),
    }


def write_tiny_clip(folder, weights, *, captions=CAPTIONS, logit_scale=100.0, size=S):
    """A CLIP-shaped encoder: (N, 3, S, S) -> Flatten -> MatMul -> Add -> Tanh -> MatMul."""
    folder.mkdir(parents=True, exist_ok=True)
    x = helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, ["N", 3, size, size])
    y = helper.make_tensor_value_info("image_embeds", TensorProto.FLOAT, ["N", D])
    inits = [numpy_helper.from_array(weights[k], k) for k in ("w1", "b1", "w2")]
    nodes = [
        helper.make_node("Flatten", ["pixel_values"], ["flat"], axis=1),
        helper.make_node("MatMul", ["flat", "w1"], ["h0"]),
        helper.make_node("Add", ["h0", "b1"], ["h1"]),
        helper.make_node("Tanh", ["h1"], ["h2"]),
        helper.make_node("MatMul", ["h2", "w2"], ["image_embeds"]),
    ]
    graph = helper.make_graph(nodes, "tiny_clip", [x], [y], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, folder / "image_encoder.onnx")
    np.save(folder / "text_embeddings.npy", weights["text"])
    cfg = {
        "model": "tiny-test",
        "image_size": S,
        "mean": list(CLIP_MEAN),
        "std": list(CLIP_STD),
        "logit_scale": logit_scale,
        "captions": list(captions),
        "prompt_template": "This image contains {}",
    }
    (folder / "clip.json").write_text(json.dumps(cfg))
    return folder


def reference_z(images, weights, logit_scale=100.0, lambda_c=0.25):
    """Independent numpy reference: PIL resize, torchvision-style crop, CLIP normalisation,
    the encoder in numpy, L2 normalisation, softmax of scaled cosines, weighted mean RGB."""
    zs = []
    for img in images:
        h, w = img.shape[:2]
        if w <= h:
            nw, nh = S, int(S * h / w)
        else:
            nh, nw = S, int(S * w / h)
        pil = Image.fromarray(img).resize((nw, nh), Image.BICUBIC)
        arr = np.asarray(pil)
        top, left = int(round((nh - S) / 2.0)), int(round((nw - S) / 2.0))
        arr = arr[top : top + S, left : left + S].astype(np.float64) / 255.0
        x = ((arr - np.array(CLIP_MEAN)) / np.array(CLIP_STD)).transpose(2, 0, 1).reshape(-1)
        emb = np.tanh(x @ weights["w1"].astype(np.float64) + weights["b1"]) @ weights["w2"]
        emb = emb / np.linalg.norm(emb)
        text = weights["text"] / np.linalg.norm(weights["text"], axis=1, keepdims=True)
        logits = logit_scale * (text @ emb)
        p = np.exp(logits - logits.max())
        p /= p.sum()
        rgb = img.reshape(-1, 3).mean(axis=0) / 255.0
        zs.append(np.concatenate([p, lambda_c * rgb]))
    return np.array(zs)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    weights = tiny_clip_weights()
    folder = write_tiny_clip(tmp_path_factory.mktemp("clip"), weights)
    return folder, weights


def smooth_images(seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for h, w in [(S, S), (60, 45), (97, 131), (224, 224), (40, 300)]:
        base = rng.integers(0, 256, (h // 4 + 1, w // 4 + 1, 3)).astype(np.uint8)
        img = np.asarray(Image.fromarray(base).resize((w, h), Image.BILINEAR))
        out.append(np.ascontiguousarray(img))
    return out


def test_the_papers_33_captions():
    assert len(CAPTIONS) == 33 and len(set(CAPTIONS)) == 33
    assert CAPTIONS[0] == "asphalt" and CAPTIONS[-1] == "mud" and "train track" in CAPTIONS
    assert prompts()[6] == "This image contains grass"


def test_clip_backend_matches_numpy_reference_end_to_end(tiny):
    folder, weights = tiny
    ext = ClipFeatureExtractor(folder)
    images = smooth_images()
    z = ext.extract(images)
    assert z.shape == (len(images), 36) and ext.dim == 36
    assert ext.names[:33] == list(CAPTIONS) and ext.names[33:] == ["mean_r", "mean_g", "mean_b"]
    ref = reference_z(images, weights)
    np.testing.assert_allclose(z, ref, atol=2e-5)
    np.testing.assert_allclose(z[:, :33].sum(axis=1), 1.0, atol=1e-9)
    assert z[:, :33].max() > 0.2  # logit_scale 100 makes the softmax peaked, not uniform
    # one image at a time (and through different batch sizes) gives the same numbers
    one = np.array([ext.extract_one(im) for im in images])
    np.testing.assert_allclose(one, z, atol=1e-6)
    ext2 = ClipFeatureExtractor(folder, batch_size=2, lambda_c=0.5)
    z2 = ext2.extract(images)
    np.testing.assert_allclose(z2[:, :33], z[:, :33], atol=1e-6)
    np.testing.assert_allclose(z2[:, 33:], 2 * z[:, 33:], atol=1e-12)
    top = ext.top_captions(z[0], k=3)
    assert [c for c, _ in top][0] == CAPTIONS[int(np.argmax(ref[0, :33]))]
    # RGBA images: alpha ignored
    rgba = np.dstack([images[3], np.full(images[3].shape[:2], 255, np.uint8)])
    np.testing.assert_allclose(ext.extract_one(rgba), z[3], atol=1e-6)


def test_clip_folder_errors_name_the_file(tiny, tmp_path):
    folder, weights = tiny
    with pytest.raises(FileNotFoundError, match="does not exist"):
        ClipFeatureExtractor(tmp_path / "nothing")
    bad = write_tiny_clip(tmp_path / "corrupt", weights)
    (bad / "image_encoder.onnx").write_bytes(b"\x08\x01garbage")
    with pytest.raises(ValueError, match=r"image_encoder.onnx could not be loaded"):
        ClipFeatureExtractor(bad)
    (bad / "image_encoder.onnx").unlink()
    with pytest.raises(FileNotFoundError, match="image_encoder.onnx"):
        ClipFeatureExtractor(bad)
    few = write_tiny_clip(tmp_path / "few", weights, captions=CAPTIONS[:30])
    with pytest.raises(ValueError, match="33 rows but clip.json lists 30 captions"):
        ClipFeatureExtractor(few)
    wide = write_tiny_clip(tmp_path / "wide", weights)
    np.save(wide / "text_embeddings.npy", np.ones((33, D + 1), np.float32))
    with pytest.raises(ValueError, match=f"embedding width {D + 1}"):
        ClipFeatureExtractor(wide)
    size = write_tiny_clip(tmp_path / "size", weights)
    cfg = json.loads((size / "clip.json").read_text())
    cfg["image_size"] = 64
    (size / "clip.json").write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match=r"does not match \(N, 3, 64, 64\)"):
        ClipFeatureExtractor(size)
    (size / "clip.json").write_text("{not json")
    with pytest.raises(ValueError, match="clip.json is not valid JSON"):
        ClipFeatureExtractor(size)
    (size / "clip.json").write_text(json.dumps({"model": "x"}))
    with pytest.raises(ValueError, match="lacks"):
        ClipFeatureExtractor(size)
    emb = write_tiny_clip(tmp_path / "emb", weights)
    (emb / "text_embeddings.npy").write_bytes(b"junk")
    with pytest.raises(ValueError, match="text_embeddings.npy could not be read"):
        ClipFeatureExtractor(emb)


@pytest.mark.parametrize("backend", ["descriptor", "clip"])
def test_bad_images_are_rejected_by_name(backend, tiny):
    ext = make_extractor(backend, tiny[0])
    good = smooth_images()[3]
    cases = [
        (good.astype(np.float32), "dtype must be uint8"),
        (good[..., 0], r"images\[0\]: shape must be"),
        (np.zeros((0, 0, 3), np.uint8), "empty or too small"),
        (np.zeros((64, 64, 3), np.uint8), "all black"),
        (np.dstack([good, good[..., :2]]), "shape must be"),
    ]
    for image, message in cases:
        with pytest.raises(ValueError, match=message):
            ext.extract([image])
    with pytest.raises(ValueError, match=r"images\[1\]: image is all black"):
        ext.extract([good, np.zeros_like(good)])
    with pytest.raises(ValueError, match="batch is empty"):
        ext.extract([])
    with pytest.raises(ValueError, match="unknown feature backend"):
        make_extractor("vit")


def test_descriptor_is_fixed_length_and_carries_the_weighted_mean_rgb():
    ext = DescriptorExtractor()
    images = smooth_images()
    z = ext.extract(images)
    assert z.shape == (len(images), ext.dim) and ext.dim == len(ext.names) == 23
    assert np.all(np.isfinite(z))
    rgb = np.array([im.reshape(-1, 3).mean(axis=0) / 255 for im in images])
    np.testing.assert_allclose(z[:, -3:], 0.25 * rgb, atol=1e-9)


def test_descriptor_separates_all_textures_in_camera_frames():
    """Nearest-centroid accuracy on held-out frames with blur, noise, exposure and rotation."""
    textures = TextureSet()
    ext = DescriptorExtractor()
    rng = np.random.default_rng(42)
    n_train, n_test = 8, 10
    train, test = [], []
    for name in textures.names:
        terrain = Terrain(name, 0.5, name)
        world = TerrainMap.from_label_image(
            np.zeros((1, 1), np.uint8),
            [terrain],
            x_min_m=0,
            y_min_m=0,
            resolution_m=1.0,
            outside=name,
        )
        cams = [
            DownwardCamera(
                world,
                CameraConfig(exposure_s=0.004, exposure_jitter=0.15, noise_std=noise),
                textures,
            )
            for noise in (2.0, 8.0)
        ]
        frames = []
        for i in range(n_train + n_test):
            x, y = rng.uniform(-50, 50, 2)
            psi, v = rng.uniform(-np.pi, np.pi), rng.uniform(0, 15)
            frames.append(cams[i % 2].render(x, y, psi, v, rng))
        z = ext.extract(frames)
        train.append(z[:n_train])
        test.append(z[n_train:])
    centroids = np.array([t.mean(axis=0) for t in train])
    z_test = np.vstack(test)
    y_test = np.repeat(np.arange(len(test)), n_test)
    pred = np.argmin(((z_test[:, None] - centroids[None]) ** 2).sum(axis=2), axis=1)
    accuracy = np.mean(pred == y_test)
    assert accuracy >= 0.95, accuracy


def test_cli_features_prints_z_for_both_backends(tiny, tmp_path, capsys):
    from pcvfe_drake.cli import main

    path = tmp_path / "frame.png"
    image = smooth_images()[3]
    Image.fromarray(image).save(path)
    assert main(["features", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(out["images"][0]["z"], DescriptorExtractor().extract_one(image))
    assert main(["features", str(path), "--clip", str(tiny[0]), "--top", "2"]) == 0
    text = capsys.readouterr().out
    best = CAPTIONS[int(np.argmax(reference_z([image], tiny[1])[0, :33]))]
    assert "backend: clip (36 numbers" in text and best in text
    assert main(["features", str(tmp_path / "missing.png")]) == 2
    assert "missing.png does not exist" in capsys.readouterr().err


def test_cli_export_clip_explains_missing_torch(tmp_path, capsys):
    import importlib.util

    from pcvfe_drake.cli import main

    if importlib.util.find_spec("open_clip") and importlib.util.find_spec("torch"):
        pytest.skip("torch and open_clip are installed here")
    assert main(["export-clip", "--out", str(tmp_path / "clip")]) == 2
    assert "needs torch and open_clip" in capsys.readouterr().err


def test_an_rgba_frame_and_its_rgb_view_give_the_same_features_from_one_contiguous_copy():
    """The camera's frames are RGBA: the batch holds their RGB as one C-contiguous copy (every
    later step reads it; a strided view cost each of them a copy of its own), with the same
    numbers as the RGB view, and an RGB image that is already contiguous is not copied."""
    rng = np.random.default_rng(3)
    rgba = rng.integers(0, 256, (64, 48, 4), dtype=np.uint8)
    view = rgba[:, :, :3]
    (from_rgba,) = as_image_batch([rgba])
    (from_view,) = as_image_batch([view])
    for rgb in (from_rgba, from_view):
        assert rgb.flags.c_contiguous and rgb.shape == (64, 48, 3)
        np.testing.assert_array_equal(rgb, view)
    own = np.ascontiguousarray(view)
    assert np.shares_memory(as_image_batch([own])[0], own)
    extractor = DescriptorExtractor()
    np.testing.assert_array_equal(extractor.extract_one(rgba), extractor.extract_one(view))
    opaque_black = np.zeros((32, 32, 4), np.uint8)
    opaque_black[..., 3] = 255  # alpha set, no colour: still blank
    with pytest.raises(BlankImageError):
        as_image_batch([opaque_black])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_percentiles_10_90_are_numpys_to_the_last_bit(dtype):
    rng = np.random.default_rng(5)
    for shape in [(1, 1), (1, 2), (3, 7), (56, 56), (112, 112), (17, 113)]:
        for scale, decimals in ((100.0, None), (1e-3, None), (100.0, 0)):
            values = (rng.random(shape) * scale).astype(dtype)
            if decimals is not None:  # ties
                values = np.round(values, decimals).astype(dtype)
            expected = np.percentile(values, (10, 90))
            got = percentiles_10_90(values)
            assert got.dtype == expected.dtype
            assert np.array_equal(got.view(np.int64), expected.view(np.int64))
