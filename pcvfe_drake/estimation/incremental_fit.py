"""Incremental refits of the effect model: windows already fitted keep their information.

A context's refit (``pcvfe_drake.estimation.effect_fit.EffectFitter``) minimises the sum over
its windows of the whitened multi-step prediction errors plus a prior on mu. Most of those
windows were already rolled out at the previous refit, at nearly the same parameters. Each
window ``w`` therefore keeps, per fit state ``s``, the sums over its steps of its errors ``e``
[state units] and their sensitivities ``J = de/dtheta`` on the fitted parameters, evaluated at
its *linearisation point* ``theta_w``::

    ee_ws = sum e^2,    ej_ws = sum e J,    jj_ws = sum J J^T

so that near ``theta_w`` its cost is the quadratic (Gauss-Newton) model::

    cost_w(theta) = sum_s (ee_ws + 2 ej_ws . d + d^T jj_ws d) / sigma_s^2,   d = theta - theta_w

in the square-root information form's terms: the normal equations of the window at its
linearisation. The sums are kept unwhitened, so the noise scales ``sigma_s`` (estimated from
the whole buffer, as the batch fit does) apply at every refit.

A refit (:func:`incremental_refit`):

1. takes the window set the batch fit would take (``EffectFitter.windows``: the newest
   ``max_windows`` of the buffer). **Forgetting**: a stored window that is no longer in that set
   (older than the newest ``max_windows``, or its samples left the buffer) is dropped; nothing
   else is forgotten, so the incremental cost is the batch cost's Gauss-Newton model;
2. rolls out, in one batched rollout, only the windows without information (new since the last
   refit) and those whose linearisation point lies more than ``RELINEARISE_SCALE`` of a
   parameter's typical magnitude (``scale``) from the current estimate (the model's error on
   the minimiser grows with the square of that distance);
3. minimises the sum of the quadratic models and the prior within the bounds (the least-squares
   core on the equivalent linear residual);
4. accepts a step shorter than ``RELINEARISE_SCALE`` at once (the models hold there);
   after a longer one it relinearises (step 2 at the new point) and iterates while the cost
   still falls, at most ``max_iterations`` times. A step that raised the cost is undone and
   retried from the best point at ``1 / STEP_SHRINK`` of its length, at most
   ``MAX_REJECTIONS`` times in a row, as the batch fit's Levenberg-Marquardt damps a rejected
   step. Without the retry a refit started where mu lies far above the friction the data
   used (the flat side of a peak tyre's cost, e.g. a first fit made before the context was
   driven near its limit) stays there: the models linearised on the flat side have almost no
   curvature, their minimiser lies on mu's lower bound, and the cost there is far higher.

A context whose samples were relabelled (a re-clustering moved samples in or out, so a
window's data may have changed) keeps its estimate but no window (``forget_windows``): its next
refit rolls every window out at that estimate, in one batched rollout. A context's first fit
is the batch fit (several starts, more iterations); its residuals and Jacobian at the solution
seed the store.

The standard deviations come from the same sums: the Gauss-Newton information ``sum jj /
sigma^2`` and the windows' scores ``sum (ej + jj d) / sigma^2`` (the gradient at the estimate,
window by window, for the Newey-West sandwich), as the batch fit forms them from its Jacobian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcvfe_drake.models import least_squares as lsq

RELINEARISE_SCALE = 0.05
"""A window's information is re-evaluated once the estimate lies more than this many of a
parameter's typical magnitudes (``EffectParam.scale``; mu's is 0.1 of the nominal mu) from its
linearisation point [-]: the quadratic model's error on the minimiser is of second order in
that distance."""

STEP_SHRINK = 4.0
"""A step that raised the cost is retried at this fraction (1 / STEP_SHRINK) of its length from
the best point [-], the factor by which the batch fit's Levenberg-Marquardt raises its damping
after a rejected step (``models.estimate.fit``)."""

MAX_REJECTIONS = 8
"""Retries of a step that raised the cost before the refit stops at the best point, as many as
the batch fit's Levenberg-Marquardt allows per iteration: 4^-8 of a step across the whole
bounds is far inside ``RELINEARISE_SCALE``, where the windows' models hold and a retry costs no
rollout."""


@dataclass(frozen=True)
class WindowInformation:
    """What the fitted windows of one context contribute, each at its linearisation point.

    Immutable (a refit returns a new one), so the estimator's copies share it.

    Attributes:
        keys: window start times on the sample clock, ``round(t_start / dt)`` (W,).
        theta: each window's linearisation point, the fitted parameters (W, F).
        ee: sums of squared errors per fit state [state units^2] (W, S).
        ej: sums of error x sensitivity (W, S, F).
        jj: sums of the sensitivities' outer products (W, S, F, F).
        estimate: the last estimate, the full parameter vector (P,).
    """

    keys: np.ndarray
    theta: np.ndarray
    ee: np.ndarray
    ej: np.ndarray
    jj: np.ndarray
    estimate: np.ndarray

    def forget_windows(self) -> WindowInformation:
        """No window, the estimate kept: the next refit re-evaluates every window there (after
        a relabelling moved samples in or out, when a window's data may have changed)."""
        return self.select(np.zeros(0, dtype=int))

    def select(self, rows: np.ndarray) -> WindowInformation:
        return WindowInformation(
            self.keys[rows],
            self.theta[rows],
            self.ee[rows],
            self.ej[rows],
            self.jj[rows],
            self.estimate,
        )


def stored_rows(stored_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Each window of ``keys``' row in ``stored_keys`` (-1: not stored)."""
    order = {int(k): i for i, k in enumerate(stored_keys)}
    return np.array([order.get(int(k), -1) for k in keys], dtype=int)


def far_from(points: np.ndarray, point: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Which windows' points (W, F) lie more than ``RELINEARISE_SCALE`` typical magnitudes
    ``scale`` (F,) from ``point`` in some parameter: their stored sums are evaluated again."""
    return np.any(np.abs(points - point) > RELINEARISE_SCALE * scale, axis=1)


def window_sums(r: np.ndarray, jac: np.ndarray, n_windows: int, sigma: np.ndarray, cols):
    """``(ee, ej, jj)`` per window and fit state from whitened residuals ``r`` and their
    Jacobian ``jac`` (window by window, steps then states), unwhitened with ``sigma`` (S,) and
    restricted to the fitted columns ``cols``."""
    n_states = sigma.size
    e = r.reshape(n_windows, -1, n_states) * sigma
    J = jac[:, cols].reshape(n_windows, -1, n_states, len(cols)) * sigma[None, None, :, None]
    ee = np.einsum("wks,wks->ws", e, e)
    ej = np.einsum("wks,wksf->wsf", e, J)
    jj = np.einsum("wksf,wksg->wsfg", J, J)
    return ee, ej, jj


def quadratic(info: WindowInformation, theta_free: np.ndarray, sigma: np.ndarray):
    """The stored windows' Gauss-Newton model at ``theta_free``: ``(ssr, gram (F, F), scores
    (W, F))`` with ``gram = sum jj / sigma^2`` and ``scores = sum_s (ej + jj d) / sigma^2`` the
    per-window ``J_w^T r_w`` of the linearised residuals."""
    w = 1.0 / sigma**2
    d = theta_free[None, :] - info.theta  # (W, F)
    jjd = np.einsum("wsfg,wg->wsf", info.jj, d)
    ssr = float(
        np.einsum("ws,s->", info.ee, w)
        + 2.0 * np.einsum("wsf,wf,s->", info.ej, d, w)
        + np.einsum("wsf,wf,s->", jjd, d, w)
    )
    gram = np.einsum("wsfg,s->fg", info.jj, w)
    scores = np.einsum("wsf,s->wf", info.ej + jjd, w)
    return ssr, gram, scores


@dataclass(frozen=True)
class Problem:
    """What a refit minimises besides the windows: the fitted parameters, the noise scales and
    the bounds, scales and prior of the full parameter vector (P,).

    Attributes:
        free: which parameters are fitted (P,) bool.
        sigma: noise scale per fit state (S,), the whitening.
        lower, upper, scale: bounds and typical magnitudes (P,).
        prior_mean, prior_precision: a Gaussian prior per parameter (precision 0: none).
    """

    free: np.ndarray
    sigma: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    scale: np.ndarray
    prior_mean: np.ndarray
    prior_precision: np.ndarray


def minimise_quadratic(info: WindowInformation, theta: np.ndarray, problem: Problem) -> np.ndarray:
    """The full parameter vector minimising the stored windows' quadratic models plus the
    prior within the bounds, from ``theta`` (the least-squares core on the equivalent linear
    residual ``R d + R^-T b``, ``R^T R`` the Gauss-Newton matrix, ``b`` the gradient / 2)."""
    free, sigma = problem.free, problem.sigma
    x0 = theta[free]
    _, gram, scores = quadratic(info, x0, sigma)
    grad = scores.sum(axis=0)
    ridge = 1e-12 * max(float(np.trace(gram)), 1e-300)
    R = np.linalg.cholesky(gram + ridge * np.eye(gram.shape[0])).T
    c = np.linalg.solve(R.T, grad)
    p_all = theta.size
    free_idx = np.flatnonzero(free)

    def fun(th, need_jacobian):
        r = R @ (th[free_idx] - x0) + c
        if not need_jacobian:
            return r, None
        J = np.zeros((r.size, p_all))
        J[:, free_idx] = R
        return r, J

    out = lsq.solve(
        fun,
        theta,
        problem.lower,
        problem.upper,
        problem.scale,
        free=free,
        prior_mean=problem.prior_mean,
        prior_precision=problem.prior_precision,
        settings=lsq.LsqSettings(max_iterations=20, xtol=1e-9, ftol=1e-12),
    )
    return out.theta


@dataclass
class IncrementalOutcome:
    """The result of :func:`incremental_refit` (the fields a ``FitResult`` is built from)."""

    theta: np.ndarray
    info: WindowInformation
    ssr: float
    gram: np.ndarray
    scores: np.ndarray
    iterations: int
    converged: bool
    rollouts: int
    history: list[float]


def incremental_refit(
    evaluate,
    keys: np.ndarray,
    info: WindowInformation,
    theta0: np.ndarray,
    problem: Problem,
    max_iterations: int,
) -> IncrementalOutcome | None:
    """Refit on the windows ``keys`` (time order) from the stored ``info`` (see the module
    docstring). ``evaluate(theta, rows) -> (ee, ej, jj)`` or None (a rollout that diverged)
    rolls out the windows ``keys[rows]`` at ``theta``. None when a rollout diverged."""
    free, sigma = problem.free, problem.sigma
    kept = np.isin(info.keys, keys)
    info = info.select(np.flatnonzero(kept))
    where = stored_rows(info.keys, keys)
    n_free = int(free.sum())
    # the store in the order of ``keys``; rows without information yet are evaluated below
    placeholder = np.zeros((keys.size, n_free))
    stored = WindowInformation(
        keys.copy(),
        np.where(where[:, None] >= 0, info.theta[np.maximum(where, 0)], placeholder)
        if info.keys.size
        else placeholder,
        np.zeros((keys.size, sigma.size)),
        np.zeros((keys.size, sigma.size, n_free)),
        np.zeros((keys.size, sigma.size, n_free, n_free)),
        info.estimate,
    )
    if info.keys.size:
        have = where >= 0
        stored.ee[have] = info.ee[where[have]]
        stored.ej[have] = info.ej[where[have]]
        stored.jj[have] = info.jj[where[have]]
    missing = where < 0
    free_scale = problem.scale[free]
    theta = np.clip(np.asarray(theta0, dtype=float).copy(), problem.lower, problem.upper)
    precision = np.asarray(problem.prior_precision, dtype=float)[free]
    mean = np.asarray(problem.prior_mean, dtype=float)[free]

    def prior_cost(th):
        p = precision > 0
        return float(np.sum(precision[p] * (th[free][p] - mean[p]) ** 2))

    rollouts = 0
    history: list[float] = []
    best = None  # (theta, cost, store) of the last accepted point
    converged = False
    iterations = 0
    rejections = 0
    while True:
        far = far_from(stored.theta, theta[free], free_scale)
        rows = np.flatnonzero(missing | far)
        if rows.size:
            sums = evaluate(theta, rows)
            rollouts += 1
            if sums is None:
                return None
            ee, ej, jj = sums
            thetas = stored.theta.copy()
            thetas[rows] = theta[free]
            new_ee, new_ej, new_jj = stored.ee.copy(), stored.ej.copy(), stored.jj.copy()
            new_ee[rows], new_ej[rows], new_jj[rows] = ee, ej, jj
            stored = WindowInformation(keys, thetas, new_ee, new_ej, new_jj, theta.copy())
            missing = np.zeros(keys.size, bool)
        ssr, _, _ = quadratic(stored, theta[free], sigma)
        cost = ssr + prior_cost(theta)
        if best is not None and not cost < best[1]:
            # the step raised the cost: back to the best point, and retry a shorter step there
            # while retries are left (the cost of a peak tyre rises steeply on one side of
            # the peak, where a model linearised on the flat side overshoots)
            rejections += 1
            if rejections > MAX_REJECTIONS:
                theta, stored = best[0], best[2]
                converged = True
                break
            trial = best[0].copy()
            trial[free] = best[0][free] + (theta[free] - best[0][free]) / STEP_SHRINK
            theta, stored = trial, best[2]
            continue
        rejections = 0
        iterations += 1
        history.append(cost)
        best = (theta.copy(), cost, stored)
        step = minimise_quadratic(stored, theta, problem)
        if np.all(np.abs(step[free] - theta[free]) <= RELINEARISE_SCALE * free_scale):
            theta = step  # a short step: the models hold there
            converged = True
            break
        if iterations == max_iterations:
            break  # the last step is not evaluated: keep the best point
        theta = step
    ssr, gram, scores = quadratic(stored, theta[free], sigma)
    stored = WindowInformation(
        stored.keys, stored.theta, stored.ee, stored.ej, stored.jj, theta.copy()
    )
    return IncrementalOutcome(
        theta, stored, ssr, gram, scores, iterations, converged, rollouts, history
    )
