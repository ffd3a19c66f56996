"""MeshcatControls: the layer sliders show and hide /pcvfe/<layer>, the rate slider sets the
simulator's target rate, the pause button holds the run until pressed again."""

from __future__ import annotations

import time

import pytest
from pydrake.geometry import Meshcat, MeshcatParams

from pcvfe_drake.diagrams.meshcat_controls import PAUSE, RATE, MeshcatControls, show_slider


def click(meshcat: Meshcat, button: str) -> None:
    """A browser's click on ``button`` (the msgpack message Meshcat's page sends)."""

    def fixstr(text: str) -> bytes:
        data = text.encode()
        assert len(data) < 32
        return bytes([0xA0 | len(data)]) + data

    message = bytes([0x82]) + fixstr("type") + fixstr("button") + fixstr("name") + fixstr(button)
    meshcat._InjectWebsocketMessage(message)


def visible(meshcat: Meshcat, path: str) -> bool | None:
    packed = bytes(meshcat._GetPackedProperty(path, "visible"))
    return None if not packed else packed[-1] == 0xC3


class FakeSimulator:
    def __init__(self) -> None:
        self.rate = None

    def set_target_realtime_rate(self, rate: float) -> None:
        self.rate = rate


@pytest.fixture
def meshcat():
    params = MeshcatParams()
    params.host = "localhost"
    return Meshcat(params)


def test_show_hide_rate_and_pause(meshcat):
    controls = MeshcatControls(meshcat, ["plan", "camera"], realtime_rate=0.0)
    assert {show_slider("plan"), show_slider("camera"), RATE} <= set(meshcat.GetSliderNames())
    assert PAUSE in meshcat.GetButtonNames()
    sim = FakeSimulator()
    controls.poll(sim)
    # Nothing moved: the simulator's own rate and the layers are left alone.
    assert sim.rate is None and visible(meshcat, "/pcvfe/plan") is None
    meshcat.SetSliderValue(show_slider("plan"), 0.0)
    meshcat.SetSliderValue(RATE, 2.0)
    controls.poll(sim)
    assert visible(meshcat, "/pcvfe/plan") is False and visible(meshcat, "/pcvfe/camera") is None
    assert sim.rate == 2.0

    click(meshcat, PAUSE)
    assert controls.paused()
    start = time.perf_counter()
    controls.poll(sim, max_pause_s=0.3)  # held while paused (bounded here)
    assert time.perf_counter() - start >= 0.3
    click(meshcat, PAUSE)
    start = time.perf_counter()
    controls.poll(sim, max_pause_s=5.0)
    assert not controls.paused() and time.perf_counter() - start < 1.0

    controls.remove()
    assert visible(meshcat, "/pcvfe/plan") is True  # every layer shown again for the playback
    assert not meshcat.GetSliderNames() and not meshcat.GetButtonNames()
