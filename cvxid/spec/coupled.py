"""Coupled problem specs: several ``[[model.equation]]`` tables, one shared delay, ties.

The format (documented in ``docs/spec.md``) extends the single-equation spec: each
equation is a ``[model]``-like table; the shared delay is ``[model.delay]`` with each
equation's known feedback gain as its ``delay_gain``; ``[[model.tie]]`` tables tie
coefficients across equations; ``[[truth.equation]]`` tables describe the simulated truth.
Like every spec it is checked key by key and never executed.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Mapping

import numpy as np

from cvxid.errors import CvxidError
from cvxid.identified import system_physical
from cvxid.model.equation import ModelSpec
from cvxid.model.library import resolve_term
from cvxid.model.system import SystemSpec
from cvxid.model.terms import Sign
from cvxid.model.delay import ASSUMED
from cvxid.simulate import CoupledSystem, Equation
from cvxid.spec.problem import (
    diagnose_settings,
    FIT_KEYS,
    VELOCITIES,
    ProblemSpec,
    Table,
    Truth,
    _fit,
    check_selection,
    _input_delay,
    declared_effects,
    _model,
    _number,
    _string,
    _table,
    data_sections,
    ties_of,
)

JOINT_TOP_KEYS = {"name", "description", "truth", "data", "model", "fit", "diagnose"}
JOINT_MODEL_KEYS = {"equation", "delay", "tie", "input_delay"}
EQUATION_KEYS = {"coordinate", "input", "inertia", "mass", "library", "constraints", "names", "algebraic", "delay_gain"}
DELAY_KEYS = {"signal", "method", "tau_min", "tau_max", "history"}


def is_joint(raw: Table) -> bool:
    model = raw.get("model")
    return isinstance(model, Mapping) and "equation" in model


def parse_joint_problem(raw: Table, folder: Path, default_name: str = "problem",
                        data_required: bool = True) -> ProblemSpec:
    unknown = set(raw) - JOINT_TOP_KEYS
    if unknown:
        raise CvxidError(f"spec: unknown top-level key(s) {', '.join(sorted(unknown))}; allowed: "
                         f"{', '.join(sorted(JOINT_TOP_KEYS))}")
    model = _table(raw, "model", "", JOINT_MODEL_KEYS, required=True)
    equations, polynomials = _equations(model)
    ties = ties_of(model, SystemSpec(equations).column_names, "'equation:term'")
    fit = _fit(_table(raw, "fit", "", FIT_KEYS), default_estimator="lstsq")
    check_selection(fit, equations, polynomials)
    if fit.velocity not in VELOCITIES:
        raise CvxidError(f"spec: [fit] velocity of a coupled spec must be one of {', '.join(VELOCITIES)}, got "
                         f"'{fit.velocity}'")
    data = data_sections(raw, data_required)
    truth = _truth(raw, equations) if "truth" in raw else None
    if truth is None and any("simulate" in t for t in data.values()):
        raise CvxidError("spec: simulated data needs a [truth] section with [[truth.equation]] tables")
    diagnose = None
    if "diagnose" in raw:
        effects = declared_effects(raw, next(iter(equations.values())))  # terms of every coordinate
        equations = {label: replace(s, effects=effects) for label, s in equations.items()}
        diagnose = diagnose_settings(raw, equations)
    if fit.orders and not polynomials:
        raise CvxidError("spec: [fit] orders searches an order's polynomial library: give one equation "
                         "[model.equation] library = { order = ... } instead of a terms list, or remove [fit] orders")
    return ProblemSpec(_string(raw, "name", "", default_name), folder, SystemSpec(equations, ties), fit, data, truth,
                       str(raw.get("description", "")), polynomials, diagnose)


def _equations(model: Table) -> tuple[dict[str, ModelSpec], dict[str, tuple]]:
    """The equations by coordinate, and the (order, cross, extra) of those whose library is
    an order's polynomial."""
    tables = model.get("equation")
    if not isinstance(tables, list) or len(tables) < 2 or not all(isinstance(t, Mapping) for t in tables):
        raise CvxidError("spec: a coupled model needs two or more [[model.equation]] tables")
    coords = []
    for i, t in enumerate(tables):
        coord = _string(t, "coordinate", f"model.equation[{i}]")
        if coord in coords:
            raise CvxidError(f"spec: two [[model.equation]] tables have the coordinate '{coord}'; each needs its own")
        coords.append(coord)
    delay = _table(model, "delay", "model", DELAY_KEYS, required=True)
    if isinstance(delay.get("signal"), list):
        raise CvxidError(f"spec: [model.delay] signal = {delay['signal']!r}: a coupled model feeds back one signal (a "
                         "coordinate or its velocity); a position and its velocity together (the paper's b0 x(t - tau) "
                         "+ b1 x'(t - tau)) are for a model of one equation")
    if _string(delay, "method", "model.delay", "exact") != "exact":
        raise CvxidError("spec: the shared delay of a coupled model is fitted exactly: [model.delay] method = \"exact\"")
    shared = _input_delay(model, "model") if "input_delay" in model else None  # the shared input's delay
    equations, named, polynomials = {}, {}, {}
    for i, t in enumerate(tables):
        where = f"model.equation[{i}]"
        if "input_delay" in t:
            raise CvxidError(f"spec: [{where}] input_delay: the equations share one input, so give its delay once, "
                             "in [model] (input_delay = seconds, or a table [model.input_delay])")
        table = _table({f"equation[{i}]": t}, f"equation[{i}]", "model", EQUATION_KEYS)
        delay_t = dict(delay, method="exact")
        if "delay_gain" in table:
            delay_t["gain"] = _number(table, "delay_gain", where)
            if not (np.isfinite(delay_t["gain"]) and delay_t["gain"] != 0):
                raise CvxidError(f"spec: [{where}] delay_gain must be a finite non-zero number (the equation's known "
                                 f"feedback gain; leave it out to estimate it), got {delay_t['gain']}")
        table = {k: v for k, v in table.items() if k != "delay_gain"}
        table["delay"] = delay_t
        others = tuple(c for c in coords if c != coords[i])
        spec, polynomial = _model(table, where, others)
        spec = replace(spec, input_delay=shared)
        if polynomial is not None:
            polynomials[spec.coordinate] = polynomial
        for pname in spec.names:
            if pname in named:
                raise CvxidError(f"spec: the physical name '{pname}' is given in two equations "
                                 f"({named[pname]} and {spec.coordinate}); names must be unique")
            named[pname] = spec.coordinate
        equations[spec.coordinate] = spec
    return equations, polynomials


