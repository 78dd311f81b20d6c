"""The diagnosis by simulation error: score tests at the polished model, held-out acceptance.

A cubic oscillator ``x'' + 0.5 x' + 4 x + 1.5 x^3 = f`` (10 ms sampling, noise 0.01 on x and
f, seeded), identified without its cubic stiffness and polished by output error.
"""

import numpy as np
import pytest
from scipy.stats import chi2

from cvxid.data.experiment import Experiment
from cvxid.diagnosis.simulation import refine_by_simulation, score_candidates
from cvxid.identified import IdentifiedModel
from cvxid.identify.output_error import output_error
from cvxid.model.equation import ModelSpec
from cvxid.model.library import Library
from cvxid.model.terms import parse_term
from cvxid.simulate import System, simulate

from .conftest import ROOT

TRUTH = {"x'": 0.5, "x": 4.0, "x^3": 1.5}
DT = 0.01


def record(seed: int, duration: float = 30.0, noise: float = 0.01) -> Experiment:
    rng = np.random.default_rng(seed)
    freqs, phases = np.array([0.5, 1.1, 1.9, 3.1, 4.3]), rng.uniform(0, 2 * np.pi, 5)
    force = lambda s: 2.0 * np.sin(np.multiply.outer(s, freqs) + phases).sum(axis=-1)  # noqa: E731
    t = np.arange(int(duration / DT) + 1) * DT
    system = System(tuple(parse_term(n) for n in TRUTH), np.array(list(TRUTH.values())), 1.0, "x")
    x, _ = simulate(system, t, force, 0.2, 0.0, substeps=4)
    return Experiment(t, {"x": x + noise * rng.standard_normal(t.size)},
                      {"f": force(t) + noise * rng.standard_normal(t.size)}, f"record {seed}")


def polished(terms, seed=0):
    spec = ModelSpec(Library(parse_term(n) for n in terms), nonnegative=("x''",))
    start = IdentifiedModel(spec, {"x''": 1.0, **{n: TRUTH[n] * 0.9 for n in terms}})
    return output_error(start, record(seed), step=DT, max_iterations=50)


def test_the_missing_term_scores_far_above_chance_and_absent_ones_do_not():
    lacking = polished(("x'", "x"))
    ranking = score_candidates(lacking.model, record(0), ["cubic_stiffness", "offset", "quadratic_damping"],
                               lacking.initial)
    # significant at the loop's level (measured 19: a model error colours the residual, n_eff is small)
    assert ranking.index[0] == "cubic_stiffness" and ranking.loc["cubic_stiffness", "score"] > chi2.ppf(0.99, 1)
    complete = polished(("x'", "x", "x^3"))
    ranking = score_candidates(complete.model, record(0), ["offset", "quadratic_damping", "quadratic_stiffness"],
                               complete.initial)
    assert (ranking["score"] < chi2.ppf(0.999, 1)).all(), ranking  # chi^2_1 when the effect is absent


def test_the_loop_adds_the_missing_term_when_the_test_record_agrees():
    lacking = polished(("x'", "x"))
    out = refine_by_simulation(lacking, record(0), record(1), ["cubic_stiffness", "offset", "quadratic_damping"])
    first = out.steps[0]
    assert first.added == "cubic_stiffness" and first.kept
    assert first.test_rms_after < 0.5 * first.test_rms_before
    assert out.polish.parameters["x^3"] == pytest.approx(TRUTH["x^3"], rel=0.05)
    assert not any(step.kept for step in out.steps[1:])  # nothing else belongs in the model


def records(train: float, test: float, noise: float, train_input: str, test_input: str) -> str:
    """The [data] tables of a simulated spec: 2 ms sampling, seeds 1 and 2."""
    return "".join(f"""
[data.{which}.simulate]
duration = {duration}
dt = 2e-3
seed = {seed}
noise = {{ output = {noise} }}
input = {excitation}""" for which, duration, seed, excitation in (("train", train, 1, train_input),
                                                               ("test", test, 2, test_input))) + "\n"


