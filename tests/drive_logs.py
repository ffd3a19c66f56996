"""The 90 s planted and clean drive logs of the loop's proofs, simulated in one batch per run.

Every module that proves the loop on planted data drives the same program (seed 0, 90 s at
20 Hz); simulating a batch costs about what one log does (the truth plant's cost is numpy's
per-call overhead), so the logs of all those modules are simulated together, once per test
run (:func:`lazy_diagnoses.shared`). Each log keeps the measurement-noise seed it had when its
module simulated only its own truths (``seed + 1 + its index there``): the logs, and so the
tests' numbers, are the same as before the batching."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from lazy_diagnoses import shared

from pcvfe_drake.workbench import synth

SINGLES = [
    "drag",
    "rolling_resistance",
    "steering_lag",
    "input_delay",
    "tire_saturation",
    "gyro_bias",
    "speed_scale",
    "steering_offset",
    "friction_speed",
    "friction_load",
]
COMBOS = {
    "input_delay+rolling_resistance": ("input_delay", "rolling_resistance"),
    "steering_lag+tire_saturation": ("steering_lag", "tire_saturation"),
    "drag+steering_lag+input_delay": ("drag", "steering_lag", "input_delay"),
}
RUN = {"duration_s": 90.0, "rate_hz": 20.0, "seed": 0, "substeps": 2}


def combined_truth(names) -> synth.Truth:
    """One truth with every named effect planted at its PLANTED magnitude."""
    fields = {}
    for name in names:
        truth = synth.PLANTED[name][0]
        for key, value in truth.__dict__.items():
            if value != getattr(synth.Truth(), key):
                fields[key] = value
    return synth.Truth(**fields)


def _batches() -> dict[str, list[tuple[str, synth.Truth]]]:
    """Per module group: its logs (name, truth) in the order the module simulated them."""
    planted = synth.PLANTED
    proof = [("clean", synth.Truth())] + [(n, planted[n][0]) for n in SINGLES]
    proof += [(c, combined_truth(names)) for c, names in COMBOS.items()]
    return {
        "proof": proof,
        "peak_tyre": [("mf", planted["peak_tyre"][0]), ("brush", planted["tire_saturation"][0])],
        "chassis": [
            (n, planted[n][0]) for n in ("axle_stiffness", "rotating_inertia", "wheel_force_steer")
        ],
        **{
            name: [("planted", planted[name][0]), ("clean", synth.Truth())]
            for name in ("suspension_lag", "roll_camber", "wheel_camber")
        },
    }


def _simulate() -> dict[str, dict[str, pd.DataFrame]]:
    truths, seeds, keys = [], [], []
    for group, logs in _batches().items():
        for i, (name, truth) in enumerate(logs):
            truths.append(truth)
            seeds.append(RUN["seed"] + 1 + i)
            keys.append((group, name))
    frames = synth.simulate_truths(truths, noise_seeds=seeds, **RUN)
    out: dict[str, dict[str, pd.DataFrame]] = {}
    for (group, name), frame in zip(keys, frames, strict=True):
        out.setdefault(group, {})[name] = frame
    return out


_LOGS: dict | None = None


def proof_logs(run_cache: Path | None, group: str) -> dict[str, pd.DataFrame]:
    """The logs of one module group (``proof``, ``peak_tyre``, ``chassis``,
    ``suspension_lag``, ``roll_camber``, ``wheel_camber``): name -> drive-log DataFrame."""
    global _LOGS
    if _LOGS is None:
        _LOGS = shared(run_cache, "seed0-logs", _simulate)
    return _LOGS[group]


def seed3_logs(run_cache: Path | None) -> dict[str, pd.DataFrame]:
    """Planted drag and planted rolling resistance, 90 s at 20 Hz, program seed 3 (noise seeds
    4 and 5): the stand-in tests' logs; the drag log is also the long-log test's."""
    names = ("drag", "rolling_resistance")

    def make() -> dict[str, pd.DataFrame]:
        truths = [synth.PLANTED[n][0] for n in names]
        frames = synth.simulate_truths(truths, duration_s=90.0, rate_hz=20.0, seed=3, substeps=2)
        return dict(zip(names, frames, strict=True))

    return shared(run_cache, "seed3-logs", make)


def drag_45s_log(run_cache: Path | None) -> pd.DataFrame:
    """Planted drag, 45 s at 20 Hz, program seed 3: the command-line tests' log (a copy: the
    tests may change it)."""

    def make() -> pd.DataFrame:
        truth = synth.PLANTED["drag"][0]
        return synth.simulate_truths([truth], duration_s=45.0, rate_hz=20.0, seed=3, substeps=2)[0]

    return shared(run_cache, "drag-45s-seed3", make).copy()
