r"""The candidate effects a diagnosis offers a system of :math:`N \ge 1` equations.

A candidate is a term added, with a coefficient of its own, to every equation that lacks
it.  A catalogue effect (:data:`~cvxid.model.library.CATALOGUE`) is built for each
coordinate: in one equation it keeps its name (``"coulomb"``: ``sign(x')``); in a system of
several each coordinate's is a candidate of its own (``"coulomb(theta)"``:
``sign(theta')`` in every equation), unless every coordinate's is the same term (``"offset"``).  A dissipative or restoring effect's sign constraint
(:math:`c \ge 0`) holds in its own coordinate's equation only: there it opposes the
coordinate's motion, while in the equations it couples into its sign is the coupling's (the
flexible joint's motor friction is :math:`+f_c` in the motor's equation and :math:`-f_c` in
the link's).  A spec's own effects (``[diagnose.effects]``) and plain term names are
candidates as written; a declared effect's sign holds in one equation's model only.

Two names are parameters estimated again, not terms, each shared by every equation:
``"delay"`` (an exact delay profiled again; scored by the column
:math:`\partial_\tau\, x(t-\tau) = -\dot x(t-\tau)` in every equation) and
``"input_delay"`` (the input's delay estimated; scored by the rate of the input each
equation receives, :math:`\dot u`).  A model of one equation without a delay is offered
``"delay"`` as a fed-back delay to add, :math:`b\,x(t-\tau)` with its gain and delay
estimated (:func:`with_feedback_delay`; scored by that column at the delay that explains
the most, :mod:`cvxid.diagnosis.ranking`): without it a missing feedback was "repaired"
with a sub-sample input delay (an outside check: 0.85 ms for a feedback of 0.15 s), whose
rate column stands in for the delay's third-order Taylor term.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

from cvxid.data.experiment import Experiment
from cvxid.errors import CvxidError
from cvxid.metrics import band_period
from cvxid.model.delay import DelayedFeedback
from cvxid.model.equation import ModelSpec
from cvxid.model.input_delay import InputDelay, record_bound
from cvxid.model.library import CATALOGUE, PARAMETERS, coordinate_effect, resolve_term
from cvxid.model.terms import DelayedSignal, InputRate, Term


@dataclass(frozen=True)
class Candidate:
    """A named term and the equations (labels) it joins; ``signed``: those where its
    coefficient is constrained to be nonnegative."""

    name: str
    term: Term
    equations: tuple[str, ...]
    signed: tuple[str, ...] = ()

    @property
    def reestimated(self) -> bool:
        """Whether the candidate is a parameter estimated again (a delay), not a term added."""
        return self.name in PARAMETERS


def _specs(model: ModelSpec | Mapping[str, ModelSpec]) -> dict[str, ModelSpec]:
    return {model.coordinate: model} if isinstance(model, ModelSpec) else dict(model)


def default_candidates(model: ModelSpec | Mapping[str, ModelSpec]) -> list[str]:
    """The catalogue and the spec's own effects minus what the model already has (``delay``:
    for an exact delay, or one equation without a delay)."""
    specs = _specs(model)
    first = next(iter(specs.values()))
    exact = first.delay is not None and first.delay.exact
    return [n for n in {**CATALOGUE, **first.effects}
            if (n != "delay" or exact or lacks_delay(specs)) and missing(specs, n)]


FEEDBACK_TAU_MAX = 0.5
"""The longest fed-back delay the ``delay`` candidate searches (the spec's default
``tau_max``), or :data:`FEEDBACK_PERIODS` of the output's median period when that is
longer (as ``cvxid init`` writes), at most a quarter of the shortest gap-free stretch of the
records."""
FEEDBACK_PERIODS = 1 / 8
"""The ``delay`` candidate's range in periods of the output's median frequency (a plant 100
times slower than a second, with a delay of 12 s, was offered 0 … 0.5 s)."""
FEEDBACK_MIN_SAMPLES = 5
"""The fewest sample steps the ``delay`` candidate's search range must span to be offered."""


