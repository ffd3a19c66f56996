"""The effect library: named, physically parameterised additions to the single-track model.

An effect changes one or more stages of the model's right-hand side (see
:mod:`pcvfe_drake.models.model` for the order of the stages):

==================  =====================================================================
hook                what it changes
==================  =====================================================================
``inputs``          the input sequence of a window before the rollout (dead time)
``accel``           the applied longitudinal acceleration command (power limit)
``wheel_angle``     the road-wheel angle the tires see (lag, offset)
``load_transfer``   the longitudinal acceleration the axle loads follow (suspension pitch)
``friction``        a factor on the friction of one axle, seeing the state and the axle load
                    (speed- and load-dependent friction)
``cornering_stiffness`` the axle's normalised cornering stiffness (not its peak)
``tire_offsets``    a slip shift inside the tyre law and a side force added to it, per axle
                    (roll camber)
``wheel_slips``     the two wheels of an axle at different slips and loads: the law is
                    evaluated at each and the axle gets the load-weighted mean (track width)
``body_forces``     extra axle lateral forces and longitudinal acceleration after the tyres
``tire``            the lateral tire force law (saturation); sees the state too
``longitudinal``    extra longitudinal acceleration [m/s^2] (drag, rolling, grade)
``state_rates``     time derivatives of the effect's own states (lag)
``initial_states``  the effect's states at the start of a window, from the measured history
``measure``         what the sensors report for a true ST state (gyro bias, speed scale,
                    steering-encoder offset), with ``unmeasure`` its inverse for the start
==================  =====================================================================

Every parameter has a unit, bounds, a starting value, a typical scale (for finite differences
and step sizes) and a *null* value at which the effect does nothing (for the signature test and
reports). A user adds an effect by subclassing :class:`Effect` and calling
:func:`register_effect`; see ``docs/workbench.md``.

Parameter values arrive as a dict ``{param_name: (N,) array}``: one value per batch row, so a
rollout can evaluate many parameter vectors at once (finite-difference sensitivities).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from scipy.signal import lfilter

if TYPE_CHECKING:
    from pcvfe_drake.models.data import DriveData

RHO_AIR_KGPM3 = 1.225
"""Air density used by the drag effect [kg/m^3] (sea level, 15 degC)."""
SIGN_WIDTH_MPS = 0.2
"""Width of ``rolling_resistance``'s smooth sign ``tanh(v / width)`` [m/s] (differentiable at
standstill)."""
POWER_WIDTH_MPS2 = 0.05
"""Width of ``motor_power_limit``'s smooth minimum [m/s^2] (keeps the fit differentiable)."""
POWER_V_MIN_MPS = 0.5
"""Speed below which ``motor_power_limit`` evaluates its limit at this speed [m/s]."""


@dataclass(frozen=True)
class EffectParam:
    """One physical parameter of an effect.

    Attributes:
        name: short name, unique within the effect (the model calls it ``effect.name``).
        unit: SI unit as text.
        lower, upper: bounds used by the estimator.
        initial: starting value of the fit.
        scale: typical magnitude (finite-difference step and step-size scaling).
        null: the value at which the effect has no influence.
        description: one line for reports.
    """

    name: str
    unit: str
    lower: float
    upper: float
    initial: float
    scale: float
    null: float
    description: str = ""

    def __post_init__(self) -> None:
        if not (self.lower <= self.initial <= self.upper):
            raise ValueError(
                f"EffectParam {self.name}: initial {self.initial} outside [{self.lower}, "
                f"{self.upper}]"
            )
        if self.scale <= 0:
            raise ValueError(f"EffectParam {self.name}: scale must be > 0, got {self.scale}")


