"""``pcvfe export-clip``: write an open_clip model into the CLIP folder format.

Needs ``torch`` and ``open_clip`` (``pip install 'pcvfe-drake[clip-export]'``) and, for
pretrained weights, internet access for open_clip's download. Nothing else in the project
needs them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pcvfe_drake.features import CAPTIONS, CLIP_MEAN, CLIP_STD, PROMPT_TEMPLATE

INSTALL_HINT = (
    "pcvfe export-clip needs torch and open_clip, which this environment lacks; install them "
    "with: pip install 'pcvfe-drake[clip-export]' (or pip install open-clip-torch)"
)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "export-clip",
        help="export an open_clip model and caption embeddings to a CLIP folder (needs torch)",
        description=(
            "Export an open_clip image encoder to ONNX (image_encoder.onnx), embed the captions "
            "with its text encoder (text_embeddings.npy) and write clip.json, the folder format "
            "that --clip / ClipFeatures read. Requires torch and open_clip (optional extra "
            "'clip-export'); pretrained weights are downloaded by open_clip."
        ),
    )
    parser.add_argument("--model", default="ViT-B-32", help="open_clip model name")
    parser.add_argument(
        "--pretrained",
        default="openai",
        help="open_clip pretrained tag; 'none' for random weights (timing only)",
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument(
        "--captions",
        type=Path,
        default=None,
        help="text file with one caption per line (default: the paper's 33 captions)",
    )
    parser.add_argument("--template", default=PROMPT_TEMPLATE, help="prompt template")
    parser.add_argument("--opset", type=int, default=17, help="ONNX opset")
    parser.set_defaults(func=run)


def read_captions(path: Path | None) -> list[str]:
    if path is None:
        return list(CAPTIONS)
    if not path.is_file():
        raise FileNotFoundError(f"caption file {path} does not exist")
    captions = [line.strip() for line in path.read_text().splitlines() if line.strip()]
    if not captions:
        raise ValueError(f"caption file {path} has no captions")
    return captions


def run(args: argparse.Namespace) -> int:
    captions = read_captions(args.captions)
    if "{}" not in args.template:
        raise ValueError(f"--template must contain '{{}}', got {args.template!r}")
    try:
        import open_clip
        import torch
    except ImportError as exc:
        raise ValueError(f"{INSTALL_HINT} ({exc})") from exc

    pretrained = None if args.pretrained.lower() == "none" else args.pretrained
    model, _, _ = open_clip.create_model_and_transforms(args.model, pretrained=pretrained)
    model.eval()
    cfg = dict(getattr(model.visual, "preprocess_cfg", {}) or {})
    size = cfg.get("size", getattr(model.visual, "image_size", 224))
    size = int(size[0] if isinstance(size, list | tuple) else size)
    mean = [float(v) for v in cfg.get("mean", CLIP_MEAN)]
    std = [float(v) for v in cfg.get("std", CLIP_STD)]
    for key, expected in (("interpolation", "bicubic"), ("resize_mode", "shortest")):
        if cfg.get(key, expected) != expected:
            print(
                f"warning: {args.model} uses {key}={cfg[key]!r}; pcvfe_drake preprocesses with "
                f"{expected} (shortest side, centre crop), so features may differ slightly"
            )

    tokenizer = open_clip.get_tokenizer(args.model)
    sentences = [args.template.format(c) for c in captions]
    with torch.no_grad():
        text = model.encode_text(tokenizer(sentences)).float().numpy()
        logit_scale = float(model.logit_scale.exp().item())

    class ImageEncoder(torch.nn.Module):
        def __init__(self, clip_model):
            super().__init__()
            self.clip_model = clip_model

        def forward(self, pixel_values):
            return self.clip_model.encode_image(pixel_values)

    args.out.mkdir(parents=True, exist_ok=True)
    dummy = torch.zeros(1, 3, size, size)
    onnx_path = args.out / "image_encoder.onnx"
    torch.onnx.export(
        ImageEncoder(model),
        (dummy,),
        str(onnx_path),
        input_names=["pixel_values"],
        output_names=["image_embeds"],
        dynamic_axes={"pixel_values": {0: "N"}, "image_embeds": {0: "N"}},
        opset_version=args.opset,
    )
    np.save(args.out / "text_embeddings.npy", text.astype(np.float32))
    config = {
        "model": f"{args.model}/{pretrained or 'random'}",
        "image_size": size,
        "mean": mean,
        "std": std,
        "logit_scale": logit_scale,
        "captions": captions,
        "prompt_template": args.template,
    }
    (args.out / "clip.json").write_text(json.dumps(config, indent=1) + "\n")

    # Check the export: onnxruntime and torch agree on one image.
    from pcvfe_drake.features import ClipFeatureExtractor

    extractor = ClipFeatureExtractor(args.out)
    rng = np.random.default_rng(0)
    pixels = rng.standard_normal((1, 3, size, size)).astype(np.float32)
    with torch.no_grad():
        ref = model.encode_image(torch.from_numpy(pixels)).float().numpy()
    got = extractor.encode(pixels)
    err = float(np.abs(got - ref).max() / max(np.abs(ref).max(), 1e-12))
    print(f"wrote {onnx_path}, text_embeddings.npy ({text.shape[0]} x {text.shape[1]}), clip.json")
    print(f"check: onnxruntime vs torch image embedding, max relative difference {err:.2e}")
    if err > 1e-3:
        raise ValueError(f"exported encoder disagrees with torch (relative error {err:.2e})")
    return 0
