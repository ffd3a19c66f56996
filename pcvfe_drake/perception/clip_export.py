"""Export an open_clip model into the CLIP folder format that ``ClipFeatureExtractor`` reads.

The folder holds ``image_encoder.onnx`` (the image tower, dynamic batch), ``text_embeddings.npy``
(the caption sentences through the text tower) and ``clip.json`` (preprocessing, captions,
logit scale); see ``docs/perception.md``. Needs ``torch``, ``open_clip`` and ``onnxscript``
(torch's ONNX exporter; the optional extra ``clip-export``), imported only when called: nothing
else in the project needs them. ``pcvfe export-clip`` (``pcvfe_drake.commands.export_clip``) is
the command line of this module.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pcvfe_drake.perception.features import (
    CAPTIONS,
    CLIP_MEAN,
    CLIP_STD,
    PROMPT_TEMPLATE,
    ClipFeatureExtractor,
)

INSTALL_HINT = (
    "pcvfe export-clip needs torch and open_clip (and onnxscript, for torch's ONNX exporter), "
    "which this environment lacks; install them with: pip install 'pcvfe-drake[clip-export]' "
    "(or pip install open-clip-torch onnxscript)"
)


def read_captions(path: Path | None) -> list[str]:
    if path is None:
        return list(CAPTIONS)
    if not path.is_file():
        raise FileNotFoundError(f"caption file {path} does not exist")
    captions = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    if not captions:
        raise ValueError(f"caption file {path} has no captions")
    return captions


def _square_size(cfg: dict, visual, model_name: str) -> int:
    size = cfg.get("size", getattr(visual, "image_size", 224))
    if isinstance(size, list | tuple):
        if len(set(int(v) for v in size)) != 1:
            raise ValueError(f"{model_name}: non-square input size {tuple(size)} is not supported")
        size = size[0]
    return int(size)


def import_export_deps():
    """(open_clip, torch), or ValueError with the install hint when they are missing."""
    try:
        import onnxscript  # noqa: F401  (torch's ONNX exporter needs it)
        import open_clip
        import torch
    except ImportError as exc:
        raise ValueError(f"{INSTALL_HINT} ({exc})") from exc
    return open_clip, torch


def load_open_clip(model_name: str, pretrained: str | None, seed: int = 0):
    """(model in eval mode, tokenizer) from open_clip.

    The activation follows the pretrained tag: OpenAI's weights (and some others) were trained
    with QuickGELU, which open_clip's plain model names (``ViT-B-32``) do not use unless told;
    loading them into a GELU model only warns and gives worse features. ``pretrained=None``
    (or "none") builds the architecture that ``--pretrained openai`` would export, with random
    weights drawn after ``torch.manual_seed(seed)`` (the same seed gives the same weights).
    """
    open_clip, torch = import_export_deps()
    if pretrained is not None and pretrained.lower() in ("none", "random"):
        pretrained = None
    tag = pretrained if pretrained is not None else "openai"
    tag_cfg = open_clip.get_pretrained_cfg(model_name, tag) or {}
    quick_gelu = bool(tag_cfg.get("quick_gelu", False))
    if pretrained is None:
        torch.manual_seed(int(seed))
    model = open_clip.create_model(model_name, pretrained=pretrained, force_quick_gelu=quick_gelu)
    model.eval()
    return model, open_clip.get_tokenizer(model_name)


def export_image_encoder(model, size: int, path: Path, opset: int = 18) -> None:
    """Write ``model.encode_image`` to ONNX at ``path`` with a dynamic batch dimension.

    Uses torch's ``torch.export``-based exporter (needs ``onnxscript``). The example batch has
    two images: ``torch.export`` specialises dimensions of size 1, so a batch-1 example would
    fix the batch at 1. Weights are stored inside the ``.onnx`` file unless they exceed about
    1.5 GiB (protobuf's 2 GiB limit), in which case they go to ``<path>.data`` beside it.
    """
    import torch

    class ImageEncoder(torch.nn.Module):
        def __init__(self, clip_model):
            super().__init__()
            self.clip_model = clip_model

        def forward(self, pixel_values):
            return self.clip_model.encode_image(pixel_values)

    if opset < 18:
        raise ValueError(f"--opset must be >= 18 for torch's exporter, got {opset}")
    encoder = ImageEncoder(model).eval()
    weight_bytes = sum(p.numel() * p.element_size() for p in model.visual.parameters())
    external = weight_bytes > 1.5 * 2**30
    stale = path.with_name(path.name + ".data")
    if stale.exists():
        stale.unlink()
    example = torch.zeros(2, 3, size, size)
    batch = torch.export.Dim("N", min=1, max=4096)
    with torch.no_grad():
        torch.onnx.export(
            encoder,
            (example,),
            str(path),
            input_names=["pixel_values"],
            output_names=["image_embeds"],
            dynamo=True,
            dynamic_shapes={"pixel_values": {0: batch}},
            opset_version=opset,
            external_data=external,
        )


def write_clip_folder(
    model,
    tokenizer,
    out: Path,
    *,
    name: str,
    captions: list[str] | None = None,
    template: str = PROMPT_TEMPLATE,
    opset: int = 18,
) -> dict:
    """Export ``model`` (an open_clip CLIP in eval mode) into the CLIP folder ``out``:
    ``image_encoder.onnx``, ``text_embeddings.npy`` (the caption sentences through the text
    tower, unnormalised) and ``clip.json`` (from the model's preprocessing configuration).
    Returns the ``clip.json`` content."""
    import torch

    captions = list(CAPTIONS) if captions is None else list(captions)
    if "{}" not in template:
        raise ValueError(f"--template must contain '{{}}', got {template!r}")
    cfg = dict(getattr(model.visual, "preprocess_cfg", {}) or {})
    size = _square_size(cfg, model.visual, name)
    mean = [float(v) for v in cfg.get("mean", CLIP_MEAN)]
    std = [float(v) for v in cfg.get("std", CLIP_STD)]
    for key, expected in (("interpolation", "bicubic"), ("resize_mode", "shortest")):
        if cfg.get(key, expected) != expected:
            print(
                f"warning: {name} uses {key}={cfg[key]!r}; pcvfe_drake preprocesses with "
                f"{expected} (shortest side, centre crop), so features may differ slightly"
            )
    sentences = [template.format(c) for c in captions]
    with torch.no_grad():
        text = model.encode_text(tokenizer(sentences)).float().numpy()
        logit_scale = float(model.logit_scale.exp().item())
    out.mkdir(parents=True, exist_ok=True)
    export_image_encoder(model, size, out / "image_encoder.onnx", opset)
    np.save(out / "text_embeddings.npy", text.astype(np.float32))
    config = {
        "model": name,
        "image_size": size,
        "mean": mean,
        "std": std,
        "logit_scale": logit_scale,
        "captions": captions,
        "prompt_template": template,
    }
    (out / "clip.json").write_text(json.dumps(config, indent=1) + "\n")
    return config


def check_export(model, folder: Path, batch: int = 3, seed: int = 0) -> float:
    """Max relative difference between onnxruntime (through ``ClipFeatureExtractor``) and
    torch image embeddings on a batch of random inputs (a batch dimension fixed at export time
    fails here)."""
    import torch

    extractor = ClipFeatureExtractor(folder)
    s = extractor.image_size
    pixels = np.random.default_rng(seed).standard_normal((batch, 3, s, s)).astype(np.float32)
    with torch.no_grad():
        ref = model.encode_image(torch.from_numpy(pixels)).float().numpy()
    got = extractor.encode(pixels)
    return float(np.abs(got - ref).max() / max(np.abs(ref).max(), 1e-12))