@dataclass
class StepContext:
    """What an effect sees inside one evaluation of the right-hand side (N batch rows).

    Attributes:
        x: ST states (N, 7) in CommonRoad order.
        states: this effect's own states (N, n_states) (empty when it has none).
        steer: constrained steering rate [rad/s] (N,).
        accel: constrained acceleration command [m/s^2] (N,) (after ``accel`` hooks).
        vehicle: the nominal :class:`~pcvfe_drake.vehicle.params.VehicleParams`.
        a_long: the longitudinal acceleration [m/s^2] (N,): the command plus the
            ``longitudinal`` hooks' resistances (set before the axle loads are computed).
        axle: ``"front"`` or ``"rear"`` inside the ``friction`` and ``tire`` hooks.
        fz_static: the static load [N] of that axle (for load sensitivity).
        mu_scale: the product of the ``friction`` factors of that axle (N,) (in ``tire``).
        mu: the row's base friction coefficient ``mu`` (N,) (of its context); with a
            ``friction_is_peak`` tyre it is the friction peak.
        delta_wheel: the road-wheel angle [rad] (N,) (in ``body_forces``).
        a_lat: the lateral acceleration [m/s^2] (N,) the axles' forces give the car,
            ``(F_yf + F_yr) / m`` after the ``body_forces`` hooks (in ``state_rates``).
        cache: values an effect computes once per evaluation and reuses in its later hook
            calls (both axles, both wheels), keyed by the effect's name: a rollout evaluates
            the right-hand side on a handful of rows, where each numpy call's overhead, not
            its arithmetic, is the cost. Valid for this evaluation only (a new context each);
            an entry keeps the objects it was formed from and is formed afresh when a later
            call passes others (a load, a stiffness, the parameters).
    """

    x: np.ndarray
    states: np.ndarray
    steer: np.ndarray
    accel: np.ndarray
    vehicle: object
    a_long: np.ndarray | None = None
    axle: str = ""
    fz_static: float = 0.0
    mu_scale: np.ndarray | float = 1.0
    mu: np.ndarray | float = 1.0
    delta_wheel: np.ndarray | float = 0.0
    a_lat: np.ndarray | float = 0.0
    cache: dict = field(default_factory=dict)


V_FLOOR_MPS = 0.1
"""Speed below which the force-form model is evaluated at this speed (matches vehicle.py)."""

RHS_HOOKS = (
    "accel",
    "wheel_angle",
    "longitudinal",
    "load_transfer",
    "friction",
    "cornering_stiffness",
    "tire_offsets",
    "wheel_slips",
    "tire",
    "body_forces",
)
"""The :class:`Effect` hooks the right-hand side calls (each is skipped for an effect that
keeps the base class's, which changes nothing)."""


