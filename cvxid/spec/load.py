"""Reading a spec file: one ``[model]`` or several ``[[model.equation]]`` tables.

A single equation written as one ``[[model.equation]]`` (with the shared ``[model.delay]``
and one ``[[truth.equation]]``) is the same problem as its ``[model]`` form: it is rewritten
into that form and read by the same checks, so both give the same numbers.
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path
from typing import Mapping

from cvxid.errors import CvxidError, CvxidWarning
from cvxid.spec.shipped import resolve_spec
from cvxid.spec.toml import tomllib
from cvxid.spec.coupled import is_joint, parse_joint_problem
from cvxid.spec.problem import ProblemSpec, Table, parse_single_problem


def load_problem(path, data_required: bool = True) -> ProblemSpec:
    """Read and check a TOML problem spec: a file, or a shipped problem's name
    (``cvxid problems`` lists them).  With ``data_required`` false the spec may leave out
    ``[data]``: its records are then given from Python
    (:meth:`~cvxid.spec.problem.ProblemSpec.with_data`, ``cvxid.run(spec, train=…)``)."""
    path = resolve_spec(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CvxidError(f"{path}: not valid TOML ({exc})") from None
    return parse_problem(raw, path.parent.resolve(), default_name=path.stem, data_required=data_required)


def parse_problem(raw: Table, folder: Path, default_name: str = "problem", data_required: bool = True) -> ProblemSpec:
    """The :class:`~cvxid.spec.problem.ProblemSpec` of one equation (``[model]`` or a
    single ``[[model.equation]]``) or of several; what reading it warned of is issued and
    kept in its ``notes`` (a run repeats it in its warnings)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CvxidWarning)
        if not is_joint(raw):
            spec = parse_single_problem(raw, folder, default_name, data_required)
        elif isinstance(equations := raw["model"].get("equation"), list) and len(equations) == 1:
            spec = parse_single_problem(single_equation_form(raw), folder, default_name, data_required)
        else:
            spec = parse_joint_problem(raw, folder, default_name, data_required)
    notes = tuple(dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, CvxidWarning)))
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return replace(spec, notes=notes) if notes else spec


def single_equation_form(raw: Table) -> dict:
    """A spec with one ``[[model.equation]]`` rewritten with ``[model]``: the equation's
    keys, the shared delay with the equation's ``delay_gain`` as its gain; likewise the
    truth's one ``[[truth.equation]]`` and per-coordinate initial states."""
    out = dict(raw)
    model = dict(raw["model"])
    (equation,) = model.pop("equation")
    if not isinstance(equation, Mapping):
        raise CvxidError("spec: [[model.equation]] must be a table")
    single = {k: v for k, v in equation.items() if k != "delay_gain"}
    if "tie" in model:  # columns of one equation print bare: "x:x'" is "x'"
        prefix = f"{single.get('coordinate', 'x')}:"
        single["tie"] = [{k: v.removeprefix(prefix) if k in ("left", "right") and isinstance(v, str) else v
                          for k, v in t.items()} if isinstance(t, Mapping) else t for t in model.pop("tie")]
    if "delay" in model:
        delay = dict(model.pop("delay"))
        if not isinstance(delay, Mapping):
            raise CvxidError("spec: [model.delay] must be a table")
        delay.setdefault("method", "exact")
        if "delay_gain" in equation:
            delay["gain"] = equation["delay_gain"]
        single["delay"] = delay
    if "input_delay" in model:  # the shared input's delay, where a coupled spec gives it
        if "input_delay" in single:
            raise CvxidError("spec: input_delay is given in [model] and in [[model.equation]]: give it once")
        single["input_delay"] = model.pop("input_delay")
    if model:
        raise CvxidError(f"spec: [model] key(s) {', '.join(sorted(model))} beside [[model.equation]]; move them into "
                         "the equation's table")
    out["model"] = single
    coordinate = single.get("coordinate", "x")
    if isinstance(raw.get("truth"), Mapping) and "equation" in raw["truth"]:
        out["truth"] = _single_truth(raw["truth"], str(single.get("input", "f")))
    if isinstance(raw.get("data"), Mapping):
        out["data"] = {k: _single_data(v, coordinate) for k, v in raw["data"].items()}
    return out


def _single_truth(truth: Table, model_input: str) -> dict:
    """The one ``[[truth.equation]]`` as ``[truth]``: driven by the model's input (a
    different one named is refused)."""
    truth = dict(truth)
    equations = truth.pop("equation")
    if not isinstance(equations, list) or len(equations) != 1 or not isinstance(equations[0], Mapping):
        raise CvxidError("spec: a one-equation model needs exactly one [[truth.equation]] table")
    (equation,) = equations
    if str(equation.get("input", model_input)) != model_input:
        raise CvxidError(f"spec: [[truth.equation]] input = '{equation['input']}' is not the model's input "
                         f"('{model_input}'): a one-equation truth is driven by the input its model reads; name "
                         "the same one")
    if "smoothing" in truth:
        raise CvxidError("spec: [truth] smoothing is for coupled specs; write the smoothed term in [truth] "
                         "coefficients instead")
    single = {k: v for k, v in equation.items() if k in ("mass", "coefficients")}
    unknown = set(equation) - {"coordinate", "mass", "coefficients", "delay_gain", "input"}
    if unknown:
        raise CvxidError(f"spec: [[truth.equation]] unknown key(s) {', '.join(sorted(unknown))}")
    if "delay" in truth:
        delay = dict(truth.pop("delay"))
        delay["gain"] = equation.get("delay_gain", 0.0)
        single["delay"] = delay
    return {**single, **truth}


def _single_data(section, coordinate: str):
    """Per-coordinate initial states ``x0 = { x = 0.3 }`` as plain numbers."""
    if not isinstance(section, Mapping) or not isinstance(section.get("simulate"), Mapping):
        return section
    simulate = dict(section["simulate"])
    for key in ("x0", "v0"):
        if isinstance(simulate.get(key), Mapping):
            simulate[key] = simulate[key].get(coordinate, 0.0)
    return {**section, "simulate": simulate}
