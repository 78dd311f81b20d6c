r"""The paper's baseline: sequentially thresholded least squares (SINDy's STLSQ).

Repeat: least squares on the current support; drop every penalised column whose scaled
coefficient is below the threshold :math:`\lambda`; stop when the support no longer changes.
Unpenalised (inertia and delay) columns are never dropped, which is the paper's rule of
restoring the delay terms.  The least squares keeps the problem's sign constraints.
"""

from __future__ import annotations

import numpy as np

from cvxid.identify.problem import Fit, Problem


def stlsq(problem: Problem, threshold: float, max_iterations: int = 20) -> Fit:
    """Thresholded least squares on ``problem``'s reduced regression (scaled units)."""
    support = np.ones(problem.k, dtype=bool)
    fit = problem.refit(support, lam=threshold)
    for _ in range(max_iterations):
        keep = (np.abs(fit.scaled) >= threshold) | (problem.penalties == 0)
        if np.array_equal(keep, support):
            break
        support = keep
        fit = problem.refit(support, lam=threshold)
    return fit
