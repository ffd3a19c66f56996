"""``pcvfe export-clip``: write an open_clip model into the CLIP folder format.

The command line of ``pcvfe_drake.perception.clip_export`` (the exporter itself). Needs
``torch``, ``open_clip`` and ``onnxscript`` (torch's ONNX exporter; ``pip install
'pcvfe-drake[clip-export]'``) and, for pretrained weights, internet access for open_clip's
download. ``--pretrained none`` builds the same architecture with random weights, which is
enough to verify the export and to time the encoder offline. Nothing else in the project needs
these packages.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pcvfe_drake.perception.clip_export import (
    check_export,
    load_open_clip,
    read_captions,
    write_clip_folder,
)
from pcvfe_drake.perception.features import PROMPT_TEMPLATE
from pcvfe_drake.runs.output_paths import check_output_dir


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "export-clip",
        help="export an open_clip model and caption embeddings to a CLIP folder (needs torch)",
        description=(
            "Export an open_clip image encoder to ONNX (image_encoder.onnx), embed the captions "
            "with its text encoder (text_embeddings.npy) and write clip.json, the folder format "
            "that --clip / ClipFeatures read. Requires torch, open_clip and onnxscript (optional "
            "extra 'clip-export'); pretrained weights are downloaded by open_clip, "
            "--pretrained none uses random weights (export check and timing only)."
        ),
    )
    parser.add_argument("--model", default="ViT-B-32", help="open_clip model name")
    parser.add_argument(
        "--pretrained",
        default="openai",
        help=(
            "open_clip pretrained tag (default: openai; downloaded by open_clip). 'none' gives "
            "random weights of the same architecture, to verify the export and time the "
            "encoder offline; their features mean nothing"
        ),
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument(
        "--captions",
        type=Path,
        default=None,
        help="text file with one caption per line (default: the paper's 33 captions)",
    )
    parser.add_argument("--template", default=PROMPT_TEMPLATE, help="prompt template")
    parser.add_argument(
        "--seed", type=int, default=0, help="seed of the random weights with --pretrained none"
    )
    parser.add_argument("--opset", type=int, default=18, help="ONNX opset (>= 18)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_output_dir(args.out)
    captions = read_captions(args.captions)
    if "{}" not in args.template:
        raise ValueError(f"--template must contain '{{}}', got {args.template!r}")
    model, tokenizer = load_open_clip(args.model, args.pretrained, args.seed)
    random = args.pretrained.lower() in ("none", "random")
    name = f"{args.model}/random-seed{args.seed}" if random else f"{args.model}/{args.pretrained}"
    write_clip_folder(
        model, tokenizer, args.out, name=name, captions=captions, template=args.template,
        opset=args.opset,
    )  # fmt: skip
    err = check_export(model, args.out)
    files = sorted(p.name for p in args.out.iterdir())
    print(f"wrote {args.out}: {', '.join(files)} ({len(captions)} captions)")
    print(f"check: onnxruntime vs torch image embeddings (batch of 3), max relative difference "
          f"{err:.2e}")  # fmt: skip
    if err > 1e-3:
        raise ValueError(f"exported encoder disagrees with torch (relative error {err:.2e})")
    return 0
