r"""Candidate terms of a model: one definition, four uses.

A :class:`Term` builds its regression column (through the algebraic operation), its value
in a simulation right-hand side, its printed name and its role as a diagnostic candidate.

States are passed as a mapping from symbols to arrays: ``"x"`` is a coordinate's position and
``"x'"`` its velocity.  A term that is an exact time derivative of a function of one
position, such as :math:`\dot x x^2 = \tfrac{d}{dt}(x^3/3)`, goes into the regression as the
first derivative of that function, so it needs no velocity estimate.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

from cvxid.errors import CvxidError
from cvxid.model.expression import Parsed, parse_expression
from cvxid.model.symbols import latex_symbol, velocity_symbol

States = Mapping[str, np.ndarray]


class Term:
    """A candidate term :math:`g_i(x, \\dot x)` of a second-order model."""

    name: str
    meaning: str

    def evaluate(self, states: States) -> np.ndarray:
        """The term's value from positions and velocities (simulation and residual plots)."""
        raise NotImplementedError

    @property
    def symbols(self) -> frozenset[str]:
        """The state symbols the term reads."""
        raise NotImplementedError

    def regression_signal(self, states: States) -> np.ndarray:
        """The signal that the algebraic operation transforms (as the derivative of order
        :attr:`regression_order`)."""
        return np.broadcast_to(self.evaluate(states), states[next(iter(states))].shape)

    @property
    def regression_order(self) -> int:
        """The derivative order of :meth:`regression_signal` in the term (0: the term itself)."""
        return 0

    @property
    def needs_velocity(self) -> bool:
        """Whether the regression column needs a velocity (estimate)."""
        return any(s.endswith("'") for s in self.symbols)

    @property
    def latex(self) -> str:
        return self.name

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}: {self.meaning})"

    def __eq__(self, other) -> bool:
        return isinstance(other, Term) and other.name == self.name

    def __hash__(self) -> int:
        return hash(self.name)


class Monomial(Term):
    r"""A product of powers of states, :math:`\prod_k s_k^{p_k}` (e.g. ``x^2 x'``)."""

    def __init__(self, factors: Mapping[str, int], meaning: str | None = None):
        clean = {str(s): int(p) for s, p in factors.items() if int(p) != 0}
        if not clean or any(p < 0 for p in clean.values()):
            raise CvxidError(f"a monomial needs positive powers, got {dict(factors)}")
        # positions first, then velocities; alphabetical within each
        self.factors = dict(sorted(clean.items(), key=lambda kv: (kv[0].endswith("'"), kv[0])))
        self.name = " ".join(s if p == 1 else f"{s}^{p}" for s, p in self.factors.items())
        self.meaning = meaning or _monomial_meaning(self.factors)

    @property
    def symbols(self) -> frozenset[str]:
        return frozenset(self.factors)

    def evaluate(self, states: States) -> np.ndarray:
        out = 1.0
        for s, p in self.factors.items():
            out = out * states[s] ** p
        return out

    @property
    def _antiderivative(self) -> tuple[str, int] | None:
        """(coordinate, power of it) when the term is ``d/dt (x^(p+1)/(p+1))``."""
        velocities = [s for s in self.factors if s.endswith("'")]
        if len(velocities) != 1 or self.factors[velocities[0]] != 1:
            return None
        coord = velocities[0][:-1]
        positions = [s for s in self.factors if not s.endswith("'")]
        if positions and positions != [coord]:
            return None
        return coord, self.factors.get(coord, 0)

    @property
    def needs_velocity(self) -> bool:
        return self._antiderivative is None and super().needs_velocity

    def regression_signal(self, states: States) -> np.ndarray:
        anti = self._antiderivative
        if anti is None:
            return self.evaluate(states)
        coord, p = anti
        return states[coord] ** (p + 1) / (p + 1)

    @property
    def regression_order(self) -> int:
        """1 for :math:`x^p x'` (the derivative of :math:`x^{p+1}/(p+1)`), else 0."""
        return 0 if self._antiderivative is None else 1

    @property
    def latex(self) -> str:
        return " ".join(
            latex_symbol(s) if p == 1 else f"{latex_symbol(s)}^{{{p}}}"
            for s, p in self.factors.items()
        )


def _monomial_meaning(factors: Mapping[str, int]) -> str:
    velocities = {s: p for s, p in factors.items() if s.endswith("'")}
    positions = {s: p for s, p in factors.items() if not s.endswith("'")}
    if not velocities:
        (p,) = positions.values() if len(positions) == 1 else (0,)
        return {1: "linear stiffness", 2: "quadratic stiffness (asymmetry)", 3: "cubic stiffness"}.get(
            p, "nonlinear stiffness"
        )
    if not positions and len(velocities) == 1:
        (p,) = velocities.values()
        return {1: "viscous damping", 2: "quadratic damping (even in velocity)", 3: "cubic damping"}.get(
            p, "nonlinear damping"
        )
    return "displacement-dependent damping"


