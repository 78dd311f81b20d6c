"""Delays: Taylor map, exact delay with profile search, output-error polish."""

from dataclasses import replace

import numpy as np
import pytest

from cvxid import CvxidError, CvxidWarning
from cvxid.data.experiment import Experiment
from cvxid.identified import IdentifiedModel
from cvxid.identify.output_error import polish
from cvxid.identify.problem import Problem
from cvxid.identify.profile import effective_rows, profile_delay
from cvxid.model.delay import DelayedFeedback
from cvxid.model.equation import ModelSpec
from cvxid.model.library import Library
from cvxid.model.terms import parse_term
from cvxid.regression.builder import RegressionBuilder
from cvxid.simulate import System, simulate

TERMS = ("x'", "x", "x^3")
TRUE = {"m": 1.0, "x'": 0.5, "x": 4.0, "x^3": 1.0, "tau": 0.15, "gain": 1.5}


def record(seed, noise, x0=0.5, duration=6.0, dt=1e-3, history="zero"):
    t = np.arange(int(duration / dt) + 1) * dt
    force = lambda s: 3 * np.sin(2.1 * s) + 2 * np.sin(5.3 * s + 1) + 1.5 * np.sin(9.7 * s)
    system = System(tuple(parse_term(n) for n in TERMS), np.array([TRUE[n] for n in TERMS]), 1.0, "x",
                    TRUE["gain"], TRUE["tau"], 0, history)
    x, v = simulate(system, t, force, x0, 0.0)
    rng = np.random.default_rng(seed)
    return Experiment(t, {"x": x + noise * rng.standard_normal(t.size)}, {"f": force(t)}, "e", {"x": v})


def model(method="exact", gain=TRUE["gain"], **kw):
    delay = DelayedFeedback("x", 0, gain, method=method, tau_max=0.4, **kw)
    return ModelSpec(Library(parse_term(n) for n in TERMS), delay=delay, nonnegative=("x''",))


def test_taylor_map_inverts_the_coefficients():
    spec = ModelSpec(Library(parse_term(n) for n in TERMS), delay=DelayedFeedback("x", 0, 2.0, 3))
    tau = 0.2
    coefs = {"x''": 1 - 2 * tau**2 / 2, "x'": 0.5 + 2 * tau, "x": 4 - 2, "x^3": 1.0, "x'''": 2 * tau**3 / 6}
    phys = spec.physical(coefs)
    assert phys["tau"] == pytest.approx(tau, rel=1e-9)
    assert phys["m"] == pytest.approx(1.0) and phys["x'"] == pytest.approx(0.5) and phys["x"] == pytest.approx(4.0)


def test_taylor_tau_fitted_from_several_coefficients():
    d = DelayedFeedback("x", 0, 2.0, 5)
    tau = 0.17
    pure = {j: d.contribution(j, tau) for j in (3, 4, 5)}
    assert d.estimate_tau(pure) == pytest.approx(tau, rel=1e-8)


def test_taylor_tau_ignores_the_gain_only_column():
    # a library without x leaves the x column to the delay alone: its coefficient is -gain
    # whatever tau is, so tau comes from the other pure-delay columns (no division by zero)
    d = DelayedFeedback("x", 0, 2.0, 3)
    tau = 0.2
    assert d.estimate_tau({j: d.contribution(j, tau) for j in (0, 3)}) == pytest.approx(tau, rel=1e-8)
    with pytest.raises(CvxidError, match="cannot be identified"):
        d.estimate_tau({0: -2.0})


@pytest.mark.parametrize("history", ["zero", "initial"])
def test_exact_delay_profile_recovers_tau_without_noise(history):
    exp = record(0, 0.0, history=history)
    spec = replace(model(), delay=replace(model().delay, history=history))
    fam = RegressionBuilder(spec, exp, "measured")
    prof = profile_delay(fam, nonnegative=spec.nonnegative)
    assert prof.estimate == pytest.approx(TRUE["tau"], abs=2e-4)
    assert prof.interval[0] <= prof.estimate <= prof.interval[1]
    fit = Problem.from_regression(fam.at(prof.estimate)).refit(np.ones(4, bool))
    phys = spec.physical(dict(zip(fam.at(prof.estimate).names, fit.coefficients)), prof.estimate)
    for name in ("m", "x'", "x", "x^3"):
        assert phys[name] == pytest.approx(TRUE[name], rel=2e-3), name


