r"""The model being identified: :class:`ModelSpec`.

.. math::

    m\,\ddot x + \sum_i c_i\, g_i(x, \dot x) = f(t) + b\, x^{(q)}(t - \tau)
    \quad\text{or}\quad f(t) + b_0\, x(t - \tau) + b_1\, \dot x(t - \tau)

A spec says which coordinate and input, whether the inertia :math:`m` is identified (or
known), the library of candidate terms :math:`g_i`, the delayed feedback, the named sign
constraints and the names of the physical parameters.  It owns the map between regression
coefficients and physical parameters.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Mapping

from cvxid.errors import CvxidError
from cvxid.model.delay import DelayedFeedback
from cvxid.model.input_delay import InputDelay
from cvxid.model.library import Effect, Library
from cvxid.model.terms import DELAYED, DelayedSignal, Derivative, Term, parse_term

INERTIA, DELAY, LIBRARY, LISTED, LINEAR = "inertia", "delay", "library", "listed", "linear"
GAIN_NAMES = ("gain", "rate_gain")
"""The physical names of the feedback gains: the fed-back signal's, and its rate's."""


@dataclass(frozen=True)
class Column:
    """One regression column: its term, its group and its L1 weight."""

    term: Term
    group: str

    @property
    def name(self) -> str:
        return self.term.name

    @property
    def penalty(self) -> float:
        """Weight of the L1 penalty: 1 on the library's candidates, 0 on inertia, delay,
        listed and kept linear columns (estimated, never selected away)."""
        return 1.0 if self.group == LIBRARY else 0.0


@dataclass(frozen=True)
class ModelSpec:
    """What to identify.

    Parameters
    ----------
    library : Library
        Candidate terms :math:`g_i` (left-hand side).
    coordinate, input : str
        Names of the measured coordinate (its second derivative is this equation's inertia)
        and of the input.
    others : tuple of str
        In a coupled system, the other measured coordinates whose states the terms and the
        delayed feedback may read (e.g. the alpha equation of a flexible joint reads theta).
    inertia : bool
        Identify :math:`m` (a column :math:`\\ddot x`); otherwise ``mass`` is known.
    delay : DelayedFeedback, optional
        The delayed feedback on the right-hand side.
    nonnegative : tuple of str
        Columns whose coefficient must be ``>= 0`` (term names; ``"x''"`` for inertia).
    names : mapping
        Physical parameter names for terms (``{"k1": "x"}``); the mass is ``m``, the delay
        ``tau``.
    orders : tuple, optional
        User's algebraic orders ``(n, m)``; by default the smallest that remove every
        initial condition.
    effects : mapping of str to Effect, optional
        Effects the spec declares (``[diagnose.effects]``): diagnosis candidates beside the
        catalogue's.
    input_delay : InputDelay, optional
        The input acts at :math:`t - \\tau_u` (:mod:`cvxid.model.input_delay`).
    """

    library: Library
    coordinate: str = "x"
    input: str = "f"
    inertia: bool = True
    mass: float = 1.0
    delay: DelayedFeedback | None = None
    nonnegative: tuple[str, ...] = ()
    names: Mapping[str, str] = field(default_factory=dict)
    orders: tuple[int | None, int | None] = (None, None)
    keep_initial_conditions: bool = False  # admit the paper's n = 2 with Taylor 3 (reproduction only)
    others: tuple[str, ...] = ()  # other coordinates of a coupled system that terms may read
    listed: tuple[str, ...] = ()  # library terms the user listed: estimated, never selected away
    keep_linear: bool = True  # the library's x and x' estimated, never selected away (see columns)
    effects: Mapping[str, Effect] = field(default_factory=dict)  # the spec's own effects for the diagnosis
    input_delay: InputDelay | None = None

    def __post_init__(self):
        if not isinstance(self.library, Library):  # (a list of terms or their names)
            object.__setattr__(self, "library", Library(self.library))
        signed = [n for n in self.column_names if not n.endswith(DELAYED)]
        for name in self.nonnegative:
            if name.endswith(DELAYED):
                raise CvxidError(
                    f"[model.constraints] nonnegative names '{name}', the delayed feedback: its sign is not "
                    f"constrained (its column carries minus the gain b of + b {name}); give the gain "
                    "([model.delay] gain = …) if you know it")
            if name not in signed:
                raise CvxidError(
                    f"[model.constraints] nonnegative names '{name}', which is not a column of "
                    f"the model; columns: {', '.join(signed)}"
                )
        for tname in self.names.values():
            parse_term(_bare(tname)[1], self.coordinates)  # a readable term (it may join the model later)
        if not self.inertia and not self.mass > 0:
            raise CvxidError(f"[model] mass must be positive when inertia = false, got {self.mass}")

    # ------------------------------------------------------------------ columns
    @property
    def coordinates(self) -> tuple[str, ...]:
        """This equation's coordinate first, then the others it may read."""
        return (self.coordinate, *self.others)

    @property
    def linear_terms(self) -> tuple[str, str]:
        """The linear stiffness and damping terms (``x``, ``x'``): the stepwise search's
        default base, kept by a selection (``keep_linear``) and never pruned (a delay
        stands in for a damping in the simulation error)."""
        return self.coordinate, self.coordinate + "'"

    @property
    def inertia_term(self) -> Derivative:
        return Derivative(self.coordinate, 2)

    @property
    def columns(self) -> list[Column]:
        r"""Inertia, the library and the delay's Taylor columns, each once.  With
        ``keep_linear`` the library's linear stiffness and damping (``x``, ``x'``) are not
        candidates: a selection that drops the damping lets a delay or a damping-like term
        stand in for it (:math:`b\,x(t-\tau) \approx b\,x - b\,\tau\,\dot x`) — except
        the :attr:`confounded_signal`, which the L1 penalty must be free to trade with the
        estimated gain (both unpenalised, a short delay makes them two nearly equal columns
        and their coefficients run away together)."""
        cols: dict[str, Column] = {}
        delay_names = {t.name for t in self.delay.taylor_terms()} if self.delay else set()
        linear = [t for t in self.linear_terms if t not in self.confounded_signals] if self.keep_linear else ()
        if self.inertia:
            cols[self.inertia_term.name] = Column(self.inertia_term, INERTIA)
        for term in self.library:
            group = DELAY if term.name in delay_names else LISTED if term.name in self.listed else \
                LINEAR if term.name in linear else LIBRARY
            cols.setdefault(term.name, Column(term, group))
        if self.delay:
            for term in self.delay.taylor_terms():
                cols.setdefault(term.name, Column(term, DELAY))
            if self.delay.exact:
                for term, estimated in zip(self.delayed_terms, self.delay.estimated):
                    if estimated:
                        cols[term.name] = Column(term, DELAY)
        return list(cols.values())

    @property
    def input_column(self) -> str:
        """The measured input this equation reads (``"-u"`` reads the column ``u``)."""
        return self.input.lstrip("-").strip()

    @property
    def input_tau(self) -> float:
        """The input's delay :math:`\\tau_u` (0 without one)."""
        return self.input_delay.value if self.input_delay is not None else 0.0

    def received_input(self, experiment) -> np.ndarray:
        """The input as this equation receives it, :math:`u(t - \\tau_u)`, at the samples."""
        return experiment.input(self.input, self.input_tau)

    def input_text(self, digits: int = 6) -> str:
        """The right-hand side's input: ``"u"``, or ``"u(t - 0.0375)"`` with a delay."""
        tau = self.input_tau
        return f"{self.input}(t - {tau:.{digits}g})" if tau else self.input

    def with_input_tau(self, value: float) -> "ModelSpec":
        """The spec with its input delay at ``value`` (within its bounds)."""
        return replace(self, input_delay=self.input_delay.at(value))

    @property
    def confounded_signals(self) -> tuple[str, ...]:
        r"""The fed-back signals (``x``; with the rate ``x'`` too) whose gains are estimated
        and that are library columns too: at :math:`\tau = 0` each and its delayed column are
        one column, and for a short delay nearly so."""
        if self.delay is None:
            return ()
        free = zip(self.delay.signals, self.delay.estimated)
        return tuple(signal for signal, estimated in free if estimated and signal in self.library.names)

    @property
    def confounded_signal(self) -> str | None:
        """The first fed-back signal (``x``) when it is confounded
        (:attr:`confounded_signals`), else None."""
        signal = self.delay.signals[0] if self.delay is not None else None
        return signal if signal in self.confounded_signals else None

    @property
    def delayed_term(self) -> DelayedSignal:
        """The exact delayed signal (its column carries minus the unknown gain); with the
        rate, the position's."""
        return self.delayed_terms[0]

    @property
    def delayed_terms(self) -> tuple[DelayedSignal, ...]:
        """The exact delayed signals, one per fed-back signal (each column carries minus its
        unknown gain)."""
        return tuple(DelayedSignal(self.delay.coordinate, q) for q in self.delay.orders)

    @property
    def column_names(self) -> list[str]:
        return [c.name for c in self.columns]

    @property
    def highest_derivative(self) -> int:
        high = 2
        if self.delay:
            high = max(high, self.delay.highest_order)
        return high

    @property
    def needs_velocity(self) -> bool:
        return any(c.term.needs_velocity for c in self.columns)

    def with_library(self, library: Library) -> "ModelSpec":
        keep = set(library.names) | {self.inertia_term.name}
        if self.delay:
            keep |= {t.name for t in self.delay.taylor_terms()}
        return replace(
            self,
            library=library,
            nonnegative=tuple(n for n in self.nonnegative if n in keep),
            listed=tuple(n for n in self.listed if n in keep),
            names={k: v for k, v in self.names.items() if parse_term(_bare(v)[1], self.coordinates).name in keep},
        )

    # ------------------------------------------------------------------ physics
    def _derivative_order(self, name: str) -> int | None:
        """Order d when column ``name`` is :math:`x^{(d)}` (x is order 0, x' order 1)."""
        term = parse_term(name, self.coordinates)
        if isinstance(term, Derivative):
            return term.order
        if term.name == self.coordinate:
            return 0
        if term.name == self.coordinate + "'":
            return 1
        return None

    def physical_terms(
        self, coefficients: Mapping[str, float], tau: float | None = None
    ) -> tuple[float, dict[str, float], float | None, tuple[float, ...] | None]:
        """Mass, each library term's own coefficient, the delay and the feedback gains (one
        per fed-back signal), from regression coefficients (column name → value).

        With a Taylor delay, tau comes from the pure-delay columns and the delay's share is
        removed from the columns it shares with physics.  With the exact delay, ``tau`` is
        the delay the regression was built for and an unknown gain is minus its column's
        coefficient.
        """
        coefs = dict(coefficients)
        gain = self.delay.gains if self.delay else None
        if self.delay and not self.delay.exact:
            physical_orders = {self._derivative_order(n) for n in self.library.names}
            if self.inertia:
                physical_orders.add(2)
            pure = {
                t.order: coefs.get(t.name, 0.0)
                for t in self.delay.taylor_terms()
                if t.order not in physical_orders
            }
            tau = self.delay.estimate_tau(pure)
            for t in self.delay.taylor_terms():
                if t.order in physical_orders and t.name in coefs:
                    coefs[t.name] -= self.delay.contribution(t.order, tau)
        elif self.delay:
            if tau is None:
                raise CvxidError("an exact-delay model needs the delay tau it was fitted for")
            known = gain or (None,) * len(self.delay.orders)
            gain = tuple(-coefs.get(t.name, 0.0) if g is None else g for t, g in zip(self.delayed_terms, known))
        mass = coefs.get(self.inertia_term.name, 0.0) if self.inertia else self.mass
        return mass, {t.name: coefs.get(t.name, 0.0) for t in self.library}, tau, gain

    def parameter_name(self, term_name: str) -> str:
        """The physical name of a term's coefficient (``names`` in the spec, else the term)."""
        return self.named_parameter(term_name)[0]

    def named_parameter(self, term_name: str) -> tuple[str, float]:
        """(physical name, sign): a name given as ``"-alpha"`` is minus the coefficient."""
        return self._named_terms.get(term_name, (term_name, 1.0))

    @cached_property
    def _named_terms(self) -> dict[str, tuple[str, float]]:
        """Term name -> (physical name, sign) of ``names`` (parsed once: the output-error
        fits ask for every parameter's name at every simulation)."""
        named = {}
        for pname, tname in self.names.items():
            sign, bare = _bare(tname)
            named.setdefault(parse_term(bare, self.coordinates).name, (pname, sign))
        return named

    def physical(self, coefficients: Mapping[str, float], tau: float | None = None) -> dict[str, float]:
        """Physical parameters by name: ``m``, each term's coefficient, ``tau`` (and the
        feedback ``gain`` when it was estimated), the input's delay ``tau_u`` when it has one."""
        mass, terms, tau, gain = self.physical_terms(coefficients, tau)
        out = {"m": mass}
        for n, v in terms.items():
            pname, sign = self.named_parameter(n)
            out[pname] = sign * v
        if tau is not None:
            out["tau"] = tau
        if self.delay:
            out.update((name, g) for name, g, free in zip(self.gain_names, gain, self.delay.estimated) if free)
        if self.input_delay is not None:
            out["tau_u"] = self.input_delay.value
        return out

    @property
    def gain_names(self) -> tuple[str, ...]:
        """The physical names of the feedback gains: ``gain``; with the rate, ``gain`` and
        ``rate_gain`` (:math:`b_0`, :math:`b_1`)."""
        return GAIN_NAMES[:len(self.delay.orders)] if self.delay else ()

    def __repr__(self) -> str:
        lhs = ("m " if self.inertia else f"{self.mass:g} ") + f"{self.coordinate}''"
        rhs = self.input + ("(t - tau_u)" if self.input_delay is not None else "")
        if self.delay:
            unknown = ("b0", "b1") if self.delay.rate else ("b",)
            known = self.delay.gains or (None,) * len(unknown)
            rhs += self.delay.feedback_text([name if g is None else g for g, name in zip(known, unknown)])
        lines = [
            f"ModelSpec: {lhs} + sum_i c_i g_i = {rhs}",
            f"  library: {len(self.library)} terms ({', '.join(self.library.names)})",
        ]
        if self.delay:
            lines.append(f"  delay: exact, tau in [{self.delay.tau_min:g}, {self.delay.tau_max:g}]" if self.delay.exact
                         else f"  delay: taylor, order {self.delay.taylor_order}")
        if self.nonnegative:
            lines.append(f"  constraints: {', '.join(n + ' >= 0' for n in self.nonnegative)}")
        n, m = self.orders
        if n is not None or m is not None:
            lines.append(f"  algebraic orders: n = {n}, m = {m}")
        return "\n".join(lines)


def _bare(name: str) -> tuple[float, str]:
    """A physical-name target ``"-alpha"`` as (-1, "alpha"); ``"alpha"`` as (1, "alpha")."""
    name = name.strip()
    return (-1.0, name[1:].strip()) if name.startswith("-") else (1.0, name)