COUPLED = """name = "coupled_cubic"
[truth]
history = "zero"
delay = { signal = "x", tau = 0.15 }
[[truth.equation]]
coordinate = "x"
mass = 1.0
input = "u"
delay_gain = 1.0
coefficients = { "x'" = 0.4, "x" = 6.0, "y" = -2.0, "x^3" = 3.0 }
[[truth.equation]]
coordinate = "y"
mass = 1.0
input = "u"
delay_gain = 0.5
coefficients = { "y'" = 0.3, "y" = 4.0, "x" = -2.0 }
""" + records(10.0, 8.0, 0.002, '[{ kind = "sine", amplitude = 3.0, omega = 1.9 }, '
                                 '{ kind = "sine", amplitude = 2.0, omega = 4.7 }]',
              '[{ kind = "sine", amplitude = 2.5, omega = 2.9 }, { kind = "sine", amplitude = 2.5, omega = 6.1 }]') + """
[model.delay]
signal = "x"
method = "exact"
tau_max = 0.4
[[model.equation]]
coordinate = "x"
input = "u"
delay_gain = 1.0
library = { terms = ["x'", "x", "y"] }
[[model.equation]]
coordinate = "y"
input = "u"
delay_gain = 0.5
library = { terms = ["y'", "y", "x"] }
[fit]
velocity = "savgol"
refine = "output_error"
"""


def test_a_coupled_system_lacking_a_cubic_stiffness_gets_it_from_the_simulation_error():
    """The diagnosis by simulation error for N = 2 (it was refused): two coupled oscillators,
    a cubic stiffness in x's equation that the model lacks; each candidate joins both
    equations (a chi^2 with 2 degrees of freedom), the missing one scores first, is added
    and kept, and the polish puts it in x's equation and (nearly) nothing in y's."""
    import tomllib

    from cvxid.app.run import run
    from cvxid.spec.load import parse_problem

    lacking = run(parse_problem(tomllib.loads(COUPLED), ROOT))
    out = refine_by_simulation(lacking.polish, lacking.train, lacking.test,
                               ["cubic_stiffness", "coulomb", "offset", "quadratic_damping"])
    ranking = out.rankings[0]
    assert ranking.index[0] == "cubic_stiffness(x)" and (ranking["df"] == 2).all()
    assert ranking.loc["cubic_stiffness(x)", "score"] > chi2.ppf(0.99, 2)  # (measured 12.1)
    first = out.steps[0]
    assert first.added == "cubic_stiffness(x)" and first.kept
    assert first.test_rms_after < 0.05 * first.test_rms_before  # (measured 0.1727 -> 0.0020)
    parameters = out.polish.parameters
    assert parameters["x:x^3"] == pytest.approx(3.0, rel=0.01) and abs(parameters["y:x^3"]) < 0.01
    assert parameters["tau"] == pytest.approx(0.15, rel=0.03)


def test_candidates_of_different_sizes_rank_by_significance_where_p_values_underflow():
    """A chi^2_2 of 3068 is more significant than a chi^2_2 of 2145, and that than a chi^2_1
    of 1919 (every p-value is 0.0 in floating point: ranked by them, the order was the
    catalogue's); a chi^2_1 of 1900 more than a chi^2_2 of 1600 (log10 p -414 and -347,
    which a normal deviate by the cube root put the other way); at usual sizes the exact
    log p-value."""
    from cvxid.diagnosis.simulation import _log_significance

    p = _log_significance([1919.0, 3068.0, 2145.0, 1900.0, 1600.0], [1, 2, 2, 1, 2])
    assert list(np.argsort(p[:3])) == [1, 2, 0] and p[3] < p[4]
    assert p[3] / np.log(10) == pytest.approx(-414.3, abs=0.1) and p[4] / np.log(10) == pytest.approx(-347.4, abs=0.1)
    for x, k in [(6.63, 1), (9.21, 2), (11.3, 3), (700.0, 3)]:
        assert _log_significance(x, k) == pytest.approx(chi2.logsf(x, k), rel=1e-12)


LATE = """
[truth]
mass = 1.0
coefficients = { "x'" = 0.4, "x" = 6.0, "x^3" = 3.0, "sign(x')" = 0.4 }
delay = { signal = "x", gain = -1.5, tau = 0.15 }
history = "zero"
input_delay = 0.03
""" + records(20.0, 10.0, 0.005, '[{ kind = "sine", amplitude = 4.0, omega = 1.3 }, '
                                 '{ kind = "quadratic_chirp", amplitude = 3.0, rate = 0.1 }]',
              '[{ kind = "square", amplitude = 3.0, frequency = 0.3 }, { kind = "sine", amplitude = 2.0, omega = 2.7 }]') + """
[model]
library = { terms = ["x'", "x", "x^3"] }
delay = { signal = "x", gain = -1.5, method = "exact", tau_min = 0.05, tau_max = 0.3 }
[fit]
refine = "output_error"
[diagnose]
refine = true
"""


