"""Friction fitting with the workbench's model: the single-track model plus effects.

``pcvfe diagnose`` finds which effects the single-track (ST) model lacks on a log; this module
lets the context fitter (``ContextEstimator``, scenario ``fitter.effects``) and ``pcvfe fit
--effects`` estimate friction *with* those effects, through the same model
(:class:`~pcvfe_drake.models.model.WorkbenchModel`), the same windows and cost
(:func:`~pcvfe_drake.models.estimate.fit`: multi-step whitened rollout errors,
finite-difference sensitivities in one batched rollout) and the same least-squares core
(:mod:`pcvfe_drake.models.least_squares`) as the diagnosis.

Per context the fitted parameters are the base ``mu`` and every effect parameter that the
scenario does not fix (``FitterEffect.fixed``: values found by ``pcvfe diagnose``); a context's
refit is warm-started from its previous full parameter vector.

What the controller gets
------------------------
The NMPC's single-track model takes ``theta = [mu, C_Sf, C_Sr]``. From a fitted effect model:

* ``mu`` = the fitted base mu. With an effect whose class says ``friction_is_peak = True`` this
  is the friction *peak* (the largest lateral force per unit load), which is what the NMPC's
  friction limit needs; otherwise it is the ST model's mu (a scale of the linear tyre);
* ``C_Sf, C_Sr`` such that ``mu * C_S`` equals the fitted model's small-slip cornering stiffness
  per unit axle load (measured on the model itself: the axle forces at a slip of 1e-4 rad, straight
  running at 10 m/s, static loads), so the NMPC's linear-range dynamics are those of the fit.

Identifiability (``friction_used``): how much friction the context's data actually used, the
95th percentile of ``sqrt(a_x^2 + a_y^2) / g`` with ``a_y = v (psi_dot + beta_dot)`` and ``a_x =
dv/dt`` from the measured states (smoothed over 0.1 s). A car that drove there without sliding
had at least that much friction: it is a lower bound on mu. When it stays far below the fitted
peak the data never came near the limit and a peak is barely observable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pcvfe_drake.estimation.fit_options import COVARIANCES, HAC_LAG_S, with_model_error
from pcvfe_drake.estimation.incremental_fit import (
    Problem,
    WindowInformation,
    incremental_refit,
    window_sums,
)
from pcvfe_drake.models.data import (
    NOISE_STRIDE_S,
    DriveData,
    NoiseScaleCache,
    denoised_delta_sigma,
    initial_state_estimates,
    robust_noise_sigmas,
    window_starts,
)
from pcvfe_drake.models.effect_model import parse_effects
from pcvfe_drake.models.estimate import fit
from pcvfe_drake.models.model import WorkbenchModel
from pcvfe_drake.vehicle.params import VehicleParams
from pcvfe_drake.vehicle.single_track import BETA, PSI_DOT, V

G_MPS2 = 9.81
FRICTION_USED_QUANTILE = 0.95
"""Quantile of the used friction ``sqrt(a_x^2 + a_y^2) / g`` taken as its lower bound on mu."""
FRICTION_USED_SMOOTH_S = 0.1
"""Central-difference half span [s] for the measured accelerations (noise averaging)."""
COLD_MU_FACTORS = (1.0, 0.8, 0.6, 0.4)
"""Starts of a context's first fit: these factors on the starting mu (the prior's)."""
COLD_ITERATION_FACTOR = 3
"""A context's first fit may take this many times ``max_iterations``."""
JACOBIAN_AT_TRIALS_MAX_FREE = 2
"""With at most this many fitted parameters the batch fit rolls each trial point out with its
finite-difference rows (``estimate.fit``'s ``jacobian_at_trials``): on a context's buffer (at
most ``max_windows`` windows) a rollout of up to 5 rows per window costs about what one row
does (numpy's per-call overhead), so an accepted step costs one rollout instead of two."""
STIFFNESS_PROBE_SLIP_RAD = 1e-4
STIFFNESS_PROBE_SPEED_MPS = 10.0


def friction_is_peak(model) -> bool:
    """Whether the model's base mu is the friction peak (an effect with ``friction_is_peak``)."""
    return any(getattr(e, "friction_is_peak", False) for e in model.effects)


