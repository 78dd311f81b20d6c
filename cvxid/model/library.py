"""Libraries of candidate terms and the catalogue of physical effects.

A :class:`Library` is an ordered set of :class:`~cvxid.model.terms.Term` objects.  The
polynomial builder follows the paper's eq. (2), :math:`\\sum_{i\\le N}\\sum_{j\\le M} c_{ij}
x^i \\dot x^j` with :math:`N = M`; the catalogue names physical effects so that users (and
the diagnosis) can speak of *Coulomb friction* rather than of ``sign(x')``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, Mapping

from cvxid.errors import CvxidError
from cvxid.model.terms import (
    AbsProduct,
    Constant,
    DelayedSignal,
    InputRate,
    Monomial,
    Sign,
    Term,
    parse_term,
    velocity_symbol,
)


class Library:
    """An ordered, duplicate-free collection of terms (:class:`Term` objects, or their
    names as :func:`~cvxid.model.terms.parse_term` reads them: ``Library(["x", "x'",
    "sign(x')"])``, of the coordinate ``x``)."""

    def __init__(self, terms: Iterable[Term | str] = ()):
        if isinstance(terms, (str, Term)):
            raise CvxidError(f"Library takes a list of terms, got one ({terms!r}): write Library([{terms!r}])")
        seen: dict[str, Term] = {}
        for term in terms:
            if isinstance(term, str):
                term = parse_term(term)
            elif not isinstance(term, Term):
                raise CvxidError(f"a library's terms are Term objects or their names (\"x^3\", \"sign(x')\"), "
                                 f"got {term!r}")
            seen.setdefault(term.name, term)
        self.terms: tuple[Term, ...] = tuple(seen.values())

    @classmethod
    def polynomial(cls, order: int, cross: bool = True, coordinate: str = "x") -> "Library":
        """Monomials :math:`x^i \\dot x^j`, ``0 <= i, j <= order`` (not both 0); without
        ``cross`` only pure powers :math:`x^i` and :math:`\\dot x^j`."""
        order = int(order)
        if order < 1:
            raise CvxidError(f"library order must be at least 1, got {order}")
        v = velocity_symbol(coordinate)
        terms = []
        for total in range(1, 2 * order + 1):  # low degrees first: reads like a Taylor series
            for j in range(0, order + 1):
                i = total - j
                if 0 <= i <= order and (cross or i == 0 or j == 0):
                    terms.append(Monomial({coordinate: i, v: j}))
        return cls(terms)

    def __add__(self, other: "Library | Iterable[Term]") -> "Library":
        return Library([*self.terms, *(other.terms if isinstance(other, Library) else other)])

    def without(self, names: Iterable[str]) -> "Library":
        drop = set(names)
        return Library(t for t in self.terms if t.name not in drop)

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.terms]

    def __contains__(self, item) -> bool:
        name = item.name if isinstance(item, Term) else item
        return name in self.names

    def __iter__(self) -> Iterator[Term]:
        return iter(self.terms)

    def __len__(self) -> int:
        return len(self.terms)

    def __repr__(self) -> str:
        rows = [f"Library of {len(self)} terms:"]
        rows += [f"  {t.name:<14} {t.meaning}" for t in self.terms]
        return "\n".join(rows)


# ---------------------------------------------------------------------- catalogue
@dataclass(frozen=True)
class Effect:
    """A named physical effect: how to build its term for a coordinate, and its sign.

    ``nonnegative`` says that the coefficient of a dissipative or restoring effect is
    expected to be ``>= 0`` (the constraint that comes with it when it is added).
    """

    name: str
    meaning: str
    build: Callable[[str], Term]
    nonnegative: bool

    def plot(self, coordinate: str = "x"):
        """The effect's signature: its force against the state it depends on."""
        from cvxid.plots import signature_figure

        return signature_figure(self, coordinate)


CATALOGUE: dict[str, Effect] = {}


def register_effect(name: str, meaning: str, build: Callable[[str], Term], nonnegative: bool = False):
    """Add a user's own effect to the catalogue (``build(coordinate) -> Term``)."""
    if not name.isidentifier():
        raise CvxidError(f"effect name '{name}' must be an identifier (letters, digits, _)")
    CATALOGUE[name] = Effect(name, meaning, build, nonnegative)
    return CATALOGUE[name]