def test_intervals_after_the_simulation_stage_are_the_final_models():
    """Outside check: the simulation stage added a Coulomb friction and the input's delay,
    and the intervals still read the first polish's delay profile, of the model without
    them: tau's was the whole range 0.05 ... 0.3, x''s 0.38 ... 0.72.  The final model is
    polished again (measured: tau 0.1517 in 0.136 ... 0.166, x' 0.402 in 0.383 ... 0.421).
    (Since 2026-11-26 the stage also keeps a cubic damping of 1.4e-5 on this record, its
    test RMS 0.6 % under the bound: the rule's 5 % level at work on a knife edge that the
    windows of a finer spectrum tipped.)  With the friction's stops located the delay held
    at tau_min = 0.05 after the Coulomb friction was added, and the score test that
    projected the late input's column on the delay's scored it 5.9 (below the 1 % level's
    6.6; 32.6 when a rough friction hid that): a parameter the error presses against its
    bound is left out of the projection (score again 30+, the input delay found)."""
    import tomllib

    from cvxid.app.run import run
    from cvxid.spec.load import parse_problem

    result = run(parse_problem(tomllib.loads(LATE), ROOT))
    steps = result.simulation_refinement.steps
    assert [(s.added, s.kept) for s in steps[:2]] == [("coulomb", True), ("input_delay", True)]
    assert all(abs(result.model.physical[s.term]) < 1e-4 for s in steps[2:] if s.kept)  # (a marginal x'^3)
    low, high = result.to_dict()["tau"]["interval"]
    assert low < 0.15 < high and high - low < 0.05
    low, high = result.polish.physical_interval("x'")
    assert low < 0.4 < high and high - low < 0.1


def test_nothing_is_tried_on_a_noise_free_record_the_model_already_reproduces():
    """An outside check's noise-free control: its polished model missed the test record by 2.3e-9 (the
    nine digits the file was written with), an input delay of 5.7e-9 s lowered that by 0.7 %, beyond the
    chance bound a noise level of 0 sets, and was kept (and the run took 29 s instead of 15).  At a millionth of
    the output's spread the stage now tries nothing, and says why."""
    spec = ModelSpec(Library(parse_term(n) for n in TRUTH), nonnegative=("x''",))
    start = IdentifiedModel(spec, {"x''": 1.0, **TRUTH})
    exact = output_error(start, record(0, noise=0.0), step=DT, max_iterations=20)
    out = refine_by_simulation(exact, record(0, noise=0.0), record(1, noise=0.0),
                               ["offset", "quadratic_damping", "input_delay"])
    assert out.at_precision and not out.steps and "numerical precision" in repr(out)


def test_a_record_with_gaps_scores_every_candidate():
    """A fourth outside check: with NaN samples in the input (``gaps = true``) the score
    test's step read the input's standard deviation as NaN, six of seven candidates scored
    NaN and the diagnosis by simulation error was off without a word."""
    lacking = polished(("x'", "x"))
    whole = record(0)
    x, f = whole.output("x").copy(), whole.input("f").copy()
    x[1500:1530], f[1490:1540] = np.nan, np.nan
    gapped = Experiment(whole.time, {"x": x}, {"f": f}, "gapped", gaps=True)
    ranking = score_candidates(lacking.model, gapped, ["cubic_stiffness", "offset", "quadratic_damping"])
    assert np.isfinite(ranking["score"]).all(), ranking
    assert ranking.index[0] == "cubic_stiffness" and ranking.loc["cubic_stiffness", "score"] > chi2.ppf(0.99, 1)


def test_a_final_re_polish_the_test_record_judges_worse_is_not_kept():
    """A fourth outside check (the unbalanced disk from `cvxid init`): the final re-polish
    (with its delay profile) fitted the training record better and was kept, though the
    test record, which had judged every step, read it 50 % worse (0.0952 against 0.0632
    rad).  It is kept only within TEST_SLACK of the judged model's test error."""
    from cvxid.diagnosis.simulation import TEST_SLACK, _no_worse

    judged = np.full(100, 0.0632)
    assert not _no_worse(np.full(100, 0.0952), judged)
    assert _no_worse(np.full(100, 0.0632 * (1 + TEST_SLACK / 2)), judged)
    assert not _no_worse(None, judged)  # a re-polish whose free run diverges on the test record


def test_a_re_polish_the_test_record_judges_worse_is_dropped_with_a_warning(monkeypatch):
    """The rule in place: the final re-polish reports a better training fit (here forced)
    with a model the test record reads worse (its cubic stiffness zeroed); the judged model
    is kept, and the warning says its intervals are local."""
    from dataclasses import replace

    import cvxid.diagnosis.simulation as stage
    from cvxid import CvxidWarning

    real = stage.polish

    def flattering(system, train, **settings):
        fit = real(system, train, **settings)
        model = fit.system.single
        worse = replace(model, coefficients=dict(model.coefficients, **{"x^3": 0.0}))
        return replace(fit, rms_after=0.5 * fit.rms_after, system=replace(fit.system, models={"x": worse}))

    monkeypatch.setattr(stage, "polish", flattering)
    lacking = polished(("x'", "x"))
    with pytest.warns(CvxidWarning, match="the model the test record judged is kept, and its intervals are its "
                                          "standard errors'"):
        out = refine_by_simulation(lacking, record(0), record(1), ["cubic_stiffness"])
    assert out.polish.parameters["x^3"] == pytest.approx(TRUTH["x^3"], rel=0.05) and out.polish.profile is None


