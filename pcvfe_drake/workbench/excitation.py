"""Does a drive log carry what a diagnosis needs? The excitation check before ``pcvfe diagnose``.

A model is only tested where the data move: on a straight drive at constant speed every model,
right or wrong, predicts the log to the noise, and a verdict "explained" would be a confident
wrong answer. Each channel below is *excited* when its spread stands above its measurement noise
by the fitter's own factor (``models.data.EXCITATION_NOISE_FACTOR``, the test that decides which
states a fit percent is judged on), the noise estimated from the log itself (``DriveData.sigma``):

* **yaw excitation**: the root mean square of the yaw rate (bends, a slalom, a steady circle):
  friction, the tyre and every lateral effect act through the yaw rate and the side slip;
* **speed change**: the standard deviation of the speed (accelerating, braking): what
  longitudinal effects (drag, rolling resistance, a speed-sensor scale, an actuator lag) act on.

Without yaw excitation the log is not diagnosable (:class:`NotDiagnosable`, naming what is
missing); without a speed change it is, but the verdict says that longitudinal effects were
not tested.
"""

from __future__ import annotations

import numpy as np

from pcvfe_drake.models.data import EXCITATION_NOISE_FACTOR, DriveData
from pcvfe_drake.vehicle.single_track import PSI_DOT, V

CHANNELS = {
    "yaw excitation": (PSI_DOT, "rms", "yaw rate", "rad/s", "drive bends, a slalom or a circle"),
    "speed change": (V, "std", "speed", "m/s", "accelerate and brake"),
}
"""Channel -> (state index, statistic, what it measures, unit, what a driver does to excite it)."""
REQUIRED = ("yaw excitation",)
"""Channels without which no verdict is given."""


class NotDiagnosable(ValueError):
    """The log carries too little excitation for a verdict (the message names what is missing)."""


def excitation(data: DriveData, factor: float = EXCITATION_NOISE_FACTOR) -> dict:
    """Per channel (:data:`CHANNELS`): its spread, its noise, their ratio and whether it is
    excited (ratio above ``factor``); ``missing`` (names, with the numbers, in ``text``),
    ``diagnosable`` (every :data:`REQUIRED` channel excited). JSON-ready."""
    channels, missing, parts = {}, [], []
    for name, (state, stat, what, unit, how) in CHANNELS.items():
        y = np.asarray(data.x[:, state], dtype=float)
        spread = float(np.sqrt(np.mean(y**2)) if stat == "rms" else np.std(y))
        noise = float(data.sigma[state])
        ratio = spread / noise if noise > 0 else float("inf")
        excited = bool(ratio > factor)
        channels[name] = {"spread": spread, "statistic": stat, "noise": noise, "ratio": ratio}
        channels[name]["excited"] = excited
        if not excited:
            missing.append(name)
            parts.append(
                f"no {name} ({what} {stat} {spread:.3g} {unit}, {ratio:.2g} x its noise "
                f"{noise:.3g} {unit}; needs > {factor:g} x: {how})"
            )
    return {
        "channels": channels,
        "factor": factor,
        "missing": missing,
        "diagnosable": not any(name in missing for name in REQUIRED),
        "text": "; ".join(parts),
    }


def require_excitation(data: DriveData) -> dict:
    """:func:`excitation`, raising :class:`NotDiagnosable` (naming the log and what is missing)
    when a :data:`REQUIRED` channel is not excited."""
    ex = excitation(data)
    if not ex["diagnosable"]:
        raise NotDiagnosable(
            f"{data.source}: not diagnosable: {ex['text']}; every model predicts such a log to "
            "the noise, so no verdict would mean anything"
        )
    return ex
