"""Bounds on the sizes a scenario controls, checked before a run starts (no pydrake).

A period, a step or a duration in a scenario sets how much work and how much output a run
makes. Each has a limit here, and a refusal says what the request would have cost:

- every period of ``rates`` is at least :data:`MIN_PERIOD_S` (nothing of a car's loop runs
  faster than 1 kHz, and each event costs work);
- ``simulator.max_step_size`` is at least :data:`MIN_STEP_S`;
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