class Effect:
    """Base class of an effect; subclasses override the hooks they need.

    Class attributes to set: ``name``, ``description``, ``params`` (tuple of
    :class:`EffectParam`), ``state_names`` (own states, default none), ``order`` (position in
    the wheel-angle chain; lower runs first), and the residual signature: ``signature_state``
    (the ST state whose residual the effect explains), ``signature_label`` (a regressor name
    for messages) and :meth:`signature_regressors`.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    params: ClassVar[tuple[EffectParam, ...]] = ()
    state_names: ClassVar[tuple[str, ...]] = ()
    order: ClassVar[int] = 10
    signature_state: ClassVar[str] = "v"
    signature_label: ClassVar[str] = ""
    #: Starting points tried before the local fit (one row per start); None = ``initial`` only.
    starts: ClassVar[tuple[tuple[float, ...], ...] | None] = None
    #: True for a tyre law with which the base parameter ``mu`` IS the friction peak (the
    #: largest lateral force / Fz of an axle, times the friction factors), not a factor on
    #: the small-slip stiffness; code downstream (fitters, friction sources, reports) reads
    #: base mu as the peak when a model has such an effect.
    friction_is_peak: ClassVar[bool] = False

    @property
    def n_states(self) -> int:
        return len(self.state_names)

    # --- hooks (defaults: no change) -------------------------------------------------------
    def inputs(self, U: np.ndarray, data: DriveData, starts: np.ndarray, p: dict) -> np.ndarray:
        """Input sequence (N, H, 2) of windows starting at sample ``starts`` (N,)."""
        return U

    def accel(self, accel: np.ndarray, ctx: StepContext, p: dict) -> np.ndarray:
        """Applied acceleration command [m/s^2] (N,)."""
        return accel

    def wheel_angle(self, delta: np.ndarray, ctx: StepContext, p: dict) -> np.ndarray:
        """Road-wheel angle [rad] (N,) seen by the front tire."""
        return delta

    def load_transfer(self, a_x, ctx: StepContext, p: dict):
        """The longitudinal acceleration [m/s^2] (N,) that moves load between the axles
        (default: ``a_x``, the command plus the ``longitudinal`` resistances, instantaneous);
        ``ctx.states`` are the effect's own states. Return None for no change."""
        return None

    def friction(self, fz, ctx: StepContext, p: dict):
        """A factor (N,) on the friction coefficient of the axle ``ctx.axle`` whose load is
        ``fz`` [N] (the cornering stiffness ``mu C_S Fz`` and a tire law's peak scale with
        it); ``ctx.x`` is the state. Return None for no change."""
        return None

    def body_forces(self, fyf, fyr, ctx: StepContext, p: dict):
        """Extra forces after the tyre law: ``(dF_yf [N], dF_yr [N], da_x [m/s^2])`` (each
        (N,) or 0) added to the axles' lateral forces (yaw and slip) and to the longitudinal
        acceleration (not to the load transfer); ``ctx.delta_wheel`` is the road-wheel angle.
        None for none."""
        return None

    def cornering_stiffness(self, c_s, ctx: StepContext, p: dict):
        """The normalised cornering stiffness [1/rad] (N,) of the axle ``ctx.axle`` (default
        ``C_Sf`` or ``C_Sr``); unlike a ``friction`` factor it leaves a tyre law's peak alone.
        Return None for no change."""
        return None

    def tire_offsets(self, fz, ctx: StepContext, p: dict):
        """Offsets of the axle ``ctx.axle``'s tyre law (Pacejka's ``S_H``, ``S_V``):
        ``(slip shift [rad], side force [N])``, each (N,) or 0; the law is evaluated at
        ``alpha + shift`` and the force added to its result (positive: toward +y, the left).
        None for none."""
        return None

    def wheel_slips(self, ctx: StepContext, p: dict):
        """The two wheels of the axle ``ctx.axle``: ``(d_left [rad], d_right [rad], share)``,
        each (N,): their slips relative to the axle's single-track slip and the left wheel's
        share of the axle load (0.5: equal); the tyre law (offsets included) is evaluated at
        ``alpha + d_left`` and ``alpha + d_right`` with the axle's load and the axle gets
        ``share F_left + (1 - share) F_right`` (the laws are linear in the load). None for
        none."""
        return None

    def tire(self, alpha, fz, c_alpha, p: dict, ctx: StepContext | None = None):
        """Lateral tire force [N] for slip ``alpha`` [rad], load ``fz`` [N], stiffness
        ``c_alpha`` [N/rad] (friction factors included) on axle ``ctx.axle`` in state
        ``ctx.x``; return None to keep the linear law. (A subclass may leave out ``ctx``.)"""
        return None

    #: True for effects that change only what the sensors report (``measure``/``unmeasure``).
    measurement: ClassVar[bool] = False

    def measure(self, y: np.ndarray, p: dict) -> np.ndarray:
        """Measured ST states for true states ``y`` (N, ..., 7); the values of ``p`` have
        shape (N, 1, ...) broadcasting along the window. Must not modify ``y`` in place."""
        return y

    def unmeasure(self, y: np.ndarray, p: dict) -> np.ndarray:
        """The inverse of :meth:`measure` for initial states (N, 7), ``p`` values (N,)."""
        return y

    def longitudinal(self, ctx: StepContext, p: dict):
        """Extra longitudinal acceleration [m/s^2] (N,), or None."""
        return None

    #: True when the effect advances its states itself with :meth:`states_at` (exactly, e.g.
    #: a stiff linear lag) instead of by the model's RK4 from :meth:`state_rates`.
    exact_states: ClassVar[bool] = False

    def states_at(self, s0, x_start, x_stage, offset: float, p: dict) -> np.ndarray:
        """For ``exact_states`` effects: own states ``offset`` seconds into an integration step
        that starts with states ``s0`` and ST state ``x_start``; ``x_stage`` is the ST state
        at that time (N, 7)."""
        raise NotImplementedError

    def stiffness_mu(self, mu: np.ndarray, vehicle, p: dict) -> np.ndarray | None:
        """For a tyre law whose small-slip stiffness is not ``mu C_S Fz``: the friction level
        (N,) that would give the linear tyre its stiffness (the model's integration step is
        chosen from it); None when the stiffness is the baseline's."""
        return None

    def stiffness_factor(self, p: dict) -> np.ndarray | None:
        """For a ``cornering_stiffness`` hook: the largest factor (N,) it puts on C_S (the
        model's integration step is chosen from it); None for none."""
        return None

    def max_step(self, p: dict) -> float | None:
        """Largest integration step [s] the effect tolerates (e.g. a fast time constant)."""
        return None

    def state_rates(self, ctx: StepContext, delta_cmd: np.ndarray, p: dict) -> np.ndarray:
        """Time derivative (N, n_states) of the effect's states."""
        return np.zeros((ctx.x.shape[0], 0))

    def initial_states(self, data: DriveData, starts: np.ndarray, p: dict) -> np.ndarray:
        """The effect's states (N, n_states) at the window starts, from the measured history."""
        return np.zeros((len(starts), 0))

    def signature_regressors(self, data: DriveData) -> np.ndarray:
        """Regressors (n_samples, m) whose correlation with the residual of
        ``signature_state`` is the effect's signature."""
        return np.ones((data.n, 1))

    def describe(self) -> dict:
        return {
            "name": self.name,
            "description": self.description,
            "states": list(self.state_names),
            "signature": f"{self.signature_state} residual vs {self.signature_label}",
            "params": [
                {
                    "name": q.name,
                    "unit": q.unit,
                    "lower": q.lower,
                    "upper": q.upper,
                    "initial": q.initial,
                    "null": q.null,
                    "description": q.description,
                }
                for q in self.params
            ],
        }


