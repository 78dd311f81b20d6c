"""A single equation is a system with N = 1: its spec may be written with ``[model]`` or
with one ``[[model.equation]]`` (the coupled format), and both give the same model."""

import numpy as np
import pytest

from cvxid.app.run import run
from cvxid.errors import CvxidError
from cvxid.spec.load import parse_problem
from cvxid.spec.problem import ProblemSpec

from .conftest import ROOT

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover
    import tomli as tomllib

DATA = """
[data.train.simulate]
duration = 4.0
dt = 2e-3
seed = 1
noise = { output = 0.001, input = 0.0 }
input = [{ kind = "sine", amplitude = 3.0, omega = 1.9 }, { kind = "sine", amplitude = 2.0, omega = 4.7 }]
[data.test.simulate]
duration = 4.0
dt = 2e-3
seed = 2
noise = { output = 0.001, input = 0.0 }
input = [{ kind = "sine", amplitude = 2.5, omega = 2.9 }, { kind = "sine", amplitude = 2.5, omega = 6.1 }]
[fit]
estimator = "lstsq"
"""

MODEL_FORM = """
[truth]
mass = 1.0
coefficients = { "x'" = 0.4, "x" = 6.0 }
delay = { signal = "x", gain = 1.5, tau = 0.15 }
[model]
library = { terms = ["x", "x'"] }
delay = { signal = "x", gain = 1.5, method = "exact", tau_max = 0.4 }
names = { k = "x", c = "x'" }
""" + DATA

EQUATION_FORM = """
[truth]
delay = { signal = "x", tau = 0.15 }
[[truth.equation]]
coordinate = "x"
mass = 1.0
coefficients = { "x'" = 0.4, "x" = 6.0 }
delay_gain = 1.5
[model]
delay = { signal = "x", method = "exact", tau_max = 0.4 }
[[model.equation]]
coordinate = "x"
library = { terms = ["x", "x'"] }
names = { k = "x", c = "x'" }
delay_gain = 1.5
""" + DATA


def _spec(text: str):
    return parse_problem(tomllib.loads(text), ROOT)


def test_one_equation_table_is_the_model_form():
    a, b = _spec(MODEL_FORM), _spec(EQUATION_FORM)
    assert isinstance(b, ProblemSpec) and repr(a.model) == repr(b.model)
    assert a.model.library.names == b.model.library.names and a.model.names == b.model.names
    np.testing.assert_array_equal(a.experiment("train").output("x"), b.experiment("train").output("x"))


def test_both_forms_identify_the_same_coefficients():
    a, b = run(_spec(MODEL_FORM)), run(_spec(EQUATION_FORM))
    assert a.model.coefficients == pytest.approx(b.model.coefficients, rel=1e-12)
    assert b.model.physical["k"] == pytest.approx(6.0, rel=0.01)
    assert b.model.physical["tau"] == pytest.approx(0.15, rel=0.02)


def test_keys_beside_the_equation_are_named():
    with pytest.raises(CvxidError, match="library"):
        _spec(EQUATION_FORM.replace("[model]\n", "[model]\nlibrary = { terms = [\"x\"] }\n"))


TIED = """
[truth]
mass = 1.0
coefficients = { "x'" = 0.4, "x" = 6.0, "x^3" = 3.0 }
delay = { signal = "x", gain = 1.5, tau = 0.15 }
[model]
library = { terms = ["x", "x'", "x^3"] }
delay = { signal = "x", gain = 1.5, method = "exact", tau_max = 0.4 }
names = { k = "x", k3 = "x^3" }
[[model.tie]]
left = "x^3"
right = "x"
factor = 0.5
""" + DATA.replace('amplitude = 3.0', 'amplitude = 5.0')


def test_ties_between_two_coefficients_of_one_equation():
    result = run(_spec(TIED))
    coefficients = result.model.coefficients
    assert coefficients["x^3"] == pytest.approx(0.5 * coefficients["x"], rel=1e-9)
    assert result.model.physical["k"] == pytest.approx(6.0, rel=0.01)
    # the equation-error delay of a 4 s record (measured: -2.1 %; the polish is not asked for)
    assert result.to_dict()["tau"]["estimate"] == pytest.approx(0.15, rel=0.03)


