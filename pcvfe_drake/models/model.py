"""The workbench model: the ST model in force form plus composable effects, vectorised.

Right-hand side, evaluated for N batch rows at once (``z`` = the 7 ST states in CommonRoad order
followed by the effects' own states)::

    1. CommonRoad's input constraints (as ``pcvfe_drake.vehicle.single_track.constrain_inputs``)
    2. accel hooks            (e.g. motor_power_limit)            -> applied command a
    3. wheel_angle hooks      (steering_lag)                      -> road-wheel angle delta_w
    4. longitudinal hooks     a_x = a + sum(extra accelerations)  (drag, rolling_resistance, grade)
    5. axle loads             Fz_f = m (g lr - a_x h) / L,  Fz_r = m (g lf + a_x h) / L
                              (the longitudinal resistances transfer load too; load_transfer
                              hooks replace a_x here, e.g. suspension_lag: the load follows
                              the acceleration through the pitch mode)
    6. slip angles            alpha_f = delta_w - beta - lf r / v,  alpha_r = -beta + lr r / v
    7. friction hooks         mu_axle = mu x the factors (friction_speed, friction_load)
    8. tire forces            F_y = mu_axle C_S Fz alpha (linear; cornering_stiffness hooks
                              change C_S), or a tire hook
                              (tire_saturation, peak_tyre; it sees the state, the friction
                              factor and the base mu); tire_offsets hooks shift the slip
                              the law sees and add a side force to it (roll_camber);
                              wheel_slips hooks put the axle's two wheels at different
                              slips and loads, the axle's force the load-weighted mean
                              of the law at each (track_slip, wheel_camber)
    9. body_forces hooks      extra lateral force per axle and longitudinal acceleration
                              (wheel_force_steer: the wheels' forces turned by the steering)
       yaw and slip           r' = (lf F_yf - lr F_yr) / I_z,  beta' = (F_yf + F_yr) / (m v) - r
                              (r = psi_dot);  v' = a_x
   10. state_rates hooks      the effects' own states (steering_lag; they see the lateral
                              acceleration (F_yf + F_yr) / m: wheel_camber's roll)

Measurement hooks (gyro_bias, speed_scale, steering_offset) map the true state to what the
sensors report: rollouts start from the *un*-measured state of the measured sample and are
compared in measured form.

With no effects this is exactly CommonRoad's dynamic ST model
(``pcvfe_drake.vehicle.single_track``'s model
for v >= 0.5 m/s); the workbench only uses windows with v >= 1 m/s. Input hooks (input_delay)
rewrite a window's input sequence before the rollout.

Parameters: the *base* parameters (default ``mu``; any of ``mu, C_Sf, C_Sr``), one value per
context, then each effect's parameters, named ``effect.param``.
"""

from __future__ import annotations

import inspect
from dataclasses import asdict, dataclass

import numpy as np

from pcvfe_drake.models.data import DriveData
from pcvfe_drake.models.effects import (
    RHS_HOOKS,
    V_FLOOR_MPS,
    Effect,
    EffectParam,
    StepContext,
    get_effect,
)
from pcvfe_drake.vehicle.params import THETA_NAMES, VehicleParams, load_vehicle
from pcvfe_drake.vehicle.single_track import BETA, DELTA, NX, PSI, PSI_DOT, V, wrap_angle

MAX_SUBSTEPS = 50
"""Most RK4 steps per sample step (taken at low speed, slow rates or fast effects)."""
RK4_STABLE_HLAMBDA = 2.5
"""Largest step x |eigenvalue| used (classical RK4 is stable up to 2.78 on the real axis)."""

BASE_BOUNDS = {"mu": (0.05, 3.0), "C_Sf": (1.0, 200.0), "C_Sr": (1.0, 200.0)}


@dataclass(frozen=True)
class ParamInfo(EffectParam):
    """One entry of the model's parameter vector: an :class:`EffectParam` (bounds, start, scale,
    null value; its checks) plus where it comes from. ``name`` is the model-wide name
    (``"mu"``, ``"mu[sand]"`` or ``"effect.param"``)."""

    effect: str | None = None
    """The effect the parameter belongs to; None for the base parameters (mu, C_Sf, C_Sr)."""
    context: int | None = None
    """Context index of a base parameter; None for effect parameters."""


