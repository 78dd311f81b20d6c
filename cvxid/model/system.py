r"""A system of :math:`N \ge 1` equations: :class:`SystemSpec`.

.. math::

    m_i\,\ddot q_i + \sum_j c_{ij}\, g_{ij}(q, \dot q) = u_i(t) + b_i\, q_d^{(r)}(t - \tau),
    \qquad i = 1..N,

each equation a :class:`~cvxid.model.equation.ModelSpec` (its own coordinate, library,
inertia and sign constraints), one shared delay, and optional ties
:math:`c_a = \rho\, c_b` between coefficients.  A single equation is the system with
:math:`N = 1`.  Columns are named ``"coordinate:term"`` when :math:`N > 1` and printed bare
(``"x'"``) when :math:`N = 1`, as python-control squeezes its single-input, single-output
responses.
"""

from __future__ import annotations

from dataclasses import dataclass

from cvxid.errors import CvxidError
from cvxid.model.equation import ModelSpec
from cvxid.model.library import Library

Tie = tuple[str, str, float]


@dataclass(frozen=True)
class SystemSpec:
    """Equations by label (their coordinate), one shared delay, ties between columns."""

    equations: dict[str, ModelSpec]
    ties: tuple[Tie, ...] = ()

    def __post_init__(self):
        if not self.equations:
            raise CvxidError("a system needs at least one equation")
        coords = [s.coordinate for s in self.equations.values()]
        if len(set(coords)) != len(coords):
            raise CvxidError(f"every equation needs its own coordinate; got {coords}")
        if len(self.equations) > 1:
            delays = {(s.delay.coordinate, s.delay.tau_min, s.delay.tau_max) if s.delay else None
                      for s in self.equations.values()}
            if len(delays) != 1 or any(s.delay is None or not s.delay.exact for s in self.equations.values()):
                raise CvxidError("a system of several equations needs one shared exact delay (method = \"exact\") "
                                 "in every equation, with the same signal and bounds")
        if len({s.input_delay for s in self.equations.values()}) > 1:
            raise CvxidError("the equations share one input, so one input delay: give it once ([model] input_delay), "
                             "the same for every equation")
        names = set(self.column_names)
        for a, b, factor in self.ties:
            for name in (a, b):
                if name not in names:
                    raise CvxidError(f"tie {a!r} = {factor:g} {b!r}: unknown column {name!r}; the columns are "
                                     f"{', '.join(sorted(names))}")

    @classmethod
    def of(cls, model: ModelSpec) -> "SystemSpec":
        """The system of one equation."""
        return cls({model.coordinate: model})

    @property
    def single(self) -> ModelSpec | None:
        """The equation when there is one (``None`` for a coupled system)."""
        return next(iter(self.equations.values())) if len(self.equations) == 1 else None

    @property
    def delay(self):
        """The shared delayed feedback (``None`` without one)."""
        return next(iter(self.equations.values())).delay

    @property
    def exact(self) -> bool:
        return self.delay is not None and self.delay.exact

    def column(self, label: str, name: str) -> str:
        """A column's name in the system: bare for one equation, ``"label:name"`` else."""
        return name if len(self.equations) == 1 else f"{label}:{name}"

    @property
    def column_names(self) -> list[str]:
        return [self.column(label, n) for label, s in self.equations.items() for n in s.column_names]

    @property
    def nonnegative(self) -> list[str]:
        return [self.column(label, n) for label, s in self.equations.items() for n in s.nonnegative]

    def split(self, coefficients: dict[str, float]) -> dict[str, dict[str, float]]:
        """System coefficients (column name → value) as one mapping per equation."""
        return {label: {n: float(coefficients.get(self.column(label, n), 0.0)) for n in s.column_names}
                for label, s in self.equations.items()}

    def selected(self, keep) -> "SystemSpec":
        """The system with each library cut to the terms whose columns are in ``keep``;
        ties lose the columns that left."""
        return self.with_libraries({label: Library(t for t in s.library if self.column(label, t.name) in keep)
                                    for label, s in self.equations.items()})

    def with_libraries(self, libraries: dict[str, Library]) -> "SystemSpec":
        """The system with the equations named in ``libraries`` on those libraries (the
        others as they are); ties lose the columns that left."""
        equations = {label: s.with_library(libraries[label]) if label in libraries else s
                     for label, s in self.equations.items()}
        names = set(SystemSpec(equations).column_names)
        return SystemSpec(equations, tuple(t for t in self.ties if t[0] in names and t[1] in names))
