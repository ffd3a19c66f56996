"""CLIP backend: cost of everything around the ONNX image encoder.

A CLIP folder with the real input and embedding sizes (224 px, 512-wide embeddings, the paper's
33 captions) but a trivial encoder (mean colour -> linear map) is built in a temporary folder, so
that the time measured is the backend's own work: preprocessing (exact CLIP resize / crop /
normalise), L2 normalisation, cosine similarities, softmax and the mean RGB. Ours
(``ClipFeatureExtractor.extract`` minus its ``encode`` calls) against the straightforward path,
in the same run: Pillow resize and crop per image, numpy normalisation, one cosine per caption in
a Python loop, softmax. Two workloads: 224 x 224 camera frames (no resize needed) and 480 x 640
photos (resize + crop). CPU time of the process.

If torch and open_clip are installed, also exports a ViT-B/32-shaped encoder with random weights
(``pcvfe export-clip --pretrained none``) and times one image and a batch of 10 with
onnxruntime (2 threads), for comparison with the public PC-VFE implementation's 0.708 s per image
(CPU, single image) and 0.086 s per image (batch of 10).

Usage: python benchmarks/features_clip_overhead.py [--quick]
Last stdout line: one JSON object.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

from pcvfe_drake.features import (
    CAPTIONS,
    CLIP_MEAN,
    CLIP_STD,
    ClipFeatureExtractor,
)

S, D = 224, 512
PUBLIC_PCVFE_S_PER_IMAGE = 0.708
PUBLIC_PCVFE_BATCH10_S_PER_IMAGE = 0.086


def write_trivial_clip(folder: Path) -> None:
    """A CLIP-shaped folder whose encoder is ReduceMean over pixels, then a 3 x D matrix."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    x = helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, ["N", 3, S, S])
    y = helper.make_tensor_value_info("image_embeds", TensorProto.FLOAT, ["N", D])
    w = numpy_helper.from_array(rng.standard_normal((3, D)).astype(np.float32), "w")
    axes = numpy_helper.from_array(np.array([2, 3], np.int64), "axes")
    nodes = [
        helper.make_node("ReduceMean", ["pixel_values", "axes"], ["m"], keepdims=0),
        helper.make_node("MatMul", ["m", "w"], ["image_embeds"]),
    ]
    graph = helper.make_graph(nodes, "trivial_clip", [x], [y], [w, axes])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 8
    onnx.save(model, folder / "image_encoder.onnx")
    np.save(folder / "text_embeddings.npy", rng.standard_normal((33, D)).astype(np.float32))
    cfg = {"model": "trivial", "image_size": S, "mean": list(CLIP_MEAN), "std": list(CLIP_STD),
           "logit_scale": 100.0, "captions": list(CAPTIONS)}  # fmt: skip
    (folder / "clip.json").write_text(json.dumps(cfg))


def straightforward_features(images, ext: ClipFeatureExtractor, lambda_c: float = 0.25):
    """The plain way: Pillow per image, numpy normalisation, one cosine per caption."""
    text = ext.text_embeddings.astype(np.float64)
    out = []
    encode_s = 0.0
    for img in images:
        pil = Image.fromarray(img)
        w, h = pil.size
        if w <= h:
            nw, nh = S, int(S * h / w)
        else:
            nh, nw = S, int(S * w / h)
        if (nw, nh) != (w, h):
            pil = pil.resize((nw, nh), Image.BICUBIC)
        top, left = int(round((nh - S) / 2.0)), int(round((nw - S) / 2.0))
        pil = pil.crop((left, top, left + S, top + S))
        arr = np.asarray(pil, dtype=np.float32) / 255.0
        arr = (arr - np.array(CLIP_MEAN, np.float32)) / np.array(CLIP_STD, np.float32)
        pixels = arr.transpose(2, 0, 1)[None].astype(np.float32)
        c0 = time.process_time()
        emb = ext.encode(pixels)[0].astype(np.float64)
        encode_s += time.process_time() - c0
        emb /= np.linalg.norm(emb)
        logits = []
        for row in text:
            logits.append(ext.logit_scale * float(np.dot(emb, row) / np.linalg.norm(row)))
        logits = np.array(logits)
        p = np.exp(logits - logits.max())
        p /= p.sum()
        rgb = np.asarray(img, np.float64).reshape(-1, 3).mean(axis=0) / 255.0
        out.append(np.concatenate([p, lambda_c * rgb]))
    return np.array(out), encode_s


