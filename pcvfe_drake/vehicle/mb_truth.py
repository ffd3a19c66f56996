"""CommonRoad's multi-body (MB) vehicle model as a high-fidelity "truth" plant.

The MB model of the ``vehiclemodels`` package (``vehicle_dynamics_mb``: 29 states, sprung and
unsprung masses, suspension, Pacejka magic-formula tires with combined slip, load transfer, wheel
spin) is wrapped here with the additions below. Its derivative is evaluated by a compiled
transcription of the package's equations (``pcvfe_drake.vehicle.mb_kernel``: the package's
Python costs most of a simulation's time), which gives the package's numbers bit for bit; the
package stays the reference the tests compare it with.

* **Friction per terrain.** The package's tire has one friction level: the peak factors
  ``p_dy1`` (lateral, 1.0489 for the Ford Escort) and ``p_dx1`` (longitudinal, 1.1739). For a
  terrain of friction coefficient ``mu`` both are scaled by ``s = mu / p_dy1_nominal``, so the
  lateral peak factor equals ``mu`` and the longitudinal one keeps its ratio to it
  (``p_dx1 = 1.1739 s``). With ``friction_scaling="peak_and_stiffness"`` (the default) the slip
  stiffnesses ``p_ky1`` and ``p_kx1`` are scaled by ``s`` too: the normalised cornering stiffness
  ``C_S = -p_ky1 / p_dy1`` then stays at its nominal value and the small-slip lateral force is
  ``mu C_S F_z alpha``, exactly the single-track model's parametrisation (``VehicleParams``), so a
  single-track fit of mu on MB data recovers the terrain's mu. With ``friction_scaling="peak"``
  only the peak factors change (the brush-model view: friction limits the peak force, the
  stiffness at small slip is unchanged), and mu shows only near saturation. With
  ``friction_scaling="lateral_peak"`` (the public PC-VFE simulator's mapping,
  ``nandantumu/common_road_sim``) only the lateral peak factor is set, ``p_dy1 = mu``; the
  longitudinal peak (1.1739) and every stiffness keep their nominal values, so "mu" is the
  lateral friction peak only: braking and driving grip stay those of dry asphalt.
* **State in single-track order.** :meth:`MbTruth.st_state` reports
  ``[sx, sy, delta, v, psi, psi_dot, beta]`` with ``v = sign(v_x) hypot(v_x, v_y)`` and
  ``beta = atan(v_y / v_x)`` (0 when ``|v_x| < 0.1`` m/s, as in the package), from the MB body
  velocities ``v_x = x[3]``, ``v_y = x[10]``.
* **Integration.** The wheel-spin dynamics are stiff: the fastest eigenvalues are about
  ``-4750 / v`` 1/s for the Ford Escort (-475 1/s at 10 m/s, -4750 1/s at 1 m/s), so fixed-step
  RK4 at 1 ms is stable only above ~2 m/s. :meth:`MbTruth.integrate` therefore uses LSODA
  (scipy; switches between Adams and BDF by stiffness) by default, or fixed-step RK4 substeps on
  request (``method="rk4"``); an LSODA interval that chatters on a slip crossing zero is taken
  in RK4 substeps instead (above 2 m/s). See ``benchmarks/plant_realtime.py`` for the measured
  speeds.
* **Wheel speeds >= 0.** The package zeroes the derivative of a negative wheel speed; an
  integrator stage that overshoots below 0 then leaves the wheel locked for good (from rest,
  LSODA and Drake's RK3 both ended at 0.37 m/s instead of 2.0 m/s after 1 s at 2 m/s^2).
  :meth:`MbTruth.rhs` evaluates the model at ``max(omega, 0)`` instead, which spins such a
  wheel up again.

* **Where the model ends.** The package divides by each wheel's ground speed (the speed of the
  wheel centre along the wheel's heading, ``u_w``) for the longitudinal slip
  ``1 - R_w omega / u_w`` whenever ``|v_x| >= 0.1`` m/s, after setting a negative ``u_w`` to 0
  ("negative wheel spin forbidden"): the model is defined for a car rolling forward on all four
  wheels. A car that reverses (``v_x <= -0.1`` m/s) or spins so far that a wheel moves backwards
  or sideways over the ground (``u_w <= 0``) has left it, and no integrator can go on.
  :meth:`MbTruth.rhs` raises :class:`MbSingularity` there (where the package raises
  ``ZeroDivisionError``; with the wheels' ground speeds named); the run loop scores it as the
  catastrophic failure ``truth_singular`` (``pcvfe_drake.control.failure``). The speeds are not
  clamped: a car in that state has already failed, and a clamp would invent tire forces the
  model does not define.

The package's model switches to kinematic equations below ``|v_x| = 0.1`` m/s and its wheel
slip becomes very stiff at low speed (eigenvalues ~ -47000 1/s at 0.1 m/s), so driving from rest
takes an error-controlled integrator many small steps; the model is meant for driving at speed.

The inputs are the single-track ones, ``u = [steer_rate rad/s, accel m/s^2]``; the model applies
the package's steering and acceleration constraints itself.
"""

