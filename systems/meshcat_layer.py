"""Meshcat drawing helpers shared by the ``/pcvfe/*`` debugging layers (not a LeafSystem).

A Meshcat recording keys transforms and properties (``visible``, ``scale``) over time but not
geometry or colours. The layers therefore draw what changes as (a) a fixed pool of objects whose
transforms are keyed, and (b) for content that changes (a colour bin, a text, a camera frame, a
re-clustered cloud), one object per distinct content of which exactly one is visible at a time
(:class:`VisibleChoice`): the live view and ``playback.html`` show the same thing.
"""

from __future__ import annotations

import struct
import tempfile
from collections.abc import Callable, Hashable
from pathlib import Path

import cv2
import numpy as np
from pydrake.geometry import Mesh, Meshcat
from pydrake.math import RigidTransform

from pcvfe_drake.vehicle.single_track import SX, SY
from pcvfe_drake.views.labels import text_image

ROOT = "/pcvfe"


def set_image_quad(
    meshcat: Meshcat,
    path: str,
    rgb: np.ndarray,
    width_m: float,
    *,
    vertical: bool = True,
) -> float:
    """A flat quad textured with ``rgb`` (H, W, 3 uint8) at ``path``; returns its height [m].

    ``vertical``: in the x-z plane facing -y (readable from the default camera south of the
    course), centred on the origin of ``path``; else in the x-y plane facing up. Both sides are
    drawn (the back one mirrored).
    """
    image = np.ascontiguousarray(rgb, dtype=np.uint8)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"set_image_quad({path}): expected (H, W, 3) RGB, got {image.shape}")
    w = float(width_m) / 2
    h = w * image.shape[0] / image.shape[1]
    if vertical:
        corners = [(-w, 0, -h), (w, 0, -h), (w, 0, h), (-w, 0, h)]
        normal = "0 -1 0"
    else:
        corners = [(-w, -h, 0), (w, -h, 0), (w, h, 0), (-w, h, 0)]
        normal = "0 0 1"
    vertices = "".join(f"v {x} {y} {z}\n" for x, y, z in corners)
    folder = _scratch_folder()
    # Fast PNG compression: the frames are small and drawn often.
    cv2.imwrite(
        str(folder / "tex.png"),
        cv2.cvtColor(image, cv2.COLOR_RGB2BGR),
        [cv2.IMWRITE_PNG_COMPRESSION, 1],
    )
    (folder / "quad.mtl").write_text("newmtl quad\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd tex.png\n")
    (folder / "quad.obj").write_text(
        f"mtllib quad.mtl\n{vertices}vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn {normal}\n"
        "usemtl quad\nf 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n"
        "f 1/2/1 3/4/1 2/1/1\nf 1/2/1 4/3/1 3/4/1\n"
    )
    # Meshcat reads the files (and embeds the texture) during SetObject.
    meshcat.SetObject(path, Mesh(str(folder / "quad.obj")))
    return 2 * h


def follow_car(meshcat: Meshcat, path: str, x: np.ndarray, offset_m, t: float) -> bool:
    """Key ``path`` at the car's position (state ``x``, ST order) plus ``offset_m`` [m], without
    its rotation (panels keep facing the camera); False (nothing set) if the position is not
    finite."""
    if not np.all(np.isfinite(x[[SX, SY]])):
        return False
    position = np.array([x[SX], x[SY], 0.0]) + np.asarray(offset_m, dtype=float)
    meshcat.SetTransform(path, RigidTransform(position), t)
    return True


def packed_translation(meshcat: Meshcat, path: str) -> np.ndarray | None:
    """Translation [m] of the transform last set on ``path`` in the live scene (None if none):
    read back from Meshcat's own message, for tests and tools that aim a camera at a layer."""
    packed = bytes(meshcat._GetPackedTransform(path))
    tag = b"matrix\xdc\x00\x10"
    if not packed or tag not in packed:
        return None
    start = packed.index(tag) + len(tag)
    values = []
    for _ in range(16):
        if packed[start] != 0xCB:  # msgpack float64
            raise ValueError(f"packed_translation({path}): unexpected transform encoding")
        values.append(struct.unpack(">d", packed[start + 1 : start + 9])[0])
        start += 9
    return np.array(values[12:15])


