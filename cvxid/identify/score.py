r"""The score (Lagrange-multiplier) test: what one more parameter would do to a
least-squares fit, read from the fit's own linearisation, without refitting.

At a fit with residual :math:`r` and Jacobian :math:`J` in its parameters, a new parameter
:math:`c` (zero at the fit) with column :math:`j_c = \partial r/\partial c` can explain only
the part of :math:`j_c` the fitted parameters cannot:

.. math::

    j_\perp = (I - J J^+)\, j_c, \qquad
    \Delta_c = \frac{(j_\perp^T r)^2}{j_\perp^T j_\perp}, \qquad
    \delta_c = -\frac{j_\perp^T r}{j_\perp^T j_\perp},

:math:`\Delta_c` the first-order fall of :math:`r^T r` when :math:`c` is fitted with the
others, at the Gauss–Newton step :math:`\delta_c`.  The diagnosis by simulation error
(:mod:`cvxid.diagnosis.simulation`) turns :math:`\Delta_c` into a :math:`\chi^2_1`
statistic; the stepwise search (:mod:`cvxid.identify.stepwise`) ranks its candidates by it
before fitting the best of them.
"""

from __future__ import annotations

import numpy as np


def score_gains(residual: np.ndarray, jacobian: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each column of ``columns`` ``(n, c)``: the first-order fall :math:`\\Delta_c` of
    the squared residual when it joins the fit of ``jacobian`` ``(n, p)`` at ``residual``
    ``(n,)``, and its Gauss–Newton step :math:`\\delta_c` (see the module docstring).  A
    column the fit already spans gains 0 at step 0."""
    columns = np.asarray(columns, float).reshape(residual.size, -1)
    return _gains(residual, columns, _perpendicular(jacobian, columns))


def _perpendicular(jacobian: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """The part of each column that the fit's columns do not span, :math:`(I - J J^+) J_c`."""
    return columns - jacobian @ np.linalg.lstsq(jacobian, columns, rcond=None)[0]


def _gains(residual: np.ndarray, columns: np.ndarray, perp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`score_gains` from the columns' parts ``perp`` (:func:`_perpendicular`)."""
    along = perp.T @ residual
    norms = np.einsum("ij,ij->j", perp, perp)
    spanned = norms <= 1e-24 * np.maximum(np.einsum("ij,ij->j", columns, columns), 1e-300)
    safe = np.where(spanned, 1.0, norms)
    return np.where(spanned, 0.0, along**2 / safe), np.where(spanned, 0.0, -along / safe)


def score_refit(residual: np.ndarray, jacobian: np.ndarray, column: np.ndarray) -> tuple[float, float, np.ndarray]:
    """:func:`score_gains` of one ``column`` ``(n,)``, with the residual its Gauss–Newton
    step leaves to first order, :math:`r + j_\\perp \\delta_c` (whose square sum is
    :math:`r^T r - \\Delta_c`)."""
    column = np.asarray(column, float).reshape(residual.size, 1)
    perp = _perpendicular(jacobian, column)
    (gain,), (step,) = _gains(residual, column, perp)
    return float(gain), float(step), residual + step * perp[:, 0]


def block_score_gain(residual: np.ndarray, jacobian: np.ndarray, columns: np.ndarray) -> tuple[float, np.ndarray]:
    r"""The first-order fall of the squared residual when every column of ``columns``
    ``(n, c)`` joins the fit together (one parameter added to several equations at once),
    and their joint Gauss–Newton step:

    .. math::

        J_\perp = (I - J J^+) J_c, \qquad \Delta = r^T J_\perp J_\perp^+ r, \qquad
        \delta = -J_\perp^+ r;

    for one column this is :func:`score_gains`."""
    columns = np.asarray(columns, float).reshape(residual.size, -1)
    if columns.shape[1] == 1:
        (gain,), step = score_gains(residual, jacobian, columns)
        return float(gain), step
    perp = _perpendicular(jacobian, columns)
    step = -np.linalg.lstsq(perp, residual, rcond=1e-10)[0]
    return float(-(perp @ step) @ residual), step