class Derivative(Term):
    """The ``order``-th time derivative of a coordinate (inertia, Taylor delay terms)."""

    def __init__(self, coordinate: str, order: int, meaning: str | None = None):
        self.coordinate = coordinate
        self.order = int(order)
        self.name = coordinate + "'" * self.order if self.order <= 3 else f"{coordinate}^({self.order})"
        self.meaning = meaning or {2: "inertia"}.get(self.order, f"derivative of order {self.order}")

    @property
    def symbols(self) -> frozenset[str]:
        return frozenset([self.coordinate])

    @property
    def needs_velocity(self) -> bool:
        return False

    def evaluate(self, states: States) -> np.ndarray:
        if self.order == 0:
            return states[self.coordinate]
        if self.order == 1:
            return states[velocity_symbol(self.coordinate)]
        raise CvxidError(f"term {self.name} cannot be evaluated from positions and velocities")

    def regression_signal(self, states: States) -> np.ndarray:
        return states[self.coordinate]

    @property
    def regression_order(self) -> int:
        return self.order

    @property
    def latex(self) -> str:
        base = latex_symbol(self.coordinate)
        return base + "^{" + "\\prime" * self.order + "}" if self.order <= 3 else f"{base}^{{({self.order})}}"


DELAYED = "(t-tau)"
"""How the delayed feedback's names end (``x(t-tau)``, ``x'(t-tau)``)."""


class DelayedSignal(Term):
    r"""The delayed feedback signal :math:`x^{(q)}(t-\tau)` (exact delay, unknown gain).

    Its samples come in the states under :attr:`symbol`, already shifted by the delay being
    tried; the column is the algebraic transform of :math:`x(t-\tau)` with derivative order
    :math:`q`.
    """

    def __init__(self, coordinate: str, derivative: int = 0, meaning: str | None = None):
        self.coordinate = coordinate
        self.derivative = int(derivative)
        self.name = f"{coordinate}{chr(39) * self.derivative}{DELAYED}"
        self.meaning = meaning or ("delayed feedback" if self.derivative == 0 else
                                   "a change of the delay (its time derivative)")

    @property
    def symbol(self) -> str:
        return f"{self.coordinate}{DELAYED}"

    @property
    def symbols(self) -> frozenset[str]:
        return frozenset([self.symbol])

    @property
    def needs_velocity(self) -> bool:
        return False

    def evaluate(self, states: States) -> np.ndarray:
        raise CvxidError("the delayed signal is simulated by the delay-differential integrator")

    def regression_signal(self, states: States) -> np.ndarray:
        return states[self.symbol]

    @property
    def regression_order(self) -> int:
        return self.derivative


class InputRate(Term):
    r"""The input's rate :math:`\dot u(t - \tau_u)`: the column by which a missing input delay
    shows, since :math:`u(t-\tau_u-\delta) \approx u(t-\tau_u) - \delta\,\dot u(t-\tau_u)`
    (its coefficient is :math:`\delta` when moved to the left-hand side).  Its column is the
    algebraic transform of the received input with derivative order 1
    (:meth:`~cvxid.regression.builder.RegressionBuilder.at`); it is never simulated.
    """

    def __init__(self, input_name: str):
        self.input = input_name
        self.name = f"{input_name}'"
        self.meaning = "a delay of the input (its first-order Taylor column)"

    @property
    def symbols(self) -> frozenset[str]:
        return frozenset()

    @property
    def needs_velocity(self) -> bool:
        return False

    def evaluate(self, states: States) -> np.ndarray:
        raise CvxidError("the input's rate is a diagnosis column; an input delay is simulated as a shifted input")


class Sign(Term):
    """Coulomb friction :math:`\\operatorname{sign}(\\dot x)`.

    With ``smoothing`` :math:`v_s > 0` it is :math:`\\tanh(\\dot x / v_s)`: a simulated rig
    whose friction changes sign smoothly instead of making a fixed-step integrator chatter
    where the motion sticks (the identified term stays the ideal sign).
    """

    def __init__(self, coordinate: str, smoothing: float = 0.0):
        self.coordinate = coordinate
        self.smoothing = float(smoothing)
        self.name = f"sign({velocity_symbol(coordinate)})"
        self.meaning = "Coulomb (dry) friction" + (f", smoothed below {smoothing:g}" if smoothing else "")

    @property
    def symbols(self) -> frozenset[str]:
        return frozenset([velocity_symbol(self.coordinate)])

    def evaluate(self, states: States) -> np.ndarray:
        v = states[velocity_symbol(self.coordinate)]
        return np.tanh(v / self.smoothing) if self.smoothing else np.sign(v)

    @property
    def latex(self) -> str:
        return rf"\operatorname{{sign}}({latex_symbol(velocity_symbol(self.coordinate))})"