def _smooth_sign(v, width: float = SIGN_WIDTH_MPS):
    return np.tanh(np.asarray(v) / width)


class Drag(Effect):
    """Aerodynamic drag: ``a = -0.5 rho CdA v|v| / m``."""

    name = "drag"
    description = "aerodynamic drag, a = -0.5 rho CdA v|v| / m"
    params = (
        EffectParam("CdA", "m^2", 0.0, 5.0, 0.5, 0.5, 0.0, "drag area (drag coefficient x area)"),
    )
    signature_state = "v"
    signature_label = "v^2"

    def longitudinal(self, ctx, p):
        v = ctx.x[:, 3]
        return -0.5 * RHO_AIR_KGPM3 * p["CdA"] * v * np.abs(v) / ctx.vehicle.m

    def signature_regressors(self, data):
        return (data.x[:, 3] * np.abs(data.x[:, 3]))[:, None]


class RollingResistance(Effect):
    """Rolling resistance: ``a = -c_rr g sign(v)`` (smooth sign)."""

    name = "rolling_resistance"
    description = "rolling resistance, a = -c_rr g sign(v)"
    params = (EffectParam("c_rr", "-", 0.0, 0.1, 0.01, 0.01, 0.0, "rolling resistance coeff."),)
    signature_state = "v"
    signature_label = "a constant (sign(v))"

    def longitudinal(self, ctx, p):
        return -p["c_rr"] * ctx.vehicle.g * _smooth_sign(ctx.x[:, 3])

    def signature_regressors(self, data):
        return _smooth_sign(data.x[:, 3])[:, None]