def test_unknown_gain_is_estimated_with_the_delay():
    exp = record(1, 0.0)
    spec = model(gain=None)
    assert "x(t-tau)" in spec.column_names
    fam = RegressionBuilder(spec, exp, "measured")
    prof = profile_delay(fam, nonnegative=spec.nonnegative)
    reg = fam.at(prof.estimate)
    fit = Problem.from_regression(reg).refit(np.ones(reg.shape[1], bool))
    phys = spec.physical(dict(zip(reg.names, fit.coefficients)), prof.estimate)
    assert phys["gain"] == pytest.approx(TRUE["gain"], rel=0.02)
    assert phys["tau"] == pytest.approx(TRUE["tau"], rel=0.02)


def test_record_shorter_than_the_delay_is_refused():
    with pytest.raises(CvxidError, match="too short for delays up to tau_max"):
        RegressionBuilder(model(), record(0, 0.0, duration=0.5), "measured")


def test_effective_rows_of_white_and_coloured_noise(rng):
    white = rng.standard_normal(4000)
    assert effective_rows(white) > 2000
    coloured = np.convolve(white, np.ones(200) / 200, mode="same")
    assert effective_rows(coloured) < 200


@pytest.mark.slow
def test_output_error_polish_reaches_the_noise_floor():
    # start from a deliberately wrong model: 20 % off everywhere and tau = 0.05
    exp = record(3, 0.01)
    spec = model()
    wrong = {"x''": 1.2, "x'": 0.4, "x": 3.2, "x^3": 1.2}
    refinement = polish(IdentifiedModel(spec, wrong, tau=0.05), exp)
    assert refinement.rms_after < 0.0105  # the noise is 0.01
    assert refinement.rms_after < refinement.rms_before / 5
    phys = refinement.model.physical
    for name in ("m", "x", "x^3"):  # well determined by this record
        assert phys[name] == pytest.approx(TRUE[name], rel=0.02), name
    for name in ("m", "x", "x^3"):  # and their intervals are narrow (measured widths 3.3 %, 0.4 %, 2.5 %)
        lo, hi = refinement.interval(name, z=3.0)
        assert lo <= TRUE[name] <= hi and hi - lo < 0.05 * TRUE[name], name
    for name, width in (("x'", 0.35), ("tau", 0.25)):  # damping and delay trade off here: the interval must
        lo, hi = refinement.interval(name, z=3.0)     # say so, and stay finite (measured 0.28, 0.19 wide)
        assert lo <= TRUE[name] <= hi and 0 < hi - lo < width, name


def test_the_profile_on_the_bands_step_compares_every_sample_and_matches_the_sample_step():
    """The polish's coarse fits simulate on a step set by the record's band
    (:func:`~cvxid.identify.output_error.profile_step`: 6 samples here) and compare every
    sample between the steps (:func:`~cvxid.identify.output_error.between_steps`): the
    delay, its interval and the other parameters are those of the profile at the sample
    step to a small share of their intervals (the steps' own samples alone moved a weakly
    determined delay to another basin on held-out systems)."""
    from cvxid.identify.output_error import between_steps, profile_step
    from cvxid.identified import IdentifiedSystem

    exp = record(5, 0.01, duration=8.0)
    start = IdentifiedModel(model(), {"x''": 1.1, "x'": 0.45, "x": 3.8, "x^3": 1.1}, tau=0.1)
    assert profile_step(IdentifiedSystem.of(start), [exp]) >= 4e-3  # (a step of several samples)
    banded, fine = polish(start, exp), polish(start, exp, coarse_step=exp.dt)
    for name in ("tau", "m", "x", "x'"):
        width = np.subtract(*fine.interval(name)[::-1])
        assert abs(banded.parameters[name] - fine.parameters[name]) < 0.02 * width, name
        assert np.allclose(banded.interval(name), fine.interval(name), rtol=0, atol=0.1 * width), name
    t = np.linspace(0, 2, 41)  # the interpolation between steps: cubic Hermite, O(h^4)
    X, V = np.sin(3 * t)[:, None, None], 3 * np.cos(3 * t)[:, None, None]
    assert np.abs(between_steps(X, V, 4, t[1] - t[0])[:, 0, 0] - np.sin(3 * np.linspace(0, 2, 161))).max() < 2e-6