from __future__ import annotations

import copy
import math

import numpy as np
from scipy.integrate import solve_ivp
from vehiclemodels.init_mb import init_mb

from pcvfe_drake.vehicle import mb_kernel
from pcvfe_drake.vehicle.mb_kernel import (
    REGULAR,
    SINGULAR,
    STEP_TOO_SMALL,
    mb_advance,
    mb_derivative,
    mb_parameter_vector,
)

NX_MB = 29
"""Number of MB states."""
VX, VY = 3, 10
"""Indices of the body-frame longitudinal and lateral velocity [m/s] in the MB state."""
WHEEL_SPEEDS = slice(23, 27)
"""Indices of the four wheel angular speeds [rad/s] in the MB state."""
LSODA_CHATTER_FACTOR = 50
"""An LSODA interval that needs this many times the right-hand-side evaluations of the same
interval in fixed RK4 substeps is chattering (see :meth:`MbTruth.integrate`)."""
RK4_MIN_SPEED_MPS = 2.0
"""Fixed RK4 substeps of 1 ms are stable above about this ``|v_x|`` (the wheel-spin modes,
module docstring); below it a chattering interval stays with LSODA."""


RK23_RTOL = 1e-5
"""Relative local error per step of the compiled error-controlled integrator (``"rk23"``)."""
RK23_ATOL = 1e-5
"""Absolute local error per step of ``"rk23"`` (m, rad, m/s, rad/s: the MB state's units)."""
RK23_MIN_STEP_S = 1e-8
"""Least step of ``"rk23"`` [s]: error control asking for less means a motion the model
cannot follow (raised as :class:`MbSingularity`)."""
INTEGRATION_METHODS = ("rk23", "rk4", "lsoda")
"""Methods of :meth:`MbTruth.integrate` (and of the plant's discrete MB update)."""


class _Chatter(Exception):
    """Raised inside LSODA's right-hand side to stop a chattering interval."""


WHEELS = ("front left", "front right", "rear left", "rear right")
"""The wheels in the package's order (wheel speeds ``x[23:27]``)."""
KINEMATIC_BELOW_MPS = mb_kernel.KINEMATIC_BELOW_MPS
"""Below this ``|v_x|`` [m/s] the package uses kinematic equations (no slip, no division)."""

FRICTION_SCALINGS = ("peak_and_stiffness", "peak", "lateral_peak")
"""Tire friction mappings (module docstring): what a terrain's mu changes in the MB tire."""


def _vehicle1():
    from vehiclemodels.parameters_vehicle1 import parameters_vehicle1

    return parameters_vehicle1()


def _vehicle2():
    from vehiclemodels.parameters_vehicle2 import parameters_vehicle2

    return parameters_vehicle2()


def _vehicle3():
    from vehiclemodels.parameters_vehicle3 import parameters_vehicle3

    return parameters_vehicle3()


MB_VEHICLES = {"ford_escort": _vehicle1, "bmw_320i": _vehicle2, "vw_vanagon": _vehicle3}
"""Vehicles with a full CommonRoad parameter set (names as in
``pcvfe_drake.vehicle.params.PRESETS``)."""


def commonroad_parameters(vehicle: str = "ford_escort"):
    """The ``vehiclemodels`` parameter set of a vehicle preset name (a fresh copy)."""
    if vehicle not in MB_VEHICLES:
        raise ValueError(
            f"vehicle {vehicle!r} has no CommonRoad multi-body parameters; "
            f"choose one of {sorted(MB_VEHICLES)}"
        )
    return MB_VEHICLES[vehicle]()


