"""Bounds on the sizes a scenario controls, checked before a run starts (no pydrake).

A period, a step or a duration in a scenario sets how much work and how much output a run
makes. Each has a limit here, and a refusal says what the request would have cost:

- every period of ``rates`` is at least :data:`MIN_PERIOD_S` (nothing of a car's loop runs
  faster than 1 kHz, and each event costs work);
- ``simulator.max_step_size`` is at least :data:`MIN_STEP_S`;
- ``rates.nmpc_period_s`` is at most :data:`MAX_NMPC_PERIOD_S`;
- the fitter keeps at most :data:`MAX_FIT_BUFFER_ROWS` samples per context, a window of
  ``fitter.horizon_steps`` fits in that buffer, and a refit uses at most :data:`MAX_FIT_WINDOWS`
  windows;
- the drive log of the longest run (``duration_s``, or ``max_duration_s`` when running by laps)
  at ``rates.log_period_s`` has at most :data:`MAX_LOG_ROWS` rows.

The NMPC's horizon is bounded by its own config (``NmpcConfig``, ``MAX_HORIZON``) and a terrain
raster by ``pcvfe_drake.perception.terrain.raster_shape``.
"""

from __future__ import annotations

import math

MIN_PERIOD_S = 1e-3
"""Shortest period of any part of the loop [s] (1 kHz)."""
MIN_STEP_S = 1e-4
"""Shortest integrator step [s]: 10 000 steps per simulated second."""
MAX_NMPC_PERIOD_S = 0.5
"""Longest controller period [s]: the NMPC steps its vehicle model and holds its actuation for a
period (``nmpc.dt_s``); beyond half a second one held steering rate turns the car through a
bend unsteered, and the explicit steps no longer follow its yaw dynamics."""
MAX_FIT_BUFFER_ROWS = 360_000
"""Most samples the fitter keeps per context (``fitter.buffer_s`` at
``rates.fitter_sample_period_s``): an hour at 100 Hz, ~26 MB a context (9 numbers a sample)."""
FIT_BYTES_PER_ROW = 72
"""Size of one fitter sample in memory [bytes] (7 states and 2 inputs as float64)."""
MAX_FIT_WINDOWS = 20_000
"""Most windows of one refit (``fitter.max_windows``, ``fitter.effect_max_windows``): each is a
rollout with its sensitivities, refitted at every refit period."""
MAX_LOG_ROWS = 1_000_000
"""Most rows of a run's drive log (15 min at 1 kHz)."""
LOG_BYTES_PER_ROW = 700
"""Size of a drive-log row on disk [bytes] (about 45 columns as text), for the estimate."""


def _number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def scenario_bound_problems(scenario) -> list[str]:
    """The bounds ``scenario`` (a ``pcvfe_drake.runs.scenario.Scenario``) exceeds, as
    ``"field=value: reason"`` strings (values of the wrong type are left to the other checks)."""
    import dataclasses

    problems = []
    rates = scenario.rates
    for f in dataclasses.fields(rates):
        value = getattr(rates, f.name)
        if f.name != "clustering_frame_offset_s" and _number(value) and 0 < value < MIN_PERIOD_S:
            problems.append(
                f"rates.{f.name}={value!r}: at least {MIN_PERIOD_S:g} s (1 kHz); "
                f"{1.0 / value:.3g} events per simulated second would be asked for"
            )
    period = rates.nmpc_period_s
    if _number(period) and period > MAX_NMPC_PERIOD_S:
        problems.append(
            f"rates.nmpc_period_s={period!r}: at most {MAX_NMPC_PERIOD_S:g} s (the NMPC holds "
            "its actuation and steps its model over a period)"
        )
    problems += _fitter_bound_problems(scenario.fitter, rates.fitter_sample_period_s)
    step = scenario.simulator.max_step_size
    if _number(step) and 0 < step < MIN_STEP_S:
        problems.append(
            f"simulator.max_step_size={step!r}: at least {MIN_STEP_S:g} s "
            f"({1.0 / step:.3g} steps per simulated second would be asked for)"
        )
    stop = scenario.duration_s if scenario.duration_s is not None else scenario.max_duration_s
    period = rates.log_period_s
    if _number(stop) and _number(period) and stop > 0 and period > 0:
        rows = stop / period
        if rows > MAX_LOG_ROWS:
            field = "duration_s" if scenario.duration_s is not None else "max_duration_s"
            problems.append(
                f"rates.log_period_s={period!r} over {field}={stop!r}: the drive log would have "
                f"{rows:.3g} rows (~{rows * LOG_BYTES_PER_ROW / 1e9:.3g} GB), more than "
                f"{MAX_LOG_ROWS}: log less often or run shorter"
            )
    return problems


def _fitter_bound_problems(fitter, sample_period_s) -> list[str]:
    """The fitter's sizes beyond their bounds (``fitter``: a ``LiveFitConfig``)."""
    problems = []
    buffer_s = fitter.buffer_s
    if _number(buffer_s) and _number(sample_period_s) and buffer_s > 0 and sample_period_s > 0:
        rows = buffer_s / sample_period_s
        if rows > MAX_FIT_BUFFER_ROWS:
            problems.append(
                f"fitter.buffer_s={buffer_s!r}: at rates.fitter_sample_period_s="
                f"{sample_period_s!r} it keeps {rows:.3g} samples per context "
                f"(~{rows * FIT_BYTES_PER_ROW / 1e9:.3g} GB each), more than "
                f"{MAX_FIT_BUFFER_ROWS}"
            )
        horizon = fitter.horizon_steps
        if _number(horizon) and horizon * sample_period_s > buffer_s:
            problems.append(
                f"fitter.horizon_steps={horizon!r}: a window of {horizon * sample_period_s:g} s "
                f"is longer than the buffer (fitter.buffer_s={buffer_s!r}): no window would "
                "ever be fitted"
            )
    for name in ("max_windows", "effect_max_windows"):
        value = getattr(fitter, name)
        if _number(value) and value > MAX_FIT_WINDOWS:
            problems.append(
                f"fitter.{name}={value!r}: at most {MAX_FIT_WINDOWS} windows per refit (each "
                "is a rollout with its sensitivities, at every refit)"
            )
    return problems