register_effect("coulomb", "Coulomb (dry) friction, sign(x')", Sign, nonnegative=True)
register_effect("viscous", "viscous damping, x'", lambda c: Monomial({velocity_symbol(c): 1}), True)
register_effect("quadratic_damping", "quadratic damping, x'|x'|", AbsProduct, True)
register_effect("cubic_damping", "cubic damping, x'^3", lambda c: Monomial({velocity_symbol(c): 3}), True)
register_effect("linear_stiffness", "linear stiffness, x", lambda c: Monomial({c: 1}), True)
register_effect("quadratic_stiffness", "quadratic stiffness (asymmetry), x^2", lambda c: Monomial({c: 2}))
register_effect("cubic_stiffness", "cubic (hardening) stiffness, x^3", lambda c: Monomial({c: 3}))
register_effect("offset", "constant force (offset, gravity, bias)", lambda c: Constant())
register_effect(
    "delay",
    "a change of the delay tau: the delayed signal's time derivative (exact-delay models); a fed-back delay "
    "x(t - tau) added, gain and delay estimated (one equation without a delay)",
    lambda c: DelayedSignal(c, 1),
)
register_effect(
    "input_delay",
    "a delay of the input, u(t - tau_u): scored by the input's rate u' (its first-order Taylor column)",
    lambda c: InputRate("u"),
)
PARAMETERS = ("delay", "input_delay")
"""Effects that are parameters estimated again (a delay), not terms added to the library."""


def effect(name: str, declared: Mapping[str, Effect] | None = None) -> Effect:
    """The effect ``name``: one a spec ``declared`` ([diagnose.effects]) or the catalogue's."""
    known = {**CATALOGUE, **(declared or {})}
    if name not in known:
        raise CvxidError(
            f"unknown effect '{name}'; the catalogue has: {', '.join(sorted(known))}"
        )
    return known[name]


def coordinate_effect(text: str, coordinates: tuple[str, ...]) -> tuple[str, str] | None:
    """``("coulomb", "theta")`` for ``"coulomb(theta)"``: a catalogue effect of one named
    coordinate (a coupled system's diagnosis names its candidates so); None for any other
    text."""
    name, _, rest = text.partition("(")
    coordinate = rest[:-1] if rest.endswith(")") else None
    return (name, coordinate) if name in CATALOGUE and name not in PARAMETERS and coordinate in coordinates else None


def resolve_term(text: str, coordinates: tuple[str, ...] = ("x",),
                 declared: Mapping[str, Effect] | None = None) -> Term:
    """A term from an effect's name (one the spec ``declared``, or the catalogue's; built for
    the first coordinate) or a term name (``x^3``, ``sin(theta)``)."""
    known = {**CATALOGUE, **(declared or {})}
    if text in known:
        return known[text].build(coordinates[0])
    if text.isidentifier() and text not in coordinates:
        raise CvxidError(
            f"unknown term or effect '{text}'; effects: {', '.join(sorted(known))}; "
            f"terms are written like x, x^3, x^2 x', sign(x'), sin(x)"
        )
    return parse_term(text, coordinates)


def declared_effect(name: str, term: str, coordinates: tuple[str, ...], meaning: str | None = None,
                    nonnegative: bool = False) -> Effect:
    """An effect a spec declares for its diagnosis: ``name`` is the ``term`` (an expression
    of the coordinates, checked now), with its ``meaning``."""
    if not name.isidentifier():
        raise CvxidError(f"effect name '{name}' must be an identifier (letters, digits, _)")
    if name in CATALOGUE:
        raise CvxidError(f"effect '{name}' is in the catalogue already; give yours another name")
    built = parse_term(term, coordinates)
    meaning = meaning or f"{name}, {built.name}"
    return Effect(name, meaning, lambda c: _with_meaning(parse_term(term, coordinates), meaning), nonnegative)


def _with_meaning(term: Term, meaning: str) -> Term:
    term.meaning = meaning
    return term