class MbSingularity(ArithmeticError):
    """The multi-body truth cannot be integrated: a wheel's ground speed is <= 0 while
    ``|v_x| >= 0.1`` m/s (the car reverses or has spun; module docstring, "Where the model
    ends"). ``state`` is the MB state (29,) where it happened, ``detail`` the numbers, ``t_s`` the
    simulated time when the caller knows it (NaN otherwise)."""

    def __init__(self, detail: str, state, t_s: float = math.nan) -> None:
        super().__init__(detail)
        self.detail = detail
        self.state = np.array(state, dtype=float)
        self.t_s = float(t_s)

    def __reduce__(self):  # pickled whole (a calibration drive raises it in a child process)
        return (MbSingularity, (self.detail, self.state, self.t_s))

    def at(self, t_s: float) -> MbSingularity:
        """The same singularity with its simulated time [s] filled in."""
        return MbSingularity(self.detail, self.state, t_s)

    def __str__(self) -> str:
        when = f" at t = {self.t_s:.3f} s" if math.isfinite(self.t_s) else ""
        return f"multi-body truth singular{when}: {self.detail}"


def _track_geometry(p) -> tuple[float, float, float]:
    """``(a, T_f, T_r)`` [m] of a parameter set or of its vector (``mb_parameter_vector``)."""
    if isinstance(p, np.ndarray):
        return float(p[mb_kernel.A]), float(p[mb_kernel.T_F]), float(p[mb_kernel.T_R])
    return p.a, p.T_f, p.T_r