_SCRATCH: tempfile.TemporaryDirectory | None = None


def _scratch_folder() -> Path:
    """A folder for the quads' files, made once per process and removed at exit."""
    global _SCRATCH
    if _SCRATCH is None:
        _SCRATCH = tempfile.TemporaryDirectory(prefix="pcvfe_quad_")
    return Path(_SCRATCH.name)


class VisibleChoice:
    """At most one visible child of ``parent`` at a time, one child per distinct key.

    ``show(key, t, create)`` creates ``parent/<name>`` with ``create(path)`` the first time a key
    is shown (hidden from time 0), then keys the old child invisible and the new one visible at
    ``t``; showing the shown key again costs nothing. ``show(None, t)`` hides the shown child.
    Keys beyond ``max_keys`` distinct ones fall back to ``overflow_key``.
    """

    def __init__(
        self,
        meshcat: Meshcat,
        parent: str,
        *,
        max_keys: int | None = None,
        overflow_key: Hashable = "more",
    ) -> None:
        self._meshcat = meshcat
        self.parent = parent
        self._max_keys = max_keys
        self._overflow = overflow_key
        self._paths: dict[Hashable, str] = {}
        self.shown: Hashable | None = None

    def reset(self) -> None:
        """Forget every child (after the parent was deleted)."""
        self._paths = {}
        self.shown = None

    @property
    def keys(self) -> list[Hashable]:
        """Keys created so far, in order."""
        return list(self._paths)

    def path(self, key: Hashable) -> str | None:
        """Path of the child of ``key`` (None if never shown)."""
        return self._paths.get(key)

    def show(
        self, key: Hashable | None, t: float, create: Callable[[str], None] | None = None
    ) -> None:
        if key is not None and key not in self._paths and self._max_keys is not None:
            if len(self._paths) >= self._max_keys:
                key = self._overflow
        if key == self.shown:
            return
        mc = self._meshcat
        if key is not None and key not in self._paths:
            if create is None:
                raise ValueError(f"VisibleChoice({self.parent}): no create for new key {key!r}")
            path = f"{self.parent}/{len(self._paths):05d}"
            create(path)
            mc.SetProperty(path, "visible", False, 0.0)
            self._paths[key] = path
        if self.shown is not None:
            mc.SetProperty(self._paths[self.shown], "visible", False, t)
        if key is not None:
            mc.SetProperty(self._paths[key], "visible", True, t)
        self.shown = key


class TextLabel:
    """A line of text on a quad of fixed height ``height_m`` that changes over time (a
    :class:`VisibleChoice` over the texts; ``max_texts`` distinct texts at most)."""

    def __init__(
        self,
        meshcat: Meshcat,
        parent: str,
        *,
        height_m: float = 0.8,
        rgb=(1.0, 1.0, 1.0),
        background=(0.1, 0.1, 0.1),
        vertical: bool = True,
        max_texts: int = 64,
    ) -> None:
        self._meshcat = meshcat
        self._height_m = float(height_m)
        self._rgb = rgb
        self._background = background
        self._vertical = vertical
        self._choice = VisibleChoice(meshcat, parent, max_keys=max_texts, overflow_key="...")
        self.widths_m: dict[str, float] = {}

    def reset(self) -> None:
        self._choice.reset()
        self.widths_m = {}

    @property
    def shown(self) -> str | None:
        """The text shown now (None: none)."""
        return None if self._choice.shown is None else self._choice.shown[0]

    def show(self, text: str | None, t: float, rgb: tuple[float, float, float] | None = None):
        """Show ``text`` (None: nothing) from ``t`` on, in ``rgb`` (default: the label's)."""
        rgb = tuple(self._rgb if rgb is None else rgb)

        def create(path: str) -> None:
            image = text_image(text, rgb=rgb, background=self._background)
            width = self._height_m * image.shape[1] / image.shape[0]
            # Left-aligned: the quad's left edge at the parent's origin.
            set_image_quad(self._meshcat, f"{path}/quad", image, width, vertical=self._vertical)
            self._meshcat.SetTransform(f"{path}/quad", RigidTransform([width / 2, 0.0, 0.0]))
            self.widths_m[text] = width

        self._choice.show(None if text is None else (text, rgb), t, create)
