"""The bad-input table (docs/bad-input.md), row by row (rows already covered elsewhere are named)."""

import re
from dataclasses import replace
import warnings

import cvxpy as cp
import numpy as np
import pandas as pd
import pytest

from cvxid import CvxidError, CvxidWarning, Experiment, Problem, SolverFailure
from cvxid.model.equation import ModelSpec
from cvxid.model.library import Library
from cvxid.model.terms import parse_term
from cvxid.regression.builder import RegressionBuilder
from cvxid.regression.regression import Regression

from .conftest import cli_error
from .test_sensor import SPEC as SENSOR_SPEC

T = np.arange(500) * 0.01
MODEL = ModelSpec(Library([parse_term("x"), parse_term("x'")]))

# NaN/inf, unequal lengths, non-increasing/non-uniform time: tests/test_data.py
# a record shorter than the delay: tests/test_delay.py::test_record_shorter_than_the_delay_is_refused
# unknown solver or term name: tests/test_problem.py, tests/test_pipeline.py
# a solver that stops early: tests/test_problem.py::test_solver_that_stops_early_is_an_error_not_zeros
# a diverging simulation: tests/test_simulate.py, tests/test_diagnostics.py
# a corrupted JSON model: tests/test_identified.py


def test_constant_input_is_refused():
    e = Experiment(T, {"x": np.sin(T)}, {"f": np.full(T.size, 2.0)})
    with pytest.raises(CvxidError, match="input 'f' is constant"):
        RegressionBuilder(MODEL, e, "savgol")
    # a free decay (a twelfth outside check's plucked structure): the message says what a decay cannot give
    with pytest.raises(CvxidError, match=r"A free decay \(no force\) cannot be identified.*two numbers"):
        RegressionBuilder(MODEL, Experiment(T, {"x": np.exp(-T) * np.sin(T)}, {"f": np.zeros(T.size)}), "savgol")


def test_rank_deficient_library_is_named():
    P = np.column_stack([np.sin(T), np.cos(T), np.sin(T) + 2 * np.cos(T)])
    reg = Regression(P, np.sin(T) + 0.1 * np.cos(T), ("a", "b", "c"), ("library",) * 3, np.ones(3))
    with pytest.warns(CvxidWarning, match=r"rank-deficient: column\(s\) c"):
        reg.reduce()


def test_a_failing_solver_falls_back_to_the_next_installed_one_and_says_so(monkeypatch):
    # signs and ties are homogeneous (all zero satisfies them), so an "infeasible" status
    # can only be the solver failing: the next installed solver answers, and a warning names both
    prob = Problem.from_arrays(np.column_stack([np.sin(T), T]), np.cos(T), ["a", "b"], nonnegative=["a"])
    reference = prob.solve(0.1)
    attempt = Problem._attempt

    def clarabel_fails(self, solver, settings):
        if solver == "CLARABEL":
            self.cvxpy._status = cp.INFEASIBLE
            return None
        return attempt(self, solver, settings)

    monkeypatch.setattr(Problem, "_attempt", clarabel_fails)
    with pytest.warns(CvxidWarning, match=r"CLARABEL: it reported the constraints \(c\[a\] >= 0\) infeasible.*"
                                          r"OSQP answered instead"):
        fit = prob.solve(0.1)
    assert fit.solver == "OSQP"
    assert fit.coefficients == pytest.approx(reference.coefficients, rel=1e-4, abs=1e-6)


def test_when_every_solver_fails_the_error_names_each_and_reports_no_numbers(monkeypatch):
    prob = Problem.from_arrays(np.column_stack([np.sin(T), T]), np.cos(T), ["a", "b"], nonnegative=["a"])
    monkeypatch.setattr(Problem, "_attempt", lambda self, solver, settings: f"{solver.lower()} crashed")
    with pytest.raises(SolverFailure, match=r"no solver answered at lambda = 0.1 \(CLARABEL: clarabel crashed; "
                                            r"OSQP: osqp crashed; SCS: scs crashed\); no solution is reported"):
        prob.solve(0.1)


def test_identically_zero_target_is_named():
    reg = Regression(np.column_stack([np.sin(T), np.cos(T)]), np.zeros(T.size), ("a", "b"), ("library",) * 2,
                     np.ones(2))
    with pytest.raises(CvxidError, match="target is identically zero: the input carries no signal"):
        reg.reduce()


@pytest.mark.parametrize(
    "text, message",
    [
        ("[model]\n[data.train.simulate]\nduration = 1e9\ndt = 1e-9\ninput = []\n[truth]\n",
         "duration = 1000000000.0 is out of range"),
        ("[model]\n[data.train.simulate]\nduration = 1e5\ndt = 1e-3\ninput = []\n[truth]\n", "samples; use between"),
        ("[model]\n[data.train]\nfile = '/etc/passwd'\n", "unknown data format"),
        ("[model]\n[data.train]\nfile = 'x.csv'\n[fit]\nlambdas = { min = 1, max = 0.1 }\n", "larger than max"),
        ("[model.library]\norder = 'three'\n[data.train]\nfile = 'x.csv'\n", "must be a number"),
        ('[model]\n[data.train]\nfile = "x.csv"\n[data.test]\nfile = "x.csv"\n[diagnose]\ncandidates = ["os.system"]\n',
         "'os.system' is not allowed"),
        # outside check, 2026-11-25: each was accepted, and gave a wrong model or did nothing, silently
        ("[model]\ninertia = false\n[data.train]\nfile = 'x.csv'\n", r"inertia = false needs the known mass: add mass"),
        ("[model]\nmass = 0.3\n[data.train]\nfile = 'x.csv'\n", r"mass is the known mass of inertia = false; remove"),
        ("[model.library]\norder = 3\nterms = ['x']\n[data.train]\nfile = 'x.csv'\n",
         r"gives terms and order: a terms list, or an order's polynomial library"),
        ("[model.library]\nterms = []\n[data.train]\nfile = 'x.csv'\n", r"terms is empty: list the terms"),
        ("[model]\n[data.train]\nfile = 'x.csv'\n[diagnose]\nrefine = true\n",
         r"\[diagnose\] compares the models on a test record: add \[data.test\]"),
        # outside check, 2026-11-26: each error named a term, not the field
        ("[model]\ncoordinate = 'x y'\n[data.train]\nfile = 'x.csv'\n",
         r"\[model\] coordinate = 'x y' is not a name: use letters, digits and _"),
        ("[model.library]\nterms = ['x', \"x''\"]\n[data.train]\nfile = 'x.csv'\n",
         r"\[model.library\] terms lists x'', the inertia: it is always in the model"),
        ("[model.library]\nterms = ['x', \"x'\", ' x']\n[data.train]\nfile = 'x.csv'\n",
         r"\[model.library\] terms lists x twice \(as written: 'x', ' x'\); list each term once"),
    ],
)
def test_hostile_or_malformed_specs_exit_2(tmp_path, capsys, text, message):
    err = cli_error(tmp_path, capsys, text)
    assert re.search(message, err), err


def test_the_tied_refit_falls_back_too_and_fails_only_when_every_solver_does(monkeypatch):
    import cvxid.identify.problem as problem_module

    P = np.column_stack([np.sin(T), np.cos(T), T])
    prob = Problem.from_arrays(P, np.sin(T) + 0.5 * np.cos(T), ["a", "b", "c"], ties=[("a", "b", 2.0)])
    reference = prob.refit(np.ones(3, bool)).coefficients
    monkeypatch.setattr(problem_module, "_tied_bounded_least_squares", lambda *a: None)  # the cvxpy path
    solve = cp.Problem.solve

    def clarabel_infeasible(self, *args, solver=None, **kwargs):
        if solver == "CLARABEL":
            self._status = cp.INFEASIBLE
            return None
        return solve(self, *args, solver=solver, **kwargs)

    monkeypatch.setattr(cp.Problem, "solve", clarabel_infeasible)
    with pytest.warns(CvxidWarning, match=r"tied least-squares refit: CLARABEL: status 'infeasible' \(infeasible, "
                                          r"though all zero .*\); OSQP answered instead"):
        fit = prob.refit(np.ones(3, bool))
    assert fit.coefficients == pytest.approx(reference, rel=1e-4, abs=1e-6)
    assert fit.coefficients[0] == pytest.approx(2.0 * fit.coefficients[1], rel=1e-6)
    monkeypatch.setattr(problem_module, "_installed", lambda: frozenset({"CLARABEL"}))
    with pytest.raises(SolverFailure, match="the tied least-squares refit failed with every solver"):
        prob.refit(np.ones(3, bool))


@pytest.mark.parametrize("scale", [1e300, 1e-310])
def test_absurd_magnitudes_are_an_error_that_says_rescale(scale):
    with pytest.raises(CvxidError, match=r"signal 'output x' reaches .* in magnitude.*rescale it \(other units\)"):
        Experiment(T, {"x": np.sin(T) * scale}, {"f": np.cos(T)})
    assert Experiment(T, {"x": np.sin(T) * 1e-6}, {"f": np.cos(T)}).output("x").max() > 0  # small units are fine


IMPLAUSIBLE = """name = "implausible"
[data.train]
file = "train.csv"
input = {{ f = "{force}" }}
[model.library]
{library}
[fit]
estimator = "{estimator}"
"""