def build_model(vehicle: VehicleParams, effects, contexts=("all",)):
    """The workbench model (base mu per context) and its fixed-parameter mask and start."""
    specs = parse_effects(effects)
    model = WorkbenchModel(vehicle, [s.name for s in specs], ("mu",), list(contexts))
    theta0 = model.initial_theta()
    fixed = np.zeros(model.n_params, bool)
    index = {p: i for i, p in enumerate(model.param_names)}
    for s in specs:
        for key, value in s.fixed.items():
            i = index[f"{s.name}.{key}"]
            theta0[i] = value
            fixed[i] = True
    return model, fixed, theta0


def small_slip_stiffness(model, theta: np.ndarray, context: int = 0) -> np.ndarray:
    """``mu * C_S`` per axle [1/rad] of the model at ``theta``: the lateral force per unit axle
    load and radian of slip at a small slip (straight running, 10 m/s, no acceleration
    command)."""
    vp = model.vehicle
    theta_rows = np.atleast_2d(np.asarray(theta, dtype=float))
    base, eff = model._unpack(theta_rows, np.array([context]))
    z = np.zeros((1, model.nz))
    z[0, V] = STIFFNESS_PROBE_SPEED_MPS
    z[0, BETA] = -STIFFNESS_PROBE_SLIP_RAD  # alpha_f = alpha_r = +slip
    zdot = model.rhs(z, np.zeros((1, 2)), base, eff)
    total = (zdot[0, BETA] + z[0, PSI_DOT]) * vp.m * STIFFNESS_PROBE_SPEED_MPS  # F_yf + F_yr
    moment = zdot[0, PSI_DOT] * vp.I_z  # lf F_yf - lr F_yr
    wheelbase = vp.lf + vp.lr
    fyf = (moment + vp.lr * total) / wheelbase
    fyr = total - fyf
    a_long = zdot[0, V]  # the loads the model used (a resistance transfers load)
    fz = vp.m * np.array([vp.g * vp.lr - a_long * vp.h, vp.g * vp.lf + a_long * vp.h]) / wheelbase
    return np.array([fyf, fyr]) / (fz * STIFFNESS_PROBE_SLIP_RAD)


def controller_theta(model, theta: np.ndarray, context: int = 0) -> np.ndarray:
    """``[mu, C_Sf, C_Sr]`` for the NMPC's ST model from a fitted effect model (see the module
    docstring): mu the fitted base mu, ``mu * C_S`` the model's small-slip stiffness."""
    mu_idx = next(
        i for i, p in enumerate(model.params) if p.effect is None and p.context == context
    )
    mu = float(theta[mu_idx])
    k = small_slip_stiffness(model, theta, context)
    return np.array([mu, k[0] / mu, k[1] / mu])


def identifiability(
    t: np.ndarray,
    states: np.ndarray,
    mu: float,
    std: float,
    peak: bool,
    lower_bound: float,
    near_limit_fraction: float,
    identifiable_std: float,
    wheel_share: float = float("nan"),
) -> dict:
    """A context estimate's identifiability fields after a fit with ``mu +- std`` on its buffer
    (``t``, ``states``); ``lower_bound``: the previous estimate's ``mu_lower_bound`` (NaN:
    none).

    ``peak``: mu is the tyre's lateral friction peak (an effect model with a peak tyre): the
    lower bound is then the lateral friction used (``friction_used(lateral_only=True)``; braking
    and driving say nothing about a lateral peak), and a fitted peak below it is impossible
    (``below_used``: not identifiable, whatever its std). Near the limit: the used friction
    reached ``near_limit_fraction`` of mu, or ``wheel_share`` (``probe.wheel_peak_share``: how
    near the most-used wheel came to its peak; NaN: not judged) reached ``near_limit_fraction``;
    identifiable: near it, not below it, and ``std <= identifiable_std``."""
    used = friction_used(t, states, lateral_only=peak)
    if math.isfinite(lower_bound):
        used = lower_bound if not math.isfinite(used) else max(used, lower_bound)
    near = bool(math.isfinite(used) and used >= near_limit_fraction * mu) or bool(
        peak and math.isfinite(wheel_share) and wheel_share >= near_limit_fraction
    )
    below = bool(peak and math.isfinite(used) and mu < used)
    ident = bool(near and not below and math.isfinite(std) and std <= identifiable_std)
    return {
        "mu_lower_bound": float(used),
        "near_limit": near,
        "identifiable": ident,
        "below_used": below,
    }


