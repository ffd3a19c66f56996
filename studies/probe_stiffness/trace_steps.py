"""Print every change of a probe's level while ``pcvfe simulate`` runs a scenario.

    python studies/probe_stiffness/trace_steps.py SCENARIO.yaml [pcvfe simulate options]

Wraps ``pcvfe_drake.estimation.probe.probe_step`` (the handing looks it up in its module at
each call) so that each call that changes the probe's state prints the time, the level before
and after, and the evidence it was given (the used-friction bound, the level's bend ratio, the
start evidence's bend ratio and level, the tight fit's target, the saturation sign); then runs
``pcvfe simulate`` with the remaining arguments. A frozen study script.
"""

from __future__ import annotations

import sys

import pcvfe_drake.estimation.probe as probe
from pcvfe_drake.cli import main as cli_main

_EVIDENCE = ("lower_bound", "bend", "start_bend", "start_mu", "fit_mu", "is_saturated")


def _traced(original):
    def step(state, t_now, **kwargs):
        new = original(state, t_now, **kwargs)
        if new != state:
            given = " ".join(f"{k}={kwargs.get(k)!r:.6}" for k in _EVIDENCE)
            print(f"PROBE t={t_now:.2f} {state.mu:.3f}->{new.mu:.3f} {given}", flush=True)
        return new

    return step


def main(argv: list[str]) -> int:
    probe.probe_step = _traced(probe.probe_step)
    return cli_main(["simulate", *argv])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