@pytest.mark.parametrize("case", ["negative inertia", "no term kept"])
def test_an_implausible_model_is_a_warning(tmp_path, rng, case):
    """A force of the wrong sign gives a negative mass; an output that the input does not
    drive (white noise) leaves the lasso no term: each is said in result.json, not reported
    silently."""
    import json

    from cvxid.app.cli import main
    from cvxid.simulate import System, simulate

    t = np.arange(6000) * 1e-3
    force = lambda s: 3 * np.sin(2.1 * s) + 2 * np.sin(5.3 * s + 1)
    x, _ = simulate(System((parse_term("x'"), parse_term("x")), np.array([0.5, 6.0]), 1.0, "x"), t, force, 0.3, 0.0)
    unrelated = rng.standard_normal(t.size)
    measured = x + 1e-3 * rng.standard_normal(t.size) if case == "negative inertia" else 0.1 * unrelated
    columns = np.column_stack([t, measured, force(t), -force(t)])
    np.savetxt(tmp_path / "train.csv", columns, delimiter=",", header="t,x,f,minus_f", comments="")
    if case == "negative inertia":
        text = IMPLAUSIBLE.format(force="minus_f", library='terms = ["x", "x\'"]', estimator="lstsq")
        said = "the identified inertia is -1, negative"
    else:
        text = IMPLAUSIBLE.format(force="f", library="order = 2", estimator="lasso")
        said = "the selection dropped every candidate term"
    (tmp_path / "spec.toml").write_text(text)
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    warnings = json.loads((tmp_path / "out" / "result.json").read_text())["warnings"]
    assert any(said in w for w in warnings), warnings


def test_a_linear_system_whose_selection_keeps_no_candidate_is_not_a_warning(tmp_path):
    """A linear oscillator (30 s of ``cvxid bench --long``'s) with an order-3 library and
    the defaults but 2 s windows: the kept x and x' explain it and the adaptive lasso
    rightly keeps no candidate, lambda at the top of its grid; that is the answer, not 'the
    model is likely missing an effect' (which an outside check saw on linear systems).
    (The automatic windows, 1.875 s since the spectra's resolution follows the record, keep
    five candidates below 1e-3 on this record: the 1se rule flips between windows of 1.8 and
    2 s, docs/limitations.md.)"""
    import json

    from cvxid.app.cli import main
    from cvxid.tools.long_record import SPEC, write_record

    write_record(tmp_path / "record.csv", 30_000)
    (tmp_path / "spec.toml").write_text(SPEC.format(window="2.0"))
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["support"] == ["x''", "x", "x'"] and result["lambda"] == 100.0
    assert not any("dropped every candidate" in w for w in result["warnings"]), result["warnings"]


def test_a_build_larger_than_the_memory_available_is_refused_before_any_work(monkeypatch):
    """1e5 samples on whole-record integrals of 16 columns: about 0.47 GB (measured 96 bytes
    per sample and column); with 0.4 GB available it is refused naming both figures and the
    fix, while windows (60 bytes per sample: 0.31 GB) fit, and allow_large tries anyway."""
    import cvxid.regression.memory as memory

    monkeypatch.setattr(memory, "available_bytes", lambda: 0.4e9)
    t = np.arange(100_000) * 1e-3
    record = Experiment(t, {"x": np.sin(t) + 0.1 * np.sin(7 * t)}, {"f": np.cos(t)})
    model = ModelSpec(Library.polynomial(3, True, "x"))
    with pytest.raises(CvxidError, match=r"100,000 samples on whole-record integrals of 16 columns need about "
                                         r"0.5 GB of memory and 0.4 GB is available: use windows"):
        RegressionBuilder(model, record, "savgol", window="record")
    assert RegressionBuilder(model, record, "savgol", window="auto").window is not None
    assert RegressionBuilder(model, record, "savgol", window="record", allow_large=True).window is None


def test_a_term_the_data_do_not_show_is_named_after_the_polish(tmp_path):
    """x^2 listed for a linear oscillator: its output-error 95 % interval contains 0 and the
    run says so; the true terms are not named."""
    import json

    from cvxid.app.cli import main

    from .conftest import TEST_SIMULATED, TRAIN_SIMULATED

    text = ('name = "spurious"\n[truth]\nmass = 1.0\ncoefficients = { "x\'" = 0.4, "x" = 6.0 }\n'
            + TRAIN_SIMULATED + "\n" + TEST_SIMULATED
            + '\n[model.library]\nterms = ["x", "x\'", "x^2"]\n[fit]\nestimator = "lstsq"\nrefine = "output_error"\n')
    (tmp_path / "spec.toml").write_text(text)
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    warnings = json.loads((tmp_path / "out" / "result.json").read_text())["warnings"]
    said = [w for w in warnings if "the training record does not determine" in w]
    assert len(said) == 1 and "x^2 (" in said[0] and "x (" not in said[0] and "x' (" not in said[0], warnings


def test_a_listed_term_held_at_its_sign_bound_is_named(tmp_path):
    """An eleventh outside check: sign(x') listed with a sign constraint, the data asking
    for none, came back 0 with '–' and a footnote saying it was given in the spec.  Here
    the record's 'friction' pushes (-0.3 sign(x')): the term is held at 0, and the run says
    which term and why; the other terms are estimated (k within 2 % of 6)."""
    import json

    from cvxid.app.cli import main

    from .conftest import TEST_SIMULATED, TRAIN_SIMULATED

    text = ('name = "held"\n[truth]\nmass = 1.0\ncoefficients = { "x\'" = 0.8, "x" = 6.0, "sign(x\')" = -0.3 }\n'
            + TRAIN_SIMULATED + "\n" + TEST_SIMULATED + '\n[model.library]\nterms = ["x", "x\'", "sign(x\')"]\n'
            '[model.constraints]\nnonnegative = ["x\'\'", "sign(x\')"]\n[fit]\nestimator = "lstsq"\n')
    (tmp_path / "spec.toml").write_text(text)
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    said = [w for w in result["warnings"] if "listed in the spec, is 0: held at its sign constraint's bound" in w]
    assert result["coefficients"]["sign(x')"] == 0.0 and said and said[0].startswith("sign(x')"), result["warnings"]
    assert abs(result["coefficients"]["x"] / 6.0 - 1) < 0.02, result["coefficients"]


def test_a_constant_output_is_refused():
    """A record whose output never moves (a wrong column, a dead sensor) holds nothing to
    identify: an error, not a model with an inertia of 1e24."""
    e = Experiment(T, {"x": np.full(T.size, 0.3)}, {"f": np.sin(T)})
    with pytest.raises(CvxidError, match="output 'x' is constant, so the record holds no motion"):
        RegressionBuilder(MODEL, e, "savgol")


def test_one_column_as_output_and_input_is_refused(tmp_path):
    from cvxid.data.experiment import load

    np.savetxt(tmp_path / "r.csv", np.column_stack([T, np.sin(T), np.cos(T)]), delimiter=",", header="t,x,f",
               comments="")
    with pytest.raises(CvxidError, match="column 'x' is both a measured output and an input"):
        load(tmp_path / "r.csv", "t", {"x": "x"}, {"f": "x"})


def test_the_time_column_as_a_signal_is_refused(tmp_path):
    """Outside check: output = "t" ran to a mass of 9e13 and a fit of 0.4 %, exit 0."""
    from cvxid.data.experiment import load

    np.savetxt(tmp_path / "r.csv", np.column_stack([T, np.sin(T), np.cos(T)]), delimiter=",", header="t,x,f",
               comments="")
    with pytest.raises(CvxidError, match="column 't' is both the time and a measured output"):
        load(tmp_path / "r.csv", "t", {"x": "t"}, {"f": "f"})


def test_a_misspelt_velocity_estimator_lists_the_estimators(tmp_path, capsys, rng):
    _delayed_record(tmp_path, rng)
    err = cli_error(tmp_path, capsys, DELAYED.format(tau_max=0.3).replace('estimator = "lstsq"', 'velocity = "savgool"'))
    assert "[fit] velocity 'savgool' is neither an estimator (observer, savgol, spline" in err, err


def test_a_misspelt_velocity_estimator_on_simulated_data_is_an_error(tmp_path, capsys):
    """It used to read the simulator's own velocity, silently (a velocity that is not an
    estimator names a measured column, and a simulation measures it)."""
    from .conftest import TRAIN_SIMULATED

    err = cli_error(tmp_path, capsys, 'name = "v"\n[truth]\nmass = 1.0\ncoefficients = { "x\'" = 0.4, "x" = 6.0 }\n'
                    + TRAIN_SIMULATED + '\n[model.library]\nterms = ["x", "x\'"]\n[fit]\nvelocity = "savgool"\n')
    assert "[fit] velocity 'savgool' is neither an estimator" in err and "[data.train] is simulated" in err, err


def test_load_takes_a_column_name_or_a_list_and_names_a_wrong_argument(tmp_path):
    from cvxid.data.experiment import load

    np.savetxt(tmp_path / "r.csv", np.column_stack([T, np.sin(T), np.cos(T)]), delimiter=",", header="t,x,f",
               comments="")
    by_name = load(tmp_path / "r.csv", "t", "x", ["f"])
    by_mapping = load(tmp_path / "r.csv", "t", {"x": "x"}, {"f": "f"})
    assert np.array_equal(by_name.output("x"), by_mapping.output("x"))
    assert np.array_equal(by_name.input("f"), np.cos(T))
    with pytest.raises(CvxidError, match=r"outputs names the file's columns: a column name \('x'\), a list"):
        load(tmp_path / "r.csv", "t", 3, "f")
    np.savetxt(tmp_path / "v.csv", np.column_stack([T, np.sin(T), np.cos(T), np.cos(T)]), delimiter=",",
               header="t,x,f,v", comments="")
    measured = load(tmp_path / "v.csv", "t", "x", "f", velocities="v")  # a velocity column is the output's
    assert np.array_equal(measured.velocities["x"], np.cos(T))
    with pytest.raises(CvxidError, match=r"'x' is both a measured output and a measured velocity"):
        load(tmp_path / "v.csv", "t", "x", "f", velocities="x")
    with pytest.raises(CvxidError, match=r"velocities names one measured velocity column per output \(x\)"):
        load(tmp_path / "v.csv", "t", "x", "f", velocities=["v", "f"])