class AbsProduct(Term):
    """Quadratic damping :math:`\\dot x |\\dot x|` (odd, unlike :math:`\\dot x^2`)."""

    def __init__(self, coordinate: str):
        self.coordinate = coordinate
        v = velocity_symbol(coordinate)
        self.name = f"{v}|{v}|"
        self.meaning = "quadratic (drag) damping"

    @property
    def symbols(self) -> frozenset[str]:
        return frozenset([velocity_symbol(self.coordinate)])

    def evaluate(self, states: States) -> np.ndarray:
        v = states[velocity_symbol(self.coordinate)]
        return v * np.abs(v)

    @property
    def latex(self) -> str:
        v = latex_symbol(velocity_symbol(self.coordinate))
        return rf"{v}|{v}|"


class Constant(Term):
    """A constant force (offset, gravity, sensor bias)."""

    name = "1"
    meaning = "constant offset"

    @property
    def symbols(self) -> frozenset[str]:
        return frozenset()

    def evaluate(self, states: States) -> np.ndarray:
        return np.ones_like(states[next(iter(states))])


@dataclass(frozen=True, eq=False)
class FunctionTerm(Term):
    """A user's own term: any function of the states, with a name and a meaning."""

    name: str
    meaning: str
    function: Callable[[States], np.ndarray]
    reads: frozenset[str]

    @property
    def symbols(self) -> frozenset[str]:
        return frozenset(self.reads)

    def evaluate(self, states: States) -> np.ndarray:
        return np.asarray(self.function(states), dtype=float)


class Expression(Term):
    """A user's term written as an expression of the coordinates and their velocities
    (``sin(theta)``; :mod:`cvxid.model.expression`): its regression column, compiled
    simulation, printed and LaTeX forms all come from one checked program."""

    def __init__(self, parsed: Parsed, coordinates: tuple[str, ...], meaning: str | None = None):
        self.parsed = parsed
        self.coordinates = tuple(coordinates)
        self.name = parsed.text
        self.meaning = meaning or f"the user term {parsed.text}"

    @property
    def symbols(self) -> frozenset[str]:
        return self.parsed.symbols

    def evaluate(self, states: States) -> np.ndarray:
        shape = np.shape(states[next(iter(states))])
        positions = [states.get(c) for c in self.coordinates]
        velocities = [states.get(velocity_symbol(c)) for c in self.coordinates]
        return np.broadcast_to(self.parsed.program.evaluate(positions, velocities), shape)

    def crossings(self, states: States) -> np.ndarray:
        """The samples after which a divisor of the term (or the base of a negative power)
        crosses 0 (:meth:`~cvxid.model.expression.Program.crossings`)."""
        positions = [states.get(c) for c in self.coordinates]
        velocities = [states.get(velocity_symbol(c)) for c in self.coordinates]
        return self.parsed.program.crossings(positions, velocities)

    @property
    def latex(self) -> str:
        return self.parsed.latex


# ---------------------------------------------------------------------- parsing
_FACTOR = re.compile(r"^([A-Za-z_][A-Za-z_0-9]*)('?)(?:\^(\d+))?$")
_SIGN = re.compile(r"^sign\(\s*([A-Za-z_][A-Za-z_0-9]*)'\s*\)$")
_ABS = re.compile(r"^([A-Za-z_][A-Za-z_0-9]*)'\s*\|\s*\1'\s*\|$")
_DERIV = re.compile(r"^([A-Za-z_][A-Za-z_0-9]*)(''+)$|^([A-Za-z_][A-Za-z_0-9]*)\^\((\d+)\)$")


def parse_term(text: str, coordinates: tuple[str, ...] = ("x",)) -> Term:
    """A term from its printed name (``"x^2 x'"``, ``"sign(x')"``, ``"x'|x'|"``, ``"1"``), or
    any other expression of the coordinates and their velocities (``"sin(theta)"``,
    :mod:`cvxid.model.expression`).

    Factors may be separated by spaces or ``*``, in any order.
    """
    raw = str(text).strip()
    s = re.sub(r"\s+", " ", raw)
    if s == "1":
        return Constant()

    def check(coord: str) -> str:
        if coord not in coordinates:
            raise CvxidError(
                f"term '{raw}' uses '{coord}', which is not a coordinate of the model "
                f"(coordinates: {', '.join(coordinates)})"
            )
        return coord

    if m := _SIGN.match(s):
        return Sign(check(m.group(1)))
    if m := _ABS.match(s.replace(" ", "")):
        return AbsProduct(check(m.group(1)))
    if m := _DERIV.match(s):
        if m.group(1):
            return Derivative(check(m.group(1)), len(m.group(2)))
        return Derivative(check(m.group(3)), int(m.group(4)))
    factors: dict[str, int] = {}
    for token in re.split(r"[ *]+", s):
        m = _FACTOR.match(token)
        if not m or m.group(1) not in coordinates:  # not a product of powers: an expression such as sin(theta)
            return Expression(parse_expression(raw, coordinates), coordinates)
        symbol = check(m.group(1)) + m.group(2)
        factors[symbol] = factors.get(symbol, 0) + int(m.group(3) or 1)
    return Monomial(factors)