def friction_used(
    t: np.ndarray,
    states: np.ndarray,
    quantile: float = FRICTION_USED_QUANTILE,
    lateral_only: bool = False,
):
    """Lower bound on mu from the measured states: the ``quantile`` of ``sqrt(a_x^2 + a_y^2) / g``
    (``lateral_only``: of ``|a_y| / g``, the bound on a lateral friction peak) over samples
    whose neighbours +-0.1 s are evenly spaced (NaN with fewer than 20 such)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(states, dtype=float)
    if t.size < 3:
        return float("nan")
    dt = float(np.median(np.diff(t)))
    m = max(1, int(round(FRICTION_USED_SMOOTH_S / max(dt, 1e-9))))
    if t.size <= 2 * m:
        return float("nan")
    span = t[2 * m :] - t[: -2 * m]
    ok = np.abs(span - 2 * m * dt) <= 0.1 * 2 * m * dt
    ax = (x[2 * m :, V] - x[: -2 * m, V]) / np.where(ok, span, 1.0)
    beta_dot = (x[2 * m :, BETA] - x[: -2 * m, BETA]) / np.where(ok, span, 1.0)
    mid = x[m:-m]
    ay = mid[:, V] * (mid[:, PSI_DOT] + beta_dot)
    use = ok & (mid[:, V] >= 1.0)
    if use.sum() < 20:
        return float("nan")
    used = np.abs(ay) if lateral_only else np.hypot(ax, ay)
    return float(np.quantile(used[use] / G_MPS2, quantile))


def drive_data_from_arrays(
    t: np.ndarray,
    states: np.ndarray,
    inputs: np.ndarray,
    source: str,
    noise_cache: NoiseScaleCache | None = None,
):
    """A one-context :class:`~pcvfe_drake.models.data.DriveData` from buffer arrays (time
    gaps allowed: the initial-state smoothing runs per gap-free segment, windows never span a
    gap), noise scales estimated as ``pcvfe diagnose`` does (with ``noise_cache``, the
    buffer's cache of them: the same numbers, only the new samples' work)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(states, dtype=float).copy()
    u = np.asarray(inputs, dtype=float)
    dt = float(np.median(np.diff(t)))
    x[:, 4] = np.unwrap(x[:, 4])
    breaks = np.flatnonzero(np.abs(np.diff(t) - dt) > 0.5 * dt) + 1
    x0 = np.empty_like(x)
    for seg in np.split(np.arange(t.size), breaks):
        x0[seg] = initial_state_estimates(x[seg], u[seg], dt)
    longest = max(np.split(np.arange(t.size), breaks), key=len)
    strides = max(1, int(round(NOISE_STRIDE_S / dt)))
    if noise_cache is None:
        sigma = robust_noise_sigmas(x[longest], strides)
    else:
        sigma = noise_cache.sigmas(t[longest], x[longest], strides)
    sigma = np.maximum(sigma, 1e-4 * np.maximum(np.ptp(x, axis=0), 1e-6))
    return DriveData(
        t,
        dt,
        x,
        u,
        np.zeros(t.size, dtype=int),
        ["all"],
        sigma,
        source,
        x0,
        x0_delta_sigma=denoised_delta_sigma(x[longest], u[longest], dt),
    )


