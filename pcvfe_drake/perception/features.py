"""Terrain information vectors z = concat(z_s, lambda_c * mean RGB) (paper eq. 4).

Two backends share one interface, :class:`FeatureExtractor` (``dim``, ``names``,
``extract(images) -> (N, dim)``), so clustering consumes either:

- :class:`ClipFeatureExtractor`: a CLIP image encoder exported to ONNX plus pre-computed caption
  embeddings (see ``docs/perception.md`` for the folder format). z_s = softmax(logit_scale *
  cosine similarities) to the captions, by default the paper's 33 captions of Appendix A as
  "This image contains {caption}".
- :class:`DescriptorExtractor`: a non-learned texture descriptor (colour statistics in CIELAB,
  multi-scale band-pass energies and gradient structure of the lightness) in place of z_s, for
  machines without CLIP weights (the default pipeline).

Images are RGB uint8 arrays (H, W, 3); RGBA (H, W, 4) is accepted and its alpha ignored. A batch
is an (N, H, W, C) array or a sequence of images. Bad images (wrong shape or dtype, empty, all
black) raise ``ValueError`` naming the image.
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

LAMBDA_C = 0.25  # paper: weight of the low-level (mean RGB) part of z
DESCRIPTOR_BACKEND = "descriptor"
"""Backend name of the non-learned texture descriptor (the scenario's ``features.backend``: this
name or the path of a CLIP model folder)."""
PROMPT_TEMPLATE = "This image contains {}"
# The paper's caption set Q (Appendix A), in its order.
CAPTIONS: tuple[str, ...] = (
    "asphalt", "concrete", "brick", "cobblestone", "tile", "hardwood", "grass", "dirt",
    "gravel", "sand", "mulch", "leaves", "snow", "ice", "metal", "sidewalk", "plastic",
    "ceramic", "granite", "slate", "pavement", "crosswalk", "train track", "boardwalk",
    "astroturf", "wood chips", "paver stones", "carpet", "linoleum", "speckled", "striped",
    "wood", "mud",
)  # fmt: skip
RGB_NAMES = ("mean_r", "mean_g", "mean_b")
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
MIN_IMAGE_SIDE = 16


class BlankImageError(ValueError):
    """An image with no signal at all (all black): a camera failure rather than a bad call."""


def prompts(captions: Sequence[str] = CAPTIONS) -> list[str]:
    """Full caption sentences, "This image contains {caption}"."""
    return [PROMPT_TEMPLATE.format(c) for c in captions]


# --------------------------------------------------------------------------------- inputs
def as_image_batch(images, what: str = "images") -> list[np.ndarray]:
    """Validate images and return a list of RGB uint8 (H, W, 3) C-contiguous arrays: the image
    itself where it is one, else one copy (an RGBA image's RGB through OpenCV, 9 us at 224 px,
    where numpy's strided copy takes 250 us; every later step reads the contiguous copy, a
    strided view cost each of them that much again)."""
    if isinstance(images, np.ndarray):
        if images.ndim == 3:
            batch = [images]
        elif images.ndim == 4:
            batch = list(images)
        else:
            raise ValueError(
                f"{what}: expected an image (H, W, 3) or a batch (N, H, W, 3), got shape "
                f"{images.shape}"
            )
    elif isinstance(images, Sequence) and not isinstance(images, str | bytes):
        batch = list(images)
    else:
        raise ValueError(f"{what}: expected numpy image arrays, got {type(images).__name__}")
    if not batch:
        raise ValueError(f"{what}: the batch is empty")
    out = []
    for i, img in enumerate(batch):
        name = f"{what}[{i}]"
        if not isinstance(img, np.ndarray):
            raise ValueError(f"{name}: expected a numpy array, got {type(img).__name__}")
        if img.dtype != np.uint8:
            raise ValueError(f"{name}: dtype must be uint8 (RGB 0-255), got {img.dtype}")
        if img.ndim != 3 or img.shape[2] not in (3, 4):
            raise ValueError(f"{name}: shape must be (H, W, 3) RGB or (H, W, 4) RGBA, got "
                             f"{img.shape}")  # fmt: skip
        if img.shape[0] < MIN_IMAGE_SIDE or img.shape[1] < MIN_IMAGE_SIDE:
            raise ValueError(
                f"{name}: image is empty or too small ({img.shape[0]}x{img.shape[1]} px, need "
                f">= {MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE})"
            )
        if img.shape[2] == 4 and img.flags.c_contiguous:
            rgb = cv2.cvtColor(img, cv2.COLOR_RGBA2RGB)
        else:
            rgb = np.ascontiguousarray(img[..., :3])
        if not rgb.any():
            raise BlankImageError(f"{name}: image is all black (camera failure or no exposure?)")
        out.append(rgb)
    return out


def mean_rgb(images: list[np.ndarray]) -> np.ndarray:
    """(N, 3) mean colour of each image, RGB in [0, 1]."""
    return np.array([cv2.mean(np.ascontiguousarray(im))[:3] for im in images]) / 255.0


def softmax(x: np.ndarray, axis: int = -1) -> np.ndarray:
    x = x - x.max(axis=axis, keepdims=True)
    e = np.exp(x)
    return e / e.sum(axis=axis, keepdims=True)


class FeatureExtractor(ABC):
    """Common interface of the feature backends."""

    lambda_c: float = LAMBDA_C

    @property
    @abstractmethod
    def semantic_names(self) -> list[str]:
        """Names of the z_s components."""

    @property
    def names(self) -> list[str]:
        """Names of the components of z (z_s first, then the weighted mean RGB)."""
        return [*self.semantic_names, *RGB_NAMES]

    @property
    def dim(self) -> int:
        return len(self.names)

    @abstractmethod
    def semantic(self, images: list[np.ndarray]) -> np.ndarray:
        """(N, len(semantic_names)) z_s of validated RGB images."""

    def extract(self, images) -> np.ndarray:
        """(N, dim) information vectors z = concat(z_s, lambda_c * mean RGB in [0, 1])."""
        batch = as_image_batch(images)
        z_s = self.semantic(batch)
        return np.hstack([z_s, self.lambda_c * mean_rgb(batch)])

    def extract_one(self, image: np.ndarray) -> np.ndarray:
        """(dim,) z of one image."""
        if not isinstance(image, np.ndarray) or image.ndim != 3:
            shape = getattr(image, "shape", None)
            raise ValueError(f"image: expected one (H, W, 3) array, got shape {shape}")
        return self.extract([image])[0]


def _check_lambda(lambda_c: float) -> float:
    if not (np.isfinite(lambda_c) and lambda_c >= 0):
        raise ValueError(f"lambda_c must be a finite number >= 0, got {lambda_c!r}")
    return float(lambda_c)


# --------------------------------------------------------------------------------- descriptor
def percentiles_10_90(values: np.ndarray) -> np.ndarray:
    """``np.percentile(values, (10, 90))`` to the last bit, from one sort: numpy's percentile
    partitions at four places, which costs several times a sort of an image's 10^4 values.
    The same order statistics, blended as numpy's linear method blends them (from the lower
    one below a weight of 0.5, from the upper one from 0.5 on)."""
    ordered = np.sort(values, axis=None)
    at = np.array([0.1, 0.9]) * (ordered.size - 1)
    lo = np.floor(at).astype(np.intp)
    hi = np.minimum(lo + 1, ordered.size - 1)
    a, b = ordered[lo], ordered[hi]
    weight = at - lo
    step = b - a
    return np.where(weight >= 0.5, b - step * (1 - weight), a + step * weight)


class DescriptorExtractor(FeatureExtractor):
    """Non-learned texture descriptor (20 numbers) in place of CLIP's z_s.

    Computed on the image shrunk to ``work_px`` square (area averaging, which also suppresses
    sensor noise), with rotation-invariant measures only:

    - colour in CIELAB (perceptual): mean and standard deviation of L, a, b; 10th and 90th
      percentile of L; mean chroma (9);
    - texture of L: mean absolute response of a 4-octave Laplacian pyramid, as log energies
      (4); the same for the chroma channels a, b in the two finest octaves (2);
    - gradient structure of L at half resolution: mean gradient magnitude, fraction of strong
      edges, and orientation coherence of the structure tensor at two integration scales (4);
    - the fraction of very dark pixels (cracks, joints, gaps; 1).

    Each entry is scaled by a fixed constant so that all are of order 0.1-1.
    """

    def __init__(self, lambda_c: float = LAMBDA_C, work_px: int = 112) -> None:
        self.lambda_c = _check_lambda(lambda_c)
        if work_px < 32:
            raise ValueError(f"work_px must be >= 32, got {work_px}")
        self.work_px = int(work_px)

    _NAMES = (
        "L_mean", "a_mean", "b_mean", "L_std", "a_std", "b_std", "L_p10", "L_p90", "chroma",
        "band1", "band2", "band4", "band8", "ab_band1", "ab_band2",
        "grad_mag", "edge_frac", "coherence_fine", "coherence_coarse", "dark_frac",
    )  # fmt: skip

    @property
    def semantic_names(self) -> list[str]:
        return list(self._NAMES)

    def semantic(self, images: list[np.ndarray]) -> np.ndarray:
        return np.array([self._describe(im) for im in images])

    def _describe(self, rgb: np.ndarray) -> np.ndarray:
        n = self.work_px
        small = cv2.resize(np.ascontiguousarray(rgb), (n, n), interpolation=cv2.INTER_AREA)
        lab = cv2.cvtColor(small.astype(np.float32) * np.float32(1 / 255), cv2.COLOR_RGB2Lab)
        L = np.ascontiguousarray(lab[..., 0])
        ab = np.ascontiguousarray(lab[..., 1:])
        a, b = ab[..., 0], ab[..., 1]
        p10, p90 = percentiles_10_90(L)
        chroma = np.sqrt(a * a + b * b)
        colour = [
            L.mean() / 100, a.mean() / 20, b.mean() / 20, L.std() / 25, a.std() / 10,
            b.std() / 10, p10 / 100, p90 / 100, chroma.mean() / 20,
        ]  # fmt: skip
        # Laplacian pyramid of L: mean absolute band energy per octave (isotropic filters)
        levels = [L]
        for _ in range(4):
            levels.append(cv2.pyrDown(levels[-1]))
        bands = []
        for fine, coarse in zip(levels[:-1], levels[1:], strict=True):
            up = cv2.pyrUp(coarse, dstsize=(fine.shape[1], fine.shape[0]))
            bands.append(np.log1p(cv2.norm(fine, up, cv2.NORM_L1) / fine.size) / 3)
        ab1 = cv2.pyrDown(ab)
        ab_up = cv2.pyrUp(ab1, dstsize=(n, n))
        ab2 = cv2.pyrDown(ab1)
        ab2_up = cv2.pyrUp(ab2, dstsize=(ab1.shape[1], ab1.shape[0]))
        ab_bands = [
            np.log1p(cv2.norm(ab, ab_up, cv2.NORM_L1) / ab.size) / 2,
            np.log1p(cv2.norm(ab1, ab2_up, cv2.NORM_L1) / ab1.size) / 2,
        ]
        # gradient structure on the half-resolution level (less sensor noise)
        g = levels[1]
        gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8
        gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8
        mag = cv2.magnitude(gx, gy)
        tensor = cv2.merge([gx * gx, gy * gy, gx * gy])
        coh = []
        for s in (1.5, 4.0):
            j = cv2.GaussianBlur(tensor, (0, 0), s)
            jxx, jyy, jxy = j[..., 0], j[..., 1], j[..., 2]
            num = np.sqrt((jxx - jyy) ** 2 + 4 * jxy**2)
            coh.append(float(num.sum() / max(float((jxx + jyy).sum()), 1e-9)))
        gradient = [np.log1p(mag.mean()) / 2, float((mag > 4.0).mean()), *coh]
        dark = [float((L < 20).mean())]
        return np.array(colour + bands + ab_bands + gradient + dark, dtype=float)


# --------------------------------------------------------------------------------- CLIP
def resize_bicubic_pil(rgb: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize RGB uint8 with Pillow's antialiased bicubic filter, the resize CLIP's own
    preprocessing uses (torchvision ``Resize`` on a PIL image), so the pixels match it exactly."""
    from PIL import Image

    resized = Image.fromarray(np.ascontiguousarray(rgb)).resize(
        (int(width), int(height)), Image.Resampling.BICUBIC
    )
    return np.asarray(resized)


