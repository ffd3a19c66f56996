"""A diagram's first step, computed before its loop: one-off costs out of the clock.

A process's first evaluation of some systems pays costs once: the compiled multi-body model is
loaded from numba's cache (or compiled, on a fresh checkout or after its source changed: tens of
seconds), modules are imported, the first message is built. Paid inside the loop they stall a
real-time loop's clock (the bridged car: studies/bridge_startup) and count in a simulated loop's
CPU time per driving second, which is meant to measure the loop's steady cost.
"""

from __future__ import annotations

import time

from pydrake.systems.lcm import LcmPublisherSystem

from pcvfe_drake.diagrams.release import all_systems
from pcvfe_drake.systems.vehicle_plant import VehiclePlant


def warm_up(diagram) -> float:
    """Evaluate, on a throwaway context of ``diagram``, its time derivatives, each
    ``VehiclePlant``'s discrete update (the multi-body truth's default state) and every
    ``LcmPublisherSystem``'s input (the messages the first step sends). Changes no context
    the caller holds and publishes nothing. Returns the wall time it took [s]."""
    t0 = time.perf_counter()
    context = diagram.CreateDefaultContext()
    diagram.EvalTimeDerivatives(context)  # nothing where no state is continuous
    for system in all_systems(diagram):
        if isinstance(system, VehiclePlant) and system.mb_integration == "discrete":
            system.EvalUniquePeriodicDiscreteUpdate(system.GetMyContextFromRoot(context))
        if isinstance(system, LcmPublisherSystem):
            # EvalAbstract: the C++ image message has no Python value type.
            system.get_input_port().EvalAbstract(system.GetMyContextFromRoot(context))
    return time.perf_counter() - t0