DELAYED = """name = "delayed"
[data.train]
file = "train.csv"
[model.library]
terms = ["x", "x'"]
[model.delay]
signal = "x"
gain = 2.0
method = "exact"
tau_max = {tau_max}
[fit]
estimator = "lstsq"
refine = "output_error"
"""


def _delayed_record(tmp_path, rng, tau: float = 0.15, dt: float = 1e-3):
    """x'' + 0.8 x' + 9 x = f + 2 x(t - tau), 6 s, noise 0.001, written as train.csv."""
    from cvxid.simulate import System, simulate

    t = np.arange(6000) * 1e-3
    force = lambda s: 4 * np.sin(2.3 * s) + 3 * np.sin(6.1 * s + 1)  # noqa: E731
    system = System((parse_term("x'"), parse_term("x")), np.array([0.8, 9.0]), 1.0, "x", gain=2.0, tau=tau)
    x, _ = simulate(system, t, force, 0.0, 0.0)
    x = x + 1e-3 * rng.standard_normal(t.size)
    np.savetxt(tmp_path / "train.csv", np.column_stack([t * dt / 1e-3, x, force(t)]), delimiter=",",
               header="t,x,f", comments="")


@pytest.mark.parametrize("tau, bounds, said", [
    (0.15, "tau_max = 0.1", "reaches the top of its search range (tau_max = 0.1 s): the true delay may be longer; "
                            "raise"),
    (0.15, "tau_max = 0.151", "reaches the top of its search range (tau_max = 0.151 s): the true delay may be longer; "
                              "raise"),  # (an estimate under the top, its interval reaching it)
    (0.15, "tau_min = 0.2\ntau_max = 0.4", "at the bottom of its search range (tau_min = 0.2 s): the true delay "
                                          "may be shorter; lower"),
    (0.0, "tau_max = 0.3", "is at 0, the bottom of its search range: the data show no delay, or another term "
                           "stands in for it"),
    (0.15, "tau_max = 0.3", None),
])
def test_a_delay_at_an_end_of_its_range_is_a_warning(tmp_path, rng, tau, bounds, said):
    """The true delay 0.15 s searched up to 0.1 s, or from 0.2 s; searched up to 0.151 s,
    where the estimate falls short of the top and its interval reaches it (an outside
    check: 0.4934 in [0, 0.5] with the interval at 0.5, for a truth of 2 s, said nothing);
    a loop closed at once (gain known); and, as a control, 0.15 s searched over [0, 0.3]:
    only the control is silent."""
    import json

    from cvxid.app.cli import main

    _delayed_record(tmp_path, rng, tau=tau)
    (tmp_path / "spec.toml").write_text(DELAYED.format(tau_max=0.3).replace("tau_max = 0.3", bounds))
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    warnings = [w for w in json.loads((tmp_path / "out" / "result.json").read_text())["warnings"]
                if "search range" in w]
    assert (warnings and said in warnings[0]) if said else not warnings, warnings


def test_a_given_gain_of_the_wrong_sign_is_named_beside_a_delay_at_0(tmp_path, rng):
    """A twelfth outside check: the gain given as -3 for +3 sent the delay to 0 (the
    stiffness absorbing the feedback) and the warning named a damping standing in, not the
    given gain; now it names the gain and how to check it."""
    import json

    from cvxid.app.cli import main

    _delayed_record(tmp_path, rng, tau=0.15)
    (tmp_path / "spec.toml").write_text(DELAYED.format(tau_max=0.3).replace("gain = 2.0", "gain = -2.0"))
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    said = [w for w in result["warnings"] if "is at 0, the bottom" in w]
    assert result["tau"]["estimate"] < 0.01 and said, result["warnings"]
    assert "The gain is given (-2): a given gain of the wrong sign or size" in said[0]


def _dead_zone_record(path, seed: int = 41):
    """An effect outside the catalogue (an eleventh outside check): ``x'' + 0.4 x' + 6 x =
    f + 3 D(x(t - 0.15))``, D a dead zone of half-width 0.4 on the fed-back signal, from a
    zero history, its 10 s from t = 5 s sampled at 500 Hz, noise 0.01 on x and f.  Our own
    RK4 (a step of 1 ms, the delayed signal by cubic Hermite between the steps), not cvxid's."""
    rng = np.random.default_rng(seed)
    freqs, phases = np.sort(rng.uniform(0.1, 3.0, 12)), rng.uniform(0, 2 * np.pi, 12)
    force = lambda s: 2.5 * np.sin(2 * np.pi * freqs * s + phases).sum()  # noqa: E731
    h, lag, steps = 1e-3, 150, 15000  # (the delay: 150 steps)
    x, v = np.zeros(steps + 1), np.zeros(steps + 1)

    def delayed(k, c):  # x at step k + c - lag, zero before the start, by Hermite between its steps
        j = k - lag
        if j < 0:
            return 0.0
        h00, h10, h01, h11 = 2 * c**3 - 3 * c**2 + 1, c**3 - 2 * c**2 + c, 3 * c**2 - 2 * c**3, c**3 - c**2
        return h00 * x[j] + h10 * h * v[j] + h01 * x[j + 1] + h11 * h * v[j + 1]

    def accel(k, c, xs, vs):
        q = delayed(k, c)
        return force((k + c) * h) - 0.4 * vs - 6 * xs + 3 * np.sign(q) * max(abs(q) - 0.4, 0.0)

    for k in range(steps):
        a1 = accel(k, 0.0, x[k], v[k])
        a2 = accel(k, 0.5, x[k] + h / 2 * v[k], v[k] + h / 2 * a1)
        a3 = accel(k, 0.5, x[k] + h / 2 * (v[k] + h / 2 * a1), v[k] + h / 2 * a2)
        a4 = accel(k, 1.0, x[k] + h * (v[k] + h / 2 * a2), v[k] + h * a3)
        x[k + 1] = x[k] + h * v[k] + h * h / 6 * (a1 + a2 + a3)
        v[k + 1] = v[k] + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
    keep = np.arange(5000, steps + 1, 2)
    t = keep * h
    f = np.array([force(s) for s in t])
    np.savetxt(path, np.column_stack([t - t[0], x[keep] + 0.01 * rng.standard_normal(t.size),
                                      f + 0.01 * rng.standard_normal(t.size)]), delimiter=",", header="t,x,f",
               comments="")


