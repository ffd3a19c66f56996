"""``pcvfe features``: print the information vector z of images (what the extractor sees)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pcvfe_drake.perception.features import (
    DESCRIPTOR_BACKEND,
    LAMBDA_C,
    ClipFeatureExtractor,
    make_extractor,
)
from pcvfe_drake.perception.texture_library import load_rgb


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "features",
        help="print the feature vector z of images (CLIP or descriptor backend)",
        description=(
            "Compute z = concat(z_s, lambda_c * mean RGB) (paper eq. 4) for each image and print "
            "it: for a CLIP model folder the top captions and their probabilities, for the "
            "descriptor backend every named component. --json prints one JSON object with all "
            "numbers instead."
        ),
    )
    parser.add_argument("images", nargs="+", type=Path, metavar="IMAGE", help="image files")
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--clip", type=Path, metavar="DIR", help="CLIP model folder (see docs/perception.md)"
    )
    group.add_argument(
        "--backend",
        choices=[DESCRIPTOR_BACKEND],
        default=DESCRIPTOR_BACKEND,
        help="non-learned texture descriptor (the default when --clip is not given)",
    )
    parser.add_argument(
        "--lambda-c", type=float, default=LAMBDA_C, help="weight of the mean RGB (paper: 0.25)"
    )
    parser.add_argument("--top", type=int, default=5, help="captions to show for CLIP")
    parser.add_argument("--json", action="store_true", help="print JSON instead of text")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.top < 1:
        raise ValueError(f"--top must be >= 1, got {args.top}")
    backend = "clip" if args.clip is not None else args.backend
    extractor = make_extractor(backend, clip_dir=args.clip, lambda_c=args.lambda_c)
    images = [load_rgb(path) for path in args.images]
    try:
        z = extractor.extract(images)
    except ValueError as exc:  # "images[k]: ..." from the extractor: name the file
        text = str(exc)
        for k, path in enumerate(args.images):
            if text.startswith(f"images[{k}]:"):
                raise ValueError(f"image {path}:{text[len(f'images[{k}]:') :]}") from exc
        raise
    is_clip = isinstance(extractor, ClipFeatureExtractor)
    if args.json:
        out = {
            "backend": backend,
            "model": extractor.model_name if is_clip else DESCRIPTOR_BACKEND,
            "lambda_c": extractor.lambda_c,
            "names": extractor.names,
            "images": [],
        }
        for path, zi in zip(args.images, z, strict=True):
            entry = {"image": str(path), "z": [float(v) for v in zi]}
            if is_clip:
                entry["top"] = [[c, p] for c, p in extractor.top_captions(zi, args.top)]
            out["images"].append(entry)
        print(json.dumps(out, indent=1))
        return 0
    print(f"backend: {backend} ({extractor.dim} numbers, lambda_c = {extractor.lambda_c:g})")
    for path, zi in zip(args.images, z, strict=True):
        print(f"\n{path}:")
        if is_clip:
            for caption, p in extractor.top_captions(zi, args.top):
                print(f"  {p:7.4f}  {caption}")
        else:
            for name, value in zip(extractor.names[:-3], zi[:-3], strict=True):
                print(f"  {name:18s} {value:9.4f}")
        rgb = np.asarray(zi[-3:]) / max(extractor.lambda_c, 1e-12)
        print(f"  mean RGB [0-1]     {rgb[0]:.3f} {rgb[1]:.3f} {rgb[2]:.3f}")
    return 0
