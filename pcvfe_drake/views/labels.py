"""Text for the Meshcat layers: text drawn into small RGB images, and what a camera frame shows.

Meshcat has no text primitive that a recording keeps, so text is drawn into an image (OpenCV's
Hershey font) that the layers put on a textured quad.

:class:`FrameCaptioner` turns an information vector z into a short line: for the CLIP backend the
top captions with their scores (z_s is a softmax over the captions), for the texture descriptor
the nearest texture of the library in feature space (the descriptor has no words of its own).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from pcvfe_drake.perception.features import ClipFeatureExtractor, FeatureExtractor
from pcvfe_drake.perception.texture_library import TextureSet


def text_image(
    text: str,
    *,
    height_px: int = 48,
    rgb: tuple[float, float, float] = (1.0, 1.0, 1.0),
    background: tuple[float, float, float] = (0.1, 0.1, 0.1),
    max_chars: int = 48,
) -> np.ndarray:
    """``text`` (one line, cut to ``max_chars``) on a plain background: RGB uint8 (H, W, 3)."""
    if height_px < 8:
        raise ValueError(f"text_image: height_px must be >= 8, got {height_px}")
    text = " ".join(str(text).split())
    if len(text) > max_chars:
        text = text[: max_chars - 3] + "..."
    text = text or " "
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = height_px / 40.0
    thick = max(1, int(round(height_px / 20)))
    (w, h), base = cv2.getTextSize(text, font, scale, thick)
    pad = height_px // 6
    image = np.empty((height_px, w + 2 * pad, 3), np.uint8)
    image[:] = np.round(255 * np.asarray(background)).astype(np.uint8)
    colour = tuple(int(round(255 * c)) for c in rgb)
    y = (height_px + h) // 2 - base // 4
    cv2.putText(image, text, (pad, y), font, scale, colour, thick, cv2.LINE_AA)
    return image


def thumbnail(rgb: np.ndarray, size_px: int = 64) -> np.ndarray:
    """The RGB part of an image (H, W, 3 or 4) shrunk to ``size_px`` square (area averaging)."""
    image = np.asarray(rgb)
    if image.ndim != 3 or image.shape[2] < 3:
        raise ValueError(f"thumbnail: expected an (H, W, 3|4) image, got shape {image.shape}")
    image = np.ascontiguousarray(image[:, :, :3], dtype=np.uint8)
    return cv2.resize(image, (size_px, size_px), interpolation=cv2.INTER_AREA)


class FrameCaptioner:
    """What a frame's information vector says in words (see the module docstring).

    Args:
        extractor: the feature backend that produced z.
        textures: candidate textures for the descriptor backend (name -> RGB uint8 image),
            e.g. the scenario's terrain textures; unused for CLIP.
        top_k: captions shown for CLIP.
    """

    def __init__(
        self,
        extractor: FeatureExtractor,
        textures: dict[str, np.ndarray] | None = None,
        top_k: int = 2,
    ) -> None:
        self.extractor = extractor
        self.top_k = max(1, int(top_k))
        self.captions: list[str] | None = None
        self.names: list[str] = []
        self._ref = np.zeros((0, extractor.dim))
        if isinstance(extractor, ClipFeatureExtractor):
            self.captions = list(extractor.captions)
        elif textures:
            self.names = list(textures)
            self._ref = extractor.extract([thumbnail(im, 224) for im in textures.values()])

    @classmethod
    def for_textures(
        cls, extractor: FeatureExtractor, texture_set: TextureSet, names: Sequence[str]
    ) -> FrameCaptioner:
        """A captioner comparing descriptor frames with the textures ``names`` of a set."""
        return cls(extractor, {n: texture_set.image(n) for n in dict.fromkeys(names)})

    def __call__(self, z: np.ndarray) -> str:
        """One line about the frame whose information vector is ``z`` ("" when z is not finite)."""
        z = np.asarray(z, dtype=float).reshape(-1)
        if z.size != self.extractor.dim or not np.all(np.isfinite(z)):
            return ""
        if self.captions is not None:
            scores = z[: len(self.captions)]
            top = np.argsort(scores)[::-1][: self.top_k]
            return ", ".join(self.captions[i] for i in top)
        if not self.names:
            return ""
        d = np.linalg.norm(self._ref - z, axis=1)
        i = int(np.argmin(d))
        return f"nearest texture: {self.names[i]}"
