r"""Delayed feedback :math:`+\,b\, x^{(q)}(t-\tau)` on the right-hand side, and its Taylor form.

The position may be fed back with its rate, the paper's form
:math:`b_0\,x(t-\tau) + b_1\,\dot x(t-\tau)` (``rate``: two signals, one delay).
Moved to the left-hand side and expanded to order :math:`r`,

.. math::

    -b\, x^{(q)}(t-\tau) \approx -b \sum_{j=0}^{r} \frac{(-\tau)^j}{j!}\, x^{(q+j)}(t),

so the column of :math:`x^{(q+j)}` carries the coefficient
:math:`a_{q+j} = p_{q+j} - b(-\tau)^j/j!` (with the rate, plus
:math:`-b_1(-\tau)^{j-1}/(j-1)!`), where :math:`p_{q+j}` is the physical coefficient
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
    gain : float or pair of floats, optional
        The known feedback gain :math:`b` (right-hand side ``+ gain * x(t - tau)``); with
        ``rate``, the pair :math:`(b_0, b_1)`; None: estimated (``method = "exact"``).
    taylor_order : int
        Order :math:`r` of the Taylor expansion.
    rate : bool
        The position's rate is fed back too, at the same delay (:math:`b_0 x(t-\\tau) +
        b_1 \\dot x(t-\\tau)`; ``derivative`` must be 0).
    """

    coordinate: str = "x"
    derivative: int = 0
    gain: float | None = None
    taylor_order: int = 3
    method: str = "taylor"
    tau_max: float = 0.5
    tau_min: float = 0.0
    history: str = "measured"
    rate: bool = False

    def __post_init__(self):
        if self.rate and self.derivative != 0:
            raise CvxidError(
                "[model.delay] signal lists a velocity and its rate: only a position and its velocity can be fed "
                "back together (signal = [\"x\", \"x'\"], the paper's b0 x(t - tau) + b1 x'(t - tau))")
        if isinstance(self.gain, (tuple, list)):
            if not self.rate or len(self.gain) != 2:
                raise CvxidError(
                    f"[model.delay] gain gives {len(self.gain)} gains for {len(self.orders)} fed-back signal(s): one "
                    "gain for each signal, in the order of signal")
            gains = tuple(None if g is None else float(g) for g in self.gain)  # (None: that one estimated)
            object.__setattr__(self, "gain", None if gains == (None, None) else gains)
        elif self.rate and self.gain is not None:
            raise CvxidError(
                "[model.delay] gain is one number for two fed-back signals: give one gain for each, in the order of "
                "signal (gain = [b0, b1]), or leave gain out with method = 'exact' to estimate both")
        if self.derivative not in (0, 1):
            raise CvxidError(
                f"[model.delay] signal must be the position or the velocity of a coordinate "
                f"(e.g. 'x' or \"x'\"), got derivative order {self.derivative}"
            )
        if self.method not in METHODS:
            raise CvxidError(
                f"[model.delay] method must be one of {', '.join(METHODS)}, got '{self.method}'"
            )
        if any(self.estimated) and self.method == "taylor":
            raise CvxidError(
                "[model.delay] gain is required with method = 'taylor' (the known feedback gain, e.g. "
                + ("gain = [2.0, 0.3] for the position's and the velocity's" if self.rate else "gain = 2.0")
                + "); with method = 'exact' it may be left out and is estimated")
        known = [g for g in self.gains or () if g is not None]
        if not np.all(np.isfinite(known)) or (known and not any(self.estimated) and not np.any(known)):
            raise CvxidError(f"[model.delay] gain must be a finite non-zero number (or pair), got {self.gain}")
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
    def orders(self) -> tuple[int, ...]:
        """The fed-back signals' derivative orders: ``(q,)``, or ``(0, 1)`` with the rate."""
        return (self.derivative, self.derivative + 1) if self.rate else (self.derivative,)

    @property
    def gains(self) -> tuple[float | None, ...] | None:
        """The known gains, one per fed-back signal (in :attr:`orders`; None for one
        estimated, which only the given-value check asks for), or None (all estimated)."""
        if self.gain is None:
            return None
        return tuple(self.gain) if self.rate else (float(self.gain),)

    @property
    def estimated(self) -> tuple[bool, ...]:
        """Whether each fed-back signal's gain is estimated."""
        if self.gains is None:
            return (True,) * len(self.orders)
        return tuple(g is None for g in self.gains)

    @property
    def signals(self) -> tuple[str, ...]:
        """The fed-back signals as written (``"x"``, ``"x'"``)."""
        return tuple(self.coordinate + "'" * q for q in self.orders)

    @property
    def signal(self) -> str:
        """The fed-back signals as written, joined (``"x"``, or ``"x, x'"`` with the rate)."""
        return ", ".join(self.signals)

    def feedback_text(self, gains, tau: str = "tau", digits: int = 6) -> str:
        """The right-hand side's feedback, ``" + 2 x(t - tau) - 0.3 x'(t - tau)"``: ``gains``
        one per signal (numbers, or names such as ``"b"``)."""
        out = ""
        for signal, gain in zip(self.signals, gains):
            if isinstance(gain, str):
                out += f" + {gain} {signal}(t - {tau})"
            else:
                out += f" {'-' if gain < 0 else '+'} {abs(gain):.{digits}g} {signal}(t - {tau})"
        return out

    @property
    def highest_order(self) -> int:
        """Highest time derivative of the coordinate that the delay's columns contain."""
        return self.orders[-1] + (0 if self.exact else self.taylor_order)

    def taylor_terms(self) -> list[Derivative]:
        """The columns :math:`x^{(q+j)}`, :math:`j = 0..r` (with the rate, up to
        :math:`r + 1`; none for the exact delay)."""
        if self.exact:
            return []
        return [Derivative(self.coordinate, order) for order in range(self.derivative, self.highest_order + 1)]

    def contribution(self, order: int, tau: float) -> float:
        """The delay's share :math:`-\\sum_s b_s(-\\tau)^j/j!` of the coefficient of
        :math:`x^{(order)}`, :math:`j` = order minus the order of signal :math:`s` (each
        signal expanded up to the same derivative, :attr:`highest_order`: with the rate the
        position's to order :math:`r + 1`)."""
        return sum(-gain * (-tau) ** j / factorial(j) for j, gain in self._powers(order))

    def _powers(self, order: int) -> list[tuple[int, float]]:
        """The power :math:`j` of :math:`-\\tau` and the gain of each signal's share of
        column ``order``."""
        if not 0 <= order <= self.highest_order:
            return []
        return [(order - q, gain) for q, gain in zip(self.orders, self.gains) if order >= q]

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
        if self.rate and not any(pure.values()):  # (every pure column 0: tau = 0 fits them exactly)
            return 0.0
        guesses = []
        for order, a in pure.items():
            if self.rate:  # each column's share is a polynomial in tau: its positive roots
                guesses += [r.real for r in self._share_polynomial(order, a).roots() if abs(r.imag) < 1e-9 * abs(r)]
                continue
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
        # (each column relative to its own size; one at 0 beside others weighs as a millionth of the largest)
        scale = np.array([weights[k] for k in orders]) / np.maximum(np.abs(values), 1e-6 * np.max(np.abs(values)))

        def resid(x):
            return scale * (values - np.array([self.contribution(k, x[0]) for k in orders]))

        best = min(
            (least_squares(resid, [g], bounds=(0.0, np.inf)) for g in guesses),
            key=lambda r: r.cost,
        )
        return float(best.x[0])

    def _share_polynomial(self, order: int, value: float) -> np.polynomial.Polynomial:
        """The delay's share of column ``order`` minus ``value``, as a polynomial in tau."""
        coefs = np.zeros(self.highest_order + 1)
        coefs[0] = -value
        for j, gain in self._powers(order):
            coefs[j] -= gain * (-1.0) ** j / factorial(j)
        return np.polynomial.Polynomial(coefs)