def test_an_effect_the_final_polish_takes_to_zero_is_not_reported_kept(monkeypatch):
    """A sixth outside check: the simulation stage reported a Coulomb friction kept while
    the final model's coefficient was exactly 0 (the final polish held it at its bound).
    Here the final polish is made to do that to the cubic stiffness (and the test record
    not to object): the step says it is not kept, and a warning says why."""
    from dataclasses import replace

    import cvxid.diagnosis.simulation as stage
    from cvxid import CvxidWarning

    real = stage.polish

    def to_zero(system, train, **settings):
        fit = real(system, train, **settings)
        model = fit.system.single
        return replace(fit, system=replace(fit.system, models={
            "x": replace(model, coefficients=dict(model.coefficients, **{"x^3": 0.0}))}))

    monkeypatch.setattr(stage, "polish", to_zero)
    monkeypatch.setattr(stage, "_no_worse", lambda residual, judged: True)
    lacking = polished(("x'", "x"))
    with pytest.warns(CvxidWarning, match=r"kept cubic_stiffness \(x\^3\) on the test record, and the final polish "
                                          "took its coefficient to 0"):
        out = refine_by_simulation(lacking, record(0), record(1), ["cubic_stiffness"])
    assert out.steps[0].added == "cubic_stiffness" and not out.steps[0].kept


def test_a_parameter_pressed_against_its_bound_is_not_free_in_the_score_test():
    """The linearisation a score test projects on leaves out a parameter that sits at a
    bound its gradient points past (the fit would move it out), and keeps one whose gradient
    points inside, or that sits away from its bounds."""
    from types import SimpleNamespace

    from cvxid.identify.output_error import _pressed

    problem = SimpleNamespace(bounds=(np.array([0.05, 0.05, -np.inf, 0.0, 0.0]), np.array([0.3, 0.3] + [np.inf] * 3)),
                              start=np.array([0.05, 0.05, 1.0, 0.3, 0.0]), natural=np.ones(5))
    r = np.array([1.0, -2.0])
    J = np.array([[1.0, -1.0, 1.0, 1.0, 1e-17], [0.0, 0.0, 0.0, 0.0, 1.0]])  # gradient J^T r = (1, -1, 1, 1, ~-2)
    assert _pressed(problem, r, J).tolist() == [True, False, False, False, False]
    problem.start = np.array([0.3, 0.3, 1.0, 0.0, 0.0])  # at the upper bound, pressed when the gradient is negative
    assert _pressed(problem, r, J).tolist() == [False, True, False, True, False]
    J[:, 4] = [2.1, 1.0]  # at its lower bound, pushed out (gradient 0.1): pressed
    assert _pressed(problem, r, J)[4]
    J[:, 4] = [2.0 + 1e-12, 1.0]  # a gradient of round-off (1e-12 against |J_i| |r| = 5) presses nothing
    assert not _pressed(problem, r, J)[4]


def test_the_candidates_fitted_as_joblib_tasks_give_the_serial_result():
    """Issue 15: the diagnosis's candidate fits run on the engine the user picks.  With
    ``n_jobs = 2`` a round's significant candidates are fitted together (threads, then
    worker processes) and read best first: the same steps, test errors and final model as
    one after another."""
    from cvxid.diagnosis.simulation import LEVEL
    from cvxid.parallel import engine

    lacking = polished(("x'", "x"))
    names = ["quadratic_damping", "offset", "cubic_stiffness", "quadratic_stiffness", "cubic_damping"]
    serial = refine_by_simulation(lacking, record(0), record(1), names)
    ranking = serial.rankings[0]
    assert (ranking["score"] >= chi2.ppf(LEVEL, ranking["df"])).sum() > 1  # (several fitted together)
    for backend in ("threading", "loky"):
        with engine(backend):
            together = refine_by_simulation(lacking, record(0), record(1), names, n_jobs=2)
        assert [(s.added, s.kept, s.test_rms_after) for s in together.steps] == \
            [(s.added, s.kept, s.test_rms_after) for s in serial.steps], backend
        assert together.polish.parameters == serial.polish.parameters, backend