def lacks_delay(model: ModelSpec | Mapping[str, ModelSpec]) -> bool:
    """Whether ``model`` is one equation without a fed-back delay (the ``delay`` candidate
    then adds one)."""
    specs = _specs(model)
    return len(specs) == 1 and next(iter(specs.values())).delay is None


def feedback_bound(coordinate: str, *experiments: Experiment) -> float:
    """The ``delay`` candidate's ``tau_max``: :data:`FEEDBACK_TAU_MAX` or
    :data:`FEEDBACK_PERIODS` of the median period of ``coordinate``'s output in the first
    record, the longer, at most a quarter of the shortest gap-free stretch of
    ``experiments`` (the measured history of every row); an error when that spans fewer
    than :data:`FEEDBACK_MIN_SAMPLES` samples (a record sampled as slowly as the delays
    searched, or cut short by gaps)."""
    stretches = [s for e in experiments for s in e.segments()]
    period = band_period([experiments[0].output(coordinate)], experiments[0].dt, share=0.5)
    bound = min(max(FEEDBACK_TAU_MAX, FEEDBACK_PERIODS * period), min(s.duration for s in stretches) / 4)
    step = max(s.dt for s in stretches)
    if bound < FEEDBACK_MIN_SAMPLES * step:
        raise CvxidError(f"a fed-back delay of up to {bound:.3g} s spans fewer than {FEEDBACK_MIN_SAMPLES} samples "
                         f"of {step:.3g} s: name it in the spec ([model.delay]) with its own range to have it")
    return bound


def with_feedback_delay(model: ModelSpec | Mapping[str, ModelSpec], *experiments: Experiment) -> dict[str, ModelSpec]:
    r"""The one equation of ``model`` with an exact fed-back delay of its own coordinate,
    :math:`b\,x(t-\tau)`, its gain estimated and :math:`\tau` searched in
    ``[0, feedback_bound(experiments)]``."""
    specs = _specs(model)
    if not lacks_delay(specs):
        raise CvxidError("a fed-back delay is added to one equation without one")
    (label, spec), = specs.items()
    delay = DelayedFeedback(spec.coordinate, 0, None, method="exact",
                            tau_max=feedback_bound(spec.coordinate, *experiments))
    return {label: replace(spec, delay=delay)}


def missing(model: ModelSpec | Mapping[str, ModelSpec], name: str) -> bool:
    """Whether the effect or term ``name`` is missing from an equation of ``model`` (an input
    delay is missing unless the spec has one, estimated or known)."""
    return bool(candidates(model, [name]))


def candidates(model: ModelSpec | Mapping[str, ModelSpec], names: Sequence[str]) -> dict[str, Candidate]:
    """The candidates the ``names`` (catalogue effects, one coordinate's catalogue effect
    ``"coulomb(theta)"``, the spec's own effects, term names, ``delay``, ``input_delay``)
    give ``model`` (one equation's spec, or specs by label), by
    candidate name, leaving out what every equation already has."""
    specs = _specs(model)
    labels = list(specs)
    first = specs[labels[0]]
    label_of = {s.coordinate: label for label, s in specs.items()}
    coords = tuple(label_of)
    declared = first.effects
    out: dict[str, Candidate] = {}
    for name in names:
        if name in PARAMETERS:
            found = _parameter(specs, name)
            if found is not None:
                out[name] = found
            continue
        one = coordinate_effect(name, coords)
        if one is not None:  # "coulomb(theta)": one coordinate's
            eff, c = CATALOGUE[one[0]], one[1]
            built = {name: (eff.build(c), label_of[c] if eff.nonnegative else None)}
        elif name in declared:
            eff = declared[name]
            built = {name: (eff.build(coords[0]), labels[0] if eff.nonnegative and len(specs) == 1 else None)}
        elif name in CATALOGUE:
            eff = CATALOGUE[name]
            terms = {c: eff.build(c) for c in coords}
            shared = len({t.name for t in terms.values()}) == 1  # (an offset is every coordinate's)
            signs = eff.nonnegative and (len(coords) == 1 or not shared)  # (a shared term has no own equation)
            built = {(name if shared else f"{name}({c})"): (t, label_of[c] if signs else None) for c, t in terms.items()}
        else:
            built = {name: (resolve_term(name, coords, declared), None)}
        for label, (term, own) in built.items():
            lacking = tuple(lb for lb, s in specs.items() if term.name not in s.column_names)
            if lacking:
                out[label] = Candidate(label, term, lacking, (own,) if own in lacking else ())
    return out


