"""Exploration for a context whose friction peak is not identifiable (``unidentified_mu: probe``).

With a saturating tyre the friction peak is observable only where the tyres work near it
(``docs/fitting.md``, "Identifiability"). The NMPC's speed profile uses about
``speed_margin^2`` (0.64) of the mu it is handed, so a car handed the used-friction lower bound
uses 0.64 of it, the bound ratchets down and the peak never becomes observable. The probe breaks
that loop for one context at a time, as a test driver would: it hands the NMPC a mu above the
demonstrated bound, raises it step by step while the tyres show no saturation, and backs off at
the first sign of it. The estimate takes over as soon as the fit is identifiable (the
``ContextEstimator`` then hands the estimate, not the probe).

The rules (:func:`probe_step`), each number a field of ``LiveFitConfig``:

* **start** at what ``lower_bound`` hands: ``max(mu_lower_bound, unknown_floor_mu)``;
* **raise** by the factor ``1 + probe_step_rel`` (0.1: the step is a tenth of the friction
  asked for, so an overshoot past the limit is at most that) after every ``probe_hold_s`` (3 s)
  spent on the context without a sign of saturation: the paper's slalom has a bend every
  18.7 m, about 3 s at the 5-6 m/s driven there, so each level is tried in a bend before the
  next;
* **bounded** by ``(mu_lower_bound + probe_max_excess) / probe_use_fraction``: the planner is
  never asked to use more than ``probe_max_excess`` (0.08, about one step on sand's 0.45) more
  friction than the car has demonstrated; the bound moves up only as the car actually uses
  more. ``probe_use_fraction`` is the planner's share of mu (``speed_margin^2``; the scenario
  fills it from ``nmpc.speed_margin``);
* **never above** the prior mu (the most the operator believes any terrain has), nor above a
  ceiling set by an earlier back-off;
* **back off** on a sign of saturation (:func:`saturated`: a large slip angle on either axle, i.e.
  side slip at the rear or yaw response short of the steering at the front): two steps down, but
  never below the start, and the level one step below the one that saturated becomes the context's
  ceiling (at least the start). "Large" is ``probe_slip_fraction`` (0.5) of the slip at which a
  magic-formula tyre (shape ``MF_SHAPE`` = 1.35, as ``peak_tyre``) with the fitted small-slip
  stiffness ``K`` would peak at the mu being handed (:func:`peak_slip_rad`: ``tan(pi / (2 C)) C mu
  / K``, 0.043 rad for mu 0.3 at the Ford Escort's K = 21.9 /rad). At half that slip such a tyre
  already delivers 92 % of its peak, about twice the slip a linear tyre needs for the force; the
  planner asks for 0.64 of the handed mu, which needs only a quarter of the peak slip (0.24) if
  the peak is where the probe assumes. A larger slip says the peak is lower than the handed mu.

No pydrake.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pcvfe_drake.json_numbers import finite_or_none
from pcvfe_drake.vehicle.single_track import BETA, DELTA, PSI_DOT, V

MIN_PROBE_MU = 0.05
"""Smallest mu a back-off hands (keeps the speed profile defined)."""
MIN_SLIP_LIMIT_RAD = 0.01
"""Smallest slip limit of the saturation test [rad]: the 90th percentile of the slip angles'
measurement noise alone (INS side slip 0.005 rad, yaw rate 0.01 rad/s: ~0.009 rad); a limit
below it would call every low level saturated and ratchet the probe down."""
MF_SHAPE = 1.35
"""Magic-formula shape factor of the tyre the saturation test assumes (``peak_tyre``'s C)."""
MIN_SPEED_MPS = 2.0
"""Samples slower than this are not used for the slip angles (kinematic slip dominates)."""


@dataclass(frozen=True)
class ProbeState:
    """One context's probe.

    Attributes:
        mu: the mu handed while probing (NaN: not started).
        ceiling: the largest mu it may hand again (inf until a back-off).
        last_step_s: time of the last raise or back-off [s].
        steps: raises so far.
        backoffs: back-offs so far.
    """

    mu: float = float("nan")
    ceiling: float = float("inf")
    last_step_s: float = float("nan")
    steps: int = 0
    backoffs: int = 0

    @property
    def started(self) -> bool:
        return math.isfinite(self.mu)

    def to_dict(self) -> dict:
        return {
            "mu": finite_or_none(self.mu),
            "ceiling": finite_or_none(self.ceiling),
            "steps": self.steps,
            "backoffs": self.backoffs,
        }


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


def peak_slip_rad(mu: float, stiffness_per_rad, shape: float = MF_SHAPE):
    """Slip angle [rad] at which a magic-formula tyre ``F/Fz = mu sin(C atan(K alpha / (C
    mu)))`` peaks: ``tan(pi / (2 C)) C mu / K`` (``K``: small-slip stiffness per unit load)."""
    return math.tan(math.pi / (2.0 * shape)) * shape * mu / np.asarray(stiffness_per_rad)


def saturated(
    states: np.ndarray, lf: float, lr: float, max_slip_rad, quantile: float = 0.9
) -> bool:
    """A sign of saturation in the measured states: the ``quantile`` of ``|alpha_f|`` or
    ``|alpha_r|`` over the samples at >= 2 m/s exceeds ``max_slip_rad`` (one number, or one
    per axle: front, rear; never below ``MIN_SLIP_LIMIT_RAD``, the noise). A large rear slip is
    side slip (the rear lets go); a large front slip is a yaw rate short of what the steering
    asks (the front lets go). The quantile (not the largest value) keeps one noisy sample from
    triggering it. Fewer than 10 usable samples: False."""
    x = np.asarray(states, dtype=float)
    if x.ndim != 2 or x.shape[0] == 0:
        return False
    use = x[:, V] >= MIN_SPEED_MPS
    if use.sum() < 10:
        return False
    af, ar = axle_slip_angles(x[use], lf, lr)
    limit_f, limit_r = np.maximum(
        np.broadcast_to(np.asarray(max_slip_rad, dtype=float), (2,)), MIN_SLIP_LIMIT_RAD
    )
    return bool(
        np.quantile(np.abs(af), quantile) > limit_f or np.quantile(np.abs(ar), quantile) > limit_r
    )


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
) -> ProbeState:
    """The probe after one update at ``t_now`` (see the module docstring)."""
    lb = lower_bound if math.isfinite(lower_bound) else 0.0
    base = min(max(lb, floor_mu), prior_mu)
    if not state.started:
        return ProbeState(mu=base, last_step_s=t_now)
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
        )
    if t_now - state.last_step_s < hold_s:
        return state
    cap = min(prior_mu, state.ceiling, (lb + max_excess) / use_fraction)
    raised = min(state.mu * (1.0 + step_rel), cap)
    if raised <= state.mu:
        return ProbeState(state.mu, state.ceiling, t_now, state.steps, state.backoffs)
    return ProbeState(raised, state.ceiling, t_now, state.steps + 1, state.backoffs)