class SteeringLag(Effect):
    """First-order lag of the road-wheel angle behind the measured (commanded) angle.

    Adds the state ``delta_wheel`` with ``tau d(delta_wheel)/dt = delta - delta_wheel``. The
    lag is integrated exactly (the measured angle ramps linearly over each step because the
    steering rate is held), so any ``tau >= 0`` works at any sample rate and ``tau = 0`` is
    exactly the baseline.
    """

    name = "steering_lag"
    description = "first-order lag of the wheel angle, tau ddelta_w/dt = delta - delta_w"
    params = (EffectParam("tau", "s", 0.0, 1.0, 0.1, 0.05, 0.0, "steering time constant"),)
    state_names = ("delta_wheel",)
    exact_states = True
    order = 0
    signature_state = "psi_dot"
    signature_label = "steering rate x speed"
    starts = ((0.05,), (0.2,), (0.5,))

    def wheel_angle(self, delta, ctx, p):
        return ctx.states[:, 0]

    def states_at(self, s0, x_start, x_stage, offset, p):
        if offset <= 0.0:
            return s0
        tau = np.asarray(p["tau"], dtype=float)
        slope = (x_stage[:, 2] - x_start[:, 2]) / offset
        e0 = s0[:, 0] - x_start[:, 2]
        safe = np.maximum(tau, 1e-12)
        e = np.where(tau > 1e-9, -safe * slope + (e0 + safe * slope) * np.exp(-offset / safe), 0.0)
        return (x_stage[:, 2] + e)[:, None]

    def initial_states(self, data, starts, p):
        # The lag run over the (denoised) measured angle from the start of the log, exactly
        # for an angle that ramps linearly between samples: with e = delta_w - delta and
        # s_k the ramp slope, e[k+1] = a e[k] - tau (1 - a) s_k, a = exp(-dt / tau).
        tau = np.asarray(p["tau"], dtype=float)
        out = np.empty(len(starts))
        delta = data.x0[:, 2]
        slope = np.diff(delta) / data.dt
        for value in np.unique(tau):
            rows = tau == value
            if value <= 1e-9:
                out[rows] = delta[starts[rows]]
                continue
            a = np.exp(-data.dt / value)
            e = np.empty(data.n)
            e[0] = -value * (slope[0] if slope.size else 0.0)
            zi = [a * e[0]]
            e[1:] = lfilter([1.0], [1.0, -a], -value * (1.0 - a) * slope, zi=zi)[0]
            out[rows] = delta[starts[rows]] + e[starts[rows]]
        return out[:, None]

    def signature_regressors(self, data):
        return data.u[:, 0:1] * data.x[:, 3:4]


class InputDelay(Effect):
    """Dead time on the acceleration command: the car applies ``accel(t - T)``.

    Uses the measured command history, averaged over each zero-order-hold step.
    """

    name = "input_delay"
    description = "dead time T on the acceleration command, a(t) = accel(t - T)"
    params = (EffectParam("T", "s", 0.0, 1.0, 0.1, 0.05, 0.0, "dead time"),)
    signature_state = "v"
    signature_label = "change of the acceleration command"
    starts = ((0.05,), (0.15,), (0.3,), (0.5,))

    def inputs(self, U, data, starts, p):
        steps = np.clip(np.asarray(p["T"], dtype=float), 0.0, None) / data.dt
        n = np.floor(steps).astype(int)
        frac = steps - n
        horizon = U.shape[1]
        k = starts[:, None] + np.arange(horizon)[None, :] - n[:, None]
        a = data.u[:, 1]
        a_now = a[np.clip(k, 0, data.n - 1)]
        a_prev = a[np.clip(k - 1, 0, data.n - 1)]
        out = U.copy()
        out[:, :, 1] = (1.0 - frac[:, None]) * a_now + frac[:, None] * a_prev
        return out

    def signature_regressors(self, data):
        a = data.u[:, 1]
        return np.concatenate([[0.0], np.diff(a)])[:, None] / data.dt


class TireSaturation(Effect):
    """Brush (Fiala) tire with a friction peak: the lateral force saturates at ``mu_peak Fz``.

    With ``z = C_alpha alpha / (3 mu_peak Fz)`` the force is ``3 mu_peak Fz (z - z|z| + z^3/3)``
    for ``|z| < 1`` and ``mu_peak Fz sign(alpha)`` beyond; for small slip it equals the
    baseline's linear force ``C_alpha alpha`` (``C_alpha = mu C_S Fz``). Friction factors
    (``friction`` hooks, e.g. speed-dependent friction) scale the peak as well.
    """

    name = "tire_saturation"
    description = "brush (Fiala) tire: lateral force saturates at mu_peak Fz"
    params = (EffectParam("mu_peak", "-", 0.1, 3.0, 1.0, 0.2, 3.0, "peak friction coefficient"),)
    signature_state = "psi_dot"
    signature_label = "lateral acceleration cubed"
    starts = ((0.6,), (1.0,), (1.6,))

    def tire(self, alpha, fz, c_alpha, p, ctx=None):
        scale = 1.0 if ctx is None else ctx.mu_scale
        f_max = p["mu_peak"] * scale * np.maximum(fz, 1.0)
        z = c_alpha * alpha / (3.0 * f_max)
        za = np.minimum(np.abs(z), 1.0)
        zs = np.sign(z) * za
        return 3.0 * f_max * (zs - zs * za + zs**3 / 3.0)

    def signature_regressors(self, data):
        ay = data.x[:, 3] * data.x[:, 5]
        return (ay**3)[:, None]


