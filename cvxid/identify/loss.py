r"""Outliers: Huber's loss, by iteratively reweighted least squares.

Huber's loss :math:`\rho(r) = r^2/2` for :math:`|r| \le k\sigma`, :math:`k\sigma|r| -
(k\sigma)^2/2` beyond, is minimised by repeating a weighted least squares with
:math:`w_i = \min(1, k\sigma/|r_i|)` (the residuals of the previous fit, :math:`\sigma`
their median absolute deviation / 0.6745, :math:`k = 1.345`).  Each iteration is the same
reduced problem with row weights, so the solver never sees the raw rows and the sign
constraints still hold.  A spike in the measured signal spreads over the rows of the windows
that contain it (``[fit] window``; over every later row with the whole-record integrals),
which the weights then discount.
"""

from __future__ import annotations

import numpy as np

from cvxid.identify.problem import Fit, Problem
from cvxid.regression.regression import Regression

HUBER_K = 1.345


def huber_weights(residual: np.ndarray, k: float = HUBER_K) -> np.ndarray:
    r = np.asarray(residual, float)
    sigma = np.median(np.abs(r - np.median(r))) / 0.6745
    if sigma == 0:
        return np.ones_like(r)
    return np.minimum(1.0, k * sigma / np.maximum(np.abs(r), 1e-300))


def huber_refit(regression: Regression, support: np.ndarray, nonnegative=(), solver: str = "CLARABEL",
                iterations: int = 20, tol: float = 1e-8, ties=()) -> tuple[Fit, np.ndarray]:
    """Huber fit on ``support`` (plus the unpenalised columns), the sign constraints and
    ``ties`` kept; returns the fit and the final row weights."""
    fit = Problem.from_regression(regression, nonnegative, solver, ties=ties).refit(support)
    weights = np.ones(regression.shape[0])
    for _ in range(iterations):
        weights = huber_weights(regression.residual(fit.coefficients))
        new = Problem.from_regression(regression, nonnegative, solver, row_weights=weights, ties=ties).refit(support)
        change = np.max(np.abs(new.coefficients - fit.coefficients) / np.maximum(np.abs(fit.coefficients), 1e-12))
        fit = new
        if change < tol:
            break
    return fit, weights