def test_a_delay_at_the_top_of_its_range_beside_an_undetermined_gain_is_said(tmp_path):
    """An eleventh outside check: a dead zone on the fed-back signal (no effect of the
    catalogue) came back from the documented new-user path (``cvxid init``, then ``cvxid
    run``) with the delay at the top of its range, 0.5 s for 0.15, its interval [0.13, 0.5]
    missing the truth, and only the gain's warning (the gain trades with the stiffness);
    a delay on the bound of its range is now said to be the bound, not a measured delay."""
    import json

    from cvxid.app.cli import main

    _dead_zone_record(tmp_path / "rig.csv")
    assert main(["init", str(tmp_path / "rig.csv"), "-o", str(tmp_path / "rig.toml")]) == 0
    assert main(["run", str(tmp_path / "rig.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["tau"]["estimate"] >= 0.45, result["tau"]
    said = [w for w in result["warnings"] if "top of its search range (tau_max = 0.5 s)" in w]
    assert said and "that is the range's bound, not a measured delay" in said[0], result["warnings"]
    assert "longer" not in said[0], said[0]  # (the true delay is shorter: no advice to search further)


@pytest.mark.parametrize("tau, hinted", [(1.05, True), (0.15, False)])
def test_a_delay_past_its_range_with_the_gain_free_is_hinted(tmp_path, rng, tau, hinted):
    """A sixth outside check: a fed-back delay of half a period (1.4 s) or a whole one,
    outside the 0.5 s a starting spec searches, with the gain estimated, came back as a
    near-cancelling gain and stiffness, an interval reaching 0 with the advice to remove
    [model.delay], or an inertia at its bound with the advice to check the input's sign —
    never that the delay may be longer (with tau_max covering it, within 0.3 %).  Here
    1.05 s (half this system's period) searched up to 0.3 s: the warning says so; 0.15 s
    (inside the range): it does not."""
    import json

    from cvxid.app.cli import main

    _delayed_record(tmp_path, rng, tau=tau)
    (tmp_path / "spec.toml").write_text(DELAYED.format(tau_max=0.3).replace("gain = 2.0\n", ""))
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    said = json.loads((tmp_path / "out" / "result.json").read_text())["warnings"]
    longer = [w for w in said if "if the loop's delay may be longer than the range searched (tau_max = 0.3 s), "
              "raise [model.delay] tau_max" in w]
    assert bool(longer) == hinted, said


def test_a_time_column_in_milliseconds_is_named(tmp_path, capsys, rng):
    """Time written in ms (dt = 1): tau_max = 0.3 is shorter than one sample, an error
    that names the units, not a model with an inertia of 6e5."""
    _delayed_record(tmp_path, rng, dt=1.0)
    err = cli_error(tmp_path, capsys, DELAYED.format(tau_max=0.3))
    assert "tau_max = 0.3 s is shorter than one sample" in err and "time column's units" in err, err
    assert '[data.train] time_unit = "ms"' in err, err


def test_a_time_column_in_milliseconds_without_a_delay_is_said(tmp_path, capsys, rng):
    """An eleventh outside check: a 500 Hz record stamped in ms, a spec without a delay,
    identified an inertia of 994753 with sliding windows of 2290 "s" and no word; `cvxid
    init` wrote tau_max = 500.  A step of a second or more on whole numbers is now said
    by the spec's record and by `cvxid init`, with the fix; a record in seconds is not."""
    from cvxid.app.cli import main
    from cvxid.spec.load import load_problem

    _delayed_record(tmp_path, rng, dt=1.0)
    spec = "\n".join(line for line in DELAYED.format(tau_max=0.3).splitlines()
                     if not line.startswith(("signal", "method", "tau_max", "gain")) and line != "[model.delay]")
    (tmp_path / "spec.toml").write_text(spec)
    with pytest.warns(CvxidWarning, match=r'\[data.train\] is sampled every 1 s .* set \[data.train\] time_unit = "ms"'):
        load_problem(tmp_path / "spec.toml").experiment("train")
    assert main(["init", str(tmp_path / "train.csv"), "-o", str(tmp_path / "init.toml")]) == 0
    assert "if it counts milliseconds, write the spec again with --time-unit ms" in capsys.readouterr().err
    _delayed_record(tmp_path, rng)  # (in seconds: nothing said)
    with warnings.catch_warnings():
        warnings.simplefilter("error", CvxidWarning)
        load_problem(tmp_path / "spec.toml").experiment("train")
        assert main(["init", str(tmp_path / "train.csv"), "-o", str(tmp_path / "init.toml"), "--force"]) == 0
    assert "milliseconds" not in capsys.readouterr().err


def test_a_model_coordinate_the_data_do_not_name_is_the_error_not_its_terms(tmp_path, capsys, rng):
    """An eleventh outside check: [model] coordinate = "y" beside output = { x = "x" } was
    refused as the term 'x', listing the velocities as (x'); the mismatch is now the error,
    with both fixes; a term of another name lists the coordinate's own velocity."""
    _delayed_record(tmp_path, rng)
    spec = DELAYED.format(tau_max=0.3).replace('file = "train.csv"', 'file = "train.csv"\noutput = { x = "x" }')
    err = cli_error(tmp_path, capsys, spec.replace('[model.library]', '[model]\ncoordinate = "y"\n[model.library]'))
    assert '[model] coordinate = "y" is not an output of [data.train], whose output table names x' in err, err
    assert 'output = { y = "x" }' in err, err
    err = cli_error(tmp_path, capsys, spec.replace('terms = ["x", "x\'"]', 'terms = ["x", "z"]'))
    assert "term 'z': the name 'z' is not allowed" in err and "their velocities (x')" in err, err


def test_a_spec_data_error_names_its_table(tmp_path, capsys, rng):
    _delayed_record(tmp_path, rng)
    err = cli_error(tmp_path, capsys, DELAYED.format(tau_max=0.3).replace('file = "train.csv"',
                                                                         'file = "train.csv"\ntime = "time"'))
    assert err.startswith("cvxid: error: spec: [data.train]") and "no column named 'time'" in err, err


def test_a_test_record_that_is_the_training_record_is_said(tmp_path):
    """[data.test] reading the training file's same samples (an outside check's spec), or part of them (a
    later outside check: fraction [0.5, 1] against [0, 0.8], silent): the test figures would be on the data the
    fit saw, and the run says how much; a split of one file by fraction is not warned."""
    import json

    from cvxid.app.cli import main
    from cvxid.simulate import System, simulate

    t = np.arange(6000) * 1e-3
    force = lambda s: 3 * np.sin(2.1 * s) + 2 * np.sin(5.3 * s + 1)
    x, _ = simulate(System((parse_term("x'"), parse_term("x")), np.array([0.5, 6.0]), 1.0, "x"), t, force, 0.3, 0.0)
    np.savetxt(tmp_path / "a.csv", np.column_stack([t, x, force(t)]), delimiter=",", header="t,x,f", comments="")
    said = "from the part of the same file that [data.train] reads"
    for train, test, share in ((None, None, 100), ([0.0, 0.8], [0.5, 1.0], 60), ([0.0, 0.7], [0.7, 1.0], None)):
        parts = [f'file = "a.csv"' + (f"\nfraction = {part}" if part else "") for part in (train, test)]
        (tmp_path / "spec.toml").write_text(f'[data.train]\n{parts[0]}\n[data.test]\n{parts[1]}\n[model.library]\n'
                                            'terms = ["x", "x\'"]\n')
        assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
        warnings = [w for w in json.loads((tmp_path / "out" / "result.json").read_text())["warnings"] if said in w]
        assert [w.split(" %)")[0].split("(")[-1] for w in warnings] == ([str(share)] if share else []), warnings


def test_a_test_record_copied_from_the_training_record_is_said(tmp_path, rng):
    """A fifteenth outside check: a renamed copy of the training file as the test record was
    reported as a held-out fit (the overlap check compared file names).  A copy of the whole
    record or of its last fifth is found stretch for stretch; a new record of the same
    system (its own noise) is not, nor are two quantised records that share only their
    stretches at rest."""
    import json

    from cvxid.app.cli import main
    from cvxid.data.overlap import copied_share
    from cvxid.simulate import System, simulate

    t = np.arange(6000) * 1e-3
    force = lambda s: 3 * np.sin(2.1 * s) + 2 * np.sin(5.3 * s + 1)
    x, _ = simulate(System((parse_term("x'"), parse_term("x")), np.array([0.5, 6.0]), 1.0, "x"), t, force, 0.3, 0.0)
    record = lambda y, u, s=slice(None): Experiment(t[s] - t[s][0], {"x": y[s]}, {"f": u[s]})
    noisy = lambda: x + 0.01 * rng.standard_normal(t.size)
    y, u = noisy(), force(t)
    train = record(y, u)
    assert copied_share(train, record(y, u)) == 1.0
    assert copied_share(train, record(y, u, slice(4800, None))) == 1.0
    assert copied_share(train, record(noisy(), u)) == 0.0
    rest = lambda y: np.where(t < 3, 0.0, np.round(y, 2))  # (an encoder's counts, at rest for 3 s)
    assert copied_share(record(rest(noisy()), u), record(rest(noisy()), u)) == 0.0
    # a review: a long quantised record's copy, whose values repeat thousands of times, was missed by a capped lookup
    long = np.arange(100_000) * 1e-3
    counts = np.round(np.sin(0.7 * long) + 0.5 * np.sin(2.3 * long) + 1e-3 * rng.standard_normal(long.size), 2)
    encoder = Experiment(long, {"x": counts}, {"f": np.cos(0.9 * long)})
    assert copied_share(encoder, encoder) == 1.0
    for name, y in (("train", y), ("copy", y), ("other", noisy())):
        np.savetxt(tmp_path / f"{name}.csv", np.column_stack([t, y, u]), delimiter=",", header="t,x,f", comments="")
    for test, copied in (("copy", True), ("other", False)):
        (tmp_path / "spec.toml").write_text(f'[data.train]\nfile = "train.csv"\n[data.test]\nfile = "{test}.csv"\n'
                                            '[model.library]\nterms = ["x", "x\'"]\n')
        assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
        said = [w for w in json.loads((tmp_path / "out" / "result.json").read_text())["warnings"]
                if "repeats [data.train] sample for sample on 100 % of the stretches checked" in w]
        assert bool(said) == copied, said


def test_a_test_record_in_other_columns_of_the_training_file_is_no_overlap(tmp_path, rng):
    """The paper's own .mat holds its training and test records side by side (``x_tr`` and
    ``x_tst``): the shipped paper specs warned that the test record read 100 % of its
    samples from the training record's part of the file.  Other output columns are judged
    by their values (a test column copied from the training one is still said); the same
    output column spelled out or left to its default is the same column (a review: those
    overlaps went unsaid)."""
    from cvxid.spec.load import load_problem
    from cvxid.simulate import System, simulate

    t = np.arange(4000) * 1e-3
    force = lambda s: 3 * np.sin(2.1 * s) + 2 * np.sin(5.3 * s + 1)
    x, _ = simulate(System((parse_term("x'"), parse_term("x")), np.array([0.5, 6.0]), 1.0, "x"), t, force, 0.3, 0.0)
    noisy = lambda: x + 0.01 * rng.standard_normal(t.size)
    x_tr = noisy()
    pd.DataFrame({"t": t, "x_tr": x_tr, "f_tr": force(t), "x_tst": noisy(), "f_tst": force(t),
                  "x_copy": x_tr, "x": x_tr, "f": force(t)}).to_csv(tmp_path / "both.csv", index=False)

    def said(train: str, test: str) -> list[str]:
        (tmp_path / "spec.toml").write_text(f'[data.train]\nfile = "both.csv"\n{train}\n[data.test]\n'
                                            f'file = "both.csv"\n{test}\n[model.library]\nterms = ["x"]\n')
        spec = load_problem(tmp_path / "spec.toml")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            spec.warn_overlap(spec.experiment("train"), spec.experiment("test"))
        return [str(w.message) for w in caught if issubclass(w.category, CvxidWarning)]

    paper = 'output = "x_tr"\ninput = "f_tr"'
    assert "reads 4000 of its 4000 samples (100 %) from the part of the same file" in said(paper, paper)[0]
    assert said(paper, 'output = "x_tst"\ninput = "f_tst"') == []
    assert "repeats [data.train] sample for sample on 100 % of the stretches checked" in \
        said(paper, 'output = "x_copy"\ninput = "f_tr"')[0]
    half = "fraction = [0.0, 0.55]", "fraction = [0.5, 1.0]"
    for spelled in ('output = "x"', 'output = { x = "x" }', 'output = "x"\ninput = "f"\ntime = "t"'):
        found = said(f"{half[0]}\n{spelled}", half[1])
        assert len(found) == 1 and "from the part of the same file that [data.train] reads" in found[0], (spelled, found)


def _training_record(fit: float, ceiling: float, error: str) -> "Comparison":
    """A training record's comparison with these fits (%): 8 s at 1 kHz of a 0.5 Hz motion
    with white noise 0.01, its free run off by a 0.5 Hz error (``"force"``, as a missing
    force errs) or a 50 Hz one (``"hum"``, a noise that is not white)."""
    from cvxid.diagnosis.compare import Comparison

    t = np.arange(8000) * 1e-3
    motion = np.sin(np.pi * t)
    measured = motion + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    off = 0.01 * np.sin(np.pi * t + 1) if error == "force" else 0.01 * np.sin(100 * np.pi * t)
    return Comparison(t, measured, motion + off, fit, None, 100, None, ceiling_percent=ceiling)


def _said_of_fits(warn, fit, k_step, ceiling, refinement=None, train=None) -> list[str]:
    """What ``warn`` (a check of a run's test comparisons) says of a comparison with these fits
    (%), and of the training record's (``train``: its fit, ceiling (%) and error,
    :func:`_training_record`) when given."""
    import warnings
    from types import SimpleNamespace

    from cvxid.diagnosis.compare import Comparison

    comparison = Comparison(np.zeros(3), np.zeros(3), np.zeros(3), fit, None, 100, k_step, ceiling_percent=ceiling)
    trained = None if train is None else {"x": _training_record(*train)}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warn(SimpleNamespace(comparisons={"x": comparison}, unpolished=None, test=None, refinement=refinement,
                             train_comparisons=trained, train=SimpleNamespace(dt=1e-3)))
    return [str(w.message) for w in caught if issubclass(w.category, CvxidWarning)]


@pytest.mark.parametrize("fit, k_step, ceiling, warned", [
    (23.32, 98.58, 98.66, True),   # held-out tuning seed 6 (Coulomb, 115 s): tau 0.003 for 0.13, a basin away from the data
    (93.68, 98.84, 99.60, False),  # the unbalanced disk's recording: a model that misses some dynamics, no drift
    (98.64, 98.60, 98.66, False),  # a fit at the noise's ceiling
])
def test_a_free_run_that_drifts_while_each_step_is_right_is_a_warning(fit, k_step, ceiling, warned):
    """The test record's free run 57 times further off than the noise allows while its
    k-step prediction is at the noise: the held-out benchmark's fit said nothing."""
    from cvxid.app.run import _warn_drift

    said = _said_of_fits(_warn_drift, fit, k_step, ceiling)
    assert bool(said) == warned, said
    if warned:
        assert "drifts away from the test record: fit 23.3 % where the noise allows 98.7 %" in said[0]
        assert "100-step-ahead prediction fits 98.6 %" in said[0] and "basin of the simulation error" in said[0]
        assert "or the model lacks part of the dynamics" in said[0]


@pytest.mark.parametrize("before, after, said", [
    (90.5, -104.8, True),   # held-out tuning seed 6 (Coulomb, 115 s chirp): 90.5 % before the polish, -105 % after
    (None, -104.8, False),  # the start's own free run diverged: nothing better to point to
    (60.0, 23.3, False),    # the start misses by more than half the polished model's error: not astray
    (70.0, None, True),     # the polished model's free run diverged, the start's did not
])
def test_a_drift_says_when_the_model_before_the_polish_fitted_the_test_record_better(before, after, said):
    """The drift warning of a polish that went astray on a long training record (its free run
    from the equation-error start far off over 115 s) names the start's own test fit, and how
    to keep it."""
    from cvxid.app.run import _astray
    from cvxid.diagnosis.compare import Comparison

    compared = [Comparison(np.zeros(3), np.zeros(3), np.zeros(3), fit, None, 100, 98.6, ceiling_percent=98.7)
                for fit in (after, before)]
    sentence = _astray(*compared)
    assert bool(sentence) == said, sentence
    if said:
        assert f"The equation-error model the output-error polish started from fits it {before:.1f} %" in sentence
        assert 'keep that model with [fit] refine = "none"' in sentence


@pytest.mark.parametrize("fit, k_step, ceiling, warned", [
    (97.06, 98.69, 98.70, True),   # a sixth outside check: a dead-zone spring (2.3 times the noise's error)
    (97.37, 98.95, 98.96, True),   # its Stribeck friction (2.5 times)
    (92.00, 99.00, 99.10, True),   # a second, unmodelled input (8.9 times)
    (93.68, 98.84, 99.60, True),   # the unbalanced disk's older model (15.8 times, the k-step 2.9: no drift)
    (23.32, 98.58, 98.66, False),  # a drift (57 times, the k-step at the noise): _warn_drift says it
    (98.64, 98.60, 98.66, False),  # at the noise's ceiling
    (98.47, 98.60, 98.66, False),  # 1.14 times: the worst of 200 tuning-seed systems' final models (8 s)
    (50.00, None, 99.00, True),    # its k-step prediction diverged: no drift to say, the gap is said
    (99.99985, 99.99993, 99.99993, True),  # a model at noise 1e-5: the fits printed with the digits that differ
])
def test_a_final_model_that_misses_the_test_record_well_beyond_its_noise_is_said(fit, k_step, ceiling, warned):
    """A sixth outside check: free runs 2–10 times further off than the noise allows
    (effects outside the catalogue) ended without a word; on the held-out benchmark's
    tuning seeds (0–9, 8 s, noise 0.01 and 0.001, five kinds of hidden effect, the gain
    given or estimated) every final model is within 1.16 times."""
    said = _said_of_fits(_incomplete, fit, k_step, ceiling)
    assert bool(said) == warned, said
    if warned and ceiling < 99.9:
        assert f"where the noise allows {ceiling:.1f} %): part of the dynamics is not in the model" in said[0]
    elif warned:
        assert "(fit 99.99985 % where the noise allows 99.999930 %)" in said[0]


def _incomplete(out) -> None:
    """:func:`~cvxid.app.run._warn_incomplete` of a run with these comparisons, its
    diagnosis on, no polish."""
    from types import SimpleNamespace

    from cvxid.app.run import _warn_incomplete

    _warn_incomplete(SimpleNamespace(comparisons=out.comparisons, train_comparisons=out.train_comparisons,
                                     spec=SimpleNamespace(diagnose=object()), test=None, train=out.train,
                                     polish=None, refinement=out.refinement))


@pytest.mark.parametrize("test, train, said", [
    ((97.88, 98.59), (96.14, 98.34, "force"), "dynamics"),  # a fourteenth outside check: x|x| fitted as x^3
    ((98.47, 98.66), (98.32, 98.50, "force"), "dynamics"),  # 1.14 on the test record, 1.12 on the training record
    ((98.47, 98.66), (98.45, 98.50, "force"), None),        # 1.14 and 1.03: the tuning seeds' worst complete models
    ((92.00, 99.10), (98.45, 98.50, "force"), "test"),      # the test record's gap alone (8.9 times)
    ((98.47, 98.66), (98.20, 98.50, "hum"), "noise"),       # 1.2 on the training record, its excess at 50 Hz
])
def test_a_final_model_that_misses_the_record_it_was_fitted_on_is_said(test, train, said):
    """The training record's free run, from the polish's own initial state, is the sharper
    measure of a missing effect: a complete model's stays within a few % of what white noise
    allows, where the short test record's, from an estimated start, spreads more.  A
    fourteenth outside check's stiffness x|x| came back as a confident x^3 with its test
    record at 1.5 times the noise's error, under the test record's threshold of 2.  A
    review: a complete model under a mains hum or a filtered sensor's noise misses its
    training record by 1.09–1.25 times too; its excess lies above the motion's band, and
    the run says the noise is not white instead."""
    told = _said_of_fits(_incomplete, test[0], 99.0, test[1], train=train)
    assert bool(told) == bool(said), told
    if said == "dynamics":  # (the training record's gap alone: the test record's is under 2)
        assert "the final model's free run misses the training record it was fitted on by" in told[0]
        assert f"(fit {train[0]:.1f} % where the noise allows {train[1]:.1f} %) (the test record: " in told[0]
        assert "part of the dynamics may be missing from the model (100 % of the excess over white noise lies in " \
               "the motion's band" in told[0]
    elif said == "test":  # (the training record's gap only as context)
        assert "misses the test record by 8.89 times" in told[0] and "(the training record: 1.03 times)" in told[0]
        assert ": part of the dynamics is not in the model" in told[0]
    elif said == "noise":
        assert "by 1.2 times what white noise of its level allows" in told[0], told[0]
        assert "100 % of the excess lies above the motion's band" in told[0] and "the measurement noise is not " \
               "white" in told[0] and "part of the dynamics" not in told[0]


def test_a_missing_effect_is_said_end_to_end(tmp_path):
    """x'' + 0.8 x' + 9 x + k2 x^2 = f + 2 x(t - 0.15), noise 0.01, fitted with x and x'
    only and no [diagnose]: with k2 = 1 the run says the model is incomplete and names
    [diagnose]; with k2 = 0 (the model is complete) it says nothing of it."""
    import json

    from cvxid.app.cli import main
    from cvxid.simulate import System, simulate

    spec = ('name = "d"\n[data.train]\nfile = "train.csv"\n[data.test]\nfile = "test.csv"\n[model.library]\n'
            'terms = ["x", "x\'"]\n[model.delay]\nsignal = "x"\ngain = 2.0\nmethod = "exact"\ntau_max = 0.3\n[fit]\n'
            'estimator = "lstsq"\nrefine = "output_error"\n')
    (tmp_path / "spec.toml").write_text(spec)
    t = np.arange(6000) * 1e-3
    forces = {"train": lambda s: 4 * np.sin(2.3 * s) + 3 * np.sin(6.1 * s + 1),
              "test": lambda s: 3 * np.sin(1.7 * s) + 3 * np.sin(4.9 * s + 2)}
    for k2, warned in ((1.0, True), (0.0, False)):
        rng = np.random.default_rng(0)
        system = System((parse_term("x'"), parse_term("x"), parse_term("x^2")), np.array([0.8, 9.0, k2]), 1.0, "x",
                        gain=2.0, tau=0.15)
        for name, force in forces.items():
            x, _ = simulate(system, t, force, 0.0, 0.0)
            np.savetxt(tmp_path / f"{name}.csv", np.column_stack([t, x + 1e-2 * rng.standard_normal(t.size), force(t)]),
                       delimiter=",", header="t,x,f", comments="")
        assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
        result = json.loads((tmp_path / "out" / "result.json").read_text())
        said = [w for w in result["warnings"] if "part of the dynamics is not in the model" in w]
        assert bool(said) == warned, said
        gap = (100 - result["train_fit_percent"]) / (100 - result["train_fit_percent_noise_ceiling"])
        assert gap > 1.5 if warned else 0.9 < gap < 1.1, gap  # (the training record's free run)
        if warned:
            assert "[diagnose] looks for it among the catalogue's effects" in said[0]
            assert "The 95 % intervals assume a complete model" in said[0]  # (a ninth outside check: the disk's
            #                                                                 moved between stretches beyond them)


@pytest.mark.parametrize("ceiling, warned", [(83.3, True), (89.9, True), (90.1, False), (98.7, False)])
def test_a_test_record_that_barely_moves_above_its_noise_is_said(ceiling, warned):
    """An outside check's step response: the test record (the last fifth) had settled, a perfect model would fit
    83.3 % of it, and the diagnosis chose on it without a word."""
    from cvxid.app.run import _warn_quiet_test

    said = _said_of_fits(_warn_quiet_test, ceiling - 0.1, ceiling, ceiling)
    assert bool(said) == warned, said
    if warned:
        assert f"a perfect model would fit only {ceiling:.1f} %" in said[0] and "give a test record" in said[0]


def test_a_run_whose_test_record_barely_moves_above_its_noise_says_so(tmp_path):
    """End to end: a test record whose noise is a third of its spread (a perfect model fits about 70 % of it)
    gets the quiet record's warning in result.json; the same record with little noise does not."""
    import json

    from cvxid.app.cli import main

    from .conftest import TEST_SIMULATED, TRAIN_SIMULATED

    for noise, warned in ((0.1, True), (0.001, False)):
        test = TEST_SIMULATED.replace("noise = { output = 0.001, input = 0.0 }",
                                      f"noise = {{ output = {noise}, input = 0.0 }}")
        (tmp_path / "spec.toml").write_text('name = "quiet"\n[truth]\nmass = 1.0\n'
                                            'coefficients = { "x\'" = 0.4, "x" = 6.0 }\n' + TRAIN_SIMULATED + "\n"
                                            + test + '\n[model.library]\nterms = ["x", "x\'"]\n'
                                            '[fit]\nestimator = "lstsq"\n')
        assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
        result = json.loads((tmp_path / "out" / "result.json").read_text())
        said = [w for w in result["warnings"] if "barely moves above its noise" in w]
        assert bool(said) == warned, (result["test_fit_percent_noise_ceiling"], result["warnings"])


def test_an_effect_added_beside_a_delay_held_at_its_top_is_named_as_a_possible_stand_in(tmp_path, rng):
    """A delay held at the top of a range too short for it may leave a misfit the diagnosis
    fills with an effect (an outside check: a delay of 4 s searched up to 0.5 s, a Coulomb
    friction added): the warning names what was added.  Here the friction is real, the
    delay 0.15 s searched up to 0.1 s.  (Since the score test leaves out a delay pressed
    against its bound, the stage by simulation error also adds an input delay of 0.7 ms and
    an offset of 3e-4 beside the held delay, and the warning names them too.)"""
    import json

    from cvxid.app.cli import main
    from cvxid.simulate import System, simulate

    t = np.arange(8001) * 1e-3
    force = lambda s: 4 * np.sin(2.3 * s) + 3 * np.sin(6.1 * s + 1)  # noqa: E731
    system = System((parse_term("x'"), parse_term("x"), parse_term("sign(x')")), np.array([0.8, 9.0, 1.0]), 1.0,
                    "x", gain=2.0, tau=0.15)
    x, _ = simulate(system, t, force, 0.0, 0.0)
    np.savetxt(tmp_path / "train.csv", np.column_stack([t, x + 1e-3 * rng.standard_normal(t.size), force(t)]),
               delimiter=",", header="t,x,f", comments="")
    spec = DELAYED.format(tau_max=0.1).replace('file = "train.csv"', 'file = "train.csv"\nfraction = [0, 0.8]')
    spec = spec.replace("[model.library]", '[data.test]\nfile = "train.csv"\nfraction = [0.8, 1]\n[model.library]')
    (tmp_path / "spec.toml").write_text(spec + "[diagnose]\nrefine = true\n")
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert [s["added"] for s in result["refinement"]] == ["coulomb"], result["refinement"]
    said = [w for w in result["warnings"] if "search range" in w]
    assert said and "the diagnosis added sign(x')" in said[0] and "which may stand in for the longer delay" in said[0]


# ---------------------------------------------------------------- a fourth outside check
def test_a_shorter_array_is_refused_when_a_part_of_the_record_is_cut(tmp_path):
    """Every `init` spec cuts a part (fraction): an x 50 samples short was cut at the same
    indices as t and f, 50 samples out of step, and the run returned a mass of 0.108 for 2
    with exit 0.  A 2-D array was read as its flattened length."""
    from cvxid.data.experiment import load

    t = np.arange(2000) * 1e-3
    np.savez(tmp_path / "late.npz", t=t, x=np.sin(3 * t)[50:], f=np.cos(7 * t))
    with pytest.raises(CvxidError, match="array 'x' has 1950 samples but 't' has 2000; all signals must have the "
                                         "same length"):
        load(tmp_path / "late.npz", "t", "x", "f", fraction=(0.0, 0.8))
    np.savez(tmp_path / "wide.npz", t=t, x=np.column_stack([np.sin(3 * t), np.sin(2 * t)]), f=np.cos(7 * t))
    with pytest.raises(CvxidError, match=r"array 'x' has shape \(2000, 2\); give a 1-D array"):
        load(tmp_path / "wide.npz", "t", "x", "f", fraction=(0.0, 0.8))


def test_a_term_that_divides_by_a_crossing_state_is_refused_and_a_bounded_quotient_is_not(rng):
    """A fourth outside check: `1/x` of an x crossing 0 (never exactly 0) peaked at 2.9e3
    against a median of 1.5 near each crossing; the run accepted it without a word and its
    mass interval excluded the truth (docs/bad-input.md said it was refused)."""
    x = np.sin(2 * T) + 0.001 * rng.standard_normal(T.size)
    e = Experiment(T, {"x": x}, {"f": np.cos(3 * T)})
    for text in ("1/x", "x^-1"):
        with pytest.raises(CvxidError, match="is unbounded on these data: it divides by a quantity that crosses 0"):
            RegressionBuilder(ModelSpec(Library([parse_term("x"), parse_term(text)])), e, "savgol").at(None)
    for text in ("tanh(x)/x", "(1 - cos(x))/x"):  # removable singularities: terms like any other (the second
        bounded = RegressionBuilder(ModelSpec(Library([parse_term("x"), parse_term(text)])), e, "savgol")  # was
        assert np.all(np.isfinite(bounded.at(None).P))  # refused by a peak far from any crossing: a review)
    long = np.arange(20000) * 1e-3  # a free decay over 20 s: its peak is far above its median, far from a crossing
    decay = Experiment(long, {"x": np.exp(-long / 2) * np.sin(6 * long) + 1e-4 * rng.standard_normal(long.size)},
                       {"f": np.cos(3 * long)})
    RegressionBuilder(ModelSpec(Library([parse_term("x"), parse_term("(1 - cos(x))/x")])), decay, "savgol").at(None)


def test_an_input_of_the_wrong_sign_names_the_sign(tmp_path, capsys):
    """A fourth outside check: a force sensor mounted the other way round gave a mass at its
    bound (1e-09) and a diverged free run, exit 0, and the "not positive" warning never fired
    (the spec constrains the inertia); now the inertia at its bound names the input's sign,
    and `input = "-f"` gives the model back."""
    import json

    from cvxid.app.cli import main

    from cvxid import load_problem, run

    from .conftest import TRAIN_SIMULATED
    from .test_sensor import spec_text

    (tmp_path / "s.toml").write_text(spec_text(TRAIN_SIMULATED))
    train = load_problem(tmp_path / "s.toml").experiment("train")
    np.savetxt(tmp_path / "r.csv", np.column_stack([train.time, train.output("x"), -train.input("f")]),
               delimiter=",", header="t,x,f", comments="")
    base = ('name = "reversed"\n[data.train]\nfile = "r.csv"\ntime = "t"\noutput = { x = "x" }\ninput = { f = "f" }\n'
            '[model.library]\nterms = ["x", "x\'"]\n[model.delay]\nsignal = "x"\ngain = 1.5\nmethod = "exact"\n'
            'tau_max = 0.4\n[model.constraints]\nnonnegative = ["x\'\'"]\n[fit]\nestimator = "lstsq"\n')
    for given, said in (("", True), ('[model]\ninput = "-f"\n', False)):
        (tmp_path / "r.toml").write_text(base + given)
        assert main(["run", str(tmp_path / "r.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
        result = json.loads((tmp_path / "out" / "result.json").read_text())
        warned = [w for w in result["warnings"] if "at its lower bound (next to 0)" in w]
        assert bool(warned) == said, result["warnings"]
        if said:
            assert 'Check the input\'s sign (a sensor mounted the other way round: [model] input = "-f")' in warned[0]
            with warnings.catch_warnings(record=True) as issued:  # the CLI prints them once, in its summary
                warnings.simplefilter("always")
                assert main(["run", str(tmp_path / "r.toml"), "--quiet"]) == 0
            assert not [w for w in issued if issubclass(w.category, CvxidWarning)]
            assert "at its lower bound (next to 0)" in capsys.readouterr().out
            with pytest.warns(CvxidWarning, match=r"at its lower bound \(next to 0\)"):  # a Python caller gets
                run(tmp_path / "r.toml")  # them as warnings (a fifth outside check: a notebook user saw none)
        else:
            assert result["physical"]["m"] == pytest.approx(1.0, rel=0.02)  # the truth: x'' + 0.4 x' + 6 x = f + ...


def test_a_negative_damping_counts_the_delayed_feedback_s_share():
    """A fourth outside check (the unbalanced disk): a damping of -1.50 beside the feedback
    35.7 theta(t - 0.0445) is +0.09 net (b x(t - tau) ~ b x - b tau x'); the negative-damping
    warning reads this net damping (here the formula; without the feedback the same damping
    stays negative)."""
    from cvxid.app.run import _net_damping
    from cvxid.identified import IdentifiedModel
    from cvxid.model.delay import DelayedFeedback

    delayed = ModelSpec(Library([parse_term("x"), parse_term("x'")]), delay=DelayedFeedback("x", method="exact"))
    model = IdentifiedModel(delayed, {"x''": 1.0, "x": 40.3, "x'": -1.50, "x(t-tau)": -35.68}, tau=0.0445)
    assert _net_damping(model, -1.50) == pytest.approx(-1.50 + 35.68 * 0.0445)
    assert _net_damping(IdentifiedModel(MODEL, {"x''": 1.0, "x": 40.3, "x'": -1.50}), -1.50) == -1.50


@pytest.mark.parametrize("model, said", [
    ('[model.constraints]\nnonnegative = ["x\'\'", "x(t - tau)"]',
     "nonnegative names 'x(t-tau)', the delayed feedback: its sign is not constrained (its column carries minus"),
    ('[model]\ncoordinate = "f"\ninput = "f"', "[model] coordinate = 'f' is also the input"),
])
def test_a_sign_on_the_feedback_or_a_coordinate_named_as_the_input_is_explained(tmp_path, capsys, model, said):
    """A fourth outside check: both ended in "the function 'x' is not allowed" (or "the name
    'x'"), though another error listed x(t-tau) among the model's columns."""
    from .conftest import TRAIN_SIMULATED

    text = (f'name = "n"\n{TRAIN_SIMULATED}\n[model.library]\nterms = ["x", "x\'"]\n'
            '[model.delay]\nsignal = "x"\nmethod = "exact"\n' + model + "\n")
    assert said in cli_error(tmp_path, capsys, text)


def test_the_python_api_names_the_argument_of_the_wrong_type():
    """A fifth outside check: arrays for Experiment's mappings ended in numpy's "truth
    value of an array is ambiguous", a list of names for Library in an AttributeError, and
    nonnegative = "x''" was read letter by letter.  A library also takes term names."""
    t = np.arange(100) * 0.01
    with pytest.raises(CvxidError, match=r"outputs must map names to arrays \(\{\"x\": x\}\), got ndarray"):
        Experiment(t, np.sin(t), np.cos(t))
    assert Library(["x", "x'", "sign(x')"]).names == Library([parse_term(n) for n in ("x", "x'", "sign(x')")]).names
    with pytest.raises(CvxidError, match=r"Library takes a list of terms, got one \('x'\)"):
        Library("x")
    with pytest.raises(CvxidError, match=r"nonnegative takes a list of column names: \[\"x''\"\]"):
        Problem.from_arrays(np.column_stack([np.sin(t), t]), np.cos(t), ["x''", "x"], nonnegative="x''")
    import cvxid

    record = Experiment(t, {"x": np.sin(t)}, {"f": np.cos(t)})
    with pytest.raises(CvxidError, match="an identified model is needed .* got ModelSpec"):
        cvxid.compare(MODEL, record)
    problem = Problem.from_arrays(np.column_stack([np.sin(t), t]), np.cos(t), ["a", "b"])
    assert cvxid.Path.compute(problem, 1e-3).lambdas.tolist() == [1e-3]  # (numpy's AxisError before)
    with pytest.raises(CvxidError, match="validate must be a function of the coefficients"):
        cvxid.Path.compute(problem, [1e-3, 1e-2], validate=record)
    with pytest.raises(CvxidError, match="the records must be an Experiment or a list of them .* got ndarray"):
        cvxid.build_regression(MODEL, np.sin(t))  # (an AttributeError 'segments' before)
    assert ModelSpec(library=["x", "x'"]).library.names == MODEL.library.names  # (an AttributeError before)


def test_results_print_what_they_hold(rng):
    """A fifth outside check: a Fit, a Choice, Residuals and a PolishResult printed raw
    arrays or the whole path; each now says what it is and its numbers by name."""
    from cvxid.diagnosis.residuals import Residuals
    from cvxid.identify.selection import Selection

    P = np.column_stack([np.sin(T), np.cos(T), np.sin(3 * T)])
    prob = Problem.from_arrays(P, P @ [1.0, 0.5, 0.0] + 0.01 * rng.standard_normal(T.size), ["a", "b", "c"])
    choice = Selection("lasso", rule="min").choose(prob, folds=5)
    assert repr(choice).startswith("Choice: lambda = ") and "keeps 2 of 3 columns: a, b" in repr(choice)
    assert "2 of 3 columns" in repr(choice.fit) and re.search(r"a = 0.99\d\d, b = 0.50", repr(choice.fit))
    r = Residuals(T, np.full(T.size, 0.5), np.sin(T), np.cos(T), np.cos(T))
    assert repr(r).startswith("Residuals: the equation error on 500 samples") and "RMS 0.5 " in repr(r)


GAPPED = SENSOR_SPEC.replace('"x" = 6.0 }}', '"x" = 6.0, "x^3" = 2.0 }}').format(
    train='file = "train.csv"\ngaps = true', test='[data.test]\nfile = "test.csv"').replace(
    'terms = ["x", "x\'"]', 'terms = ["x", "x\'", "x^3"]')
"""The sensor tests' spec with a cubic stiffness, its training record loaded with gaps."""


def test_a_gap_near_the_start_neither_shortens_the_windows_nor_hides_a_delay_at_0(tmp_path, rng):
    """A seventh outside check: x'' + 0.4 x' + 6 x + 2 x^3 = f + 1.5 x(t - 0.15), noise
    0.001, a gap of 11 samples 1 s into a 4.8 s training record.  The windows were a quarter
    of the shortest gap-free stretch (0.15 s for 1.1 s without the gap) and the delay came
    out 0.0010 (its damping 0.62 for 0.4) with no warning, a sample above 0 and above the
    at-0 tolerance (1e-3 of the range, 0.0004 s).  Now the windows come from the longest
    stretch, the short one is said to give no rows, and the delay is within 5 %; with the
    user's 0.15 s windows the delay at one sample is said to be at 0."""
    import json

    from cvxid.app.cli import main
    from cvxid.simulate import System, simulate

    system = System(tuple(map(parse_term, ("x'", "x", "x^3"))), np.array([0.4, 6.0, 2.0]), 1.0, "x", gain=1.5,
                    tau=0.15)
    for name, seconds, force in (("train", 4.8, lambda s: 3 * np.sin(1.9 * s) + 2 * np.sin(4.7 * s + 1)),
                                 ("test", 3.0, lambda s: 2 * np.sin(2.6 * s) + 2 * np.sin(5.9 * s + 2))):
        t = np.arange(int(seconds * 1000)) * 1e-3
        x, _ = simulate(system, t, force, 0.2, 0.0)
        x = x + 1e-3 * rng.standard_normal(t.size)
        if name == "train":
            x[1000:1011] = np.nan
        np.savetxt(tmp_path / f"{name}.csv", np.column_stack([t, x, force(t)]), delimiter=",", header="t,x,f",
                   comments="")
    said = {}
    for window in ("auto", 0.15):
        (tmp_path / "spec.toml").write_text(GAPPED + f"window = {json.dumps(window)}\n")
        assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / str(window))]) == 0
        said[window] = json.loads((tmp_path / str(window) / "result.json").read_text())
    auto = said["auto"]
    assert auto["window"]["seconds"] > 0.5 and abs(auto["tau"]["estimate"] / 0.15 - 1) < 0.05, auto["tau"]
    assert any("1 record(s) or gap-free stretch(es) (train[0:1000]; 21 % of the samples) are shorter than one window" in w
               for w in auto["warnings"]), auto["warnings"]
    short = said[0.15]
    assert short["tau"]["estimate"] < 2e-3, short["tau"]  # (these windows put the delay a sample above 0)
    assert any("is at 0, the bottom of its search range" in w for w in short["warnings"]), short["warnings"]


def test_a_measured_velocity_without_its_column_names_both_keys(tmp_path, capsys, rng):
    """A seventh outside check: ``[fit] velocity = "measured"`` with no velocity column was
    accepted without a word where no term read it (and an error naming neither key where
    one did)."""
    _delayed_record(tmp_path, rng)
    err = cli_error(tmp_path, capsys, DELAYED.format(tau_max=0.3).replace("[fit]\n", "[fit]\nvelocity = \"measured\"\n"))
    assert ("[fit] velocity = \"measured\" reads each coordinate's velocity from the records, and [data.train] has "
            "none of 'x': name its column ([data.train] velocity = \"v\"; from Python, a column x'), or choose an "
            "estimator ([fit] velocity = \"savgol\")") in err, err


@pytest.mark.parametrize("kind, said", [("square", True), ("prbs", True), ("sine", False), ("white", False)])
def test_the_gap_warning_names_a_test_input_that_jumps(kind, said):
    """A seventh outside check: the flexible joint's true model misses its square-wave test
    record by 3.1 times the noise's error (a jump between two samples happens at a time the
    record cannot tell) and reaches the noise on a sine; the gap warning named only missing
    dynamics."""
    from cvxid import Experiment
    from cvxid.app.run import _jumping

    t = np.arange(20000) * 1e-3
    rng = np.random.default_rng(0)
    u = {"square": lambda: 0.81 * np.sign(np.sin(2 * np.pi * 0.66 * t)),
         "prbs": lambda: np.repeat(rng.choice([-1.0, 1.0], 200), 100),
         "sine": lambda: np.sin(3.0 * t),
         "white": lambda: rng.standard_normal(t.size)}[kind]()  # (broadband excitation: no jumps between stills)
    text = _jumping(Experiment(t, {"x": np.sin(t)}, {"u": u}))
    assert bool(text) == said, text
    if said:
        assert "an input that jumps ('u' on the test record: a square wave or steps)" in text


def test_bench_says_when_scikit_learn_is_not_there_to_compare(monkeypatch, capsys):
    """A seventh outside check: without scikit-learn the bench printed its row as NaN and
    its differences as None, with no word why."""
    import cvxid.tools.bench as bench

    figures = {"terms": 26, "rows": 25001, "lambdas": 50, "path_seconds": 0.05, "naive_cvxpy_seconds": 1.0,
               "naive_lambdas_measured": 5, "naive_failures": 0, "sklearn_seconds": None, "stlsq_seconds": 0.01,
               "algorithm1_seconds": 9.0, "algorithm1_order": 4, "max_coefficient_difference": 1e-7,
               "sklearn_max_difference": None, "sklearn_max_objective_gap": None}
    monkeypatch.setattr(bench, "benchmark", lambda *args: figures)
    bench.run_bench("hidden_friction")
    out = capsys.readouterr().out
    assert "(c) not measured: scikit-learn is not installed (pip install \"cvxid[bench]\" brings it)" in out
    assert "(a) vs (c)" not in out


@pytest.mark.parametrize("force", ["blow at 0.3 s", "blow at 0.6 s", "step at 0.3 s"])
def test_an_input_that_acts_only_in_the_delay_s_history_is_refused(force):
    """Eighth outside check: an impact hammer's blow inside an exact delay's history (tau_max)
    leaves a free motion with no force after it, and the run gave an inertia of 1e-9 and
    warnings about the input's sign.  A blow after the history, or a step inside it (its
    force stays), pass (a stranger's review: a first version that also asked for a quarter
    window after the history refused records that identified within 1.5 %)."""
    from cvxid import build_regression, load_problem

    model = load_problem("hidden_friction").model  # exact delay, tau_max 0.4 s
    rng = np.random.default_rng(0)
    t = np.arange(10_001) * 1e-3
    at = float(force.split()[-2])
    after = np.clip(t - at, 0.0, None)
    x = np.where(t > at, 0.3 * np.exp(-0.2 * after) * np.sin(2.4 * after), 0.0) + 1e-3 * rng.standard_normal(t.size)
    shape = np.exp(-0.5 * ((t - at) / 0.01) ** 2) if force.startswith("blow") else (t >= at).astype(float)
    record = Experiment(t, {"x": x}, {"f": 50.0 * shape + 1e-3 * rng.standard_normal(t.size)})
    linear = replace(model, library=Library(["x", "x'"]))
    if force == "blow at 0.3 s":
        with pytest.raises(CvxidError, match=r"input 'f' acts only in the first tau_max = 0\.4 s of the record.*"
                                             r"pre-trigger.*tau_max"):
            build_regression(linear, record, tau=0.1)
    else:
        assert build_regression(linear, record, tau=0.1).shape[1] == 3


@pytest.mark.parametrize("samples, said", [(4.6, True), (18.0, False)])
def test_a_gap_on_a_coarsely_sampled_record_names_the_sample_step(samples, said):
    """A ninth outside check: the unbalanced disk at every fourth sample (4.6 samples a
    period of its band edge) lost its friction, and the gap warning named only missing
    effects; at 18 (its 40 Hz) and 9 the disk identifies alike."""
    from types import SimpleNamespace

    from cvxid.app.run import _coarse
    from cvxid.diagnosis.compare import Comparison

    rng = np.random.default_rng(0)
    dt, period = 0.1, 0.1 * samples
    t = np.arange(4000) * dt
    x = np.sin(2 * np.pi * t / period) + 0.3 * np.sin(2 * np.pi * t / (3.1 * period)) + 1e-3 * rng.standard_normal(t.size)
    text = _coarse(Comparison(t, x, x, 90.0, None, 90.0, 90.0), SimpleNamespace(dt=dt))
    assert bool(text) == said, text
    if said:
        assert "sample step coarse against the motion" in text and "sample faster" in text


def test_a_gap_names_the_candidate_the_diagnosis_refused():
    """A ninth outside check: on 8 s of stick-slip the Coulomb friction was ranked first,
    refused (kept on 65 % of the halves), and the drift and gap warnings named only effects
    outside the catalogue; given by hand, the friction fits to the noise.  The warnings name
    the refused candidate, why, and its term."""
    from types import SimpleNamespace

    from cvxid.app.run import _warn_drift
    from cvxid.diagnosis.acceptance import stopped_at

    ranking = pd.DataFrame({"term": ["sign(x')", "x'|x'|"], "validation_ratio": [4.08, 3.58]},
                           index=pd.Index(["coulomb", "quadratic_damping"], name="effect"))
    refused = SimpleNamespace(stopped=stopped_at("coulomb", 4.08, True, 0.65), diagnoses=[SimpleNamespace(
        ranking=ranking)])
    said = _said_of_fits(_warn_drift, 53.6, 98.7, 98.8, refused)
    assert said and "stopped at coulomb (validation ratio 4.08): halves of the training record keep it on 65 %" in said[0]
    assert "add its term to the model's terms, one at a time, and compare the test fits (sign(x') (coulomb, 4.08), " \
           "x'|x'| (quadratic_damping, 3.58):" in said[0]
    gap = _said_of_fits(_incomplete, 90.0, 91.0, 98.8, refused)
    assert gap and "part of the dynamics is not in the model, and the diagnosis stopped at coulomb" in gap[0]
    unhelpful = SimpleNamespace(stopped=stopped_at("offset", 0.98), diagnoses=[SimpleNamespace(ranking=ranking)])
    assert "stopped at" not in _said_of_fits(_warn_drift, 53.6, 98.7, 98.8, unhelpful)[0]  # it did not help: unsaid


def test_a_parameter_without_a_standard_error_has_no_interval_of_zero_width():
    """A twelfth outside check (input and output swapped, a diverged polish): every standard
    error was NaN, the profile's one inside point hulled each value with itself, and
    result.json read m [0.000379, 0.000379], an exact parameter to a script; now no interval
    (NaN, null in result.json), and a profile that spans values still gives its range."""
    from cvxid.identify.output_error import PolishResult
    from cvxid.identify.profile import DelayProfile

    profile = DelayProfile(np.array([0.1, 0.2]), np.array([1.0, 2.0]), 0.1, (0.1, 0.1), 100.0, "output_error",
                           {"m": (0.000379, 0.000379), "k": (5.0, 6.0)})
    polish = PolishResult(None, {"m": 0.000379, "k": 5.5}, {"m": np.nan, "k": np.nan}, 1.0, 1.0, (), 0, 0.0, profile)
    assert np.isnan(polish.interval("m")).all()
    assert polish.interval("k") == (5.0, 6.0)


def test_a_header_that_names_a_column_twice_is_refused(tmp_path):
    """A twelfth outside check: ``t,x,x,f`` was read with the second x renamed x.1 by pandas,
    and `cvxid init` listed "not used: x.1", a name the file does not hold; two sensors
    labelled x passed silently.  Now refused, naming the columns; empty trailing fields are
    not names."""
    from cvxid.data.experiment import _csv_columns

    path = tmp_path / "twice.csv"
    path.write_text("t,x,x,f\n0,1,1,0\n0.1,2,2,1\n0.2,3,3,0\n")
    with pytest.raises(CvxidError, match=r"names a column twice \('x' in columns 2 and 3\)"):
        _csv_columns(path)
    path.write_text("t,x,f,,\n0,1,0,,\n0.1,2,1,,\n")
    assert set(_csv_columns(path)) >= {"t", "x", "f"}


@pytest.mark.parametrize("duration, warned", [(0.5, True), (8.0, False)])
def test_a_test_record_shorter_than_a_swing_is_said(tmp_path, duration, warned):
    """A twelfth outside check's 0.4 s test record (under half a period of its 1 s response)
    passed without a word; ``x'' + 0.4 x' + 6 x = f`` (a period of 2.6 s) tested on 0.5 s is
    said to rest on little, on 8 s it is not."""
    import json

    from cvxid.app.cli import main

    from .conftest import TEST_SIMULATED, TRAIN_SIMULATED

    text = ('name = "short"\n[truth]\nmass = 1.0\ncoefficients = { "x\'" = 0.4, "x" = 6.0 }\n' + TRAIN_SIMULATED
            + "\n" + TEST_SIMULATED.replace("duration = 8.0", f"duration = {duration}")
            + '\n[model.library]\nterms = ["x", "x\'"]\n[fit]\nestimator = "lstsq"\n')
    (tmp_path / "spec.toml").write_text(text)
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    said = [w for w in json.loads((tmp_path / "out" / "result.json").read_text())["warnings"]
            if "less than one period" in w]
    assert bool(said) == warned, said
    if warned:
        assert said[0].startswith("the test record spans 0.5 s") and "[data.test] fraction" in said[0]
