"""Exploration for a context whose friction peak is not identifiable (``!Probe``; no pydrake).

With a saturating tyre the friction peak is observable only where the tyres work near it
(``docs/fitting.md``, "Identifiability"). The NMPC's speed profile uses about
``speed_margin^2`` (0.64) of the mu it is handed, so a car handed the used-friction lower bound
uses 0.64 of it, the bound ratchets down and the peak never becomes observable. The probe breaks
that loop for one context at a time, as a test driver would: it hands the NMPC a mu above the
demonstrated bound, raises it while the tyres show no saturation, and backs off at the first
sign of it. The estimate takes over as soon as the fit is identifiable
(``pcvfe_drake.handing``). The rules (:func:`probe_step`; numbers in :class:`ProbeSettings`):

* **start** at ``max(mu_lower_bound, floor_mu)``; with a stated floor the first step is taken on
  the data the context already has: before its id the car drove the new terrain at the floor
  and those samples joined the context when it was named (paper eq. 5d relabelling); with a
  stated floor the probe also starts once the context's visit is confirmed, before its first
  fit (``Handing.probes_before_fit``: the evidence below reads the tyres, not a fit);
* **before the id**, with a stated floor, the unknown value itself is probed, one step above
  the floor at most (:func:`unknown_probe_update`), and the level is carried into the context
  that ends the phase where most of its data belong to it (:func:`carried_probe`);
* **raise** at most after every ``hold_s`` on the context (long enough to drive a bend at the
  level), to the peak the level's *bend ratio* implies (:func:`bend_ratios`: the slip the tyres
  needed for their force over the slip a linear tyre would need; over a bend whose demand peaks
  at a fraction ``q`` of a magic-formula tyre's peak it is :func:`sine_bend_ratio`), by at most
  ``fast_step_rel``, while the ratio is at most ``linear_ratio`` (the ratio at the planner's
  share); the implied peak is the one consistent with the stiffness it implies where the
  car's stiffness follows the friction (:func:`implied_level_ratio`); without evidence (no
  bend driven at the level) the level is kept;
* **toward a tight fit**: a level tried in a bend with no sign of saturation is raised at least
  to a fit whose std is small but whose data never came near its peak, one fast step at most;
* **bounded** by ``(mu_lower_bound + max_excess) / use_fraction`` (the planner is never asked for
  more than ``max_excess`` above the friction demonstrated), the prior mu and a ceiling set by a
  back-off;
* **back off** on a sign of saturation (:func:`saturated`: a slip angle, a 0.2 s mean, on either
  axle over ``SLIP_FRACTION`` of a magic-formula tyre's peak slip at the handed mu; or the
  level's bend ratio above ``bend_limit``): two steps down, never below the start, and one step
  below the level that saturated becomes the ceiling.

Evidence is judged relative to the level tried: a sample counts toward a bend ratio when its
force is at least ``EVIDENCE_FRACTION`` of the planner's demand at that level
(:func:`evidence_force`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pcvfe_drake.json_numbers import finite_or_none
from pcvfe_drake.models.chassis_effects import wheel_slip_offsets
from pcvfe_drake.vehicle.single_track import BETA, DELTA, PSI_DOT, V

WINDOW_S = 1.0
"""The newest span [s] checked for saturation."""
SLIP_FRACTION = 0.5
"""A slip angle over this fraction of the handed mu's peak slip is a sign of saturation: at half
its peak slip a magic-formula tyre already delivers 92 % of its peak, twice the slip a linear
tyre needs for that force, while the planner's demand needs about a quarter of it."""
EVIDENCE_FRACTION = 0.5
"""A sample is bend evidence when its force is at least this fraction of the planner's demand at
the level tried: a bend whose demand rises and falls as a sine spends two thirds of its time
there."""
OVERSHOOT = 1.25
"""The bend limit is the bend ratio of a handed mu this many times the peak (one default fast
step past it)."""
DEFAULT_PROBE_USE_FRACTION = 0.64
"""The planner's share of mu when the scenario does not say (the NMPC's default 0.8^2)."""
MIN_PROBE_MU = 0.05
"""Smallest mu a back-off hands (keeps the speed profile defined)."""
MIN_SLIP_LIMIT_RAD = 0.01
"""Smallest slip limit of the saturation test [rad]: the 90th percentile of one sample's
slip-angle noise (INS side slip 0.005 rad, yaw rate 0.01 rad/s: ~0.009 rad). The test reads
the slips' moving mean (:data:`SLIP_SMOOTH_S`), whose noise is well below it; the floor stays
so that no level is judged by a limit finer than what one sample resolves."""
MF_SHAPE = 1.35
"""Magic-formula shape factor of the tyre the saturation test assumes (``peak_tyre``'s C)."""
MIN_SPEED_MPS = 2.0
"""Samples slower than this are not used for the slip angles (kinematic slip dominates)."""
G_MPS2 = 9.81
BEND_SMOOTH_S = 0.1
"""Central-difference half span [s] of the yaw and side-slip rates in :func:`axle_force_per_load`
(as ``effect_fit.friction_used``: averages the rate noise)."""
TRIED_FRACTION = 0.8
"""A level counts as tried in a bend (:func:`level_bend`) when the 90th percentile of its axle
forces reached this fraction of the planner's demand: over a window holding one bend whose
demand rises as a sine, the 90th percentile is 0.99 of the apex's, and the apex demand is the
planner's share of the handed mu."""
MIN_BEND_S = 1.5
"""Least time [s] of samples at force a bend ratio is computed from (half a bend of the paper's
slalom, which spends ~2.4 s of its 3 s at >= 0.1 g: the level's window must hold most of a
bend). Over shorter spans the INS noise dominates the ratio and the tail of a bend reads as
linear; less: no evidence (NaN)."""