def controller_theta(
    estimate, probe: ProbeState, theta: np.ndarray, unidentified_mu: str, floor_mu: float
) -> np.ndarray:
    """The theta the controller gets for a fitted context (``ContextEstimate`` ``estimate``,
    its fit's ``theta``); the stiffnesses are always scaled to keep the fit's ``mu * C_S``:

    * a friction peak fitted below the friction the data used (``below_used``) is impossible:
      mu is raised to the used friction (the smallest peak the data allow);
    * ``unidentified_mu: lower_bound``: a context whose mu is not identifiable gets
      ``max(mu_lower_bound, floor_mu)`` (at most its estimate);
    * ``unidentified_mu: probe``: such a context gets the probe's mu (before its first step
      the lower bound's value), at most the upper end of the estimate's 95 % interval ``mu +
      1.96 std`` (a value the context's data do not exclude; no limit when the estimate is
      below the used friction or has no std).
    """
    mu = float(theta[0])
    bound = estimate.mu_lower_bound if math.isfinite(estimate.mu_lower_bound) else 0.0
    if estimate.below_used:
        mu = max(mu, bound)
    if not estimate.identifiable and unidentified_mu in ("lower_bound", "probe"):
        cap = math.inf if estimate.below_used else mu
        start = max(bound, floor_mu)
        if unidentified_mu == "probe":
            std = estimate.mu_std
            cap = mu + 1.96 * std if math.isfinite(std) and not estimate.below_used else math.inf
            start = probe.mu if probe.started else start
        mu = min(start, cap)
    if mu == theta[0]:
        return theta
    return np.array([mu, theta[1] * theta[0] / mu, theta[2] * theta[0] / mu])