def _parameter(specs: dict[str, ModelSpec], name: str) -> Candidate | None:
    """The ``delay`` or ``input_delay`` candidate, its column in every equation (None when
    the system has an input delay already)."""
    spec = next(iter(specs.values()))
    if name == "input_delay":  # (each equation's column is the rate of the input it receives)
        return Candidate(name, InputRate(spec.input), tuple(specs)) if spec.input_delay is None else None
    if lacks_delay(specs):
        return Candidate(name, DelayedSignal(spec.coordinate, 0, "a fed-back delay, gain and delay estimated"),
                         tuple(specs))
    if not (spec.delay is not None and spec.delay.exact):
        raise CvxidError("the 'delay' candidate needs a model with an exact delay ([model.delay] method = 'exact') "
                         "or one equation without a delay (to add one)")
    change = DelayedSignal(spec.delay.coordinate, spec.delay.derivative + 1)  # (a change of the delay, to first order)
    if change.name in spec.column_names:  # (the paper's fed-back velocity, its gain estimated: the model has it)
        return None
    return Candidate(name, change, tuple(specs))


def with_candidate(specs: Mapping[str, ModelSpec], candidate: Candidate) -> dict[str, ModelSpec]:
    """``specs`` with the candidate's term in each equation it joins, its sign constraint
    where it has one."""
    if candidate.reestimated:
        raise CvxidError(f"'{candidate.name}' is not added but estimated again")
    return {label: replace(s, library=s.library + [candidate.term],
                           nonnegative=s.nonnegative + ((candidate.term.name,) if label in candidate.signed else ()))
            if label in candidate.equations else s for label, s in specs.items()}


def with_effect(spec: ModelSpec, name: str) -> ModelSpec:
    """``spec`` with a catalogue effect (or a term) added, its sign constraint included."""
    if name == "delay" and lacks_delay(spec):
        raise CvxidError("a fed-back delay is not a term: give the spec one to estimate (with_feedback_delay), or "
                         "let the diagnosis add it (refine)")
    if name == "delay":
        raise CvxidError("the delay is not added but estimated again: refit the model (refit() profiles tau)")
    if name == "input_delay":
        raise CvxidError("an input delay is not a term: give the spec one to estimate (with_input_delay)")
    found = candidates(spec, [name])
    if not found:
        raise CvxidError(f"the model already has {resolve_term(name, (spec.coordinate,), spec.effects).name} ({name})")
    return with_candidate({spec.coordinate: spec}, found[name])[spec.coordinate]


def with_input_delay(model: ModelSpec | Mapping[str, ModelSpec], train: Experiment):
    """``model`` (one equation's spec, or specs by label) with an input delay to estimate,
    the same in every equation, from 0 to a quarter period of the training outputs' band
    edge (:func:`~cvxid.model.input_delay.record_bound`)."""
    specs = _specs(model)
    bound = record_bound([train.output(s.coordinate) for s in specs.values()], train.dt)
    late = {label: replace(s, input_delay=InputDelay(0.0, 0.0, bound)) for label, s in specs.items()}
    return late if not isinstance(model, ModelSpec) else late[model.coordinate]