@dataclass(frozen=True)
class ProbeState:
    """One context's probe.

    Attributes:
        mu: the mu handed while probing (NaN: not started).
        ceiling: the largest mu it may hand again (inf until a back-off).
        last_step_s: time of the last raise or back-off [s].
        steps: raises so far.
        backoffs: back-offs so far.
        backed_off: the last move was a back-off (no raise since).
    """

    mu: float = float("nan")
    ceiling: float = float("inf")
    last_step_s: float = float("nan")
    steps: int = 0
    backoffs: int = 0
    backed_off: bool = False

    @property
    def started(self) -> bool:
        return math.isfinite(self.mu)

    def to_dict(self) -> dict:
        return {
            "mu": finite_or_none(self.mu),
            "ceiling": finite_or_none(self.ceiling),
            "steps": self.steps,
            "backoffs": self.backoffs,
            "backed_off": self.backed_off,
        }


@dataclass(frozen=True)
class ProbeSettings:
    """The probe's numbers (``Handing`` builds them from ``HandingConfig`` and the planner's
    share of mu).

    Attributes:
        use_fraction: the planner's share of the handed mu (``speed_margin^2``).
        floor_mu: the floor the probe starts at (``HandingConfig.floor_mu``).
        max_excess, fast_step_rel, hold_s: ``!Probe``'s fields.
        start_evidence: the data before a context's id were driven at the stated floor, so its
            first step may be taken on them (``!StatedFloor``).
        step_rel: the slow step and the back-off's step (a tenth of the friction asked for: an
            overshoot past the limit is at most that).
    """

    use_fraction: float = DEFAULT_PROBE_USE_FRACTION
    floor_mu: float = 0.3
    max_excess: float = 0.12
    fast_step_rel: float | None = 0.4
    hold_s: float = 3.0
    start_evidence: bool = False
    step_rel: float = 0.1

    def __post_init__(self) -> None:
        if not (0 < self.use_fraction <= 1):
            raise ValueError(
                f"the planner's share of mu must be in (0, 1], got {self.use_fraction!r} "
                "(speed_margin^2)"
            )

    @property
    def linear_ratio(self) -> float:
        """The bend ratio at which the implied peak is the handed mu: a bend whose demand peaks
        at the planner's share of it (:func:`sine_bend_ratio`; 1.14 at 0.64)."""
        return sine_bend_ratio(self.use_fraction)

    @property
    def bend_limit(self) -> float:
        """The bend ratio above which a level counts as saturated: the planner's demand on a
        handed mu ``OVERSHOOT`` times the peak (1.25 at 0.64)."""
        return sine_bend_ratio(min(OVERSHOOT * self.use_fraction, 0.99))


def axle_slip_angles(states: np.ndarray, lf: float, lr: float) -> tuple[np.ndarray, np.ndarray]:
    """Front and rear slip angles [rad] of the single-track model from states (N, 7):
    ``alpha_f = delta - atan((v sin beta + lf psi_dot) / (v cos beta))``, ``alpha_r =
    -atan((v sin beta - lr psi_dot) / (v cos beta))``."""
    x = np.asarray(states, dtype=float)
    v, beta, r = x[:, V], x[:, BETA], x[:, PSI_DOT]
    vx = np.maximum(v * np.cos(beta), 1e-3)
    alpha_f = x[:, DELTA] - np.arctan((v * np.sin(beta) + lf * r) / vx)
    alpha_r = -np.arctan((v * np.sin(beta) - lr * r) / vx)
    return alpha_f, alpha_r


