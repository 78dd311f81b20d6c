"""A user's terms as expressions (sin(theta), cos(theta) theta', tanh(50 x')): read
safely, the same numbers in the regression (numpy) and the simulation (compiled), printed
and in LaTeX, end to end through `cvxid run` with a spec's own diagnosis effect."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cvxid
from cvxid import CvxidError
from cvxid.app.cli import main
from cvxid.model.expression import parse_expression
from cvxid.model.terms import Derivative, Expression, FunctionTerm, Monomial, parse_term
from cvxid.simulate import System, simulate


@pytest.mark.parametrize("text, message", [
    ('__import__("os").system("ls")', "'__import__\\('os'\\).system\\('ls'\\)' is not allowed"),
    ('__import__("os")', "the function '__import__' is not allowed"),
    ("x.real", "'x.real' is not allowed"),
    ("x[0]", "'x\\[0\\]' is not allowed"),
    ("lambda: 1", "'lambda: 1' is not allowed"),
    ("log(x)", "the function 'log' is not allowed"),
    ("sin(y)", "the name 'y' is not allowed"),
    ("sin x", "the name 'sin' \\(a function needs parentheses\\)"),
    ("sin(x, x)", "sin with 2 arguments"),
    ("1e400 * x", "the constant inf"),
    ("x'' * x", "an acceleration"),
    ("sin(" * 80 + "x" + ")" * 80, "longer than 200 characters"),
    ("sin(x", "cannot read term 'sin\\(x' as an expression"),
])
def test_anything_but_the_grammar_is_refused_naming_it(text, message):
    with pytest.raises(CvxidError, match=message):
        parse_term(text, ("x",))


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet="x'()+-*/^ 0123456789.sincotahexpbgqrl_,[]{}\"", max_size=30))
def test_any_text_is_a_term_or_one_clear_error(text):
    try:
        term = parse_term(text, ("x",))
    except CvxidError as exc:
        assert str(exc)
    else:
        if not isinstance(term, Derivative):  # x'' and higher are regression columns, not functions of states
            states = {"x": np.linspace(-1, 1, 7), "x'": np.linspace(2, -2, 7)}
            assert np.shape(term.evaluate(states)) == (7,)


def test_the_program_computes_what_numpy_computes():
    x, v = np.linspace(-2, 2, 41), np.linspace(1, -3, 41)
    states = {"x": x, "x'": v}
    expected = {
        "sin(x)": np.sin(x),
        "cos(x) x'": np.cos(x) * v,
        "tanh(50 x')": np.tanh(50 * v),
        "exp(-x^2)": np.exp(-x ** 2),
        "abs(x)^1.5 - sqrt(abs(x')) / 2": np.abs(x) ** 1.5 - np.sqrt(np.abs(v)) / 2,
        "-(x + 1) * sign(x')": -(x + 1) * np.sign(v),
    }
    for text, value in expected.items():
        term = parse_term(text, ("x",))
        assert isinstance(term, Expression), text
        np.testing.assert_allclose(term.evaluate(states), value, rtol=1e-14, atol=1e-14, err_msg=text)
    assert isinstance(parse_term("x^2 x'", ("x",)), Monomial)  # products of powers stay monomials


@pytest.mark.parametrize("text, friction", [
    ("sign(x') * exp(-(x' / 0.05)^2)", True), ("exp(-(x' / 0.05)^2) * sign(x')", True), ("sign(x') * x^2", True),
    ("sign(x') * x * 2", False), ("sign(x') + x", False), ("sign(x') * sign(x)", False), ("sign(x) * x'", False)])
def test_a_sign_of_a_velocity_times_a_factor_is_read_as_a_friction(text, friction):
    """The integrator splits its steps where a friction's sliding stops: a term that is
    sign(q') times a factor holding no sign is one (its bound the factor); anything else is
    an expression evaluated as written."""
    signed = parse_expression(text, ("x",)).program.signed()
    assert (signed is not None) == friction
    if friction:
        factor = signed[1].evaluate([np.array([0.3])], [np.array([0.02])])
        whole = parse_expression(text, ("x",)).program.evaluate([np.array([0.3])], [np.array([0.02])])
        assert signed[0] == 0 and factor == pytest.approx(whole)  # (the sign is +1 at x' = 0.02)


def test_printed_latex_and_symbols():
    term = parse_term("cos(theta) theta'", ("theta",))
    assert term.name == "cos(theta) * theta'"
    assert term.latex == r"\cos\left(\theta\right) \dot{\theta}"
    assert term.symbols == {"theta", "theta'"} and term.needs_velocity
    assert parse_expression("(x + 1) * x", ("x",)).latex == r"\left(x + 1\right) x"
    assert parse_term(term.name, ("theta",)) == term  # the printed name reads back as the same term


def test_the_compiled_simulation_runs_an_expression_as_python_would():
    """A driven pendulum with sin(theta) and cos(theta) theta' in the compiled kernel, and
    the same terms as Python functions in the Python kernel: the same trajectory."""
    t = np.arange(4001) * 1e-3
    force = lambda s: 2 * np.sin(1.3 * s) + np.sin(4.1 * s)
    damping = parse_term("theta'", ("theta",))
    expressions = (parse_term("sin(theta)", ("theta",)), parse_term("cos(theta) theta'", ("theta",)))
    functions = (FunctionTerm("g", "", lambda s: np.sin(s["theta"]), frozenset({"theta"})),
                 FunctionTerm("h", "", lambda s: np.cos(s["theta"]) * s["theta'"], frozenset({"theta", "theta'"})))
    coefficients = np.array([0.3, 9.0, 0.2])
    compiled = simulate(System((damping, *expressions), coefficients, 1.0, "theta"), t, force, 2.5, 0.0)
    python = simulate(System((damping, *functions), coefficients, 1.0, "theta"), t, force, 2.5, 0.0)
    assert np.ptp(compiled[0]) > 3  # it swings over the top
    np.testing.assert_allclose(compiled[0], python[0], rtol=0, atol=1e-12)


PENDULUM = """name = "pendulum"
description = "theta'' + 0.3 theta' + 9 sin(theta) + 1.5 cos(theta) = u: the model lacks the unbalance"
[truth]
mass = 1.0
coefficients = { "theta'" = 0.3, "sin(theta)" = 9.0, "cos(theta)" = 1.5 }
[data.train.simulate]
duration = 10.0
dt = 1e-3
x0 = 0.5
seed = 1
noise = { output = 0.002, input = 0.0 }
input = [ { kind = "sine", amplitude = 6.0, omega = 2.1 }, { kind = "sine", amplitude = 4.0, omega = 3.3, phase = 1.0 } ]
[data.test.simulate]
duration = 10.0
dt = 1e-3
x0 = -0.3
seed = 2
noise = { output = 0.002, input = 0.0 }
input = [ { kind = "sine", amplitude = 5.0, omega = 2.6 }, { kind = "sine", amplitude = 4.0, omega = 1.4, phase = 1.0 } ]
[model]
coordinate = "theta"
input = "u"
[model.library]
terms = ["theta'", "sin(theta)"]
[model.names]
c = "theta'"
mgl = "sin(theta)"
[fit]
estimator = "lstsq"
[diagnose]
refine = true
[diagnose.effects]
unbalance = { term = "cos(theta)", meaning = "a mass off the vertical" }
"""


def test_a_pendulum_with_user_terms_and_its_own_effect_end_to_end(tmp_path):
    """`cvxid run`: sin(theta) estimated, the declared effect ranked first and added, the
    error falls; result.json, model.json (read back) and the python-control export agree
    (measured: every parameter within 0.03 %, test fit 100.0 %)."""
    (tmp_path / "pendulum.toml").write_text(PENDULUM)
    assert main(["run", str(tmp_path / "pendulum.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    truth = {"m": 1.0, "c": 0.3, "mgl": 9.0, "cos(theta)": 1.5}
    for name, value in truth.items():
        assert result["physical"][name] == pytest.approx(value, rel=2e-3), name
    steps = result["refinement"]
    assert [s["added"] for s in steps] == ["unbalance"]
    assert steps[0]["test_mse_after"] < 1e-4 * steps[0]["test_mse_before"]
    assert r"\sin\left(\theta\right)" in result["equation_latex"]
    model = cvxid.IdentifiedSystem.load(tmp_path / "out" / "model.json").single
    assert model.physical == pytest.approx(result["physical"])
    test = cvxid.load_problem(tmp_path / "pendulum.toml").experiment("test")
    assert cvxid.compare(model, test).fit_percent > 99.5
    import control

    t = np.linspace(0, 0.05, 6)
    response = control.input_output_response(model.to_control(), t, np.zeros_like(t), X0=[0.2, 0.0])
    acceleration = -(9.0 * np.sin(0.2) + 1.5 * np.cos(0.2))  # from rest at 0.2 rad
    assert np.ravel(response.outputs)[1] - 0.2 == pytest.approx(0.5 * acceleration * 0.01 ** 2, rel=0.02)


@pytest.mark.parametrize("effects, message", [
    ('coulomb = "sign(theta\')"', "effect 'coulomb' is in the catalogue already"),
    ('unbalance = "cos(phi)"', "the name 'phi' is not allowed"),
    ('unbalance = { term = "cos(theta)", sign = 1 }', r"unknown key"),
    ('unbalance = 3', "must be a table"),
])
def test_a_bad_declared_effect_is_a_clear_error(tmp_path, capsys, effects, message):
    from .conftest import cli_error

    text = PENDULUM.replace('unbalance = { term = "cos(theta)", meaning = "a mass off the vertical" }', effects)
    assert re_search(message, cli_error(tmp_path, capsys, text))


def re_search(pattern, text):
    import re

    return re.search(pattern, text) is not None


def test_a_division_by_zero_is_a_diverged_simulation_and_a_non_finite_column_an_error():
    """1/x at x = 0: the compiled kernel returned a ZeroDivisionError traceback before (numba's
    Python error model); now inf, a diverged simulation.  x^1.5 of a signal crossing 0: a
    regression column of NaN ended in an SVD failure; now an error naming the term."""
    from cvxid.model.equation import ModelSpec
    from cvxid.model.library import Library
    from cvxid.regression.builder import RegressionBuilder
    from cvxid.simulate import SimulationDiverged

    t = np.arange(2001) * 1e-3
    system = System((parse_term("x'"), parse_term("sin(x) / x")), np.array([0.3, 1.0]), 1.0, "x")
    with pytest.raises(SimulationDiverged, match="diverged at t = 0"):
        simulate(system, t, np.sin, 0.0, 0.0)
    record = cvxid.Experiment(t, {"x": np.sin(5 * t)}, {"f": np.cos(3 * t)})
    model = ModelSpec(Library([parse_term("x'"), parse_term("x^1.5")]))
    with pytest.raises(CvxidError, match=r"term 'x\^1.5' is not finite on these data .* e.g. abs\(x\)\^1.5"):
        RegressionBuilder(model, record, "savgol").at(None)