class Grade(Effect):
    """A planar road slope: ``a = -g (gx cos psi + gy sin psi)`` with the grade vector
    (gx, gy) = the rise per metre along world x and y."""

    name = "grade"
    description = "planar road grade, a = -g (gx cos psi + gy sin psi)"
    params = (
        EffectParam("gx", "-", -0.2, 0.2, 0.0, 0.01, 0.0, "rise per metre along world x"),
        EffectParam("gy", "-", -0.2, 0.2, 0.0, 0.01, 0.0, "rise per metre along world y"),
    )
    signature_state = "v"
    signature_label = "cos/sin of heading"

    def longitudinal(self, ctx, p):
        psi = ctx.x[:, 4]
        return -ctx.vehicle.g * (p["gx"] * np.cos(psi) + p["gy"] * np.sin(psi))

    def signature_regressors(self, data):
        return np.stack([np.cos(data.x[:, 4]), np.sin(data.x[:, 4])], axis=1)


class MotorPowerLimit(Effect):
    """Drive power limit: the positive acceleration is at most ``P_max / (m v)``."""

    name = "motor_power_limit"
    description = "drive power limit, accel <= P_max / (m v)"
    params = (EffectParam("P_max", "kW", 5.0, 1000.0, 60.0, 10.0, 1000.0, "maximum drive power"),)
    signature_state = "v"
    signature_label = "positive accel x speed"
    starts = ((30.0,), (60.0,), (150.0,))

    def accel(self, accel, ctx, p):
        v = np.maximum(ctx.x[:, 3], POWER_V_MIN_MPS)
        limit = 1000.0 * p["P_max"] / (ctx.vehicle.m * v)
        width = POWER_WIDTH_MPS2  # a smooth minimum
        d = accel - limit
        return np.where(accel > 0, accel - width * np.logaddexp(0.0, d / width), accel)

    def signature_regressors(self, data):
        return (np.maximum(data.u[:, 1], 0.0) * data.x[:, 3])[:, None]


_REGISTRY: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Add an effect class to the library (usable as a decorator); returns the class."""
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise TypeError(f"register_effect: {cls!r} is not an Effect subclass")
    if not cls.name or not cls.name.isidentifier():
        raise ValueError(f"register_effect: effect name {cls.name!r} must be an identifier")
    names = [q.name for q in cls.params]
    if len(set(names)) != len(names):
        raise ValueError(f"register_effect: {cls.name}: duplicated parameter names {names}")
    _REGISTRY[cls.name] = cls
    return cls


def unregister_effect(name: str) -> None:
    """Remove an effect from the library (e.g. one registered for a test)."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown effect {name!r}; known effects: {', '.join(known_effects())}")
    del _REGISTRY[name]


for _cls in (
    Drag,
    RollingResistance,
    SteeringLag,
    InputDelay,
    TireSaturation,
    Grade,
    MotorPowerLimit,
):
    register_effect(_cls)


def known_effects() -> list[str]:
    """Names of the registered effects, in registration order."""
    return list(_REGISTRY)


def get_effect(name: str | Effect) -> Effect:
    """An effect instance by name (or the instance itself)."""
    if isinstance(name, Effect):
        return name
    if isinstance(name, type) and issubclass(name, Effect):
        return name()
    try:
        return _REGISTRY[str(name)]()
    except KeyError:
        raise ValueError(
            f"unknown effect {name!r}; known effects: {', '.join(known_effects())}"
        ) from None
