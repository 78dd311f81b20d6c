r"""Least squares of a system of :math:`N \ge 1` equations at its profiled delay.

Every equation :math:`i` has its own regression :math:`P_i c_i \approx p_i`; for
:math:`N > 1` they are stacked block-diagonally
(:meth:`~cvxid.regression.regression.Regression.block`) into one problem, coefficients
shared across equations are tied by linear equality constraints :math:`c_a = \rho\, c_b`,
and the shared exact delay is profiled on the joint optimal value

.. math::

    \hat\tau = \arg\min_\tau \min_{c:\ \text{ties, signs}} \sum_i \|P_i(\tau) c_i - p_i\|^2 .

:func:`fit_support` is that step for any support: the λ path's selection, a bootstrap's
mean, or the diagnosis's candidate added.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cvxid.identified import IdentifiedModel, IdentifiedSystem
from cvxid.identify.problem import Fit, Problem
from cvxid.identify.profile import DelayProfile, profile_delay
from cvxid.model.system import SystemSpec
from cvxid.regression.builder import SystemBuilder


@dataclass(frozen=True)
class SupportFit:
    """Least-squares coefficients on a support (zero off it), the delay they were fitted
    at and its profile (for an exact delay), and the solve."""

    coefficients: dict[str, float]
    tau: float | None
    profile: DelayProfile | None
    fit: Fit


def fit_support(system: SystemSpec, rows: SystemBuilder, keep=None, tau: float | None = None,
                solver: str = "CLARABEL", profile: DelayProfile | None = None) -> SupportFit:
    """Least squares of ``system`` on the columns in ``keep`` (a boolean mask over
    ``system.column_names``, all by default; unpenalised columns always), signs and ties
    kept.  An exact delay is profiled on that support unless ``tau`` is given, or
    ``profile`` (of this very support) is passed to be reused."""
    if system.exact and tau is None:
        if profile is None:
            profile = profile_delay(rows, support=keep, nonnegative=system.nonnegative, model=system.equations,
                                    ties=system.ties)
        tau = profile.estimate
    problem = Problem.from_regression(rows.at(tau, system.equations), system.nonnegative, solver, ties=system.ties)
    mask = np.ones(problem.k, bool) if keep is None else np.asarray(keep, bool) | (problem.penalties == 0)
    fit = problem.refit(mask)
    coefficients = dict(zip(problem.names, map(float, np.where(mask, fit.coefficients, 0.0))))
    return SupportFit(coefficients, tau, profile, fit)


def identified(system: SystemSpec, coefficients: dict[str, float], tau: float | None, lam: float = 0.0,
               profile: DelayProfile | None = None, info: dict | None = None) -> IdentifiedSystem:
    """The :class:`~cvxid.identified.IdentifiedSystem` of ``system`` with these
    coefficients (by system column name) at the delay ``tau``."""
    info = dict(info or {})
    models = {label: IdentifiedModel(spec, coefs, lam, dict(info), tau)
              for (label, spec), coefs in zip(system.equations.items(), system.split(coefficients).values())}
    return IdentifiedSystem(models, tau, None if profile is None else (profile.taus, profile.values), system.ties,
                            info)


def identify_system(system: SystemSpec, rows: SystemBuilder, keep=None, solver: str = "CLARABEL",
                    lam: float = 0.0, tau: float | None = None) -> IdentifiedSystem:
    """:func:`fit_support` as an :class:`~cvxid.identified.IdentifiedSystem` (its info:
    the training equation error and the delay's profile interval)."""
    est = fit_support(system, rows, keep, tau=tau, solver=solver)
    info = {"method": "equation_error", "train_mse": est.fit.train_mse}
    if est.profile is not None:
        info["tau_interval"] = list(est.profile.interval)
    return identified(system, est.coefficients, est.tau, lam, est.profile, info)