SLIP_SMOOTH_S = 0.2
"""Width [s] of the moving mean over slip angles read from measured states (:func:`saturated`,
:func:`wheel_peak_share`): it averages the INS side-slip and yaw-rate noise (0.005 rad and
0.01 rad/s per sample), which at a low level is as large as the slip limit itself and would
read as saturation or as use, and keeps a tyre's saturation, which lasts most of a bend."""


def slip_smoothing_width(t: np.ndarray) -> int:
    """Samples in :data:`SLIP_SMOOTH_S` at the median spacing of the times ``t`` [s] (>= 1)."""
    tt = np.asarray(t, dtype=float)
    dt = float(np.median(np.diff(tt))) if tt.size > 1 else 0.0
    return max(1, int(round(SLIP_SMOOTH_S / dt))) if dt > 0 else 1


def wheel_peak_share(
    t: np.ndarray,
    states: np.ndarray,
    vehicle,
    mu: float,
    stiffness_per_rad,
    track_m: float,
    quantile: float = 0.95,
    shape: float = MF_SHAPE,
) -> float:
    """How near the tyres came to their peak, per wheel: the ``quantile`` over the samples
    (``t`` [s], ``states`` (N, 7), at least ``MIN_SPEED_MPS``) of the largest share of its peak
    any wheel worked at, on a magic-formula tyre (shape ``shape``) with the peak ``mu`` and the
    small-slip stiffness ``stiffness_per_rad`` per axle (``mu * C_S``, per load), each wheel of
    an axle at its own slip for the track ``track_m`` [m] (``track_slip``'s
    ``wheel_slip_offsets``; 0: the single-track slip). Past its peak slip a wheel counts as at
    the peak (share 1). The slips are a moving mean over ``SLIP_SMOOTH_S``. NaN with
    fewer than 20 samples.

    The car's lateral acceleration says how much friction the car used, on average over its
    wheels; in a slow tight bend the inner front wheel works at a much larger slip than the
    axle's mean (the track; ``studies/peak_bias/front_axle_gap.py``), so the tyres can be near their
    peak while the car's mean use is not. The share depends on the fitted ``mu`` and errs
    safe: a peak fitted too high reads a smaller share."""

    x = np.asarray(states, dtype=float)
    tt = np.asarray(t, dtype=float)
    fast = x[:, V] >= MIN_SPEED_MPS
    if fast.sum() < 20 or not (math.isfinite(mu) and mu > 0):
        return float("nan")
    x, tt = x[fast], tt[fast]
    width = slip_smoothing_width(tt)
    kernel = np.ones(width) / width
    stiffness = np.broadcast_to(np.asarray(stiffness_per_rad, dtype=float), (2,))
    track = np.full(x.shape[0], float(track_m))
    levers = (vehicle.lf, -vehicle.lr)
    shares = []
    for alpha, lever, k in zip(
        axle_slip_angles(x, vehicle.lf, vehicle.lr), levers, stiffness, strict=True
    ):
        left, right = wheel_slip_offsets(x, lever, track)
        b = k / (shape * mu)
        for wheel in (alpha + left, alpha + right):
            slip = np.convolve(wheel, kernel, mode="same")
            shares.append(np.sin(np.minimum(shape * np.arctan(b * np.abs(slip)), 0.5 * math.pi)))
    return float(np.quantile(np.max(shares, axis=0), quantile))