@dataclass
class EffectFitResult:
    """One context's fit of the effect model (duck-compatible with ``FitResult`` where the
    ``ContextEstimator`` reads it).

    Attributes:
        theta, std: the controller's ``[mu, C_Sf, C_Sr]`` (see the module docstring) and their
            standard deviations (mu's from the fit; the stiffnesses' NaN).
        model_theta, model_std: the fitted model's full parameter vector and its std.
        param_names: names of ``model_theta``.
        loss: the training cost per residual (whitened, ~1 when the model explains the data to
            the noise).
        status, converged, iterations, n_windows, warnings: as ``FitResult``.
        mu_is_peak: whether mu is the friction peak.
    """

    theta: np.ndarray
    std: np.ndarray
    model_theta: np.ndarray
    model_std: np.ndarray
    param_names: list[str]
    loss: float
    status: str
    converged: bool
    iterations: int
    n_windows: int
    mu_is_peak: bool
    warnings: list[str] = field(default_factory=list)
    incremental: bool = False
    """Whether the refit kept the stored windows' information (``incremental_fit``)."""
    rollouts: int = 0
    """Batched rollouts of an incremental refit (0: a batch fit)."""
    data_end_s: float = math.nan
    """The newest sample time inside a fitted window [s]."""
    ssr: float = math.nan
    """An incremental refit's whitened sum of squared errors at the estimate: the windows'
    quadratic models there (``incremental_fit.quadratic``; NaN: a batch fit)."""
    windows: tuple | None = field(default=None, repr=False, compare=False)
    """What the fit was made on, ``(DriveData, starts, horizon, burn_in)``, for checks of the
    same windows (``fit_quality.peak_not_shown``) without building the data again."""


