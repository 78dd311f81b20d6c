r"""Delayed feedback :math:`+\,b\, x^{(q)}(t-\tau)` on the right-hand side, and its Taylor form.

Moved to the left-hand side and expanded to order :math:`r`,

.. math::

    -b\, x^{(q)}(t-\tau) \approx -b \sum_{j=0}^{r} \frac{(-\tau)^j}{j!}\, x^{(q+j)}(t),

so the column of :math:`x^{(q+j)}` carries the coefficient
:math:`a_{q+j} = p_{q+j} - b(-\tau)^j/j!`, where :math:`p_{q+j}` is the physical coefficient
of the same derivative (stiffness :math:`k_1` for order 0, damping :math:`c_1` for 1, mass
:math:`m` for 2, none above).  Columns with no physical coefficient ("pure delay" columns)
determine :math:`\tau`; the others then give the physical coefficients back.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from math import factorial

import numpy as np
from scipy.optimize import least_squares

from cvxid.errors import CvxidError, EquationErrorDelayWarning
from cvxid.model.terms import Derivative

METHODS = ("taylor", "exact")
END_SHARE = 1e-3
"""A delay within this share of its search range's width from an end of its range is at
that end (at the bottom, :data:`END_SAMPLES` samples if that is more)."""
END_SAMPLES = 1.5
"""The samples from the bottom of its range within which a delay is at the bottom, where
that is more than :data:`END_SHARE` of the range (a seventh outside check's 0.0010002 s at
1 kHz, a range of 0.4 s, its damping standing in for the delay, was not said to be at 0:
the equation-error profile's grid is about a sample; a delay of two samples, a digital
loop's, is not at 0).  At the top :data:`END_SHARE` alone: a flat profile's estimate a sample
under the top is undetermined, its interval spanning the range, not beyond it."""
HISTORIES = ("measured", "zero", "initial")
"""What the feedback read before a simulation's start: the measured signal (see
:mod:`cvxid.regression.history`), nothing, or the initial position held."""
ASSUMED = ("zero", "initial")
"""Histories that need no data: what a simulated truth may assume before its start."""


@dataclass(frozen=True)
class DelayedFeedback:
    """The delayed feedback of a model.

    Parameters
    ----------
    coordinate : str
        The fed-back coordinate.
    derivative : int
        0 for :math:`x(t-\\tau)`, 1 for :math:`\\dot x(t-\\tau)`.
    gain : float
        The known feedback gain :math:`b` (right-hand side ``+ gain * x(t - tau)``).
    taylor_order : int
        Order :math:`r` of the Taylor expansion.
    """

    coordinate: str = "x"
    derivative: int = 0
    gain: float | None = None
    taylor_order: int = 3
    method: str = "taylor"
    tau_max: float = 0.5
    tau_min: float = 0.0
    history: str = "measured"

    def __post_init__(self):
        if self.derivative not in (0, 1):
            raise CvxidError(
                f"[model.delay] signal must be the position or the velocity of a coordinate "
                f"(e.g. 'x' or \"x'\"), got derivative order {self.derivative}"
            )
        if self.method not in METHODS:
            raise CvxidError(
                f"[model.delay] method must be one of {', '.join(METHODS)}, got '{self.method}'"
            )
        if self.gain is None and self.method == "taylor":
            raise CvxidError(
                "[model.delay] gain is required with method = 'taylor' (a known feedback gain, "
                "e.g. gain = 2.0); with method = 'exact' it may be left out and is estimated"
            )
        if self.gain is not None and (not np.isfinite(self.gain) or self.gain == 0):
            raise CvxidError(f"[model.delay] gain must be a finite non-zero number, got {self.gain}")
        if self.taylor_order < 1:
            raise CvxidError(
                f"[model.delay] taylor_order must be at least 1, got {self.taylor_order}"
            )
        if self.history not in HISTORIES:
            raise CvxidError(f"[model.delay] history must be one of {', '.join(HISTORIES)}, got '{self.history}'")
        if not 0 <= self.tau_min < self.tau_max:
            raise CvxidError(
                f"[model.delay] needs 0 <= tau_min < tau_max, got {self.tau_min} and {self.tau_max}"
            )

    @property
    def exact(self) -> bool:
        return self.method == "exact"

    def end(self, tau: float, dt: float = 0.0) -> str | None:
        """``"top"`` or ``"bottom"`` where the delay ``tau`` sits at that end of the search
        range (:data:`END_SHARE`; at the bottom :data:`END_SAMPLES` samples of ``dt`` if that
        is more), else None."""
        share = END_SHARE * (self.tau_max - self.tau_min)
        if tau >= self.tau_max - share:
            return "top"
        return "bottom" if tau <= self.tau_min + max(share, END_SAMPLES * dt) else None

    @property
    def signal(self) -> str:
        return self.coordinate + "'" * self.derivative

    @property
    def highest_order(self) -> int:
        """Highest time derivative of the coordinate that the delay's columns contain."""
        return self.derivative + (0 if self.exact else self.taylor_order)

    def taylor_terms(self) -> list[Derivative]:
        """The columns :math:`x^{(q+j)}`, :math:`j = 0..r` (none for the exact delay)."""
        if self.exact:
            return []
        return [Derivative(self.coordinate, self.derivative + j) for j in range(self.taylor_order + 1)]

    def contribution(self, order: int, tau: float) -> float:
        """The delay's share :math:`-b(-\\tau)^j/j!` of the coefficient of :math:`x^{(order)}`."""
        j = order - self.derivative
        if j < 0 or j > self.taylor_order:
            return 0.0
        return -self.gain * (-tau) ** j / factorial(j)

    def estimate_tau(self, pure: dict[int, float], weights: dict[int, float] | None = None) -> float:
        """:math:`\\tau` from the coefficients of the pure-delay columns (order → value).

        With one such column this is the closed form (the paper's rule); with several, a
        small bounded least-squares fit over all of them.
        """
        pure = {k: v for k, v in pure.items() if k != self.derivative}  # tau^0: the gain, no delay in it
        if not pure:
            raise CvxidError(
                "the delay cannot be identified: every Taylor column also carries a physical "
                "coefficient; raise [model.delay] taylor_order"
            )
        weights = weights or {k: 1.0 for k in pure}
        guesses = []
        for order, a in pure.items():
            j = order - self.derivative
            base = -a * factorial(j) / self.gain  # = (-tau)^j
            if j % 2:
                guesses.append(-np.sign(base) * abs(base) ** (1 / j))
            elif base > 0:
                guesses.append(base ** (1 / j))
        guesses = [g for g in guesses if np.isfinite(g) and g > 0]
        if not guesses:
            warnings.warn(
                "the Taylor delay coefficients have the wrong sign for a positive delay; "
                "tau is reported as 0", EquationErrorDelayWarning, stacklevel=2,
            )
            return 0.0
        orders = np.array(list(pure))
        values = np.array([pure[k] for k in orders])
        scale = np.array([weights[k] for k in orders]) / np.maximum(np.abs(values), 1e-300)

        def resid(x):
            return scale * (values - np.array([self.contribution(k, x[0]) for k in orders]))

        best = min(
            (least_squares(resid, [g], bounds=(0.0, np.inf)) for g in guesses),
            key=lambda r: r.cost,
        )
        return float(best.x[0])