def axle_force_per_load(t: np.ndarray, states: np.ndarray, lf: float, lr: float, iz_per_m: float):
    """Lateral force per static axle load [g] of each axle from measured states (N, 7) at times
    ``t``, from the single-track model's force and moment balance ``F_f + F_r = m a_y``, ``lf
    F_f - lr F_r = I_z r_dot``: ``f_f = (a_y + I_z r_dot / (m lr)) / g``, ``f_r = (a_y - I_z
    r_dot / (m lf)) / g``, with ``a_y = v (psi_dot + beta_dot)`` and the rates by central
    differences over +-``BEND_SMOOTH_S``. Returns ``(rows, f_f, f_r)``: the rows of ``states``
    the forces belong to (those whose neighbours are evenly spaced; none with too few
    samples)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(states, dtype=float)
    empty = (np.zeros(0, int), np.zeros(0), np.zeros(0))
    if t.size < 3:
        return empty
    dt = float(np.median(np.diff(t)))
    m = max(1, int(round(BEND_SMOOTH_S / max(dt, 1e-9))))
    if t.size <= 2 * m:
        return empty
    span = t[2 * m :] - t[: -2 * m]
    ok = np.abs(span - 2 * m * dt) <= 0.1 * 2 * m * dt
    span = np.where(ok, span, 1.0)
    beta_dot = (x[2 * m :, BETA] - x[: -2 * m, BETA]) / span
    r_dot = (x[2 * m :, PSI_DOT] - x[: -2 * m, PSI_DOT]) / span
    rows = np.arange(m, t.size - m)
    ay = x[rows, V] * (x[rows, PSI_DOT] + beta_dot)
    f_f = (ay + iz_per_m * r_dot / lr) / G_MPS2
    f_r = (ay - iz_per_m * r_dot / lf) / G_MPS2
    return rows[ok], f_f[ok], f_r[ok]


def bend_ratios(
    t: np.ndarray,
    states: np.ndarray,
    lf: float,
    lr: float,
    iz_per_m: float,
    stiffness_per_rad,
    min_force: float,
) -> tuple[float, float]:
    """How far along the tyre curve each axle worked: the least-squares slope of the measured
    slip angle on the slip a linear tyre would need for the measured force, ``alpha ~ b f /
    K`` (``K``: the small-slip stiffness per unit load, per axle: front, rear), over the
    samples at >= 2 m/s with ``|f| >= min_force``. 1: the tyre is linear there; a magic-formula
    tyre (shape 1.35) at a fraction q of its peak needs ``C tan(asin(q) / C) / q`` times the
    linear slip (1.1 at q = 0.5, 3.1 at the peak; over a whole bend: :func:`sine_bend_ratio`). The
    slope is taken with the noise on the slip side (the slip angles come from the INS side slip
    and yaw rate, the forces from smoothed rates), so that noise adds scatter, not bias. NaN
    for an axle with less than ``MIN_BEND_S`` of such samples."""
    x = np.asarray(states, dtype=float)
    k = np.broadcast_to(np.asarray(stiffness_per_rad, dtype=float), (2,))
    rows, f_f, f_r = axle_force_per_load(t, x, lf, lr, iz_per_m)
    if rows.size == 0:
        return math.nan, math.nan
    alpha_f, alpha_r = axle_slip_angles(x[rows], lf, lr)
    fast = x[rows, V] >= MIN_SPEED_MPS
    min_samples = MIN_BEND_S / float(np.median(np.diff(np.asarray(t, dtype=float))))
    out = []
    for alpha, f, kk in ((alpha_f, f_f, k[0]), (alpha_r, f_r, k[1])):
        use = fast & (np.abs(f) >= min_force)
        if use.sum() < min_samples or not kk > 0:
            out.append(math.nan)
            continue
        lin = f[use] / kk
        out.append(float(np.sum(alpha[use] * lin) / np.sum(lin * lin)))
    return out[0], out[1]


def level_bend(
    t: np.ndarray, states: np.ndarray, vehicle, stiffness_per_rad, min_force: float, demand: float
) -> float:
    """The evidence of one probe level of ``vehicle`` (``VehicleParams``): the larger of its axle
    bend ratios (:func:`bend_ratios`), NaN where there is none or where the level was not tried
    in a bend: the 90th percentile of the larger axle force per load (at >= 2 m/s) below
    ``TRIED_FRACTION`` of the planner's ``demand`` (its share of the handed mu). The tail of a
    bend and the straight after it say nothing about how the tyres take the level's demand, yet
    such a window reads as linear and would raise the level."""
    x = np.asarray(states, dtype=float)
    lf, lr, iz_per_m = vehicle.lf, vehicle.lr, vehicle.I_z / vehicle.m
    rows, f_f, f_r = axle_force_per_load(t, x, lf, lr, iz_per_m)
    fast = x[rows, V] >= MIN_SPEED_MPS
    if not fast.any():
        return math.nan
    force = np.quantile(np.maximum(np.abs(f_f), np.abs(f_r))[fast], 0.9)
    if force < TRIED_FRACTION * demand:
        return math.nan
    bends = bend_ratios(t, x, lf, lr, iz_per_m, stiffness_per_rad, min_force)
    return max((b for b in bends if math.isfinite(b)), default=math.nan)


def sine_bend_ratio(q: float, shape: float = MF_SHAPE, n: int = 2001) -> float:
    """The bend ratio (:func:`bend_ratios`' slope) of a magic-formula tyre over a bend whose force
    rises and falls as ``q sin`` of its peak (0 < q < 1): 1.075 at q = 0.5, 1.10 at 0.57, 1.14 at
    0.64, 1.25 at 0.80, 1.40 at 0.90 (quasi-static, every sample used)."""
    f = q * np.sin(np.linspace(0.0, math.pi, n))
    slip = shape * np.tan(np.arcsin(f) / shape)  # K alpha / peak
    return float(np.sum(slip * f) / np.sum(f * f))


_Q_GRID = np.linspace(0.01, 0.99, 197)
_SINE_RATIOS = None


def implied_peak_fraction(bend: float, shape: float = MF_SHAPE) -> float:
    """The inverse of :func:`sine_bend_ratio`: the fraction ``q`` of a magic-formula tyre's peak
    that a bend's demand reached, from its bend ratio (0.01 at or below a ratio of 1, 0.99 at or
    above that of q = 0.99)."""
    return float(np.interp(bend, _sine_ratios(shape), _Q_GRID))


def _sine_ratios(shape: float = MF_SHAPE) -> np.ndarray:
    """:func:`sine_bend_ratio` over ``_Q_GRID`` (computed once, for the default shape)."""
    global _SINE_RATIOS
    if shape != MF_SHAPE:
        return np.array([sine_bend_ratio(q, shape) for q in _Q_GRID])
    if _SINE_RATIOS is None:
        _SINE_RATIOS = np.array([sine_bend_ratio(q, shape) for q in _Q_GRID])
    return _SINE_RATIOS


def implied_level_ratio(bend: float, use_fraction: float, stiffness_law: float = 0.0) -> float:
    """The peak a level's bend ratio implies, over that level: ``r = mu / level``.

    The bend ratio scales with the small-slip stiffness it is read with. Where that is the
    stiffness the car's model states for the level (a context without a fit, the unknown
    value: :func:`~pcvfe_drake.handing.unknown.with_friction`) and the model's stiffness
    follows the friction (``stiffness_law`` k: stiffness ~ mu^k), a level below the peak
    assumes a softer tyre than the car has, the tyre reads more linear than it is, and the
    peak read as ``use_fraction / q(bend)`` lies above the truth. (Read with a fit's own
    stiffness, which the data set, k is 0.) The implied peak is the one consistent
    with its own stiffness: ``sine_bend_ratio(use_fraction / r) = bend * r^k`` (a bend whose
    demand is ``use_fraction`` of the level reaches ``use_fraction / r`` of a peak ``r``
    times the level, and read at that peak's stiffness its ratio is ``bend * r^k``). k = 0:
    ``use_fraction / implied_peak_fraction(bend)``. Clipped to the grid of peak fractions
    (0.01-0.99)."""
    if not math.isfinite(bend):
        return math.nan
    if stiffness_law == 0.0:
        return use_fraction / implied_peak_fraction(bend)
    q = _Q_GRID
    h = _sine_ratios() - float(bend) * (use_fraction / q) ** float(stiffness_law)
    return float(use_fraction / np.interp(0.0, h, q))


def peak_slip_rad(mu: float, stiffness_per_rad, shape: float = MF_SHAPE):
    """Slip angle [rad] at which a magic-formula tyre ``F/Fz = mu sin(C atan(K alpha / (C
    mu)))`` peaks: ``tan(pi / (2 C)) C mu / K`` (``K``: small-slip stiffness per unit load)."""
    return math.tan(math.pi / (2.0 * shape)) * shape * mu / np.asarray(stiffness_per_rad)


def saturated(
    t: np.ndarray,
    states: np.ndarray,
    lf: float,
    lr: float,
    max_slip_rad,
    quantile: float = 0.9,
) -> bool:
    """A sign of saturation in the measured states (``t`` [s], ``states`` (N, 7)): the
    ``quantile`` of ``|alpha_f|`` or ``|alpha_r|``, each a moving mean over ``SLIP_SMOOTH_S``
    of the samples at >= 2 m/s, exceeds ``max_slip_rad`` (one number, or one per axle: front,
    rear; never below ``MIN_SLIP_LIMIT_RAD``). A large rear slip is side slip (the rear lets
    go); a large front slip is a yaw rate short of what the steering asks (the front lets go).
    The moving mean keeps the INS noise from reading as saturation at a low level, where the
    limit is no larger than one sample's noise; the quantile (not the largest value) keeps one
    wild sample from triggering it. Fewer than 10 usable samples (after the mean): False."""
    x = np.asarray(states, dtype=float)
    tt = np.asarray(t, dtype=float)
    if x.ndim != 2 or x.shape[0] == 0 or tt.shape != (x.shape[0],):
        return False
    use = x[:, V] >= MIN_SPEED_MPS
    width = slip_smoothing_width(tt[use])
    if use.sum() - width + 1 < 10:
        return False
    kernel = np.ones(width) / width
    limits = np.maximum(
        np.broadcast_to(np.asarray(max_slip_rad, dtype=float), (2,)), MIN_SLIP_LIMIT_RAD
    )
    for alpha, limit in zip(axle_slip_angles(x[use], lf, lr), limits, strict=True):
        mean = np.convolve(alpha, kernel, mode="valid")  # no padding: the newest samples count
        if np.quantile(np.abs(mean), quantile) > limit:
            return True
    return False


def probe_base(lower_bound: float, floor_mu: float, prior_mu: float) -> float:
    """Where a context's probe starts and never steps below: the used friction ``lower_bound``
    (NaN: none) floored at ``floor_mu``, at most the prior."""
    lb = lower_bound if math.isfinite(lower_bound) else 0.0
    return min(max(lb, floor_mu), prior_mu)


def probe_step(
    state: ProbeState,
    t_now: float,
    *,
    lower_bound: float,
    floor_mu: float,
    prior_mu: float,
    is_saturated: bool,
    step_rel: float,
    hold_s: float,
    max_excess: float,
    use_fraction: float,
    bend: float = math.nan,
    fast_step_rel: float | None = None,
    linear_ratio: float = 1.1,
    bend_limit: float = math.inf,
    start_bend: float = math.nan,
    start_mu: float = math.nan,
    fit_mu: float = math.nan,
    start_since_s: float = math.nan,
    stiffness_law: float = 0.0,
) -> ProbeState:
    """The probe after one update at ``t_now`` (see the module docstring). ``bend``: the larger
    of the current level's axle bend ratios (NaN: no evidence); at most ``linear_ratio``: the
    raise is to the implied peak, at most ``fast_step_rel``; above it or without evidence: no
    raise; above ``bend_limit``: a sign of saturation (``fast_step_rel`` None: the bend is not
    used for the raise, which is ``step_rel`` after every ``hold_s``). ``start_bend``: the
    bend ratio of the context's data before the probe started, driven at ``start_mu`` (NaN: no
    such evidence; the probe starts at its base and holds it ``hold_s``); used only by the
    first call. ``fit_mu``: the context's
    fitted peak where the fit is tight but not identifiable (``probe_fit_target``; NaN: not
    used): a level tried in a bend (a finite ratio, at most ``bend_limit``: no sign of
    saturation) is raised at least to it, still at most one fast step and within the bounds.
    ``start_since_s``: the time [s] from which the context's data were driven at ``start_mu``
    (NaN: not known); a probe that starts at that level counts it from then (its hold and its
    evidence take in those data): the level is not new, the car has driven it since.
    ``stiffness_law``: how the small-slip stiffness the level's bends were read with follows
    the level (the model's law for a level handed with the model's stiffness, 0 for a fit's
    own); the peak a bend implies is the one consistent with it (:func:`implied_level_ratio`)."""
    is_saturated = is_saturated or bool(bend > bend_limit)
    lb = lower_bound if math.isfinite(lower_bound) else 0.0
    base = probe_base(lb, floor_mu, prior_mu)
    if not state.started:
        since_s = t_now  # the level is set now, unless the car drove it already
        if math.isfinite(start_since_s) and math.isclose(base, start_mu, rel_tol=1e-9):
            since_s = start_since_s
        start = ProbeState(mu=base, last_step_s=since_s)
        if is_saturated or fast_step_rel is None or not math.isfinite(start_mu):
            return start
        target = fit_mu if start_bend <= bend_limit and math.isfinite(fit_mu) else 0.0
        if not (start_bend <= linear_ratio or target > base):
            return start  # bent (and no fit above the base), or no evidence (NaN): the base
        implied = 0.0
        if start_bend <= linear_ratio:
            implied = implied_level_ratio(start_bend, use_fraction, stiffness_law) * start_mu
        cap = min(prior_mu, (lb + max_excess) / use_fraction)
        raised = min(start_mu * (1.0 + fast_step_rel), max(implied, target), cap)
        if raised <= base:
            return start
        return ProbeState(mu=raised, last_step_s=t_now, steps=1)
    if is_saturated:
        # never below where it started (what lower_bound hands: the demonstrated friction or
        # the floor), else repeated back-offs would ratchet it down to nothing
        down = max(state.mu / (1.0 + step_rel) ** 2, min(base, state.mu), MIN_PROBE_MU)
        ceiling = max(state.mu / (1.0 + step_rel), min(base, state.mu), MIN_PROBE_MU)
        return ProbeState(
            mu=down,
            ceiling=min(state.ceiling, ceiling),
            last_step_s=t_now,
            steps=state.steps,
            backoffs=state.backoffs + 1,
            backed_off=True,
        )
    if t_now - state.last_step_s < hold_s:
        return state
    cap = min(prior_mu, state.ceiling, (lb + max_excess) / use_fraction)
    step = step_rel  # the bend not in use: the slow step
    if fast_step_rel is not None:
        # to the peak the bend implies (the planner's demand, use_fraction of the handed mu, at
        # the fraction q of it), at most the fast step; bent beyond linear_ratio, or no
        # evidence (a straight): stay
        implied = 0.0
        if bend <= linear_ratio:
            implied = implied_level_ratio(bend, use_fraction, stiffness_law) - 1.0
        if bend <= bend_limit and math.isfinite(fit_mu):  # tried in a bend, not saturated
            implied = max(implied, fit_mu / state.mu - 1.0)
        step = min(fast_step_rel, implied)
    raised = min(state.mu * (1.0 + max(step, 0.0)), cap)
    if raised <= state.mu:  # held or capped: the level and its evidence carry on
        return state
    return ProbeState(raised, state.ceiling, t_now, state.steps + 1, state.backoffs)


def probe_after_fit(
    state: ProbeState, t_now: float, fit_mu: float, base: float, step_rel: float
) -> ProbeState:
    """The back-off at ``t_now`` on a sign of saturation judged at an identifiable fit's level
    ``fit_mu``, handed to the context (not identifiable again) within the last ``hold_s``:
    the car's speed and slips still answer the fit's level, not the probe's, so the ceiling
    becomes one step below ``fit_mu`` and the level at most two steps below it, never below
    the start ``base`` (as :func:`probe_step`). Judged at the probe's own lower level, the slips
    that follow a fit handed above it would read as saturation and set the ceiling at the
    start."""
    mu = state.mu if state.started else base
    ceiling = max(fit_mu / (1.0 + step_rel), min(base, fit_mu), MIN_PROBE_MU)
    down = max(min(mu, fit_mu / (1.0 + step_rel) ** 2), min(base, mu), MIN_PROBE_MU)
    ceiling = min(state.ceiling, ceiling)
    return ProbeState(down, ceiling, t_now, state.steps, state.backoffs + 1, True)


def _step_settings(settings: ProbeSettings) -> dict:
    """:func:`probe_step`'s step, hold and limit settings."""
    return {
        "step_rel": settings.step_rel,
        "hold_s": settings.hold_s,
        "max_excess": settings.max_excess,
        "fast_step_rel": settings.fast_step_rel,
        "linear_ratio": settings.linear_ratio,
        "bend_limit": settings.bend_limit,
    }


