"""VehiclePlant: the simulated car, with a selectable truth model and friction from the terrain."""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from pcvfe_drake.vehicle.mb_truth import INTEGRATION_METHODS, MbSingularity, MbTruth, st_state
from pcvfe_drake.vehicle.params import TRUTH_MODELS, VehicleParams, ford_escort
from pcvfe_drake.vehicle.single_track import INPUT_NAMES, NX, STATE_NAMES, st_dynamics

MB_UPDATE_OFFSET_S = 1e-6
"""The discrete multi-body update runs this long [s] after each multiple of its period.
Drake computes each periodic event's times from its own period, so a controller's update at a
multiple of 0.05 s and the plant's at the same multiple of 0.01 s can differ in the last bits;
where the plant's came first it would read the command before that update and apply it a
period late (about one in six of the controller's updates). 1 us later it always follows, and
a reader sampling on the grid sees the state 1 us ahead (12 um at 12 m/s)."""


class VehiclePlant(LeafSystem):
    """The simulated vehicle: single-track (ST) or CommonRoad multi-body (MB) dynamics.

    .. pydrake_system::

        name: VehiclePlant
        input_ports:
        - actuation
        output_ports:
        - state
        - true_mu
        - true_terrain

    Ports:
        actuation: input (2) ``[steer_rate rad/s, accel m/s^2]``; a non-finite value raises a
            ``ValueError`` naming the port, the value and the time.
        state: output (7) ``[sx m, sy m, delta rad, v m/s, psi rad, psi_dot rad/s, beta rad]``
            (ST order, ``pcvfe_drake.vehicle.single_track.STATE_NAMES``); for the MB truth, ``v``
            and ``beta``
            come from the body velocities (``pcvfe_drake.vehicle.mb_truth.st_state``). No direct
            feedthrough.
        true_mu: output (1), **simulation only**: the true friction coefficient under the centre
            of gravity (the terrain map's mu there; ``params.mu`` without a map).
        true_terrain: output (1), **simulation only**: index of the terrain under the centre of
            gravity in ``terrain_map.terrains``; -1 without a map.

    Truth models:
        ``"st"``: ``pcvfe_drake.vehicle.single_track.st_dynamics`` with theta = [mu under the car,
        C_Sf,
        C_Sr]; continuous state (7); any Drake integrator works (the default error-controlled
        RK3 is the fast choice).
        ``"mb"``: ``vehiclemodels.vehicle_dynamics_mb`` through :class:`MbTruth` (its compiled
        transcription, ``pcvfe_drake.vehicle.mb_kernel``), tire friction scaled to the mu under
        the car. Two state realisations (``mb_integration``):

        * ``"discrete"`` (default): 29 discrete states advanced every ``mb_period_s`` (the
          scenario's fitter sampling period, 0.01 s: every periodic reader of the state samples
          on that grid), each update integrating the MB equations over the period with the
          input and mu sampled at the update, by ``mb_method``: ``"rk23"`` (default: compiled
          error-controlled Bogacki-Shampine steps, ``MbTruth.advance``, the step carried from
          one update to the next in a second discrete state), ``"rk4"`` (1 ms RK4 substeps,
          stable above ~2 m/s) or ``"lsoda"`` (stiff-aware, restarted every period). The
          outputs hold between updates; independent of the simulator's integrator settings.
          The update runs :data:`MB_UPDATE_OFFSET_S` after each multiple of the period, so a
          command the NMPC computes on the grid is applied from its instant.
        * ``"continuous"``: 29 continuous states, integrated by the simulator's integrator
          (Drake's error-controlled RK3; mu looked up at every derivative).

        How the integrators compare (measured): ``docs/simulation.md``, "The plant's
        integrators".

        The MB truth exists for vehicles with CommonRoad parameter sets (Ford Escort, BMW 320i,
        VW Vanagon; ``mb_vehicle`` defaults to ``params.name``).

    Where the MB model ends (a wheel's ground speed <= 0 at speed: the car reverses or has spun;
    ``pcvfe_drake.vehicle.mb_truth``) the derivatives and updates raise
    :class:`pcvfe_drake.vehicle.mb_truth.MbSingularity` with the simulated time; the run loop
    scores it as the catastrophic failure ``truth_singular``.

    Friction changes with the terrain under the car: the ST derivatives (and each MB update)
    look up the terrain at the current ``(sx, sy)``. A car that leaves a map without an
    ``outside`` terrain stops the simulation with the terrain map's ``ValueError``.

    Args:
        params: vehicle parameters (default: Ford Escort).
        terrain_map: a ``pcvfe_drake.perception.terrain.TerrainMap``; None uses ``params.mu``
        everywhere.
        truth: ``"st"`` or ``"mb"``.
        x0: default initial ST state (7) of new contexts; default at rest at the origin, heading
            along +x. :meth:`set_initial_state` sets it in a given context.
        mb_vehicle: CommonRoad vehicle name for the MB truth (default ``params.name``).
        friction_scaling: MB tire friction mapping, see ``pcvfe_drake.vehicle.mb_truth``.
        mb_integration: ``"discrete"`` or ``"continuous"`` (MB only).
        mb_period_s: period of the MB discrete update [s] (``"discrete"`` only).
        mb_method: ``"rk23"``, ``"rk4"`` or ``"lsoda"``, the integrator inside a discrete MB
            update.
    """

    def __init__(
        self,
        params: VehicleParams | None = None,
        terrain_map=None,
        truth: str = "st",
        x0=None,
        *,
        mb_vehicle: str | None = None,
        friction_scaling: str = "peak_and_stiffness",
        mb_integration: str = "discrete",
        mb_period_s: float = 0.01,
        mb_method: str = "rk23",
    ) -> None:
        super().__init__()
        if truth not in TRUTH_MODELS:
            raise ValueError(f"VehiclePlant: truth={truth!r}; choose one of {TRUTH_MODELS}")
        if mb_integration not in ("discrete", "continuous"):
            raise ValueError(
                f"VehiclePlant: mb_integration={mb_integration!r}; "
                "choose 'discrete' or 'continuous'"
            )
        if not (math.isfinite(mb_period_s) and mb_period_s > 0):
            raise ValueError(f"VehiclePlant: mb_period_s={mb_period_s!r} must be > 0")
        self.params = params if params is not None else ford_escort()
        self.terrain_map = terrain_map
        self.truth = truth
        self.mb_integration = mb_integration if truth == "mb" else None
        self.mb_period_s = float(mb_period_s)
        if mb_method not in INTEGRATION_METHODS:
            raise ValueError(
                f"VehiclePlant: mb_method={mb_method!r}; choose one of {INTEGRATION_METHODS}"
            )
        self.mb_method = mb_method
        x0 = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]) if x0 is None else x0
        x0 = self._checked_st_state(x0, "x0")
        if terrain_map is not None:
            self._mu_index(x0)  # fail now, not at the first step, if x0 is off the map

        self._actuation_port = self.DeclareVectorInputPort("actuation", len(INPUT_NAMES))
        self.mb = None
        if truth == "st":
            self._state_index = None
            self._x0 = x0
            self.DeclareContinuousState(BasicVector(self._x0))
            state_ticket = self.xc_ticket()
        else:
            self.mb = MbTruth(mb_vehicle or self.params.name, friction_scaling)
            # Parameter vectors per terrain (index -1: no map, params.mu), built once.
            self._mb_params = {-1: self.mb.parameter_vector_for_mu(self.params.mu)}
            if terrain_map is not None:
                for k, terrain in enumerate(terrain_map.terrains):
                    self._mb_params[k] = self.mb.parameter_vector_for_mu(terrain.mu)
            self._x0 = self.mb.initial_state(x0)
            if mb_integration == "continuous":
                self._state_index = None
                self.DeclareContinuousState(BasicVector(self._x0))
                state_ticket = self.xc_ticket()
            else:
                self._state_index = self.DeclareDiscreteState(self._x0)
                # rk23's next step [s], carried from update to update (in the context, so a
                # cloned or reset context integrates alike).
                self._step_index = self.DeclareDiscreteState(np.array([self.mb_period_s]))
                self.DeclarePeriodicDiscreteUpdateEvent(
                    period_sec=self.mb_period_s,
                    offset_sec=MB_UPDATE_OFFSET_S,
                    update=self._mb_discrete_update,
                )
                state_ticket = self.xd_ticket()

        self._state_port = self.DeclareVectorOutputPort(
            "state", NX, self._calc_state, prerequisites_of_calc={state_ticket}
        )
        self._true_mu_port = self.DeclareVectorOutputPort(
            "true_mu", 1, self._calc_true_mu, prerequisites_of_calc={state_ticket}
        )
        self._true_terrain_port = self.DeclareVectorOutputPort(
            "true_terrain", 1, self._calc_true_terrain, prerequisites_of_calc={state_ticket}
        )

    # ------------------------------------------------------------------ set-up helpers
    @staticmethod
    def _checked_st_state(x, name: str) -> np.ndarray:
        x = np.asarray(x, dtype=float).reshape(-1)
        if x.shape != (NX,) or not np.all(np.isfinite(x)):
            raise ValueError(
                f"VehiclePlant: {name} must be {NX} finite numbers {STATE_NAMES}, got {x.tolist()}"
            )
        return x

    def set_initial_state(self, context, x_st) -> None:
        """Set this plant's state in ``context`` from an ST state (7) (MB: via ``init_mb``)."""
        x_st = self._checked_st_state(x_st, "initial state")
        if self.terrain_map is not None:
            self._mu_index(x_st)
        x = x_st if self.mb is None else self.mb.initial_state(x_st)
        if self._state_index is None:
            context.SetContinuousState(x)
        else:
            context.SetDiscreteState(self._state_index, x)
            context.SetDiscreteState(self._step_index, np.array([self.mb_period_s]))

    # ------------------------------------------------------------------ helpers
    def _mu_index(self, x) -> tuple[float, int]:
        """(mu, terrain index) under the centre of gravity; ``x`` is an ST or MB state (both
        start with sx, sy)."""
        if self.terrain_map is None:
            return self.params.mu, -1
        return self.terrain_map.mu_and_index_at_point(x[0], x[1])

    def _mb_parameters(self, mu: float, k: int) -> np.ndarray:
        """The multi-body parameter vector (``MbTruth.parameter_vector_for_mu``) for friction
        ``mu`` on terrain ``k``: the terrain's, built once, unless the terrain's mu varies in
        space (then one per 0.005 of mu, cached)."""
        if k < 0 or self.terrain_map.mu_fields[k] is None:
            return self._mb_params[k]
        key = ("mu", round(mu / 0.005))
        params = self._mb_params.get(key)
        if params is None:
            params = self._mb_params[key] = self.mb.parameter_vector_for_mu(key[1] * 0.005)
        return params

    def _raw_state(self, context) -> np.ndarray:
        if self._state_index is None:
            return context.get_continuous_state_vector().CopyToVector()
        return context.get_discrete_state(self._state_index).CopyToVector()

    def _st_of(self, context) -> np.ndarray:
        x = self._raw_state(context)
        return x if self.mb is None else st_state(x)

    def _actuation(self, context) -> np.ndarray:
        u = self._actuation_port.Eval(context)
        if not (math.isfinite(u[0]) and math.isfinite(u[1])):
            raise ValueError(
                f"VehiclePlant: input 'actuation' {list(INPUT_NAMES)} = {u.tolist()} is not "
                f"finite at t = {context.get_time():.4f} s"
            )
        return u

    # ------------------------------------------------------------------ dynamics
    def DoCalcTimeDerivatives(self, context, derivatives) -> None:  # noqa: N802 (Drake's name)
        if self._state_index is not None:  # a discrete MB state: nothing continuous
            return
        x = self._raw_state(context)
        u = self._actuation(context)
        if self.mb is None:
            mu, _ = self._mu_index(x)
            theta = np.array([mu, self.params.C_Sf, self.params.C_Sr])
            xdot = st_dynamics(x, u, self.params, theta)
        else:
            mu, k = self._mu_index(x)
            try:
                xdot = self.mb.rhs(x, u, self._mb_parameters(mu, k))
            except MbSingularity as exc:
                raise exc.at(context.get_time()) from exc
            # a finite sum has only finite terms; the exact test only where the sum is not
            if not math.isfinite(xdot.sum()) and not np.isfinite(xdot).all():
                raise ValueError(
                    f"VehiclePlant: MB derivatives are not finite at t = {context.get_time():.4f} "
                    f"s (state {x.tolist()}, input {u.tolist()})"
                )
        derivatives.get_mutable_vector().SetFromVector(xdot)

    def _mb_discrete_update(self, context, discrete_state) -> None:
        x = context.get_discrete_state(self._state_index).CopyToVector()
        u = self._actuation(context)
        mu, k = self._mu_index(x)
        try:
            if self.mb_method == "rk23":
                step = context.get_discrete_state(self._step_index).GetAtIndex(0)
                x_next, step = self.mb.advance(
                    x, u, self._mb_parameters(mu, k), self.mb_period_s, step
                )
                discrete_state.get_mutable_vector(self._step_index).SetAtIndex(0, step)
            else:
                x_next = self.mb.integrate(x, u, mu, self.mb_period_s, method=self.mb_method)
        except MbSingularity as exc:
            raise exc.at(context.get_time()) from exc
        discrete_state.get_mutable_vector(self._state_index).SetFromVector(x_next)

    # ------------------------------------------------------------------ outputs
    def _calc_state(self, context, output: BasicVector) -> None:
        output.SetFromVector(self._st_of(context))

    def _calc_true_mu(self, context, output: BasicVector) -> None:
        mu, _ = self._mu_index(self._raw_state(context))
        output.SetAtIndex(0, mu)

    def _calc_true_terrain(self, context, output: BasicVector) -> None:
        _, k = self._mu_index(self._raw_state(context))
        output.SetAtIndex(0, float(k))

    # ------------------------------------------------------------------ port accessors
    def get_actuation_input_port(self):
        return self._actuation_port

    def get_state_output_port(self):
        return self._state_port

    def get_true_mu_output_port(self):
        return self._true_mu_port

    def get_true_terrain_output_port(self):
        return self._true_terrain_port
