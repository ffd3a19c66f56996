"""Fixtures of the system tests: a localhost Meshcat and a probe that reads back what it holds."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from pydrake.geometry import Meshcat, MeshcatParams

from pcvfe_drake.systems.meshcat_layer import packed_translation


def local_meshcat() -> Meshcat:
    """A Meshcat server bound to localhost only."""
    params = MeshcatParams()
    params.host = "localhost"
    return Meshcat(params)


def translation(meshcat: Meshcat, path: str) -> np.ndarray:
    """The translation [m] of the transform last set on ``path``."""
    t = packed_translation(meshcat, path)
    assert t is not None, f"no transform set on {path}"
    return t


def _floats(packed: bytes, start: int, n: int) -> list[float]:
    values = []
    for _ in range(n):
        assert packed[start] == 0xCB, "expected msgpack float64"
        values.append(struct.unpack(">d", packed[start + 1 : start + 9])[0])
        start += 9
    return values


def scale(meshcat: Meshcat, path: str) -> np.ndarray | None:
    """The ``scale`` property last set on ``path`` (None if never set)."""
    packed = bytes(meshcat._GetPackedProperty(path, "scale"))
    tag = b"value\x93"
    return np.array(_floats(packed, packed.index(tag) + len(tag), 3)) if packed else None


def visible(meshcat: Meshcat, path: str) -> bool | None:
    """The ``visible`` property last set on ``path`` (None if never set)."""
    packed = bytes(meshcat._GetPackedProperty(path, "visible"))
    if not packed:
        return None
    return packed[packed.index(b"value") + 5] == 0xC3


def object_bytes(meshcat: Meshcat, path: str) -> bytes:
    """The packed set_object message of ``path`` (b"" if none)."""
    return bytes(meshcat._GetPackedObject(path))


class MeshcatProbe:
    """What a Meshcat holds for a path: translation, object, scale, visible."""

    translation = staticmethod(translation)
    object_bytes = staticmethod(object_bytes)
    scale = staticmethod(scale)
    visible = staticmethod(visible)


@pytest.fixture(scope="session")
def local_meshcat_server() -> Meshcat:
    """One localhost Meshcat shared by the layer tests."""
    return local_meshcat()


@pytest.fixture
def probe() -> MeshcatProbe:
    return MeshcatProbe()