def test_a_tie_in_the_equation_form_names_its_columns_like_the_coupled_format():
    text = EQUATION_FORM.replace("[data.train.simulate]", '[[model.tie]]\nleft = "x:x\'"\nright = "x:x"\nfactor = 0.1\n'
                                 "[data.train.simulate]", 1)
    spec = _spec(text)
    assert spec.system.ties == (("x'", "x", 0.1),)


@pytest.mark.parametrize("tie, message", [
    ({"left": "x^5", "right": "x"}, r"'x\^5' is not a column; columns are written as the terms"),
    ({"left": "x", "right": "x"}, "ties 'x' to itself"),
    ({"left": "x^3", "right": "x", "factor": 0.0}, "factor = 0 forces 'x\\^3' to 0"),
])
def test_bad_ties_in_one_equation_are_named(tie, message):
    raw = tomllib.loads(TIED)
    raw["model"]["tie"] = [tie]
    with pytest.raises(CvxidError, match=message):
        parse_problem(raw, ROOT)


def test_a_tie_whose_columns_the_lasso_drops_holds_at_zero():
    """At a large lambda the lasso drops both tied columns: the tie holds at zero (it used
    to end in a KeyError inside the refit)."""
    raw = tomllib.loads(TIED)
    raw["fit"] = {"estimator": "lasso", "lambdas": {"min": 10.0, "max": 100.0, "count": 3}}
    result = run(parse_problem(raw, ROOT))
    coefficients = result.model.coefficients
    assert coefficients["x^3"] == pytest.approx(0.5 * coefficients["x"], abs=1e-12)


def test_a_tie_in_one_equation_holds_through_the_order_search():
    """A tie in one equation with [fit] orders (it was refused): every order's fit keeps
    it, and so does the model at the chosen order."""
    raw = tomllib.loads(TIED)
    raw["model"]["library"] = {"order": 3, "cross": False}
    raw["fit"] = {"estimator": "lasso", "orders": {"min": 3, "max": 4}, "lambdas": {"min": 1e-6, "max": 1.0,
                                                                                     "count": 8}}
    result = run(parse_problem(raw, ROOT))
    for coefficients in result.order_search.coefficients.values():
        assert coefficients["x^3"] == pytest.approx(0.5 * coefficients["x"], rel=1e-9, abs=1e-12)
    coefficients = result.model.coefficients
    assert coefficients["x^3"] == pytest.approx(0.5 * coefficients["x"], rel=1e-9)
    assert result.model.physical["k"] == pytest.approx(6.0, rel=0.02)


def test_a_tie_in_one_equation_holds_through_the_diagnosis():
    """A tie with [diagnose] (it was refused): the hidden friction is named and added, and
    the tied coefficients keep their ratio in the final model."""
    raw = tomllib.loads(TIED)
    raw["truth"]["coefficients"]["sign(x')"] = 0.5
    raw["diagnose"] = {"refine": True}
    result = run(parse_problem(raw, ROOT))
    assert [s.added for s in result.refinement.steps] == ["coulomb"]
    coefficients = result.model.coefficients
    assert coefficients["x^3"] == pytest.approx(0.5 * coefficients["x"], rel=1e-9)
    assert coefficients["sign(x')"] == pytest.approx(0.5, rel=0.02)  # (measured +0.3 %)


def test_a_tie_in_one_equation_holds_through_the_stepwise_search():
    """A tie with estimator = "stepwise_oe" (it was refused): the search adds x^3 to x and
    x' and nothing else, and x^3 stays half of x."""
    raw = tomllib.loads(TIED)
    raw["model"]["library"] = {"terms": ["x", "x'", "x^3", "x^2", "x'^3"], "select": True}
    raw["fit"] = {"estimator": "stepwise_oe"}
    result = run(parse_problem(raw, ROOT))
    coefficients = result.model.coefficients
    assert {n for n, c in coefficients.items() if c != 0} == {"x''", "x", "x'", "x^3"}
    assert coefficients["x^3"] == pytest.approx(0.5 * coefficients["x"], rel=1e-9)
    assert result.model.physical["k"] == pytest.approx(6.0, rel=0.01)


