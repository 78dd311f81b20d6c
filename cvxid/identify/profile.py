r"""The delay by profile search: :math:`\hat\tau = \arg\min_\tau J(\tau)`.

For a fixed :math:`\tau` the exact-delay regression is linear, so its optimal value
:math:`J(\tau)` (least squares on a support, with the sign constraints) is one convex solve.
The profile is evaluated on a coarse grid over ``[tau_min, tau_max]`` and refined by a
bounded scalar search around the best grid point (scipy).

The interval is the set where :math:`J(\tau) \le J(\hat\tau)\,(1 + \chi^2_{1,0.95}/n_\mathrm{eff})`,
a profile-likelihood interval for Gaussian equation errors with an *effective* number of
independent rows :math:`n_\mathrm{eff} = n / (1 + 2\sum_k \rho_k)` from the residual's own
autocorrelation (algebraic residuals are strongly coloured, so :math:`n` itself would give
an interval far too narrow).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.stats import chi2

from cvxid.errors import CvxidError, CvxidWarning
from cvxid.identify.problem import constrained_least_squares

GRID = 41


@dataclass(frozen=True)
class DelayProfile:
    """The profile :math:`J(\\tau)`, the estimate and its interval."""

    taus: np.ndarray
    values: np.ndarray
    estimate: float
    interval: tuple[float, float]
    effective_rows: float
    method: str = "profile"
    ranges: dict = field(default_factory=dict)  # output error: each parameter's refitted range over the interval

    def as_dict(self) -> dict:
        return {"estimate": self.estimate, "interval": list(self.interval), "method": self.method}


def effective_rows(residual: np.ndarray) -> float:
    """:math:`n / (1 + 2\\sum_k \\rho_k)`, summing autocorrelations until the first negative
    (``n`` for a residual of zeros)."""
    r = np.asarray(residual, float) - np.mean(residual)
    n = r.size
    spectrum = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
    if not acf[0] > 0:  # a residual of zeros (an exact fit) carries no correlation to count
        return float(n)
    acf = acf / acf[0]
    negative = np.flatnonzero(acf[1:] < 0)
    stop = negative[0] + 1 if negative.size else n
    return float(max(1.0, n / (1 + 2 * acf[1:stop].sum())))


CHANCE = 0.95
"""The level of :func:`chance_factor`."""


def chance_factor(effective: float, parameters: int = 1, tries: int = 1) -> float:
    r"""The factor by which ``parameters`` added parameters lower a root-mean-square error
    by chance alone, read off the error of the model *with* them as an F test reads the
    larger model's residual variance,

    .. math:: \left(1 + \chi^2_{p,\,1 - (1 - \text{CHANCE}) / m} / n_\text{eff}\right)^{1/2},

    with :math:`n_\text{eff}` its :func:`effective_rows` and :math:`m` the ``tries`` the
    best of which was taken (Bonferroni's level; 1: the one candidate there was), at the
    level :data:`CHANCE`."""
    level = 1.0 - (1.0 - CHANCE) / max(tries, 1)
    return float(np.sqrt(1.0 + chi2.ppf(level, parameters) / max(effective, 1.0)))


def profiled_tau(builder) -> float | None:
    """The delay at which to build ``builder``'s regression when nothing has chosen one
    yet: for an exact delay the profile's estimate over every column, else None (a Taylor
    delay, or none, needs no delay to build)."""
    delay = builder.delay
    if delay is None or not delay.exact:
        return None
    return profile_delay(builder, nonnegative=builder.model.nonnegative).estimate


def profile_delay(builder, support=None, nonnegative=(), grid: int = GRID, level: float = 0.95, model=None,
                  ties=(), interval: bool = True) -> DelayProfile:
    """Profile the least-squares optimal value over the delay.

    ``builder`` makes the regression at any delay (a
    :class:`~cvxid.regression.builder.RegressionBuilder` for ``model``, by default its own,
    or a :class:`~cvxid.regression.builder.SystemBuilder`); ``support`` is a boolean mask
    over the columns (all by default), ``nonnegative`` and ``ties`` the constraints kept.
    ``interval = False``: the best delay alone (the interval's bisections cost as much again
    as the grid; its interval and effective rows are NaN).
    """
    delay = builder.delay
    return _profile(lambda tau: builder.at(tau, model), delay.tau_min, delay.tau_max, support, nonnegative, grid,
                    level, ties, interval=interval)


def profile_input_delay(builder, model, tau: float | None = None, support=None, nonnegative=(), grid: int = GRID,
                        level: float = 0.95, ties=()) -> DelayProfile:
    r"""Profile the least-squares optimal value over the input's delay :math:`\tau_u`
    (:mod:`cvxid.model.input_delay`) within its bounds, the fed-back delay held at ``tau``:
    only the target changes with :math:`\tau_u`.  ``model`` is a
    :class:`~cvxid.model.equation.ModelSpec` (with a
    :class:`~cvxid.regression.builder.RegressionBuilder`) or equations by label (with a
    :class:`~cvxid.regression.builder.SystemBuilder`); every equation with an input delay
    takes the same :math:`\tau_u`."""
    bounds = input_delay_bounds(model)
    return _profile(lambda tau_u: builder.at(tau, with_input_tau(model, tau_u)), *bounds, support, nonnegative, grid,
                    level, ties, method="input delay profile")


def with_input_tau(model, tau_u: float):
    """``model`` (one spec, or specs by label) with every input delay at ``tau_u``."""
    if isinstance(model, dict):
        return {label: with_input_tau(spec, tau_u) for label, spec in model.items()}
    return model.with_input_tau(tau_u) if model.input_delay is not None else model


def input_delay_bounds(model) -> tuple[float, float]:
    """The bounds of the input delay of ``model`` (one spec, or specs by label: they must agree)."""
    specs = model.values() if isinstance(model, dict) else [model]
    bounds = {(s.input_delay.tau_min, s.input_delay.tau_max) for s in specs if s.input_delay is not None}
    if len(bounds) != 1:
        raise CvxidError("the equations' input delays need the same bounds (one delay of the shared input)")
    return next(iter(bounds))


def _profile(regression_at, lo: float, hi: float, support, nonnegative, grid: int, level: float, ties,
             method: str = "profile", interval: bool = True) -> DelayProfile:
    """The profile of the least-squares optimal value over a delay in ``[lo, hi]``, given
    the regression at any delay (``regression_at``); without its ``interval`` (NaN) when
    only the best delay is wanted."""
    cache: dict[float, float] = {}

    def regression(tau: float):
        with warnings.catch_warnings():
            # at tau = 0 an unknown gain's column equals x: a poor candidate, not news
            warnings.filterwarnings("ignore", message="the regression is rank-deficient", category=CvxidWarning)
            reg = regression_at(tau)
            return reg, reg.reduce()

    def fit(tau: float):
        reg, reduced = regression(tau)
        mask = np.ones(len(reg.names), bool) if support is None else np.asarray(support, bool)
        mask = mask | (reg.penalties == 0)
        return reg, reduced, constrained_least_squares(reduced, reg.names, mask, nonnegative, ties)

    def value(tau: float) -> float:
        tau = float(tau)
        if tau not in cache:
            _, reduced, scaled = fit(tau)
            cache[tau] = reduced.mse(scaled)
        return cache[tau]

    taus = np.linspace(lo, hi, grid)
    tau = least_between(value, taus, np.array([value(t) for t in taus]), hi)
    bounds, n_eff = (np.nan, np.nan), np.nan
    if interval:
        reg, reduced, scaled = fit(tau)
        n_eff = effective_rows(reg.residual(reduced.to_physical(scaled)))
        bound = value(tau) * (1 + chi2.ppf(level, 1) / n_eff)
        bounds = (_crossing(value, tau, lo, bound, taus), _crossing(value, tau, hi, bound, taus))
    order = np.argsort(list(cache))  # (every delay evaluated, the crossings' too)
    return DelayProfile(np.array(list(cache))[order], np.array(list(cache.values()))[order], tau, bounds, n_eff, method)


def least_between(value, taus: np.ndarray, values: np.ndarray, top: float) -> float:
    """The least of a profile sampled at ``taus`` (``values``), refined between that point's
    neighbours by scipy's bounded scalar minimiser of ``value`` (to 1e-6 of ``top``, the
    range's upper end); the grid point where the refinement finds nothing lower."""
    i = int(np.argmin(values))
    if taus.size < 2:
        return float(taus[i])
    best = minimize_scalar(value, bounds=(taus[max(i - 1, 0)], taus[min(i + 1, taus.size - 1)]), method="bounded",
                           options={"xatol": 1e-6 * top})
    return float(best.x) if best.fun <= values[i] else float(taus[i])


def _crossing(value, tau, edge, bound, grid) -> float:
    """Where the profile rises through ``bound`` between ``tau`` and ``edge`` (bisection)."""
    inside, outside = tau, edge
    if value(edge) <= bound:
        return float(edge)
    # start from the nearest grid point beyond the bound, then bisect
    step = grid[1] - grid[0]
    probe = tau
    while (probe - edge) * (tau - edge) > 0:
        nxt = probe + np.sign(edge - tau) * step
        if (nxt - edge) * (tau - edge) < 0:
            nxt = edge
        if value(nxt) > bound:
            outside = nxt
            break
        inside = probe = nxt
    for _ in range(40):
        mid = 0.5 * (inside + outside)
        if value(mid) > bound:
            outside = mid
        else:
            inside = mid
        if abs(outside - inside) < 1e-7 * max(abs(edge), 1e-3):
            break
    return float(0.5 * (inside + outside))