def evidence_force(use_fraction: float, mu: float) -> float:
    """The least lateral force per load [g] a sample needs to count as bend evidence for a level
    ``mu``: ``EVIDENCE_FRACTION`` of the planner's demand ``use_fraction * mu`` (relative to the
    level tried: at a low level the planner never asks for an absolute threshold's force)."""
    return EVIDENCE_FRACTION * use_fraction * mu


def probe_update(
    state: ProbeState,
    t_now: float,
    settings: ProbeSettings,
    vehicle,
    lower_bound: float,
    handed: np.ndarray,
    since,
    prior_mu: float,
    drove_mu: float = math.nan,
    fit_mu: float = math.nan,
    stiffness_law: float = 0.0,
) -> ProbeState:
    """One step of a fitted, not identifiable context's probe (:func:`probe_step`) with the
    evidence of its own samples: ``since(t0)`` returns the context's ``(times, states)`` from
    ``t0`` on; ``vehicle`` is the ``VehicleParams``, ``handed`` the theta the car drove with.
    Saturation is checked on the newest ``WINDOW_S``, at ``drove_mu`` where it is above the
    handed mu (an identified fit's, handed within ``hold_s``; a back-off then steps down from
    it: :func:`probe_after_fit`); the bend ratio on the current level's data, all of it (the
    newest ``hold_s`` before the first step); with ``settings.start_evidence`` the first step
    also gets the bend ratio of all the context's data, driven at the stated floor; ``fit_mu``:
    the tight fit's peak the level rises to (NaN: none); ``stiffness_law``: how ``handed``'s
    small-slip stiffness follows its mu (the model's law for a level handed without a fit, 0
    for a fit's own stiffness; :func:`implied_level_ratio`)."""
    use = settings.use_fraction
    t_recent, recent = since(t_now - WINDOW_S)
    level = state.last_step_s if state.started else t_now - settings.hold_s
    t_level, s_level = since(level)
    stiffness = handed[0] * handed[1:]  # mu * C_S per axle: the fit's small-slip stiffness
    judged = max(handed[0], drove_mu) if math.isfinite(drove_mu) else handed[0]
    limit = SLIP_FRACTION * peak_slip_rad(judged, stiffness)
    is_saturated = saturated(t_recent, recent, vehicle.lf, vehicle.lr, limit)
    if is_saturated and judged > handed[0]:
        base = probe_base(lower_bound, settings.floor_mu, prior_mu)
        return probe_after_fit(state, t_now, judged, base, settings.step_rel)
    force = evidence_force(use, handed[0])
    bend = level_bend(t_level, s_level, vehicle, stiffness, force, use * handed[0])
    start_bend = start_mu = start_since = math.nan
    if settings.start_evidence and not state.started:
        # the data before the start, driven at the floor (the unknown-context value)
        start_mu = settings.floor_mu
        t_all, s_all = since(-math.inf)
        start_force = evidence_force(use, start_mu)
        start_bend = level_bend(t_all, s_all, vehicle, stiffness, start_force, use * start_mu)
        start_since = float(t_all[0]) if t_all.size else math.nan
    return probe_step(
        state,
        t_now,
        lower_bound=lower_bound,
        floor_mu=settings.floor_mu,
        prior_mu=prior_mu,
        is_saturated=is_saturated,
        use_fraction=use,
        bend=bend,
        **_step_settings(settings),
        start_bend=start_bend,
        start_mu=start_mu,
        fit_mu=fit_mu,
        start_since_s=start_since,
        stiffness_law=stiffness_law,
    )