def _truth(raw: Table, equations: dict[str, ModelSpec]) -> Truth:
    t = _table(raw, "truth", "", {"equation", "delay", "history", "smoothing", "input_delay"})
    tables = t.get("equation")
    if not isinstance(tables, list) or not all(isinstance(e, Mapping) for e in tables):
        raise CvxidError("spec: a coupled [truth] needs [[truth.equation]] tables")
    coords = tuple(equations)
    smoothing = t.get("smoothing", {})
    if not isinstance(smoothing, Mapping):
        raise CvxidError("spec: [truth] smoothing must be a table like { \"sign(x')\" = 0.05 }")
    delay = _table(t, "delay", "truth", {"signal", "tau"}, required=True)
    tau = _number(delay, "tau", "truth.delay", positive=True)
    signal = _string(delay, "signal", "truth.delay", coords[0])
    derivative = 1 if signal.endswith("'") else 0  # a velocity fed back: "theta'"
    signal = signal.removesuffix("'")
    if signal not in coords:
        raise CvxidError(f"spec: [truth.delay] signal must be one of the coordinates {', '.join(coords)} (or its "
                         f"velocity, {coords[0]}'), got '{delay['signal']}'")
    eqs, inputs, coefficients, extra = [], set(), {}, {}
    for i, e in enumerate(tables):
        where = f"truth.equation[{i}]"
        if "input_delay" in e:
            raise CvxidError(f"spec: [{where}] input_delay: the equations share one input, so give its delay once, "
                             "as [truth] input_delay")
        e = _table({f"equation[{i}]": e}, f"equation[{i}]", "truth", {"coordinate", "mass", "input", "coefficients",
                                                                     "delay_gain"})
        coord = _string(e, "coordinate", where)
        if coord not in coords:
            raise CvxidError(f"spec: [{where}] coordinate '{coord}' has no [[model.equation]]; the model has "
                             f"{', '.join(coords)}")
        inp = _string(e, "input", where, equations[coord].input)
        inputs.add(inp.lstrip("-").strip())
        coefs_t = e.get("coefficients", {})
        if not isinstance(coefs_t, Mapping):
            raise CvxidError(f"spec: [{where}] coefficients must be a table of term = value")
        terms, values = [], []
        for name in coefs_t:
            term = resolve_term(name, (coord, *(c for c in coords if c != coord)))
            if isinstance(term, Sign) and name in smoothing:
                term = Sign(term.coordinate, _number(smoothing, name, "truth.smoothing", positive=True))
            terms.append(term)
            values.append(_number(coefs_t, name, f"{where}.coefficients"))
        mass = _number(e, "mass", where, 1.0, positive=True)
        eqs.append(Equation(coord, mass, tuple(terms), tuple(values), -1.0 if inp.startswith("-") else 1.0,
                            _number(e, "delay_gain", where, 0.0)))
        spec = equations[coord]
        coefficients[coord] = {spec.inertia_term.name: mass, **{t.name: v for t, v in zip(terms, values)}}
        extra[coord] = {t.name: v for t, v in zip(terms, values) if t.name not in spec.library.names}
    if sorted(e.coordinate for e in eqs) != sorted(coords):
        raise CvxidError(f"spec: [[truth.equation]] must describe every coordinate ({', '.join(coords)}) once")
    if len(inputs) != 1:
        raise CvxidError(f"spec: the truth's equations must share one input (with or without a '-'), got {sorted(inputs)}")
    for i, spec in enumerate(equations.values()):
        if spec.input_column not in inputs:
            raise CvxidError(f"spec: [model.equation[{i}]] input = '{spec.input}' is not the input the [truth] "
                             f"simulates ('{next(iter(inputs))}'): name that one, with or without a '-'")
    history = _string(t, "history", "truth", "zero", choices=ASSUMED)
    order = {c: i for i, c in enumerate(coords)}
    system = CoupledSystem(tuple(sorted(eqs, key=lambda q: order[q.coordinate])), signal, tau, history, derivative)
    physical = system_physical(equations, coefficients, tau, extra)
    for q in eqs:  # the truth's own gains and input delay, where the model estimates or has them
        if f"{q.coordinate}:gain" in physical:
            physical[f"{q.coordinate}:gain"] = q.delay_gain
    physical.pop("tau_u", None)
    late = _number(t, "input_delay", "truth", 0.0, within=(0, 10.0), fix="the shared input's delay in seconds")
    if late:
        physical["tau_u"] = late
    return Truth(system, inputs.pop(), physical, late)
