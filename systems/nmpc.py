"""Nmpc: the friction-aware tracking controller as a discrete-time LeafSystem."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from pcvfe_drake.control.course import Course, load_course
from pcvfe_drake.control.nmpc import NmpcConfig, NmpcController, NmpcDiagnostics, NmpcMemory
from pcvfe_drake.control.plan import NmpcPlan
from pcvfe_drake.vehicle.params import VehicleParams, ford_escort
from pcvfe_drake.vehicle.single_track import NTHETA, NU, NX


class Nmpc(LeafSystem):
    """Model predictive path tracking with the friction the estimator believes.

    .. pydrake_system::

        name: Nmpc
        input_ports:
        - state
        - theta_hat
        output_ports:
        - actuation
        - diagnostics
        - plan

    Ports:
        state: input (7), the measured ST state (``pcvfe_drake.vehicle.single_track.STATE_NAMES``).
        theta_hat: input (3), ``[mu, C_Sf, C_Sr]`` the controller believes; not read (and may be
            left unconnected) when ``fixed_theta`` is given. Invalid values (non-finite, mu <= 0)
            fall back to the vehicle's nominal theta, noted in the diagnostics.
        actuation: output (2) ``[steer_rate rad/s, accel m/s^2]``, held from discrete state
            between updates (zero before the first); no direct feedthrough.
        diagnostics: output (abstract :class:`pcvfe_drake.control.nmpc.NmpcDiagnostics`) of the last
            update: mode, OSQP status, update and solve times, fallback counters, tracking
            errors.
        plan: output (abstract :class:`pcvfe_drake.control.plan.NmpcPlan`) of the last update:
            predicted states and inputs over the horizon, the reference window, the fallback
            mode and reason, stamped with the update's time; held from state (no solving
            when it is evaluated).

    Rate: one periodic unrestricted update every ``config.dt_s`` (default 0.05 s, 20 Hz; offset
    0) runs one real-time iteration of :class:`pcvfe_drake.control.nmpc.NmpcController`. The
    controller's memory (last plan, warm start, counters) is abstract state of the context; the
    OSQP workspace is a cache inside the system, so use one Nmpc per simulated vehicle.

    Args:
        course: the course to track (a :class:`Course`, a shipped name or a YAML path;
            default ``"slalom"``).
        params: vehicle parameters (default Ford Escort).
        config: :class:`NmpcConfig` (``model="ks"`` gives the KMPC baseline).
        fixed_theta: if given, ``[mu, C_Sf, C_Sr]`` used instead of the ``theta_hat`` input
            (baselines with a fixed friction).
    """

    def __init__(
        self,
        course: Course | str | Path | None = None,
        params: VehicleParams | None = None,
        config: NmpcConfig | None = None,
        fixed_theta=None,
    ) -> None:
        super().__init__()
        course = course if isinstance(course, Course) else load_course(course)
        self.params = params if params is not None else ford_escort()
        self.controller = NmpcController(course, self.params, config)
        self.period_s = self.controller.config.dt_s
        if fixed_theta is not None:
            fixed_theta = np.asarray(fixed_theta, dtype=float).reshape(-1)
            if fixed_theta.size != NTHETA or not np.all(np.isfinite(fixed_theta)):
                raise ValueError(f"Nmpc: fixed_theta={fixed_theta!r} must be 3 finite numbers")
            if fixed_theta[0] <= 0 or not math.isfinite(fixed_theta[0]):
                raise ValueError(f"Nmpc: fixed_theta mu={fixed_theta[0]!r} must be > 0")
        self.fixed_theta = fixed_theta

        self._state_port = self.DeclareVectorInputPort("state", NX)
        self._theta_port = self.DeclareVectorInputPort("theta_hat", NTHETA)
        self._u_index = self.DeclareDiscreteState(NU)
        self._memory_index = self.DeclareAbstractState(AbstractValue.Make(NmpcMemory()))
        self._diag_index = self.DeclareAbstractState(AbstractValue.Make(NmpcDiagnostics()))
        self._actuation_port = self.DeclareStateOutputPort("actuation", self._u_index)
        self._plan_index = self.DeclareAbstractState(AbstractValue.Make(NmpcPlan()))
        self._diagnostics_port = self.DeclareStateOutputPort("diagnostics", self._diag_index)
        self._plan_port = self.DeclareStateOutputPort("plan", self._plan_index)
        self.DeclarePeriodicUnrestrictedUpdateEvent(
            period_sec=self.period_s, offset_sec=0.0, update=self._update
        )

    def _update(self, context, state) -> EventStatus:
        x = self._state_port.Eval(context)
        theta = self.fixed_theta if self.fixed_theta is not None else self._theta_port.Eval(context)
        memory = context.get_abstract_state(self._memory_index).get_value()
        u, memory, diagnostics = self.controller.step(x, theta, memory)
        state.get_mutable_discrete_state(self._u_index).set_value(u)
        state.get_mutable_abstract_state(self._memory_index).set_value(memory)
        state.get_mutable_abstract_state(self._diag_index).set_value(diagnostics)
        plan = dataclasses.replace(diagnostics.plan, time_s=context.get_time())
        state.get_mutable_abstract_state(self._plan_index).set_value(plan)
        return EventStatus.Succeeded()