def wheel_ground_speeds(x, p) -> np.ndarray:
    """The four wheels' ground speeds ``u_w`` [m/s] (``WHEELS`` order) of an MB state ``x``
    under parameters ``p`` (a parameter set or its vector), before the package sets negative
    ones to 0 (its own formulas)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return np.array(mb_kernel.wheel_ground_speeds(x, *_track_geometry(p)))


def singularity_detail(x, p) -> str:
    """Why the model is singular at MB state ``x`` under parameters ``p`` (a parameter set or
    its vector): the wheels whose ground speed is <= 0 and the car's ``v_x`` and yaw rate (""
    where it is not singular)."""
    x = np.asarray(x, dtype=float)
    if abs(x[VX]) < KINEMATIC_BELOW_MPS:
        return ""
    u_w = wheel_ground_speeds(x, p)
    stopped = [f"{WHEELS[i]} {u_w[i]:.3f} m/s" for i in np.flatnonzero(u_w <= 0.0)]
    if not stopped:
        return ""
    why = "reversing" if x[VX] < 0 else "spun"
    return (
        f"wheel ground speed <= 0 ({', '.join(stopped)}) at v_x {x[VX]:.3f} m/s, yaw rate "
        f"{x[5]:.3f} rad/s: the car is {why}, outside the model"
    )


def _check_mu(mu: float) -> float:
    mu = float(mu)
    if not math.isfinite(mu) or mu <= 0.0:
        raise ValueError(f"friction coefficient mu={mu!r} must be finite and > 0")
    return mu


class MbTruth:
    """The CommonRoad multi-body model with per-terrain friction (see the module docstring).

    Args:
        vehicle: a preset name with CommonRoad parameters (``MB_VEHICLES``).
        friction_scaling: ``"peak_and_stiffness"`` (default), ``"peak"`` or ``"lateral_peak"``.
    """

    def __init__(
        self, vehicle: str = "ford_escort", friction_scaling: str = "peak_and_stiffness"
    ) -> None:
        if friction_scaling not in FRICTION_SCALINGS:
            raise ValueError(
                f"friction_scaling={friction_scaling!r}; choose one of {FRICTION_SCALINGS}"
            )
        self.vehicle = vehicle
        self.friction_scaling = friction_scaling
        self.base_parameters = commonroad_parameters(vehicle)
        self.mu_nominal = float(self.base_parameters.tire.p_dy1)
        self._by_mu: dict[float, object] = {}
        self._vector_by_mu: dict[float, np.ndarray] = {}

    def parameters_for_mu(self, mu: float):
        """The CommonRoad parameter set with the tire friction scaled to ``mu`` (cached)."""
        mu = _check_mu(mu)
        p = self._by_mu.get(mu)
        if p is None:
            p = copy.deepcopy(self.base_parameters)
            base = self.base_parameters.tire
            s = mu / self.mu_nominal
            p.tire.p_dy1 = base.p_dy1 * s
            if self.friction_scaling != "lateral_peak":
                p.tire.p_dx1 = base.p_dx1 * s
            if self.friction_scaling == "peak_and_stiffness":
                p.tire.p_ky1 = base.p_ky1 * s
                p.tire.p_kx1 = base.p_kx1 * s
            self._by_mu[mu] = p
        return p

    def parameter_vector_for_mu(self, mu: float) -> np.ndarray:
        """The parameter vector (``mb_kernel.mb_parameter_vector``) of
        :meth:`parameters_for_mu`'s set, what :meth:`rhs` evaluates fastest (cached)."""
        mu = _check_mu(mu)
        pv = self._vector_by_mu.get(mu)
        if pv is None:
            pv = self._vector_by_mu[mu] = mb_parameter_vector(self.parameters_for_mu(mu))
        return pv

    def initial_state(self, x_st) -> np.ndarray:
        """MB state (29,) from a single-track state [sx, sy, delta, v, psi, psi_dot, beta]
        (``vehiclemodels.init_mb``: suspension at rest, wheels rolling without slip)."""
        x_st = np.asarray(x_st, dtype=float)
        if x_st.shape != (7,) or not np.all(np.isfinite(x_st)):
            raise ValueError(f"initial single-track state must be 7 finite numbers, got {x_st}")
        return np.array(init_mb(x_st.tolist(), self.base_parameters), dtype=float)

    def derivatives(self, x, u, mu: float) -> np.ndarray:
        """Time derivative (29,) of the MB state ``x`` under input ``u`` on friction ``mu``."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if x.shape != (NX_MB,):
            raise ValueError(f"MB state must have {NX_MB} entries, got shape {x.shape}")
        if u.shape != (2,):
            raise ValueError(f"input must be [steer_rate, accel], got shape {u.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"MB state is not finite: entries {np.flatnonzero(~np.isfinite(x))}")
        if not np.all(np.isfinite(u)):
            raise ValueError(f"input [steer_rate, accel] = {u.tolist()} is not finite")
        return self.rhs(x, u, self.parameter_vector_for_mu(mu))

    @staticmethod
    def rhs(x, u, p) -> np.ndarray:
        """Unchecked fast path: the derivative (29,) at an MB state ``x`` (array or list; not
        changed), an input ``u = [steer_rate, accel]`` and parameters ``p``: the vector of
        :meth:`parameter_vector_for_mu` (fastest), or a parameter set from
        :meth:`parameters_for_mu` (converted on each call). The caller has validated them.
        Raises :class:`MbSingularity` where the model ends (module docstring)."""
        # Wheel speeds are evaluated at max(omega, 0) (in the kernel). The package itself zeroes
        # the derivative of a negative wheel speed, which lets a wheel that an integrator stage
        # pushed below 0 stay there, locked, for ever (seen from rest with Drake's RK3 and with
        # LSODA); at 0 the package's derivative is the physical one and spins the wheel up again.
        pv = p if isinstance(p, np.ndarray) else mb_parameter_vector(p)
        if not (
            type(x) is np.ndarray
            and x.dtype == np.float64
            and x.flags.c_contiguous
            and x.flags.writeable
        ):  # one array type for the compiled kernel: no second compilation
            x = np.array(x, dtype=np.float64)
        if x.shape != (NX_MB,) or pv.shape != (len(mb_kernel.MB_PARAMETER_FIELDS),):
            raise ValueError(
                f"MbTruth.rhs: state of shape {x.shape} (want ({NX_MB},)) or parameter vector "
                f"of shape {pv.shape} (want ({len(mb_kernel.MB_PARAMETER_FIELDS)},))"
            )
        out = np.empty(NX_MB)
        code = mb_derivative(x, float(u[0]), float(u[1]), pv, out)
        if code:
            x = x.copy()
            wheels = x[WHEEL_SPEEDS]
            wheels[wheels < 0.0] = 0.0  # the state as evaluated
            detail = singularity_detail(x, pv) or f"the model divides by zero: {SINGULAR[code]}"
            raise MbSingularity(detail, x)
        return out

    def advance(self, x, u, p, duration_s: float, step_s: float) -> tuple[np.ndarray, float]:
        """Unchecked fast path of ``method="rk23"``: the MB state after ``duration_s`` [s] from
        ``x`` (float64 array, not changed) with ``u = [steer_rate, accel]`` and the parameter
        vector ``p`` held, and the step [s] to try first next time (start with ``duration_s``).

        Compiled error-controlled Bogacki-Shampine 3(2) steps (``mb_kernel.mb_advance``;
        local errors within :data:`RK23_ATOL` + :data:`RK23_RTOL` |x|): the stiff wheel-spin
        modes set the step (a few ms at speed, less near rest), and a whole period costs one
        call. Raises :class:`MbSingularity` where the model ends."""
        out = np.empty(NX_MB)
        code, step, _ = mb_advance(
            x,
            float(u[0]),
            float(u[1]),
            p,
            float(duration_s),
            float(step_s),
            RK23_RTOL,
            RK23_ATOL,
            RK23_MIN_STEP_S,
            out,
        )
        if code == STEP_TOO_SMALL:
            raise MbSingularity(
                f"the integrator's error control asked for a step below {RK23_MIN_STEP_S:g} s "
                f"(a motion too fast to follow) at v_x = {out[VX]:.3f} m/s",
                out,
            )
        if code != REGULAR:
            detail = singularity_detail(out, p) or f"the model divides by zero: {SINGULAR[code]}"
            raise MbSingularity(detail, out)
        return out, step

    def integrate(
        self,
        x,
        u,
        mu: float,
        duration_s: float,
        method: str = "lsoda",
        rtol: float = 1e-6,
        atol: float = 1e-6,
        rk4_step_s: float = 1e-3,
    ) -> np.ndarray:
        """Advance the MB state by ``duration_s`` [s] with ``u`` and ``mu`` held constant.

        ``method="lsoda"`` (default) uses scipy's LSODA with tolerances ``rtol``/``atol``;
        ``method="rk4"`` takes fixed RK4 substeps of at most ``rk4_step_s`` (stable for
        v >~ 2 m/s at 1 ms); ``method="rk23"`` the compiled error-controlled steps of
        :meth:`advance` (its own tolerances). Wheel speeds are kept >= 0 as in the package.

        An LSODA interval that needs more than :data:`LSODA_CHATTER_FACTOR` times the
        right-hand-side evaluations of RK4 substeps is taken again in RK4 substeps, where
        ``|v_x| >= RK4_MIN_SPEED_MPS``: the package's tyre forces are not smooth where a
        slip crosses zero, and on a soft tyre (``peak_and_stiffness`` at a low friction) the
        error control then shrinks its steps to nothing (over a million evaluations for one
        0.05 s interval at 7.7 m/s, where RK4's 200 land within 5e-5 of LSODA's answer). The
        count, not the clock, decides, so a drive gives one result on any computer.
        """
        x = np.asarray(x, dtype=float)
        self.derivatives(x, u, mu)  # validates shapes, finiteness and mu
        if not duration_s > 0:
            raise ValueError(f"duration_s={duration_s!r} must be > 0")
        p = self.parameter_vector_for_mu(mu)
        ul = np.asarray(u, dtype=float).tolist()
        n_rk4 = max(1, math.ceil(duration_s / rk4_step_s - 1e-9))
        if method == "lsoda":
            fast = abs(x[VX]) >= RK4_MIN_SPEED_MPS
            cap = LSODA_CHATTER_FACTOR * 4 * n_rk4 if fast else math.inf
            calls = [0]

            def rhs(_t, y):
                calls[0] += 1
                if calls[0] > cap:
                    raise _Chatter
                return self.rhs(y, ul, p)

            try:
                sol = solve_ivp(
                    rhs, (0.0, float(duration_s)), x, method="LSODA", rtol=rtol, atol=atol
                )
            except _Chatter:  # the interval again, in fixed RK4 substeps
                xn = self._rk4(x, ul, p, duration_s / n_rk4, n_rk4)
            else:
                if not sol.success:
                    raise RuntimeError(f"MB integration failed: {sol.message}")
                xn = sol.y[:, -1]
        elif method == "rk4":
            xn = self._rk4(x, ul, p, duration_s / n_rk4, n_rk4)
        elif method == "rk23":
            xn, _ = self.advance(np.array(x, dtype=np.float64), ul, p, duration_s, duration_s)
        else:
            raise ValueError(f"method={method!r}; choose one of {INTEGRATION_METHODS}")
        np.maximum(xn[WHEEL_SPEEDS], 0.0, out=xn[WHEEL_SPEEDS])
        if not np.all(np.isfinite(xn)):
            raise RuntimeError(
                f"MB integration produced a non-finite state (mu={mu}, u={ul}, "
                f"from v_x={x[VX]:.3f} m/s)"
            )
        return xn

    def _rk4(self, x: np.ndarray, ul: list, p: np.ndarray, h: float, n: int) -> np.ndarray:
        """``n`` fixed RK4 substeps of ``h`` [s] from ``x`` (wheel speeds kept >= 0)."""
        xn = x.copy()
        for _ in range(n):
            k1 = self.rhs(xn, ul, p)
            k2 = self.rhs(xn + 0.5 * h * k1, ul, p)
            k3 = self.rhs(xn + 0.5 * h * k2, ul, p)
            k4 = self.rhs(xn + h * k3, ul, p)
            xn = xn + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            np.maximum(xn[WHEEL_SPEEDS], 0.0, out=xn[WHEEL_SPEEDS])
        return xn

    def simulate(
        self, x0_st, inputs, dt_s: float, mu, method: str = "lsoda"
    ) -> tuple[np.ndarray, np.ndarray]:
        """Roll out from a single-track state with inputs ``(H, 2)`` held for ``dt_s`` each.

        ``mu`` is a number or a callable ``mu(x_st) -> float`` (friction under the car, sampled
        at the start of each interval). Returns ``(X_st (H+1, 7), X_mb (H+1, 29))``.
        """
        inputs = np.asarray(inputs, dtype=float)
        if inputs.ndim != 2 or inputs.shape[1] != 2:
            raise ValueError(f"inputs must have shape (H, 2), got {inputs.shape}")
        xs = [self.initial_state(x0_st)]
        for u in inputs:
            mu_k = mu(st_state(xs[-1])) if callable(mu) else mu
            xs.append(self.integrate(xs[-1], u, mu_k, dt_s, method=method))
        x_mb = np.array(xs)
        return st_state(x_mb), x_mb


MOVING_VX_MPS = 0.1
"""``|v_x|`` [m/s] from which :func:`st_state` forms the side-slip angle (the package's own
kinematic threshold; below it beta is 0)."""


def st_state(x_mb) -> np.ndarray:
    """Single-track state(s) ``[sx, sy, delta, v, psi, psi_dot, beta]`` of MB state(s).

    ``x_mb`` is (29,) or (N, 29). ``v`` is the signed speed ``sign(v_x) hypot(v_x, v_y)``;
    ``beta = atan(v_y / v_x)``, 0 where ``|v_x| < 0.1`` m/s (the package's own convention).
    """
    x = np.asarray(x_mb, dtype=float)
    single = x.ndim == 1
    if single and x.shape[0] == NX_MB:
        return _st_state_one(x)
    x2 = np.atleast_2d(x)
    if x2.shape[1] != NX_MB:
        raise ValueError(f"MB state must have {NX_MB} entries, got shape {x.shape}")
    vx, vy = x2[:, VX], x2[:, VY]
    moving = np.abs(vx) >= MOVING_VX_MPS
    speed = np.hypot(vx, vy) * np.where(vx < 0, -1.0, 1.0)
    beta = np.where(moving, np.arctan(vy / np.where(moving, vx, 1.0)), 0.0)
    out = np.stack([x2[:, 0], x2[:, 1], x2[:, 2], speed, x2[:, 4], x2[:, 5], beta], axis=1)
    return out[0] if single else out


def _st_state_one(x: np.ndarray) -> np.ndarray:
    """:func:`st_state` of one MB state (29,): the same operations on one-element slices (the
    same numpy loops, so the same bits), without the batch's stacking (the plant's state
    output calls this at every sensor sample)."""
    vx, vy = x[VX : VX + 1], x[VY : VY + 1]
    speed = np.hypot(vx, vy)[0] * (-1.0 if vx[0] < 0 else 1.0)
    beta = np.arctan(vy / vx)[0] if abs(vx[0]) >= MOVING_VX_MPS else 0.0
    return np.array([x[0], x[1], x[2], speed, x[4], x[5], beta])