def test_a_start_outside_the_bounds_is_projected_and_said():
    """An equation-error start with a negative mass (seen on held-out records) used to end
    in scipy's "Initial guess is outside of provided bounds"; the start is projected into
    the bounds (mass 1e-9, tau into [tau_min, tau_max]) and the user is told."""
    exp = record(4, 0.001, duration=3.0)
    wrong = {"x''": -0.3, "x'": 0.4, "x": 4.0, "x^3": 1.5}
    from cvxid.identify.output_error import output_error

    with pytest.warns(CvxidWarning, match=r"started outside its bounds: m = -0.3 \(set to 1e-09\).*tau = 0.9"):
        fit = output_error(IdentifiedModel(model(), wrong, tau=0.9), exp, step=2e-3, max_iterations=5)
    assert fit.parameters["m"] > 0 and 0 <= fit.parameters["tau"] <= model().delay.tau_max


def test_a_delay_interval_stays_within_the_delays_searched():
    """Outside check: ``polish(model, train, grid=0).interval("tau")`` gave (0, 18.1) for a
    search range of [0, 0.5] (a standard error far larger than the range): a delay's
    interval is clipped to its bounds, as the input delay's was."""
    from dataclasses import replace

    exp = record(4, 0.001, duration=3.0)
    start = {"x''": 1.0, **{n: TRUE[n] for n in TERMS}}
    fit = polish(IdentifiedModel(model(), start, tau=TRUE["tau"]), exp, grid=0, final=False,
                 max_iterations=3)
    loose = replace(fit, standard_errors=dict(fit.standard_errors, tau=100.0))
    assert loose.interval("tau") == (0.0, model().delay.tau_max)


def test_feedback_without_delay_is_identified_with_a_zero_delay(tmp_path):
    """A loop closed without delay, identified by a user who allowed one (gain unknown):
    the delay's interval lies in [0, tau_max] and covers 0 (the polish used to report 1e-10
    with an interval of nan … nan), the free run fits the test record (measured 99.8 %, the
    noise allows 99.8 %), and the warning says gain and stiffness are one at tau = 0."""
    import json

    from cvxid.app.cli import main

    from .test_sensor import SIMULATED, spec_text

    text = (spec_text(SIMULATED)  # the sensor tests' delayed oscillator, its loop closed at once, 4 s records
            .replace("tau = 0.15 }", "tau = 0.0 }").replace("gain = 1.5\nmethod", "method")
            .replace("duration = 8.0", "duration = 4.0") + 'refine = "output_error"\n')
    (tmp_path / "spec.toml").write_text(text)
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    low, high = result["tau"]["interval"]
    # within [tau_min, tau_max] and covering 0 (measured on 4 s records: the gain comes out
    # -0.007, so every delay fits: 0 … 0.4; on 8 s: 0.015 in 0 … 0.022)
    assert 0 == low <= result["tau"]["estimate"] <= high <= 0.4
    assert result["test_fit_percent"] >= 99.0
    # gain and stiffness are one column at tau = 0: their difference is identified, and the
    # warning says so (the run found gain -438, k -434: k - gain = 4.50 for a true 4.5)
    k, gain = result["physical"]["x"], result["physical"]["gain"]
    assert k - gain == pytest.approx(6.0 - 1.5, rel=0.01)
    assert any("not identified separately" in w and "Give the gain" in w for w in result["warnings"])
    assert not any("search range" in w for w in result["warnings"])  # (that warning, not a second one)


@pytest.mark.slow
def test_a_record_sampled_faster_than_the_profile_step_gets_a_profile_interval():
    """problems/duffing_delay_exact.toml is sampled at 5 kHz; the delay profile simulates
    on a 1 ms step.  Its interval compared the profile with the final fit's error at the
    sample step, which differs from the profile's by more than the interval's threshold
    (0.6 % against 0.01 %): the interval spread over whatever part of the profile lay below
    it (c3af0fd: 0.1583 ... 0.2266, half-width 17 % of the delay; 1.8 to 17 % over the
    noise seeds 1-8).  Read against the converged fit on its own step it is 0.1944 ...
    0.2027 (1.9 to 4.1 % over those seeds, all eight covering 0.2), beside the standard
    error's 1.96 se = 1.9 %."""
    from cvxid.app.run import run

    from .conftest import ROOT

    result = run(ROOT / "problems" / "duffing_delay_exact.toml")
    low, high = result.tau["interval"]
    se = result.polish.standard_errors["tau"]
    assert low <= 0.2 <= high
    assert (high - low) / 2 < 3 * 1.96 * se, (low, high, se)