def unknown_probe_update(
    state: ProbeState,
    t_now: float,
    settings: ProbeSettings,
    vehicle,
    used: float,
    stiffness_per_rad,
    since,
    prior_mu: float,
    stiffness_law: float = 0.0,
) -> ProbeState:
    """One step of the unknown phase's probe (``!StatedFloor``): while the controller gets the
    unknown-context value (the stated floor), the bends driven since the phase began are read as
    a level tried at the floor, and where they read linear the value is raised once, to at most
    one fast step above the floor (:func:`probe_step`'s rules; ``used``: the lateral friction
    used in the level's data, ``stiffness_per_rad``: the small-slip stiffness the unknown value
    hands, ``since(t0)``: all samples' ``(times, states)`` from ``t0`` on, whatever their
    label; ``stiffness_law``: how that stiffness follows the friction). One step and no more:
    the terrain under a noise frame is unknown and may change under it, and a level one fast
    step above the stated floor asks the car for at most about the floor. A sign of saturation
    backs it off to the floor, where it stays for the rest of the phase."""
    floor, use = settings.floor_mu, settings.use_fraction
    if not state.started:
        return ProbeState(mu=floor, last_step_s=t_now)
    t_recent, recent = since(t_now - WINDOW_S)
    t_level, s_level = since(state.last_step_s)
    force = evidence_force(use, state.mu)
    bend = level_bend(t_level, s_level, vehicle, stiffness_per_rad, force, use * state.mu)
    limit = SLIP_FRACTION * peak_slip_rad(state.mu, stiffness_per_rad)
    new = probe_step(
        state,
        t_now,
        lower_bound=used,
        floor_mu=floor,
        prior_mu=prior_mu,
        is_saturated=saturated(t_recent, recent, vehicle.lf, vehicle.lr, limit),
        use_fraction=use,
        bend=bend,
        **_step_settings(settings),
        stiffness_law=stiffness_law,
    )
    if new.backoffs > state.backoffs:  # back to the floor for the rest of the phase
        return ProbeState(floor, floor, t_now, max(new.steps, 1), new.backoffs, True)
    return state if new.steps > 1 else new


def carried_probe(carried: ProbeState, labels: np.ndarray, ident: int) -> ProbeState | None:
    """The unknown phase's probe ``carried`` as context ``ident``'s first level, or None: only
    when most (80 %) of the level's samples (``labels`` of the samples since its last step) now
    belong to that context (relabelled into it when it was named), i.e. the level was tried on
    this terrain, not on the one before it. A phase's probe that backed off (to the floor) is
    not carried: its back-off says nothing of the new terrain, and carried it would stand for
    a level just set, delaying the context's first step by a hold."""
    if not carried.started or carried.steps < 1 or carried.backoffs or labels.size == 0:
        return None
    if float(np.mean(labels == ident)) < 0.8:
        return None
    return ProbeState(mu=carried.mu, last_step_s=carried.last_step_s, steps=carried.steps)
