"""Meshcat controls of a live run: show/hide each debugging layer, pause/resume, real-time rate.

The controls appear in Meshcat's control panel (top right of the browser page):

- sliders ``show plan``, ``show friction_circle``, ``show camera``, ``show features`` (1 shown,
  0 hidden): the visibility of ``/pcvfe/<layer>`` in the live view;
- a button ``pause / resume`` (keyboard: space): the simulation waits, polling the controls,
  until it is pressed again;
- a slider ``real-time rate`` (0 = as fast as the machine goes, else the simulator's target
  real-time rate).

:class:`MeshcatControls` is polled by the run loop (``run_simulation``) between chunks of
simulated time, so a pause takes effect at the end of the running chunk. The layers' visibility
is not recorded: ``playback.html`` shows every layer, and its own scene tree (Open Controls >
Scene > pcvfe) hides and shows them.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from pydrake.geometry import Meshcat

from pcvfe_drake.diagrams.debug_layers import LAYERS

PAUSE = "pause / resume"
RATE = "real-time rate"


def show_slider(layer: str) -> str:
    """Name of the slider that shows/hides ``/pcvfe/<layer>``."""
    return f"show {layer}"


class MeshcatControls:
    """The controls above, added to ``meshcat`` (``remove`` takes them away again).

    Args:
        meshcat: the live Meshcat.
        layers: layer names under ``/pcvfe/`` that get a show/hide slider.
        realtime_rate: the slider's initial real-time rate (0: as fast as possible); pass the
            simulator's own target rate.
        poll_s: how often a paused run polls the controls [s of wall time].
    """

    def __init__(
        self,
        meshcat: Meshcat,
        layers: Sequence[str] = LAYERS,
        *,
        realtime_rate: float = 0.0,
        poll_s: float = 0.05,
    ) -> None:
        self._meshcat = meshcat
        self.layers = list(layers)
        self._poll_s = float(poll_s)
        for layer in self.layers:
            meshcat.AddSlider(show_slider(layer), 0.0, 1.0, 1.0, 1.0)
        meshcat.AddSlider(RATE, 0.0, 10.0, 0.25, float(realtime_rate))
        meshcat.AddButton(PAUSE, "Space")
        self._shown = {layer: True for layer in self.layers}
        self._rate = meshcat.GetSliderValue(RATE)

    def layer_visible(self, layer: str) -> bool:
        """Whether the slider of ``layer`` shows it."""
        return self._meshcat.GetSliderValue(show_slider(layer)) >= 0.5

    def _apply_visibility(self) -> None:
        for layer in self.layers:
            shown = self.layer_visible(layer)
            if shown != self._shown[layer]:
                self._meshcat.SetProperty(f"/pcvfe/{layer}", "visible", shown)
                self._shown[layer] = shown

    def paused(self) -> bool:
        """Whether the pause button has been pressed an odd number of times."""
        return self._meshcat.GetButtonClicks(PAUSE) % 2 == 1

    def poll(self, simulator, *, max_pause_s: float | None = None) -> None:
        """Apply the controls to ``simulator`` (its target real-time rate only when the slider
        moved, so a rate set elsewhere stands until then); while paused, wait here (at most
        ``max_pause_s`` [s] of wall time if given) applying visibility changes."""
        self._apply_visibility()
        self._apply_rate(simulator)
        start = time.perf_counter()
        while self.paused():
            if max_pause_s is not None and time.perf_counter() - start >= max_pause_s:
                break
            time.sleep(self._poll_s)
            self._apply_visibility()
        self._apply_rate(simulator)

    def _apply_rate(self, simulator) -> None:
        rate = self._meshcat.GetSliderValue(RATE)
        if rate != self._rate:
            simulator.set_target_realtime_rate(max(0.0, rate))
            self._rate = rate

    def remove(self) -> None:
        """Take the controls away and show every layer again (before saving a playback)."""
        for layer in self.layers:
            if not self._shown[layer]:
                self._meshcat.SetProperty(f"/pcvfe/{layer}", "visible", True)
            self._meshcat.DeleteSlider(show_slider(layer))
        self._meshcat.DeleteSlider(RATE)
        self._meshcat.DeleteButton(PAUSE)
