"""Terrain textures: find the ``textures/`` folder, read its index, load images (RGB uint8).

The folder holds tileable PNG images and ``index.yaml``::

    textures:
      - name: patchy_grass        # unique name, used by Terrain.texture
        file: patchy_grass.png    # RGB PNG, square, tileable (wraps seamlessly)
        mu: 0.3                   # default true friction coefficient [-]
        tile_m: 2.0               # world size of one tile [m]
        provenance: ...           # where the pixels come from
        method: ...               # how the image was made (textures/make_textures.py)

Search order for the folder: the ``PCVFE_TEXTURES_DIR`` environment variable, ``textures/``
installed inside the ``pcvfe_drake`` package, then ``textures/`` at the repository root (an
editable install or a source checkout).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

INDEX_FILE = "index.yaml"
ENV_VAR = "PCVFE_TEXTURES_DIR"


def textures_dir() -> Path:
    """The folder with the terrain textures and ``index.yaml`` (see the module docstring)."""
    candidates: list[Path] = []
    if os.environ.get(ENV_VAR):
        candidates.append(Path(os.environ[ENV_VAR]))
    package_dir = Path(__file__).resolve().parents[1]
    candidates += [package_dir / "textures", package_dir.parent / "textures"]
    for folder in candidates:
        if (folder / INDEX_FILE).is_file():
            return folder
    raise FileNotFoundError(
        "no terrain texture folder with index.yaml found; looked in "
        + ", ".join(str(c) for c in candidates)
        + f" (set {ENV_VAR} to the folder)"
    )


@dataclass(frozen=True)
class TextureEntry:
    """One row of ``index.yaml``."""

    name: str
    file: str
    mu: float
    tile_m: float
    provenance: str = ""
    method: str = ""


def read_index(folder: Path | str) -> list[TextureEntry]:
    """Parse and check ``folder/index.yaml``."""
    path = Path(folder) / INDEX_FILE
    if not path.is_file():
        raise FileNotFoundError(f"texture index {path} does not exist")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"texture index {path} is not valid YAML: {exc}") from exc
    rows = data.get("textures") if isinstance(data, dict) else None
    if not isinstance(rows, list) or not rows:
        raise ValueError(f"texture index {path} needs a non-empty 'textures' list")
    entries = []
    for i, row in enumerate(rows):
        try:
            entry = TextureEntry(
                name=str(row["name"]),
                file=str(row["file"]),
                mu=float(row["mu"]),
                tile_m=float(row["tile_m"]),
                provenance=str(row.get("provenance", "")),
                method=str(row.get("method", "")),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"texture index {path}: entry {i} is malformed ({exc!r})") from exc
        if not entry.tile_m > 0:
            raise ValueError(f"texture index {path}: {entry.name} has tile_m {entry.tile_m}")
        entries.append(entry)
    names = [e.name for e in entries]
    if len(set(names)) != len(names):
        raise ValueError(f"texture index {path}: duplicate names in {names}")
    return entries


def load_rgb(path: Path | str) -> np.ndarray:
    """Read an image file as RGB uint8 (H, W, 3); clear error if missing or unreadable."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(
            f"image {path} is a folder, not an image file; name the image files (e.g. {path}/*.png)"
        )
    if not path.is_file():
        raise FileNotFoundError(f"image {path} does not exist")
    try:
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    except cv2.error as exc:  # OpenCV refuses a header that claims too many pixels
        raise ValueError(
            f"image {path} could not be decoded: its size is beyond OpenCV's limit "
            f"({exc.err or 'too many pixels'})"
        ) from exc
    if bgr is None:
        raise ValueError(f"image {path} could not be decoded")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


class TextureSet:
    """Texture images (RGB uint8, loaded lazily and cached) with their world tile size.

    ``TextureSet()`` reads the packaged folder; ``TextureSet(folder)`` another one;
    ``TextureSet.from_arrays({name: (image, tile_m)})`` builds one in memory (tests, tools).
    """

    def __init__(self, folder: Path | str | None = None) -> None:
        self.folder = Path(folder) if folder is not None else textures_dir()
        self._entries = {e.name: e for e in read_index(self.folder)}
        self._images: dict[str, np.ndarray] = {}
        self._mean: dict[str, np.ndarray] = {}

    @classmethod
    def from_arrays(cls, images: dict[str, tuple[np.ndarray, float]]) -> TextureSet:
        self = cls.__new__(cls)
        self.folder = None
        self._entries = {}
        self._images = {}
        self._mean = {}
        for name, (image, tile_m) in images.items():
            image = np.asarray(image)
            if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
                raise ValueError(
                    f"texture {name!r} must be RGB uint8 (H, W, 3), got {image.shape} {image.dtype}"
                )
            self._entries[name] = TextureEntry(name, "", 1.0, float(tile_m), "in memory", "")
            self._images[name] = np.ascontiguousarray(image)
        return self

    def with_files(self, files: dict[str, tuple[Path, float]]) -> TextureSet:
        """A copy of this set plus image-file textures: ``{name: (image file, tile_m)}`` (a
        photo of the ground used as a texture; the file is read when first drawn)."""
        other = TextureSet.__new__(TextureSet)
        other.folder = self.folder
        other._entries = dict(self._entries)
        other._images = dict(self._images)
        other._mean = dict(self._mean)
        for name, (path, tile_m) in files.items():
            path = Path(path).resolve()
            other._entries[name] = TextureEntry(
                name, str(path), float("nan"), float(tile_m), "image file", ""
            )
        return other

    @property
    def names(self) -> list[str]:
        return list(self._entries)

    def entry(self, name: str) -> TextureEntry:
        if name not in self._entries:
            raise ValueError(f"unknown texture {name!r}; known textures: {self.names}")
        return self._entries[name]

    def image(self, name: str) -> np.ndarray:
        """RGB uint8 (H, W, 3) texture image."""
        entry = self.entry(name)
        if name not in self._images:
            self._images[name] = load_rgb(Path(self.folder or ".") / entry.file)
        return self._images[name]

    def tile_m(self, name: str) -> float:
        """World size [m] of one texture tile (its width)."""
        return self.entry(name).tile_m

    def mean_rgb(self, name: str) -> np.ndarray:
        """Mean colour of the texture, RGB in [0, 255] (float, shape (3,))."""
        if name not in self._mean:
            self._mean[name] = self.image(name).reshape(-1, 3).mean(axis=0)
        return self._mean[name]


_DEFAULT: TextureSet | None = None


def default_textures() -> TextureSet:
    """The packaged texture set (one shared, lazily loaded instance)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = TextureSet()
    return _DEFAULT