def test_a_taylor_delay_warning_from_inside_the_polish_is_not_the_runs():
    """duffing_delay.toml selected by the lasso with the output-error polish (noise seed 1):
    the polish's delay profile rewrites the Taylor columns at every delay of its grid, and
    near tau = 0 they give no positive delay: "the Taylor delay coefficients have the wrong
    sign ...; tau is reported as 0" used to reach the result beside tau = 0.199.  A delay
    the polish estimates supersedes every equation-error (Taylor) reading of it."""
    import tomllib

    from cvxid.app.run import run
    from cvxid.errors import EquationErrorDelayWarning
    from cvxid.spec.load import parse_problem

    from .conftest import ROOT

    raw = tomllib.loads((ROOT / "problems" / "duffing_delay.toml").read_text())
    raw["fit"] = {"estimator": "lasso", "velocity": "savgol", "refine": "output_error"}
    polished = run(parse_problem(raw, ROOT / "problems"))
    assert polished.tau["estimate"] == pytest.approx(0.2, rel=0.01)
    assert not any("wrong sign for a positive delay" in w for w in polished.warnings), polished.warnings
    delay = DelayedFeedback(gain=2.0, taylor_order=3)
    with pytest.warns(EquationErrorDelayWarning, match="wrong sign for a positive delay; tau is reported as 0"):
        assert delay.estimate_tau({1: -1.0}) == 0.0  # x''s share is gain * tau > 0: a negative one has no tau


def test_an_interval_of_a_parameter_named_negated_is_in_its_sign(tmp_path):
    """Review: ``k = "-x"`` printed k -6.0 with the interval 6.0 … 6.0 (the coefficient's):
    the interval is the physical parameter's, around its estimate."""
    import json

    from cvxid.app.cli import main

    from .conftest import TEST_SIMULATED, TRAIN_SIMULATED

    text = ('name = "negated"\n[truth]\nmass = 1.0\ncoefficients = { "x\'" = 0.4, "x" = 6.0 }\n'
            + TRAIN_SIMULATED + "\n" + TEST_SIMULATED
            + '\n[model.library]\nterms = ["x", "x\'"]\n[model.names]\nk = "-x"\n'
              '[fit]\nestimator = "lstsq"\nrefine = "output_error"\n')
    (tmp_path / "spec.toml").write_text(text)
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    low, high = result["polish"]["intervals"]["k"]
    assert result["physical"]["k"] == pytest.approx(-6.0, rel=1e-3) and low < result["physical"]["k"] < high < 0


def delayed_spec(name: str, k: float, gain: float, tau: float, duration: float, dt: float, seed: int,
                 noise: tuple[float, float], omegas: tuple[float, float, float], tau_max: float, fit: str = "") -> str:
    """A spec of a simulated ``x'' + 0.6 x' + k x = f + gain x(t - tau)``, the gain estimated,
    a three-sine force of amplitudes 3, 2 and 1.5 (``noise``: on the output and the input)."""
    sines = ",\n".join(f'  {{ kind = "sine", amplitude = {a}, omega = {w}, phase = {p} }}'
                        for a, w, p in zip((3.0, 2.0, 1.5), omegas, (0.0, 1.0, 2.0)))
    return f"""name = "{name}"
[truth]
mass = 1.0
coefficients = {{ "x'" = 0.6, "x" = {k} }}
delay = {{ signal = "x", gain = {gain}, tau = {tau} }}
[data.train.simulate]
duration = {duration}
dt = {dt}
x0 = 0.3
seed = {seed}
noise = {{ output = {noise[0]}, input = {noise[1]} }}
input = [
{sines},
]
[model.library]
terms = ["x", "x'"]
[model.delay]
signal = "x"
method = "exact"
tau_max = {tau_max}
{fit}"""


CANCELLING_SPEC = delayed_spec("cancelling", 5.0, 1.2, 0.12, 20.0, 1e-3, 11, (0.005, 0.005), (1.3, 3.1, 5.7), 0.4)