def applied_inputs(x: np.ndarray, u: np.ndarray, vp: VehicleParams):
    """CommonRoad's input constraints (as ``pcvfe_drake.vehicle.single_track.constrain_inputs``,
    which also
    returns derivatives) in the lean form the rollouts need: (steer_rate, accel), each (N,).

    The rollouts call it four times per step on a handful of rows, where numpy's per-call
    overhead is the cost: the rare cases (a steering angle or a speed at its limit) are
    found by one cheap test each before their masks are built."""
    delta, v = x[:, DELTA], x[:, V]
    steer = np.minimum(np.maximum(u[:, 0], vp.delta_dot_min), vp.delta_dot_max)
    if (delta <= vp.delta_min).any() or (delta >= vp.delta_max).any():
        stop = ((delta <= vp.delta_min) & (steer <= 0)) | ((delta >= vp.delta_max) & (steer >= 0))
        steer[stop] = 0.0
    above = v > vp.v_switch
    # a_max v_switch / v above the switching speed, a_max below (one masked division)
    upper = np.divide(vp.a_max * vp.v_switch, v, out=np.full(v.shape, vp.a_max), where=above)
    acc = np.minimum(np.maximum(u[:, 1], -vp.a_max), upper)
    if (v <= vp.v_min).any() or (v >= vp.v_max).any():
        halt = ((v <= vp.v_min) & (acc <= 0)) | ((v >= vp.v_max) & (acc >= 0))
        acc[halt] = 0.0
    return steer, acc


def _plus(a, b):
    """``a + b``, without the numpy call when ``b`` is the scalar 0 (a hook's "no change")."""
    return a if isinstance(b, float | int) and b == 0 else a + b


def _overrides(effect: Effect, hook: str) -> bool:
    return getattr(type(effect), hook) is not getattr(Effect, hook)


