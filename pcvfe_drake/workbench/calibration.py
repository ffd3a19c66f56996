"""Calibrate a car's effect model for the context fitter on a calibration drive.

``pcvfe calibrate`` runs the workbench's loop (:mod:`pcvfe_drake.workbench.selection`: forward
selection with a backward check, the same machinery as ``pcvfe diagnose --add``) on a drive
log that holds only what a car measures (the drive log's required columns: measured state and
commanded inputs), and returns the model the live fitter holds
(:class:`~pcvfe_drake.models.effect_model.EffectModel`):

1. the loop starts from the effects a car has by construction, with the constants its own data
   give held (``effect_model.vehicle_constants``): ``peak_tyre`` (the fitter hands the friction
   *peak*; its stiffness law ``k_s`` is stated, one surface cannot show it), ``track_slip``
   (width ``t`` the vehicle's track; the load share ``k_lt`` fitted) and, for a CommonRoad
   tyre, ``roll_camber`` at the tyre's constants;
2. it adds, one by one, the candidates (:data:`CANDIDATES`) that are significant on top of it
   and lower the held-out error;
3. every parameter of the final model is then held at its fitted value, with its standard
   deviation; the friction is the only parameter left to the fitter;
4. the model-error budget ``model_error_rel``: the final model fits the friction alone on each
   time block of the drive where it is identifiable; the spread of those peaks beyond their own
   standard deviations, relative to the whole drive's, is the error that a fit on one stretch
   of driving makes and that no covariance of its own data sees.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.models.data import DriveData, block_ids, window_starts
from pcvfe_drake.models.effect_model import EffectModel, FitterEffect, vehicle_constants
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.workbench.ranking import DiagnoseConfig, Workbench

START_EFFECTS = ("peak_tyre", "track_slip", "roll_camber")
"""Effects every calibration starts from (module docstring; ``roll_camber`` only where the
car's tyre gives its constants)."""

CANDIDATES = (
    "axle_stiffness",
    "steering_lag",
    "wheel_force_steer",
    "suspension_lag",
    "friction_load",
    "input_delay",
    "rolling_resistance",
)
"""Effects the loop may add: those of the library that change how the car corners or brakes
on one surface and that a real car can have (sensor effects are a log's problem, not the car's;
effects of speed above 15 m/s or of the road, grade and drag, do not belong to the car's
handling at the evaluation's speeds)."""

BLOCK_STD_MAX = 0.05
"""A time block's friction counts for the model-error budget when its std is at most this."""


@dataclass
class Calibration:
    """The result of :func:`calibrate`: the model and what the calibration measured."""

    model: EffectModel
    effects: list[str]
    surface_mu: dict[str, float]
    """The fitted friction peak per context of the drive (its surface)."""
    surface_mu_std: dict[str, float]
    baseline_heldout_error: float
    heldout_error: float
    noise_floor: float
    heldout_multistep_error: float
    block_mu: list[float] = field(default_factory=list)
    path: list[dict] = field(default_factory=list)
    fits: int = 0

    def summary(self) -> dict:
        """JSON-ready numbers (a model file's ``calibration`` section)."""
        return {
            "selected": list(self.effects),
            "surface_mu": {k: round(v, 4) for k, v in self.surface_mu.items()},
            "surface_mu_std": {k: round(v, 4) for k, v in self.surface_mu_std.items()},
            "baseline_heldout_error": float(self.baseline_heldout_error),
            "heldout_error": float(self.heldout_error),
            "heldout_multistep_error": float(self.heldout_multistep_error),
            "noise_floor": float(self.noise_floor),
            "block_mu": [round(v, 4) for v in self.block_mu],
            "loop": [
                f"{'+' if s['action'] == 'add' else '-'} {s['name']}: held-out error "
                f"{s['heldout_error_before']:.4g} -> {s['heldout_error']:.4g}"
                for s in self.path
            ],
            "fits": int(self.fits),
        }


class _CalibrationBench(Workbench):
    """The workbench with parameters held at given values in every fit (``held``) and a
    progress report per fit."""

    def __init__(self, data, vehicle, held: dict[str, float], progress=None, **kwargs):
        super().__init__(data, vehicle, **kwargs)
        self.held = dict(held)
        self.progress = progress

    def fit_model(self, model, warm=None, fixed=None, hac_lag=None, starts=None):
        if self.progress is not None:
            self.progress(f"fit {self.n_fits + 1}: {' + '.join(model.effect_names) or 'ST'}")
        held = {k: v for k, v in self.held.items() if k in model.param_names}
        return super().fit_model(model, warm, {**held, **(fixed or {})}, hac_lag, starts)


def calibrate(
    data: DriveData,
    vehicle: str,
    params: VehicleParams,
    k_s: float,
    candidates: tuple[str, ...] = CANDIDATES,
    config: DiagnoseConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> Calibration:
    """Calibrate the effect model of ``vehicle`` (preset name or file; ``params`` its
    parameters) on ``data`` (module docstring); ``k_s``: ``peak_tyre``'s stated stiffness
    law."""
    constants = vehicle_constants(vehicle, params)
    start = [e for e in START_EFFECTS if e != "roll_camber" or "roll_camber" in constants]
    held = {"peak_tyre.k_s": float(k_s)}
    for effect, values in constants.items():
        held.update({f"{effect}.{p}": v for p, v in values.items()})
    wb = _CalibrationBench(data, params, held, progress, config=config)
    report = wb.rank(candidates=list(candidates), start=start)
    final, final_eval = wb.final_fit, wb.final_eval
    values = final.params_dict()
    effects = []
    for name in final.model.effect_names:
        fixed, std = {}, {}
        for key, p in values.items():
            if not key.startswith(f"{name}."):
                continue
            short = key.split(".", 1)[1]
            fixed[short] = float(p["value"])
            is_held = key in held
            std[short] = 0.0 if is_held or not math.isfinite(p["std"]) else float(p["std"])
        effects.append(FitterEffect(name, fixed, std))
    mu_names = [p.name for p in final.model.params if p.effect is None]
    surface = {_context(n, data): float(values[n]["value"]) for n in mu_names}
    surface_std = {_context(n, data): float(values[n]["std"]) for n in mu_names}
    all_held = {f"{e.name}.{k}": v for e in effects for k, v in e.fixed.items()}
    blocks = _block_frictions(wb, final.model, all_held, final)
    excess = [((m - surface[c]) ** 2 - s**2) / surface[c] ** 2 for c, m, s in blocks]
    budget = math.sqrt(max(float(np.mean(excess)), 0.0)) if excess else 0.0
    whole = float(np.mean(list(surface.values())))
    model = EffectModel(
        effects=effects, model_error_rel=round(budget, 4), calibrated_mu=round(whole, 4)
    )
    return Calibration(
        model=model,
        effects=list(final.model.effect_names),
        surface_mu=surface,
        surface_mu_std=surface_std,
        baseline_heldout_error=float(wb.baseline_eval["model_error"]),
        heldout_error=float(final_eval["model_error"]),
        noise_floor=float(final_eval["noise_floor"]),
        heldout_multistep_error=float(final_eval["multistep_error"]),
        block_mu=[m for _, m, _ in blocks],
        path=report["selection"]["path"],
        fits=wb.n_fits,
    )


def _context(param_name: str, data: DriveData) -> str:
    """The context label of a base-mu parameter name (``mu`` or ``mu[label]``)."""
    return param_name[3:-1] if "[" in param_name else data.context_names[0]


def _block_frictions(wb: Workbench, model, held: dict[str, float], final) -> list[tuple]:
    """The friction fitted alone (every effect parameter held) on each time block of the
    drive where it is identifiable (std <= :data:`BLOCK_STD_MAX`): (context, peak, std)."""
    data = wb.data
    starts = window_starts(data, wb.h_fit, wb.h_fit, "all", wb.config.n_blocks)
    blocks = block_ids(data.n, wb.config.n_blocks)[starts]
    out = []
    for b in np.unique(blocks):
        chosen = starts[blocks == b]
        if chosen.size < 5:
            continue
        res = wb.fit_model(model, warm=final, fixed=held, starts=chosen)
        for i, p in enumerate(model.params):
            if p.effect is not None or (res.informed is not None and not res.informed[i]):
                continue
            std = float(res.std[i])
            if math.isfinite(std) and std <= BLOCK_STD_MAX:
                out.append((_context(p.name, data), float(res.theta[i]), std))
    return out