def timed_ours(ext: ClipFeatureExtractor, images, batch: bool):
    """(z, total CPU s, encoder CPU s) of ours, one image per call or batched."""
    encode_s = 0.0
    original = ext.encode

    def counting_encode(pixels):
        nonlocal encode_s
        c0 = time.process_time()
        result = original(pixels)
        encode_s += time.process_time() - c0
        return result

    ext.encode = counting_encode
    try:
        c0 = time.process_time()
        if batch:
            z = ext.extract(images)
        else:
            z = np.array([ext.extract_one(im) for im in images])
        total = time.process_time() - c0
    finally:
        del ext.encode
    return z, total, encode_s


def vit_b32_timing(quick: bool) -> dict:
    if not (importlib.util.find_spec("torch") and importlib.util.find_spec("open_clip")):
        return {"available": False, "reason": "torch and open_clip are not installed"}
    from pcvfe_drake.cli import main as cli_main

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "vitb32"
        code = cli_main(["export-clip", "--model", "ViT-B-32", "--pretrained", "none",
                         "--out", str(folder)])  # fmt: skip
        if code != 0:
            return {"available": False, "reason": f"export-clip failed with code {code}"}
        ext = ClipFeatureExtractor(folder, threads=2)
        rng = np.random.default_rng(1)
        frames = [rng.integers(0, 256, (224, 224, 3), dtype=np.uint8) for _ in range(10)]
        ext.extract(frames[:1])
        reps = 3 if quick else 10
        t0 = time.perf_counter()
        for i in range(reps):
            ext.extract(frames[i % 10 : i % 10 + 1])
        single = (time.perf_counter() - t0) / reps
        t0 = time.perf_counter()
        ext.batch_size = 10
        ext.extract(frames)
        batch10 = (time.perf_counter() - t0) / 10
    return {
        "available": True,
        "wall_s_per_image_single": round(single, 4),
        "wall_s_per_image_batch10": round(batch10, 4),
        "speedup_vs_public_single": round(PUBLIC_PCVFE_S_PER_IMAGE / single, 1),
        "speedup_vs_public_batch10": round(PUBLIC_PCVFE_BATCH10_S_PER_IMAGE / batch10, 1),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer images")
    args = parser.parse_args()
    n = 40 if args.quick else 200
    rng = np.random.default_rng(0)
    from pcvfe_drake.camera import DownwardCamera
    from pcvfe_drake.terrain import default_terrain_map

    cam = DownwardCamera(default_terrain_map())
    xy = rng.uniform([-60, -40], [60, 40], size=(n, 2))
    workloads = {
        "camera_224": [cam.render(x, y, rng.uniform(-np.pi, np.pi)) for x, y in xy],
        "photo_480x640": [
            np.ascontiguousarray(
                np.asarray(Image.fromarray(cam.render(x, y, 0.0)).resize((640, 480)))
            )
            for x, y in xy[: n // 2]
        ],
    }
    result: dict = {"benchmark": "features_clip_overhead", "images": {}}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        write_trivial_clip(folder)
        ext = ClipFeatureExtractor(folder)
        for name, images in workloads.items():
            ext.extract(images[:2])  # warm-up
            z_single, total_single, enc_single = timed_ours(ext, images, batch=False)
            z_batch, total_batch, enc_batch = timed_ours(ext, images, batch=True)
            c0 = time.process_time()
            z_ref, enc_ref = straightforward_features(images, ext)
            total_ref = time.process_time() - c0
            m = len(images)
            ours_single_ms = (total_single - enc_single) / m * 1e3
            ours_batch_ms = (total_batch - enc_batch) / m * 1e3
            ref_ms = (total_ref - enc_ref) / m * 1e3
            err = float(np.abs(z_single - z_ref).max())
            print(f"{name}: overhead per image (CPU) ours {ours_single_ms:.3f} ms single, "
                  f"{ours_batch_ms:.3f} ms batched; straightforward {ref_ms:.3f} ms; "
                  f"max |z difference| {err:.1e}")  # fmt: skip
            assert np.allclose(z_batch, z_single, atol=1e-6)
            result["images"][name] = {
                "count": m,
                "ours_overhead_cpu_ms_single": round(ours_single_ms, 4),
                "ours_overhead_cpu_ms_batched": round(ours_batch_ms, 4),
                "straightforward_overhead_cpu_ms": round(ref_ms, 4),
                "speedup_single": round(ref_ms / ours_single_ms, 1),
                "speedup_batched": round(ref_ms / ours_batch_ms, 1),
                "max_abs_z_difference": err,
            }
    result["vit_b32"] = vit_b32_timing(args.quick)
    print(f"ViT-B/32-shaped encoder: {result['vit_b32']}")
    result["load_average_1min"] = round(os.getloadavg()[0], 2)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