class WorkbenchModel:
    """Baseline ST model plus effects; immutable (``with_effects`` returns a new model).

    :meth:`simulate` runs its RK4 loop compiled (``models/compiled_rollout.py``) when every
    effect that changes the right-hand side is one the compiled code knows, else with
    :meth:`rhs` in numpy; ``compiled_rollout = False`` on an instance makes it use numpy
    always (the reference the compiled loop is tested against).

    Args:
        vehicle: nominal parameters (a preset name, a file, or VehicleParams; None = Ford).
        effects: effect names or instances.
        base_params: which of ``mu, C_Sf, C_Sr`` are fitted per context.
        contexts: context labels (one base-parameter set each).
    """

    compiled_rollout: bool = True
    """Use the compiled RK4 loop where it applies (the numpy loop otherwise)."""

    def __init__(
        self,
        vehicle: VehicleParams | str | None = None,
        effects=(),
        base_params: tuple[str, ...] = ("mu",),
        contexts: tuple[str, ...] | list[str] = ("all",),
    ) -> None:
        self.vehicle = vehicle if isinstance(vehicle, VehicleParams) else load_vehicle(vehicle)
        for b in base_params:
            if b not in THETA_NAMES:
                raise ValueError(f"base parameter {b!r} is not one of {THETA_NAMES}")
        self.base_params = tuple(base_params)
        self.contexts = list(contexts) or ["all"]
        eff = [get_effect(e) for e in effects]
        names = [e.name for e in eff]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"effect(s) {dup} given more than once")
        self.effects: list[Effect] = sorted(eff, key=lambda e: e.order)
        self._tire_takes_ctx = {
            e.name: len(inspect.signature(e.tire).parameters) >= 5 for e in self.effects
        }
        self._sensors = [e for e in self.effects if e.measurement]
        self.params: list[ParamInfo] = []
        nominal = dict(zip(THETA_NAMES, self.vehicle.theta, strict=True))
        for b in self.base_params:
            lo, hi = BASE_BOUNDS[b]
            unit = "-" if b == "mu" else "1/rad"
            for c, label in enumerate(self.contexts):
                name = b if len(self.contexts) == 1 else f"{b}[{label}]"
                v0 = float(np.clip(nominal[b], lo, hi))
                self.params.append(
                    ParamInfo(name, unit, lo, hi, v0, 0.1 * v0, v0, effect=None, context=c)
                )
        self._state_slices: list[slice] = []
        start = NX
        for e in self.effects:
            for q in e.params:
                self.params.append(
                    ParamInfo(**{**asdict(q), "name": f"{e.name}.{q.name}"}, effect=e.name)
                )
            self._state_slices.append(slice(start, start + e.n_states))
            start += e.n_states
        self.nz = start
        # Per hook, the effects that override it (in order): the right-hand side runs once per
        # RK4 stage for every window, so it skips the hooks that would do nothing.
        pairs = list(zip(self.effects, self._state_slices, strict=True))
        self._hooked = {
            hook: [(e, sl) for e, sl in pairs if _overrides(e, hook)] for hook in RHS_HOOKS
        }
        self._with_states = [(e, sl) for e, sl in pairs if e.n_states]
        self._plan: dict | None | bool = False  # the compiled rollout's plan, on first use

    # ------------------------------------------------------------------ composition
    def with_effects(self, *effects) -> WorkbenchModel:
        """A new model with these effects added (names or :class:`Effect` instances)."""
        return WorkbenchModel(
            self.vehicle, [*self.effects, *effects], self.base_params, self.contexts
        )

    @property
    def effect_names(self) -> list[str]:
        return [e.name for e in self.effects]

    @property
    def param_names(self) -> list[str]:
        return [p.name for p in self.params]

    @property
    def n_params(self) -> int:
        return len(self.params)

    @property
    def state_names(self) -> list[str]:
        names = ["sx", "sy", "delta", "v", "psi", "psi_dot", "beta"]
        for e in self.effects:
            names += [f"{e.name}.{s}" for s in e.state_names]
        return names

    def initial_theta(self) -> np.ndarray:
        return np.array([p.initial for p in self.params])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array([p.lower for p in self.params]), np.array([p.upper for p in self.params])

    def scales(self) -> np.ndarray:
        return np.array([p.scale for p in self.params])

    def effect_param_indices(self, effect_name: str) -> list[int]:
        return [i for i, p in enumerate(self.params) if p.effect == effect_name]

    def transfer(self, theta_from: np.ndarray, other: WorkbenchModel) -> np.ndarray:
        """This model's initial vector with values copied by name from ``other``'s vector."""
        values = dict(zip(other.param_names, theta_from, strict=True))
        return np.array([values.get(p.name, p.initial) for p in self.params])

    # ------------------------------------------------------------------ evaluation
    def _unpack(self, theta_rows: np.ndarray, ctx_rows: np.ndarray):
        """Per-row base parameters (dict of (N,)) and per-effect parameter dicts."""
        n = theta_rows.shape[0]
        base = dict(zip(THETA_NAMES, (np.full(n, v) for v in self.vehicle.theta), strict=True))
        eff: dict[str, dict[str, np.ndarray]] = {e.name: {} for e in self.effects}
        for j, p in enumerate(self.params):
            if p.effect is None:
                sel = ctx_rows == p.context
                base[p.name.split("[")[0]][sel] = theta_rows[sel, j]
            else:
                eff[p.effect][p.name.split(".", 1)[1]] = theta_rows[:, j]
        return base, eff

    def rhs(self, z: np.ndarray, u: np.ndarray, base: dict, eff: dict) -> np.ndarray:
        """Time derivative of the augmented state ``z`` (N, nz) under inputs ``u`` (N, 2)."""
        vp = self.vehicle
        x = z[:, :NX]
        hooked = self._hooked
        steer, acc = applied_inputs(x, u, vp)
        ctx = StepContext(x, z[:, NX:NX], steer, acc, vp, mu=base["mu"])
        for e, sl in hooked["accel"]:
            ctx.states = z[:, sl]
            acc = e.accel(acc, ctx, eff[e.name])
            ctx.accel = acc
        delta_w = x[:, DELTA]
        for e, sl in hooked["wheel_angle"]:
            ctx.states = z[:, sl]
            delta_w = e.wheel_angle(delta_w, ctx, eff[e.name])
        a_long = acc.copy()
        for e, sl in hooked["longitudinal"]:
            ctx.states = z[:, sl]
            extra = e.longitudinal(ctx, eff[e.name])
            if extra is not None:
                a_long = a_long + extra
        ctx.a_long = a_long
        a_load = a_long
        for e, sl in hooked["load_transfer"]:
            ctx.states = z[:, sl]
            out = e.load_transfer(a_load, ctx, eff[e.name])
            if out is not None:
                a_load = out
        v = x[:, V]
        vd = np.maximum(v, V_FLOOR_MPS)
        r = x[:, PSI_DOT]
        beta = x[:, BETA]
        wheelbase = vp.lf + vp.lr
        fzf = vp.m * (vp.g * vp.lr - a_load * vp.h) / wheelbase
        fzr = vp.m * (vp.g * vp.lf + a_load * vp.h) / wheelbase
        alpha_f = delta_w - beta - vp.lf * r / vd
        alpha_r = -beta + vp.lr * r / vd
        axles = (
            ("front", fzf, alpha_f, base["C_Sf"], vp.m * vp.g * vp.lr / wheelbase),
            ("rear", fzr, alpha_r, base["C_Sr"], vp.m * vp.g * vp.lf / wheelbase),
        )
        forces = []
        for axle, fz, alpha, c_s, fz_static in axles:
            ctx.axle, ctx.fz_static = axle, fz_static
            scale = 1.0
            for e, _ in hooked["friction"]:
                factor = e.friction(fz, ctx, eff[e.name])
                if factor is not None:
                    scale = scale * factor
            ctx.mu_scale = scale
            for e, _ in hooked["cornering_stiffness"]:
                stiff = e.cornering_stiffness(c_s, ctx, eff[e.name])
                if stiff is not None:
                    c_s = stiff
            # (no friction hook: mu x 1.0 is mu, one multiplication less per evaluation)
            c_alpha = (base["mu"] * scale if hooked["friction"] else base["mu"]) * c_s * fz
            side = None
            for e, sl in hooked["tire_offsets"]:
                ctx.states = z[:, sl]
                out = e.tire_offsets(fz, ctx, eff[e.name])
                if out is not None:
                    alpha, side = alpha + out[0], out[1] if side is None else side + out[1]
            spread = None
            for e, sl in hooked["wheel_slips"]:
                ctx.states = z[:, sl]
                out = e.wheel_slips(ctx, eff[e.name])
                if out is not None and spread is None:
                    spread = out
                elif out is not None:
                    spread = (spread[0] + out[0], spread[1] + out[1], spread[2] + out[2] - 0.5)
            if spread is None:
                fy = self._tire_law(alpha, fz, c_alpha, ctx, eff)
            else:
                fy = spread[2] * self._tire_law(alpha + spread[0], fz, c_alpha, ctx, eff) + (
                    1.0 - spread[2]
                ) * self._tire_law(alpha + spread[1], fz, c_alpha, ctx, eff)
            forces.append(fy if side is None else fy + side)
        fyf, fyr = forces
        ctx.delta_wheel = delta_w
        for e, _ in hooked["body_forces"]:
            out = e.body_forces(fyf, fyr, ctx, eff[e.name])
            if out is not None:
                fyf, fyr, a_long = (_plus(fyf, out[0]), _plus(fyr, out[1]), _plus(a_long, out[2]))
        lateral = fyf + fyr
        ctx.a_lat = lateral / vp.m
        zdot = np.empty_like(z)
        course = x[:, PSI] + beta
        zdot[:, 0] = v * np.cos(course)
        zdot[:, 1] = v * np.sin(course)
        zdot[:, DELTA] = steer
        zdot[:, V] = a_long
        zdot[:, PSI] = r
        zdot[:, PSI_DOT] = (vp.lf * fyf - vp.lr * fyr) / vp.I_z
        zdot[:, BETA] = lateral / (vp.m * vd) - r
        for e, sl in self._with_states:
            if not e.exact_states:
                ctx.states = z[:, sl]
                zdot[:, sl] = e.state_rates(ctx, x[:, DELTA], eff[e.name])
            else:
                zdot[:, sl] = 0.0
        return zdot

    def _tire_law(self, alpha, fz, c_alpha, ctx: StepContext, eff: dict):
        """Step 8's law at slip ``alpha``: linear, or the last ``tire`` hook's."""
        fy = None
        for e, _ in self._hooked["tire"]:
            if self._tire_takes_ctx[e.name]:
                out = e.tire(alpha, fz, c_alpha, eff[e.name], ctx)
            else:
                out = e.tire(alpha, fz, c_alpha, eff[e.name])
            if out is not None:
                fy = out
        return c_alpha * alpha if fy is None else fy

    def stable_step(self, base: dict, speeds: np.ndarray, eff: dict | None = None) -> float:
        """Largest RK4 step [s] for the lateral dynamics at the lowest speed in ``speeds``.

        The yaw/slip eigenvalues are about ``-mu C_S g max(1, m lf lr / I_z) / v`` (they grow
        like 1/v); the step keeps ``h |lambda| <= RK4_STABLE_HLAMBDA``. A tyre effect whose
        small-slip stiffness is not ``mu C_S`` says so with ``stiffness_mu``, which then sets
        the step alone (the steepest slope of a tyre with a peak is at small slip, whatever
        its peak: a peak far above the data's friction must not shrink the step), a
        ``cornering_stiffness`` hook with ``stiffness_factor`` (``eff``: the effects' parameter
        dicts).
        """
        vp = self.vehicle
        v_min = max(float(np.min(speeds)) if np.size(speeds) else 1.0, V_FLOOR_MPS)
        own = None  # a tyre law's own small-slip stiffness replaces the linear tyre's mu C_S
        for e in self.effects if eff is not None else ():
            alt = e.stiffness_mu(base["mu"], vp, eff[e.name])
            if alt is not None:
                own = alt if own is None else np.maximum(own, alt)
        mu = base["mu"] if own is None else own
        for e in self.effects if eff is not None else ():
            factor = e.stiffness_factor(eff[e.name])
            if factor is not None:
                mu = mu * factor
        stiff = float(np.max(mu * np.maximum(base["C_Sf"], base["C_Sr"])))
        lam = stiff * vp.g * max(1.0, vp.m * vp.lf * vp.lr / vp.I_z) / v_min
        return RK4_STABLE_HLAMBDA / max(lam, 1e-9)

    def simulate(
        self,
        theta_rows: np.ndarray,
        data: DriveData,
        starts: np.ndarray,
        horizon: int,
        ctx_rows: np.ndarray | None = None,
        x0: np.ndarray | None = None,
        sensitivity: np.ndarray | None = None,
    ) -> np.ndarray:
        """Roll out windows of ``horizon`` steps from the measured states at ``starts``.

        Args:
            theta_rows: parameter vector(s), (P,) or one per window (N, P).
            data: the log (inputs and measured initial states come from it).
            starts: window start samples (N,).
            horizon: steps per window.
            ctx_rows: context index per window (default: the context at the start).
            x0: initial ST states (N, 7) as measured (default: ``data.x0[starts]``).
            sensitivity: (N, horizon + 1, 7), filled with the ST states' derivatives along
                each row's base mu (:meth:`mu_sensitivity`, which says when it applies).
        Returns:
            Z (N, horizon + 1, nz): RK4 with the inputs held over each sample step. Rollouts
            start from the measured state passed back through the sensor effects'
            ``unmeasure``; the ST part of Z is what the sensors would report (``measure``),
            the effects' own states are true values.
        """
        starts = np.asarray(starts, dtype=int)
        n = starts.size
        theta_rows = np.broadcast_to(np.atleast_2d(theta_rows), (n, self.n_params))
        if ctx_rows is None:
            ctx_rows = data.context[starts]
        base, eff = self._unpack(theta_rows, ctx_rows)
        idx = starts[:, None] + np.arange(horizon)[None, :]
        U = data.u[idx]
        x_start = data.x0[starts] if x0 is None else np.asarray(x0, dtype=float)
        for e in reversed(self._sensors):
            x_start = e.unmeasure(x_start, eff[e.name])
        parts = [x_start]
        for e in self.effects:
            U = e.inputs(U, data, starts, eff[e.name])
            if e.n_states:
                parts.append(e.initial_states(data, starts, eff[e.name]))
        Z = np.empty((n, horizon + 1, self.nz))
        Z[:, 0] = np.concatenate(parts, axis=1)
        limits = [e.max_step(eff[e.name]) for e in self.effects]
        limits = [m for m in limits if m is not None and m > 0]
        limits.append(self.stable_step(base, data.x[idx, V], eff))
        substeps = int(min(MAX_SUBSTEPS, max(1, np.ceil(data.dt / min(limits) - 1e-9))))
        h = data.dt / substeps
        plan = self._compiled_plan()
        if plan is not None:
            from pcvfe_drake.models.compiled_rollout import rollout

            rollout(Z, U, substeps, h, base, eff, plan, S=sensitivity)
            return self._measured(Z, eff)
        if sensitivity is not None:
            raise ValueError("WorkbenchModel.simulate: a sensitivity needs the compiled rollout")
        pairs = zip(self.effects, self._state_slices, strict=True)
        exact = [(e, sl) for e, sl in pairs if e.exact_states]

        def stage(z0, z, offset):
            for e, sl in exact:
                z[:, sl] = e.states_at(z0[:, sl], z0[:, :NX], z[:, :NX], offset, eff[e.name])
            return z

        for k in range(horizon):
            z = Z[:, k]
            uk = U[:, k]
            for _ in range(substeps):
                k1 = self.rhs(z, uk, base, eff)
                k2 = self.rhs(stage(z, z + 0.5 * h * k1, 0.5 * h), uk, base, eff)
                k3 = self.rhs(stage(z, z + 0.5 * h * k2, 0.5 * h), uk, base, eff)
                k4 = self.rhs(stage(z, z + h * k3, h), uk, base, eff)
                z = stage(z, z + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4), h)
            Z[:, k + 1] = z
        return self._measured(Z, eff)

    def mu_sensitivity(
        self, theta_rows: np.ndarray, data: DriveData, starts: np.ndarray, horizon: int
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """``(Z, dZ/dmu)``: :meth:`simulate`'s rollout and the exact derivative of its ST states
        (N, horizon + 1, 7) along each row's base ``mu`` (forward mode through the same RK4
        steps, ``compiled_rollout``), instead of finite differences. None where it does not
        apply: the rollout is not compiled, or a sensor effect reports other states than the
        model's (its derivative is not the states')."""
        if self._compiled_plan() is None or self._sensors:
            return None
        n = np.asarray(starts).size
        sens = np.zeros((n, horizon + 1, NX))
        Z = self.simulate(theta_rows, data, starts, horizon, sensitivity=sens)
        return Z, sens

    def load_compiled_rollout(self) -> bool:
        """Load the compiled rollout now (numba's compilation or disk cache) rather than in the
        first rollout, so that a real-time loop's first refit does not pay for it; False when
        this model is rolled out by numpy."""
        plan = self._compiled_plan()
        if plan is None:
            return False
        from pcvfe_drake.models.compiled_rollout import load

        load(self, plan)
        return True

    def _compiled_plan(self) -> dict | None:
        """The compiled rollout's plan for this model's effects, found once; None: the numpy
        rollout (effects the compiled code does not know, or ``compiled_rollout`` off)."""
        if not self.compiled_rollout:
            return None
        if self._plan is False:
            from pcvfe_drake.models.compiled_rollout import compiled_effect_plan

            self._plan = compiled_effect_plan(self.effects, self.vehicle)
        return self._plan

    def _measured(self, Z: np.ndarray, eff: dict) -> np.ndarray:
        """``Z`` with its ST part as the sensor effects report it."""
        if self._sensors:
            y = Z[:, :, :NX]
            for e in self._sensors:
                y = e.measure(y, {k: v[:, None] for k, v in eff[e.name].items()})
            Z[:, :, :NX] = y
        return Z

    def errors(
        self, theta_rows: np.ndarray, data: DriveData, starts: np.ndarray, horizon: int
    ) -> np.ndarray:
        """Prediction minus measurement (N, horizon, 7) for steps 1..horizon (heading wrapped)."""
        Z = self.simulate(theta_rows, data, starts, horizon)
        return rollout_errors(Z, data, starts, horizon)


def rollout_errors(Z: np.ndarray, data: DriveData, starts: np.ndarray, horizon: int) -> np.ndarray:
    """:meth:`WorkbenchModel.errors` of the rollout ``Z`` (N, horizon + 1, nz)."""
    idx = np.asarray(starts)[:, None] + np.arange(1, horizon + 1)[None, :]
    err = Z[:, 1:, :NX] - data.x[idx]
    err[:, :, PSI] = wrap_angle(err[:, :, PSI])
    return err
