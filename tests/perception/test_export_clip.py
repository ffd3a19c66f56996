"""``pcvfe export-clip``'s exporter on a tiny open_clip CLIP with random weights.

Needs the optional 'clip-export' packages (torch, open_clip, onnxscript); skipped without them,
as in the project's own environment. With them, it checks the exported folder against open_clip
in torch: preprocessing, a dynamic batch dimension, and z end to end.
"""

import json

import numpy as np
import pytest
from PIL import Image

torch = pytest.importorskip("torch")
open_clip = pytest.importorskip("open_clip")
pytest.importorskip("onnxscript")

from pcvfe_drake.perception.clip_export import check_export, write_clip_folder  # noqa: E402
from pcvfe_drake.perception.features import CAPTIONS, ClipFeatureExtractor, prompts  # noqa: E402

SIZE, CONTEXT = 32, 16


def tiny_open_clip():
    """An open_clip CLIP with the ViT structure of ViT-B/32 (QuickGELU, class token, projection)
    but 2 layers of width 32 on 32 px images; logit scale 100 so the softmax is peaked."""
    torch.manual_seed(0)
    model = open_clip.model.CLIP(
        embed_dim=16,
        vision_cfg=dict(layers=2, width=32, head_width=16, patch_size=8, image_size=SIZE),
        text_cfg=dict(context_length=CONTEXT, width=32, heads=2, layers=1),
        quick_gelu=True,
    )
    with torch.no_grad():
        model.logit_scale.fill_(np.log(100.0))
    model.eval()
    return model, open_clip.SimpleTokenizer(context_length=CONTEXT)


def torch_z(model, tokenizer, images, lambda_c=0.25):
    """z computed in torch with open_clip's own preprocessing transform."""
    transform = open_clip.image_transform(
        SIZE, is_train=False, resize_mode="shortest", interpolation="bicubic"
    )
    pixels = torch.stack([transform(Image.fromarray(im)) for im in images])
    with torch.no_grad():
        img = torch.nn.functional.normalize(model.encode_image(pixels), dim=-1)
        txt = torch.nn.functional.normalize(model.encode_text(tokenizer(prompts())), dim=-1)
        z_s = torch.softmax(model.logit_scale.exp() * img @ txt.T, dim=-1).double().numpy()
    rgb = np.array([im.reshape(-1, 3).mean(axis=0) / 255.0 for im in images])
    return np.hstack([z_s, lambda_c * rgb])


def test_exported_folder_matches_open_clip_in_torch(tmp_path):
    model, tokenizer = tiny_open_clip()
    folder = tmp_path / "clip"
    cfg = write_clip_folder(model, tokenizer, folder, name="tiny/random")
    assert sorted(p.name for p in folder.iterdir()) == [
        "clip.json",
        "image_encoder.onnx",
        "text_embeddings.npy",
    ]
    assert json.loads((folder / "clip.json").read_text()) == cfg
    assert cfg["image_size"] == SIZE and cfg["captions"] == list(CAPTIONS)
    assert cfg["logit_scale"] == pytest.approx(100.0, rel=1e-5)
    assert np.load(folder / "text_embeddings.npy").shape == (33, 16)
    assert check_export(model, folder, batch=3) < 1e-4

    rng = np.random.default_rng(0)
    images = []
    for h, w in [(SIZE, SIZE), (48, 40), (64, 90), (SIZE, SIZE), (37, 33)]:
        base = rng.integers(0, 256, (h // 4 + 1, w // 4 + 1, 3)).astype(np.uint8)
        images.append(np.asarray(Image.fromarray(base).resize((w, h), Image.BILINEAR)))
    ext = ClipFeatureExtractor(folder, batch_size=4)  # batches of 4 and 1
    z = ext.extract(images)
    ref = torch_z(model, tokenizer, images)
    np.testing.assert_allclose(z, ref, atol=1e-5)
    assert z[:, :33].max() > 0.1  # a peaked softmax, not a uniform one
    one = np.array([ext.extract_one(im) for im in images])
    np.testing.assert_allclose(one, z, atol=1e-6)