def test_the_one_equation_form_takes_its_input_delay_where_a_coupled_spec_gives_it():
    """[model] input_delay beside one [[model.equation]] (a coupled spec's place for the
    shared input's delay; it was refused for N = 1), but not in both places."""
    raw = tomllib.loads(EQUATION_FORM)
    raw["model"]["input_delay"] = {"tau_max": 0.1}
    assert parse_problem(raw, ROOT).model.input_delay.tau_max == 0.1
    raw["model"]["equation"][0]["input_delay"] = 0.1
    with pytest.raises(CvxidError, match=r"input_delay is given in \[model\] and in \[\[model.equation\]\]"):
        parse_problem(raw, ROOT)


def test_a_chain_of_ties_holds_through_the_output_error_polish():
    """Review: x^3 = 0.5 x and x = 15 x' (a chain) ended in a KeyError inside the polish, and
    two ties of one left column broke one of them.  The spec gives every chain as a star
    (each column a multiple of the chain's last), and the polish follows chains given
    through the Python API; both ratios hold."""
    from dataclasses import replace as _replace

    from cvxid.model.system import SystemSpec

    raw = tomllib.loads(TIED)
    raw["model"]["tie"] = [{"left": "x^3", "right": "x", "factor": 0.5}, {"left": "x", "right": "x'", "factor": 15.0}]
    raw["fit"] = {"estimator": "lstsq", "refine": "output_error"}
    spec = parse_problem(raw, ROOT)
    assert spec.system.ties == (("x^3", "x'", 7.5), ("x", "x'", 15.0))
    chained = _replace(spec, system=SystemSpec(spec.system.equations, (("x^3", "x", 0.5), ("x", "x'", 15.0))))
    for s in (chained, spec):  # (the spec's last: its result's ties are read below)
        result = run(s)
        coefficients = result.model.coefficients
        assert coefficients["x^3"] == pytest.approx(0.5 * coefficients["x"], rel=1e-9)
        assert coefficients["x"] == pytest.approx(15.0 * coefficients["x'"], rel=1e-9)
    # a seventh outside check: the ties were in model.json only, not the printout or result.json
    assert "  tie: x^3 = 7.5 x'\n  tie: x = 15 x'\n" in result.summary()
    assert result.to_dict()["ties"] == [{"left": "x^3", "right": "x'", "factor": 7.5},
                                        {"left": "x", "right": "x'", "factor": 15.0}]


def test_a_one_equation_truth_driven_by_another_input_is_refused():
    raw = tomllib.loads(EQUATION_FORM)
    raw["truth"]["equation"][0]["input"] = "-f"
    with pytest.raises(CvxidError, match=r"\[\[truth.equation\]\] input = '-f' is not the model's input \('f'\)"):
        parse_problem(raw, ROOT)


def test_a_selection_with_least_squares_is_refused_for_one_equation_too():
    raw = tomllib.loads(TIED)
    raw["model"]["library"] = {"terms": ["x", "x'", "x^3"], "select": True}
    with pytest.raises(CvxidError, match=r'\[model.library\] has select = true.*estimator = "lstsq" selects nothing'):
        parse_problem(raw, ROOT)


@pytest.mark.parametrize("candidate", ["delay(x)", "input_delay(x)"])
def test_the_systems_delays_are_not_one_coordinates(candidate):
    """Review: "delay(x)" passed the spec and crashed the run (a DelayedSignal term)."""
    raw = tomllib.loads(EQUATION_FORM)
    raw["diagnose"] = {"candidates": [candidate]}
    with pytest.raises(CvxidError, match="the delay and the input's delay are the system's"):
        parse_problem(raw, ROOT)