@pytest.mark.slow
def test_a_polish_started_where_the_gain_and_the_stiffness_cancel_leaves_that_basin(tmp_path):
    """An outside check's equation-error fit with the gain free: 1289 x - 14.7 x' = f + 1285 x(t - 0.012)
    for a truth of 5, 0.6, 1.2 and 0.12 (x and x(t - tau) nearly one column).  From there the polish stayed
    in that basin (k 1195, gain 1191, intervals +-0.4 that miss the truth, simulation RMS 0.005067); it
    restarts from the net model with a small gain, and reaches the valley where gain and delay trade (RMS
    0.004993), its intervals covering the truth."""
    import cvxid
    from cvxid.identify.output_error import cancelling_gain, output_rms, without_cancelling_gain

    (tmp_path / "spec.toml").write_text(CANCELLING_SPEC)
    run = cvxid.run(str(tmp_path / "spec.toml"))
    model = run.model
    coefficients = {**model.coefficients, "x''": 1.084, "x": 1289.1, "x'": -14.68, "x(t-tau)": -1285.3}
    runaway = IdentifiedModel(model.spec, coefficients, model.lam, dict(model.info), 0.012)
    start = without_cancelling_gain(runaway).models["x"].coefficients
    assert start["x"] == pytest.approx(3.8 + 0.38) and start["x(t-tau)"] == pytest.approx(-0.38)
    assert start["x'"] == pytest.approx(-14.68 + (1285.3 - 0.38) * 0.012)  # b x(t - tau) = b x - b tau x' + ...
    polished = polish(runaway, run.train)
    assert polished.rms_after < 0.0050 < output_rms(runaway, run.train)
    assert cancelling_gain(runaway) == pytest.approx(1285.3) and cancelling_gain(polished.system.single) is None
    for name, truth in (("x", 5.0), ("gain", 1.2), ("x'", 0.6), ("m", 1.0)):
        low, high = polished.physical_interval(name)
        assert low <= truth <= high, (name, low, high)


@pytest.mark.slow
def test_a_profile_walked_from_a_runaway_gain_is_refitted_from_its_good_neighbours(tmp_path):
    """An outside check's fast plant started the delay profile where the estimated gain was six times the truth:
    every fit beyond it diverged (its neighbour's gain unstable there), each started from the diverged one before,
    and the interval missed the truth.  Here a start with a gain of 200 (truth 1.2) at tau 0.02: 15 of the 28
    points diverged and the interval was 0.145 … 0.216 for a truth of 0.12 (the record cannot tell delays of
    0.04 … 0.4 apart with the gain free).  A diverged fit now starts again from the net model with a small gain,
    a stranded point is refitted from its neighbour towards the best, and the interval spans the valley."""
    import cvxid

    (tmp_path / "spec.toml").write_text(CANCELLING_SPEC)
    run = cvxid.run(str(tmp_path / "spec.toml"))
    model = run.model
    coefficients = {**model.coefficients, "x''": 1.0, "x": 183.8, "x'": 4.576, "x(t-tau)": -200.0}
    runaway = IdentifiedModel(model.spec, coefficients, model.lam, dict(model.info), 0.02)
    polished = polish(runaway, run.train)
    profile = polished.profile
    assert np.all(profile.values < 1.2 * profile.values.min()), profile.values  # no diverged or stranded point
    low, high = profile.interval
    assert low < 0.06 and high == pytest.approx(0.4) and low <= 0.12 <= high


WIDE_RANGE_SPEC = delayed_spec("wide", 9.0, 2.25, 0.15, 200.0, 0.01, 3, (0.01, 0.0), (1.7, 2.9, 4.3), 20.0,
                               '[fit]\nestimator = "lstsq"\nrefine = "output_error"\n')


@pytest.mark.slow
def test_a_delay_interval_edge_between_coarse_profile_points_is_found_by_bisection(tmp_path):
    """A delay range of 20 s (a tenth of a 200 s record) for a delay of 0.15: the profile's points are 1 s apart
    and the gain, estimated, trades with the delay, so the profile is flat from about 0.03 s and steep below.  The
    interval's lower edge came from the chord between tau = 0 and the estimate, 0.214, next to the estimate
    (0.216), and missed the truth; bisected, it is within a few hundredths of the valley's end."""
    import cvxid

    (tmp_path / "spec.toml").write_text(WIDE_RANGE_SPEC)
    run = cvxid.run(str(tmp_path / "spec.toml"))
    low, high = run.polish.profile.interval
    assert low < 0.1 < 0.15 < 0.5 < high, (low, high)