@dataclass
class EffectFitter:
    """Fits one context's buffer with the effect model (the online path of ``fitter.effects``).

    Windows of ``horizon_s`` (default 1 s, as ``pcvfe diagnose``) every ``stride_s``, the first
    ``burn_in_s`` of each left out of the cost, at v >= 1 m/s, not spanning a time gap; the
    newest ``max_windows`` are used, at most ``max_iterations`` Levenberg-Marquardt iterations
    per refit (warm-started). Standard deviations: ``covariance`` ``hac`` (default: the sandwich
    with a Newey-West estimate over the time-ordered windows, lag ``horizon_s + hac_lag_s``;
    ``least_squares.hac_covariance``) or ``iid`` (the workbench's Gauss-Newton std inflated for
    the windows' overlap); ``model_error_rel`` adds a model-error budget to mu's std
    (``fit_options.with_model_error``). A weak Gaussian prior on mu (mean: ``mu_start``, the
    estimator's prior mu; sd ``mu_prior_sd``, inf: none) keeps a peak the data never approached
    near the prior instead of on a bound; on data that determine mu (std ~0.02) it moves mu by
    ~0.1 % of its distance to the prior.
    """

    vehicle: VehicleParams
    effects: list = field(default_factory=list)
    horizon_s: float = 1.0
    burn_in_s: float = 0.25
    stride_s: float = 0.5
    max_windows: int = 100
    max_iterations: int = 5
    min_windows: int = 10
    mu_prior_sd: float = 0.5
    covariance: str = "hac"
    hac_lag_s: float = HAC_LAG_S
    model_error_rel: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.model_error_rel) and self.model_error_rel >= 0):
            raise ValueError(
                f"EffectFitter.model_error_rel must be >= 0, got {self.model_error_rel!r}"
            )
        if self.covariance not in COVARIANCES:
            raise ValueError(
                f"EffectFitter.covariance must be one of {COVARIANCES}, got {self.covariance!r}"
            )
        self.model, self.fixed, self.theta_init = build_model(self.vehicle, self.effects)
        self._free_cols = np.flatnonzero(~self.fixed)
        self.mu_is_peak = friction_is_peak(self.model)
        # the compiled rollout and the noise scales' kernels loaded when the fitter is built,
        # not in its first refit (which would wait for numba's import and disk cache inside
        # the loop)
        from pcvfe_drake.models import noise_kernel

        self.model.load_compiled_rollout()
        noise_kernel.load()

    def hac_lag(self) -> int | None:
        """Lag in windows of the ``hac`` covariance (windows starting within a window's span
        plus ``hac_lag_s``), None for ``iid`` (the workbench's overlap-inflated std)."""
        if self.covariance != "hac":
            return None
        return max(1, math.ceil((self.horizon_s + self.hac_lag_s) / self.stride_s - 1e-9))

    def start_vector(self, previous=None, mu_start: float | None = None) -> np.ndarray:
        """The warm start: the previous full vector if it fits this model, else the initial
        vector with mu = ``mu_start``."""
        if previous is not None and len(previous) == self.model.n_params:
            return np.asarray(previous, dtype=float)
        theta = self.theta_init.copy()
        if mu_start is not None and math.isfinite(mu_start):
            theta[0] = mu_start
        return theta

    def windows(self, data) -> tuple[np.ndarray, int, int]:

        horizon = max(2, int(round(self.horizon_s / data.dt)))
        stride = max(1, int(round(self.stride_s / data.dt)))
        burn_in = min(int(round(self.burn_in_s / data.dt)), horizon - 1)
        # One block: every window of the buffer. The workbench's default (6 time blocks, no
        # window across a block boundary) is its train/held-out split; here it would drop most
        # windows of a short buffer and delay a context's first fit.
        starts = window_starts(data, horizon, stride, "all", 1)
        return starts[-self.max_windows :], horizon, burn_in

    def __call__(
        self,
        t,
        states,
        inputs,
        previous=None,
        mu_start=None,
        with_information: bool = False,
        noise_cache: NoiseScaleCache | None = None,
    ):
        """Fit the buffer (the batch fit); None when it holds fewer than ``min_windows``
        windows; with ``with_information`` a pair ``(result, WindowInformation)`` (the windows'
        sums at the solution, to seed :meth:`refit`).

        A warm refit (``previous``: the context's last full vector) runs ``max_iterations``;
        the first fit of a context (cold) starts from the best of ``COLD_MU_FACTORS`` x
        ``mu_start`` (with a peak tyre the nominal mu is rarely near the peak; the costs of the
        starts are residual-only rollouts) and runs ``COLD_ITERATION_FACTOR`` x as many.
        ``noise_cache``: the buffer's noise scales cache (``drive_data_from_arrays``)."""

        if len(t) < 10:
            return None
        data = drive_data_from_arrays(t, states, inputs, "context buffer", noise_cache)
        starts, horizon, burn_in = self.windows(data)
        if starts.size < self.min_windows:
            return None
        theta0 = self.start_vector(previous, mu_start)
        cold = previous is None or len(previous) != self.model.n_params
        candidates = None
        if cold:
            candidates = []
            for f in COLD_MU_FACTORS[1:]:
                c = theta0.copy()
                c[0] = theta0[0] * f
                candidates.append(c)
        prior_mean = self.start_vector(None, mu_start)
        prior_sd = np.full(self.model.n_params, np.inf)
        prior_sd[0] = self.mu_prior_sd
        res = fit(
            self.model,
            data,
            starts,
            horizon,
            theta0=theta0,
            candidates=candidates,
            prior_mean=prior_mean,
            prior_sd=prior_sd,
            max_iter=self.max_iterations * (COLD_ITERATION_FACTOR if cold else 1),
            overlap=self.horizon_s / self.stride_s,
            burn_in=burn_in,
            fixed=self.fixed,
            hac_lag=self.hac_lag(),
            jacobian_at_trials=self._free_cols.size <= JACOBIAN_AT_TRIALS_MAX_FREE,
        )
        result = to_result(self.model, res, starts.size, self.model_error_rel)
        result.data_end_s = float(data.t[starts[-1] + horizon])
        result.windows = (data, starts, horizon, burn_in)
        if not with_information or res.residuals is None or res.jacobian is None:
            return result
        if not np.all(np.isfinite(res.residuals)):
            return result, None
        ee, ej, jj = window_sums(
            res.residuals, res.jacobian, starts.size, self._fit_sigma(data), self._free_cols
        )
        info = WindowInformation(
            self._window_keys(data, starts),
            np.tile(res.theta[~self.fixed], (starts.size, 1)),
            ee,
            ej,
            jj,
            res.theta.copy(),
        )
        return result, info

    def _fit_sigma(self, data) -> np.ndarray:
        from pcvfe_drake.models.estimate import FIT_STATES

        return data.sigma[list(FIT_STATES)]

    @staticmethod
    def _window_keys(data, starts) -> np.ndarray:
        return np.round(data.t[starts] / data.dt).astype(np.int64)

    def refit(self, t, states, inputs, info=None, mu_start=None, previous=None, noise_cache=None):
        """An incremental refit (``pcvfe_drake.estimation.incremental_fit``): ``(result,
        information)``, the result None when the buffer holds fewer than ``min_windows``
        windows (the information then unchanged). Without stored ``info`` (a context's first
        fit, or its samples relabelled) the batch fit (:meth:`__call__`, warm from
        ``previous``) runs and seeds it. ``noise_cache``: the buffer's noise scales cache
        (``drive_data_from_arrays``)."""
        from pcvfe_drake.models.estimate import (
            FIT_STATES,
            FitResult,
            _residuals_and_jacobian,
            parameter_std,
        )

        if info is None or info.estimate.size != self.model.n_params:
            out = self(t, states, inputs, previous, mu_start, True, noise_cache)
            return (None, info) if out is None else out
        if len(t) < 10:
            return None, info
        data = drive_data_from_arrays(t, states, inputs, "context buffer", noise_cache)
        starts, horizon, burn_in = self.windows(data)
        if starts.size < self.min_windows:
            return None, info
        sigma = self._fit_sigma(data)
        model, free = self.model, ~self.fixed

        def evaluate(theta, rows):
            r, jac = _residuals_and_jacobian(
                model, theta, data, starts[rows], horizon, True, burn_in, self._free_cols
            )
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
                return None
            return window_sums(r, jac, rows.size, sigma, self._free_cols)

        prior_mean = self.start_vector(None, mu_start)
        precision = np.zeros(model.n_params)
        precision[0] = 1.0 / self.mu_prior_sd**2
        lo, hi = model.bounds()
        problem = Problem(free, sigma, lo, hi, model.scales(), prior_mean, precision)
        out = incremental_refit(
            evaluate,
            self._window_keys(data, starts),
            info,
            info.estimate,
            problem,
            self.max_iterations,
        )
        if out is None:
            return None, info
        n_res = starts.size * (horizon - burn_in) * len(FIT_STATES)
        overlap = self.horizon_s / self.stride_s
        n_eff = max(starts.size / max(overlap, 1.0) * len(FIT_STATES), model.n_params + 1.0)
        gram = np.zeros((model.n_params, model.n_params))
        gram[np.ix_(free, free)] = out.gram
        scores = np.zeros((starts.size, model.n_params))
        scores[:, free] = out.scores
        informed = (np.diag(gram) > 0.0) | self.fixed
        std, cov = parameter_std(
            model,
            out.theta,
            self.fixed,
            informed,
            precision,
            gram,
            scores,
            out.ssr,
            n_res,
            n_eff,
            self.hac_lag(),
        )
        res = FitResult(
            model,
            out.theta,
            std,
            out.ssr,
            n_res,
            n_eff,
            out.iterations,
            out.converged,
            out.history,
            informed,
            cov,
        )
        result = to_result(model, res, starts.size, self.model_error_rel)
        result.incremental, result.rollouts, result.ssr = True, out.rollouts, out.ssr
        result.data_end_s = float(data.t[starts[-1] + horizon])
        result.windows = (data, starts, horizon, burn_in)
        return result, out.info


def to_result(model, res, n_windows: int, model_error_rel: float = 0.0) -> EffectFitResult:
    """An :class:`EffectFitResult` from a workbench ``FitResult`` (context 0); mu's std with
    the model-error budget ``model_error_rel``."""
    theta = controller_theta(model, res.theta)
    std = np.full(3, np.nan)
    std[0] = with_model_error(res.theta[0], res.std[0], model_error_rel)
    warnings = []
    at = res.at_bound()
    if at[0]:
        # on a bound the data do not determine mu (e.g. a peak never approached): no std
        std[0] = np.inf
        warnings.append(f"mu on its bound ({res.theta[0]:.3g}): not determined by the data")
    return EffectFitResult(
        theta=theta,
        std=std,
        model_theta=res.theta.copy(),
        model_std=res.std.copy(),
        param_names=model.param_names,
        loss=float(res.cost / max(res.n_residuals, 1)),
        status="converged" if res.converged else "max_iterations",
        converged=bool(res.converged),
        iterations=int(res.n_iter),
        n_windows=int(n_windows),
        mu_is_peak=friction_is_peak(model),
        warnings=warnings,
    )