@lru_cache(maxsize=8)
def _normalise_lut(mean: tuple[float, ...], std: tuple[float, ...]) -> np.ndarray:
    """(3, 256) float32: (v / 255 - mean[c]) / std[c] for every 8-bit value v."""
    v = np.arange(256, dtype=np.float32) * np.float32(1 / 255)
    m = np.asarray(mean, np.float32)[:, None]
    s = np.asarray(std, np.float32)[:, None]
    return (v[None, :] - m) / s


def clip_preprocess(
    images: list[np.ndarray],
    size: int,
    mean: Sequence[float] = CLIP_MEAN,
    std: Sequence[float] = CLIP_STD,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """CLIP's preprocessing, exactly: resize the short side to ``size`` (Pillow bicubic),
    centre crop ``size`` x ``size`` (torchvision's rounding), RGB / 255, normalise by mean and
    std (through a per-channel look-up table of the 256 values). Returns float32
    (N, 3, size, size), written into ``out[:N]`` when given (a reusable buffer)."""
    if out is None:
        out = np.empty((len(images), 3, size, size), np.float32)
    else:
        out = out[: len(images)]
    lut = _normalise_lut(tuple(float(v) for v in mean), tuple(float(v) for v in std))
    for i, img in enumerate(images):
        h, w = img.shape[:2]
        if (h, w) != (size, size):
            if w <= h:
                new_w, new_h = size, int(size * h / w)
            else:
                new_h, new_w = size, int(size * w / h)
            img = resize_bicubic_pil(img, new_w, new_h)
            top = int(round((new_h - size) / 2.0))
            left = int(round((new_w - size) / 2.0))
            img = img[top : top + size, left : left + size]
        for c in range(3):
            np.take(lut[c], img[:, :, c], out=out[i, c])
    return out


class ClipFeatureExtractor(FeatureExtractor):
    """CLIP backend reading a model folder (``image_encoder.onnx``, ``text_embeddings.npy``,
    ``clip.json``; see ``docs/perception.md``).

    Args:
        folder: the model folder.
        lambda_c: weight of the mean-RGB part of z (paper: 0.25).
        threads: onnxruntime intra-op threads (default 2: this project's target machine).
        batch_size: images per encoder call in ``extract``.
    """

    CONFIG = "clip.json"
    ENCODER = "image_encoder.onnx"
    EMBEDDINGS = "text_embeddings.npy"

    def __init__(
        self,
        folder: Path | str,
        lambda_c: float = LAMBDA_C,
        threads: int = 2,
        batch_size: int = 16,
    ) -> None:
        self.lambda_c = _check_lambda(lambda_c)
        self.folder = Path(folder)
        if self.folder.exists() and not self.folder.is_dir():
            hint = (
                f"; use its folder {self.folder.parent}" if self.folder.name == "clip.json" else ""
            )
            raise ValueError(
                f"CLIP model folder {self.folder} is a file; give the folder that holds clip.json "
                f"and image_encoder.onnx (docs/perception.md){hint}"
            )
        if not self.folder.is_dir():
            raise FileNotFoundError(f"CLIP model folder {self.folder} does not exist")
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.batch_size = int(batch_size)
        cfg = self._read_config(self.folder / self.CONFIG)
        self.model_name: str = cfg["model"]
        self.image_size: int = cfg["image_size"]
        self.mean = tuple(cfg["mean"])
        self.std = tuple(cfg["std"])
        self.logit_scale: float = cfg["logit_scale"]
        self.captions: list[str] = cfg["captions"]
        self.text_embeddings = self._read_embeddings(self.folder / self.EMBEDDINGS)
        self._buffer: np.ndarray | None = None
        self.threads = int(threads)
        """onnxruntime intra-op threads of the image encoder session."""
        self._session, self._input_name = self._open_session(self.folder / self.ENCODER, threads)

    # ------------------------------------------------------------------ loading
    def _read_config(self, path: Path) -> dict:
        if not path.is_file():
            raise FileNotFoundError(f"CLIP config {path} does not exist")
        try:
            cfg = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"CLIP config {path} is not valid JSON: {exc}") from exc
        required = ("model", "image_size", "mean", "std", "logit_scale", "captions")
        missing = [k for k in required if not isinstance(cfg, dict) or k not in cfg]
        if missing:
            raise ValueError(f"CLIP config {path} lacks {missing}")
        try:
            cfg["image_size"] = int(cfg["image_size"])
            cfg["logit_scale"] = float(cfg["logit_scale"])
            cfg["mean"] = [float(v) for v in cfg["mean"]]
            cfg["std"] = [float(v) for v in cfg["std"]]
        except (TypeError, ValueError) as exc:
            raise ValueError(f"CLIP config {path}: bad number ({exc})") from exc
        if cfg["image_size"] < MIN_IMAGE_SIDE:
            raise ValueError(f"CLIP config {path}: image_size {cfg['image_size']} too small")
        if len(cfg["mean"]) != 3 or len(cfg["std"]) != 3 or min(cfg["std"]) <= 0:
            raise ValueError(f"CLIP config {path}: mean and std need 3 values, std > 0")
        if not (np.isfinite(cfg["logit_scale"]) and cfg["logit_scale"] > 0):
            raise ValueError(f"CLIP config {path}: logit_scale must be > 0")
        caps = cfg["captions"]
        if not isinstance(caps, list) or not caps or not all(isinstance(c, str) for c in caps):
            raise ValueError(f"CLIP config {path}: captions must be a non-empty list of strings")
        return cfg

    def _read_embeddings(self, path: Path) -> np.ndarray:
        if not path.is_file():
            raise FileNotFoundError(f"CLIP caption embeddings {path} do not exist")
        try:
            emb = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise ValueError(f"CLIP caption embeddings {path} could not be read: {exc}") from exc
        if emb.ndim != 2 or not np.issubdtype(emb.dtype, np.floating):
            raise ValueError(
                f"CLIP caption embeddings {path}: expected a float (K, D) array, got "
                f"{emb.dtype} {emb.shape}"
            )
        if emb.shape[0] != len(self.captions):
            raise ValueError(
                f"CLIP caption embeddings {path} have {emb.shape[0]} rows but {self.CONFIG} "
                f"lists {len(self.captions)} captions"
            )
        if not np.all(np.isfinite(emb)):
            raise ValueError(f"CLIP caption embeddings {path} contain NaN or inf")
        norms = np.linalg.norm(emb, axis=1, keepdims=True)
        if np.any(norms == 0):
            raise ValueError(f"CLIP caption embeddings {path} contain an all-zero row")
        return (emb / norms).astype(np.float32)

    def _open_session(self, path: Path, threads: int):
        import onnxruntime as ort

        if not path.is_file():
            raise FileNotFoundError(f"CLIP image encoder {path} does not exist")
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(threads)
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        try:
            session = ort.InferenceSession(
                str(path), sess_options=options, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ValueError(f"CLIP image encoder {path} could not be loaded: {exc}") from exc
        inputs, outputs = session.get_inputs(), session.get_outputs()
        if len(inputs) != 1 or len(outputs) < 1:
            raise ValueError(
                f"CLIP image encoder {path} must have one input and an output, has "
                f"{len(inputs)} inputs and {len(outputs)} outputs"
            )
        shape = list(inputs[0].shape)
        s = self.image_size
        if len(shape) != 4 or any(
            isinstance(d, int) and d != want for d, want in zip(shape[1:], (3, s, s), strict=True)
        ):
            raise ValueError(
                f"CLIP image encoder {path}: input shape {shape} does not match "
                f"(N, 3, {s}, {s}) from {self.CONFIG}"
            )
        out_shape = list(outputs[0].shape)
        d = self.text_embeddings.shape[1]
        if len(out_shape) != 2 or (isinstance(out_shape[1], int) and out_shape[1] != d):
            raise ValueError(
                f"CLIP image encoder {path}: output shape {out_shape} does not match the caption "
                f"embedding width {d} of {self.EMBEDDINGS}"
            )
        return session, inputs[0].name

    # ------------------------------------------------------------------ features
    @property
    def semantic_names(self) -> list[str]:
        return list(self.captions)

    def preprocess(self, images: list[np.ndarray]) -> np.ndarray:
        """(N, 3, S, S) float32 encoder input. Batches of up to ``batch_size`` images are
        written into one reused buffer (a fresh multi-megabyte array per call costs more than
        the preprocessing itself); the result is valid until the next call."""
        n = len(images)
        if n > self.batch_size:
            return clip_preprocess(images, self.image_size, self.mean, self.std)
        if self._buffer is None or self._buffer.shape[0] < n:
            s = self.image_size
            self._buffer = np.empty((max(n, self.batch_size), 3, s, s), np.float32)
        return clip_preprocess(images, self.image_size, self.mean, self.std, out=self._buffer)

    def encode(self, pixels: np.ndarray) -> np.ndarray:
        """Image embeddings (N, D) of preprocessed pixels, unnormalised."""
        emb = self._session.run(None, {self._input_name: pixels})[0]
        d = self.text_embeddings.shape[1]
        if emb.ndim != 2 or emb.shape != (pixels.shape[0], d):
            raise ValueError(
                f"CLIP image encoder {self.folder / self.ENCODER} returned shape {emb.shape}, "
                f"expected ({pixels.shape[0]}, {d}) to match {self.EMBEDDINGS}"
            )
        return emb

    def similarities_to_probabilities(self, emb: np.ndarray) -> np.ndarray:
        """z_s = softmax(logit_scale * cos(image, caption)) for (N, D) image embeddings."""
        emb = emb.astype(np.float32)
        norms = np.linalg.norm(emb, axis=1, keepdims=True)
        if np.any(norms == 0) or not np.all(np.isfinite(emb)):
            raise ValueError("CLIP image encoder produced a zero or non-finite embedding")
        cos = (emb / norms) @ self.text_embeddings.T
        return softmax(self.logit_scale * cos.astype(np.float64), axis=1)

    def semantic(self, images: list[np.ndarray]) -> np.ndarray:
        parts = []
        for i in range(0, len(images), self.batch_size):
            pixels = self.preprocess(images[i : i + self.batch_size])
            parts.append(self.similarities_to_probabilities(self.encode(pixels)))
        return np.vstack(parts)

    def top_captions(self, z: np.ndarray, k: int = 3) -> list[tuple[str, float]]:
        """The k captions with the largest probability in one z (or z_s)."""
        z_s = np.asarray(z)[: len(self.captions)]
        order = np.argsort(-z_s)[:k]
        return [(self.captions[j], float(z_s[j])) for j in order]


def make_extractor(
    backend: str = DESCRIPTOR_BACKEND,
    clip_dir: Path | str | None = None,
    lambda_c: float = LAMBDA_C,
    threads: int = 2,
) -> FeatureExtractor:
    """Backend by name: ``"descriptor"`` or ``"clip"`` (needs ``clip_dir``; ``threads`` is the
    onnxruntime intra-op thread count, 1 is the safer choice on a loaded 2-core machine)."""
    if backend == DESCRIPTOR_BACKEND:
        return DescriptorExtractor(lambda_c=lambda_c)
    if backend == "clip":
        if clip_dir is None:
            raise ValueError("the clip backend needs a model folder (clip_dir)")
        return ClipFeatureExtractor(clip_dir, lambda_c=lambda_c, threads=threads)
    raise ValueError(f"unknown feature backend {backend!r}; use 'descriptor' or 'clip'")