def test_a_delay_the_record_does_not_determine_is_said_aloud(tmp_path):
    """The same system, the gain free and no polish: the convex profile's interval is 0.089 … 0.4 s of the
    range 0 … 0.4 (the truth 0.12, the estimate 0.399): the run says the delay is not determined, where it
    said nothing (the interval did not reach 0, the estimate was not at the bound)."""
    import json

    from cvxid.app.cli import main

    (tmp_path / "spec.toml").write_text(CANCELLING_SPEC)
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    low, high = result["tau"]["interval"]
    assert low <= 0.12 <= high and high - low > 0.2
    assert any("the delay is not determined by these data" in w for w in result["warnings"]), result["warnings"]


@pytest.mark.slow
def test_a_free_gain_on_a_loop_without_feedback_is_told_to_go_not_to_look_further(tmp_path):
    """A linear oscillator without feedback, identified with [model.delay] and its gain free (an outside check):
    the delay ran to tau_max and the run said to raise it; the gain's interval holds 0 and the gain trades with
    the stiffness, so the run says that, and to remove [model.delay] if the loop has no delay."""
    import json

    from cvxid.app.cli import main

    text = CANCELLING_SPEC.replace('delay = { signal = "x", gain = 1.2, tau = 0.12 }\n', "") + \
        '[fit]\nrefine = "output_error"\n'
    (tmp_path / "spec.toml").write_text(text)
    assert main(["run", str(tmp_path / "spec.toml"), "--quiet", "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    low, high = result["polish"]["intervals"]["gain"]
    assert low <= 0 <= high
    warned = " ".join(result["warnings"])
    assert result["tau"]["estimate"] >= 0.399  # (measured: 0.4, the top of the range)
    assert "raise [model.delay] tau_max" not in warned
    assert "remove [model.delay] if the loop has no delay" in warned


SLOW_SPEC = """
name = "slow"
[data.train]
file = "train.csv"
time = "t"
output = "x"
input = "f"
[data.test]
file = "test.csv"
time = "t"
output = "x"
input = "f"
[model.library]
terms = ["x", "x'"]
[model.delay]
signal = "x"
method = "exact"
tau_max = 0.3
[model.names]
k = "x"
c = "x'"
[fit]
refine = "output_error"
"""


def test_a_gain_that_cancels_the_stiffness_does_not_hold_the_delay_profile(tmp_path):
    """A tenth outside check: at 50-100 Hz with the gain free, the polish's delay profile
    walked from a fit whose gain cancelled the stiffness (k -245, gain -250 for 6 and 1.5)
    and every fit of the walk stayed there, while from the truth's side the simulation
    error was lower.  Here x'' + 0.4 x' + 6 x = f + 1.5 x(t - 0.15) at 100 Hz, noise 0.005
    of each signal's spread (seed 3 of eight tried: before, tau 0.0 with the interval
    0 ... 0.031, c's missing 0.4); each profile fit whose gain cancels is now also started
    from its net model with a small gain, and the intervals hold the truth."""
    import pandas as pd

    from cvxid.app.run import run

    system = System((parse_term("x'"), parse_term("x")), np.array([0.4, 6.0]), 1.0, "x", 1.5, 0.15, 0, "zero")
    for i, (amps, omegas) in enumerate((([3, 2, 1.5], [1.9, 4.7, 8.3]), ([2.5, 2.5], [2.9, 6.1]))):
        phases = np.linspace(0, 3, len(amps))

        def force(s, amps=amps, omegas=omegas, phases=phases):
            return sum(a * np.sin(o * s + p) for a, o, p in zip(amps, omegas, phases))

        t = np.arange(13001) * 1e-3
        x, _ = simulate(system, t, force, 0.0, 0.0)
        kept = slice(3000, None, 10)  # (the last 10 s at 100 Hz, from mid-motion)
        rng = np.random.default_rng(3 + i)
        xs, fs = x[kept], force(t[kept])
        pd.DataFrame({"t": t[kept] - 3.0, "x": xs + 0.005 * xs.std() * rng.standard_normal(xs.size),
                      "f": fs + 0.005 * fs.std() * rng.standard_normal(fs.size)}).to_csv(
            tmp_path / ("train.csv", "test.csv")[i], index=False)
    (tmp_path / "spec.toml").write_text(SLOW_SPEC)
    result = run(tmp_path / "spec.toml")
    low, high = result.tau["interval"]
    assert low <= 0.15 <= high
    for name, value in {"k": 6.0, "c": 0.4, "gain": 1.5}.items():
        low, high = result.polish.physical_interval(name)
        assert low <= value <= high, name
